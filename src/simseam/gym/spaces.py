"""Gymnasium spaces from the scene contract, and seam observation -> gym observation.

Everything here is derived from what a rollout advertises before its first
reset (``SceneInfo``, the ``ActionLayout`` it implies, and the ``RobotSpec``
for limits and declared sensors), so the spaces match any engine, in-process
or sidecar. Units and shapes follow ``simseam.seam``:

observation (``spaces.Dict``; a key is present only when stated):

- ``images``: ``{feature_key: Box(0, 255, (H, W, 3), uint8)}`` per RGB camera in
  ``SceneInfo.cameras``; absent when the scene renders no images.
- ``state``: ``Box(-inf, inf, (state_dim,), float32)`` (layout's state contract).
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

action: ``Box(low, high, (action_dim,), float32)`` in the ``ActionLayout`` slot order:
CARTESIAN_DELTA arm slots in [-1, 1]; JOINT_POSITION arm slots within the joint limits
(rad / m; unbounded joints get +-inf); gripper in [-1, 1]; base twist ``[vx, vy, wz]``
within ``+-max_linear`` (m/s) and ``+-max_angular`` (rad/s). The scene also clips
``[vx, vy]`` to ``max_linear`` in norm, so the Box is a superset of what moves the base.
"""

from __future__ import annotations

from typing import Any

import numpy as np
from gymnasium import spaces

from simseam.robot.spec import RobotSpec
from simseam.scene.actions import ActionLayout
from simseam.seam import (
    OBS_BASE_POSE,
    OBS_DEPTH_POINTS,
    OBS_IMAGES,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_PRIVILEGED,
    OBS_SCAN,
    OBS_STATE,
    ControlMode,
    Observation,
    SceneInfo,
    SimulationError,
)

INF = np.inf


def _vec(n: int, low: float = -INF, high: float = INF, dtype=np.float32) -> spaces.Box:
    return spaces.Box(low, high, (n,), dtype)


def action_space(info: SceneInfo, robot: RobotSpec) -> spaces.Box:
    """The Box of the rollout's action layout (see the module docstring for bounds)."""
    layout = ActionLayout.from_scene(info)
    low = np.full(layout.dim, -1.0)
    high = np.full(layout.dim, 1.0)
    if layout.control_mode == ControlMode.JOINT_POSITION:
        joints = {j.name: j for j in robot.arm_joints}
        for i, name in enumerate(layout.arm_names):
            j = joints[name]
            low[i] = -INF if j.lower is None else j.lower
            high[i] = INF if j.upper is None else j.upper
    if layout.base is not None:
        kb = robot.kinematic_base
        lim = np.array([kb.max_linear, kb.max_linear, kb.max_angular])
        low[layout.base], high[layout.base] = -lim, lim
    return spaces.Box(low.astype(np.float32), high.astype(np.float32), (layout.dim,), np.float32)


def observation_space(info: SceneInfo, robot: RobotSpec, *, depth_points: int | None = None,
                      privileged: Observation | None = None) -> spaces.Dict:
    """The Dict observation space. ``depth_points``: K rows per depth sensor, or None to leave
    depth clouds out (they are also left out when the scene renders no images: it computes none).
    ``privileged``: a sample ``observation['privileged']`` giving the layout's object names, or
    None to leave ground truth out."""
    n = len(info.joint_names)
    out: dict[str, spaces.Space] = {}
    if info.cameras:
        out[OBS_IMAGES] = spaces.Dict({k: spaces.Box(0, 255, (h, w, 3), np.uint8)
                                       for k, (h, w) in info.cameras.items()})
    out[OBS_STATE] = _vec(info.state_dim)
    out[OBS_JOINT_POSITIONS] = _vec(n)
    out[OBS_JOINT_VELOCITIES] = _vec(n)
    if robot.kinematic_base is not None:
        out[OBS_BASE_POSE] = spaces.Box(np.array([-INF, -INF, -np.pi], np.float32),
                                        np.array([INF, INF, np.pi], np.float32), (3,), np.float32)
    for s in robot.sensors_of("lidar_2d")[:1]:
        out[OBS_SCAN] = _vec(s.beams, 0.0, s.range_max)
    depth = robot.sensors_of("depth")
    if depth_points and depth and info.cameras:
        out[OBS_DEPTH_POINTS] = spaces.Dict({s.name: spaces.Box(-INF, INF, (depth_points, 3), np.float32)
                                             for s in depth})
    if privileged is not None:
        priv: dict[str, spaces.Space] = {"eef_pose": _vec(7, dtype=np.float64)}
        if privileged.get("objects"):
            priv["objects"] = spaces.Dict({k: _vec(len(v), dtype=np.float64) for k, v in privileged["objects"].items()})
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
