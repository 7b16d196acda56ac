"""Train ACT on scripted lift_cube demonstrations and measure its success in simseam.

    .venv/bin/python benchmarks/train_act_lift.py [--episodes 200] [--train-budget-s 420] ...

Three phases, one process, all through simseam's own code paths:

1. collect: the scripted expert (privileged ground truth) runs ``--episodes``
   episodes of franka_panda / lift_cube (MuJoCo, two RGB cameras at
   ``--image-size``, 7-D CARTESIAN_DELTA, 20 Hz), seeds 0..N-1; successful ones are
   written as a LeRobot dataset (``collect_dataset``);
2. train: LeRobot ACT from scratch (no ImageNet weights: no network) on that
   dataset (``train_act``) for ``--steps`` optimizer steps or ``--train-budget-s``
   seconds, whichever comes first;
3. evaluate: the checkpoint is loaded through ``lerobot:<dir>`` (the spec users
   give ``simseam run``) and run on ``--eval-seeds`` held-out seeds (10000+), with
   images only (no privileged state); the scripted expert runs on the same seeds
   as the reference.

Prints a table and writes JSON (``--json``, default benchmarks/results/act_lift.json).
On the GPU machine it runs through ``benchmarks/device/act_lift.sh``.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from simseam.policies.base import make_policy  # noqa: E402
from simseam.robot.manifest import load_robot  # noqa: E402
from simseam.runner.collect import collect_dataset  # noqa: E402
from simseam.runner.episodes import run_episode  # noqa: E402
from simseam.runner.summary import wilson_interval  # noqa: E402
from simseam.runner.training import ActTrainConfig, train_act  # noqa: E402
from simseam.scene.manifest_scene import ManifestScene, SceneOptions  # noqa: E402


def evaluate(spec, policy, seeds, size, privileged, max_steps):
    scene = ManifestScene(spec, "lift_cube", "mujoco",
                          SceneOptions(image_size=(size, size), privileged=privileged, max_steps=max_steps))
    try:
        results = [run_episode(scene, policy, index=i, seed=s) for i, s in enumerate(seeds)]
    finally:
        scene.close()
    return results


def _write(path: Path, report: dict) -> None:
    """Write the report so far (a run cut short still leaves its finished phases)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2) + "\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--episodes", type=int, default=200)
    ap.add_argument("--image-size", type=int, default=96)
    ap.add_argument("--max-steps", type=int, default=150)
    ap.add_argument("--steps", type=int, default=200_000)
    ap.add_argument("--train-budget-s", type=float, default=420.0)
    ap.add_argument("--deadline-s", type=float, default=None,
                    help="whole-run limit: training stops early enough to leave --eval-reserve-s for evaluation")
    ap.add_argument("--eval-reserve-s", type=float, default=75.0)
    ap.add_argument("--batch-size", type=int, default=64)
    ap.add_argument("--lr", type=float, default=1e-4)
    ap.add_argument("--chunk-size", type=int, default=20)
    ap.add_argument("--n-action-steps", type=int, default=10)
    ap.add_argument("--dim-model", type=int, default=512)
    ap.add_argument("--workers", type=int, default=8)
    ap.add_argument("--amp", action="store_true", help="bfloat16 autocast for training on CUDA")
    ap.add_argument("--eval-n-action-steps", default="",
                    help="extra evaluations of the same checkpoint, comma-separated: an integer is n_action_steps, "
                         "'te' is ACT's temporal ensembling (n_action_steps=1, coefficient 0.01)")
    ap.add_argument("--no-cache", action="store_true",
                    help="stream batches through LeRobotDataset's loader instead of caching frames on the device")
    ap.add_argument("--eval-seeds", type=int, default=20)
    ap.add_argument("--videos", action="store_true", help="store camera frames as AV1 video (default: PNG images)")
    ap.add_argument("--work", type=Path, default=Path("runs/act_lift"))
    ap.add_argument("--json", type=Path, default=Path("benchmarks/results/act_lift.json"))
    args = ap.parse_args()

    import torch

    spec = load_robot("franka_panda")
    size = args.image_size
    report: dict = {"host": platform.node(), "torch": torch.__version__,
                    "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
                    "args": {k: str(v) if isinstance(v, Path) else v for k, v in vars(args).items()}}

    t0 = time.perf_counter()
    scene = ManifestScene(spec, "lift_cube", "mujoco",
                          SceneOptions(image_size=(size, size), privileged=True, max_steps=args.max_steps))
    try:
        col = collect_dataset(scene, make_policy("scripted"), args.work / "dataset", episodes=args.episodes,
                              use_videos=args.videos, overwrite=True)
    finally:
        scene.close()
    report["collect"] = {"episodes_run": col.episodes_run, "episodes_written": col.episodes_written,
                         "frames": col.frames_written, "seconds": time.perf_counter() - t0}
    _write(args.json, report)
    print(f"collect: {col.episodes_written}/{col.episodes_run} episodes, {col.frames_written} frames, "
          f"{report['collect']['seconds']:.0f} s", flush=True)

    budget = args.train_budget_s
    if args.deadline_s is not None:
        budget = min(budget, args.deadline_s - args.eval_reserve_s - (time.perf_counter() - t0))
    cfg = ActTrainConfig(steps=args.steps, time_budget_s=budget, batch_size=args.batch_size,
                         lr=args.lr, lr_backbone=args.lr, chunk_size=args.chunk_size,
                         n_action_steps=args.n_action_steps, dim_model=args.dim_model,
                         num_workers=args.workers, cache_on_device=not args.no_cache, use_amp=args.amp,
                         log_every=500)
    res = train_act(args.work / "dataset", args.work / "act", cfg,
                    on_log=lambda s, loss: print(f"  step {s:6d}  loss {loss:.4f}", flush=True))
    report["train"] = {"steps": res.steps, "seconds": res.seconds, "prepare_seconds": res.prepare_seconds,
                       "steps_per_s": res.steps / max(res.seconds, 1e-9), "cached_on_device": not args.no_cache, "device": res.device, "n_params": res.n_params,
                       "batch_size": args.batch_size, "samples_seen": res.steps * args.batch_size,
                       "epochs": res.steps * args.batch_size / max(res.frames, 1), "losses": res.losses}
    _write(args.json, report)
    print(f"train: {res.steps} steps in {res.seconds:.0f} s (+{res.prepare_seconds:.0f} s preparing) on "
          f"{res.device} ({res.n_params / 1e6:.1f} M params)",
          flush=True)

    seeds = list(range(10_000, 10_000 + args.eval_seeds))
    spec_str = f"lerobot:{args.work / 'act'}"
    t1 = time.perf_counter()
    ev = evaluate(spec, make_policy(spec_str), seeds, size, privileged=False, max_steps=args.max_steps)
    eval_s = time.perf_counter() - t1
    runs = [(f"act, n_action_steps={args.n_action_steps}", ev)]
    for variant in filter(None, args.eval_n_action_steps.split(",")):
        if args.deadline_s is not None and time.perf_counter() - t0 > args.deadline_s - 40:
            report.setdefault("skipped_variants", []).append(variant)
            print(f"skipping evaluation variant {variant!r}: too close to --deadline-s", flush=True)
            continue
        if variant == "te":
            pol = make_policy(spec_str, n_action_steps=1, config_overrides={"temporal_ensemble_coeff": 0.01})
            label = "act, temporal ensembling"
        else:
            pol = make_policy(spec_str, n_action_steps=int(variant))
            label = f"act, n_action_steps={int(variant)}"
        runs.append((label, evaluate(spec, pol, seeds, size, privileged=False, max_steps=args.max_steps)))
    ref = evaluate(spec, make_policy("scripted"), seeds, size, privileged=True, max_steps=args.max_steps)
    rows = []
    for name, results in runs + [("scripted expert", ref)]:
        k = sum(r.success for r in results)
        lo, hi = wilson_interval(k, len(results))
        rows.append({"policy": name, "success": k, "episodes": len(results), "rate": k / len(results),
                     "wilson95": [lo, hi], "mean_steps": sum(r.steps for r in results) / len(results),
                     "per_seed": {r.seed: r.success for r in results}})
    report["eval"] = {"seeds": seeds, "seconds": eval_s, "policies": rows,
                      "policy_ms_p50": float(np.median([x for r in ev for x in r.policy_ms]))}
    report["total_seconds"] = time.perf_counter() - t0

    print(f"\n{'policy':28s} {'success':>9s} {'rate':>6s} {'Wilson 95%':>14s} {'mean steps':>11s}")
    for r in rows:
        print(f"{r['policy']:28s} {r['success']:>4d}/{r['episodes']:<4d} {r['rate']:6.0%} "
              f"[{r['wilson95'][0]:.2f}, {r['wilson95'][1]:.2f}] {r['mean_steps']:11.1f}")
    print(f"training budget: {res.steps} steps x batch {args.batch_size} in {res.seconds:.0f} s on "
          f"{report['gpu'] or res.device}; data: {col.episodes_written} demos / {col.frames_written} frames")
    _write(args.json, report)
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
