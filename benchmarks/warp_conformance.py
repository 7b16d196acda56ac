"""The GPU-batched engine against the CPU MuJoCo engine, on any warp device (the GPU machine's check).

The engine's tests (tests/engines/test_mujoco_warp.py) run these comparisons on warp's CPU device
with a handful of worlds; this script runs them on a real device (``cuda:0``) at a useful scale,
for each robot manifest given, and prints a table + writes JSON:

1. ``replay``: the CPU engine's scripted lift episode (seed 11, or the first seed it succeeds on),
   its actions replayed on every world of a small batch: the tool and cube position error per step
   against the CPU trajectory (max before the first contact, max over the episode), whether the
   worlds stay identical to each other, and the success step on both sides;
2. ``expert``: closed loop, the scripted expert on ``--worlds`` worlds (seeds 0..N-1, each world its
   own policy, the batch's own observations) vs the same seeds on the CPU engine (``--cpu-seeds`` of
   them): success rates and the per-seed agreement;
3. ``reach``: the reach task in both control modes, expert closed loop on the batch vs CPU: success
   and steps per seed.

    python benchmarks/warp_conformance.py --robot franka_panda --robot so101 --device cuda:0
    python benchmarks/warp_conformance.py --robot franka_panda --device cpu --worlds 2 --cpu-seeds 2   # smoke

Nothing is asserted: the numbers are the result (the tests assert the CPU-device tolerances).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path

import numpy as np


def _cpu_episode(robot, task, opts, seed):
    from simseam.policies.base import make_policy
    from simseam.scene.manifest_scene import ManifestScene
    from simseam.seam import STATE_ONLY

    scene = ManifestScene(robot, task, "mujoco", opts)
    pol = make_policy("scripted")
    pol.reset(scene.spec)
    obs = scene.reset(seed, STATE_ONLY)
    acts, tool, cube, touch, success_at = [], [], [], [], None
    for k in range(scene.spec.task.max_steps):
        a = pol.act(obs)
        r = scene.step(a, STATE_ONLY)
        obs = r.observation
        acts.append(a)
        tool.append(np.asarray(obs["state"][:3], float).copy())
        objs = obs.get("privileged", {}).get("objects", {})
        cube.append(np.asarray(objs["cube"][:3], float).copy() if "cube" in objs else np.zeros(3))
        touch.append(bool(scene.engine.contacts_between("cube", "robot")) if "cube" in objs else False)
        if r.terminated:
            success_at = k + 1
            break
    scene.close()
    return np.array(acts), np.array(tool), np.array(cube), touch, success_at


def replay(robot, n, device):
    from simseam.scene.warp import BatchedScene, WarpOptions
    from simseam.scene.manifest_scene import SceneOptions

    opts = SceneOptions(render_images=False, privileged=True)
    for seed in (11, 0, 1, 2, 3):
        acts, tool, cube, touch, success_at = _cpu_episode(robot, "lift_cube", opts, seed)
        if success_at is not None:
            break
    b = BatchedScene(robot, "lift_cube", n, opts, WarpOptions(device=device))
    b.reset(np.arange(n), np.full(n, seed))
    tool_err, cube_err, identical, spread = [], [], True, 0.0
    for k, a in enumerate(acts):
        r = b.step(np.tile(a, (n, 1)))
        h = b.host_arrays()
        tool_err.append(float(np.abs(h["state"][0, :3] - tool[k]).max()))
        cube_err.append(float(np.abs(h["objects"]["cube"][0, :3] - cube[k]).max()))
        identical &= bool((h["state"] == h["state"][0]).all())
        spread = max(spread, float(np.abs(h["state"] - h["state"][0]).max()), float(np.abs(h["objects"]["cube"] - h["objects"]["cube"][0]).max()))
    first = touch.index(True) if True in touch else len(acts)
    row = {"check": "replay", "robot": robot.name, "worlds": n, "seed": seed, "cpu_success_step": success_at,
           "batch_success": bool(r.success[0]), "batch_success_step": int(r.steps[0]) if r.terminated[0] else None,
           "tool_err_before_contact_m": max(tool_err[:first]) if first else None,
           "tool_err_episode_m": max(tool_err), "cube_err_episode_m": max(cube_err), "worlds_identical": identical,
           "max_spread_between_worlds": spread}
    b.close()
    return row


def expert(robot, task, n, cpu_seeds, device, mode=None):
    from simseam.scene.warp import BatchedScene, WarpOptions, world_observations
    from simseam.policies.base import make_policy
    from simseam.scene.manifest_scene import SceneOptions
    from simseam.seam import STATE_ONLY

    opts = SceneOptions(render_images=False, privileged=True, control_mode=mode)
    cpu = {s: _cpu_episode(robot, task, opts, s)[4] for s in range(cpu_seeds)}
    b = BatchedScene(robot, task, n, opts, WarpOptions(device=device))
    b.reset(np.arange(n), np.arange(n))
    pols = [make_policy("scripted") for _ in range(n)]
    for p in pols:
        p.reset(b.spec)
    done = [None] * n
    success = [False] * n
    t0 = time.perf_counter()
    steps = 0
    obs = world_observations(b, range(n), [STATE_ONLY] * n)
    for _ in range(b.spec.task.max_steps):
        r = b.step(np.stack([p.act(o) for p, o in zip(pols, obs)]))
        steps += 1
        obs = world_observations(b, range(n), [STATE_ONLY] * n)
        for w in np.flatnonzero(r.terminated | r.truncated):
            if done[w] is None:
                done[w] = int(r.steps[w])
                success[w] = bool(r.success[w])
        if all(d is not None for d in done):
            break
    dt = time.perf_counter() - t0
    b.close()
    both = [s for s in range(min(cpu_seeds, n))]
    agree = sum((cpu[s] is not None) == success[s] for s in both)
    step_diff = [abs(done[s] - cpu[s]) for s in both if cpu[s] is not None and success[s]]
    return {"check": f"expert {task}" + (f" ({mode})" if mode else ""), "robot": robot.name, "worlds": n,
            "batch_success_rate": round(sum(success) / n, 4),
            "cpu_success_rate": round(sum(v is not None for v in cpu.values()) / max(cpu_seeds, 1), 4),
            "cpu_seeds": cpu_seeds, "same_outcome_seeds": agree,
            "max_success_step_diff": max(step_diff) if step_diff else None,
            "loop_env_steps_per_s": round(n * steps / dt, 1)}


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--robot", action="append", help="built-in robot name or manifest path (repeatable)")
    ap.add_argument("--device", default=None)
    ap.add_argument("--worlds", type=int, default=64)
    ap.add_argument("--cpu-seeds", type=int, default=16)
    ap.add_argument("--replay-worlds", type=int, default=4)
    ap.add_argument("--only-replay", action="store_true")
    ap.add_argument("--out", default="benchmarks/results/warp_conformance.json")
    args = ap.parse_args(argv)
    import warp as wp

    from simseam.robot.manifest import load_robot

    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(args.device) if args.device else wp.get_preferred_device()
    meta = {"device": str(dev), "device_name": getattr(dev, "name", str(dev)), "python": sys.version.split()[0],
            "platform": platform.platform(), "warp": wp.config.version}
    rows = []
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)

    def emit(row):
        rows.append(row)
        print(json.dumps(row), flush=True)
        out.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))

    for name in args.robot or ["franka_panda"]:
        robot = load_robot(name)
        jobs = [lambda: replay(robot, args.replay_worlds, str(dev)),
                lambda: expert(robot, "lift_cube", args.worlds, args.cpu_seeds, str(dev)),
                lambda: expert(robot, "reach", args.worlds, args.cpu_seeds, str(dev)),
                lambda: expert(robot, "reach", args.worlds, args.cpu_seeds, str(dev), "joint_position")]
        for job in jobs[:1] if args.only_replay else jobs:
            t0 = time.perf_counter()
            try:
                row = job()
            except Exception as exc:  # noqa: BLE001  (recorded, the next check runs)
                row = {"robot": robot.name, "error": f"{type(exc).__name__}: {exc}"[:500]}
            row["wall_s"] = round(time.perf_counter() - t0, 1)
            emit(row)
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
