"""RGB cameras of N MuJoCo Warp worlds, rendered at once by MuJoCo Warp's ray tracer: the one place a render
context is made and its packed pixels are unpacked into images.

``WarpCameras(mjm, nworld, cameras, device=..., groups=..., **options)``: ``cameras`` is a list of
``(mujoco camera name, feature key, (H, W))``; ``options`` are ``mujoco_warp.create_render_context``'s
(``use_textures``, ``render_skybox``, ``use_shadows``, ...). ``render(m, d)`` runs the camera and light
poses (``camlight``), the refit of the scene BVH over every world's geoms (``refit_bvh``), the ray casting
(``render``) and the unpack into ``images``: device ``uint8[N, H, W, 3]`` per feature key, row 0 the top
of the image (as MuJoCo's ``Renderer`` returns it). ``render`` only launches device work, so a caller may
capture it in a CUDA graph (the batched scene does). Users: the batched manifest scene
(``simseam.scene.warp``), the pose renderer, Meta-World on MuJoCo Warp, ``benchmarks/bench_warp_render.py``.
"""

from __future__ import annotations

from typing import Any, Sequence

import mujoco_warp as mjw
import warp as wp

from simseam.engines.mujoco_warp import kernels as K
from simseam.seam import ConfigError


class WarpCameras:
    """The cameras of ``nworld`` worlds of one model (see the module's doc)."""

    def __init__(self, mjm: Any, nworld: int, cameras: Sequence[tuple[str, str, tuple[int, int]]], *,
                 device: Any = None, groups: Sequence[int] = (0, 1, 2), **options: Any):
        if not cameras:
            raise ConfigError("WarpCameras: no cameras to render")
        known = {mjm.camera(i).name for i in range(mjm.ncam)}
        missing = [name for name, _, _ in cameras if name not in known]
        if missing:
            raise ConfigError(f"WarpCameras: the model has no camera {missing[0]!r}; it has {sorted(known)}")
        self.device = wp.get_device(device)
        self.num_worlds = int(nworld)
        self.sizes = {key: (int(h), int(w)) for _, key, (h, w) in cameras}
        res = [(int(w), int(h)) for _, _, (h, w) in cameras]
        with wp.ScopedDevice(self.device):
            self.rc = mjw.create_render_context(mjm, nworld=self.num_worlds, cam_res=res, render_rgb=True,
                                                render_depth=False, cam_active=[name for name, _, _ in cameras],
                                                enabled_geom_groups=list(groups), **options)
            self.images = {key: wp.zeros((self.num_worlds, h, w, 3), dtype=wp.uint8)
                           for key, (h, w) in self.sizes.items()}
        adr = self.rc.rgb_adr.numpy()
        self._adr = [(key, int(adr[i]), res[i][0]) for i, (_, key, _) in enumerate(cameras)]

    def cast(self, m: Any, d: Any) -> None:
        """Camera and light poses, the BVH refit and the ray casting (the packed pixels in ``rc.rgb_data``)."""
        mjw.camlight(m, d)
        mjw.refit_bvh(m, d, self.rc)
        mjw.render(m, d, self.rc)

    def unpack(self) -> dict[str, Any]:
        """The last cast's packed pixels into ``images`` (device uint8[N, H, W, 3] per key)."""
        for key, adr, width in self._adr:
            out = self.images[key]
            wp.launch(K.unpack_rgb_u8_kernel, dim=(self.num_worlds, out.shape[1] * out.shape[2]),
                      inputs=[self.rc.rgb_data, adr, width, out], device=self.device)
        return self.images

    def render(self, m: Any, d: Any) -> dict[str, Any]:
        """Every camera of every world from the state in ``d``: ``cast`` then ``unpack``."""
        with wp.ScopedDevice(self.device):
            self.cast(m, d)
            return self.unpack()
