"""robosuite's observables for N worlds of a LIBERO batch: when they sample (``Clock``) and, on MuJoCo Warp, the
sampling itself as a device launch (``Sampler``), so that a whole control step can be one captured CUDA graph.

robosuite updates its observables after every physics step; each samples when its clock says (``Clock``, per
world). The clock depends on time alone, never on the state, so a control step's sampling substeps are known
before the step runs (``Clock.ahead``). ``Sampler.launch(d, k)`` copies, for the worlds whose clock samples after
substep ``k``, what the observables read of MuJoCo Warp's data then (the end-effector site's position, the
``eef_body``'s quaternion, qpos, qvel, each object's root body pose) into the batch's observation buffers: the same
values ``env.LiberoBatch._observe`` copies on the host after that substep, with no host round trip between the
substeps. ``ImageSampler.launch(m, d, k)`` does the same for the cameras (MuJoCo Warp's ray tracer): every world
drawn, the sampling worlds' images kept, mirrored left-right as ``_observe`` keeps them; launched only after the
substeps where some world samples.
"""

from __future__ import annotations

from typing import Any

import numpy as np
import warp as wp

wp.set_module_options({"enable_backward": False})

#: the observation buffers a ``Sampler`` writes (``LiberoBatch.observed``'s state keys)
KEYS = ("eef_pos", "eef_quat", "qpos", "qvel", "obj_pos", "obj_quat")


class Clock:
    """robosuite's ``Observable.update`` clock, per world (host float64, the same arithmetic): after each physics
    step ``t += dt``; an observable that has not sampled this period samples while ``t <= period`` (no delay), or
    late once ``t >= period``, which then wraps ``t`` (``t %= period``) and starts a new period."""

    def __init__(self, n: int, dt: float):
        self.dt = dt
        self.t, self.sampled, self.period = np.zeros(n), np.zeros(n, dtype=bool), np.full(n, np.inf)

    def set(self, rows: np.ndarray, clocks: list[dict[str, Any]]) -> None:
        self.t[rows] = [c["t"] for c in clocks]
        self.sampled[rows] = [c["sampled"] for c in clocks]
        self.period[rows] = [c["period"] for c in clocks]

    def copy(self) -> "Clock":
        out = Clock(0, self.dt)
        out.t, out.sampled, out.period = self.t.copy(), self.sampled.copy(), self.period.copy()
        return out

    def put(self, rows: np.ndarray, other: "Clock") -> None:
        """``rows`` as ``other`` holds them."""
        self.t[rows], self.sampled[rows], self.period[rows] = other.t[rows], other.sampled[rows], other.period[rows]

    def tick(self) -> np.ndarray:
        """One physics step: bool[N], the worlds whose observables sample after it."""
        self.t += self.dt
        now = ~self.sampled & (self.period >= self.t)
        self.sampled |= now
        wrap = self.t >= self.period
        now |= wrap & ~self.sampled
        self.t[wrap] %= self.period[wrap]
        self.sampled[wrap] = False
        return now

    def ahead(self, substeps: int) -> np.ndarray:
        """``substeps`` physics steps at once: bool[substeps, N], row k the worlds that sample after step k."""
        return np.stack([self.tick() for _ in range(int(substeps))]) if substeps else np.zeros((0, len(self.t)), bool)


