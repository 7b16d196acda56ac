"""Robot manifests: YAML -> validated RobotSpec, and every way a manifest can be wrong.

Manifests under test are written into ``tmp_path`` next to a copy of the
test-only ``tests/assets/tiny_arm.urdf`` (links base_link, link1..3, tip_link;
movable joints joint1 [-2.9, 2.9], joint2 [-1.2, 1.2], joint3 prismatic [0, 0.1]).
"""

from __future__ import annotations

import copy
import json
import shutil
from pathlib import Path

import pytest
import yaml

from simseam.robot.assets import resolve_asset
from simseam.robot.manifest import builtin_manifests, find_manifest, load_manifest, load_robot
from simseam.robot.spec import RobotSpec
from simseam.robot.urdf import read_urdf
from simseam.seam import ConfigError

TINY_URDF = Path(__file__).resolve().parents[1] / "assets" / "tiny_arm.urdf"

TINY = {
    "name": "tiny",
    "description": "test arm",
    "urdf": "file:tiny_arm.urdf",
    "base_link": "base_link",
    "ee_link": "tip_link",
    "joints": [
        {"name": "shoulder_yaw", "sim_name": "joint1", "role": "arm", "home": 0.1, "kp": 300, "kd": 5},
        {"name": "joint2", "role": "arm", "home": -0.2},
        {"name": "joint3", "role": "gripper", "home": 0.05},
    ],
    "gripper": {"open": [0.1], "closed": [0.0]},
    "sensors": [
        {"name": "wrist", "kind": "rgb", "parent": "link3", "xyz": [0.05, 0, 0.02], "rpy": [0, 0.3, 0],
         "width": 64, "height": 48, "fovy_deg": 60, "feature_key": "camera2"},
        {"name": "belly", "kind": "depth", "parent": "base_link", "width": 32, "height": 24, "fovy_deg": 50,
         "range_min": 0.05, "range_max": 4.0},
        {"name": "scan", "kind": "lidar_2d", "parent": "base_link", "beams": 90, "range_min": 0.1, "range_max": 8.0},
    ],
    "action": {"control_mode": "joint_position", "max_translation": 0.02, "max_rotation": 0.3},
}


def mobile_tiny() -> dict:
    """TINY on a kinematic planar base (base joints are not in the URDF)."""
    data = copy.deepcopy(TINY)
    data["joints"] += [
        {"name": "base_x", "role": "base"},
        {"name": "base_y", "role": "base"},
        {"name": "base_yaw", "role": "base", "limits": [-3.0, 3.0]},
    ]
    data["kinematic_base"] = {"joints": ["base_x", "base_y", "base_yaw"], "max_linear": 0.4, "max_angular": 0.8}
    return data


@pytest.fixture
def write(tmp_path):
    """``write(data, name='tiny.yaml')`` -> path of a manifest next to a copy of tiny_arm.urdf."""
    shutil.copy(TINY_URDF, tmp_path / "tiny_arm.urdf")

    def _write(data, name: str = "tiny.yaml") -> Path:
        path = tmp_path / name
        path.write_text(data if isinstance(data, str) else yaml.safe_dump(data, sort_keys=False))
        return path

    return _write


def edited(**changes) -> dict:
    data = copy.deepcopy(TINY)
    data.update(changes)
    return data


