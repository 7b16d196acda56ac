"""``RolloutSpec``: what a rollout is, described once, as plain data.

Every rollout (in-process scene, sidecar, benchmark backend) returns one from
``rollout.spec``; everything above the seam derives from it: gym spaces, HAL
limits and gripper mapping, ROS TF and CameraInfo, dataset features, policy
contracts, openpi metadata. It round-trips through JSON
(``RolloutSpec.from_json(spec.to_json()) == spec``) so it crosses a process
boundary unchanged.

Parts:

- ``ObservationSpec``: every observation key with dtype and shape (``-1`` for a
  size that varies per step, e.g. the points of a depth cloud), whether it is
  always there, declared-only or sent only on request, and its unit.
- ``ActionSpec``: the control mode and the action's slots in order, each with
  its bounds, unit and the controller group that owns it (``arm``, ``grip``,
  ``base``). ``clip``, ``pack`` and ``unpack`` live here and nowhere else.
- ``RobotFacts``: joint names and limits, gripper open/closed positions, the
  kinematic base's limits, sensor mounts and intrinsics, the URDF link tree.
- ``TaskSpec``: instruction, success key, step limit, the task's state vector
  (slot names) and the names of the diagnostics its ``evaluate`` reports.

Units: metres, radians, seconds; frames follow REP-103 (+x forward, +y left, +z up).
Imports numpy and the standard library only.
"""

from __future__ import annotations

import enum
import math
from dataclasses import dataclass
from typing import Any

import numpy as np

from simseam.seam.errors import ConfigError, InvalidActionError
from simseam.seam.keys import OBS_ENV_STATE, OBS_IMAGES, OBS_STATE


