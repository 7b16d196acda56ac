"""Meta-World's cameras on MuJoCo Warp against MuJoCo's OpenGL renderer, on the same states: SSIM and PSNR per
camera.

Per task and seed, ``--worlds`` worlds of ``MetaWorldBatchRollout`` (the port behind the seam, cameras on,
``--cameras`` at ``--image``²) run Meta-World's scripted expert closed loop; at each step of ``--at`` every
world's images (the rollout's observation: MuJoCo Warp's ray tracer) are compared with the CPU backend's
images of the very same state (qpos, qvel, mocap), rendered by the native worker through
``MetaWorldRollout``'s own cameras: ``env.render()`` on MuJoCo's OpenGL renderer (``MUJOCO_GL``, default
``egl``; llvmpipe on a machine without a GPU), Meta-World on its pinned MuJoCo, after the same seed's native
reset. Metrics from scikit-image: SSIM (``structural_similarity``, 7x7 window, over the 3 channels) and
PSNR, both on uint8 images with a data range of 255; also the mean absolute difference in 0-255 units.

The render options (``metaworld_gpu.env.RENDER_OPTIONS``: textures, skybox, shadows) were chosen from OpenGL's
defaults and looked at on pick-place seeds 0-1 only; the default seeds here (10-12: MT1 variations 10-12)
were not used to choose anything.

    .venv/bin/python benchmarks/metaworld_warp_cameras.py --device cpu \\
        --out benchmarks/results/metaworld_warp_cameras_cpu.json
    .venv/bin/python benchmarks/metaworld_warp_cameras.py --device cuda:0 --out $OUT/cameras_cuda.json

Prints a table (per task and camera, then per camera) and writes JSON (kept unless ``--overwrite``).
"""

from __future__ import annotations

import argparse
import json
import platform
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

OUT = Path(__file__).resolve().parent / "results" / "metaworld_warp_cameras.json"
TASKS = ("reach-v3", "pick-place-v3", "door-open-v3", "drawer-close-v3", "button-press-topdown-v3")


def image_metrics(ours: np.ndarray, reference: np.ndarray) -> dict[str, float]:
    """SSIM, PSNR (dB) and mean |difference| of two uint8 [H, W, 3] images (scikit-image's metrics)."""
    from skimage.metrics import peak_signal_noise_ratio, structural_similarity

    a, b = np.asarray(ours), np.asarray(reference)
    psnr = peak_signal_noise_ratio(b, a, data_range=255) if not np.array_equal(a, b) else float("inf")
    return {"ssim": float(structural_similarity(a, b, channel_axis=2, data_range=255)), "psnr": float(psnr),
            "mean_abs": float(np.abs(a.astype(np.int16) - b.astype(np.int16)).mean())}


def states_of(batch, envs: list[int]) -> list[dict[str, np.ndarray]]:
    """The render state (qpos, qvel, mocap) of ``envs`` of a ``MetaWorldBatchRollout``, on the host."""
    p = batch.world.physics
    arrays = {k: _host(p.view(getattr(p.d, k))) for k in ("qpos", "qvel", "mocap_pos", "mocap_quat")}
    return [{k: np.asarray(v[e], dtype=np.float64) for k, v in arrays.items()} for e in envs]


def compare_task(worker, task: str, seeds: list[int], at: list[int], cameras: list[str], size: int,
                 device: str | None, image_flip: bool = False) -> dict[str, Any]:
    """One batch of ``len(seeds)`` worlds of ``task``; the expert closed loop; at each step of ``at`` each
    world's images against the CPU backend's of its state. Returns per camera key the metrics of every
    image (``samples``: seed, step, ssim, psnr, mean_abs) and the images of the last sample (``last``)."""
    from simseam.backends.metaworld_gpu.rollout import MetaWorldBatchRollout
    from simseam.seam import ObsRequest

    config = {"task": task, "cameras": True, "camera": list(cameras), "image_size": [size, size],
              "image_flip": image_flip}
    n = len(seeds)
    out: dict[str, Any] = {"samples": {}, "last": {}}
    with MetaWorldBatchRollout(config, n, worker, privileged=True, device=device) as batch:
        envs = list(range(n))
        none = ObsRequest.state_only()
        obs = batch.reset(envs, seeds, observe=ObsRequest() if 0 in at else none)
        for t in range(max(at) + 1):
            if t:
                actions = np.stack([o["expert_action"] for o in obs])
                obs = batch.step(envs, actions, observe=ObsRequest() if t in at else none).observations
            if t not in at:
                continue
            states = states_of(batch, envs)
            for i, seed in enumerate(seeds):
                reference = worker.call("render", config=config, seed=seed, states=[states[i]])[0]
                for key, img in obs[i]["images"].items():
                    row = {"seed": seed, "step": t, **image_metrics(img, reference[key])}
                    out["samples"].setdefault(key, []).append(row)
                    out["last"][key] = (img, reference[key])
    return out


