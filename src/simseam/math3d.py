"""Small rigid-body math helpers (numpy only). Quaternions are [w, x, y, z]."""

from __future__ import annotations

import math

import numpy as np


def rpy_to_matrix(rpy) -> np.ndarray:
    """URDF convention: R = Rz(yaw) @ Ry(pitch) @ Rx(roll)."""
    r, p, y = rpy
    cr, sr, cp, sp, cy, sy = np.cos(r), np.sin(r), np.cos(p), np.sin(p), np.cos(y), np.sin(y)
    return np.array(
        [
            [cy * cp, cy * sp * sr - sy * cr, cy * sp * cr + sy * sr],
            [sy * cp, sy * sp * sr + cy * cr, sy * sp * cr - cy * sr],
            [-sp, cp * sr, cp * cr],
        ]
    )


def matrix_to_rpy(m: np.ndarray) -> np.ndarray:
    """The inverse of ``rpy_to_matrix`` (pitch in [-pi/2, pi/2]; at +-pi/2 roll is taken as 0)."""
    pitch = math.asin(max(-1.0, min(1.0, -float(m[2, 0]))))
    if abs(abs(pitch) - math.pi / 2) < 1e-9:  # gimbal lock: only roll -+ yaw is defined
        return np.array([0.0, pitch, math.atan2(-float(m[0, 1]), float(m[1, 1]))])
    return np.array([math.atan2(float(m[2, 1]), float(m[2, 2])), pitch, math.atan2(float(m[1, 0]), float(m[0, 0]))])


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """Rotation matrix -> unit quaternion [w, x, y, z] with w >= 0."""
    t = np.trace(m)
    if t > 0:
        s = 2.0 * np.sqrt(t + 1.0)
        q = np.array([0.25 * s, (m[2, 1] - m[1, 2]) / s, (m[0, 2] - m[2, 0]) / s, (m[1, 0] - m[0, 1]) / s])
    elif m[0, 0] > m[1, 1] and m[0, 0] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[0, 0] - m[1, 1] - m[2, 2])
        q = np.array([(m[2, 1] - m[1, 2]) / s, 0.25 * s, (m[0, 1] + m[1, 0]) / s, (m[0, 2] + m[2, 0]) / s])
    elif m[1, 1] > m[2, 2]:
        s = 2.0 * np.sqrt(1.0 + m[1, 1] - m[0, 0] - m[2, 2])
        q = np.array([(m[0, 2] - m[2, 0]) / s, (m[0, 1] + m[1, 0]) / s, 0.25 * s, (m[1, 2] + m[2, 1]) / s])
    else:
        s = 2.0 * np.sqrt(1.0 + m[2, 2] - m[0, 0] - m[1, 1])
        q = np.array([(m[1, 0] - m[0, 1]) / s, (m[0, 2] + m[2, 0]) / s, (m[1, 2] + m[2, 1]) / s, 0.25 * s])
    q /= np.linalg.norm(q)
    return q if q[0] >= 0 else -q


def quat_to_matrix(q) -> np.ndarray:
    w, x, y, z = q.tolist() if isinstance(q, np.ndarray) else q  # Python floats: ~3x faster than numpy scalars
    return np.array(
        [
            [1 - 2 * (y * y + z * z), 2 * (x * y - z * w), 2 * (x * z + y * w)],
            [2 * (x * y + z * w), 1 - 2 * (x * x + z * z), 2 * (y * z - x * w)],
            [2 * (x * z - y * w), 2 * (y * z + x * w), 1 - 2 * (x * x + y * y)],
        ]
    )


def rpy_to_quat(rpy) -> np.ndarray:
    return matrix_to_quat(rpy_to_matrix(rpy))


def yaw_quat(yaw: float) -> np.ndarray:
    return np.array([np.cos(yaw / 2), 0.0, 0.0, np.sin(yaw / 2)])


def axis_angle_to_matrix(v) -> np.ndarray:
    """Rotation vector (axis * angle, rad) -> matrix (Rodrigues)."""
    x, y, z = np.asarray(v, dtype=np.float64).tolist()
    th = math.sqrt(x * x + y * y + z * z)
    if th < 1e-12:
        return np.eye(3)
    x, y, z = x / th, y / th, z / th
    s, c = math.sin(th), 1.0 - math.cos(th)  # R = I + s [k]x + c (k k^T - I)
    return np.array([[1.0 + c * (x * x - 1.0), c * x * y - s * z, c * x * z + s * y],
                     [c * x * y + s * z, 1.0 + c * (y * y - 1.0), c * y * z - s * x],
                     [c * x * z - s * y, c * y * z + s * x, 1.0 + c * (z * z - 1.0)]])


def sign_reference(q) -> np.ndarray:
    """``q`` (or ``-q``, the same rotation) with its largest-magnitude component positive: a fixed
    choice of sign for a reference orientation, see ``matrix_to_axis_angle``."""
    q = np.asarray(q, dtype=np.float64)
    return q if q[int(np.argmax(np.abs(q)))] >= 0 else -q


def matrix_to_axis_angle(m: np.ndarray, reference) -> np.ndarray:
    """Matrix -> rotation vector (axis * angle, angle in [0, 2 pi)), continuous around ``reference``
    (a unit quaternion [w, x, y, z]).

    A 3-vector cannot be continuous over every rotation; the common [0, pi] choice jumps at pi, which
    is exactly where a top-down gripper sits (rx flips between +3.1 and -3.1 under millimetre
    motions). Here the quaternion's sign follows ``reference`` (a robot's home tool orientation), so
    the vector runs smoothly through pi near it, as LIBERO's ``quat2axisangle`` of MuJoCo's body
    quaternion does; the jump moves to the rotations half a turn away from the reference.
    """
    q = matrix_to_quat(m)
    if float(np.dot(q, reference)) < 0.0:
        q = -q
    return quat_to_axis_angle(q)


def quat_to_axis_angle(q) -> np.ndarray:
    """Quaternion -> rotation vector, robosuite/LIBERO ``quat2axisangle`` semantics."""
    q = np.asarray(q, dtype=np.float64)
    w = np.clip(q[0], -1.0, 1.0)
    den = np.sqrt(max(1.0 - w * w, 0.0))
    if den < 1e-9:
        return np.zeros(3)
    return q[1:] * 2.0 * np.arccos(w) / den


def rotation_error(target: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Rotation vector (world frame) that takes ``current`` to ``target``."""
    m = target @ current.T
    v = np.array([m[2, 1] - m[1, 2], m[0, 2] - m[2, 0], m[1, 0] - m[0, 1]])
    cos = min(max((m[0, 0] + m[1, 1] + m[2, 2] - 1.0) * 0.5, -1.0), 1.0)
    if cos > 0.999:  # small angle: sin(a) ~ a, v = 2 sin(a) axis
        return 0.5 * v
    if cos > -0.99:
        angle = math.acos(cos)
        return v * (angle / (2.0 * math.sin(angle)))
    return quat_to_axis_angle(matrix_to_quat(m))  # near pi: go through the quaternion


def make_transform(pos, rot: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rot
    t[:3, 3] = pos
    return t
