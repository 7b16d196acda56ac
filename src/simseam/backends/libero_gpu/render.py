"""``render: opengl``: MuJoCo's OpenGL renderer drawing the worlds' states as robosuite draws LIBERO's cameras, on
the host (EGL without a display: ``MUJOCO_GL=egl``).

robosuite's offscreen render (``MjRenderContextOffscreen.render``): a scene of at most 1,000 geoms, the default
``MjvOption`` but for geom group 0 (the collision geoms) turned off, the fixed camera, ``mjv_updateScene`` with every
category, ``mjr_render``, ``mjr_readPixels``. Here ``mujoco.Renderer`` does the same for the task's model as
compiled from robosuite's XML (the same textures, materials and lights) and each world's data as the physics left
it (``mujoco_warp.get_data_into``: the poses robosuite's renderer would read, stale by the last integration as
``mj_step`` leaves them). Images are returned as MuJoCo's renderer returns them (row 0 the top); the batch turns
them as the CPU backend does.
"""

from __future__ import annotations

import copy
from typing import Any, Sequence

import numpy as np

MAX_GEOM = 1000  # robosuite's MjvScene


class OpenGLCameras:
    """``OpenGLCameras(mjm, cameras)``; ``draw(data)`` -> {key: uint8[H, W, 3]} of one ``MjData`` of ``self.mjm``
    (a copy of ``mjm``); ``render(physics, rows)`` -> {key: uint8[k, H, W, 3]} of MuJoCo Warp worlds ``rows``."""

    def __init__(self, mjm: Any, cameras: Sequence[tuple[str, str, tuple[int, int]]]):
        import mujoco

        self._mj, self.mjm, self.cameras = mujoco, copy.deepcopy(mjm), list(cameras)  # its fields move per world
        mjm = self.mjm
        self.option = mujoco.MjvOption()
        self.option.geomgroup[0] = 0
        self.data = mujoco.MjData(mjm)
        self._renderers: dict[tuple[int, int], Any] = {}
        for _, _, (h, w) in self.cameras:
            if (h, w) not in self._renderers:
                self._renderers[(h, w)] = mujoco.Renderer(mjm, int(h), int(w), max_geom=MAX_GEOM)

    def draw(self, data: Any) -> dict[str, np.ndarray]:
        out = {}
        for name, key, size in self.cameras:
            r = self._renderers[tuple(size)]
            r.update_scene(data, camera=name, scene_option=self.option)
            out[key] = r.render().copy()
        return out

    def render(self, physics: Any, rows: np.ndarray) -> dict[str, np.ndarray]:
        """Worlds ``rows`` of ``physics`` (a ``worlds.LiberoWorlds``): each world's own model fields (its fixtures'
        poses) set into this renderer's copy of the model, then its data."""
        import mujoco_warp as mjw

        drawn = []
        fields = {k: physics.view(getattr(physics.m, k)) for k in physics.batched}
        for w in np.asarray(rows).tolist():
            for key, value in fields.items():
                getattr(self.mjm, key)[...] = _host(value[w])
            mjw.get_data_into(self.data, self.mjm, physics.d, world_id=int(w))
            drawn.append(self.draw(self.data))
        return {key: np.stack([x[key] for x in drawn]) for _, key, _ in self.cameras}

    def close(self) -> None:
        for r in self._renderers.values():
            r.close()
        self._renderers = {}


def _host(a: Any) -> np.ndarray:
    return a.get() if hasattr(a, "get") else np.asarray(a)
