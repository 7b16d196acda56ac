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

Sites: MuJoCo's OpenGL renderer draws every site of a visible group (0-2) whose alpha is not zero (a goal
marker); MuJoCo Warp's ray tracer draws geoms only. ``with_site_geoms(spec, mjm)`` compiles a render model:
the model's geoms, then one visual-only geom per drawn site (its type, size and colour), appended to the
last body so the model's own geoms keep their indices; ``WarpCameras(..., render_model=(model, sites))``
then renders from it, each geom posed as the physics state has it and each site geom where its site is.
"""

from __future__ import annotations

from typing import Any, Sequence

import mujoco_warp as mjw
import numpy as np
import warp as wp

from simseam.engines.mujoco_warp import kernels as K
from simseam.seam import ConfigError


def drawn_sites(mjm: Any, groups: Sequence[int] = (0, 1, 2)) -> np.ndarray:
    """The sites MuJoCo's OpenGL renderer draws by default: a visible group, a colour not fully transparent."""
    return np.flatnonzero(np.isin(mjm.site_group, list(groups)) & (mjm.site_rgba[:, 3] > 0)).astype(np.int64)


def with_site_geoms(spec: Any, mjm: Any, groups: Sequence[int] = (0, 1, 2)) -> tuple[Any, np.ndarray]:
    """``(render model, sites)``: ``spec`` (an ``MjSpec`` that compiles to ``mjm``'s geoms) compiled with one
    visual-only geom per site of ``drawn_sites(mjm)``, appended after every geom of the model; raises
    ``ConfigError`` if the model's own geoms do not keep their indices."""
    import mujoco

    sites = drawn_sites(mjm, groups)
    last = spec.bodies[-1]
    for s in sites.tolist():
        g = last.add_geom()
        g.type, g.size, g.rgba = mujoco.mjtGeom(int(mjm.site_type[s])), mjm.site_size[s], mjm.site_rgba[s]
        g.contype = g.conaffinity = 0
        g.group = int(mjm.site_group[s])
    render = spec.compile()
    n = mjm.ngeom
    if (render.ngeom != n + sites.size or not np.array_equal(render.geom_bodyid[:n], mjm.geom_bodyid)
            or not np.array_equal(render.geom_type[:n], mjm.geom_type)):
        raise ConfigError("with_site_geoms: the render model's geoms do not extend the model's")
    return render, sites


class WarpCameras:
    """The cameras of ``nworld`` worlds of one model (see the module's doc)."""

    def __init__(self, mjm: Any, nworld: int, cameras: Sequence[tuple[str, str, tuple[int, int]]], *,
                 device: Any = None, groups: Sequence[int] = (0, 1, 2), render_model: tuple[Any, Any] | None = None,
                 **options: Any):
        self._mirror = None
        if render_model is not None:  # draw from a model with the sites as geoms (with_site_geoms)
            self._mirror = _SiteGeoms(mjm, nworld, *render_model, device)
            mjm = render_model[0]
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
        if self._mirror is not None:
            m, d = self._mirror.pose(d)
        mjw.refit_bvh(m, d, self.rc)
        mjw.render(m, d, self.rc)

    def unpack(self) -> dict[str, Any]:
        """The last cast's packed pixels into ``images`` (device uint8[N, H, W, 3] per key)."""
        for key, adr, width in self._adr:
            out = self.images[key]
            wp.launch(K.unpack_rgb_u8_kernel, dim=(self.num_worlds, out.shape[1] * out.shape[2]),
                      inputs=[self.rc.rgb_data, adr, width, out], device=self.device)
        return self.images

    def unpack_rows(self, out: dict[str, Any], mask: Any, k: int, mirror: bool = False) -> None:
        """The last cast's pixels into ``out`` (a Warp uint8[N, H, W, 3] per feature key) for the worlds whose
        ``mask[k]`` (Warp int32[K, N]) is set, the others' images left as they are; ``mirror``: left-right.
        Device launches only (a captured graph may hold them)."""
        for key, adr, width in self._adr:
            dst = out[key]
            wp.launch(K.unpack_rgb_u8_rows_kernel, dim=(self.num_worlds, dst.shape[1] * dst.shape[2]),
                      inputs=[self.rc.rgb_data, adr, width, mask, int(k), int(mirror), dst], device=self.device)

    def render(self, m: Any, d: Any) -> dict[str, Any]:
        """Every camera of every world from the state in ``d``: ``cast`` then ``unpack``."""
        with wp.ScopedDevice(self.device):
            self.cast(m, d)
            return self.unpack()


class _SiteGeoms:
    """The render model's device copy and a small Data posed from the physics state: its geoms where the
    physics has them, its site geoms where their sites are, the cameras and lights as the physics posed them."""

    def __init__(self, mjm: Any, nworld: int, render_mjm: Any, sites: np.ndarray, device: Any):
        self.ngeom, self.nworld = int(mjm.ngeom), int(nworld)
        with wp.ScopedDevice(wp.get_device(device)):
            self.m = mjw.put_model(render_mjm)
            self.d = mjw.make_data(render_mjm, nworld=self.nworld, nconmax=1, njmax=1)
            self.sites = wp.array(np.asarray(sites, dtype=np.int32), dtype=int)

    def pose(self, d: Any) -> tuple[Any, Any]:
        r = self.d
        wp.launch(K.site_geoms_kernel, dim=(self.nworld, r.geom_xpos.shape[1]),
                  inputs=[d.geom_xpos, d.geom_xmat, d.site_xpos, d.site_xmat, self.sites, self.ngeom],
                  outputs=[r.geom_xpos, r.geom_xmat])
        for key in ("cam_xpos", "cam_xmat", "light_xpos", "light_xdir"):
            wp.copy(getattr(r, key), getattr(d, key))
        return self.m, r
