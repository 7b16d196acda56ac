"""Robot manifests: validated YAML -> RobotSpec (client side; uses pydantic).

A manifest is checked twice: against its schema (unknown keys are errors) and
against its URDF (every joint, the base, end-effector and sensor parent links
must exist there). Every error is a ``ConfigError`` whose message names the
manifest file and the field, and, for URDF mismatches, lists what the URDF has.
"""

from __future__ import annotations

from pathlib import Path
from typing import Literal

from pydantic import BaseModel, ConfigDict, Field, model_validator

from simseam.config_files import load_yaml_model
from simseam.robot.assets import resolve_asset
from simseam.robot.spec import (
    ActionDefaults,
    JointSpec,
    KinematicBaseSpec,
    RobotSpec,
    ToolFrameSpec,
)
from simseam.robot.urdf import read_urdf
from simseam.seam import BackendUnavailableError, ConfigError, GripperFacts, SensorFacts
from simseam.seam.errors import did_you_mean

BUILTIN_DIR = Path(__file__).parent / "manifests"


class _Strict(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


class JointModel(_Strict):
    name: str
    role: Literal["arm", "gripper", "base"]
    sim_name: str | None = None
    home: float = 0.0
    limits: tuple[float, float] | None = None
    kp: float | None = Field(default=None, gt=0)
    kd: float | None = Field(default=None, ge=0)


class GripperModel(_Strict):
    open: list[float]
    closed: list[float]


class ShapeModel(_Strict):
    kind: Literal["box", "sphere", "cylinder"]
    size: list[float] = Field(min_length=1, max_length=3)
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rgba: tuple[float, float, float, float] = (0.3, 0.3, 0.32, 1.0)


class KinematicBaseModel(_Strict):
    joints: tuple[str, str, str]
    max_linear: float = Field(default=0.5, gt=0)
    max_angular: float = Field(default=1.0, gt=0)
    height: float = Field(default=0.0, ge=0)
    shapes: list[ShapeModel] = []


class SensorModel(_Strict):
    name: str
    kind: Literal["rgb", "depth", "lidar_2d"]
    parent: str
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)
    feature_key: str | None = None
    width: int = Field(default=0, ge=0, le=4096)
    height: int = Field(default=0, ge=0, le=4096)
    fovy_deg: float = Field(default=0.0, ge=0, lt=180)
    range_min: float = Field(default=0.0, ge=0)
    range_max: float = Field(default=0.0, ge=0)
    beams: int = Field(default=0, ge=0)
    fov_deg: float = Field(default=360.0, gt=0, le=360)

    @model_validator(mode="after")
    def _kind_fields(self) -> "SensorModel":
        if self.kind in ("rgb", "depth"):
            if not (self.width and self.height and self.fovy_deg):
                raise ValueError(f"sensor {self.name!r} ({self.kind}) needs width, height and fovy_deg")
        if self.kind in ("depth", "lidar_2d") and not (0 <= self.range_min < self.range_max):
            raise ValueError(f"sensor {self.name!r} ({self.kind}) needs 0 <= range_min < range_max")
        if self.kind == "lidar_2d" and self.beams < 1:
            raise ValueError(f"sensor {self.name!r} (lidar_2d) needs beams >= 1")
        return self


class ToolFrameModel(_Strict):
    """A tool frame fixed to a URDF link (for URDFs without a link where the fingers close)."""

    name: str = Field(default="tcp", pattern=r"^[A-Za-z0-9_\-]+$")
    parent: str
    xyz: tuple[float, float, float] = (0.0, 0.0, 0.0)
    rpy: tuple[float, float, float] = (0.0, 0.0, 0.0)


class ActionModel(_Strict):
    control_mode: Literal["joint_position", "cartesian_delta"] = "cartesian_delta"
    max_translation: float = Field(default=0.05, gt=0)
    max_rotation: float = Field(default=0.5, gt=0)


