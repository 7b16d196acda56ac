"""A task written once for N worlds: what it reads (``TaskState``) and what it returns (``BatchEvaluation``).

A task's reset draws (``Task.sample``), reward, success, diagnostics and ground-truth extras are one
definition over a batched physics state, one row per world. The same code runs

- on the CPU engine (``ManifestScene``): N = 1, NumPy arrays;
- on MuJoCo Warp (``simseam.scene.warp``): N worlds; NumPy views of Warp's CPU device, or CuPy views of
  a CUDA device's memory (DLPack, no copy) ordered on Warp's stream.

So task code is written against the NumPy API with the namespace it is handed (``state.xp``): arithmetic
and comparisons, ``xp.where``, ``xp.sqrt``, ``xp.abs``, ``xp.arctan2``, ``xp.arccos``, ``xp.sin``,
``xp.cos``, ``xp.clip``, ``xp.minimum`` / ``xp.maximum``, ``xp.sum`` / ``xp.any`` / ``xp.all`` with
``axis`` (and ``norm`` below), ``xp.einsum``, ``xp.matmul``, ``xp.stack`` /
``xp.concatenate``, slicing. NumPy and CuPy both implement that subset; nothing else is assumed. A task
never branches on the engine or on N, and never converts to Python scalars (that would force a device
sync per world).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Protocol

import numpy as np


@dataclass(slots=True)
class BatchEvaluation:
    """A task's judgement of N worlds after a control step: ``reward`` float[N] (or bool[N] for a sparse
    reward: 1.0 where True), ``success`` bool[N] and,
    for each name in ``Task.diagnostics``, a float or bool array [N] (SI units), all of ``state.xp``."""

    reward: Any
    success: Any
    diagnostics: dict[str, Any] = field(default_factory=dict)


@dataclass(slots=True)
class Draw:
    """A task's random choices for one episode, from the episode's generator (``Task.sample``):
    ``poses``: each prop it places, ``name -> (position[3] world, quaternion wxyz[4])``;
    ``params``: the episode's other choices (a target, a goal, which props take part), each an array
    whose leading axis is added per world (``params[k][w]`` is world ``w``'s)."""

    poses: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    params: dict[str, np.ndarray] = field(default_factory=dict)


class TaskState(Protocol):
    """What a task may read of N worlds, one row per world, as arrays of ``xp`` (world frame unless said).

    ``params``: the episode's draws stacked per world (``Draw.params``; a task may replace an entry to
    carry something over steps, e.g. a touch that cannot be undone)."""

    xp: Any
    num_worlds: int
    params: dict[str, Any]

    def object_pos(self, name: str) -> Any:
        """float[N, 3]: the prop's position."""

    def object_quat(self, name: str) -> Any:
        """float[N, 4]: the prop's orientation, wxyz."""

    def object_velocity(self, name: str) -> Any:
        """float[N, 6]: the prop's linear then angular velocity (world frame); zeros for a static prop."""

    def contacts(self, a: str, b: str, where: Any = None) -> Any:
        """bool[N]: whether ``a`` and ``b`` (prop names, or ``robot``) touch; with ``where`` (bool[N]) only
        those worlds need an answer (the others give False), which lets an engine skip its collision pass."""

    def eef_position_world(self) -> Any:
        """float[N, 3]: the measured tool position."""

    def eef_pose_base(self) -> tuple[Any, Any]:
        """(float[N, 3], float[N, 3, 3]): the measured tool pose in the robot base frame."""

    def base_pose(self) -> Any:
        """float[N, 3]: the base link's [x, y, yaw] in the world."""

    def to_base(self, pos: Any, quat: Any) -> Any:
        """float[N, 7]: world poses (float[N, 3], wxyz float[N, 4]) as base-frame [x y z qw qx qy qz]."""


# ------------------------------------------------------------------------------------------ batched math
def norm(xp, v):
    """float[...]: the Euclidean norm over the last axis (cheaper than ``xp.linalg.norm`` on NumPy's
    small arrays, where the CPU engine's single world pays per call)."""
    return xp.sqrt((v * v).sum(axis=-1))


def quat_to_matrix(xp, q):
    """wxyz float[N, 4] -> float[N, 3, 3] (unit quaternions)."""
    w, x, y, z = q[..., 0], q[..., 1], q[..., 2], q[..., 3]
    rows = [1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y),
            2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x),
            2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]
    return xp.stack(rows, axis=-1).reshape(q.shape[:-1] + (3, 3))