# ------------------------------------------------------------------ valid manifests
def test_tiny_manifest_becomes_a_spec(write):
    path = write(TINY)
    spec = load_manifest(path)
    assert spec.name == "tiny" and spec.description == "test arm"
    assert spec.source == str(path.resolve())
    assert spec.base_link == "base_link" and spec.ee_link == "tip_link"
    assert spec.joint_names == ["shoulder_yaw", "joint2", "joint3"]
    j1, j2, j3 = spec.joints
    assert (j1.sim_name, j1.role, j1.home, j1.kp, j1.kd) == ("joint1", "arm", 0.1, 300, 5)
    assert (j2.sim_name, j2.kp, j2.kd) == ("joint2", None, None)
    # limits come from the URDF
    assert (j1.lower, j1.upper) == (-2.9, 2.9)
    assert (j2.lower, j2.upper) == (-1.2, 1.2)
    assert (j3.lower, j3.upper) == (0.0, 0.1)
    assert (j1.max_velocity, j3.max_velocity) == (2.0, 0.2)  # URDF <limit velocity>
    assert spec.inertia == "urdf"  # the default
    assert [j.name for j in spec.arm_joints] == ["shoulder_yaw", "joint2"]
    assert spec.gripper.joints == ("joint3",)  # the seam's GripperFacts
    assert (spec.gripper.open, spec.gripper.closed) == ((0.1,), (0.0,))
    assert spec.kinematic_base is None
    wrist, belly, scan = spec.sensors
    assert (wrist.feature_key, wrist.width, wrist.height, wrist.xyz, wrist.rpy) == (
        "camera2", 64, 48, (0.05, 0, 0.02), (0, 0.3, 0))
    assert belly.feature_key == "belly"  # defaults to the sensor name
    assert (scan.kind, scan.beams, scan.range_max, scan.fov_deg) == ("lidar_2d", 90, 8.0, 360.0)
    assert [s.name for s in spec.sensors_of("rgb")] == ["wrist"]
    assert (spec.action.control_mode, spec.action.max_translation, spec.action.max_rotation) == (
        "joint_position", 0.02, 0.3)


def test_relative_urdf_is_resolved_against_the_manifest_directory(write, tmp_path, monkeypatch):
    """The spec carries an absolute file: reference, usable from any working directory (or a sidecar)."""
    elsewhere = tmp_path / "elsewhere"
    elsewhere.mkdir()
    monkeypatch.chdir(elsewhere)
    sub = tmp_path / "robots"
    sub.mkdir()
    path = write(edited(urdf="file:../tiny_arm.urdf"), name="robots/tiny.yaml")
    spec = load_manifest(path)
    assert spec.urdf.startswith("file:")
    assert Path(spec.urdf[5:]).is_absolute()
    assert resolve_asset(spec.urdf) == (tmp_path / "tiny_arm.urdf").resolve()


def test_manifest_limits_narrow_the_urdf_limits(write):
    data = copy.deepcopy(TINY)
    data["joints"][0]["limits"] = [-1.0, 3.5]  # narrows the lower bound only
    data["joints"][1]["limits"] = [-0.5, 0.25]  # narrows both
    spec = load_manifest(write(data))
    assert (spec.joints[0].lower, spec.joints[0].upper) == (-1.0, 2.9)
    assert (spec.joints[1].lower, spec.joints[1].upper) == (-0.5, 0.25)
    assert (spec.joints[2].lower, spec.joints[2].upper) == (0.0, 0.1)


def test_kinematic_base_joints_need_no_urdf_joint(write):
    spec = load_manifest(write(mobile_tiny()))
    assert spec.kinematic_base.joints == ("base_x", "base_y", "base_yaw")
    assert (spec.kinematic_base.max_linear, spec.kinematic_base.max_angular) == (0.4, 0.8)
    base = {j.name: j for j in spec.joints_with_role("base")}
    assert (base["base_x"].lower, base["base_x"].upper) == (None, None)
    assert (base["base_yaw"].lower, base["base_yaw"].upper) == (-3.0, 3.0)
    assert base["base_x"].max_velocity is None


def test_inertia_source(write):
    assert load_manifest(write(edited(inertia="geometry"))).inertia == "geometry"
    assert load_robot("franka_panda").inertia == "geometry"  # pybullet's Panda has placeholder inertias


def test_collision_model(write):
    assert load_manifest(write(TINY)).collision == "mesh"
    assert load_manifest(write(edited(collision="primitives"))).collision == "primitives"
    with pytest.raises(ConfigError, match="collision"):
        load_manifest(write(edited(collision="spheres")))


def test_spec_json_round_trip(write):
    """RobotSpec -> JSON text -> RobotSpec is lossless (it crosses process boundaries this way)."""
    specs = [load_manifest(write(TINY)), load_manifest(write(mobile_tiny(), "mobile.yaml"))]
    specs += [load_robot(name) for name in builtin_manifests()]
    for spec in specs:
        text = spec.dumps()
        again = RobotSpec.from_json(json.loads(text))
        assert again == spec
        assert again.dumps() == text


