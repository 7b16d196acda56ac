"""Model checks of every Meta-World v3 task (MT50) for MuJoCo Warp: each task's model compiled here from
Meta-World's own XML (in its provisioned venv's files) and checked against the native model
(``backends.metaworld_gpu.model.check_model``: sizes, masses, inertias, frames, mesh extents, options,
and the contact pairs of the native reset of seed 0), then loaded by ``mujoco_warp.put_model`` with the
per-world fields its resets move (seeds 0..``--seeds``-1).

Always compiles afresh (the cache is not read), so the report is this run's. Prints a table, writes
``benchmarks/results/metaworld_model_checks.json``. Usage::

    python benchmarks/metaworld_model_checks.py [--tasks a,b] [--seeds 3] [--out FILE]
"""

from __future__ import annotations

import argparse
import json
import time
import traceback
from pathlib import Path

import numpy as np

from simseam.backends.metaworld_gpu.model import check_model, compile_model
from simseam.backends.metaworld_gpu.tasks import OBJECTS
from simseam.backends.metaworld_gpu.worker import NativeWorker

RESULTS = Path(__file__).resolve().parent / "results"


def check_task(worker: NativeWorker, task: str, seeds: int) -> dict:
    """One task's checks: compile, compare, then put on Warp's CPU device with its batched fields."""
    t0 = time.perf_counter()
    info = worker.call("describe", task=task)
    states = worker.call("resets", task=task, variation="mt1", goal_seed=0, seeds=list(range(seeds)))
    model, notes = compile_model(info)
    entry = {"task": task, "metaworld": info["metaworld"], "native_mujoco": info["mujoco"], "widened": notes}
    try:
        report = check_model(model, info, states[0])
        entry.update(passed=True, worst=report["worst"], mesh_extent=report.get("mesh_extent"),
                     contacts=report.get("contacts"))
    except Exception as exc:  # noqa: BLE001 - recorded per task
        entry.update(passed=False, error=f"{type(exc).__name__}: {exc}")
    batched = sorted({k for s in states for k in s["model"]} - {"eq_data"})
    entry["reset_fields"] = batched
    try:
        from simseam.backends.warp_physics import WarpPhysics

        loaded = states[:2] if len(states) >= 2 else states * 2
        physics = WarpPhysics(model, 2, "cpu", tuple(batched))
        physics.load(np.arange(2), loaded)
        entry["warp_pose_gap"] = _pose_gap(physics, loaded)
        entry["warp_loads"] = bool(np.isfinite(physics.poses().qpos).all()) and entry["warp_pose_gap"] < 1e-5
    except Exception as exc:  # noqa: BLE001
        entry["warp_loads"] = False
        entry["warp_error"] = f"{type(exc).__name__}: {exc}"
    entry["seconds"] = round(time.perf_counter() - t0, 2)
    return entry


def _pose_gap(physics, states: list) -> float:
    """The largest gap between the geoms' world positions on Warp after loading ``states`` and CPU MuJoCo's
    (``CpuPhysics``, the same model, each state alone)."""
    from simseam.backends.warp_physics import CpuPhysics

    gap = 0.0
    for w, state in enumerate(states):
        cpu = CpuPhysics(physics.mjm)
        cpu.load(np.arange(1), [state])
        gap = max(gap, float(np.abs(np.asarray(physics.poses().geom_xpos)[w] - cpu.poses().geom_xpos[0]).max()))
        for key, value in cpu._pristine.items():  # CpuPhysics changed the shared model: put it back
            getattr(physics.mjm, key)[...] = value
    return gap


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", default=None, help="comma-separated subset (default: all 50)")
    ap.add_argument("--seeds", type=int, default=3, help="native resets per task (their moved fields are batched)")
    ap.add_argument("--out", type=Path, default=RESULTS / "metaworld_model_checks.json")
    args = ap.parse_args()
    tasks = args.tasks.split(",") if args.tasks else sorted(OBJECTS)
    rows = []
    with NativeWorker() as worker:
        for task in tasks:
            try:
                rows.append(check_task(worker, task, args.seeds))
            except Exception as exc:  # noqa: BLE001 - one task's failure is its row
                rows.append({"task": task, "passed": False, "warp_loads": False,
                             "error": f"{type(exc).__name__}: {exc}", "trace": traceback.format_exc()[-2000:]})
            r = rows[-1]
            print(f"{task:32s} checks {'pass' if r['passed'] else 'FAIL'}  warp {'ok' if r.get('warp_loads') else 'FAIL'}"
                  f"  {r.get('seconds', 0):6.1f} s  {r.get('error', r.get('warp_error', ''))[:200]}", flush=True)
    passed = sum(r["passed"] and r.get("warp_loads", False) for r in rows)
    print(f"{passed}/{len(rows)} tasks pass the model checks and load on MuJoCo Warp with every geom where CPU "
          f"MuJoCo puts it after a reset (worst gap {max(r.get('warp_pose_gap', 0.0) for r in rows):.1e} m)")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"tasks": {r["task"]: r for r in rows}, "passed": passed, "total": len(rows),
                                    "seeds": args.seeds}, indent=1, default=float))


if __name__ == "__main__":
    main()
