"""Headless MuJoCo camera rendering (EGL or OSMesa, chosen by ``MUJOCO_GL``).

One ``mujoco.Renderer`` per image size, created lazily, so cameras that are
never observed cost nothing. "lean" quality turns off shadows, reflections,
the skybox and MSAA (20-30x faster on a CPU rasterizer); "full" keeps them.
"""

from __future__ import annotations

import importlib.util
import os
import sys

import mujoco
import numpy as np

from simseam.engines.base import CameraModel
from simseam.seam import BackendUnavailableError, ConfigError

_GL_HINT = (
    "headless rendering needs EGL or OSMesa: on Debian `apt-get install libegl1 libgl1 libegl-mesa0 libosmesa6`, "
    "then set MUJOCO_GL=egl (default) or MUJOCO_GL=osmesa"
)


def _load_triton_before_mesa() -> None:
    """Import Triton (when installed, i.e. beside PyTorch) before the first GL context.

    Mesa's llvmpipe/OSMesa rasterizers load their own LLVM; loading Triton's
    libtriton (which PyTorch, torchvision and LeRobot import) *after* that
    segfaults the process. Importing it first avoids the clash. No-op when Triton
    is absent or already imported; ``SIMSEAM_NO_TRITON_PRELOAD=1`` turns it off.
    """
    if "triton" in sys.modules or os.environ.get("SIMSEAM_NO_TRITON_PRELOAD") == "1":
        return
    if importlib.util.find_spec("triton") is None:
        return
    try:
        import triton  # noqa: F401
    except Exception:  # a broken Triton install must not stop rendering  # noqa: BLE001
        pass


class CameraRenderer:
    """Renders the named cameras of a compiled model."""

    def __init__(self, model: "mujoco.MjModel", cameras: dict[str, CameraModel], quality: str):
        self._model = model
        self._cameras = cameras
        self._full = quality == "full"
        self._rgb: dict[tuple[int, int], mujoco.Renderer] = {}
        self._depth: dict[tuple[int, int], mujoco.Renderer] = {}
        self._cam_ids = {name: model.camera(f"cam:{name}").id for name in cameras}
        self._mjv_cams = {}
        for cid in self._cam_ids.values():
            cam = self._mjv_cams[cid] = mujoco.MjvCamera()
            cam.type, cam.fixedcamid = mujoco.mjtCamera.mjCAMERA_FIXED, cid
        self._opt = mujoco.MjvOption()
        self._opt.geomgroup[:] = 0
        self._opt.geomgroup[0] = self._opt.geomgroup[1] = self._opt.geomgroup[2] = 1

    def _make(self, size: tuple[int, int], depth: bool) -> "mujoco.Renderer":
        _load_triton_before_mesa()
        try:
            r = mujoco.Renderer(self._model, height=size[0], width=size[1])
        except Exception as exc:  # GL context creation errors vary by backend
            raise BackendUnavailableError(
                f"cannot create a MuJoCo renderer with MUJOCO_GL={os.environ.get('MUJOCO_GL')!r}: {exc}; {_GL_HINT}"
            ) from None
        flags = r.scene.flags
        flags[mujoco.mjtRndFlag.mjRND_SHADOW] = self._full
        flags[mujoco.mjtRndFlag.mjRND_REFLECTION] = self._full
        flags[mujoco.mjtRndFlag.mjRND_SKYBOX] = self._full
        if depth:
            r.enable_depth_rendering()
        return r

    def _get(self, camera: str, depth: bool) -> tuple["mujoco.Renderer", int]:
        try:
            cam = self._cameras[camera]
        except KeyError:
            raise ConfigError(f"unknown camera {camera!r}; cameras: {', '.join(self._cameras) or 'none'}") from None
        pool = self._depth if depth else self._rgb
        size = (cam.height, cam.width)
        if size not in pool:
            pool[size] = self._make(size, depth)
        return pool[size], self._cam_ids[camera]

    def _update(self, r: "mujoco.Renderer", data: "mujoco.MjData", cid: int) -> None:
        # mjv_updateScene places the headlight from the scene's camera *before* it updates that
        # camera: without this the headlight sits where the previous frame's camera was, so a
        # renderer's first frame, or a frame after another camera, differs from a repeat render
        # of the same state (the same seed must give the same images).
        cam = self._mjv_cams[cid]
        mujoco.mjv_updateCamera(self._model, data, cam, r.scene)
        r.update_scene(data, camera=cam, scene_option=self._opt)

    def rgb(self, data: "mujoco.MjData", camera: str) -> np.ndarray:
        r, cid = self._get(camera, depth=False)
        self._update(r, data, cid)
        return r.render()

    def depth(self, data: "mujoco.MjData", camera: str) -> np.ndarray:
        r, cid = self._get(camera, depth=True)
        self._update(r, data, cid)
        return r.render().astype(np.float32, copy=False)

    def close(self) -> None:
        for r in [*self._rgb.values(), *self._depth.values()]:
            r.close()
        self._rgb.clear()
        self._depth.clear()