@pytest.mark.parametrize("name", sorted(builtin_manifests()))
def test_builtin_manifest_matches_its_urdf(name):
    spec = load_robot(name)
    assert spec.name == name
    urdf = read_urdf(resolve_asset(spec.urdf))
    assert spec.base_link == urdf.root_link
    assert spec.tool_parent in urdf.links  # the tool link, or the link a manifest tcp is fixed to
    assert (spec.ee_link in urdf.links) == (spec.tcp is None)
    for joint in spec.joints:
        if joint.role == "base":  # kinematic base joints are virtual: not in the URDF
            assert spec.kinematic_base is not None and joint.name in spec.kinematic_base.joints
            continue
        uj = urdf.joint(joint.sim_name)
        assert uj.type in ("revolute", "prismatic")
        assert (joint.lower, joint.upper, joint.max_velocity) == (uj.lower, uj.upper, uj.velocity)
        assert joint.lower <= joint.home <= joint.upper, joint.name
    # the arm joints form the chain from the base to the end effector
    chain = [j.name for j in urdf.chain(spec.base_link, spec.tool_parent) if j.type != "fixed"]
    assert [j.sim_name for j in spec.arm_joints] == chain
    grip = spec.gripper
    assert len(grip.open) == len(grip.closed) == len(grip.joints) == len(spec.joints_with_role("gripper"))
    # LIBERO-shaped cameras: third-person camera1 and (tabletop arms) wrist camera2, 256x256 RGB
    cams = {s.feature_key: s for s in spec.sensors_of("rgb")}
    assert ({"camera1", "camera2"} if spec.kinematic_base is None else {"camera1"}) <= set(cams)
    assert all((s.width, s.height) == (256, 256) and s.parent in urdf.links for s in cams.values())


def test_panda_manifest():
    spec = load_robot("franka_panda")
    assert spec.joint_names == [f"panda_joint{i}" for i in range(1, 8)] + ["panda_finger_joint1",
                                                                          "panda_finger_joint2"]
    assert [j.role for j in spec.joints] == ["arm"] * 7 + ["gripper"] * 2
    assert spec.ee_link == "panda_grasptarget"
    assert spec.gripper.open == (0.04, 0.04) and spec.gripper.closed == (0.0, 0.0)
    assert spec.joints[3].lower == pytest.approx(-3.1416) and spec.joints[3].upper == 0.0
    assert spec.action.control_mode == "cartesian_delta"


def test_find_manifest_by_name_or_path(write):
    assert find_manifest("franka_panda") == builtin_manifests()["franka_panda"]
    path = write(TINY)
    assert find_manifest(str(path)) == path
    assert load_robot(str(path)).name == "tiny"


def test_unknown_robot_lists_builtins():
    with pytest.raises(ConfigError) as err:
        load_robot("robby")
    msg = str(err.value)
    assert "'robby'" in msg
    for name in builtin_manifests():
        assert name in msg


# ------------------------------------------------------------------ invalid manifests
def _joints(*patches) -> list[dict]:
    joints = copy.deepcopy(TINY["joints"])
    for i, patch in patches:
        joints[i].update(patch)
    return joints


