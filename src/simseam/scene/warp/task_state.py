"""The batched task code's view of a ``BatchedScene`` (``simseam.scene.tasks.batch.TaskState``).

Every read is a view of the worlds' device memory, made once when the scene is built: NumPy on
Warp's CPU device (``wp.array.numpy()`` shares the memory), CuPy on a CUDA device (DLPack), with
CuPy's work ordered on Warp's stream (``array_stream``), so task code runs between two Warp launches
with no copy and no synchronisation. Contacts are the one read that computes: a pair's flags are
gathered from the step's contact list by ``contact_pair_kernel`` when a task first asks for them.
"""

from __future__ import annotations

import contextlib

import numpy as np
import warp as wp

from simseam.engines.mujoco_warp import kernels as K
from simseam.scene.tasks.batch import matrix_to_quat, quat_to_matrix
from simseam.seam import BackendUnavailableError, ConfigError


def array_module(device):
    """The array namespace task code runs with on ``device``: NumPy on the CPU, CuPy on CUDA."""
    if not device.is_cuda:
        return np
    try:
        import cupy
    except ImportError as exc:
        raise BackendUnavailableError(
            "engine 'mujoco_warp' on a CUDA device runs the tasks' batched code with CuPy: "
            f"pip install cupy-cuda12x (or the build for your CUDA) ({exc})") from None
    return cupy


def array_view(xp, arr):
    """``arr`` (a warp array) as an array of ``xp`` sharing its memory (vector and matrix element types
    become trailing axes)."""
    if xp is np:
        return arr.numpy()
    return xp.from_dlpack(arr)


def array_stream(xp, device):
    """A context in which ``xp``'s arrays live on ``device`` (whichever GPU it is) and its work runs on
    Warp's stream there, in order with Warp's launches (no-op for NumPy)."""
    if xp is np:
        return contextlib.nullcontext()
    stack = contextlib.ExitStack()
    stack.enter_context(xp.cuda.Device(device.ordinal))
    stack.enter_context(xp.cuda.ExternalStream(wp.get_stream(device).cuda_stream))
    return stack


class WarpTaskState:
    """``TaskState`` of the worlds of a ``BatchedScene`` (see the module docstring)."""

    def __init__(self, scene):
        self.xp = xp = scene.xp
        self.num_worlds = n = scene.num_envs
        self.params: dict = {}
        self._scene = scene
        d = scene.d
        self._xpos, self._xquat, self._xmat = (array_view(xp, a) for a in (d.xpos, d.xquat, d.xmat))
        self._qvel = array_view(xp, d.qvel)
        self._eef_world, self._eef_pos, self._eef_rot = (
            array_view(xp, a) for a in (scene.eef_world, scene.eef_pos, scene.eef_rot))
        layout = scene.host.engine.layout
        self._body, self._vadr, self._owner = layout.object_body, layout.object_vadr, layout.owner_code
        base_pos, base_rot = scene.host.base_frame()
        self._base_pos = xp.asarray(base_pos, dtype=xp.float32)
        self._base_rot_t = xp.asarray(base_rot.T, dtype=xp.float32)
        yaw = float(np.arctan2(base_rot[1, 0], base_rot[0, 0]))
        self._base_pose = xp.asarray(np.tile([base_pos[0], base_pos[1], yaw], (n, 1)), dtype=xp.float32)
        self._pairs: dict[tuple[int, int], tuple] = {}
        self._fresh: set = set()
        self._all = wp.ones(n, dtype=int, device=scene.device)

    def new_step(self) -> None:
        """The physics moved: contact flags are gathered again when next asked for."""
        self._fresh.clear()

    def _body_of(self, name: str) -> int:
        try:
            return self._body[name]
        except KeyError:
            raise ConfigError(f"unknown object {name!r}; objects: {', '.join(self._body)}") from None

    def object_pos(self, name: str):
        return self._xpos[:, self._body_of(name)]

    def object_quat(self, name: str):
        return self._xquat[:, self._body_of(name)]

    def object_velocity(self, name: str):
        """Linear and angular velocity in the world frame (a free joint's angular part is in the body frame)."""
        b = self._body_of(name)
        v = self._vadr.get(name)
        if v is None:
            return self.xp.zeros((self.num_worlds, 6), dtype=self.xp.float32)
        lin, ang = self._qvel[:, v:v + 3], self._qvel[:, v + 3:v + 6]
        return self.xp.concatenate([lin, self.xp.einsum("nij,nj->ni", self._xmat[:, b], ang)], axis=-1)

    def contacts(self, a: str, b: str, where=None):
        try:
            ca, cb = self._owner[a], self._owner[b]
        except KeyError as exc:
            raise ConfigError(f"contacts: unknown name {exc.args[0]!r}; names: {', '.join(self._owner)}") from None
        key = (min(ca, cb), max(ca, cb))
        flags, view = self._pairs.get(key) or self._pairs.setdefault(key, self._new_pair())
        if key not in self._fresh:
            self._fresh.add(key)
            d, scene = self._scene.d, self._scene
            flags.zero_()
            wp.launch(K.contact_pair_kernel, dim=d.naconmax, device=scene.device, inputs=[
                d.nacon, d.contact.geom, d.contact.worldid, scene.geom_owner, ca, cb, self._all, flags])
        touching = view != 0
        return touching if where is None else touching & where

    def _new_pair(self):
        flags = wp.zeros(self.num_worlds, dtype=int, device=self._scene.device)
        return flags, array_view(self.xp, flags)

    def eef_position_world(self):
        return self._eef_world

    def eef_pose_base(self):
        return self._eef_pos, self._eef_rot

    def base_pose(self):
        return self._base_pose

    def to_base(self, pos, quat):
        xp = self.xp
        p = xp.einsum("ij,nj->ni", self._base_rot_t, pos - self._base_pos)
        r = xp.matmul(self._base_rot_t, quat_to_matrix(xp, quat))
        return xp.concatenate([p, matrix_to_quat(xp, r)], axis=-1)
