"""What a LIBERO control step costs on MuJoCo Warp (``backends/libero_gpu``), per number of worlds, state-only and
with both cameras drawn, and what a reset (its settle steps) costs.

    .venv/bin/python benchmarks/libero_warp_step.py [--task libero_spatial/0] [--worlds 1,4] [--steps 5]
        [--image-size 128] [--sim-device cpu] [--ways whole,substep] [--json PATH]

For each renderer (``render: warp``, ``opengl``) and N: a ``LiberoBatchRollout`` of N worlds (``cameras: true``), the
reset of all N (10 settle steps, the cameras drawn on the last), then ``--steps`` steps of every world state-only and
``--steps`` with both images asked (the dummy action). Both steps are timed each way of ``--ways``, alternated twice
on the same batch: ``whole`` (a whole control step as device launches, the observables sampled by a launch after each
substep, the ray tracer's images after the substeps where some world samples: one captured CUDA graph per step) and
``substep`` (a graph per substep, the observables and images sampled on the host between them); with ``render:
opengl`` the images are drawn on the host either way. Prints one row per N (seconds per reset, per step
state-only each way and with images, and per world-step) and writes JSON (default
benchmarks/results/libero_warp_step_cpu.json). Wall-clock on whatever else the machine runs: say so beside the
numbers. Nothing is asserted.
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


def _timed(batch, envs, action, request, steps: int) -> float:
    t0 = time.perf_counter()
    for _ in range(steps):
        batch.step(envs, action, request)
    return (time.perf_counter() - t0) / steps


def measure(task: str, n: int, steps: int, size: int, device: str, worker, render: str,
            ways: tuple[str, ...] = ("whole", "substep")) -> dict:
    from simseam.backends.libero_gpu.rollout import LiberoBatchRollout
    from simseam.seam import ObsRequest

    suite, _, index = task.partition("/")
    config = {"suite": suite, "task": int(index), "image_size": [size, size], "cameras": True, "render": render}
    envs, action = list(range(n)), np.tile(np.asarray([0, 0, 0, 0, 0, 0, -1], np.float32), (n, 1))
    with LiberoBatchRollout(config, n, worker, device=device) as batch:
        batch.reset(envs, envs)  # kernels compiled and loaded, reset states cached: not timed
        for way in ways:  # on CUDA a graph runs directly once, is captured on its second call
            batch.world.whole_step = way == "whole"
            for request in (ObsRequest.state_only(), ObsRequest()) * 2:
                batch.step(envs, action, request)
        t0 = time.perf_counter()
        batch.reset(envs, envs)
        reset = time.perf_counter() - t0
        out = {"worlds": n, "render": render, "reset_s": reset}
        for _ in range(2):
            for way in ways:
                batch.world.whole_step = way == "whole"
                out.setdefault(f"step_s_state_only_{way}", []).append(
                    _timed(batch, envs, action, ObsRequest.state_only(), steps))
                out.setdefault(f"step_s_images_{way}", []).append(_timed(batch, envs, action, ObsRequest(), steps))
    out["step_s_state_only"] = min(out[f"step_s_state_only_{ways[0]}"])
    out["step_s_images"] = min(out[f"step_s_images_{ways[0]}"])
    out["world_step_ms_state_only"] = 1e3 * out["step_s_state_only"] / n
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--task", default="libero_spatial/0")
    ap.add_argument("--worlds", default="1,4")
    ap.add_argument("--steps", type=int, default=5)
    ap.add_argument("--image-size", type=int, default=128)
    ap.add_argument("--sim-device", default="cpu")
    ap.add_argument("--render", default="warp,opengl", help="the renderers of the images (warp, opengl)")
    ap.add_argument("--ways", default="whole,substep", help="how a state-only step runs (whole, substep); the first "
                    "is the row's figure")
    ap.add_argument("--json", type=Path, default=HERE / "results" / "libero_warp_step_cpu.json")
    args = ap.parse_args()
    ways = tuple(args.ways.split(","))
    from simseam.backends.libero_gpu.worker import NativeWorker

    rows = []
    with NativeWorker() as worker:
        for render in args.render.split(","):
            for n in (int(x) for x in args.worlds.split(",")):
                rows.append(measure(args.task, n, args.steps, args.image_size, args.sim_device, worker, render, ways))
                r = rows[-1]
                each = ", ".join(f"{w} " + "/".join(f"{t:.4f}" for t in r[f"step_s_state_only_{w}"]) for w in ways)
                imgs = ", ".join(f"{w} " + "/".join(f"{t:.4f}" for t in r[f"step_s_images_{w}"]) for w in ways)
                print(f"{render:>6} {n:>3} worlds: reset {r['reset_s']:.2f} s, step state-only {each} s "
                      f"({r['world_step_ms_state_only']:.1f} ms per world {ways[0]}), with 2 x {args.image_size}^2 "
                      f"images {imgs} s", flush=True)
    doc = {"benchmark": "libero_warp_step", "task": args.task, "sim_device": args.sim_device, "ways": list(ways),
           "image_size": args.image_size, "steps": args.steps, "load_1min": os.getloadavg()[0],
           "machine": {"cpus": os.cpu_count(), "python": platform.python_version()}, "rows": rows}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
