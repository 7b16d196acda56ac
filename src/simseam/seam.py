"""The seam: the one contract between policies and simulators.

Everything above the seam (HAL, policies, runner, CLI) depends on this module
only; everything below it (scenes, engines, the sidecar) implements it. It
imports nothing but numpy and the standard library, so any interpreter that
hosts an engine can import it.

Observation contract (a plain dict, keys fixed here):

- ``images``: ``{feature_key: uint8[H, W, 3]}``, one per declared RGB sensor
  (empty when the scene renders no images).
- ``state``: ``float32[state_dim]``, laid out by the layout's state contract.
- ``task``: the natural-language instruction (str).
- ``joint_positions`` / ``joint_velocities``: ``float32[n_joints]`` in manifest
  joint order (radians, metres; rad/s, m/s). Base joints come from the
  kinematic base pose.
- ``sim_time_ns``: int, monotonic within an episode, 0 at reset.
- only when declared by the robot: ``base_pose`` ``float32[3]`` = [x, y, yaw]
  in the world frame; ``depth_points`` ``{sensor: float32[N, 3]}`` in base_link;
  ``scan`` ``float32[n_beams]`` ranges (beam 0 at -pi, counter-clockwise, in
  base_link).
- only when the scene is built with ``privileged=True`` (scripted experts,
  dataset collection): ``privileged``, a dict of ground truth in the robot base
  frame: ``eef_pose`` ``float64[7]`` (xyz + quaternion wxyz) and ``objects``
  ``{name: float64[7]}``.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Any, Protocol, runtime_checkable

import numpy as np

# --------------------------------------------------------------------------- keys
OBS_IMAGES = "images"
OBS_STATE = "state"
OBS_TASK = "task"
OBS_JOINT_POSITIONS = "joint_positions"
OBS_JOINT_VELOCITIES = "joint_velocities"
OBS_SIM_TIME_NS = "sim_time_ns"
OBS_BASE_POSE = "base_pose"
OBS_DEPTH_POINTS = "depth_points"
OBS_SCAN = "scan"
OBS_PRIVILEGED = "privileged"

#: Keys present in every observation.
REQUIRED_OBS_KEYS = (
    OBS_IMAGES,
    OBS_STATE,
    OBS_TASK,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_SIM_TIME_NS,
)
#: Keys present only when the robot declares the matching part / sensor.
OPTIONAL_OBS_KEYS = (OBS_BASE_POSE, OBS_DEPTH_POINTS, OBS_SCAN, OBS_PRIVILEGED)

Observation = dict[str, Any]


class ControlMode(str, enum.Enum):
    """How an action vector is interpreted.

    - ``JOINT_POSITION``: absolute arm joint targets (rad / m), manifest order.
    - ``CARTESIAN_DELTA``: ``[dx, dy, dz, dax, day, daz]`` in [-1, 1], scaled by
      the layout's max step (m, rad), in the robot base frame, solved by IK.
    - ``BODY_TWIST``: ``[vx, vy, wz]`` in the base frame (m/s, rad/s).
    - ``GRIPPER``: one scalar, -1 fully open, +1 fully closed.

    Every arm action ends with the gripper scalar when the robot has a
    gripper; mobile manipulators append ``[vx, vy, wz]``.
    """

    JOINT_POSITION = "joint_position"
    CARTESIAN_DELTA = "cartesian_delta"
    BODY_TWIST = "body_twist"
    GRIPPER = "gripper"

    @classmethod
    def parse(cls, value: "str | ControlMode") -> "ControlMode":
        """Accept the enum, its value or its name (any case)."""
        if isinstance(value, cls):
            return value
        text = str(value).strip().lower()
        for mode in cls:
            if text in (mode.value, mode.name.lower()):
                return mode
        raise ConfigError(
            f"unknown control mode {value!r}; expected one of "
            + ", ".join(m.value for m in cls)
        )


# ------------------------------------------------------------------------- errors
class SimseamError(Exception):
    """Base of every error simseam raises on purpose."""


class ConfigError(SimseamError, ValueError):
    """A manifest, scene file, name or option is wrong. The message says where."""


class InvalidActionError(SimseamError, ValueError):
    """An action has the wrong shape, dtype or non-finite values. Nothing was applied."""


class BackendUnavailableError(SimseamError):
    """An engine or renderer cannot run here (not installed, no GL, no GPU)."""


class SimulationError(SimseamError):
    """The simulator failed while building or stepping the scene."""


class SidecarError(SimseamError):
    """Transport-level failure talking to an out-of-process engine."""


# ------------------------------------------------------------------------ results
@dataclass(frozen=True)
class StepResult:
    """What ``SimRollout.step`` returns (gymnasium's five-tuple, named)."""

    observation: Observation
    reward: float
    terminated: bool
    truncated: bool
    info: dict[str, Any] = field(default_factory=dict)


@dataclass(frozen=True)
class TaskInfo:
    """What the rollout is asking the policy to do."""

    layout: str
    instruction: str
    success_key: str = "success"
    max_steps: int = 300


@dataclass(frozen=True)
class SceneInfo:
    """Static description of a rollout: enough to check a policy fits it.

    ``cameras`` maps feature key -> (height, width) of each RGB image in the
    observation; ``joint_names`` is the manifest joint order.
    """

    robot: str
    engine: str
    layout: str
    control_mode: ControlMode
    action_dim: int
    state_dim: int
    control_hz: float
    cameras: dict[str, tuple[int, int]]
    joint_names: tuple[str, ...]
    action_names: tuple[str, ...] = ()
    #: CARTESIAN_DELTA scale: metres and radians per step at |action| = 1
    action_scale: tuple[float, float] = (0.05, 0.5)

    def to_json(self) -> dict[str, Any]:
        """Plain JSON types (for summaries and the wire)."""
        return {
            "robot": self.robot,
            "engine": self.engine,
            "layout": self.layout,
            "control_mode": self.control_mode.value,
            "action_dim": self.action_dim,
            "state_dim": self.state_dim,
            "control_hz": self.control_hz,
            "cameras": {k: list(v) for k, v in self.cameras.items()},
            "joint_names": list(self.joint_names),
            "action_names": list(self.action_names),
            "action_scale": list(self.action_scale),
        }

    @classmethod
    def from_json(cls, data: Any) -> "SceneInfo":
        """Inverse of ``to_json``; a malformed document raises ``ConfigError`` naming the field."""
        if not isinstance(data, dict):
            raise ConfigError(f"scene info: expected a JSON object, got {type(data).__name__}")
        try:
            return cls(
                robot=str(data["robot"]), engine=str(data["engine"]), layout=str(data["layout"]),
                control_mode=ControlMode.parse(data["control_mode"]),
                action_dim=int(data["action_dim"]), state_dim=int(data["state_dim"]),
                control_hz=float(data["control_hz"]),
                cameras={str(k): (int(v[0]), int(v[1])) for k, v in dict(data["cameras"]).items()},
                joint_names=tuple(str(n) for n in data["joint_names"]),
                action_names=tuple(str(n) for n in data.get("action_names", ())),
                action_scale=tuple(float(x) for x in data.get("action_scale", (0.05, 0.5))),
            )
        except KeyError as exc:
            raise ConfigError(f"scene info: missing field {exc.args[0]!r}") from None
        except (TypeError, ValueError, IndexError) as exc:
            raise ConfigError(f"scene info: malformed field: {exc}") from None


# ------------------------------------------------------------------------ protocol
@runtime_checkable
class SimRollout(Protocol):
    """One simulated robot in one scene, driven step by step.

    Contract:
    - ``reset(seed)`` starts a new episode; the same seed gives the same
      initial observation. ``seed=None`` draws from the rollout's own stream.
    - ``step(action)`` takes ``float32[action_dim]``; a wrong shape or a
      non-finite value raises ``InvalidActionError`` and changes nothing.
    - ``render()`` returns an ``uint8[H, W, 3]`` frame for videos (the first
      RGB camera), or None when the scene has no camera.
    - ``close()`` releases every resource; calling it twice is harmless.
    """

    @property
    def action_dim(self) -> int: ...

    @property
    def scene(self) -> SceneInfo: ...

    @property
    def task(self) -> TaskInfo: ...

    def reset(self, seed: int | None = None) -> Observation: ...

    def step(self, action: np.ndarray) -> StepResult: ...

    def render(self) -> np.ndarray | None: ...

    def sim_time_ns(self) -> int: ...

    def close(self) -> None: ...


def check_action(action: Any, action_dim: int) -> np.ndarray:
    """Validate an action against the seam contract; return it as float32.

    Raises ``InvalidActionError`` naming the problem (shape, dtype, index of the
    first non-finite entry). Never mutates the caller's array.
    """
    try:
        arr = np.asarray(action, dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise InvalidActionError(f"action is not numeric: {exc}") from None
    if arr.ndim != 1 or arr.shape[0] != action_dim:
        raise InvalidActionError(
            f"action has shape {tuple(arr.shape)}, expected ({action_dim},)"
        )
    finite = np.isfinite(arr)
    if not finite.all():
        bad = int(np.flatnonzero(~finite)[0])
        raise InvalidActionError(
            f"action[{bad}] is {float(arr[bad])}; every entry must be finite"
        )
    return arr
