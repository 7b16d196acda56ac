"""LIBERO's BDDL goal predicates on MuJoCo Warp (``backends/libero_gpu/predicates.py``), checked against LIBERO's
own evaluation on every task of the four suites (libero_spatial, libero_object, libero_goal, libero_10).

For each task, states of three sources, made in LIBERO's env (reset with seed 0):

- ``crafted``: from init state 0 after LIBERO's 10 settle steps, the goal posed (each moved object over its
  target, each articulated joint in LIBERO's own range for its predicate) and dropped under LIBERO's physics for
  20 control steps, then each moved object swept along x, y and z (31 offsets in [-0.15, 0.15] m) through where
  it landed (``On``) or was posed (``In``: the region's centre), and each articulated joint swept across its
  range and LIBERO's range ends (``native.craft``);
- ``init``: init states 0 .. ``--inits`` - 1 after the settle steps;
- ``episode``: every state along episodes from init states 0 and 1: LIBERO's scripted expert
  (``backends.libero``'s) on libero_spatial and libero_object, random actions (init 0) and zero actions
  (init 1) elsewhere, ``--steps`` control steps at most (5 past LIBERO's first success).

LIBERO evaluates each state in its own env, its fixtures placed as in the port's model (where a reset puts them
depends on the env's earlier resets, not on the seed alone): set, ``sim.forward()``, ``_check_success()`` and
``_eval_predicate`` of each goal predicate (``native.check``). The batched predicates evaluate the same states on the arrays LIBERO's
data held (``native``), and on the same qpos / qvel forwarded by this interpreter's CPU MuJoCo (``mujoco``) and by
MuJoCo Warp (``mujoco_warp``, ``--device``, default Warp's CPU device, 128 worlds a batch). A disagreement is a
state where the success flag or a predicate's value differs from LIBERO's.

Also recorded, for episodes: how often LIBERO's own ``done`` from ``env.step`` (read right after the step: poses
and contacts of the last substep's start) differs from its evaluation of the same state forwarded.

Prints a table, writes ``benchmarks/results/libero_predicates_check.json`` (one entry per task under ``tasks``;
refuses to replace an existing file without ``--overwrite``). Usage::

    python benchmarks/libero_predicates_check.py [--suites libero_goal,libero_10] [--tasks 0,1] [--inits 5]
        [--steps 300] [--device cpu] [--out FILE] [--overwrite]
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
import traceback
from pathlib import Path

import numpy as np

from simseam.backends.libero_gpu import model as M
from simseam.backends.libero_gpu.goal_replay import ENGINES, compare, libero_check
from simseam.backends.libero_gpu.predicates import GoalCheck
from simseam.backends.libero_gpu.worker import NativeWorker

RESULTS = Path(__file__).resolve().parent / "results"
SUITES = ("libero_spatial", "libero_object", "libero_goal", "libero_10")
EXPERT_SUITES = ("libero_spatial", "libero_object")
SHOWN = 5  # disagreeing states named per engine


def states(worker: NativeWorker, suite: str, task: int, args: argparse.Namespace) -> tuple[list, np.ndarray, np.ndarray, dict]:
    """(labels, qpos, qvel, lag) of the task's crafted, init and episode states; ``lag``: per episode, the states
    and LIBERO's ``done`` as ``env.step`` returned it."""
    crafted = worker.call("craft", suite=suite, task=task)
    labels, qs, vs = [f"crafted {x}" for x in crafted["labels"]], [crafted["qpos"]], [crafted["qvel"]]
    for init in range(args.inits):
        e = worker.call("episode", suite=suite, task=task, init=init, policy="zero", steps=0)
        labels.append(f"init {init}"), qs.append(e["qpos"]), vs.append(e["qvel"])
    policies = [("expert", 0), ("expert", 1)] if suite in EXPERT_SUITES else [("random", 0), ("zero", 1)]
    lag = {}
    for policy, init in policies:
        e = worker.call("episode", suite=suite, task=task, init=init, policy=policy, steps=args.steps)
        lag[f"{policy} {init}"] = (len(labels), e["done"])
        labels += [f"episode {policy} {init} step {k}" for k in range(len(e["qpos"]))]
        qs.append(e["qpos"]), vs.append(e["qvel"])
    return labels, np.concatenate(qs), np.concatenate(vs), lag


