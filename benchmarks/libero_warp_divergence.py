"""The state divergence curve of LIBERO's port against LIBERO itself, along the expert's episodes.

    .venv/bin/python benchmarks/libero_warp_divergence.py [--tasks libero_spatial/0,libero_object/0]
        [--init-states 10:13] [--sim-device cpu] [--steps 220] [--json PATH] [--overwrite]

For each task and init state LIBERO's scripted expert runs natively, in the LIBERO venv (the native worker's
``episode``: ``seed``, ``reset``, ``set_init_state``, the 10 settle steps, then the expert until 5 steps past
LIBERO's success), recording the actions it sent and the state after each step. Its actions are then replayed open
loop from the same reset by the port's code (``backends/libero_gpu``: the reset settled by LIBERO but for its
last settle step, robosuite's controller batched) on two engines:

- ``mujoco``: CPU MuJoCo, this venv's (``physics.CpuArm``), float64: what the port's code and the MuJoCo version
  (LIBERO's venv pins another) add;
- ``warp``: MuJoCo Warp on ``--sim-device`` (``env.LiberoBatch``, one world per init state), float32: what the
  engine adds.

Per control step, against LIBERO's state after the same step: the worst gap over the arm's 7 joints (rad) and
over the objects' positions (m, every free joint's). Open loop, a gap grows where contacts amplify it (a grasp, a
drop); closed loop (the success table of ``libero_warp_expert.py``) the expert corrects it. Prints per task the
median and worst gap over its init states at a few steps, writes every curve to JSON (default
benchmarks/results/libero_warp_divergence.json). Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
MARKS = (1, 10, 25, 50, 100, 150)


def native_episodes(worker, suite: str, task: int, inits: list[int], steps: int) -> list[dict]:
    return [worker.call("episode", suite=suite, task=task, init=i % 50, policy="expert", steps=steps, seed=i)
            for i in inits]


def padded(episodes: list[dict]) -> np.ndarray:
    """float[T, N, 7]: each episode's actions, the dummy action after it ends."""
    from simseam.backends.libero_gpu.env import DUMMY_ACTION

    length = max(len(e["actions"]) for e in episodes)
    out = np.tile(np.asarray(DUMMY_ACTION), (length, len(episodes), 1))
    for w, e in enumerate(episodes):
        out[:len(e["actions"]), w] = e["actions"]
    return out


def replay_warp(batch, inits: list[int], actions: np.ndarray) -> np.ndarray:
    """float[T + 1, N, nq]: the worlds' qpos after the reset and after each step."""
    batch.reset(list(range(len(inits))), inits)
    out = [_host(batch.physics.poses().qpos)]
    for a in actions:
        batch.step(a)
        out.append(_host(batch.physics.poses().qpos))
    return np.stack(out)


def _host(a) -> np.ndarray:
    return np.array(a.get() if hasattr(a, "get") else a, dtype=np.float64)


def replay_mujoco(batch, inits: list[int], actions: np.ndarray) -> np.ndarray:
    """The same on CPU MuJoCo, one world at a time: ``batch``'s model, reset states and controller."""
    from simseam.backends.libero_gpu.control import OscState
    from simseam.backends.libero_gpu.env import DUMMY_ACTION
    from simseam.backends.libero_gpu.physics import CpuArm
    from simseam.backends.libero_gpu.stepping import control_step

    out = np.zeros((len(actions) + 1, len(inits), batch.model.model.nq))
    for w, state in enumerate(batch._reset_states(inits)):
        arm, osc = CpuArm.from_reset(batch.model.model, batch.layout, state), OscState.from_native(np, [state["start"]])
        for _ in range(batch.settle_steps - batch.native_settle):
            osc = control_step(arm, batch.cfg, osc, np.asarray([DUMMY_ACTION]), batch.facts)
        out[0, w] = arm.data.qpos
        for k, a in enumerate(actions):
            osc = control_step(arm, batch.cfg, osc, np.clip(a[w:w + 1], -1, 1), batch.facts)
            out[k + 1, w] = arm.data.qpos
    return out


