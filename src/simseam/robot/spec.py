"""RobotSpec: a validated robot manifest as plain, JSON-ready data.

It is described with the seam's own facts (``JointFacts``, ``GripperFacts``, ``SensorFacts``,
``BaseFacts``), extended only by what the scene alone uses (a joint's home and gains, a base's
chassis shapes, the default action contract), so a robot is described once.

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

from simseam.seam.spec import BaseFacts, GripperFacts, JointFacts, SensorFacts


@dataclass(frozen=True)
class JointSpec(JointFacts):
    """One controllable joint, in manifest order: the seam's ``JointFacts`` (name, role, limits from the
    URDF unless the manifest narrows them, ``max_velocity``, ``sim_name``: its name in the simulator
    model) plus what only the scene uses: ``home`` (its reset position) and ``kp``/``kd``
    (position-servo gains, N m/rad and N m s/rad; None: the engine's defaults)."""

    home: float = 0.0
    kp: float | None = None
    kd: float | None = None


@dataclass(frozen=True)
class KinematicBaseSpec(BaseFacts):
    """A planar holonomic base moved kinematically (the robot root is teleported): the seam's
    ``BaseFacts`` (virtual [x, y, yaw] ``joints``, not in the URDF; ``max_linear`` m/s in norm and
    ``max_angular`` rad/s, which clip BODY_TWIST; ``height`` of the base link above the floor) plus
    ``shapes``: primitive chassis geometry fixed to the base link (``{kind, size, pos, rgba}``, same
    conventions as ``engines.base.Shape``), part of the robot."""

    shapes: tuple[dict, ...] = ()


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
class ActionDefaults:
    """The robot's default action contract (the scene's controllers turn it into the seam's ``ActionSpec``)."""

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
    gripper: GripperFacts | None = None
    sensors: list[SensorFacts] = field(default_factory=list)
    kinematic_base: KinematicBaseSpec | None = None
    action: ActionDefaults = field(default_factory=ActionDefaults)
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

    def sensors_of(self, kind: str) -> list[SensorFacts]:
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
        d["sensors"] = [SensorFacts(**{**s, "xyz": tuple(s["xyz"]), "rpy": tuple(s["rpy"])})
                        for s in d.get("sensors", [])]
        if d.get("gripper") is not None:
            g = d["gripper"]
            d["gripper"] = GripperFacts(tuple(g["joints"]), tuple(g["open"]), tuple(g["closed"]))
        if d.get("kinematic_base") is not None:
            k = d["kinematic_base"]
            d["kinematic_base"] = KinematicBaseSpec(**{**k, "joints": tuple(k["joints"]),
                                                       "shapes": tuple(k.get("shapes", ()))})
        d["action"] = ActionDefaults(**d.get("action", {}))
        if d.get("tcp") is not None:
            d["tcp"] = ToolFrameSpec(**d["tcp"])
        return cls(**d)
