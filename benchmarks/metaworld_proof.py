"""Meta-World: the benchmark's own experts -> demonstrations through the seam -> one ACT policy per task ->
``simseam eval metaworld_mt10`` on held-out seeds.

    .venv/bin/python benchmarks/metaworld_proof.py [--tasks reach-v3,push-v3,...] [--demos 200]
        [--train-steps 3000] [--train-s 240] [--eval-seed 10000] [--episodes 50] [--work DIR] [--json FILE]

For each task, three phases, each through the ``simseam`` command a user types:

1. ``simseam collect --scene <task>.yaml --policy scripted --no-cameras``: Meta-World's scripted expert
   for the task (``metaworld.policies``, replayed through the seam as the privileged ``expert_action``),
   on seeds ``0 .. demos-1`` with ``variation: sampled``: every seed draws its own object and goal
   positions from the task's reset distribution, so no demonstration starts from one of the 50 fixed
   MT1 variations that the evaluation runs. State alone: the 39-D Meta-World observation (hand, gripper,
   object poses, the previous frame of those, the goal), exactly what the eval preset hands a policy;
2. ``simseam train``: LeRobot ACT from scratch (the state proof's recipe: no VAE, chunk 10, one model
   call per step with temporal ensembling 0.01, a small transformer, cosine lr), capped at ``--train-s``;
3. ``simseam eval metaworld_mt10 --tasks <task> --seed <eval-seed> --episodes N`` for the policy and for
   the scripted expert (the reference), on the preset's standard episodes: MT1's fixed variations
   ``seed % 50``, 500 steps, success = ``info['success']``.

Held out twice over: the evaluation seeds (10000+) are not demonstration seeds, and the initial states
they give (MT1's variations) are not among the demonstrations' (sampled ones). With the preset's own
``variation: mt1`` the demonstrations would have started from exactly the evaluation's states (seed s
and s + 50 are the same episode), so it is not used for them.

The scene files are written under ``--work``. Every ``simseam`` command runs with ``OMP_NUM_THREADS=1``
(unless set): on a shared 2-core machine, torch's two threads per process made training 10x slower. Prints a table, writes JSON after every task (``--json``;
default ``benchmarks/results/metaworld_proof.json``). The last printed line ends with
``success_rate=<float>``: the mean of the tasks' held-out success rates. Exits 0 when every phase
finished (whatever the rate), 1 when one failed.
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
#: the first five tasks of the metaworld_mt10 preset, in its order (chosen before any training, not by result)
DEFAULT_TASKS = ("reach-v3", "push-v3", "pick-place-v3", "door-open-v3", "drawer-open-v3")


@dataclass(frozen=True)
class Recipe:
    """The demonstrations and training recipe, the same for every task (the budgets docs/policies.md reports)."""

    demos: int = 200
    steps: int = 3000
    batch_size: int = 64
    lr: float = 3e-4
    lr_schedule: str = "cosine"
    chunk_size: int = 10
    n_action_steps: int = 1
    temporal_ensemble: float | None = 0.01
    dim_model: int = 128
    ff_dim: int = 512
    encoder_layers: int = 2


def scene_yaml(task: str) -> str:
    return ("# Meta-World's expert for one task, state alone, each seed its own sampled variation "
            "(benchmarks/metaworld_proof.py)\n"
            f"benchmark: {{name: metaworld, task: {task}, expert: true, variation: sampled, max_steps: 500}}\n")


def _simseam(*args: str, log: Path) -> float:
    """Run one ``simseam`` command (output appended to ``log``); returns its wall time in seconds."""
    t0 = time.perf_counter()
    with log.open("a") as f:
        f.write(f"$ simseam {' '.join(args)}\n")
        f.flush()
        rc = subprocess.run([SIMSEAM, *args], stdout=f, stderr=subprocess.STDOUT, cwd=ROOT).returncode
    if rc != 0:
        raise RuntimeError(f"simseam {args[0]} exited {rc}; its output is in {log}")
    return time.perf_counter() - t0


def _eval(policy: str, task: str, seed: int, episodes: int, out: Path, device: str, log: Path) -> dict:
    seconds = _simseam("eval", "metaworld_mt10", "--tasks", task, "--policy", policy, "--seed", str(seed),
                       "--episodes", str(episodes), "--out", str(out), "--overwrite",
                       *(["--device", device] if policy.startswith("lerobot:") else []), log=log)
    summary = json.loads((out / "summary.json").read_text())
    t = summary["per_task"][task]
    eps = summary["episodes"]
    return {"policy": policy, "seeds": f"{seed}:{seed + episodes}", "episodes": t["n_episodes"],
            "successes": t["n_success"], "success_rate": t["success_rate"], "wilson95": t["success_rate_wilson95"],
            "mean_steps": round(sum(e["steps"] for e in eps) / len(eps), 1),
            "failed_seeds": sorted(e["seed"] for e in eps if not e["success"]), "seconds": round(seconds, 1)}


def collect_and_train(task: str, recipe: Recipe, scene: Path, data: Path, ckpt: Path, train_s: float, device: str,
                      log: Path) -> tuple[float, float]:
    """Phases 1 and 2 for one task: the expert's demonstrations into ``data``, ACT trained into ``ckpt``;
    their wall seconds."""
    collect_s = _simseam("collect", "--scene", str(scene), "--policy", "scripted", "--episodes", str(recipe.demos),
                         "--seed", "0", "--no-cameras", "--out", str(data), "--overwrite", log=log)
    train_wall = _simseam("train", "--dataset", str(data), "--out", str(ckpt), "--overwrite", "--cache",
                          "--workers", "0", "--device", device, "--no-vae",
                          "--steps", str(recipe.steps), "--time-budget-s", str(train_s),
                          "--batch-size", str(recipe.batch_size), "--lr", str(recipe.lr),
                          "--lr-schedule", recipe.lr_schedule,
                          "--chunk-size", str(recipe.chunk_size), "--n-action-steps", str(recipe.n_action_steps),
                          *(["--temporal-ensemble", str(recipe.temporal_ensemble)] if recipe.temporal_ensemble else []),
                          "--dim-model", str(recipe.dim_model), "--ff-dim", str(recipe.ff_dim),
                          "--encoder-layers", str(recipe.encoder_layers), log=log)
    return collect_s, train_wall


def prove(task: str, recipe: Recipe, eval_seed: int, episodes: int, work: Path, train_s: float,
          device: str) -> dict:
    """Collect, train and evaluate one task (and the expert on the same seeds); returns its row of the report."""
    if eval_seed < recipe.demos:
        raise SystemExit(f"--eval-seed {eval_seed} overlaps the demonstration seeds 0:{recipe.demos}")
    scene = work / f"{task}.yaml"
    scene.write_text(scene_yaml(task))
    data, ckpt = work / f"{task}_data", work / f"{task}_act"
    log = work / f"{task}.log"
    collect_s, train_wall = collect_and_train(task, recipe, scene, data, ckpt, train_s, device, log)
    info = json.loads((data / "meta" / "info.json").read_text())
    training = json.loads((ckpt / "training.json").read_text())
    policy = _eval(f"lerobot:{ckpt}", task, eval_seed, episodes, work / f"{task}_eval", device, log)
    expert = _eval("scripted", task, eval_seed, episodes, work / f"{task}_expert", device, log)
    return {
        "task": task, "scene": scene_yaml(task).splitlines()[-1],
        "demos": {"seeds": f"0:{recipe.demos}", "variation": "sampled", "episodes_run": recipe.demos,
                  "episodes_kept": info["total_episodes"], "frames": info["total_frames"],
                  "seconds": round(collect_s, 1)},
        "training": {"steps": training["steps"], "seconds": round(training["seconds"], 1),
                     "wall_seconds": round(train_wall, 1), "n_params": training["n_params"],
                     "final_loss": training["losses"][-1][1] if training["losses"] else None,
                     "device": training["device"]},
        "eval": policy, "expert": expert,
    }


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--tasks", default=",".join(DEFAULT_TASKS), help="comma-separated metaworld_mt10 tasks "
                    f"(default: {','.join(DEFAULT_TASKS)})")
    ap.add_argument("--eval-seed", type=int, default=10000, help="first evaluation seed (default 10000)")
    ap.add_argument("--episodes", type=int, default=50, help="evaluation episodes per task (default 50: "
                    "the preset's, every MT1 variation once)")
    ap.add_argument("--train-s", type=float, default=240.0, help="training wall-clock cap per task, seconds")
    ap.add_argument("--train-steps", type=int, default=None, help="optimizer steps per task (default: the recipe's)")
    ap.add_argument("--demos", type=int, default=None, help="demonstrations per task (default: the recipe's)")
    ap.add_argument("--device", default="cpu", help="torch device for training and evaluation (default cpu)")
    ap.add_argument("--work", type=Path, default=None, help="keep scenes, datasets, checkpoints and runs here "
                    "(default: a new temporary directory)")
    ap.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "metaworld_proof.json")
    args = ap.parse_args()
    tasks = [t.strip() for t in args.tasks.split(",") if t.strip()]
    if not tasks:
        ap.error("--tasks: no task given")
    recipe = Recipe(**{k: v for k, v in {"demos": args.demos, "steps": args.train_steps}.items() if v is not None})
    work = args.work or Path(tempfile.mkdtemp(prefix="metaworld_proof_"))
    work.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("MUJOCO_GL", "egl")
    # one torch thread per process: on this shared 2-core machine two threads per process made training 10x and
    # a policy call ~90x slower (200 steps: 16 s against 167 s; 1.9 ms against 173 ms per call, load ~7)
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    report = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
              "recipe": asdict(recipe), "train_budget_s": args.train_s, "work": str(work), "tasks": []}

    def save() -> None:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2) + "\n")

    try:
        for task in tasks:
            report["tasks"].append(prove(task, recipe, args.eval_seed, args.episodes, work, args.train_s, args.device))
            save()
    except RuntimeError as exc:
        print(f"metaworld_proof: {exc}", file=sys.stderr)
        return 1
    finally:
        if report["tasks"]:
            report["mean_success_rate"] = sum(r["eval"]["success_rate"] for r in report["tasks"]) / len(report["tasks"])
            report["expert_mean_success_rate"] = (sum(r["expert"]["success_rate"] for r in report["tasks"])
                                                  / len(report["tasks"]))
        save()
    print(f"{'task':24} {'demos':>5} {'frames':>6} {'train s':>7} {'steps':>6} {'loss':>7} "
          f"{'ACT':>7} {'Wilson 95 %':>14} {'expert':>7} {'Wilson 95 %':>14}")
    for r in report["tasks"]:
        e, x = r["eval"], r["expert"]
        print(f"{r['task']:24} {r['demos']['episodes_kept']:5d} {r['demos']['frames']:6d} "
              f"{r['training']['seconds']:7.0f} {r['training']['steps']:6d} {r['training']['final_loss']:7.4f} "
              f"{e['successes']:3d}/{e['episodes']:<3d} [{e['wilson95'][0]:.3f}, {e['wilson95'][1]:.3f}] "
              f"{x['successes']:3d}/{x['episodes']:<3d} [{x['wilson95'][0]:.3f}, {x['wilson95'][1]:.3f}]")
    seeds = f"{args.eval_seed}:{args.eval_seed + args.episodes}"
    print(f"mean over {len(report['tasks'])} task(s): ACT {report['mean_success_rate']:.3f}, "
          f"expert {report['expert_mean_success_rate']:.3f}")
    print(f"json: {args.json}")
    print(f"metaworld_proof: mean task success rate on held-out seeds {seeds} "
          f"success_rate={report['mean_success_rate']:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
