"""Where MuJoCo Warp's camera step spends its time, and what the render options buy.

    python3 benchmarks/bench_warp_render.py --robot-json panda.json --urdf franka_panda/panda.urdf \
        --worlds 1024,4096 --image 128 --out $OUT/warp_render.json      # on the GPU machine
    .venv/bin/python benchmarks/bench_warp_render.py --device cpu --worlds 2 --image 32 --steps 2   # CPU smoke

lift_cube on the Panda (``collision: primitives``), both cameras (camera1 + wrist camera2) at
``--image``², ``--worlds`` worlds. For each world count:

1. **The split.** The same scene built state-only, its control step timed the same way (what the
   cameras cost the physics step itself, if anything). A control step alone (physics: the captured CUDA graph of the substeps), then the
   render's parts one at a time, each synchronised: ``camlight`` (camera and light poses),
   ``refit_bvh`` (the scene BVH over every world's geoms), ``render`` (the ray casting) and the unpack
   into uint8 images. Per call, in ms, and as a share of a camera step.
2. **Render variants**, each a render context built beside the scene's own (the scene's default is
   ``visual``), its ray casting timed by direct launches (the default's too: the scene's own render
   replays a CUDA graph captured with its own context, so swapping the context under it would time the
   default again) and added to the control step's time, with the images' distance to the default's
   on the same state (mean absolute difference in 0-255 units and the share of pixels off by more
   than 8):
   - ``visual``: what simseam renders (the robot's visual meshes, textures, specular, vertex normals);
   - ``flat``: the same geometry without specular highlights and vertex-normal smoothing;
   - ``collision``: the robot drawn with its collision geometry (render-only coarse geometry: with
     ``collision: primitives``, capsules and boxes instead of the visual meshes);
   - ``collision_flat``: both;
   - ``untextured``: the default without textures (flat material colours);
   - ``collision_flat_untextured``: all three.
3. **Cadence.** env-steps/s when the images are asked for every k-th control step (k = 1, 2, 5, 10,
   20), as a chunked policy does (an ACT executing chunks of k actions reads the cameras once per
   chunk; the scene renders only when an observation request asks for images), with the default
   render.

Prints a table and writes JSON (``--out``, rewritten after each world count).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import platform
import sys
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_warp import _robot  # noqa: E402

VARIANTS = {
    "visual": {},
    "flat": {"enable_specular": False, "enable_vertex_normals": False},
    "collision": {"geometry": "collision"},
    "collision_flat": {"geometry": "collision", "enable_specular": False, "enable_vertex_normals": False},
    "untextured": {"use_textures": False},
    "collision_flat_untextured": {"geometry": "collision", "enable_specular": False,
                                  "enable_vertex_normals": False, "use_textures": False},
}
CADENCES = (1, 2, 5, 10, 20)


def _timed(fn, reps: int, device) -> float:
    """Seconds per call of ``fn`` (device work synchronised), the mean of ``reps`` calls after one untimed."""
    import warp as wp

    fn()
    wp.synchronize_device(device)
    t0 = time.perf_counter()
    for _ in range(reps):
        fn()
    wp.synchronize_device(device)
    return (time.perf_counter() - t0) / reps


def _context(b, variant: dict):
    """The cameras of ``b`` (a ``WarpCameras``) with ``variant``'s render options (the scene's own: ``visual``)."""
    from simseam.engines.mujoco.engine import GROUP_ROBOT_COLLISION, GROUP_ROBOT_VISUAL, GROUP_WORLD
    from simseam.engines.mujoco_warp.cameras import WarpCameras

    opts = {"use_textures": True, **variant}
    robot_group = GROUP_ROBOT_COLLISION if opts.pop("geometry", "visual") == "collision" else GROUP_ROBOT_VISUAL
    cams = [(f"cam:{name}", key, hw) for name, key, hw in b.host.plan.cameras]
    return WarpCameras(b.mjm, b.num_envs, cams, device=b.device, groups=(GROUP_WORLD, robot_group),
                       background_color=(0.0, 0.0, 0.0, 1.0), **opts)


def _cast(b, cams) -> None:
    """Camera and light poses, the scene BVH's refit and the ray casting, with ``cams`` (launched directly:
    the scene's own render replays the CUDA graph it captured with its own context)."""
    cams.cast(b.m, b.d)


def _images(b, cams):
    """Host uint8 images [N, H, W, 3] per camera key, rendered with ``cams`` on ``b``'s current state."""
    import numpy as np

    return {key: img.numpy().astype(np.int16) for key, img in cams.render(b.m, b.d).items()}


def split(b, acts, reps: int) -> dict:
    import mujoco_warp as mjw

    rc, m, d = b.camera_renderer.rc, b.m, b.d
    parts = {
        "step": _timed(lambda: b.step(acts), reps, b.device),
        "camlight": _timed(lambda: mjw.camlight(m, d), reps, b.device),
        "refit_bvh": _timed(lambda: mjw.refit_bvh(m, d, rc), reps, b.device),
        "render": _timed(lambda: mjw.render(m, d, rc), reps, b.device),
        "render_total": _timed(b.render, reps, b.device),
    }
    parts["unpack"] = max(0.0, parts["render_total"] - parts["camlight"] - parts["refit_bvh"] - parts["render"])
    cam_step = parts["step"] + parts["render_total"]
    return {k: {"ms": round(v * 1e3, 3), "share_of_camera_step": round(v / cam_step, 3)} for k, v in parts.items()}


