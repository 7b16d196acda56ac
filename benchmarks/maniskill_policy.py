"""ManiSkill3 PickCube from state: the motion planner's demonstrations through the seam -> LeRobot ACT ->
``simseam eval`` on held-out seeds, beside the planner itself on the same seeds.

    .venv/bin/python benchmarks/maniskill_policy.py [--eval-seeds 10000:10100] [--demos 200] [--train-steps N]
        [--train-s 900] [--work DIR] [--json FILE] [--checkpoint DIR]

Four phases, each a ``simseam`` command a user types:

1. ``simseam collect --scene scenes/maniskill_pickcube_joint.yaml --policy scripted --no-cameras``:
   ManiSkill's motion-planning solution (mplib, planned at each reset on a twin env, replayed through the
   seam) on seeds ``0 .. demos-1``; the state is ManiSkill's own ``obs_mode="state"`` vector (42-D: the
   Panda's qpos and qvel, the TCP pose, the cube's pose, the goal, and their differences); the action the
   planner's ``pd_joint_pos`` targets (7 joints + grip), 20 Hz; successful episodes only;
2. ``simseam train``: LeRobot ACT from scratch (the state proof's recipe: no VAE, chunk 10, one model call
   per step with temporal ensembling 0.01, cosine decay, a small transformer), a fixed step count capped
   at ``--train-s`` seconds;
3. ``simseam eval maniskill_tabletop_mp --tasks PickCube-v1 --policy lerobot:<checkpoint>`` on
   ``--eval-seeds`` (held out: they may not overlap the demonstration seeds). The preset runs the
   planner's control mode at the 100-step limit ManiSkill's own imitation-learning baselines evaluate
   PickCube with (docs/benchmarks.md);
4. the same eval with ``--policy scripted``: the planner itself on the same seeds.

``--checkpoint DIR`` skips phases 1-2: it evaluates a checkpoint trained elsewhere on ``--work``'s
``pickcube_data`` (the 2-core machine trains at ~1 step/s while it is shared:
``benchmarks/device/maniskill_train.sh`` trains the same recipe on a lent GPU), and reports that
checkpoint's ``training.json``.

Prints a table, writes JSON (``--json``; default ``benchmarks/results/maniskill_pickcube_act.json``,
with each seed's outcome for both) and keeps the dataset, checkpoint and run directories under
``--work``. The last printed line ends with ``success_rate=<float>``: the policy's. Exits 0 when every
phase finished (whatever the rate), 1 when one failed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
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

    demos: int = 200
    steps: int = 9000
    batch_size: int = 64
    lr: float = 3e-4
    lr_schedule: str = "cosine"
    chunk_size: int = 10
    n_action_steps: int = 1
    temporal_ensemble: float | None = 0.01
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


def _eval(policy: str, seeds: range, out: Path, device: str, log: Path) -> dict:
    seconds = _simseam("eval", PRESET, "--tasks", TASK, "--policy", policy,
                       *(["--device", device] if policy.startswith("lerobot:") else []),
                       "--seed", str(seeds.start), "--episodes", str(len(seeds)), "--out", str(out), "--overwrite",
                       log=log)
    summary = json.loads((out / "summary.json").read_text())
    episodes = sorted(summary["episodes"], key=lambda e: e["seed"])
    wins = [e["steps"] for e in episodes if e["success"]]
    return {"policy": policy, "seeds": f"{seeds.start}:{seeds.stop}", "episodes": summary["n_episodes"],
            "successes": summary["n_success"], "success_rate": summary["success_rate"],
            "wilson95": summary["success_rate_wilson95"], "max_steps": summary["spec"]["task"]["max_steps"],
            "control_mode": summary["spec"]["action"]["control_mode"],
            "mean_steps_to_success": round(sum(wins) / len(wins), 1) if wins else None,
            "seconds": round(seconds, 1), "run_dir": str(out),
            "per_seed": [{"seed": e["seed"], "success": e["success"], "steps": e["steps"]} for e in episodes]}


def prove(recipe: Recipe, seeds: range, work: Path, train_s: float, device: str,
          checkpoint: Path | None = None) -> dict:
    if seeds.start < recipe.demos:
        raise SystemExit(f"--eval-seeds {seeds.start}:{seeds.stop} overlaps the demonstration seeds "
                         f"0:{recipe.demos}; evaluate on held-out seeds (START >= {recipe.demos})")
    data, ckpt = work / "pickcube_data", checkpoint or work / "pickcube_act"
    log = work / "pickcube.log"
    if checkpoint is not None and not (data / "meta" / "info.json").exists():
        raise SystemExit(f"--checkpoint: {data} holds no dataset (the one the checkpoint was trained on)")
    if checkpoint is None:
        collect_s = _simseam("collect", "--scene", SCENE, "--policy", "scripted", "--episodes", str(recipe.demos),
                             "--seed", "0", "--no-cameras", "--out", str(data), "--overwrite", log=log)
    info = json.loads((data / "meta" / "info.json").read_text())
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
    else:
        collect_s = train_wall = None
    training = json.loads((ckpt / "training.json").read_text())
    policy = _eval(f"lerobot:{ckpt}", seeds, work / "eval_act", device, log)
    expert = _eval("scripted", seeds, work / "eval_expert", device, log)
    return {
        "task": TASK, "scene": SCENE, "preset": PRESET, "recipe": asdict(recipe),
        "demos": {"seeds": f"0:{recipe.demos}", "episodes_kept": info["total_episodes"],
                  "frames": info["total_frames"], "seconds": round(collect_s, 1) if collect_s else None,
                  "state_dim": info["features"]["observation.state"]["shape"][0],
                  "action_dim": info["features"]["action"]["shape"][0]},
        "training": {"steps": training["steps"], "seconds": round(training["seconds"], 1),
                     "wall_seconds": round(train_wall, 1) if train_wall else None,
                     "checkpoint": str(ckpt), "n_params": training["n_params"],
                     "final_loss": training["losses"][-1][1] if training["losses"] else None,
                     "device": training["device"], "losses": training["losses"]},
        "eval": policy, "expert": expert,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--eval-seeds", type=parse_seeds, default=parse_seeds("10000:10100"),
                    help="held-out evaluation seeds START:END (default 10000:10100)")
    ap.add_argument("--demos", type=int, default=None, help="demonstrations (default: the recipe's)")
    ap.add_argument("--train-steps", type=int, default=None, help="optimizer steps (default: the recipe's); "
                    "training ends at the first of the step count and --train-s")
    ap.add_argument("--train-s", type=float, default=900.0, help="training wall-clock cap, seconds (default 900)")
    ap.add_argument("--lr", type=float, default=None, help="learning rate (default: the recipe's)")
    ap.add_argument("--device", default="cpu", help="torch device for training and evaluation (default cpu)")
    ap.add_argument("--work", type=Path, default=None, help="keep the dataset, checkpoint and runs here "
                    "(default: a new temporary directory)")
    ap.add_argument("--checkpoint", type=Path, default=None, help="evaluate this checkpoint, trained on "
                    "--work's pickcube_data elsewhere (skips collection and training)")
    ap.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "maniskill_pickcube_act.json")
    args = ap.parse_args()
    overrides = {"demos": args.demos, "steps": args.train_steps, "lr": args.lr}
    recipe = Recipe(**{**asdict(Recipe()), **{k: v for k, v in overrides.items() if v is not None}})
    work = args.work or Path(tempfile.mkdtemp(prefix="maniskill_policy_"))
    work.mkdir(parents=True, exist_ok=True)
    report = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
              "train_budget_s": args.train_s, "work": str(work)}
    try:
        report.update(prove(recipe, args.eval_seeds, work, args.train_s, args.device, args.checkpoint))
    except RuntimeError as exc:
        print(f"maniskill_policy: {exc}", file=sys.stderr)
        return 1
    finally:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2) + "\n")
    d, t = report["demos"], report["training"]
    print(f"ManiSkill3 {TASK}, state ({d['state_dim']}-D), pd_joint_pos ({d['action_dim']}-D), "
          f"preset {PRESET} ({report['eval']['max_steps']} steps)")
    print(f"demos {d['episodes_kept']} (seeds {d['seeds']}, {d['frames']} frames, {d['seconds'] or 0:.0f} s); "
          f"training {t['steps']} steps x {recipe.batch_size} in {t['seconds']:.0f} s on {t['device']}, "
          f"{t['n_params']} parameters, final loss {t['final_loss']:.4f}")
    print(f"{'policy':28} {'eval seeds':>12} {'success':>9} {'Wilson 95 %':>15} {'steps':>6} {'eval s':>7}")
    for key in ("eval", "expert"):
        r = report[key]
        lo, hi = r["wilson95"]
        name = "ACT (lerobot)" if key == "eval" else "motion planner (scripted)"
        print(f"{name:28} {r['seeds']:>12} {r['successes']:4d}/{r['episodes']:<4d} [{lo:.3f}, {hi:.3f}] "
              f"{r['mean_steps_to_success'] or 0:6.1f} {r['seconds']:7.0f}")
    print(f"json: {args.json}")
    print(f"maniskill_policy: ACT on {TASK}, held-out seeds {args.eval_seeds.start}:{args.eval_seeds.stop} "
          f"success_rate={report['eval']['success_rate']:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
