"""LIBERO: simseam's scripted expert -> demonstrations through the seam -> one ACT policy per task, from state ->
evaluated on held-out init states, with the expert on the same init states as the reference.

    .venv/bin/python benchmarks/libero_proof.py [--suite libero_spatial] [--tasks 0,1,2,3,4]
        [--demo-states 0:30] [--eval-states 30:50] [--train-steps 3000] [--train-s 150] [--action-noise 0]
        [--state-std-floor F] [--state-noise S] [--train-seed N] [--demos-from DIR] [--no-expert] [--train-only] [--work DIR] [--json FILE]

For each task, through the ``simseam`` command a user types (the CPU ``libero`` backend in LIBERO's venv
behind the sidecar):

1. ``simseam collect --scene <task>.yaml --policy scripted --no-cameras --seed 0 --episodes 30``:
   simseam's LIBERO expert (``backends/libero_expert.py``: privileged poses, approach, grasp, carry, place)
   from LIBERO's init states 0-29 (episode seed ``s`` starts from init state ``s % 50``); collect keeps the
   successful episodes only. State alone: ``observation.state`` (the robot's 8-D: end-effector position,
   axis-angle, finger joints) and ``observation.environment_state`` (``environment_state: true``: every
   object of the task's BDDL problem, its position and quaternion from LIBERO's own object observables,
   7 numbers each, in ``objects_dict`` order); the scene is the preset's (``settle_steps: 10``, openpi's
   step limit) with ``environment_state: true``;
2. ``simseam train``: LeRobot ACT from scratch, the state proofs' recipe (benchmarks/metaworld_proof.py: no
   VAE, chunk 10, one model call per step with temporal ensembling 0.01, a small transformer, cosine lr),
   capped at ``--train-s`` wall seconds;
3. ``simseam run --scene <task>.yaml --policy lerobot:<ckpt> --seed 30 --episodes 20``: the policy on init
   states 30-49, never demonstrated (the same scene: the ``libero_spatial`` preset's config plus
   ``environment_state``, which the preset does not turn on), and ``simseam eval <suite> --tasks <task>
   --policy scripted --seed 30 --episodes 20``: the expert on the same init states (the preset itself).

``--state-std-floor F``, ``--state-noise S`` and ``--train-seed N`` train with ``simseam train``'s
``--state-std-floor``, ``--state-noise`` and ``--seed``; ``--no-expert`` leaves out the expert's evaluation;
``--demos-from DIR`` trains on the datasets an earlier run recorded in DIR (``DIR/<suite>_<task>_data``)
instead of collecting again (the expert is deterministic: the same init states give the same demonstrations);
``--train-only`` stops after phase 2 (the checkpoints are then evaluated elsewhere, e.g. paired on two engines
by ``libero_warp_expert.py``).

Nothing was tuned on init states 30-49: the recipe is Meta-World's, and the budgets (30 demonstrations,
``--train-s``) were set by the time this 2-core machine had, before any evaluation. Every ``simseam``
command runs with ``OMP_NUM_THREADS=1`` (unless set). Prints a table, writes JSON after every task (default
``benchmarks/results/libero_proof.json``), so a run cut off keeps its finished tasks. The last printed line
ends with ``success_rate=<float>``: the mean of the tasks' held-out success rates. Exits 0 when every phase
finished (whatever the rate), 1 when one failed.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
from dataclasses import asdict, dataclass
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(ROOT / "benchmarks"))
from metaworld_proof import _simseam  # noqa: E402  (one command runner for the proofs: output to the log, rc checked)
N_INIT = 50  # LIBERO's init states per task; episode seed s starts from init state s % 50
#: simseam train options the proof passes through -> this script's argument holding each
TRAIN_OPTIONS = {"state_std_floor": "state_std_floor", "state_noise": "state_noise", "seed": "train_seed"}
STEPS = {"libero_spatial": 220, "libero_object": 280}  # the eval presets' (openpi's) step limits


@dataclass(frozen=True)
class Recipe:
    """The training recipe, the same for every task: metaworld_proof.py's (docs/policies.md)."""

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


