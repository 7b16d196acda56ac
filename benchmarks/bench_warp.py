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

    from simseam.scene.warp import BatchedScene, WarpOptions
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
    t0 = time.perf_counter()
    b.step(acts[0])  # the second call captures the CUDA graph (the engine captures on second use)
    wp.synchronize_device(b.device)
    capture_s = time.perf_counter() - t0
    first_render_s = None
    if cameras:
        t0 = time.perf_counter()
        b.render()
        wp.synchronize_device(b.device)
        first_render_s = time.perf_counter() - t0
        b.render()  # a second untimed render, as for the step
        wp.synchronize_device(b.device)
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
        "capture_step_s": round(capture_s, 3),
        "first_render_s": None if first_render_s is None else round(first_render_s, 3),
        "step_ms": round(step_s * 1e3, 3), "env_steps_per_s": round(n / step_s, 1),
        "physics_steps_per_s": round(n * b.substeps / step_s, 1),
        "resets_per_step": int(len(worlds)), "reset_ms": round(reset_s * 1e3, 3),
        "env_steps_per_s_with_resets": round(n / (step_s + reset_s), 1), "image_std": img_check,
    }
    b.close()
    return row


def bench_expert(robot, collision: str, n: int, args) -> dict:
    """The real task at scale: the vectorized scripted expert on every world (state only), finished
    worlds reset alone with fresh seeds; env-steps/s of the whole loop (host policy and resets included)
    and the success rate of the episodes that finished."""
    import numpy as np
    import warp as wp

    from simseam.scene.warp import BatchedScene, WarpOptions
    from simseam.policies.batched_expert import LiftExpertBatch
    from simseam.scene.manifest_scene import SceneOptions

    r = dataclasses.replace(robot, collision=collision)
    b = BatchedScene(r, "lift_cube", n, SceneOptions(render_images=False, privileged=True),
                     WarpOptions(device=args.device))
    pol = LiftExpertBatch(b.spec.action, n)
    seeds = np.arange(n)
    next_seed = n
    b.reset(np.arange(n), seeds)
    h = b.host_arrays()
    pol.act(h["eef_pose"], h["objects"]["cube"])  # warm-up: compile, graph capture
    b.step(np.zeros((n, b.action_dim), np.float32))
    b.reset(np.arange(n), seeds)
    pol.reset(np.arange(n))
    wp.synchronize_device(b.device)
    finished = succeeded = 0
    steps_ok = []
    t0 = time.perf_counter()
    for _ in range(args.expert_steps):
        h = b.host_arrays()
        r_ = b.step(pol.act(h["eef_pose"], h["objects"]["cube"]))
        done = np.flatnonzero(r_.terminated | r_.truncated)
        if done.size:
            finished += done.size
            succeeded += int(r_.success[done].sum())
            steps_ok += r_.steps[done][r_.success[done]].tolist()
            b.reset(done, np.arange(next_seed, next_seed + done.size))
            pol.reset(done)
            next_seed += done.size
    wp.synchronize_device(b.device)
    dt = time.perf_counter() - t0
    b.close()
    return {"collision": collision, "observation": "state, scripted expert", "worlds": n,
            "control_steps": args.expert_steps, "env_steps_per_s": round(n * args.expert_steps / dt, 1),
            "episodes_finished": finished, "success_rate": round(succeeded / finished, 4) if finished else None,
            "mean_steps_to_success": round(float(np.mean(steps_ok)), 2) if steps_ok else None}