BAD = {
    # id: (manifest data, substrings the message must contain besides the file name)
    "unknown top-level key": (edited(colour="red"), ["'colour'", "unknown key"]),
    "unknown nested key": (edited(joints=_joints((0, {"colour": "red"}))), ["'joints.0.colour'", "unknown key"]),
    "unknown sensor key": (edited(sensors=[{**TINY["sensors"][0], "exposure": 3}]), ["'sensors.0.exposure'"]),
    "bad role": (edited(joints=_joints((1, {"role": "leg"}))), ["'joints.1.role'", "'arm', 'gripper' or 'base'"]),
    "missing field": ({k: v for k, v in TINY.items() if k != "ee_link"}, ["'ee_link'"]),
    "bad name": (edited(name="my robot!"), ["'name'"]),
    "negative kp": (edited(joints=_joints((0, {"kp": -1}))), ["'joints.0.kp'"]),
    "joint not in urdf": (
        edited(joints=_joints((1, {"name": "elbow"}))),
        ["'joints.1'", "'elbow'", "movable joints are: joint1, joint2, joint3"],
    ),
    "sim_name not in urdf": (
        edited(joints=_joints((0, {"sim_name": "joint9"}))),
        ["'joints.0'", "'joint9'", "joint1, joint2, joint3"],
    ),
    "ee_link not in urdf": (
        edited(ee_link="hand"), ["'ee_link'", "'hand'", "base_link, link1, link2, link3, tip_link"]),
    "base_link not in urdf": (edited(base_link="chassis"), ["'base_link'", "'chassis'", "tip_link"]),
    "sensor parent not in urdf": (
        edited(sensors=[{**TINY["sensors"][0], "parent": "wrist_link"}]),
        ["'sensors.0.parent'", "'wrist_link'", "base_link, link1, link2, link3, tip_link"],
    ),
    "gripper open length": (edited(gripper={"open": [0.1, 0.1], "closed": [0.0]}), ["gripper.open", "2 values"]),
    "gripper closed length": (edited(gripper={"open": [0.1], "closed": []}), ["gripper.closed", "0 values"]),
    "gripper joints without section": ({k: v for k, v in TINY.items() if k != "gripper"}, ["gripper", "joint3"]),
    "duplicate joint names": (edited(joints=_joints((1, {"name": "joint3"}))), ["duplicate joint names", "joint3"]),
    "no arm joint": (edited(joints=_joints((0, {"role": "gripper"}), (1, {"role": "gripper"}))), ["'arm'"]),
    "rgb without width": (
        edited(sensors=[{k: v for k, v in TINY["sensors"][0].items() if k != "width"}]),
        ["'sensors.0'", "'wrist'", "width"],
    ),
    "depth without range": (
        edited(sensors=[{k: v for k, v in TINY["sensors"][1].items() if k != "range_max"}]),
        ["'sensors.0'", "range_max"],
    ),
    "lidar without beams": (
        edited(sensors=[{k: v for k, v in TINY["sensors"][2].items() if k != "beams"}]), ["'sensors.0'", "beams"]),
    "duplicate feature keys": (
        edited(sensors=[TINY["sensors"][0], {**TINY["sensors"][1], "feature_key": "camera2"}]),
        ["duplicate feature keys", "camera2"],
    ),
    "inverted limits": (edited(joints=_joints((1, {"limits": [0.5, -0.5]}))), ["'joints.1.limits'"]),
    "base joints without kinematic_base": (
        edited(joints=TINY["joints"] + [{"name": "base_x", "role": "base"}]), ["kinematic_base", "base_x"]),
    "bad inertia source": (edited(inertia="cad"), ["'inertia'", "'urdf' or 'geometry'"]),
    "unsupported control mode": (edited(action={"control_mode": "body_twist"}), ["'action.control_mode'"]),
}


@pytest.mark.parametrize("data, needles", list(BAD.values()), ids=list(BAD))
def test_bad_manifest_is_a_config_error_naming_file_and_field(write, data, needles):
    path = write(data)
    with pytest.raises(ConfigError) as err:
        load_manifest(path)
    msg = str(err.value)
    assert str(path) in msg
    for needle in needles:
        assert needle in msg


def test_all_schema_errors_are_reported_at_once(write):
    path = write(edited(colour="red", joints=_joints((0, {"colour": "blue"}))))
    with pytest.raises(ConfigError) as err:
        load_manifest(path)
    assert "'colour'" in str(err.value) and "'joints.0.colour'" in str(err.value)


def test_all_urdf_mismatches_are_reported_at_once(write):
    path = write(edited(ee_link="hand", joints=_joints((1, {"name": "elbow"}))))
    with pytest.raises(ConfigError) as err:
        load_manifest(path)
    assert "'hand'" in str(err.value) and "'elbow'" in str(err.value)


@pytest.mark.parametrize(
    "text, needle",
    [("name: [tiny\n", "not valid YAML"), ("- tiny\n- arm\n", "must be a YAML mapping, got list"),
     ("just a string\n", "must be a YAML mapping, got str"), ("", "must be a YAML mapping, got NoneType")],
    ids=["malformed", "list", "scalar", "empty"],
)
def test_non_manifest_yaml_is_a_config_error(write, text, needle):
    path = write(text)
    with pytest.raises(ConfigError) as err:
        load_manifest(path)
    assert str(path) in str(err.value) and needle in str(err.value)


def test_missing_manifest_file_is_a_config_error(tmp_path):
    path = tmp_path / "nope.yaml"
    with pytest.raises(ConfigError, match="nope.yaml"):
        load_manifest(path)