def scene_yaml(suite: str, task: int) -> str:
    return (f"# {suite}/{task} as the {suite} eval preset runs it, plus the objects' poses (environment_state) for "
            "a state policy (benchmarks/libero_proof.py)\n"
            f"benchmark: {{name: libero, suite: {suite}, task: {task}, environment_state: true, settle_steps: 10, "
            f"max_steps: {STEPS[suite]}}}\n")


def _result(out: Path, policy: str, states: range, seconds: float, key: str | None) -> dict:
    """One evaluation's row from its run directory (``key``: the task in an eval's ``per_task``)."""
    summary = json.loads((out / "summary.json").read_text())
    t = summary["per_task"][key] if key else summary
    eps = summary["episodes"]
    return {"policy": policy, "init_states": f"{states.start}:{states.stop}", "episodes": t["n_episodes"],
            "successes": t["n_success"], "success_rate": t["success_rate"], "wilson95": t["success_rate_wilson95"],
            "mean_steps": round(sum(e["steps"] for e in eps) / len(eps), 1),
            "failed_init_states": sorted(e["seed"] % N_INIT for e in eps if not e["success"]),
            "seconds": round(seconds, 1)}


def collect_and_train(recipe: Recipe, scene: Path, demo: range, data: Path, ckpt: Path, train_s: float,
                      log: Path, noise: float = 0.0, options: dict | None = None,
                      demos_from: Path | None = None) -> tuple[float, float]:
    """Phases 1 and 2 for one task: the expert's demonstrations into ``data`` (executed with Gaussian action
    noise ``noise`` when > 0, the expert's own action recorded; or ``demos_from``'s dataset of the task), ACT
    trained into ``ckpt`` (``options``: ``simseam train`` options by name, ``TRAIN_OPTIONS``);
    their wall seconds (0 for a reused dataset)."""
    if demos_from is not None:
        return 0.0, _train(recipe, demos_from / data.name, ckpt, train_s, log, options)
    collect_s = _simseam("collect", "--scene", str(scene), "--policy", "scripted", "--episodes", str(len(demo)),
                         "--seed", str(demo.start), "--no-cameras", "--out", str(data), "--overwrite",
                         *(["--action-noise", str(noise)] if noise > 0 else []), log=log)
    return collect_s, _train(recipe, data, ckpt, train_s, log, options)


def _train(recipe: Recipe, data: Path, ckpt: Path, train_s: float, log: Path, options: dict | None) -> float:
    """``simseam train`` with the recipe; its wall seconds."""
    return _simseam("train", "--dataset", str(data), "--out", str(ckpt), "--overwrite", "--cache",
                          "--workers", "0", "--device", "cpu", "--no-vae",
                          "--steps", str(recipe.steps), "--time-budget-s", str(train_s),
                          "--batch-size", str(recipe.batch_size), "--lr", str(recipe.lr),
                          "--lr-schedule", recipe.lr_schedule,
                          "--chunk-size", str(recipe.chunk_size), "--n-action-steps", str(recipe.n_action_steps),
                          *(["--temporal-ensemble", str(recipe.temporal_ensemble)] if recipe.temporal_ensemble else []),
                          "--dim-model", str(recipe.dim_model), "--ff-dim", str(recipe.ff_dim),
                          "--encoder-layers", str(recipe.encoder_layers),
                          *_option_flags(options), log=log)


def _option_flags(options: dict | None) -> list[str]:
    """``simseam train`` flags of the options that are set (``state_noise`` -> ``--state-noise``)."""
    return [x for k, v in (options or {}).items() if v is not None for x in (f"--{k.replace('_', '-')}", str(v))]


def evaluate(suite: str, task: int, scene: Path, ckpt: Path, states: range, work: Path, log: Path,
             expert: bool = True) -> tuple[dict, dict | None]:
    """Phase 3: the policy (``simseam run`` on the scene) and the expert (``simseam eval`` of the preset; None
    when not ``expert``) on init states ``states``."""
    name, n = f"{suite}/{task}", str(len(states))
    out = work / f"{suite}_{task}_eval"
    seconds = _simseam("run", "--scene", str(scene), "--policy", f"lerobot:{ckpt}", "--device", "cpu",
                       "--seed", str(states.start), "--episodes", n, "--out", str(out), "--overwrite", log=log)
    policy = _result(out, f"lerobot:{ckpt}", states, seconds, None)
    if not expert:
        return policy, None
    out = work / f"{suite}_{task}_expert"
    seconds = _simseam("eval", suite, "--tasks", name, "--policy", "scripted", "--seed", str(states.start),
                       "--episodes", n, "--out", str(out), "--overwrite", log=log)
    return policy, _result(out, "scripted", states, seconds, name)


