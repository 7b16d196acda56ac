"""Gymnasium spaces from the scene contract, and seam observation -> gym observation.

Everything here is derived from the rollout's ``RolloutSpec`` (available
before the first reset), so the spaces match any backend, in-process or
sidecar. Units and shapes follow ``simseam.seam``:

observation (``spaces.Dict``; a key is present only when stated):

- ``images``: ``{feature_key: Box(0, 255, (H, W, 3), uint8)}`` per RGB camera in
  ``SceneInfo.cameras``; absent when the scene renders no images.
- ``state``: ``Box(-inf, inf, (state_dim,), float32)`` (the task's state vector).
- ``joint_positions`` / ``joint_velocities``: ``Box(-inf, inf, (n_joints,), float32)``,
  manifest joint order (rad, m; rad/s, m/s). Unbounded: physics can overshoot a limit.
- ``base_pose``: ``Box([-inf, -inf, -pi], [inf, inf, pi], (3,), float32)`` = [x, y, yaw]
  in the world (m, rad); robots with a kinematic base.
- ``scan``: ``Box(0, range_max, (beams,), float32)`` ranges in m (no hit reads range_max);
  robots with a 2-D lidar.
- ``depth_points``: only when asked for (``depth_points=K``) and images are rendered:
  ``{sensor: Box(-inf, inf, (K, 3), float32)}`` in base_link (m). A depth cloud has a
  variable number N of points; the first ``min(N, K)`` rows hold points (an evenly
  strided subsample when N > K, same order as the cloud), the rest are zeros.
- ``privileged``: only with ``privileged=True``: ``eef_pose`` ``Box(-inf, inf, (7,),
  float64)`` (xyz + quaternion wxyz, base frame) and ``objects`` ``{name: Box(7,)}``.

action: ``Box(spec.action.low, spec.action.high, (action_dim,), float32)``, the slot bounds:
CARTESIAN_DELTA arm slots in [-1, 1]; JOINT_POSITION arm slots within the joint limits
(rad / m; unbounded joints get +-inf); gripper in [-1, 1]; base twist ``[vx, vy, wz]``
within ``+-max_linear`` (m/s) and ``+-max_angular`` (rad/s). The rollout also clips
``[vx, vy]`` to ``max_linear`` in norm (``spec.action.norm_bounds``), so the Box is a
superset of what moves the base.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from simseam.seam import (
    OBS_BASE_POSE,
    OBS_DEPTH_POINTS,
    OBS_IMAGES,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_PRIVILEGED,
    OBS_SCAN,
    OBS_STATE,
    RolloutSpec,
    SimulationError,
)

INF = np.inf


def _vec(n: int, low: float = -INF, high: float = INF, dtype=np.float32) -> spaces.Box:
    return spaces.Box(low, high, (n,), dtype)


def action_space(spec: RolloutSpec) -> spaces.Box:
    """The Box of the rollout's action slots (see the module docstring for bounds)."""
    a = spec.action
    return spaces.Box(a.low.astype(np.float32), a.high.astype(np.float32), (a.dim,), np.float32)


def observation_space(spec: RolloutSpec, *, depth_points: int | None = None,
                      privileged: bool = False) -> spaces.Dict:
    """The Dict observation space. ``depth_points``: K rows per depth sensor, or None to leave
    depth clouds out (also left out when the rollout declares none: a state-only scene);
    ``privileged``: include the ground truth the spec declares."""
    fields = spec.observation.fields
    n = len(spec.robot.joints)
    out: dict[str, spaces.Space] = {}
    if spec.cameras:
        out[OBS_IMAGES] = spaces.Dict({k: spaces.Box(0, 255, (h, w, 3), np.uint8) for k, (h, w) in spec.cameras.items()})
    out[OBS_STATE] = _vec(spec.state_dim)
    out[OBS_JOINT_POSITIONS] = _vec(n)
    out[OBS_JOINT_VELOCITIES] = _vec(n)
    if OBS_BASE_POSE in fields:
        out[OBS_BASE_POSE] = spaces.Box(np.array([-INF, -INF, -np.pi], np.float32),
                                        np.array([INF, INF, np.pi], np.float32), (3,), np.float32)
    if OBS_SCAN in fields:
        lidar = spec.robot.sensors_of("lidar_2d")[0]
        out[OBS_SCAN] = _vec(lidar.beams, 0.0, lidar.range_max)
    if depth_points and OBS_DEPTH_POINTS in fields:
        out[OBS_DEPTH_POINTS] = spaces.Dict({name: spaces.Box(-INF, INF, (depth_points, 3), np.float32)
                                             for name in fields[OBS_DEPTH_POINTS].entries})
    if privileged and OBS_PRIVILEGED in fields:
        objects = fields[OBS_PRIVILEGED].entries["objects"].entries
        priv: dict[str, spaces.Space] = {"eef_pose": _vec(7, dtype=np.float64)}
        if objects:
            priv["objects"] = spaces.Dict({k: _vec(7, dtype=np.float64) for k in objects})
        out[OBS_PRIVILEGED] = spaces.Dict(priv)
    return spaces.Dict(out)


def pad_points(points: np.ndarray, k: int) -> tuple[np.ndarray, int]:
    """``float32[N, 3]`` -> (``float32[k, 3]``, rows used). N > k: ``k`` evenly strided
    points, order kept; N < k: zero rows after the N points."""
    points = np.asarray(points, dtype=np.float32).reshape(-1, 3)
    n = len(points)
    if n > k:
        return points[np.linspace(0, n - 1, k).round().astype(np.intp)], k
    out = np.zeros((k, 3), dtype=np.float32)
    out[:n] = points
    return out, n


def to_gym(obs: Any, space: spaces.Space, key: str = "observation") -> Any:
    """Cast a seam observation (or part of it) to ``space``: keys the space lacks are dropped,
    arrays cast to the space's dtype. ``depth_points`` must already be padded. Raises
    ``SimulationError`` naming the key when a part is missing or has the wrong shape."""
    if isinstance(space, spaces.Dict):
        if not isinstance(obs, dict):
            raise SimulationError(f"{key}: expected a dict, got {type(obs).__name__}")
        missing = [k for k in space.spaces if k not in obs]
        if missing:
            raise SimulationError(f"{key}: the rollout's observation lacks {missing}")
        return {k: to_gym(obs[k], s, f"{key}[{k!r}]") for k, s in space.spaces.items()}
    arr = np.asarray(obs, dtype=space.dtype)
    if arr.shape != space.shape:
        raise SimulationError(f"{key}: shape {arr.shape}, the observation space says {space.shape}")
    return arr
