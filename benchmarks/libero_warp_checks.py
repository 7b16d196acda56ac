"""LIBERO on MuJoCo Warp, first parts, checked on every task of the four suites (libero_spatial, libero_object,
libero_goal, libero_10):

- the model: robosuite's compiled XML (from the LIBERO backend's venv) compiled here and checked against the
  native model (``backends.warp_model.check_model``: sizes, masses, inertias, frames, mesh extents, options, the
  contact pairs of init state 0 after LIBERO's settle steps), then put on MuJoCo Warp;
- the controller: robosuite's OSC_POSE and gripper ramp, recorded natively from ``--inits`` init states under
  the same seeded actions (``--settle`` dummy steps, then ``--steps`` varied actions), replayed batched (one world
  per init state) on CPU MuJoCo and on MuJoCo Warp (``--device``, default Warp's CPU device): the worst torque,
  finger ctrl and goal gaps against robosuite's own.

Always compiles afresh (the cache is not read), so the report is this run's. Prints a table, writes
``benchmarks/results/libero_warp_checks.json`` (one entry per task under ``tasks``; refuses to replace an existing
file without ``--overwrite``). Usage::

    python benchmarks/libero_warp_checks.py [--suites libero_spatial,libero_10] [--tasks 0,1] [--inits 2]
        [--settle 10] [--steps 10] [--device cpu] [--out FILE] [--overwrite]
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
from simseam.backends.libero_gpu.replay import controller_gaps
from simseam.backends.libero_gpu.worker import NativeWorker

RESULTS = Path(__file__).resolve().parent / "results"
SUITES = ("libero_spatial", "libero_object", "libero_goal", "libero_10")


def actions(steps: int, seed: int) -> np.ndarray:
    """Full-range arm deltas, every third without rotation, grips that open, close and hold (0)."""
    rng = np.random.default_rng(seed)
    a = rng.uniform(-1.0, 1.0, (steps, 7))
    a[::3, 3:6] = 0.0
    a[:, 6] = np.sign(a[:, 6])
    a[4::6, 6] = 0.0
    return a


def check_task(worker: NativeWorker, suite: str, task: int, args: argparse.Namespace) -> dict:
    t0 = time.perf_counter()
    info = worker.call("describe", suite=suite, task=task)
    entry = {"suite": suite, "task": task, "language": info["language"], "versions": info["versions"]}
    model = M.compile_model(info)
    entry["sizes"] = {k: int(getattr(model, k)) for k in ("nq", "nv", "nu", "nbody", "ngeom", "nmeshvert")}
    try:
        report = M.check_model(model, info)
        entry.update(model_passed=True, worst=report["worst"], mesh_extent=report["mesh_extent"],
                     contacts={k: report["contacts"][k] for k in ("ncon", "native_ncon", "touching_here_only")})
    except Exception as exc:  # noqa: BLE001 - recorded per task
        entry.update(model_passed=False, model_error=f"{type(exc).__name__}: {exc}")
        return entry
    model = M.compile_model(info)  # pristine: the checks set a state's model fields
    records = [worker.call("record", suite=suite, task=task, init=i, actions=actions(args.steps, task),
                           settle=args.settle) for i in range(args.inits)]
    for engine in ("mujoco", "mujoco_warp"):
        try:
            entry[engine] = controller_gaps(model, info["control"], records, engine, args.device)
        except Exception as exc:  # noqa: BLE001
            entry[engine] = {"error": f"{type(exc).__name__}: {exc}", "trace": traceback.format_exc(limit=3)}
    entry["seconds"] = round(time.perf_counter() - t0, 1)
    return entry


def main(argv: list[str] | None = None) -> int:
    p = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    p.add_argument("--suites", default=",".join(SUITES))
    p.add_argument("--tasks", default="all", help="task indices (comma-separated) or all")
    p.add_argument("--inits", type=int, default=2)
    p.add_argument("--settle", type=int, default=10)
    p.add_argument("--steps", type=int, default=10)
    p.add_argument("--device", default="cpu")
    p.add_argument("--out", type=Path, default=RESULTS / "libero_warp_checks.json")
    p.add_argument("--overwrite", action="store_true")
    args = p.parse_args(argv)
    if args.out.exists() and not args.overwrite:
        print(f"libero_warp_checks: {args.out} exists; pass --overwrite to replace it", file=sys.stderr)
        return 2
    config = {k: (str(v) if isinstance(v, Path) else v) for k, v in vars(args).items()}
    if args.out.resolve().is_relative_to(RESULTS.parent.parent):
        config["out"] = str(args.out.resolve().relative_to(RESULTS.parent.parent))
    result = {"config": config, "tasks": []}
    print(f"{'task':<18} {'nv':>3} {'ngeom':>5} {'model':>5} {'ncon':>9} {'cpu torque':>11} {'warp torque':>11} "
          f"{'warp rel':>9} {'s':>6}")
    from simseam.backends.provision import catalog

    suites = catalog("libero")["suites"]
    with NativeWorker() as worker:
        for suite in args.suites.split(","):
            count = len(suites[suite])
            for task in range(count) if args.tasks == "all" else [int(t) for t in args.tasks.split(",")]:
                entry = check_task(worker, suite, task, args)
                result["tasks"].append(entry)
                _write(args.out, result)
                print(_row(entry), flush=True)
    failed = [f"{e['suite']}/{e['task']}" for e in result["tasks"] if not e.get("model_passed")
              or "error" in e.get("mujoco", {}) or "error" in e.get("mujoco_warp", {})]
    print(f"{len(result['tasks'])} tasks, {len(failed)} failed {failed}; wrote {args.out}")
    return 1 if failed else 0


def _row(e: dict) -> str:
    cpu, warp = e.get("mujoco", {}), e.get("mujoco_warp", {})
    ncon = f"{e['contacts']['ncon']}/{e['contacts']['native_ncon']}" if "contacts" in e else "-"
    return (f"{e['suite'] + '/' + str(e['task']):<18} {e['sizes']['nv']:>3} {e['sizes']['ngeom']:>5} "
            f"{'ok' if e.get('model_passed') else 'FAIL':>5} {ncon:>9} {cpu.get('torque', float('nan')):>11.2e} "
            f"{warp.get('torque', float('nan')):>11.2e} {warp.get('torque_rel', float('nan')):>9.2e} "
            f"{e.get('seconds', 0):>6}")


def _write(path: Path, result: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp = path.with_suffix(".json.partial")
    tmp.write_text(json.dumps(result, indent=1, default=lambda o: o.tolist() if hasattr(o, "tolist") else str(o)))
    os.replace(tmp, path)


if __name__ == "__main__":
    sys.exit(main())