class ControlMode(str, enum.Enum):
    """How the arm part of an action is interpreted.

    - ``JOINT_POSITION``: absolute arm joint targets (rad / m), manifest order.
    - ``CARTESIAN_DELTA``: ``[dx, dy, dz, dax, day, daz]`` in [-1, 1], scaled by
      the action's max step (m, rad), in the robot base frame, solved by IK.
    - ``BODY_TWIST``: ``[vx, vy, wz]`` in the base frame (m/s, rad/s).
    - ``GRIPPER``: one scalar, -1 fully open, +1 fully closed.
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
        raise ConfigError(f"unknown control mode {value!r}; expected one of " + ", ".join(m.value for m in cls))


def _err(where: str, exc: BaseException) -> ConfigError:
    if isinstance(exc, KeyError):
        return ConfigError(f"{where}: missing field {exc.args[0]!r}")
    return ConfigError(f"{where}: malformed field: {exc}")


def _num(x: float) -> float | str:
    """JSON-safe float (``inf`` travels as the string "inf")."""
    return x if math.isfinite(x) else ("inf" if x > 0 else "-inf")


# =================================================================== observations
@dataclass(frozen=True)
class FieldSpec:
    """One observation key.

    ``dtype``: a numpy dtype name (``float32``, ``uint8``, ``float64``), or
    ``str`` / ``int`` for scalars, or ``dict`` for keyed groups whose members are
    in ``entries``. ``shape``: ``-1`` marks a size that varies per step.
    ``presence``: ``always``; ``declared`` (always present in this rollout:
    the robot has the part or sensor); ``on_request`` (present only when the
    caller's ``ObsRequest`` asks for it). ``names``: element names of a vector.
    """

    dtype: str
    shape: tuple[int, ...] = ()
    presence: str = "always"
    unit: str = ""
    names: tuple[str, ...] = ()
    entries: dict[str, "FieldSpec"] | None = None

    def to_json(self) -> dict[str, Any]:
        out: dict[str, Any] = {"dtype": self.dtype, "shape": list(self.shape), "presence": self.presence}
        if self.unit:
            out["unit"] = self.unit
        if self.names:
            out["names"] = list(self.names)
        if self.entries is not None:
            out["entries"] = {k: v.to_json() for k, v in self.entries.items()}
        return out

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "FieldSpec":
        entries = d.get("entries")
        return cls(dtype=str(d["dtype"]), shape=tuple(int(x) for x in d.get("shape", ())),
                   presence=str(d.get("presence", "always")), unit=str(d.get("unit", "")),
                   names=tuple(str(n) for n in d.get("names", ())),
                   entries=None if entries is None else {str(k): cls.from_json(v) for k, v in entries.items()})


@dataclass(frozen=True)
class ObservationSpec:
    """Every key of the observation dict (see ``simseam.seam.keys``)."""

    fields: dict[str, FieldSpec]

    @property
    def images(self) -> dict[str, tuple[int, int]]:
        """RGB cameras in the observation: feature key -> (height, width)."""
        f = self.fields.get(OBS_IMAGES)
        return {k: (e.shape[0], e.shape[1]) for k, e in (f.entries or {}).items()} if f else {}

    @property
    def state_dim(self) -> int:
        return self.fields[OBS_STATE].shape[0]

    @property
    def state_names(self) -> tuple[str, ...]:
        return self.fields[OBS_STATE].names

    @property
    def env_state_dim(self) -> int | None:
        """Length of ``environment_state``, or None when the rollout does not declare it."""
        f = self.fields.get(OBS_ENV_STATE)
        return f.shape[0] if f is not None else None

    def has(self, key: str) -> bool:
        return key in self.fields

    def to_json(self) -> dict[str, Any]:
        return {k: v.to_json() for k, v in self.fields.items()}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "ObservationSpec":
        return cls({str(k): FieldSpec.from_json(v) for k, v in d.items()})


# ======================================================================== actions
@dataclass(frozen=True)
class ActionSlot:
    """One entry of the action vector: its bounds (inclusive), unit and owning controller group."""

    name: str
    group: str  # "arm" | "grip" | "base"
    low: float
    high: float
    unit: str = ""

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "group": self.group, "low": _num(self.low), "high": _num(self.high),
                "unit": self.unit}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "ActionSlot":
        return cls(str(d["name"]), str(d["group"]), float(d["low"]), float(d["high"]), str(d.get("unit", "")))


@dataclass(frozen=True)
class NormBound:
    """Slots whose vector norm is bounded (e.g. ``[vx, vy]`` by the base's max linear speed)."""

    slots: tuple[str, ...]
    limit: float

    def to_json(self) -> dict[str, Any]:
        return {"slots": list(self.slots), "limit": self.limit}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "NormBound":
        return cls(tuple(str(s) for s in d["slots"]), float(d["limit"]))


GROUPS = ("arm", "grip", "base")


@dataclass(frozen=True)
class ActionSpec:
    """The action vector: ``float32[dim]``, slots in order ``arm..., grip?, base[vx, vy, wz]?``.

    ``max_translation`` / ``max_rotation``: metres and radians per step at
    ``|action| = 1`` (CARTESIAN_DELTA only). ``clip`` maps any finite action
    into the bounds exactly as the rollout applies it.
    """

    control_mode: ControlMode
    slots: tuple[ActionSlot, ...]
    norm_bounds: tuple[NormBound, ...] = ()
    max_translation: float = 0.0
    max_rotation: float = 0.0

    def __post_init__(self) -> None:
        seen = [s.group for s in self.slots]
        order = [g for g in GROUPS if g in seen]
        if seen != sorted(seen, key=GROUPS.index) or any(g not in GROUPS for g in seen):
            raise ConfigError(f"action slots must be grouped in the order {GROUPS}, got groups {order}")
        object.__setattr__(self, "_low", np.array([s.low for s in self.slots], dtype=np.float64))
        object.__setattr__(self, "_high", np.array([s.high for s in self.slots], dtype=np.float64))
        norm_idx = tuple((np.array([self.names.index(n) for n in b.slots]), b.limit) for b in self.norm_bounds)
        object.__setattr__(self, "_norm_idx", norm_idx)
        groups = {}
        for i, s in enumerate(self.slots):
            start, _ = groups.get(s.group, (i, i))
            groups[s.group] = (start, i + 1)
        object.__setattr__(self, "_groups", {g: slice(a, b) for g, (a, b) in groups.items()})
        object.__setattr__(self, "_grip", groups["grip"][0] if "grip" in groups else None)

    # ------------------------------------------------------------ layout
    @property
    def dim(self) -> int:
        return len(self.slots)

    @property
    def names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.slots)

    @property
    def low(self) -> np.ndarray:
        return self._low.copy()

    @property
    def high(self) -> np.ndarray:
        return self._high.copy()

    def group(self, name: str) -> slice | None:
        """The slice of ``name``'s slots (``arm``, ``grip``, ``base``), or None when absent."""
        return self._groups.get(name)

    @property
    def arm(self) -> slice:
        return self.group("arm") or slice(0, 0)

    @property
    def arm_names(self) -> tuple[str, ...]:
        return tuple(s.name for s in self.slots if s.group == "arm")

    @property
    def arm_dim(self) -> int:
        return len(self.arm_names)

    @property
    def grip(self) -> int | None:
        """Index of the gripper scalar, or None."""
        return self._grip

    @property
    def base(self) -> slice | None:
        return self.group("base")

    @property
    def has_gripper(self) -> bool:
        return self.grip is not None

    @property
    def has_base(self) -> bool:
        return self.base is not None

    # --------------------------------------------------------- operations
    def validate(self, action: Any) -> np.ndarray:
        """The action as ``float32[dim]``; ``InvalidActionError`` naming the problem otherwise."""
        return check_action(action, self.dim)

    def clip(self, action: np.ndarray) -> np.ndarray:
        """A copy of ``action`` within the slot bounds and norm bounds (what the rollout applies)."""
        out = np.minimum(np.maximum(np.asarray(action, dtype=np.float64), self._low), self._high)
        for idx, limit in self._norm_idx:
            n = float(np.linalg.norm(out[idx]))
            if n > limit:
                out[idx] *= limit / n
        return out

    def clip_group(self, name: str, values: np.ndarray) -> np.ndarray:
        """``values`` for group ``name`` alone, clipped as ``clip`` would (norm bounds within the group)."""
        sl = self.group(name)
        if sl is None:
            raise ConfigError(f"this action has no {name!r} slots (slots: {', '.join(self.names)})")
        full = (self._low + self._high) * 0.5
        full = np.where(np.isfinite(full), full, 0.0)
        full[sl] = values
        return self.clip(full)[sl]

    def pack(self, arm=None, grip: float | None = None, base=None) -> np.ndarray:
        """Build an action; omitted parts are zero."""
        out = np.zeros(self.dim, dtype=np.float32)
        if arm is not None:
            out[self.arm] = arm
        if grip is not None:
            if self.grip is None:
                raise ConfigError("this robot has no gripper")
            out[self.grip] = grip
        if base is not None:
            if self.base is None:
                raise ConfigError("this robot has no kinematic base")
            out[self.base] = base
        return out

    def unpack(self, action: np.ndarray) -> tuple[np.ndarray, float | None, np.ndarray | None]:
        """(arm part, grip scalar or None, base twist or None)."""
        grip = float(action[self.grip]) if self.grip is not None else None
        base = action[self.base] if self.base is not None else None
        return action[self.arm], grip, base

    # ------------------------------------------------------------- serde
    def to_json(self) -> dict[str, Any]:
        return {"control_mode": self.control_mode.value, "slots": [s.to_json() for s in self.slots],
                "norm_bounds": [b.to_json() for b in self.norm_bounds],
                "max_translation": self.max_translation, "max_rotation": self.max_rotation}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "ActionSpec":
        return cls(ControlMode.parse(d["control_mode"]), tuple(ActionSlot.from_json(s) for s in d["slots"]),
                   tuple(NormBound.from_json(b) for b in d.get("norm_bounds", ())),
                   float(d.get("max_translation", 0.0)), float(d.get("max_rotation", 0.0)))


def check_action(action: Any, action_dim: int) -> np.ndarray:
    """Validate an action's shape and values; return it as float32 (never mutates the caller's array).

    Raises ``InvalidActionError`` naming the problem (shape, dtype, index of the
    first non-finite entry).
    """
    try:
        arr = np.asarray(action, dtype=np.float32)
    except (TypeError, ValueError) as exc:
        raise InvalidActionError(f"action is not numeric: {exc}") from None
    if arr.ndim != 1 or arr.shape[0] != action_dim:
        raise InvalidActionError(f"action has shape {tuple(arr.shape)}, expected ({action_dim},)")
    finite = np.isfinite(arr)
    if np.count_nonzero(finite) != finite.size:  # not finite.all(): its reduction machinery costs more per call
        bad = int(np.flatnonzero(~finite)[0])
        raise InvalidActionError(f"action[{bad}] is {float(arr[bad])}; every entry must be finite")
    return arr


# ========================================================================== robot
@dataclass(frozen=True)
class JointFacts:
    """A manifest joint: role ``arm`` | ``gripper`` | ``base``; limits in rad or m (None: unbounded);
    ``max_velocity`` in rad/s or m/s (None: unbounded); ``sim_name``: its name in the URDF
    (empty: the same as ``name``; base joints are not in the URDF)."""

    name: str
    role: str
    lower: float | None = None
    upper: float | None = None
    max_velocity: float | None = None
    sim_name: str = ""

    def __post_init__(self) -> None:
        if not self.sim_name:
            object.__setattr__(self, "sim_name", self.name)


@dataclass(frozen=True)
class GripperFacts:
    """Finger joints and their positions at command -1 (open) and +1 (closed), linear in between."""

    joints: tuple[str, ...]
    open: tuple[float, ...]
    closed: tuple[float, ...]

    def command_of(self, finger_positions: np.ndarray) -> float:
        """The gripper command in [-1, 1] that matches the fingers' measured opening."""
        span = np.asarray(self.closed) - np.asarray(self.open)
        ok = np.abs(span) > 1e-9
        if not ok.any():
            return -1.0
        g = float(np.mean((np.asarray(finger_positions, dtype=np.float64)[ok] - np.asarray(self.open)[ok])
                          / span[ok]))
        return float(np.clip(round(2.0 * g - 1.0, 4), -1.0, 1.0))  # float32 noise off


@dataclass(frozen=True)
class BaseFacts:
    """A kinematic planar base: virtual joints ``[x, y, yaw]``, speed limits (m/s in norm, rad/s),
    base link height above the floor (m)."""

    joints: tuple[str, ...]
    max_linear: float
    max_angular: float
    height: float = 0.0


@dataclass(frozen=True)
class SensorFacts:
    """A declared sensor: ``kind`` rgb | depth | lidar_2d, mounted at ``xyz``/``rpy`` on ``parent``
    (the mount frame looks along +x). Cameras: ``width`` x ``height`` pixels as observed, vertical
    field of view ``fovy_deg``. Ranges in metres; lidar ``beams`` over ``fov_deg``."""

    name: str
    kind: str
    parent: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    feature_key: str = ""
    width: int = 0
    height: int = 0
    fovy_deg: float = 0.0
    range_min: float = 0.0
    range_max: float = 0.0
    beams: int = 0
    fov_deg: float = 360.0


@dataclass(frozen=True)
class LinkFacts:
    """One link of the robot's kinematic tree: its parent link (None for the root) and the joint
    between them (type and origin ``xyz``/``rpy`` in the parent frame, ``axis``)."""

    name: str
    parent: str | None = None
    joint: str = ""
    joint_type: str = "fixed"
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    axis: tuple[float, float, float] = (0.0, 0.0, 1.0)


def _tuple(d: dict, key: str, conv=float) -> tuple:
    return tuple(conv(x) for x in d[key])


@dataclass(frozen=True)
class RobotFacts:
    """What is known of the robot: ``joints`` in observation order, ``base_link`` (the frame of
    state, depth points and scans), ``tool_link`` (the end-effector frame of CARTESIAN_DELTA),
    ``urdf`` (an asset reference, empty when the backend has none)."""

    name: str
    base_link: str
    tool_link: str
    joints: tuple[JointFacts, ...]
    gripper: GripperFacts | None = None
    base: BaseFacts | None = None
    sensors: tuple[SensorFacts, ...] = ()
    links: tuple[LinkFacts, ...] = ()
    urdf: str = ""

    @property
    def joint_names(self) -> tuple[str, ...]:
        return tuple(j.name for j in self.joints)

    @property
    def arm_joints(self) -> tuple[JointFacts, ...]:
        return tuple(j for j in self.joints if j.role == "arm")

    def joint(self, name: str) -> JointFacts:
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(name)

    def sensors_of(self, kind: str) -> tuple[SensorFacts, ...]:
        return tuple(s for s in self.sensors if s.kind == kind)

    def to_json(self) -> dict[str, Any]:
        def opt(x):
            return None if x is None else _num(x)

        return {
            "name": self.name, "base_link": self.base_link, "tool_link": self.tool_link, "urdf": self.urdf,
            "joints": [{"name": j.name, "role": j.role, "lower": opt(j.lower), "upper": opt(j.upper),
                        "max_velocity": opt(j.max_velocity), "sim_name": j.sim_name} for j in self.joints],
            "gripper": None if self.gripper is None else {
                "joints": list(self.gripper.joints), "open": list(self.gripper.open),
                "closed": list(self.gripper.closed)},
            "base": None if self.base is None else {
                "joints": list(self.base.joints), "max_linear": self.base.max_linear,
                "max_angular": self.base.max_angular, "height": self.base.height},
            "sensors": [{k: (list(v) if isinstance(v, tuple) else v) for k, v in s.__dict__.items()}
                        for s in self.sensors],
            "links": [{"name": link.name, "parent": link.parent, "joint": link.joint, "joint_type": link.joint_type,
                       "xyz": list(link.xyz), "rpy": list(link.rpy), "axis": list(link.axis)} for link in self.links],
        }

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "RobotFacts":
        def opt(x):
            return None if x is None else float(x)

        g, b = d.get("gripper"), d.get("base")
        return cls(
            name=str(d["name"]), base_link=str(d["base_link"]), tool_link=str(d["tool_link"]),
            urdf=str(d.get("urdf", "")),
            joints=tuple(JointFacts(str(j["name"]), str(j["role"]), opt(j.get("lower")), opt(j.get("upper")),
                                    opt(j.get("max_velocity")), str(j.get("sim_name", ""))) for j in d["joints"]),
            gripper=None if g is None else GripperFacts(_tuple(g, "joints", str), _tuple(g, "open"),
                                                        _tuple(g, "closed")),
            base=None if b is None else BaseFacts(_tuple(b, "joints", str), float(b["max_linear"]),
                                                  float(b["max_angular"]), float(b.get("height", 0.0))),
            sensors=tuple(SensorFacts(
                name=str(s["name"]), kind=str(s["kind"]), parent=str(s["parent"]), xyz=_tuple(s, "xyz"),
                rpy=_tuple(s, "rpy"), feature_key=str(s.get("feature_key", "")), width=int(s.get("width", 0)),
                height=int(s.get("height", 0)), fovy_deg=float(s.get("fovy_deg", 0.0)),
                range_min=float(s.get("range_min", 0.0)), range_max=float(s.get("range_max", 0.0)),
                beams=int(s.get("beams", 0)), fov_deg=float(s.get("fov_deg", 360.0))) for s in d.get("sensors", ())),
            links=tuple(LinkFacts(str(x["name"]), None if x.get("parent") is None else str(x["parent"]),
                                  str(x.get("joint", "")), str(x.get("joint_type", "fixed")), _tuple(x, "xyz"),
                                  _tuple(x, "rpy"), _tuple(x, "axis")) for x in d.get("links", ())),
        )


# =========================================================================== task
@dataclass(frozen=True)
class TaskSpec:
    """What the rollout asks of the policy: ``name`` (e.g. ``lift_cube``), the instruction,
    ``info[success_key]`` is the success flag, ``max_steps`` truncates an episode,
    ``diagnostics``: names of the values ``info["diagnostics"]`` carries after each step;
    ``geometry``: sizes of the task's props in metres (e.g. ``bowl_height``), for privileged experts."""

    name: str
    instruction: str
    success_key: str = "success"
    max_steps: int = 300
    diagnostics: tuple[str, ...] = ()
    geometry: tuple[tuple[str, float], ...] = ()

    def size(self, name: str) -> float:
        """One of ``geometry``'s sizes (metres); a ``ConfigError`` naming the task when it has none."""
        for key, value in self.geometry:
            if key == name:
                return value
        raise ConfigError(f"task {self.name!r} publishes no size {name!r} (it has {[k for k, _ in self.geometry]})")

    def to_json(self) -> dict[str, Any]:
        return {"name": self.name, "instruction": self.instruction, "success_key": self.success_key,
                "max_steps": self.max_steps, "diagnostics": list(self.diagnostics), "geometry": dict(self.geometry)}

    @classmethod
    def from_json(cls, d: dict[str, Any]) -> "TaskSpec":
        return cls(str(d["name"]), str(d["instruction"]), str(d.get("success_key", "success")),
                   int(d.get("max_steps", 300)), tuple(str(x) for x in d.get("diagnostics", ())),
                   tuple((str(k), float(v)) for k, v in (d.get("geometry") or {}).items()))


# ======================================================================== rollout
#: optional abilities a rollout declares (callers never probe for methods)
CAP_RESTART = "restart"  # rollout.restart() rebuilds the simulator after a crash (sidecars)
CAP_PRIVILEGED = "privileged"  # observations carry ground truth (``privileged``)
CAP_LINK_POSES = "link_poses"  # ObsRequest(link_poses=True) is honoured


@dataclass(frozen=True)
class RolloutSpec:
    """A rollout, described once (see the module docstring). ``engine``: the simulator's name;
    ``backend``: where it runs (``inprocess``, ``sidecar``, ...); ``control_hz``: control steps
    per second of sim time."""

    robot: RobotFacts
    task: TaskSpec
    observation: ObservationSpec
    action: ActionSpec
    engine: str
    control_hz: float
    backend: str = "inprocess"
    capabilities: tuple[str, ...] = ()

    # shorthands used everywhere above the seam
    @property
    def action_dim(self) -> int:
        return self.action.dim

    @property
    def control_mode(self) -> ControlMode:
        return self.action.control_mode

    @property
    def cameras(self) -> dict[str, tuple[int, int]]:
        return self.observation.images

    @property
    def state_dim(self) -> int:
        return self.observation.state_dim

    @property
    def env_state_dim(self) -> int | None:
        return self.observation.env_state_dim

    def can(self, capability: str) -> bool:
        return capability in self.capabilities

    def describe(self) -> str:
        """One line: robot, engine, task, control mode."""
        return (f"{self.robot.name} on {self.engine} ({self.backend}), task {self.task.name}, "
                f"{self.control_mode.value} ({self.action_dim}-D actions)")

    def to_json(self) -> dict[str, Any]:
        return {"robot": self.robot.to_json(), "task": self.task.to_json(),
                "observation": self.observation.to_json(), "action": self.action.to_json(),
                "engine": self.engine, "control_hz": self.control_hz, "backend": self.backend,
                "capabilities": list(self.capabilities)}

    @classmethod
    def from_json(cls, data: Any, where: str = "rollout spec") -> "RolloutSpec":
        """Inverse of ``to_json``; a malformed document raises ``ConfigError`` naming ``where`` and the field."""
        if not isinstance(data, dict):
            raise ConfigError(f"{where}: expected a JSON object, got {type(data).__name__}")
        try:
            return cls(robot=RobotFacts.from_json(data["robot"]), task=TaskSpec.from_json(data["task"]),
                       observation=ObservationSpec.from_json(data["observation"]),
                       action=ActionSpec.from_json(data["action"]), engine=str(data["engine"]),
                       control_hz=float(data["control_hz"]), backend=str(data.get("backend", "inprocess")),
                       capabilities=tuple(str(c) for c in data.get("capabilities", ())))
        except ConfigError:
            raise
        except (KeyError, TypeError, ValueError, IndexError, AttributeError) as exc:
            raise _err(where, exc) from None

    def replace(self, **changes: Any) -> "RolloutSpec":
        import dataclasses

        return dataclasses.replace(self, **changes)


__all__ = [
    "ActionSlot", "ActionSpec", "BaseFacts", "ControlMode", "FieldSpec", "GripperFacts", "JointFacts", "LinkFacts",
    "NormBound", "ObservationSpec", "RobotFacts", "RolloutSpec", "SensorFacts", "TaskSpec", "check_action",
    "CAP_RESTART", "CAP_PRIVILEGED", "CAP_LINK_POSES",
]
