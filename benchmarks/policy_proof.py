"""A learned policy that succeeds through the seam: demonstrations -> training -> held-out evaluation.

    .venv/bin/python benchmarks/policy_proof.py --eval-seeds 10000:10100 [--tasks lift,reach] [--train-s S]
        [--train-steps N] [--lr LR] [--demos N] [--work DIR] [--json FILE [--overwrite]]

For each task (``lift``: franka_panda lifts a cube, ``reach``: so101 brings its tool to a target pose),
three phases, each through the ``simseam`` command a user types:

1. ``simseam collect --policy scripted --no-cameras``: the scripted expert's demonstrations on seeds
   ``0 .. demos-1``, state alone (proprioception + the task's object poses: the scene file says
   ``environment_state: true``);
2. ``simseam train``: LeRobot ACT from scratch on that dataset, trained to the recipe's step count
   however long that takes on this machine (the time is reported): a recipe's result must not depend
   on the machine's load. ``--train-s S`` is an optional budget: when it runs out before the recipe's
   steps, the task fails (exit 1, the steps done named) and its half-trained policy is not evaluated;
3. ``simseam run --policy lerobot:<checkpoint>`` on ``--eval-seeds`` (held out: they may not overlap
   the demonstration seeds), with the success rate and its Wilson 95 % interval from ``summary.json``.

Prints a table, writes JSON and keeps the datasets, checkpoints and run directories under ``--work``
(default: a new temporary directory). The JSON goes to the run's own place, ``WORK/policy_proof.json``,
unless ``--json FILE`` names another; an existing ``FILE`` (the committed
``benchmarks/results/policy_proof.json``, say) is replaced only with ``--overwrite``. The last printed
line ends with ``success_rate=<float>``: the lowest of the tasks' rates. Exits 0 when every phase
finished (whatever the rate), 1 when one failed or the budget ran out.
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
SIMSEAM = [sys.executable, "-m", "simseam.cli.main"]  # the simseam this interpreter imports (a clone: its own)


@dataclass(frozen=True)
class Recipe:
    """One task's demonstrations and training recipe (the budgets docs/policies.md reports)."""

    scene: str
    demos: int
    steps: int
    batch_size: int = 64
    lr: float = 3e-4
    lr_schedule: str = "cosine"
    chunk_size: int = 10
    n_action_steps: int = 1
    temporal_ensemble: float | None = None
    dim_model: int = 128
    ff_dim: int = 512
    encoder_layers: int = 2


RECIPES = {
    "lift": Recipe(scene="scenes/franka_lift_state.yaml", demos=200, steps=9000, temporal_ensemble=0.01),
    "reach": Recipe(scene="scenes/so101_reach_state.yaml", demos=200, steps=4000),
}


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
        rc = subprocess.run([*SIMSEAM, *args], stdout=f, stderr=subprocess.STDOUT, cwd=ROOT).returncode
    if rc != 0:
        raise RuntimeError(f"simseam {args[0]} exited {rc}; its output is in {log}")
    return time.perf_counter() - t0


class BudgetHit(RuntimeError):
    """Training stopped by ``--train-s`` before the recipe's steps: the task is not evaluated."""


