"""Range sensors and the mobile-manipulator step, on this machine.

    .venv/bin/python benchmarks/bench_sensors.py [--reps 300] [--rounds 3]

Cases (MuJoCo, EGL on whatever GL this machine has, lean rendering):

- ``scan_360``: one 360-beam ``lidar_2d`` scan of panda_mobile in nav_obstacles (the scene's
  ``Lidar2D.scan``: one batched ``mj_multiRay`` plus frame math).
- ``depth_to_cloud_256``: a 256x256 depth image (rendered once, outside the timing) turned into a
  base_link point cloud (``DepthCloud.points``).
- ``depth_render_256``: rendering that depth image, for scale.
- ``step_panda_mobile_all``: a full panda_mobile control step with every declared sensor (three RGB
  cameras 256x256, the 160x120 depth camera -> cloud, the lidar), driving the base.
- ``step_franka_fixed``: the fixed Franka's step with its two 256x256 cameras (lift_cube), for
  comparison.

Each round times every case; the table reports medians over rounds of per-call p50 / p90, and
writes JSON (``--json``).
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from simseam.robot.manifest import load_robot  # noqa: E402
from simseam.scene.manifest_scene import ManifestScene, SceneOptions  # noqa: E402
from simseam.scene.sensors import DepthCloud  # noqa: E402

HERE = Path(__file__).resolve().parent


def timed(fn, n: int) -> np.ndarray:
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        fn(i)
        out[i] = time.perf_counter() - t0
    return out * 1e3


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=300)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--json", default=str(HERE / "results" / "sensors.json"))
    args = ap.parse_args()

    mobile = load_robot("panda_mobile")
    depth = mobile.sensors_of("depth")[0]
    depth256 = dataclasses.replace(depth, name="depth256", width=256, height=256)
    spec256 = dataclasses.replace(mobile, sensors=[*mobile.sensors, depth256])
    nav = ManifestScene(spec256, "nav_obstacles", "mujoco", SceneOptions(image_size=(256, 256)))
    nav.reset(0)
    lidar = nav._lidar
    parent = nav.link_in_base(lidar.sensor.parent)
    img = nav.engine.render_depth("depth256")
    cloud = DepthCloud(depth256, 256, 256)
    cam_parent = nav.link_in_base(depth256.parent)

    steps = {}
    acts = {}
    for name, spec, layout in (("step_panda_mobile_all", mobile, "nav_obstacles"),
                               ("step_franka_fixed", load_robot("franka_panda"), "lift_cube")):
        sc = ManifestScene(spec, layout, "mujoco", SceneOptions(image_size=(256, 256)))
        sc.reset(0)
        lay = sc.spec.action
        rng = np.random.default_rng(0)
        acts[name] = [lay.pack(arm=rng.uniform(-0.2, 0.2, 6), grip=-1.0,
                               base=[0.2, 0.0, 0.1] if lay.has_base else None) for _ in range(args.reps)]
        steps[name] = sc

    cases = {
        "scan_360": (lambda i: lidar.scan(nav.engine, nav._base_rot, nav._base_pos, *parent), args.reps),
        "depth_to_cloud_256": (lambda i: cloud.points(img, *cam_parent), args.reps),
        "depth_render_256": (lambda i: nav.engine.render_depth("depth256"), max(30, args.reps // 10)),
        "step_panda_mobile_all": (lambda i: steps["step_panda_mobile_all"].step(acts["step_panda_mobile_all"][i]),
                                  max(30, args.reps // 10)),
        "step_franka_fixed": (lambda i: steps["step_franka_fixed"].step(acts["step_franka_fixed"][i]),
                              max(30, args.reps // 10)),
    }
    rounds = {k: [] for k in cases}
    for _ in range(args.rounds):
        for sc in steps.values():
            sc.reset(0)
        for name, (fn, n) in cases.items():
            ms = timed(fn, n)
            rounds[name].append({"p50_ms": float(np.percentile(ms, 50)), "p90_ms": float(np.percentile(ms, 90))})
    results = {k: {"p50_ms": float(np.median([r["p50_ms"] for r in v])),
                   "p90_ms": float(np.median([r["p90_ms"] for r in v])), "rounds": v} for k, v in rounds.items()}
    print(f"\n{'case':26s} {'p50 ms':>9s} {'p90 ms':>9s}")
    for k, r in results.items():
        print(f"{k:26s} {r['p50_ms']:9.3f} {r['p90_ms']:9.3f}")
    goals = {"scan_360_le_0.5ms": results["scan_360"]["p50_ms"] <= 0.5,
             "depth_to_cloud_256_le_1ms": results["depth_to_cloud_256"]["p50_ms"] <= 1.0}
    print("\ngoals: " + ", ".join(f"{k}={'met' if v else 'NOT met'}" for k, v in goals.items()))
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"results": results, "goals": goals, "points_in_cloud": int(len(
        cloud.points(img, *cam_parent)))}, indent=2))
    print(f"wrote {out}")
    for sc in (nav, *steps.values()):
        sc.close()


if __name__ == "__main__":
    main()
