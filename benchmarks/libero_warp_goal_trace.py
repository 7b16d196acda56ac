"""One LIBERO episode of the expert, step by step, on the port's two engines: CPU MuJoCo (the port's own code,
float64) and MuJoCo Warp (Warp's CPU device, or ``--sim-device``), with what the goal reads at every step: each
predicate, each contact test, and the goal objects' positions. Where two engines end an episode at different
steps, the trace says what happened in between (a grasp that slipped, a contact sooner or later).

    .venv/bin/python benchmarks/libero_warp_goal_trace.py --task libero_spatial/0 --seed 32 \\
        [--steps 240] [--sim-device cpu] [--json benchmarks/results/libero_warp_goal_trace.json]

Writes JSON (``engines``: per engine the steps, each with the expert's action, the predicates' and contact
tests' truth, the goal objects' body positions and the contacts between the gripper and each of them) and prints
the step where each engine's goal first held and the first step where the objects part by more than 1 cm.
Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent


def trace(task: str, seed: int, steps: int, engine: str, device: str, worker) -> list[dict]:
    from simseam.backends.libero_gpu.rollout import LiberoBatchRollout
    from simseam.seam import OBS_EXPERT_ACTION

    suite, _, index = task.partition("/")
    kw = {"engine": "mujoco"} if engine == "mujoco" else {"device": device}
    out = []
    with LiberoBatchRollout({"suite": suite, "task": int(index)}, 1, worker, privileged=True, **kw) as batch:
        obs, world = batch.reset([0], [seed])[0], batch.world
        names = world.info["names"]
        bodies = {o: int(names["bodies"][o]) for o in names["objects"] if any(o in g for g in world.goal.names)}
        mjm = world.model.model
        gripper = np.array([mjm.geom(i).name.startswith("gripper0_") for i in range(mjm.ngeom)])
        held = {o: np.asarray(mjm.geom_bodyid) == i for o, i in bodies.items()}  # each goal object's own geoms
        for t in range(1, steps + 1):
            action = np.asarray(obs[OBS_EXPERT_ACTION], np.float32)[None]
            result = batch.step([0], action)
            obs, s = result.observations[0], world.physics.goal_state()
            xpos = _host(s.xpos)[0]
            out.append({"step": t, "action": action[0].round(4).tolist(),
                        "predicates": _host(world.goal.values(s)).tolist()[0],
                        "contact_tests": _host(world.goal.touch(s)).tolist()[0],
                        "objects": {o: xpos[i].round(5).tolist() for o, i in bodies.items()},
                        "gripper_contacts": _gripper_contacts(s, gripper, held),
                        "success": bool(result.terminated[0])})
            if result.terminated[0] or result.truncated[0]:
                break
    return out


def _gripper_contacts(s, gripper: np.ndarray, held: dict) -> dict[str, int]:
    """World 0's contacts between the gripper's geoms and each goal object's (the grasp)."""
    geom, world = _host(s.contact_geom), _host(s.contact_world)
    g = geom[world == 0]
    return {o: int(((gripper[g[:, 0]] & mine[g[:, 1]]) | (gripper[g[:, 1]] & mine[g[:, 0]])).sum())
            for o, mine in held.items()}


def _host(a) -> np.ndarray:
    """A host copy of ``a`` (NumPy, or CuPy on a CUDA device)."""
    return a.get() if hasattr(a, "get") else np.asarray(a)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="libero_spatial/0")
    ap.add_argument("--seed", type=int, default=32)
    ap.add_argument("--steps", type=int, default=240)
    ap.add_argument("--sim-device", default="cpu")
    ap.add_argument("--json", type=Path, default=HERE / "results" / "libero_warp_goal_trace.json")
    args = ap.parse_args()

    from simseam.backends.libero_gpu.worker import NativeWorker

    doc = {"task": args.task, "seed": args.seed, "sim_device": args.sim_device, "engines": {}}
    with NativeWorker() as worker:
        for engine in ("mujoco", "mujoco_warp"):
            doc["engines"][engine] = trace(args.task, args.seed, args.steps, engine, args.sim_device, worker)
    a, b = doc["engines"]["mujoco"], doc["engines"]["mujoco_warp"]
    for name, rows in doc["engines"].items():
        held = next((r["step"] for r in rows if r["success"]), None)
        print(f"{name:<12} goal first held at step {held} ({len(rows)} steps)")
    parted = next((ra["step"] for ra, rb in zip(a, b)
                   if any(np.linalg.norm(np.subtract(ra["objects"][o], rb["objects"][o])) > 0.01 for o in ra["objects"])),
                  None)
    print(f"the goal objects first part by more than 1 cm at step {parted}")
    doc["objects_part_at_step"] = parted
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(doc))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