@wp.kernel
def sample_kernel(mask: wp.array2d(dtype=wp.int32), k: int, site: int, body: int, bodies: wp.array(dtype=wp.int32),
                  site_xpos: wp.array2d(dtype=wp.vec3), xpos: wp.array2d(dtype=wp.vec3),
                  xquat: wp.array2d(dtype=wp.quat), qpos: wp.array2d(dtype=float), qvel: wp.array2d(dtype=float),
                  eef_pos: wp.array2d(dtype=float), eef_quat: wp.array2d(dtype=float),
                  out_qpos: wp.array2d(dtype=float), out_qvel: wp.array2d(dtype=float),
                  obj_pos: wp.array3d(dtype=float), obj_quat: wp.array3d(dtype=float)):
    """World ``i``'s observables, if its clock samples after substep ``k`` (``mask[k, i]``)."""
    i = wp.tid()
    if mask[k, i] == 0:
        return
    p = site_xpos[i, site]
    q = xquat[i, body]
    for a in range(3):
        eef_pos[i, a] = p[a]
    for a in range(4):
        eef_quat[i, a] = q[a]
    for j in range(qpos.shape[1]):
        out_qpos[i, j] = qpos[i, j]
    for j in range(qvel.shape[1]):
        out_qvel[i, j] = qvel[i, j]
    for o in range(bodies.shape[0]):
        b = bodies[o]
        bp = xpos[i, b]
        bq = xquat[i, b]
        for a in range(3):
            obj_pos[i, o, a] = bp[a]
        for a in range(4):
            obj_quat[i, o, a] = bq[a]


def _alias(key: str, a: Any, device: Any, dtype: Any = np.float32) -> Any:
    """The batch's buffer ``key``, an ``xp`` array of ``dtype`` (contiguous: a ``TypeError`` otherwise), as a Warp
    array sharing its memory."""
    if a.dtype != dtype or not a.flags.c_contiguous:
        raise TypeError(f"the observation buffer {key!r} must be contiguous {np.dtype(dtype)}, not {a.dtype}")
    if device.is_cuda:
        return wp.from_dlpack(a)
    return wp.array(a, dtype=wp.dtype_from_numpy(np.dtype(dtype)), device="cpu", copy=False)


class Sampler:
    """``sample_kernel`` for the worlds of ``physics`` (a ``worlds.LiberoWorlds``) into ``observed`` (the batch's
    float32 state buffers, ``KEYS``, written in place: a captured graph holds their addresses): ``load(masks)``
    before a control step (``Clock.ahead``'s rows), then ``launch(d, k)`` after each substep ``k``."""

    def __init__(self, physics: Any, observed: dict[str, Any], site: int, body: int, bodies: list[int],
                 substeps: int):
        self.n, self.device = physics.num_worlds, physics.device
        self.out = [_alias(k, observed[k], self.device) for k in KEYS]
        self.site, self.body = int(site), int(body)
        self.bodies = wp.array(np.asarray(bodies, dtype=np.int32), dtype=wp.int32, device=self.device)
        self.mask = wp.zeros((int(substeps), self.n), dtype=wp.int32, device=self.device)

    def load(self, masks: np.ndarray) -> None:
        """Which worlds sample after which substep (bool[substeps, N]), into the buffer the launches read."""
        self.mask.assign(np.ascontiguousarray(masks, dtype=np.int32))

    def launch(self, d: Any, k: int) -> None:
        wp.launch(sample_kernel, dim=self.n, device=self.device,
                  inputs=[self.mask, int(k), self.site, self.body, self.bodies, d.site_xpos, d.xpos, d.xquat, d.qpos,
                          d.qvel, *self.out])


class ImageSampler:
    """The cameras' share of a ``Sampler``: ``cameras`` (an ``engines.mujoco_warp.cameras.WarpCameras`` of the
    batch's worlds) drawn into ``images`` (feature key -> the batch's ``xp`` uint8[N, H, W, 3] buffer, written in
    place) for the worlds ``sampler``'s mask says, mirrored left-right (as robosuite's images reach the CPU
    backend). ``launch(m, d, k)`` after a substep ``k`` where some world samples."""

    def __init__(self, cameras: Any, images: dict[str, Any], sampler: Sampler):
        self.cameras, self.sampler = cameras, sampler
        self.out = {key: _alias(key, a, sampler.device, np.uint8) for key, a in images.items()}

    def launch(self, m: Any, d: Any, k: int) -> None:
        self.cameras.cast(m, d)
        self.cameras.unpack_rows(self.out, self.sampler.mask, k, mirror=True)
