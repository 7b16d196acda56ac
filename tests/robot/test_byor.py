"""Bring your own robot: two arms the built-ins never used, from URDFs shipped in a PyPI wheel
(pybullet's pybullet_data), with manifests written from docs/robots.md alone
(tests/assets/kuka_iiwa.yaml: 7-DoF, no gripper; tests/assets/xarm6.yaml: 6-DoF + gripper, a URDF
without a tool link). check -> run -> joint tracking -> video; and what ``robots check`` catches."""

import json
import re
from pathlib import Path

import imageio.v2 as imageio
import numpy as np
import pytest
from typer.testing import CliRunner

from simseam.cli.main import app
from simseam.math3d import quat_to_matrix
from simseam.policies.base import make_policy
from simseam.robot.assets import resolve_asset
from simseam.robot.manifest import load_manifest
from simseam.seam import ConfigError, ObsRequest, check_rollout
from cli_util import simseam as _simseam

ASSETS = Path(__file__).resolve().parents[1] / "assets"
KUKA = ASSETS / "kuka_iiwa.yaml"
XARM = ASSETS / "xarm6.yaml"
TINY_URDF = ASSETS / "tiny_arm.urdf"
runner = CliRunner()


def _check(path):
    res = runner.invoke(app, ["robots", "check", str(path)])
    return res.exit_code, " ".join((res.stdout + res.stderr).split())


@pytest.fixture(scope="module")
def kuka():
    return load_manifest(KUKA)


@pytest.fixture(scope="module")
def xarm():
    return load_manifest(XARM)


# ------------------------------------------------------------------------------------ check
@pytest.mark.parametrize("path", [KUKA, XARM])
def test_robots_check_passes_the_pypi_arms(path):
    code, out = _check(path)
    assert code == 0, out
    assert out.startswith("ok") and "built in MuJoCo" in out and "warning" not in out


def test_check_maps_a_compile_failure_to_the_manifest_fix(tmp_path):
    """The xArm URDF's link2 inertia violates the triangle inequality: MuJoCo says 'use balanceinertia',
    a setting a manifest cannot reach; check (and run) say `inertia: geometry` instead."""
    bad = tmp_path / "xarm6.yaml"
    bad.write_text(XARM.read_text().replace("inertia: geometry", ""))
    load_manifest(bad)  # the schema and URDF names are fine: only building it shows the problem
    code, out = _check(bad)
    assert code == 2
    assert "inertia: geometry" in out and "link2" in out and str(bad) in out
    run = tmp_path / "scene.yaml"
    run.write_text(f"robot: {bad}\ntask: reach\n")
    proc = _simseam("run", "--scene", str(run), "--policy", "zero", "--episodes", "1", "--out", str(tmp_path / "r"))
    assert proc.returncode == 2 and "inertia: geometry" in proc.stderr and "Traceback" not in proc.stderr


def _tiny(tmp_path, urdf_text, extra=""):
    (tmp_path / "tiny_arm.urdf").write_text(urdf_text)
    manifest = tmp_path / "tiny.yaml"
    manifest.write_text(
        "name: tiny\nurdf: file:tiny_arm.urdf\nbase_link: base_link\nee_link: tip_link\njoints:\n"
        "  - {name: joint1, role: arm}\n  - {name: joint2, role: arm, home: 0.3}\n"
        "  - {name: joint3, role: arm, home: 0.1}\n" + extra)
    return manifest


def test_check_missing_mesh_is_an_error(tmp_path):
    urdf = TINY_URDF.read_text().replace('<box size="0.2 0.2 0.1"/>', '<mesh filename="meshes/base.stl"/>', 1)
    code, out = _check(_tiny(tmp_path, urdf))
    assert code == 2 and "meshes/base.stl" in out and "not found" in out


def test_check_warns_about_a_robot_without_visual_geometry(tmp_path):
    text = TINY_URDF.read_text()
    no_visual = re.sub(r"<visual>.*?</visual>", "", text, flags=re.S)
    code, out = _check(_tiny(tmp_path, no_visual))
    assert code == 0 and "warning" in out and "no <visual> geometry" in out
    nothing = re.sub(r"<collision>.*?</collision>", "", no_visual, flags=re.S)
    code, out = _check(_tiny(tmp_path, nothing))
    assert code == 0 and "invisible" in out
    code, out = _check(_tiny(tmp_path, text))
    assert code == 0 and "warning" not in out