class ManifestModel(_Strict):
    name: str = Field(pattern=r"^[A-Za-z0-9_\-]+$")
    description: str = ""
    urdf: str
    base_link: str
    ee_link: str | None = None
    tcp: ToolFrameModel | None = None
    joints: list[JointModel] = Field(min_length=1)
    gripper: GripperModel | None = None
    kinematic_base: KinematicBaseModel | None = None
    sensors: list[SensorModel] = []
    action: ActionModel = ActionModel()
    inertia: Literal["urdf", "geometry"] = "urdf"
    # "primitives": each link's collision meshes collide as fitted capsules (boxes for gripper fingers)
    collision: Literal["mesh", "primitives"] = "mesh"

    @model_validator(mode="after")
    def _consistent(self) -> "ManifestModel":
        if (self.ee_link is None) == (self.tcp is None):
            raise ValueError("give the tool frame either as 'ee_link' (a URDF link) or as 'tcp' "
                             "({parent: LINK, xyz: [...], rpy: [...]}), exactly one of them")
        names = [j.name for j in self.joints]
        dupes = sorted({n for n in names if names.count(n) > 1})
        if dupes:
            raise ValueError(f"duplicate joint names {dupes}")
        if not any(j.role == "arm" for j in self.joints):
            raise ValueError("at least one joint must have role 'arm'")
        grip = [j.name for j in self.joints if j.role == "gripper"]
        if grip and self.gripper is None:
            raise ValueError(f"joints {grip} have role 'gripper' but no 'gripper' section gives open/closed positions")
        if self.gripper is not None:
            if not grip:
                raise ValueError("'gripper' section given but no joint has role 'gripper'")
            for key in ("open", "closed"):
                vals = getattr(self.gripper, key)
                if len(vals) != len(grip):
                    raise ValueError(f"gripper.{key} has {len(vals)} values for {len(grip)} gripper joints {grip}")
        base = [j.name for j in self.joints if j.role == "base"]
        if self.kinematic_base is None and base:
            raise ValueError(f"joints {base} have role 'base' but no 'kinematic_base' section")
        if self.kinematic_base is not None and sorted(base) != sorted(self.kinematic_base.joints):
            raise ValueError(
                f"kinematic_base.joints {list(self.kinematic_base.joints)} must be exactly the role-'base' joints {base}"
            )
        keys = [s.feature_key or s.name for s in self.sensors]
        snames = [s.name for s in self.sensors]
        for label, seq in (("sensor names", snames), ("feature keys", keys)):
            d = sorted({k for k in seq if seq.count(k) > 1})
            if d:
                raise ValueError(f"duplicate {label} {d}")
        return self


def parse_manifest(path: str | Path) -> ManifestModel:
    """Read and schema-validate a manifest file (no URDF access)."""
    return load_yaml_model(path, ManifestModel, "robot manifest")


def _absolute_ref(ref: str, base_dir: Path) -> str:
    if ref.startswith("file:") and not Path(ref[5:]).expanduser().is_absolute():
        return "file:" + str((base_dir / ref[5:]).resolve())
    return ref


def _within(value: float, lower: float | None, upper: float | None, tol: float = 1e-9) -> bool:
    return (lower is None or value >= lower - tol) and (upper is None or value <= upper + tol)


def _listing(items: list[str]) -> str:
    return ", ".join(items) if items else "(none)"


def load_manifest(path: str | Path) -> RobotSpec:
    """Validate a manifest file against its schema and its URDF; return its RobotSpec.

    Joint limits come from the URDF unless the manifest narrows them. Raises
    ``ConfigError`` naming the file and field; ``BackendUnavailableError`` if
    the URDF's package is not installed.
    """
    path = Path(path).resolve()
    m = parse_manifest(path)
    urdf_ref = _absolute_ref(m.urdf, path.parent)
    try:
        urdf_path = resolve_asset(urdf_ref, path.parent)
    except ConfigError as exc:
        raise ConfigError(f"{path}: field 'urdf': {exc}") from None
    except BackendUnavailableError as exc:
        raise BackendUnavailableError(f"{path}: field 'urdf': {exc}") from None
    urdf = read_urdf(urdf_path)
    problems: list[str] = []
    _check_links(m, list(urdf.links), problems)
    joints = _joints(m, urdf, problems)
    _check_gripper(m, joints, problems)
    if problems:
        raise ConfigError(f"{path}: manifest does not match its URDF {urdf_path}\n  " + "\n  ".join(problems))
    return RobotSpec(
        name=m.name,
        urdf=urdf_ref,
        base_link=m.base_link,
        ee_link=m.tcp.name if m.tcp is not None else m.ee_link,
        tcp=None if m.tcp is None else ToolFrameSpec(m.tcp.name, m.tcp.parent, list(m.tcp.xyz), list(m.tcp.rpy)),
        joints=joints,
        gripper=None if m.gripper is None else GripperFacts(tuple(j.name for j in m.joints if j.role == "gripper"),
                                                            tuple(m.gripper.open), tuple(m.gripper.closed)),
        sensors=[_sensor(s) for s in m.sensors],
        kinematic_base=None if m.kinematic_base is None else _kinematic_base(m.kinematic_base),
        action=ActionDefaults(**m.action.model_dump()),
        description=m.description,
        source=str(path),
        inertia=m.inertia,
        collision=m.collision,
    )


