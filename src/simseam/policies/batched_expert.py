"""The lift_cube scripted expert for N worlds at once (numpy over the batch, no per-world loop).

``LiftExpertBatch`` is ``policies.scripted.LiftExpert`` vectorized: the same phases (hover above the
cube yaw-aligned, descend, close, lift 20 cm), thresholds, gains and saturation, computed for every
world in array operations from the privileged poses (``eef_pose``, ``cube``: float[N, 7] base-frame
``[x, y, z, qw, qx, qy, qz]``). The tests check it returns the per-world expert's actions.
It drives the batched engine's benchmarks and success-rate runs at thousands of worlds.
"""

from __future__ import annotations

import numpy as np

from simseam.math3d import matrix_to_quat, quat_to_axis_angle
from simseam.seam import ActionSpec

OPEN, CLOSE = -1.0, 1.0
GAIN, ROT_GAIN = 0.5, 0.2  # as _CartesianExpert


def quats_to_matrices(q: np.ndarray) -> np.ndarray:
    w, x, y, z = q[:, 0], q[:, 1], q[:, 2], q[:, 3]
    return np.stack([
        np.stack([1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)], -1),
        np.stack([2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)], -1),
        np.stack([2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)], -1)], -2)


def rotation_errors(target: np.ndarray, current: np.ndarray) -> np.ndarray:
    """``math3d.rotation_error`` for [N, 3, 3] stacks."""
    m = target @ np.swapaxes(current, 1, 2)
    v = np.stack([m[:, 2, 1] - m[:, 1, 2], m[:, 0, 2] - m[:, 2, 0], m[:, 1, 0] - m[:, 0, 1]], -1)
    cos = np.clip((np.trace(m, axis1=1, axis2=2) - 1.0) * 0.5, -1.0, 1.0)
    out = 0.5 * v
    mid = (cos <= 0.999) & (cos > -0.99)
    if mid.any():
        ang = np.arccos(cos[mid])
        out[mid] = v[mid] * (ang / (2.0 * np.sin(ang)))[:, None]
    for i in np.flatnonzero(cos <= -0.99):  # near pi: through the quaternion, as the host code
        out[i] = quat_to_axis_angle(matrix_to_quat(m[i]))
    return out


def _rz(yaw: np.ndarray) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    z, o = np.zeros_like(yaw), np.ones_like(yaw)
    return np.stack([np.stack([c, -s, z], -1), np.stack([s, c, z], -1), np.stack([z, z, o], -1)], -2)


class LiftExpertBatch:
    """N lift_cube experts; ``reset(worlds)`` starts new episodes, ``act(eef_pose, cube)`` -> float32[N, dim]."""

    def __init__(self, action: ActionSpec, n: int):
        self.action, self.n = action, n
        self.max_t, self.max_r = action.max_translation, action.max_rotation
        self.down = np.zeros((n, 3, 3))
        self.fresh = np.ones(n, bool)
        self.phase = np.zeros(n, np.int64)
        self.timer = np.zeros(n, np.int64)
        self.lift_to = np.zeros((n, 3))
        names = [s.name for s in action.slots]
        self._arm = [names.index(k) for k in ("dx", "dy", "dz", "dax", "day", "daz")]
        self._grip = names.index("grip")

    def reset(self, worlds) -> None:
        self.fresh[worlds] = True
        self.phase[worlds] = 0
        self.timer[worlds] = 0

    def _yaw_of(self, rot: np.ndarray) -> np.ndarray:
        rel = rot @ np.swapaxes(self.down, 1, 2)
        return np.arctan2(rel[:, 1, 0], rel[:, 0, 0])

    def act(self, eef_pose: np.ndarray, cube: np.ndarray) -> np.ndarray:
        eef_pose, cube = np.asarray(eef_pose, np.float64), np.asarray(cube, np.float64)
        pos, rot = eef_pose[:, :3], quats_to_matrices(eef_pose[:, 3:])
        if self.fresh.any():
            self.down[self.fresh] = rot[self.fresh]
            self.fresh[:] = False
        eef_yaw = self._yaw_of(rot)
        cube_yaw = self._yaw_of(quats_to_matrices(cube[:, 3:]))
        period = np.pi / 2
        yaw = cube_yaw + period * np.round((eef_yaw - cube_yaw) / period)
        self.timer += 1
        above = cube[:, :3] + [0.0, 0.0, 0.08]
        grasp = cube[:, :3] + [0.0, 0.0, 0.005]
        err = lambda p: np.linalg.norm(p - pos, axis=1)  # noqa: E731
        ph = self.phase.copy()
        target = np.where((ph == 0)[:, None], above, np.where((ph == 1)[:, None], grasp,
                          np.where((ph == 2)[:, None], pos, self.lift_to)))
        speed = np.where((ph == 1) | (ph == 3), 0.6, 1.0)
        grip = np.where(ph >= 2, CLOSE, OPEN)
        # phase transitions take effect at the next step (as the per-world expert's)
        adv0 = (ph == 0) & (((err(above) < 0.01) & (np.abs(eef_yaw - yaw) < 0.05)) | (self.timer > 60))
        adv1 = (ph == 1) & ((err(grasp) < 0.008) | (self.timer > 40))
        adv2 = (ph == 2) & (self.timer > 6)
        self.lift_to[adv2] = pos[adv2] + [0.0, 0.0, 0.2]
        adv = adv0 | adv1 | adv2
        self.phase[adv] += 1
        self.timer[adv] = 0
        dpos = GAIN * (target - pos) / self.max_t
        dpos *= np.minimum(1.0, speed / np.maximum(np.abs(dpos).max(axis=1), 1e-12))[:, None]  # straight lines
        drot = np.clip(ROT_GAIN * rotation_errors(_rz(yaw) @ self.down, rot) / self.max_r, -0.5, 0.5)
        out = np.zeros((eef_pose.shape[0], self.action.dim), np.float32)
        out[:, self._arm[:3]] = dpos
        out[:, self._arm[3:]] = drot
        out[:, self._grip] = grip
        return out