def test_home_outside_the_joint_limits_is_an_error_naming_the_field(tmp_path):
    bad = tmp_path / "xarm6.yaml"
    bad.write_text(XARM.read_text().replace("{name: joint3, role: arm, home: -0.8}",
                                            "{name: joint3, role: arm, home: 0.5}"))
    with pytest.raises(ConfigError, match=r"joints\.2\.home' \(joint3\): 0\.5 is outside the joint limits"):
        load_manifest(bad)
    code, out = _check(bad)
    assert code == 2 and "joints.2.home" in out


@pytest.mark.parametrize("key", ["open", "closed"])
def test_gripper_positions_outside_the_finger_limits_are_errors(tmp_path, key):
    bad = tmp_path / "xarm6.yaml"
    text = XARM.read_text().replace("open: [0.0]", "open: [-0.2]" if key == "open" else "open: [0.0]")
    text = text.replace("closed: [0.85]", "closed: [1.2]" if key == "closed" else "closed: [0.85]")
    bad.write_text(text)
    with pytest.raises(ConfigError, match=rf"gripper\.{key}\.0' \(drive_joint\): .* outside the finger joint's limits"):
        load_manifest(bad)


def test_tool_frame_is_given_exactly_once(tmp_path):
    both = tmp_path / "xarm6.yaml"
    both.write_text(XARM.read_text().replace("base_link: link_base\n", "base_link: link_base\nee_link: link6\n"))
    with pytest.raises(ConfigError, match="either as 'ee_link'.*or as 'tcp'"):
        load_manifest(both)
    wrong = tmp_path / "wrong.yaml"
    wrong.write_text(XARM.read_text().replace("tcp: {parent: link6,", "tcp: {parent: link66,"))
    with pytest.raises(ConfigError, match="tcp.parent': link 'link66' is not in the URDF"):
        load_manifest(wrong)


# ---------------------------------------------------------------------------- the tool frame
def test_tcp_is_a_virtual_link_the_scene_composes(xarm, make_scene):
    scene = make_scene(xarm, render_images=False, privileged=True)
    robot = scene.spec.robot
    assert robot.tool_link == "tcp" and xarm.ee_link == "tcp" and xarm.tool_parent == "link6"
    tcp = {link.name: link for link in robot.links}["tcp"]
    assert (tcp.parent, tcp.joint_type, tcp.xyz) == ("link6", "fixed", (0.0, 0.0, 0.15))
    scene.reset(0)
    obs = scene.step(scene.spec.action.pack(), ObsRequest(images=frozenset(), link_poses=True)).observation
    poses = obs["link_poses"]
    flange, tool = poses["link6"], poses["tcp"]
    expected = flange[:3] + quat_to_matrix(flange[3:].astype(np.float64)) @ np.array([0.0, 0.0, 0.15])
    np.testing.assert_allclose(tool[:3], expected, atol=1e-5)
    np.testing.assert_allclose(obs["state"][:3], tool[:3], atol=1e-5)  # state reports the tool frame
    np.testing.assert_allclose(obs["privileged"]["eef_pose"][:3], tool[:3], atol=1e-5)
    # the scene's IK chain ends at the tool frame as well
    tip, _ = scene.chain.forward(obs["joint_positions"][:6].astype(np.float64))
    np.testing.assert_allclose(tip[:3, 3], tool[:3], atol=2e-3)


def test_xarm_lifts_with_its_tcp_and_not_with_its_flange(xarm, make_scene, count_successes, tmp_path):
    """The issue's finding, reproduced: the flange as the tool frame lifts nothing; the tcp lifts."""
    scene = make_scene(xarm, render_images=False, privileged=True)
    assert count_successes(scene, make_policy("scripted"), range(10)) >= 8
    flange = tmp_path / "xarm6_flange.yaml"
    flange.write_text(XARM.read_text().replace("tcp: {parent: link6, xyz: [0.0, 0.0, 0.15], rpy: [0.0, 0.0, 0.0]}",
                                               "ee_link: link6"))
    scene = make_scene(load_manifest(flange), render_images=False, privileged=True)
    assert count_successes(scene, make_policy("scripted"), range(3)) == 0


