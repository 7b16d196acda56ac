"""RobotSpec: a validated robot manifest as plain, JSON-ready data.

The manifest (YAML, validated with pydantic on the client side) is turned into
a ``RobotSpec`` once; engines, scenes and sidecars only ever see the spec. It
uses dataclasses of JSON types (str, float, int, bool, list, dict) so it can
cross a process boundary as JSON and be rebuilt with the standard library.

Frames and units: lengths in metres, angles in radians. A sensor mount pose
(``xyz``, ``rpy``) is relative to its ``parent`` link; the mount frame follows
REP-103: +x is the viewing direction, +y left, +z up.
"""

from __future__ import annotations

import json
from dataclasses import asdict, dataclass, field
from typing import Any

ROLES = ("arm", "gripper", "base")
SENSOR_KINDS = ("rgb", "depth", "lidar_2d")


@dataclass(frozen=True)
class JointSpec:
    """One controllable joint, in manifest order.

    ``sim_name`` is the joint's name inside the simulator model (defaults to
    ``name``). ``lower``/``upper`` come from the URDF unless the manifest
    narrows them. ``kp``/``kd`` are position-servo gains (N m/rad, N m s/rad).
    ``max_velocity`` bounds how far one control step may move the joint's target.
    """

    name: str
    role: str
    sim_name: str
    home: float = 0.0
    lower: float | None = None
    upper: float | None = None
    kp: float | None = None
    kd: float | None = None
    max_velocity: float | None = None  # rad/s or m/s, from the URDF <limit velocity>


@dataclass(frozen=True)
class GripperSpec:
    """Gripper joints and their positions at -1 (open) and +1 (closed)."""

    joints: list[str]
    open: list[float]
    closed: list[float]


@dataclass(frozen=True)
class SensorSpec:
    """A declared sensor. Only declared sensors are ever created.

    rgb/depth: ``width`` x ``height`` pixels, vertical field of view ``fovy_deg``.
    depth/lidar_2d: valid ranges in [``range_min``, ``range_max``] metres.
    lidar_2d: ``beams`` rays over ``fov_deg`` centred on the mount's +x.
    ``feature_key`` names the image in ``observation['images']``.
    """

    name: str
    kind: str
    parent: str
    xyz: list[float]
    rpy: list[float]
    feature_key: str
    width: int = 0
    height: int = 0
    fovy_deg: float = 0.0
    range_min: float = 0.0
    range_max: float = 0.0
    beams: int = 0
    fov_deg: float = 360.0


@dataclass(frozen=True)
class KinematicBaseSpec:
    """A planar holonomic base moved kinematically (the robot root is teleported).

    ``joints``: names of the virtual [x, y, yaw] joints (not in the URDF).
    ``max_linear`` (m/s, norm of [vx, vy]) and ``max_angular`` (rad/s) clip
    BODY_TWIST. ``height``: z of the base link above the floor (m). ``shapes``:
    primitive chassis geometry fixed to the base link (``{kind, size, pos,
    rgba}``, same conventions as ``engines.base.Shape``), part of the robot.
    """

    joints: list[str]
    max_linear: float
    max_angular: float
    height: float = 0.0
    shapes: list[dict] = field(default_factory=list)


@dataclass(frozen=True)
class ToolFrameSpec:
    """A tool frame (TCP) fixed to a URDF link: ``xyz``/``rpy`` place it in ``parent``'s frame.

    For URDFs without a link where the fingers close. It is a virtual link named ``name``:
    the scene composes the offset (IK, the Cartesian action frame, state, link poses);
    engines never see it.
    """

    name: str
    parent: str
    xyz: list[float]
    rpy: list[float]


@dataclass(frozen=True)
class ActionSpec:
    """The robot's default action contract."""

    control_mode: str = "cartesian_delta"
    max_translation: float = 0.05
    max_rotation: float = 0.5


@dataclass(frozen=True)
class RobotSpec:
    """Everything an engine and a scene need to build and drive one robot.

    ``urdf`` is an asset reference (``pkg:<dist>/<path>`` or ``file:<path>``),
    resolved by ``simseam.robot.assets.resolve_asset`` in the process that
    loads it. ``joints`` is the manifest order that observations use.
    ``ee_link`` names the tool frame: a URDF link, or ``tcp.name`` when the
    manifest declares a ``tcp`` (a virtual link fixed to ``tcp.parent``).
    """

    name: str
    urdf: str
    base_link: str
    ee_link: str
    joints: list[JointSpec]
    gripper: GripperSpec | None = None
    sensors: list[SensorSpec] = field(default_factory=list)
    kinematic_base: KinematicBaseSpec | None = None
    action: ActionSpec = field(default_factory=ActionSpec)
    description: str = ""
    source: str = ""
    #: "urdf": the URDF's masses/inertias; "geometry": computed from collision geometry
    inertia: str = "urdf"
    tcp: ToolFrameSpec | None = None
    #: "mesh": the URDF's collision meshes; "primitives": fitted capsules (boxes for gripper fingers)
    collision: str = "mesh"

    # ------------------------------------------------------------ derived views
    def joints_with_role(self, role: str) -> list[JointSpec]:
        return [j for j in self.joints if j.role == role]

    @property
    def arm_joints(self) -> list[JointSpec]:
        return self.joints_with_role("arm")

    @property
    def tool_parent(self) -> str:
        """The URDF link the tool frame is fixed to (the tool link itself without a ``tcp``)."""
        return self.tcp.parent if self.tcp is not None else self.ee_link

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    def sensors_of(self, kind: str) -> list[SensorSpec]:
        return [s for s in self.sensors if s.kind == kind]

    # ----------------------------------------------------------------- (de)serde
    def to_json(self) -> dict[str, Any]:
        return asdict(self)

    def dumps(self) -> str:
        return json.dumps(self.to_json(), sort_keys=True)

    @classmethod
    def from_json(cls, data: dict[str, Any]) -> "RobotSpec":
        d = dict(data)
        d["joints"] = [JointSpec(**j) for j in d["joints"]]
        d["sensors"] = [SensorSpec(**s) for s in d.get("sensors", [])]
        if d.get("gripper") is not None:
            d["gripper"] = GripperSpec(**d["gripper"])
        if d.get("kinematic_base") is not None:
            d["kinematic_base"] = KinematicBaseSpec(**d["kinematic_base"])
        d["action"] = ActionSpec(**d.get("action", {}))
        if d.get("tcp") is not None:
            d["tcp"] = ToolFrameSpec(**d["tcp"])
        return cls(**d)