def check_task(worker: NativeWorker, suite: str, task: int, args: argparse.Namespace) -> dict:
    t0 = time.perf_counter()
    info = worker.call("describe", suite=suite, task=task)
    mjm = M.load_or_build(info).model
    goal = info["goal"]
    check = GoalCheck.compile(M.label(info), goal["goal_state"], mjm, goal["objects"])
    labels, qpos, qvel, lag = states(worker, suite, task, args)
    native = libero_check(worker, suite, task, mjm, qpos, qvel)
    source = np.array([x.split()[0] for x in labels])
    entry = {"suite": suite, "task": task, "language": info["language"], "goal": list(check.names),
             "states": {s: int((source == s).sum()) for s in ("crafted", "init", "episode")},
             "success": {s: int(native["success"][source == s].sum()) for s in ("crafted", "init", "episode")},
             "true": dict(zip(check.names, native["values"].sum(axis=0).tolist())),
             "false": dict(zip(check.names, (~native["values"]).sum(axis=0).tolist())),
             "episode_lag": {k: {"steps": len(done), "libero_done": int(done.sum()),
                                 "forwarded_success": int(native["success"][at:at + len(done)].sum()),
                                 "differ": int((done != native["success"][at:at + len(done)]).sum())}
                             for k, (at, done) in lag.items()}}
    t1 = time.perf_counter()
    gaps = compare(check, mjm, native, qpos, qvel, ENGINES, args.device)
    entry["engines"] = {e: {"success": len(g["success"]), "values": len(g["values"]),
                            "states": [labels[i] for i in sorted({*g["success"], *(s for s, _ in g["values"])})][:SHOWN]}
                        for e, g in gaps.items()}
    entry["seconds"] = {"states_and_libero": round(t1 - t0, 1), "engines": round(time.perf_counter() - t1, 1)}
    return entry


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--suites", default=",".join(SUITES))
    p.add_argument("--tasks", default="all", help="task indices (comma-separated) or all")
    p.add_argument("--inits", type=int, default=5)
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--device", default="cpu")
    p.add_argument("--out", type=Path, default=RESULTS / "libero_predicates_check.json")
    p.add_argument("--overwrite", action="store_true")
    args = p.parse_args(argv)
    if args.out.exists() and not args.overwrite:
        print(f"libero_predicates_check: {args.out} exists; pass --overwrite to replace it", file=sys.stderr)
        return 2
    config = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    if args.out.resolve().is_relative_to(RESULTS.parent.parent):
        config["out"] = str(args.out.resolve().relative_to(RESULTS.parent.parent))
    result = {"config": config, "tasks": []}
    print(f"{'task':<17} {'goal':<44} {'states c/i/e':>13} {'LIBERO true c/i/e':>17} "
          f"{'disagree native/mujoco/warp':>27} {'s':>6}")
    from simseam.backends.provision import catalog

    suites = catalog("libero")["suites"]
    with NativeWorker() as worker:
        for suite in args.suites.split(","):
            tasks = range(len(suites[suite])) if args.tasks == "all" else [int(t) for t in args.tasks.split(",")]
            for task in tasks:
                try:
                    entry = check_task(worker, suite, task, args)
                except Exception as exc:  # noqa: BLE001 - recorded per task
                    entry = {"suite": suite, "task": task, "error": f"{type(exc).__name__}: {exc}",
                             "trace": traceback.format_exc(limit=4)}
                result["tasks"].append(entry)
                _write(args.out, result)
                print(_row(entry), flush=True)
    failed = [f"{e['suite']}/{e['task']}" for e in result["tasks"]
              if "error" in e or any(g["success"] or g["values"] for g in e["engines"].values())]
    print(f"{len(result['tasks'])} tasks, {len(failed)} with an error or a disagreement {failed}; wrote {args.out}")
    return 1 if failed else 0


def _row(e: dict) -> str:
    name = f"{e['suite']}/{e['task']}"
    if "error" in e:
        return f"{name:<17} ERROR {e['error']}"
    c = lambda d: "/".join(str(d[s]) for s in ("crafted", "init", "episode"))  # noqa: E731
    gaps = "/".join(str(g["success"] + g["values"]) for g in e["engines"].values())
    goal = " ".join(e["goal"])
    goal = goal if len(goal) <= 44 else goal[:41] + "..."
    return (f"{name:<17} {goal:<44} {c(e['states']):>13} {c(e['success']):>17} {gaps:>27} "
            f"{sum(e['seconds'].values()):>6.0f}")


def _write(path: Path, result: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".tmp")
    tmp.write_text(json.dumps(result, indent=1) + "\n")
    os.replace(tmp, path)


if __name__ == "__main__":
    sys.exit(main())