def matrix_to_quat(xp, m):
    """float[N, 3, 3] -> wxyz float[N, 4], w >= 0 (``math3d.matrix_to_quat``, every branch evaluated and
    the right one selected per row: no per-world control flow)."""
    m00, m11, m22 = m[..., 0, 0], m[..., 1, 1], m[..., 2, 2]
    t = m00 + m11 + m22
    cands = []
    s = 2.0 * xp.sqrt(xp.maximum(t + 1.0, 1e-12))
    cands.append((0.25 * s, (m[..., 2, 1] - m[..., 1, 2]) / s, (m[..., 0, 2] - m[..., 2, 0]) / s,
                  (m[..., 1, 0] - m[..., 0, 1]) / s))
    s = 2.0 * xp.sqrt(xp.maximum(1.0 + m00 - m11 - m22, 1e-12))
    cands.append(((m[..., 2, 1] - m[..., 1, 2]) / s, 0.25 * s, (m[..., 0, 1] + m[..., 1, 0]) / s,
                  (m[..., 0, 2] + m[..., 2, 0]) / s))
    s = 2.0 * xp.sqrt(xp.maximum(1.0 + m11 - m00 - m22, 1e-12))
    cands.append(((m[..., 0, 2] - m[..., 2, 0]) / s, (m[..., 0, 1] + m[..., 1, 0]) / s, 0.25 * s,
                  (m[..., 1, 2] + m[..., 2, 1]) / s))
    s = 2.0 * xp.sqrt(xp.maximum(1.0 + m22 - m00 - m11, 1e-12))
    cands.append(((m[..., 1, 0] - m[..., 0, 1]) / s, (m[..., 0, 2] + m[..., 2, 0]) / s,
                  (m[..., 1, 2] + m[..., 2, 1]) / s, 0.25 * s))
    quats = [xp.stack(c, axis=-1) for c in cands]
    first = (t > 0.0)[..., None]
    second = ((m00 > m11) & (m00 > m22))[..., None]
    third = (m11 > m22)[..., None]
    q = xp.where(first, quats[0], xp.where(second, quats[1], xp.where(third, quats[2], quats[3])))
    q = q / norm(xp, q)[..., None]
    return xp.where(q[..., :1] < 0.0, -q, q)


def rotation_angle(xp, target, current):
    """float[N]: the angle (rad, [0, pi]) of the rotation taking ``current`` to ``target`` (float[N, 3, 3]):
    ``atan2(|vee(M)| / 2, (trace(M) - 1) / 2)`` with ``M = target current^T``, accurate at every angle."""
    m = xp.matmul(target, xp.swapaxes(current, -1, -2))
    v = xp.stack([m[..., 2, 1] - m[..., 1, 2], m[..., 0, 2] - m[..., 2, 0], m[..., 1, 0] - m[..., 0, 1]], axis=-1)
    c = (m[..., 0, 0] + m[..., 1, 1] + m[..., 2, 2] - 1.0) * 0.5
    return xp.arctan2(0.5 * norm(xp, v), c)


def wrap_angle(xp, a):
    """Angles to (-pi, pi]."""
    return xp.arctan2(xp.sin(a), xp.cos(a))


def yaw_quats(xp, yaw):
    """float[N] yaw -> wxyz float[N, 4] about +z."""
    h = 0.5 * yaw
    zero = xp.zeros_like(h)
    return xp.stack([xp.cos(h), zero, zero, xp.sin(h)], axis=-1)


# ------------------------------------------------------------------------------------------ one world
_NO = np.zeros(1, dtype=bool)
_YES = np.ones(1, dtype=bool)


class SceneState:
    """``TaskState`` of one ``ManifestScene`` (any engine of primitives): N = 1, NumPy, read on demand
    from the scene's engine, so a task pays only for what it reads."""

    __slots__ = ("scene", "params")
    xp = np
    num_worlds = 1

    def __init__(self, scene, params: dict[str, np.ndarray]):
        self.scene = scene
        self.params = params

    def object_pos(self, name: str) -> np.ndarray:
        return self.scene.engine.object_pose(name)[0][None]

    def object_quat(self, name: str) -> np.ndarray:
        return self.scene.engine.object_pose(name)[1][None]

    def object_velocity(self, name: str) -> np.ndarray:
        return self.scene.engine.object_velocity(name)[None]

    def contacts(self, a: str, b: str, where=None) -> np.ndarray:
        """bool[1]; ``where`` (bool[N]): only those worlds are asked (the rest answer False), so a task
        that needs a contact only in some state spares the others the collision pass."""
        if where is not None and not where[0]:
            return _NO
        return _YES if self.scene.engine.contacts_between(a, b) else _NO

    def eef_position_world(self) -> np.ndarray:
        return self.scene.eef_position_world()[None]

    def eef_pose_base(self) -> tuple[np.ndarray, np.ndarray]:
        pos, rot = self.scene.eef_pose_base()
        return pos[None], rot[None]

    def base_pose(self) -> np.ndarray:
        return self.scene.base_pose()[None]

    def to_base(self, pos, quat) -> np.ndarray:
        return self.scene.to_base(np.asarray(pos)[0], np.asarray(quat)[0])[None]
