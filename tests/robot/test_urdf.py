"""The standard-library URDF reader: structure of the model, and errors that name the file."""

from __future__ import annotations

import re
from pathlib import Path

import pytest

from simseam.robot.assets import resolve_asset
from simseam.robot.urdf import read_urdf
from simseam.seam import ConfigError

TINY_URDF = Path(__file__).resolve().parents[1] / "assets" / "tiny_arm.urdf"


def test_tiny_arm_structure():
    urdf = read_urdf(TINY_URDF)
    assert urdf.name == "tiny_arm" and urdf.path == str(TINY_URDF)
    assert urdf.links == ("base_link", "link1", "link2", "link3", "tip_link")
    assert urdf.joint_names == ["joint1", "joint2", "joint3", "tip_joint"]
    assert urdf.movable_joint_names == ["joint1", "joint2", "joint3"]
    assert urdf.root_link == "base_link"
    j1, j2, j3, tip = urdf.joints
    assert (j1.type, j1.parent, j1.child, j1.axis) == ("revolute", "base_link", "link1", (0.0, 0.0, 1.0))
    assert (j1.lower, j1.upper, j1.effort, j1.velocity) == (-2.9, 2.9, 50.0, 2.0)
    assert (j2.xyz, j2.rpy, j2.axis) == ((0.0, 0.0, 0.3), (0.0, 0.0, 0.2), (0.0, 1.0, 0.0))
    assert (j3.type, j3.lower, j3.upper, j3.effort) == ("prismatic", 0.0, 0.1, 20.0)
    assert (tip.type, tip.xyz, tip.rpy) == ("fixed", (0.1, 0.01, 0.0), (0.3, -0.2, 0.5))
    assert (tip.lower, tip.upper, tip.effort) == (None, None, None)
    with pytest.raises(KeyError):
        urdf.joint("joint9")


def test_chain_lists_joints_from_base_to_tip():
    urdf = read_urdf(TINY_URDF)
    assert [j.name for j in urdf.chain("base_link", "tip_link")] == ["joint1", "joint2", "joint3", "tip_joint"]
    assert [j.name for j in urdf.chain("link1", "link3")] == ["joint2", "joint3"]
    assert urdf.chain("link2", "link2") == []


def test_chain_to_a_link_not_below_the_base_names_the_file():
    urdf = read_urdf(TINY_URDF)
    with pytest.raises(ConfigError) as err:
        urdf.chain("link2", "link1")
    assert str(TINY_URDF) in str(err.value) and "'link1'" in str(err.value)


def test_panda_urdf():
    urdf = read_urdf(resolve_asset("pkg:pybullet/pybullet_data/franka_panda/panda.urdf"))
    assert urdf.root_link == "panda_link0"
    assert urdf.movable_joint_names == [f"panda_joint{i}" for i in range(1, 8)] + [
        "panda_finger_joint1", "panda_finger_joint2"]
    assert "panda_grasptarget" in urdf.links
    assert urdf.joint("panda_joint4").upper == 0.0 and urdf.joint("panda_joint4").effort == 87.0
    assert urdf.joint("panda_finger_joint1").type == "prismatic"


def _write(tmp_path: Path, body: str, name: str = "robot.urdf") -> Path:
    path = tmp_path / name
    path.write_text(body)
    return path


def test_defaults_for_missing_origin_axis_and_limits(tmp_path):
    path = _write(tmp_path, """<robot name="r"><link name="a"/><link name="b"/><link name="c"/>
        <joint name="spin" type="continuous"><parent link="a"/><child link="b"/>
          <limit effort="3" velocity="1"/></joint>
        <joint name="weld"><parent link="b"/><child link="c"/></joint></robot>""")
    urdf = read_urdf(path)
    spin, weld = urdf.joints
    assert (spin.xyz, spin.rpy, spin.axis) == ((0.0, 0.0, 0.0), (0.0, 0.0, 0.0), (1.0, 0.0, 0.0))
    assert (spin.lower, spin.upper, spin.effort, spin.velocity) == (None, None, 3.0, 1.0)  # continuous: unbounded
    assert weld.type == "fixed"  # the reader takes a joint without a type as fixed
    assert urdf.movable_joint_names == ["spin"]


@pytest.mark.parametrize(
    "body, needle",
    [
        ("<robot name='r'><link name='a'>", "cannot read URDF"),
        ("not xml at all", "cannot read URDF"),
        ("<sdf version='1.7'><model name='m'/></sdf>", "root element is <sdf>, expected <robot>"),
    ],
    ids=["truncated", "not-xml", "wrong-root"],
)
def test_unreadable_urdf_is_a_config_error_naming_the_file(tmp_path, body, needle):
    path = _write(tmp_path, body)
    with pytest.raises(ConfigError) as err:
        read_urdf(path)
    assert str(path) in str(err.value) and needle in str(err.value)


def test_missing_urdf_is_a_config_error_naming_the_file(tmp_path):
    path = tmp_path / "gone.urdf"
    with pytest.raises(ConfigError, match="gone.urdf"):
        read_urdf(path)


@pytest.mark.parametrize(
    "joint",
    [
        "<joint name='j' type='revolute'><child link='b'/></joint>",
        "<joint name='j' type='revolute'><parent link='a'/><child link='b'/>"
        "<limit lower='-1' upper='one' effort='1' velocity='1'/></joint>",
        "<joint name='j' type='revolute'><parent link='a'/><child link='b'/><origin xyz='0 0 x'/></joint>",
    ],
    ids=["no-parent", "bad-limit", "bad-origin"],
)
def test_malformed_joint_is_a_config_error_naming_the_file(tmp_path, joint):
    path = _write(tmp_path, f"<robot name='r'><link name='a'/><link name='b'/>{joint}</robot>")
    with pytest.raises(ConfigError) as err:
        read_urdf(path)
    assert str(path) in str(err.value) and "'j'" in str(err.value)


def test_manifest_urdf_errors_surface_with_the_urdf_path(tmp_path):
    """A broken URDF behind a valid manifest is reported with the URDF's own path."""
    import yaml

    from simseam.robot.manifest import load_manifest

    urdf = _write(tmp_path, "<robot name='r'><link name='a'>", name="broken.urdf")
    manifest = tmp_path / "r.yaml"
    manifest.write_text(yaml.safe_dump({"name": "r", "urdf": "file:broken.urdf", "base_link": "a", "ee_link": "a",
                                        "joints": [{"name": "j", "role": "arm"}]}))
    with pytest.raises(ConfigError, match=re.escape(str(urdf))):
        load_manifest(manifest)
