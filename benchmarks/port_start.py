"""How long a benchmark port's batch takes to build, side by side in one run, the ways it can start:

- ``default``: as simseam does it: MuJoCo Warp imported on a thread while the batch asks its native worker and
  loads its model (``warp_physics.imported_meanwhile``), and the task's description kept on disk beside its model
  (``libero_gpu.model.described``, ``metaworld_gpu.model.described``: the worker asked only for its versions);
- ``no-overlap``: the import left to ``WarpPhysics``, after the rest;
- ``no-kept``: the benchmark's ``describe`` asked every time (its env built in the worker: LIBERO's sends 160 MB,
  Meta-World's ~40 MB);
- ``neither``: both, as the ports started before either.

    .venv/bin/python benchmarks/port_start.py [--port libero|metaworld] [--task libero_spatial/1]
        [--repeats 3] [--sim-device cpu] [--json PATH] [--overwrite]

Each trial is a fresh interpreter (an import happens once per process): it starts the port's native worker and
waits for it to be ready (not timed), then builds one world's batch (``LiberoBatch`` or ``MetaWorldBatch``) and
times it: the model, description and reset states come from the disk caches, which a first untimed trial fills.
Each round runs every way, in turn forward and backward, so a machine that slows down during the run moves all of
them. Prints one row per trial and each way's median; writes JSON (default
benchmarks/results/port_start_<port>_<device>.json) with the machine's CPU facts and the load around each trial. Wall-clock on whatever else the machine runs. Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE))
from cpu_facts import CpuWindow, topology  # noqa: E402

WAYS = ("default", "no-overlap", "no-kept", "neither")

# one trial, in its own interpreter: argv = port, task, device, way; prints the seconds as JSON
TRIAL = r"""
import json, sys, time
port, task, device, way = sys.argv[1:5]
if port == "libero":
    from simseam.backends.libero_gpu import env as module
    from simseam.backends.libero_gpu.worker import NativeWorker
    suite, _, index = task.partition("/")
    build = lambda w: module.LiberoBatch(suite, int(index), 1, w, device=device)
else:
    from simseam.backends.metaworld_gpu import env as module
    from simseam.backends.metaworld_gpu.worker import NativeWorker
    build = lambda w: module.MetaWorldBatch(task, 1, w, device=device)
if way in ("no-overlap", "neither"):
    module.imported_meanwhile = lambda call, engine="mujoco_warp": call()
if way in ("no-kept", "neither") and port == "libero":
    from simseam.backends.libero_gpu import model as M
    module.task_model = lambda w, suite, task: M.load_or_build(w.call("describe", suite=suite, task=task))
elif way in ("no-kept", "neither"):
    from simseam.backends.metaworld_gpu import model as M
    module.described = lambda w, task: w.call("describe", task=task)
    module.task_model = lambda w, info, settled: M.load_or_build(info, settled)
with NativeWorker() as worker:
    t0 = time.perf_counter()
    batch = build(worker)
    built = time.perf_counter() - t0
    batch.close()
print(json.dumps({"built_s": built}))
"""


def trial(port: str, task: str, device: str, way: str) -> dict:
    with CpuWindow() as window:
        out = subprocess.run([sys.executable, "-c", TRIAL, port, task, device, way], capture_output=True, text=True)
    if out.returncode:
        raise SystemExit(f"port_start: a {way} trial of {port} {task} failed (rc {out.returncode}):\n{out.stderr[-2000:]}")
    return {"way": way, **json.loads(out.stdout.strip().splitlines()[-1]), "cpu": window.facts()}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--port", choices=("libero", "metaworld"), default="libero")
    ap.add_argument("--task", default=None, help="libero: SUITE/INDEX (default libero_spatial/1); metaworld: "
                                                  "a task (default reach-v3)")
    ap.add_argument("--repeats", type=int, default=3)
    ap.add_argument("--sim-device", default="cpu")
    ap.add_argument("--json", type=Path, default=None)
    ap.add_argument("--overwrite", action="store_true")
    a = ap.parse_args()
    task = a.task or ("libero_spatial/1" if a.port == "libero" else "reach-v3")
    path = a.json or HERE / "results" / f"port_start_{a.port}_{a.sim_device.replace(':', '')}.json"
    if path.exists() and not a.overwrite:
        raise SystemExit(f"port_start: {path} exists; pass --overwrite or another --json")
    trial(a.port, task, a.sim_device, "default")  # fills the model, description and reset caches; not counted
    rows = []
    print(f"{'trial':>5} {'way':>11} {'built s':>8} {'busy %':>7}")
    for i in range(a.repeats):
        for way in (WAYS if i % 2 == 0 else WAYS[::-1]):
            row = trial(a.port, task, a.sim_device, way)
            rows.append({"trial": i, **row})
            print(f"{i:5d} {way:>11} {row['built_s']:8.2f} {100 * (row['cpu'].get('busy_share') or 0):7.1f}")
    medians = {w: statistics.median(r["built_s"] for r in rows if r["way"] == w) for w in WAYS}
    for w in WAYS:
        worst = max(r["built_s"] for r in rows if r["way"] == w)
        print(f"median {w:>10}: {medians[w]:.2f} s (worst {worst:.2f} s)")
    result = {"port": a.port, "task": task, "sim_device": a.sim_device, "repeats": a.repeats,
              "when": time.strftime("%Y-%m-%dT%H:%M:%SZ", time.gmtime()), "machine": topology(),
              "median_built_s": medians, "trials": rows}
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(result, indent=1))
    print(f"wrote {path}")


if __name__ == "__main__":
    main()