def gaps(model, facts: dict, native: list[dict], port: np.ndarray) -> dict[str, list[list[float]]]:
    """Per init state, per step of its native episode: the arm's and the objects' worst gaps."""
    free = [int(model.jnt_qposadr[j]) for j in range(model.njnt) if int(model.jnt_type[j]) == 0]
    objects = np.concatenate([np.arange(a, a + 3) for a in free]) if free else np.zeros(0, np.int64)
    arm = np.asarray(facts["qpos_index"], np.int64)
    out = {"arm_rad": [], "objects_m": []}
    for w, e in enumerate(native):
        n = len(e["qpos"])
        diff = np.abs(port[:n, w] - e["qpos"])
        out["arm_rad"].append(diff[:, arm].max(axis=1).tolist())
        out["objects_m"].append((diff[:, objects].reshape(n, -1, 3).max(axis=(1, 2)) if len(objects)
                                 else np.zeros(n)).tolist())
    return out


def at_marks(curves: list[list[float]]) -> dict[int, tuple[float, float]]:
    """step -> (median, worst) over the init states whose episode reached it."""
    out = {}
    for m in MARKS:
        v = [c[m] for c in curves if len(c) > m]
        if v:
            out[m] = (float(np.median(v)), float(np.max(v)))
    return out


def run_task(worker, task: str, inits: list[int], device: str, steps: int) -> dict:
    from simseam.backends.libero_gpu.env import LiberoBatch

    suite, _, index = task.partition("/")
    t0 = time.perf_counter()
    native = native_episodes(worker, suite, int(index), inits, steps)
    actions = padded(native)
    batch = LiberoBatch(suite, int(index), len(inits), worker, device=device)
    try:
        t1 = time.perf_counter()
        cpu = replay_mujoco(batch, inits, actions)
        t2 = time.perf_counter()
        warp = replay_warp(batch, inits, actions)
        t3 = time.perf_counter()
        model, facts = batch.model.model, batch.facts
    finally:
        batch.close()
    return {"init_states": inits, "native_steps": [len(e["actions"]) for e in native],
            "native_success_step": [int(np.argmax(e["done"])) if e["done"].any() else None for e in native],
            "mujoco": gaps(model, facts, native, cpu), "warp": gaps(model, facts, native, warp),
            "seconds": {"native": t1 - t0, "mujoco": t2 - t1, "warp": t3 - t2}}


def print_task(task: str, row: dict) -> None:
    for engine in ("mujoco", "warp"):
        for key, unit in (("arm_rad", "rad"), ("objects_m", "m")):
            marks = at_marks(row[engine][key])
            cells = "  ".join(f"{m}: {med:.1e}/{worst:.1e}" for m, (med, worst) in marks.items())
            print(f"{task:18s} {engine:6s} {key:9s} (median/worst, {unit}) {cells}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tasks", default="libero_spatial/0")
    ap.add_argument("--init-states", default="10:13", help="A:B: init states A..B-1 of every task")
    ap.add_argument("--sim-device", default="cpu", help="MuJoCo Warp's device (cpu, cuda:0, ...)")
    ap.add_argument("--steps", type=int, default=220, help="the native episode's step limit")
    ap.add_argument("--json", type=Path, default=HERE / "results" / "libero_warp_divergence.json")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing --json file")
    args = ap.parse_args()
    if args.json.exists() and not args.overwrite:
        ap.error(f"--json: {args.json} exists; pass --overwrite to replace it")
    from simseam.backends.libero_gpu.worker import NativeWorker
    from simseam.origin import revision

    first, _, end = args.init_states.partition(":")
    inits = list(range(int(first), int(end)))
    rows = {}
    with NativeWorker() as worker:
        for task in args.tasks.split(","):
            rows[task] = run_task(worker, task, inits, args.sim_device, args.steps)
            print_task(task, rows[task])
            doc = {"benchmark": "libero_warp_divergence", "policy": "LIBERO's scripted expert, natively; its actions "
                   "replayed open loop", "marks": list(MARKS), "sim_device": args.sim_device,
                   "revision": revision(), "machine": {"cpus": os.cpu_count(), "python": platform.python_version(),
                                                       "loadavg": os.getloadavg()}, "tasks": rows}
            args.json.parent.mkdir(parents=True, exist_ok=True)
            args.json.write_text(json.dumps(doc, indent=1) + "\n")  # after every task: a cut-off run keeps its tasks
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
