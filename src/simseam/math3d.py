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
    return np.array(_quat_of(np.asarray(m).tolist()))


def _quat_of(m: list) -> list[float]:
    """``matrix_to_quat`` on a nested list, in Python floats (a fraction of numpy's per-call cost)."""
    (m00, m01, m02), (m10, m11, m12), (m20, m21, m22) = m
    t = m00 + m11 + m22
    if t > 0:
        s = 2.0 * math.sqrt(t + 1.0)
        q = [0.25 * s, (m21 - m12) / s, (m02 - m20) / s, (m10 - m01) / s]
    elif m00 > m11 and m00 > m22:
        s = 2.0 * math.sqrt(1.0 + m00 - m11 - m22)
        q = [(m21 - m12) / s, 0.25 * s, (m01 + m10) / s, (m02 + m20) / s]
    elif m11 > m22:
        s = 2.0 * math.sqrt(1.0 + m11 - m00 - m22)
        q = [(m02 - m20) / s, (m01 + m10) / s, 0.25 * s, (m12 + m21) / s]
    else:
        s = 2.0 * math.sqrt(1.0 + m22 - m00 - m11)
        q = [(m10 - m01) / s, (m02 + m20) / s, (m12 + m21) / s, 0.25 * s]
    n = math.sqrt(q[0] * q[0] + q[1] * q[1] + q[2] * q[2] + q[3] * q[3])
    if q[0] < 0:
        n = -n
    return [q[0] / n, q[1] / n, q[2] / n, q[3] / n]


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
    return np.array(_rodrigues(*np.asarray(v, dtype=np.float64).tolist()))


def axis_angle_times(v, r: np.ndarray) -> np.ndarray:
    """``axis_angle_to_matrix(v) @ r``, the product formed in Python floats (cheaper than a 3x3 BLAS call)."""
    return np.array(axis_angle_times_rows(*np.asarray(v, dtype=np.float64).tolist(), np.asarray(r).tolist()))


