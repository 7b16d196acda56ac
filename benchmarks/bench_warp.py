"""Throughput of the GPU-batched engine (MuJoCo Warp): env-steps/s vs number of worlds.

For each collision model (the URDF's meshes, or fitted primitives: ``collision: primitives``) and
observation (state only; two RGB cameras at --image) and each world count: the build time, the
first step (kernel compile / load + CUDA graph capture), the first render, then --steps timed control
steps of every world with random Cartesian actions (host numpy actions, uploaded each step; images
stay on the device, as a device-side policy would read them), and the cost of the per-world resets
a steady episode stream needs (N / max_steps worlds per step, each reset settled on the CPU).

Prints a table and writes JSON (--out, rewritten after every row so a cut-short run keeps its rows).

    python benchmarks/bench_warp.py --worlds 256,1024,4096 --collision mesh,primitives
    python benchmarks/bench_warp.py --device cpu --worlds 2,4 --steps 3      # a CPU smoke run
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import math
import os
import platform
import sys
import time
from pathlib import Path


def _robot(args):
    from simseam.robot.spec import RobotSpec

    if args.robot_json:
        spec = RobotSpec.from_json(json.loads(Path(args.robot_json).read_text()))
    else:
        from simseam.robot.manifest import load_robot

        spec = load_robot(args.robot)
    if args.urdf:
        spec = dataclasses.replace(spec, urdf="file:" + str(Path(args.urdf).resolve()))
    return spec


def bench_one(robot, collision: str, cameras: bool, n: int, args) -> dict:
    import numpy as np
    import warp as wp

    from simseam.engines.mujoco_warp import BatchedScene, WarpOptions
    from simseam.scene.manifest_scene import SceneOptions

    size = (args.image, args.image)
    opts = SceneOptions(render_images=cameras, image_size=size if cameras else None)
    r = dataclasses.replace(robot, collision=collision)
    t0 = time.perf_counter()
    b = BatchedScene(r, "lift_cube", n, opts, WarpOptions(device=args.device))
    build_s = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    b.reset(np.arange(n), np.arange(n))
    acts = rng.uniform(-1, 1, size=(args.steps + 1, n, b.action_dim)).astype(np.float32)
    t0 = time.perf_counter()
    b.step(acts[0])
    wp.synchronize_device(b.device)
    first_step_s = time.perf_counter() - t0
    first_render_s = None
    if cameras:
        t0 = time.perf_counter()
        b.render()
        wp.synchronize_device(b.device)
        first_render_s = time.perf_counter() - t0
    t0 = time.perf_counter()
    for k in range(1, args.steps + 1):
        b.step(acts[k])
        if cameras:
            b.render()
    wp.synchronize_device(b.device)
    step_s = (time.perf_counter() - t0) / args.steps
    # resets at the steady episode rate: N / max_steps worlds per control step
    k_reset = max(1, math.ceil(n / b.max_steps))
    worlds = rng.choice(n, size=min(k_reset, n), replace=False)
    t0 = time.perf_counter()
    b.reset(worlds, worlds + 10_000)
    wp.synchronize_device(b.device)
    reset_s = time.perf_counter() - t0
    img_check = None
    if cameras:
        imgs = {k: v.numpy()[:2] for k, v in b.render().items()}
        img_check = {k: float(v.std()) for k, v in imgs.items()}  # > 0: real frames
    row = {
        "collision": collision, "observation": f"2x{args.image}x{args.image} rgb" if cameras else "state",
        "worlds": n, "substeps": b.substeps, "build_s": round(build_s, 3), "first_step_s": round(first_step_s, 3),
        "first_render_s": None if first_render_s is None else round(first_render_s, 3),
        "step_ms": round(step_s * 1e3, 3), "env_steps_per_s": round(n / step_s, 1),
        "physics_steps_per_s": round(n * b.substeps / step_s, 1),
        "resets_per_step": int(len(worlds)), "reset_ms": round(reset_s * 1e3, 3),
        "env_steps_per_s_with_resets": round(n / (step_s + reset_s), 1), "image_std": img_check,
    }
    b.close()
    return row


def main(argv=None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--worlds", default="256,1024,4096")
    ap.add_argument("--collision", default="mesh,primitives")
    ap.add_argument("--observations", default="state,rgb")
    ap.add_argument("--image", type=int, default=128)
    ap.add_argument("--steps", type=int, default=10)
    ap.add_argument("--device", default=None, help="warp device (default: warp's preferred: cuda:0 if any)")
    ap.add_argument("--robot", default="franka_panda")
    ap.add_argument("--robot-json", default=None, help="a RobotSpec as JSON (machines without pydantic)")
    ap.add_argument("--urdf", default=None, help="override the robot's URDF path")
    ap.add_argument("--out", default="benchmarks/results/warp.json")
    args = ap.parse_args(argv)
    import warp as wp

    wp.config.quiet = True
    wp.init()
    robot = _robot(args)
    dev = wp.get_device(args.device) if args.device else wp.get_preferred_device()
    meta = {"device": str(dev), "device_name": getattr(dev, "name", str(dev)), "python": sys.version.split()[0],
            "platform": platform.platform(), "warp": wp.config.version, "task": "lift_cube", "robot": robot.name}
    try:
        import mujoco_warp

        meta["mujoco_warp"] = mujoco_warp.__version__
    except Exception:  # noqa: BLE001
        pass
    rows = []
    out = Path(args.out)
    out.parent.mkdir(parents=True, exist_ok=True)
    hdr = (f"{'collision':<11} {'obs':<16} {'worlds':>6} {'build s':>8} {'1st step s':>10} {'1st rndr s':>10} "
           f"{'step ms':>9} {'env-steps/s':>12} {'phys steps/s':>13} {'w/ resets':>10}")
    print(hdr, flush=True)
    for collision in args.collision.split(","):
        for obs in args.observations.split(","):
            for n in [int(x) for x in args.worlds.split(",")]:
                try:
                    row = bench_one(robot, collision, obs == "rgb", n, args)
                except Exception as exc:  # noqa: BLE001  (recorded: a size that does not fit, say)
                    row = {"collision": collision, "observation": obs, "worlds": n,
                           "error": f"{type(exc).__name__}: {exc}"[:400]}
                    print(f"{collision:<11} {obs:<16} {n:>6} ERROR {row['error']}", flush=True)
                else:
                    fr = "-" if row["first_render_s"] is None else f"{row['first_render_s']:.1f}"
                    print(f"{collision:<11} {row['observation']:<16} {n:>6} {row['build_s']:>8.1f} "
                          f"{row['first_step_s']:>10.1f} {fr:>10} {row['step_ms']:>9.1f} "
                          f"{row['env_steps_per_s']:>12,.0f} {row['physics_steps_per_s']:>13,.0f} "
                          f"{row['env_steps_per_s_with_resets']:>10,.0f}", flush=True)
                rows.append(row)
                out.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