def bench_pose_renderer(robot, n: int, args) -> dict:
    """CPU-physics states rendered centrally: upload N states, render 2 cameras, images back on the host."""
    import numpy as np
    import warp as wp

    from simseam.engines.mujoco_warp.pose_renderer import PoseRenderer, pose_state
    from simseam.scene.manifest_scene import ManifestScene, SceneOptions
    from simseam.seam import STATE_ONLY

    scene = ManifestScene(robot, "lift_cube", "mujoco", SceneOptions(image_size=(args.image, args.image)))
    states = []
    for s in range(16):
        scene.reset(s, STATE_ONLY)
        states.append(pose_state(scene))
    states = np.tile(np.stack(states), (n // 16 + 1, 1))[:n]
    pr = PoseRenderer(scene, n, device=args.device)
    t0 = time.perf_counter()
    pr.render(states)
    first = time.perf_counter() - t0
    reps = max(3, args.steps // 2)
    t0 = time.perf_counter()
    for _ in range(reps):
        pr.render(states, host=False)
    wp.synchronize_device(pr.device)
    dev_s = (time.perf_counter() - t0) / reps
    t0 = time.perf_counter()
    for _ in range(reps):
        pr.render(states, host=True)
    host_s = (time.perf_counter() - t0) / reps
    scene.close()
    return {"collision": "-", "observation": f"pose renderer 2x{args.image}x{args.image}", "worlds": n,
            "first_render_s": round(first, 3), "env_renders_per_s_device": round(n / dev_s, 1),
            "env_renders_per_s_to_host": round(n / host_s, 1)}


def cpu_expert_reference(robot, collision: str, episodes: int) -> dict:
    """The per-world scripted expert on the CPU MuJoCo engine, seeds 0..episodes-1: the reference rate."""
    from simseam.policies.base import make_policy
    from simseam.scene.manifest_scene import ManifestScene, SceneOptions
    from simseam.seam import STATE_ONLY

    scene = ManifestScene(dataclasses.replace(robot, collision=collision), "lift_cube", "mujoco",
                          SceneOptions(render_images=False, privileged=True))
    ok, steps = 0, []
    t0 = time.perf_counter()
    n_steps = 0
    for seed in range(episodes):
        pol = make_policy("scripted")
        pol.reset(scene.spec)
        obs = scene.reset(seed, STATE_ONLY)
        for k in range(scene.spec.task.max_steps):
            r = scene.step(pol.act(obs), STATE_ONLY)
            obs = r.observation
            n_steps += 1
            if r.terminated:
                ok += 1
                steps.append(k + 1)
                break
    dt = time.perf_counter() - t0
    scene.close()
    return {"collision": collision, "observation": "state, scripted expert, CPU MuJoCo (reference)", "worlds": 1,
            "episodes_finished": episodes, "success_rate": round(ok / episodes, 4),
            "mean_steps_to_success": round(sum(steps) / len(steps), 2) if steps else None,
            "env_steps_per_s": round(n_steps / dt, 1)}


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
    ap.add_argument("--expert-worlds", default="", help="world counts for the scripted-expert runs (empty: none)")
    ap.add_argument("--expert-steps", type=int, default=80)
    ap.add_argument("--cpu-expert-episodes", type=int, default=0, help="CPU reference episodes (0: none)")
    ap.add_argument("--pose-worlds", default="", help="batch sizes for the pose renderer (empty: none)")
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
            for n in [int(x) for x in args.worlds.split(",") if x]:
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
    for collision in args.collision.split(","):
        for n in [int(x) for x in args.expert_worlds.split(",") if x]:
            try:
                row = bench_expert(robot, collision, n, args)
                print(f"{collision:<11} expert (state)   {n:>6} env-steps/s {row['env_steps_per_s']:>10,.0f}  "
                      f"episodes {row['episodes_finished']}  success {row['success_rate']}  "
                      f"mean steps {row['mean_steps_to_success']}", flush=True)
            except Exception as exc:  # noqa: BLE001
                row = {"collision": collision, "observation": "expert", "worlds": n,
                       "error": f"{type(exc).__name__}: {exc}"[:400]}
                print(f"{collision:<11} expert {n} ERROR {row['error']}", flush=True)
            rows.append(row)
            out.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    if args.cpu_expert_episodes:
        for collision in args.collision.split(","):
            row = cpu_expert_reference(robot, collision, args.cpu_expert_episodes)
            print(f"{collision:<11} CPU expert (1 world) episodes {row['episodes_finished']}  success "
                  f"{row['success_rate']}  mean steps {row['mean_steps_to_success']}  "
                  f"env-steps/s {row['env_steps_per_s']:,.0f}", flush=True)
            rows.append(row)
            out.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    for n in [int(x) for x in args.pose_worlds.split(",") if x]:
        try:
            row = bench_pose_renderer(robot, n, args)
            print(f"pose renderer 2x{args.image}  {n:>6} env-renders/s on device {row['env_renders_per_s_device']:>10,.0f}"
                  f"  to host {row['env_renders_per_s_to_host']:>10,.0f}  first {row['first_render_s']:.1f} s",
                  flush=True)
        except Exception as exc:  # noqa: BLE001
            row = {"observation": "pose renderer", "worlds": n, "error": f"{type(exc).__name__}: {exc}"[:400]}
            print(f"pose renderer {n} ERROR {row['error']}", flush=True)
        rows.append(row)
        out.write_text(json.dumps({"meta": meta, "rows": rows}, indent=1))
    print(f"wrote {out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