def variants(b, acts, reps: int) -> list[dict]:
    """Each variant's ray casting timed the same way (direct launches, the default's too), added to the
    control step's time for env-steps/s; its images against the default's on the same state."""
    import numpy as np

    step_s = _timed(lambda: b.step(acts), reps, b.device)
    ref = _images(b, b.camera_renderer)
    rows = []
    for name, opts in VARIANTS.items():
        cams = b.camera_renderer if name == "visual" else _context(b, opts)
        diff = np.concatenate([np.abs(v - ref[k]).ravel() for k, v in _images(b, cams).items()])
        cast_s = _timed(lambda: _cast(b, cams), reps, b.device)
        rows.append({"variant": name, "options": opts, "render_ms": round(cast_s * 1e3, 3),
                     "step_ms": round((step_s + cast_s) * 1e3, 3),
                     "env_steps_per_s": round(b.num_envs / (step_s + cast_s), 1),
                     "mean_abs_diff": round(float(diff.mean()), 3),
                     "share_off_by_8": round(float((diff > 8).mean()), 5)})
    return rows


def cadence(b, acts, reps: int) -> list[dict]:
    rows = []
    for k in CADENCES:
        n_steps = max(k, reps - reps % k)

        def run(k=k, n_steps=n_steps):
            for i in range(n_steps):
                b.step(acts)
                if i % k == 0:
                    b.render()

        s = _timed(run, 1, b.device) / n_steps
        rows.append({"images_every": k, "step_ms": round(s * 1e3, 3), "env_steps_per_s": round(b.num_envs / s, 1)})
    return rows


def bench(robot, n: int, args) -> dict:
    import numpy as np

    from simseam.scene.manifest_scene import SceneOptions
    from simseam.scene.warp import BatchedScene, WarpOptions

    r = dataclasses.replace(robot, collision="primitives")
    state_step = _state_only_step(r, n, args)
    opts = SceneOptions(render_images=True, image_size=(args.image, args.image))
    b = BatchedScene(r, "lift_cube", n, opts, WarpOptions(device=args.device))
    try:
        b.reset(np.arange(n), np.arange(n))
        acts = _actions(b)
        for _ in range(3):  # compile, capture the step's graph, settle into motion
            b.step(acts)
            b.render()
        return {"worlds": n, "image": args.image, "substeps": b.substeps,
                "state_only_step_ms": round(state_step * 1e3, 3), "split": split(b, acts, args.steps),
                "variants": variants(b, acts, args.steps), "cadence": cadence(b, acts, args.steps)}
    finally:
        b.close()


def _actions(b):
    import numpy as np

    return np.random.default_rng(0).uniform(-1, 1, size=(b.num_envs, b.action_dim)).astype(np.float32)


def _state_only_step(robot, n: int, args) -> float:
    """Seconds per control step of the same scene built state-only (no render context), timed the same
    way as the camera scene's step: what the cameras cost the physics step itself, if anything."""
    import numpy as np

    from simseam.scene.manifest_scene import SceneOptions
    from simseam.scene.warp import BatchedScene, WarpOptions

    b = BatchedScene(robot, "lift_cube", n, SceneOptions(render_images=False), WarpOptions(device=args.device))
    try:
        b.reset(np.arange(n), np.arange(n))
        acts = _actions(b)
        for _ in range(3):
            b.step(acts)
        return _timed(lambda: b.step(acts), args.steps, b.device)
    finally:
        b.close()


def _print(row: dict) -> None:
    n = row["worlds"]
    print(f"\n{n} worlds, 2 x {row['image']}^2 RGB, lift_cube, {row['substeps']} substeps per control step; "
          f"the state-only scene's step: {row['state_only_step_ms']:.3f} ms")
    print(f"{'part':14} {'ms':>9} {'share':>7}")
    for k, v in row["split"].items():
        print(f"{k:14} {v['ms']:9.3f} {v['share_of_camera_step']:7.3f}")
    print(f"{'variant':16} {'render ms':>10} {'step+render ms':>15} {'env-steps/s':>12} {'mean |diff|':>12} {'>8 off':>8}")
    for v in row["variants"]:
        print(f"{v['variant']:16} {v['render_ms']:10.3f} {v['step_ms']:15.3f} {v['env_steps_per_s']:12,.0f} "
              f"{v['mean_abs_diff']:12.3f} {v['share_off_by_8']:8.4f}")
    print(f"{'images every k':16} {'ms/step':>9} {'env-steps/s':>12}")
    for c in row["cadence"]:
        print(f"{c['images_every']:16d} {c['step_ms']:9.3f} {c['env_steps_per_s']:12,.0f}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--worlds", default="1024,4096")
    ap.add_argument("--image", type=int, default=128)
    ap.add_argument("--steps", type=int, default=20, help="timed calls per measurement")
    ap.add_argument("--device", default=None, help="warp device (default: warp's preferred)")
    ap.add_argument("--robot", default="franka_panda")
    ap.add_argument("--robot-json", default=None, help="a RobotSpec as JSON (machines without pydantic)")
    ap.add_argument("--urdf", default=None, help="override the robot's URDF path")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/warp_render.json"))
    args = ap.parse_args()
    import warp as wp

    robot = _robot(args)
    report = {"machine": {"platform": platform.platform(), "python": platform.python_version(),
                          "device": str(wp.get_device(args.device))}, "rows": []}
    for n in (int(x) for x in args.worlds.split(",")):
        row = bench(robot, n, args)
        report["rows"].append(row)
        _print(row)
        args.out.parent.mkdir(parents=True, exist_ok=True)
        args.out.write_text(json.dumps(report, indent=2) + "\n")
    return 0


if __name__ == "__main__":
    sys.exit(main())