def axis_angle_times_rows(x: float, y: float, z: float, r: list) -> list[list[float]]:
    """``axis_angle_times([x, y, z], r)`` with ``r`` and the result nested lists (no numpy call)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = _rodrigues(x, y, z)
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = r
    return [[a00 * b00 + a01 * b10 + a02 * b20, a00 * b01 + a01 * b11 + a02 * b21, a00 * b02 + a01 * b12 + a02 * b22],
            [a10 * b00 + a11 * b10 + a12 * b20, a10 * b01 + a11 * b11 + a12 * b21, a10 * b02 + a11 * b12 + a12 * b22],
            [a20 * b00 + a21 * b10 + a22 * b20, a20 * b01 + a21 * b11 + a22 * b21, a20 * b02 + a21 * b12 + a22 * b22]]


def _rodrigues(x: float, y: float, z: float) -> list[list[float]]:
    th = math.sqrt(x * x + y * y + z * z)
    if th < 1e-12:
        return [[1.0, 0.0, 0.0], [0.0, 1.0, 0.0], [0.0, 0.0, 1.0]]
    x, y, z = x / th, y / th, z / th
    s, c = math.sin(th), 1.0 - math.cos(th)  # R = I + s [k]x + c (k k^T - I)
    return [[1.0 + c * (x * x - 1.0), c * x * y - s * z, c * x * z + s * y],
            [c * x * y + s * z, 1.0 + c * (y * y - 1.0), c * y * z - s * x],
            [c * x * z - s * y, c * y * z + s * x, 1.0 + c * (z * z - 1.0)]]


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
    return np.array(axis_angle_of(np.asarray(m).tolist(), np.asarray(reference, dtype=np.float64).tolist()))


def axis_angle_of(m: list, reference) -> tuple[float, float, float]:
    """``matrix_to_axis_angle`` of a nested list, ``reference`` four Python floats, the result three
    (for callers that go on in floats: no numpy call)."""
    w, x, y, z = _quat_of(m)
    rw, rx, ry, rz = reference
    if w * rw + x * rx + y * ry + z * rz < 0.0:
        w, x, y, z = -w, -x, -y, -z
    return _axis_angle_of(w, x, y, z)


def quat_to_axis_angle(q) -> np.ndarray:
    """Quaternion -> rotation vector, robosuite/LIBERO ``quat2axisangle`` semantics."""
    return np.array(_axis_angle_of(*np.asarray(q, dtype=np.float64).tolist()))


def _axis_angle_of(w: float, x: float, y: float, z: float) -> tuple[float, float, float]:
    w = min(max(w, -1.0), 1.0)
    den = math.sqrt(max(1.0 - w * w, 0.0))
    if den < 1e-9:
        return 0.0, 0.0, 0.0
    k = 2.0 * math.acos(w)
    return x * k / den, y * k / den, z * k / den


def rotation_error(target: np.ndarray, current: np.ndarray) -> np.ndarray:
    """Rotation vector (world frame) that takes ``current`` to ``target``."""
    return np.array(rotation_error_of(target, current))


def rotation_error_of(target: np.ndarray, current: np.ndarray) -> tuple[float, float, float]:
    """``rotation_error`` as three Python floats (for callers that go on in floats). The product
    ``target @ current.T`` is formed in Python floats too: cheaper than a 3x3 BLAS call, per step."""
    return rotation_error_rows(np.asarray(target).tolist(), np.asarray(current).tolist())


def rotation_error_rows(target: list, current: list) -> tuple[float, float, float]:
    """``rotation_error_of`` of two 3x3 nested lists (no numpy call)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = target
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = current
    m00, m11 = a00 * b00 + a01 * b01 + a02 * b02, a10 * b10 + a11 * b11 + a12 * b12
    m22 = a20 * b20 + a21 * b21 + a22 * b22
    m01, m10 = a00 * b10 + a01 * b11 + a02 * b12, a10 * b00 + a11 * b01 + a12 * b02
    m02, m20 = a00 * b20 + a01 * b21 + a02 * b22, a20 * b00 + a21 * b01 + a22 * b02
    m12, m21 = a10 * b20 + a11 * b21 + a12 * b22, a20 * b10 + a21 * b11 + a22 * b12
    vx, vy, vz = m21 - m12, m02 - m20, m10 - m01
    cos = min(max((m00 + m11 + m22 - 1.0) * 0.5, -1.0), 1.0)
    if cos > 0.999:  # small angle: sin(a) ~ a, v = 2 sin(a) axis
        return 0.5 * vx, 0.5 * vy, 0.5 * vz
    if cos > -0.99:
        angle = math.acos(cos)
        k = angle / (2.0 * math.sin(angle))
        return vx * k, vy * k, vz * k
    return _axis_angle_of(*_quat_of([[m00, m01, m02], [m10, m11, m12], [m20, m21, m22]]))  # near pi: quaternion


def rotation_angle_rows(a: list, b: list) -> float:
    """The angle (rad, in [0, pi]) of the rotation between two 3x3 nested lists: of ``a @ b.T``, whose
    trace is the sum of the elementwise products (no numpy call, no rotation vector)."""
    (a00, a01, a02), (a10, a11, a12), (a20, a21, a22) = a
    (b00, b01, b02), (b10, b11, b12), (b20, b21, b22) = b
    tr = a00 * b00 + a01 * b01 + a02 * b02 + a10 * b10 + a11 * b11 + a12 * b12 + a20 * b20 + a21 * b21 + a22 * b22
    return math.acos(min(max((tr - 1.0) * 0.5, -1.0), 1.0))


def pose_rows(t: np.ndarray) -> tuple[list[float], list[list[float]]]:
    """A 4x4 pose as Python floats: (position[3], rotation rows 3x3), for callers that go on in floats."""
    (r00, r01, r02, x), (r10, r11, r12, y), (r20, r21, r22, z), _ = t.tolist()
    return [x, y, z], [[r00, r01, r02], [r10, r11, r12], [r20, r21, r22]]


def make_transform(pos, rot: np.ndarray) -> np.ndarray:
    t = np.eye(4)
    t[:3, :3] = rot
    t[:3, 3] = pos
    return t