def _check_links(m, links: list[str], problems: list[str]) -> None:
    """The links the manifest names (base, end effector, tool parent, sensor parents) are the URDF's."""
    for field_name, link in (("base_link", m.base_link), ("ee_link", m.ee_link),
                             ("tcp.parent", m.tcp.parent if m.tcp else None)):
        if link is not None and link not in links:
            problems.append(f"field '{field_name}': link {link!r} is not in the URDF; its links are: {_listing(links)}")
    if m.tcp is not None and m.tcp.name in links:
        problems.append(f"field 'tcp.name': {m.tcp.name!r} is already a link of the URDF; name the tool frame "
                        f"differently, or use ee_link: {m.tcp.name} instead of tcp")
    for i, s in enumerate(m.sensors):
        if s.parent not in links:
            problems.append(
                f"field 'sensors.{i}.parent' ({s.name}): link {s.parent!r} is not in the URDF; its links are: {_listing(links)}"
            )


def _joints(m, urdf, problems: list[str]) -> list[JointSpec]:
    """The manifest's joints with the URDF's limits, narrowed by the manifest's; each mismatch a problem."""
    movable = urdf.movable_joint_names
    joints: list[JointSpec] = []
    for i, j in enumerate(m.joints):
        sim_name = j.sim_name or j.name
        lower = upper = velocity = None
        if j.role != "base":
            if sim_name not in movable:
                problems.append(
                    f"field 'joints.{i}' ({j.name}): joint {sim_name!r} is not a movable joint of the URDF; "
                    f"its movable joints are: {_listing(movable)}"
                )
                continue
            uj = urdf.joint(sim_name)
            lower, upper, velocity = uj.lower, uj.upper, uj.velocity
        if j.limits is not None:
            lo, hi = j.limits
            if lo >= hi:
                problems.append(f"field 'joints.{i}.limits': lower {lo} must be below upper {hi}")
            lower = lo if lower is None else max(lower, lo)
            upper = hi if upper is None else min(upper, hi)
        if j.role != "base" and not _within(j.home, lower, upper):
            problems.append(f"field 'joints.{i}.home' ({j.name}): {j.home:g} is outside the joint limits "
                            f"[{lower:g}, {upper:g}]")
        joints.append(JointSpec(j.name, j.role, lower, upper, velocity, sim_name, home=j.home, kp=j.kp, kd=j.kd))
    return joints


def _check_gripper(m, joints: list[JointSpec], problems: list[str]) -> None:
    """The gripper's open and closed positions lie within its finger joints' limits."""
    if m.gripper is None:
        return
    by_name = {j.name: j for j in joints}
    grip_joints = [j.name for j in m.joints if j.role == "gripper"]
    for key in ("open", "closed"):
        for k, (name, value) in enumerate(zip(grip_joints, getattr(m.gripper, key))):
            j = by_name.get(name)
            if j is not None and not _within(value, j.lower, j.upper):
                problems.append(f"field 'gripper.{key}.{k}' ({name}): {value:g} is outside the finger joint's "
                                f"limits [{j.lower:g}, {j.upper:g}]")


def _kinematic_base(k) -> KinematicBaseSpec:
    return KinematicBaseSpec(tuple(k.joints), k.max_linear, k.max_angular, k.height,
                             tuple(sh.model_dump(mode="json") for sh in k.shapes))


def _sensor(s) -> SensorFacts:
    return SensorFacts(name=s.name, kind=s.kind, parent=s.parent, xyz=tuple(s.xyz), rpy=tuple(s.rpy),
                       feature_key=s.feature_key or s.name, width=s.width, height=s.height, fovy_deg=s.fovy_deg,
                       range_min=s.range_min, range_max=s.range_max, beams=s.beams, fov_deg=s.fov_deg)



def builtin_manifests() -> dict[str, Path]:
    """Names of the manifests shipped with simseam -> their files."""
    return {p.stem: p for p in sorted(BUILTIN_DIR.glob("*.yaml"))}


def find_manifest(name_or_path: str) -> Path:
    """A built-in robot name or a manifest file path -> the manifest file."""
    builtin = builtin_manifests()
    if name_or_path in builtin:
        return builtin[name_or_path]
    p = Path(name_or_path)
    if p.suffix in (".yaml", ".yml") and p.is_file():
        return p
    raise ConfigError(
        f"unknown robot {name_or_path!r}{did_you_mean(name_or_path, builtin)}: not a built-in robot "
        f"({', '.join(builtin) or 'none'}) and not a manifest file"
    )


def load_robot(name_or_path: str) -> RobotSpec:
    """Load a built-in robot by name, or a manifest by path."""
    return load_manifest(find_manifest(name_or_path))
