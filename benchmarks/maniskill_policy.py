"""ManiSkill3 PickCube from state: the motion planner's demonstrations through the seam -> LeRobot ACT ->
``simseam eval`` on held-out seeds, beside the planner itself on the same seeds.

    .venv/bin/python benchmarks/maniskill_policy.py [--eval-seeds 10000:10100] [--demos 320] [--train-steps 6000]
        [--train-s 900] [--workers 2] [--work DIR] [--json FILE] [--checkpoint DIR] [--n-action-steps K]
        [--collect-only]

    # the recipe that reaches 96/100 (docs/policies.md): 480 demonstrations here, ACT dim 256 trained on a GPU
    .venv/bin/python benchmarks/maniskill_policy.py --demos 480 --work W --collect-only
    #   then benchmarks/device/maniskill_train.sh (its header) with STEPS=16000 DIM_MODEL=256 FF_DIM=1024
    #   ENCODER_LAYERS=4, and here:
    .venv/bin/python benchmarks/maniskill_policy.py --work W --checkpoint W/ckpt --json benchmarks/results/X.json

Four phases:

1. collect: ManiSkill's motion-planning solution (mplib, planned at each reset on a twin env, replayed through
   the seam) on seeds ``0 .. demos-1``, in ``--workers`` processes (blocks of seeds, merged with LeRobot's
   ``aggregate_datasets``); the state is ManiSkill's own ``obs_mode="state"`` vector (42-D: the Panda's qpos
   and qvel, the TCP pose, the cube's pose, the goal, and their differences); the action the planner's
   ``pd_joint_pos`` targets (7 joints + grip), 20 Hz. Unlike ``simseam collect`` (which ends an episode at
   its first success), each episode is recorded for ``tail`` more steps of the planner after its first
   success (it holds its last target): at the first success the arm is still decelerating, so demonstrations
   cut there never show the arm settling at the goal, and a policy that reaches the goal without stopping
   finds no data there (docs/policies.md). Kept: episodes that succeed within the preset's step limit and
   are still successful at the end of the tail;
2. ``simseam train``: LeRobot ACT from scratch, no VAE, chunk 20, the whole chunk executed open loop before
   the next model call (no temporal ensembling: on this data it made the policy hesitate, 1/30 against 9/30
   for the same weights executing whole chunks of 10), cosine decay, a small transformer; a fixed step count
   capped at ``--train-s`` seconds;
3. ``simseam eval maniskill_tabletop_mp --tasks PickCube-v1 --policy lerobot:<checkpoint>`` on
   ``--eval-seeds`` (held out: they may not overlap the demonstration seeds). The preset runs the
   planner's control mode at the 100-step limit ManiSkill's own imitation-learning baselines evaluate
   PickCube with (docs/benchmarks.md);
4. the same eval with ``--policy scripted``: the planner itself on the same seeds.

``--checkpoint DIR`` skips phases 1-2: it evaluates a checkpoint trained elsewhere on ``--work``'s
``pickcube_data`` and reports that checkpoint's ``training.json``.

Prints a table, writes JSON (``--json``; default ``benchmarks/results/maniskill_pickcube_act_chunks.json``,
with each seed's outcome for both) and keeps the dataset, checkpoint and run directories under
``--work``. The last printed line ends with ``success_rate=<float>``: the policy's. Exits 0 when every
phase finished (whatever the rate), 1 when one failed.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SIMSEAM = str(Path(sys.executable).with_name("simseam"))
SCENE = "scenes/maniskill_pickcube_joint.yaml"
PRESET, TASK = "maniskill_tabletop_mp", "PickCube-v1"


@dataclass(frozen=True)
class Recipe:
    """The demonstrations and the training recipe (the budgets docs/policies.md reports)."""

    demos: int = 320
    tail: int = 20  # planner steps recorded after an episode's first success
    steps: int = 6000  # the cosine horizon: 761 s on the shared 2-core machine (69/100); 5,500 cut at 3,804 got 64/100
    batch_size: int = 64
    lr: float = 3e-4
    lr_schedule: str = "cosine"
    chunk_size: int = 20
    n_action_steps: int = 20  # whole chunks, open loop: 25/30 on validation seeds 5000-5029 against 16/30 for 10
    temporal_ensemble: float | None = None  # off: with 0.01 the same weights got 1/30 (docs/policies.md)
    dim_model: int = 128
    ff_dim: int = 512
    encoder_layers: int = 2


def parse_seeds(text: str) -> range:
    try:
        start, end = (int(x) for x in text.split(":"))
    except ValueError:
        raise argparse.ArgumentTypeError(f"--eval-seeds {text!r}: expected START:END (integers)") from None
    if not 0 <= start < end:
        raise argparse.ArgumentTypeError(f"--eval-seeds {text!r}: expected 0 <= START < END")
    return range(start, end)


def _simseam(*args: str, log: Path) -> float:
    """Run one ``simseam`` command (output appended to ``log``); returns its wall time in seconds."""
    t0 = time.perf_counter()
    with log.open("a") as f:
        f.write(f"$ simseam {' '.join(args)}\n")
        f.flush()
        rc = subprocess.run([SIMSEAM, *args], stdout=f, stderr=subprocess.STDOUT, cwd=ROOT,
                            env={"OMP_NUM_THREADS": "1", **os.environ}).returncode  # torch's threads contend
    if rc != 0:
        raise RuntimeError(f"simseam {args[0]} exited {rc}; its output is in {log}")
    return time.perf_counter() - t0


def _collect_block(job: tuple[int, int, str, int]) -> tuple[int, int, int]:
    """One worker: the planner on seeds [start, end), each episode recorded up to ``tail`` steps past its
    first success; returns (episodes run, episodes kept, frames kept)."""
    start, end, out, tail = job
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    from simseam.policies.base import make_policy
    from simseam.runner.dataset_recorder import LeRobotRecorder
    from simseam.runner.scene_config import build_rollout, load_scene_config

    cfg, base = load_scene_config(ROOT / SCENE)
    policy = make_policy("scripted")
    rollout = build_rollout(cfg, base, privileged=True, render_images=False, seed=start)
    limit = rollout.spec.task.max_steps
    key = rollout.spec.task.success_key
    kept = frames = 0
    try:
        with LeRobotRecorder(out, rollout.spec, use_videos=False, overwrite=True) as rec:
            for seed in range(start, end):
                policy.reset(rollout.spec)
                obs = rollout.reset(seed, None)
                first, n, success = None, 0, False
                while n < limit + tail:
                    action = policy.act(obs)
                    rec.add(obs, action)
                    step = rollout.step(action, None)
                    n, obs = n + 1, step.observation
                    success = bool(step.info.get(key))
                    if success and first is None:
                        first = n
                    if first is not None and n >= first + tail:
                        break
                keep = first is not None and first <= limit and success
                rec.end_episode(keep)
                kept, frames = kept + keep, frames + (n if keep else 0)
    finally:
        rollout.close()
    return end - start, kept, frames


def collect(recipe: Recipe, root: Path, workers: int) -> dict:
    t0 = time.perf_counter()
    shards = root.parent / (root.name + "_shards")
    shutil.rmtree(shards, ignore_errors=True)
    shutil.rmtree(root, ignore_errors=True)
    shards.mkdir(parents=True)
    bounds = [recipe.demos * k // workers for k in range(workers + 1)]
    jobs = [(bounds[k], bounds[k + 1], str(shards / f"shard{k}"), recipe.tail) for k in range(workers)]
    with mp.get_context("spawn").Pool(workers) as pool:
        runs = pool.map(_collect_block, jobs)
    from lerobot.datasets.aggregate import aggregate_datasets

    kept = [Path(j[2]) for j, r in zip(jobs, runs) if r[1] > 0]
    if not kept:
        raise RuntimeError(f"the planner succeeded in none of {recipe.demos} episodes: no demonstrations")
    aggregate_datasets([f"simseam/shard{k}" for k in range(len(kept))], "simseam/local", roots=kept, aggr_root=root)
    shutil.copy(kept[0] / "meta" / "simseam_skill.json", root / "meta" / "simseam_skill.json")
    shutil.rmtree(shards, ignore_errors=True)
    report = {"seeds": f"0:{recipe.demos}", "episodes_run": sum(r[0] for r in runs),
              "episodes_written": sum(r[1] for r in runs), "frames_written": sum(r[2] for r in runs),
              "workers": workers, "seconds": round(time.perf_counter() - t0, 1)}
    (root.parent / "collect.json").write_text(json.dumps(report) + "\n")  # read back by a --checkpoint run
    return report


def _recorded_collection(work: Path) -> dict | None:
    """The collection report written beside the dataset (``collect.json``), if any."""
    path = work / "collect.json"
    return json.loads(path.read_text()) if path.exists() else None


def _demo_seeds(recipe: Recipe, collected: dict | None) -> range:
    """The seeds the demonstrations came from: the collection's report, else the recipe's."""
    if collected is None:
        return range(0, recipe.demos)
    start, end = (int(x) for x in collected.get("seeds", f"0:{collected['episodes_run']}").split(":"))
    return range(start, end)


def _eval(policy: str, seeds: range, out: Path, device: str, log: Path, n_action_steps: int | None = None) -> dict:
    seconds = _simseam("eval", PRESET, "--tasks", TASK, "--policy", policy,
                       *(["--device", device] if policy.startswith("lerobot:") else []),
                       *(["--n-action-steps", str(n_action_steps)] if n_action_steps else []),
                       "--seed", str(seeds.start), "--episodes", str(len(seeds)), "--out", str(out), "--overwrite",
                       log=log)
    summary = json.loads((out / "summary.json").read_text())
    episodes = sorted(summary["episodes"], key=lambda e: e["seed"])
    wins = [e["steps"] for e in episodes if e["success"]]
    spec, config = summary.get("spec") or {}, summary["config"]  # spec is null in an eval run with --n-action-steps
    return {"policy": policy, "seeds": f"{seeds.start}:{seeds.stop}", "episodes": summary["n_episodes"],
            "successes": summary["n_success"], "success_rate": summary["success_rate"],
            "wilson95": summary["success_rate_wilson95"],
            "max_steps": spec.get("task", {}).get("max_steps") or config["per_task_config"][TASK]["max_steps"],
            "control_mode": spec.get("action", {}).get("control_mode") or config["task_config"]["control_mode"],
            "n_action_steps": n_action_steps, "diagnostics_mean": summary.get("diagnostics_mean"),
            "mean_steps_to_success": round(sum(wins) / len(wins), 1) if wins else None,
            "seconds": round(seconds, 1), "run_dir": str(out),
            "per_seed": [{"seed": e["seed"], "success": e["success"], "steps": e["steps"]} for e in episodes]}


def prove(recipe: Recipe, seeds: range, work: Path, train_s: float, device: str, workers: int,
          checkpoint: Path | None = None, n_action_steps: int | None = None, expert: bool = True) -> dict:
    data, ckpt = work / "pickcube_data", checkpoint or work / "pickcube_act"
    log = work / "pickcube.log"
    if checkpoint is not None and not (data / "meta" / "info.json").exists():
        raise SystemExit(f"--checkpoint: {data} holds no dataset (the one the checkpoint was trained on)")
    demo_seeds = _demo_seeds(recipe, _recorded_collection(work) if checkpoint is not None else None)
    if seeds.start < demo_seeds.stop and demo_seeds.start < seeds.stop:
        raise SystemExit(f"--eval-seeds {seeds.start}:{seeds.stop} overlaps the demonstration seeds "
                         f"{demo_seeds.start}:{demo_seeds.stop}; evaluate on held-out seeds")
    collected = collect(recipe, data, workers) if checkpoint is None else _recorded_collection(work)
    info = json.loads((data / "meta" / "info.json").read_text())
    train_wall = None
    if checkpoint is None:
        train_wall = _simseam("train", "--dataset", str(data), "--out", str(ckpt), "--overwrite", "--cache",
                              "--workers", "0", "--device", device, "--no-vae",
                              "--steps", str(recipe.steps), "--time-budget-s", str(train_s),
                              "--batch-size", str(recipe.batch_size), "--lr", str(recipe.lr),
                              "--lr-schedule", recipe.lr_schedule,
                              "--chunk-size", str(recipe.chunk_size), "--n-action-steps", str(recipe.n_action_steps),
                              *(["--temporal-ensemble", str(recipe.temporal_ensemble)] if recipe.temporal_ensemble else []),
                              "--dim-model", str(recipe.dim_model), "--ff-dim", str(recipe.ff_dim),
                              "--encoder-layers", str(recipe.encoder_layers), log=log)
    training = json.loads((ckpt / "training.json").read_text())
    policy = _eval(f"lerobot:{ckpt}", seeds, work / "eval_act", device, log, n_action_steps)
    planner = _eval("scripted", seeds, work / "eval_expert", device, log) if expert else None
    return {
        "task": TASK, "scene": SCENE, "preset": PRESET,
        # a checkpoint trained elsewhere reports its own training config, not this script's recipe
        "recipe": asdict(recipe) if checkpoint is None else {"tail": recipe.tail, **training["config"]},
        "demos": {"seeds": f"{demo_seeds.start}:{demo_seeds.stop}", "tail_steps_after_success": recipe.tail,
                  "episodes_kept": info["total_episodes"], "frames": info["total_frames"],
                  "collect": collected,
                  "state_dim": info["features"]["observation.state"]["shape"][0],
                  "action_dim": info["features"]["action"]["shape"][0]},
        "training": {"steps": training["steps"], "seconds": round(training["seconds"], 1),
                     "wall_seconds": round(train_wall, 1) if train_wall else None,
                     "checkpoint": str(ckpt), "n_params": training["n_params"],
                     "final_loss": training["losses"][-1][1] if training["losses"] else None,
                     "device": training["device"], "losses": training["losses"]},
        "eval": policy, "expert": planner,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--eval-seeds", type=parse_seeds, default=parse_seeds("10000:10100"),
                    help="held-out evaluation seeds START:END (default 10000:10100)")
    ap.add_argument("--demos", type=int, default=None, help="demonstrations (default: the recipe's)")
    ap.add_argument("--train-steps", type=int, default=None, help="optimizer steps (default: the recipe's); "
                    "training ends at the first of the step count and --train-s")
    ap.add_argument("--train-s", type=float, default=900.0, help="training wall-clock cap, seconds (default 900)")
    ap.add_argument("--workers", type=int, default=2, help="collection processes (default 2)")
    ap.add_argument("--device", default="cpu", help="torch device for training and evaluation (default cpu)")
    ap.add_argument("--n-action-steps", type=int, default=None,
                    help="evaluate executing this many actions per chunk (default: the checkpoint's)")
    ap.add_argument("--no-expert", action="store_true", help="skip the planner's own evaluation")
    ap.add_argument("--collect-only", action="store_true", help="only collect the demonstrations into "
                    "--work's pickcube_data (to train elsewhere: benchmarks/device/maniskill_train.sh)")
    ap.add_argument("--work", type=Path, default=None, help="keep the dataset, checkpoint and runs here "
                    "(default: a new temporary directory)")
    ap.add_argument("--checkpoint", type=Path, default=None, help="evaluate this checkpoint, trained on "
                    "--work's pickcube_data (skips collection and training)")
    ap.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "maniskill_pickcube_act_chunks.json")
    args = ap.parse_args()
    overrides = {"demos": args.demos, "steps": args.train_steps}
    recipe = Recipe(**{**asdict(Recipe()), **{k: v for k, v in overrides.items() if v is not None}})
    work = args.work or Path(tempfile.mkdtemp(prefix="maniskill_policy_"))
    work.mkdir(parents=True, exist_ok=True)
    if args.collect_only:
        print(json.dumps(collect(recipe, work / "pickcube_data", args.workers)))
        return 0
    report = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
              "train_budget_s": args.train_s, "work": str(work)}
    try:
        report.update(prove(recipe, args.eval_seeds, work, args.train_s, args.device, args.workers,
                            args.checkpoint, args.n_action_steps, not args.no_expert))
    except RuntimeError as exc:
        print(f"maniskill_policy: {exc}", file=sys.stderr)
        return 1
    finally:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    d, t, rec = report["demos"], report["training"], report["recipe"]
    print(f"ManiSkill3 {TASK}, state ({d['state_dim']}-D), pd_joint_pos ({d['action_dim']}-D), "
          f"preset {PRESET} ({report['eval']['max_steps']} steps)")
    print(f"demos {d['episodes_kept']} (seeds {d['seeds']}, {d['frames']} frames, {d['tail_steps_after_success']} "
          f"steps past success); training {t['steps']} steps x {rec['batch_size']} in {t['seconds']:.0f} s on "
          f"{t['device']}, {t['n_params']} parameters, final loss {t['final_loss']:.4f}")
    print(f"{'policy':34} {'eval seeds':>12} {'success':>9} {'Wilson 95 %':>15} {'steps':>6} {'eval s':>7}")
    for key in ("eval", "expert"):
        r = report[key]
        if r is None:
            continue
        lo, hi = r["wilson95"]
        name = f"ACT (chunk {rec['chunk_size']}, {r['n_action_steps'] or rec['n_action_steps']} per call)" \
            if key == "eval" else "motion planner (scripted)"
        print(f"{name:34} {r['seeds']:>12} {r['successes']:4d}/{r['episodes']:<4d} [{lo:.3f}, {hi:.3f}] "
              f"{r['mean_steps_to_success'] or 0:6.1f} {r['seconds']:7.0f}")
    print(f"json: {args.json}")
    print(f"maniskill_policy: ACT on {TASK}, held-out seeds {args.eval_seeds.start}:{args.eval_seeds.stop} "
          f"success_rate={report['eval']['success_rate']:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