def prove(task: str, recipe: Recipe, seeds: range, work: Path, train_s: float | None, device: str,
          report: dict) -> dict:
    """Collect, train to the recipe's steps and evaluate one task; returns its row of the report (appended to
    ``report["tasks"]`` as soon as it is known, so a budget that runs out is recorded with the steps done)."""
    if seeds.start < recipe.demos:
        raise SystemExit(f"--eval-seeds {seeds.start}:{seeds.stop} overlaps the demonstration seeds "
                         f"0:{recipe.demos}; evaluate on held-out seeds (START >= {recipe.demos})")
    data, ckpt, run = work / f"{task}_data", work / f"{task}_act", work / f"{task}_eval"
    log = work / f"{task}.log"
    collect_s = _simseam("collect", "--scene", recipe.scene, "--policy", "scripted", "--episodes", str(recipe.demos),
                         "--seed", "0", "--no-cameras", "--out", str(data), "--overwrite", log=log)
    info = json.loads((data / "meta" / "info.json").read_text())
    train_wall = _simseam("train", "--dataset", str(data), "--out", str(ckpt), "--overwrite", "--cache",
                          "--workers", "0", "--device", device, "--no-vae",
                          "--steps", str(recipe.steps), *(["--time-budget-s", str(train_s)] if train_s else []),
                          "--batch-size", str(recipe.batch_size), "--lr", str(recipe.lr),
                          "--lr-schedule", recipe.lr_schedule,
                          "--chunk-size", str(recipe.chunk_size), "--n-action-steps", str(recipe.n_action_steps),
                          *(["--temporal-ensemble", str(recipe.temporal_ensemble)] if recipe.temporal_ensemble else []),
                          "--dim-model", str(recipe.dim_model), "--ff-dim", str(recipe.ff_dim),
                          "--encoder-layers", str(recipe.encoder_layers), log=log)
    training = json.loads((ckpt / "training.json").read_text())
    row = {"task": task, "scene": recipe.scene, "recipe": asdict(recipe),
           "demos": {"seeds": f"0:{recipe.demos}", "episodes_kept": info["total_episodes"],
                     "frames": info["total_frames"], "seconds": round(collect_s, 1)},
           "training": {"steps": training["steps"], "recipe_steps": recipe.steps,
                        "seconds": round(training["seconds"], 3), "wall_seconds": round(train_wall, 1),
                        "n_params": training["n_params"],
                        "final_loss": training["losses"][-1][1] if training["losses"] else None,
                        "device": training["device"]}}
    report["tasks"].append(row)
    if training["steps"] < recipe.steps:
        row["failed"] = (f"{task}: --train-s {train_s:g} ran out after {training['steps']} of the recipe's "
                         f"{recipe.steps} steps ({training['seconds']:.0f} s of training); a half-trained policy "
                         "is not the recipe's, so it was not evaluated: run again without --train-s (or with more)")
        raise BudgetHit(row["failed"])
    eval_s = _simseam("run", "--scene", recipe.scene, "--policy", f"lerobot:{ckpt}", "--device", device,
                      "--seed", str(seeds.start), "--episodes", str(len(seeds)), "--out", str(run), "--overwrite",
                      log=log)
    summary = json.loads((run / "summary.json").read_text())
    row["eval"] = {"seeds": f"{seeds.start}:{seeds.stop}", "episodes": summary["n_episodes"],
                   "successes": summary["n_success"], "success_rate": summary["success_rate"],
                   "wilson95": summary["success_rate_wilson95"], "seconds": round(eval_s, 1)}
    return row


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--eval-seeds", type=parse_seeds, default=parse_seeds("10000:10100"),
                    help="held-out evaluation seeds START:END (default 10000:10100)")
    ap.add_argument("--tasks", default="lift,reach", help="comma-separated: " + ", ".join(RECIPES))
    ap.add_argument("--train-s", type=float, default=None,
                    help="optional training budget per task, seconds: when it runs out before the recipe's steps "
                         "the task fails (exit 1) and is not evaluated (default: none, train to the steps)")
    ap.add_argument("--train-steps", type=int, default=None,
                    help="optimizer steps per task (default: the recipe's)")
    ap.add_argument("--lr", type=float, default=None, help="learning rate (default: the recipe's)")
    ap.add_argument("--demos", type=int, default=None, help="demonstrations per task (default: the recipe's)")
    ap.add_argument("--device", default="cpu", help="torch device for training and evaluation (default cpu)")
    ap.add_argument("--work", type=Path, default=None, help="keep datasets, checkpoints and runs here "
                    "(default: a new temporary directory)")
    ap.add_argument("--json", type=Path, default=None, help="where the JSON goes (default: WORK/policy_proof.json, "
                    "the run's own place); an existing file is replaced only with --overwrite")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing --json file")
    args = ap.parse_args()
    if args.train_s is not None and args.train_s <= 0:
        ap.error(f"--train-s {args.train_s:g}: a budget is a positive number of seconds")
    if args.json is not None and args.json.exists() and not args.overwrite:
        ap.error(f"--json {args.json} already exists (results are never replaced silently); pass --overwrite to "
                 "replace it, or name another file")
    tasks = [t.strip() for t in args.tasks.split(",") if t.strip()]
    unknown = [t for t in tasks if t not in RECIPES]
    if unknown or not tasks:
        ap.error(f"--tasks: unknown task(s) {unknown}; known: {', '.join(RECIPES)}")
    work = args.work or Path(tempfile.mkdtemp(prefix="policy_proof_"))
    work.mkdir(parents=True, exist_ok=True)
    out_json = args.json or work / "policy_proof.json"
    os.environ.setdefault("MUJOCO_GL", "egl")
    report = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
              "train_budget_s": args.train_s, "work": str(work), "tasks": []}
    try:
        for task in tasks:
            recipe = RECIPES[task]
            overrides = {"demos": args.demos, "steps": args.train_steps, "lr": args.lr}
            recipe = Recipe(**{**asdict(recipe), **{k: v for k, v in overrides.items() if v is not None}})
            prove(task, recipe, args.eval_seeds, work, args.train_s, args.device, report)
    except RuntimeError as exc:
        print(f"policy_proof: {exc}", file=sys.stderr)
        return 1
    finally:
        out_json.parent.mkdir(parents=True, exist_ok=True)
        out_json.write_text(json.dumps(report, indent=2) + "\n")
        print(f"json: {out_json}")
    print(f"{'task':6} {'demos':>5} {'frames':>6} {'train s':>7} {'steps':>6} {'loss':>7} {'eval seeds':>12} "
          f"{'success':>8} {'Wilson 95 %':>14}")
    for r in report["tasks"]:
        lo, hi = r["eval"]["wilson95"]
        print(f"{r['task']:6} {r['demos']['episodes_kept']:5d} {r['demos']['frames']:6d} "
              f"{r['training']['seconds']:7.0f} {r['training']['steps']:6d} {r['training']['final_loss']:7.4f} "
              f"{r['eval']['seeds']:>12} {r['eval']['successes']:3d}/{r['eval']['episodes']:<4d} "
              f"[{lo:.3f}, {hi:.3f}]")
    print("(train s: the time training took to reach the recipe's steps on this machine)")
    rate = min(r["eval"]["success_rate"] for r in report["tasks"])
    print(f"policy_proof: lowest task success rate on seeds {args.eval_seeds.start}:{args.eval_seeds.stop} "
          f"success_rate={rate:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