# ---------------------------------------------------------------------- reach, any arm
@pytest.mark.parametrize("mode", ["cartesian_delta", "joint_position"])
def test_gripperless_arm_reaches_in_9_of_10(kuka, make_scene, count_successes, mode):
    scene = make_scene(kuka, task="reach", render_images=False, privileged=True, control_mode=mode)
    assert "grip" not in [s.name for s in scene.spec.action.slots]
    assert count_successes(scene, make_policy("scripted"), range(10)) >= 9


def test_gripperless_arm_cannot_lift_and_says_why(kuka, make_scene):
    with pytest.raises(ConfigError, match="task 'lift_cube' needs robot 'kuka_iiwa' to declare a gripper"):
        make_scene(kuka, task="lift_cube")


@pytest.mark.parametrize("path", [KUKA, XARM])
def test_pypi_arms_pass_the_rollout_contract(path, make_scene):
    check_rollout(make_scene(load_manifest(path), task="reach", image_size=(32, 32)))


@pytest.mark.parametrize("path", [KUKA, XARM])
def test_joint_position_targets_are_tracked(path, make_scene):
    spec = load_manifest(path)
    scene = make_scene(spec, task="reach", render_images=False, control_mode="joint_position")
    obs = scene.reset(0)
    arm = np.array([spec.joint_names.index(j.name) for j in spec.arm_joints])
    target = obs["joint_positions"][arm] + np.where(np.arange(len(arm)) % 2 == 0, 0.25, -0.2)
    action = scene.spec.action.pack(arm=target, grip=-1.0 if spec.gripper else None)
    for _ in range(40):
        obs = scene.step(action).observation
    np.testing.assert_allclose(obs["joint_positions"][arm], target, atol=0.02)


# --------------------------------------------------------------------------- end to end
@pytest.mark.parametrize("path, task, mode", [(KUKA, "reach", "joint_position"), (XARM, "lift_cube", "cartesian_delta")])
def test_check_then_run_with_video(tmp_path, path, task, mode):
    assert _check(path)[0] == 0
    scene_file = tmp_path / "scene.yaml"
    scene_file.write_text(f"robot: {path}\ntask: {task}\ncontrol_mode: {mode}\nimage_size: [96, 96]\n")
    out = tmp_path / "run"
    proc = _simseam("run", "--scene", str(scene_file), "--policy", "scripted", "--episodes", "2", "--out", str(out),
                    "--video")
    assert proc.returncode == 0, proc.stderr
    summary = json.loads((out / "summary.json").read_text())
    assert summary["n_episodes"] == 2 and summary["success_rate"] == 1.0
    for ep in summary["episodes"]:
        frames = list(imageio.get_reader(ep["video"], format="ffmpeg").iter_data())
        assert len(frames) == ep["steps"] + 1 and frames[0].shape == (96, 96, 3)
        assert frames[0].std() > 10  # a scene, not a blank frame
        assert np.abs(frames[0].astype(int) - frames[-1].astype(int)).mean() > 0.5  # the arm moved


def test_urdfs_come_from_the_installed_wheel():
    for path in (KUKA, XARM):
        spec = load_manifest(path)
        assert spec.urdf.startswith("pkg:pybullet/") and resolve_asset(spec.urdf).is_file()


def test_tcp_is_in_the_ros2_tf_tree(xarm, make_scene):
    from simseam.ros2.robot_model import RobotModel

    scene = make_scene(xarm, render_images=False)
    model = RobotModel(scene.spec.robot)
    assert "tcp" in model.frames()
    tcp = [t for t in model.static_transforms(0) if t.child_frame_id == "tcp"]
    assert len(tcp) == 1 and tcp[0].header.frame_id == "link6"
    assert (tcp[0].transform.translation.x, tcp[0].transform.translation.z) == (0.0, 0.15)


@pytest.mark.parametrize("name", ["franka_panda", "so101", "panda_mobile", "stretch"])
def test_builtin_robots_pass_check(name):
    from simseam.runner.robot_check import check_robot
    from simseam.robot.manifest import builtin_manifests

    report = check_robot(builtin_manifests()[name])
    assert report.visual_geoms > 0 and report.tabletop_reach > 0.2
    assert report.cameras == sorted(s.feature_key for s in report.spec.sensors_of("rgb"))