def prove(suite: str, task: int, recipe: Recipe, demo: range, held_out: range, work: Path, train_s: float,
          noise: float = 0.0, options: dict | None = None, demos_from: Path | None = None,
          evaluate_too: bool = True, expert: bool = True) -> dict:
    """Collect, train and evaluate one task (and the expert on the same init states); its row of the report
    (without ``eval`` / ``expert`` when not ``evaluate_too``)."""
    scene = work / f"{suite}_{task}.yaml"
    scene.write_text(scene_yaml(suite, task))
    data, ckpt = work / f"{suite}_{task}_data", work / f"{suite}_{task}_act"
    log = work / f"{suite}_{task}.log"
    collect_s, train_wall = collect_and_train(recipe, scene, demo, data, ckpt, train_s, log, noise, options, demos_from)
    info = json.loads(((demos_from or work) / data.name / "meta" / "info.json").read_text())
    training = json.loads((ckpt / "training.json").read_text())
    row = {
        "task": f"{suite}/{task}", "scene": scene_yaml(suite, task).splitlines()[-1],
        "environment_state_dim": info["features"]["observation.environment_state"]["shape"][0],
        "demos": {"init_states": f"{demo.start}:{demo.stop}", "episodes_run": len(demo),
                  "episodes_kept": info["total_episodes"], "frames": info["total_frames"],
                  "action_noise": noise, "seconds": round(collect_s, 1),
                  "from": str(demos_from / data.name) if demos_from else None},
        "training": {"steps": training["steps"], "seconds": round(training["seconds"], 1),
                     "wall_seconds": round(train_wall, 1), "n_params": training["n_params"],
                     "final_loss": training["losses"][-1][1] if training["losses"] else None,
                     "device": training["device"], **{k: training["config"].get(k) for k in TRAIN_OPTIONS}},
    }
    if evaluate_too:
        row["eval"], row["expert"] = evaluate(suite, task, scene, ckpt, held_out, work, log, expert)
    return row


def init_range(text: str, flag: str) -> range:
    a, _, b = text.partition(":")
    if not (a.isdigit() and b.isdigit() and int(a) < int(b) <= N_INIT):
        raise SystemExit(f"{flag}: expected A:B with 0 <= A < B <= {N_INIT}, got {text!r}")
    return range(int(a), int(b))


def summarize(report: dict) -> None:
    rows = report["tasks"]
    if rows and all("eval" in r for r in rows):
        report["mean_success_rate"] = sum(r["eval"]["success_rate"] for r in rows) / len(rows)
    if rows and all(r.get("expert") for r in rows):
        report["expert_mean_success_rate"] = sum(r["expert"]["success_rate"] for r in rows) / len(rows)