def summarize(rows: list[dict[str, Any]]) -> dict[str, float]:
    ssim = np.array([r["ssim"] for r in rows])
    psnr = np.array([r["psnr"] for r in rows])
    return {"images": len(rows), "ssim_mean": float(ssim.mean()), "ssim_min": float(ssim.min()),
            "psnr_mean": float(psnr.mean()), "psnr_min": float(psnr.min()),
            "mean_abs": float(np.mean([r["mean_abs"] for r in rows]))}


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", default=",".join(TASKS))
    ap.add_argument("--seeds", default="10:13", help="start:stop (one world each)")
    ap.add_argument("--at", default="0,40,80", help="the control steps whose images are compared")
    ap.add_argument("--cameras", default="corner,gripperPOV")
    ap.add_argument("--image", type=int, default=128)
    ap.add_argument("--device", default=None, help="a Warp device (cpu, cuda:0); default Warp's preferred one")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args(argv)
    if args.out.exists() and not args.overwrite:
        print(f"{args.out} exists; pass --overwrite to replace it", file=sys.stderr)
        return 2
    from simseam.backends.metaworld_gpu.worker import NativeWorker

    lo, hi = (int(x) for x in args.seeds.split(":"))
    seeds, at = list(range(lo, hi)), [int(x) for x in args.at.split(",")]
    tasks, cameras = args.tasks.split(","), args.cameras.split(",")
    doc: dict[str, Any] = {"benchmark": "metaworld_warp_cameras", "argv": sys.argv[1:] if argv is None else argv,
                           "machine": _machine(args.device), "seeds": seeds, "at": at, "cameras": cameras,
                           "image": args.image, "tasks": {}}
    t0 = time.perf_counter()
    with NativeWorker() as worker:
        for task in tasks:
            got = compare_task(worker, task, seeds, at, cameras, args.image, args.device)
            doc["tasks"][task] = {key: {"camera": cameras[int(key[6:]) - 1], **summarize(rows), "samples": rows}
                                  for key, rows in got["samples"].items()}
            _save(doc, args.out)
    every: dict[str, list] = {}
    for row in doc["tasks"].values():
        for key, r in row.items():
            every.setdefault(key, []).extend(r["samples"])
    doc["cameras_overall"] = {key: {"camera": cameras[int(key[6:]) - 1], **summarize(rows)}
                              for key, rows in every.items()}
    doc["seconds"] = time.perf_counter() - t0
    _save(doc, args.out)
    print_table(doc)
    print(f"wrote {args.out}")
    return 0


def print_table(doc: dict[str, Any]) -> None:
    print(f"\n{'task':26s} {'camera':12s} {'images':>6s} {'SSIM mean':>9s} {'min':>6s} {'PSNR mean':>9s} "
          f"{'min':>6s} {'|diff|':>7s}")
    rows = [(t, r) for t, cams in doc["tasks"].items() for r in cams.values()]
    rows += [("all", r) for r in doc["cameras_overall"].values()]
    for task, r in rows:
        print(f"{task:26s} {r['camera']:12s} {r['images']:6d} {r['ssim_mean']:9.3f} {r['ssim_min']:6.3f} "
              f"{r['psnr_mean']:9.2f} {r['psnr_min']:6.2f} {r['mean_abs']:7.2f}")


def _machine(device: str | None) -> dict[str, Any]:
    import os

    import mujoco
    import skimage
    import warp as wp

    wp.config.quiet = True
    wp.init()
    dev = wp.get_device(device) if device else wp.get_preferred_device()
    return {"python": platform.python_version(), "mujoco": mujoco.__version__, "warp": wp.config.version,
            "device": str(dev), "device_name": dev.name, "scikit_image": skimage.__version__,
            "mujoco_gl": os.environ.get("MUJOCO_GL", "egl")}


def _save(doc: dict[str, Any], out: Path) -> None:
    out.parent.mkdir(parents=True, exist_ok=True)
    tmp = out.with_suffix(".partial")
    tmp.write_text(json.dumps(doc, indent=1) + "\n")
    tmp.replace(out)


def _host(a: Any) -> np.ndarray:
    return a.get() if hasattr(a, "get") else np.asarray(a)


if __name__ == "__main__":
    sys.exit(main())