def print_table(report: dict) -> None:
    print(f"{'task':18} {'demos':>5} {'frames':>6} {'train s':>7} {'steps':>6} {'loss':>7} "
          f"{'ACT':>7} {'Wilson 95 %':>14} {'expert':>7} {'Wilson 95 %':>14}")
    for r in report["tasks"]:
        if "eval" not in r:
            print(f"{r['task']:18} {r['demos']['episodes_kept']:5d} {r['demos']['frames']:6d} "
                  f"{r['training']['seconds']:7.0f} {r['training']['steps']:6d} {r['training']['final_loss']:7.4f} "
                  "(trained only)")
            continue
        e, x = r["eval"], r["expert"]
        print(f"{r['task']:18} {r['demos']['episodes_kept']:5d} {r['demos']['frames']:6d} "
              f"{r['training']['seconds']:7.0f} {r['training']['steps']:6d} {r['training']['final_loss']:7.4f} "
              f"{e['successes']:3d}/{e['episodes']:<3d} [{e['wilson95'][0]:.3f}, {e['wilson95'][1]:.3f}] "
              + (f"{x['successes']:3d}/{x['episodes']:<3d} [{x['wilson95'][0]:.3f}, {x['wilson95'][1]:.3f}]"
                 if x else "(expert not run)"))


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--suite", default="libero_spatial", choices=sorted(STEPS))
    ap.add_argument("--tasks", default="0,1,2,3,4", help="comma-separated task indices (default 0,1,2,3,4)")
    ap.add_argument("--demo-states", default="0:30", help="init states A:B demonstrated (default 0:30)")
    ap.add_argument("--eval-states", default="30:50", help="held-out init states A:B evaluated (default 30:50)")
    ap.add_argument("--train-s", type=float, default=150.0, help="training wall-clock cap per task, seconds")
    ap.add_argument("--train-steps", type=int, default=None, help="optimizer steps per task (default: the recipe's)")
    ap.add_argument("--action-noise", type=float, default=0.0, help="collect --action-noise: Gaussian noise (action "
                    "units) on the executed demonstration actions, the expert's own recorded (default 0: off)")
    ap.add_argument("--state-std-floor", type=float, default=None, help="simseam train --state-std-floor (default: "
                    "off, the data's own statistics)")
    ap.add_argument("--state-noise", type=float, default=None, help="simseam train --state-noise (default: off)")
    ap.add_argument("--train-seed", type=int, default=None, help="simseam train --seed (default: its own, 0)")
    ap.add_argument("--no-expert", action="store_true", help="leave out the expert's evaluation")
    ap.add_argument("--demos-from", type=Path, default=None, help="train on the datasets an earlier run recorded in "
                    "this work directory instead of collecting")
    ap.add_argument("--train-only", action="store_true", help="stop after training (no evaluation)")
    ap.add_argument("--work", type=Path, default=None, help="keep scenes, datasets, checkpoints and runs here "
                    "(default: a new temporary directory)")
    ap.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "libero_proof.json")
    args = ap.parse_args()
    tasks = [int(t) for t in args.tasks.split(",") if t.strip()]
    demo, held_out = init_range(args.demo_states, "--demo-states"), init_range(args.eval_states, "--eval-states")
    if set(demo) & set(held_out):
        raise SystemExit(f"--eval-states {args.eval_states} overlaps the demonstrated init states {args.demo_states}")
    recipe = Recipe(**({"steps": args.train_steps} if args.train_steps is not None else {}))
    work = args.work or Path(tempfile.mkdtemp(prefix="libero_proof_"))
    work.mkdir(parents=True, exist_ok=True)
    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ.setdefault("OMP_NUM_THREADS", "1")  # one torch thread per process (metaworld_proof.py says why)
    report = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(), "python": platform.python_version()},
              "suite": args.suite, "recipe": asdict(recipe), "train_budget_s": args.train_s,
              "action_noise": args.action_noise, **{k: getattr(args, a) for k, a in TRAIN_OPTIONS.items()},
              "demo_init_states": args.demo_states, "held_out_init_states": args.eval_states, "work": str(work),
              "tasks": []}

    def save() -> None:
        summarize(report)
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps(report, indent=2) + "\n")

    try:
        for task in tasks:
            report["tasks"].append(prove(args.suite, task, recipe, demo, held_out, work, args.train_s,
                                         args.action_noise, {k: getattr(args, a) for k, a in TRAIN_OPTIONS.items()},
                                         args.demos_from, not args.train_only, not args.no_expert))
            save()
            print(f"libero_proof: {report['tasks'][-1]['task']} done", flush=True)
    except RuntimeError as exc:
        print(f"libero_proof: {exc}", file=sys.stderr)
        return 1
    finally:
        save()
    print_table(report)
    if "mean_success_rate" not in report:
        print(f"json: {args.json}")
        return 0
    expert = report.get("expert_mean_success_rate")
    print(f"mean over {len(report['tasks'])} task(s): ACT {report['mean_success_rate']:.3f}, "
          f"expert {'not run' if expert is None else f'{expert:.3f}'}")
    print(f"json: {args.json}")
    print(f"libero_proof: mean task success rate on held-out init states {args.eval_states} "
          f"success_rate={report['mean_success_rate']:.4f}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
