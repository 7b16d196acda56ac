"""Mobile manipulators and range sensors, measured: kinematic base, 2-D lidar, depth clouds."""

import dataclasses
import math

import numpy as np
import pytest

from simseam.math3d import yaw_quat
from simseam.policies.base import make_policy
from simseam.robot.manifest import load_robot
from simseam.robot.spec import KinematicBaseSpec
from simseam.scene.base_motion import KinematicBase
from simseam.scene.manifest_scene import ManifestScene, SceneOptions
from simseam.seam import ConfigError


def _twist(scene, vx=0.0, vy=0.0, wz=0.0):
    return scene.spec.action.pack(grip=-1.0, base=[vx, vy, wz])


def _clear_obstacles(scene, far=60.0):
    """Move every obstacle of nav_obstacles out of the lidar's range."""
    for k in range(6):
        scene.engine.set_object_pose(f"obstacle{k}", np.array([far + 3 * k, far, 0.0]), yaw_quat(0.0))
    scene.task.params["active"][:] = False


def test_body_twist_moves_and_turns_the_base_by_the_commanded_amount(mobile_spec, make_scene):
    scene = make_scene(mobile_spec, task="nav_obstacles", render_images=False)
    obs = scene.reset(0)
    assert obs["base_pose"].tolist() == [0.0, 0.0, 0.0]
    for _ in range(20):  # 1 s at 20 Hz
        obs = scene.step(_twist(scene, vx=0.3)).observation
    assert obs["base_pose"][0] == pytest.approx(0.30, abs=0.03) and abs(obs["base_pose"][1]) < 1e-6
    for _ in range(20):
        obs = scene.step(_twist(scene, wz=0.5)).observation
    assert obs["base_pose"][2] == pytest.approx(0.5, abs=0.05)
    # the twist is in the base frame: after a quarter turn, +vx drives along world +y
    scene.reset(0)
    for _ in range(40):
        scene.step(_twist(scene, wz=math.pi / 4))
    obs = scene.step(_twist(scene)).observation
    for _ in range(10):
        obs = scene.step(_twist(scene, vx=0.4)).observation
    x, y, yaw = obs["base_pose"]
    assert yaw == pytest.approx(math.pi / 2, abs=0.02)
    assert y == pytest.approx(0.2, abs=0.02) and abs(x) < 0.01


def test_base_joints_in_manifest_order_and_speed_limits(mobile_spec, make_scene):
    scene = make_scene(mobile_spec, task="nav_obstacles", render_images=False)
    scene.reset(0)
    for _ in range(10):
        obs = scene.step(_twist(scene, vx=3.0, vy=3.0, wz=9.0)).observation  # far above the limits
    names = list(scene.spec.robot.joint_names)
    assert names[:3] == ["base_x", "base_y", "base_yaw"]
    kb = mobile_spec.kinematic_base
    v = obs["joint_velocities"][:3]
    assert math.hypot(v[0], v[1]) == pytest.approx(kb.max_linear, rel=1e-3)
    assert v[2] == pytest.approx(kb.max_angular, rel=1e-3)
    np.testing.assert_allclose(obs["joint_positions"][:3], obs["base_pose"], atol=1e-6)
    # the arm rode along: the end effector stays put in the base frame
    np.testing.assert_allclose(obs["state"][:3], scene.reset(0)["state"][:3], atol=0.01)


def test_exact_arc_integration():
    base = KinematicBase(KinematicBaseSpec(["x", "y", "yaw"], 1.0, 2.0))
    base.reset(0.0, 0.0, 0.0)
    for _ in range(7):
        base.advance(np.array([0.5, 0.0, 1.0]), 0.05 * math.pi)  # a half circle of radius 0.5
    # 7 steps of 0.05*pi rad is 0.35*pi; the pose lies on the circle centred at (0, 0.5)
    x, y, yaw = base.pose
    assert yaw == pytest.approx(0.35 * math.pi)
    assert math.hypot(x, y - 0.5) == pytest.approx(0.5, abs=1e-12)


def test_lidar_ranges_match_known_obstacles_and_never_hit_the_robot(mobile_spec, make_scene):
    scene = make_scene(mobile_spec, task="nav_obstacles", render_images=False, control_mode="joint_position")
    scene.reset(0)
    _clear_obstacles(scene)
    lidar = mobile_spec.sensors_of("lidar_2d")[0]
    # A box (half extents 0.2 x 0.3) centred 2.0 m ahead: its face is 1.8 m from the base centre,
    # where the lidar sits. A cylinder (radius 0.22) centred 1.5 m to the left.
    scene.engine.set_object_pose("obstacle0", np.array([2.0, 0.0, 0.0]), yaw_quat(0.0))
    scene.engine.set_object_pose("obstacle1", np.array([0.0, 1.5, 0.0]), yaw_quat(0.0))
    layout = scene.spec.action
    home = np.array([j.home for j in mobile_spec.arm_joints])
    scan = scene.step(layout.pack(arm=home, grip=-1.0)).observation["scan"]
    assert scan.shape == (360,) and scan.dtype == np.float32
    angles = -np.pi + np.arange(360) * (2 * np.pi / 360)
    ahead, left = int(np.argmin(np.abs(angles))), int(np.argmin(np.abs(angles - np.pi / 2)))
    assert scan[ahead] == pytest.approx(1.8, abs=0.02)
    assert scan[left] == pytest.approx(1.5 - 0.22, abs=0.02)
    assert scan[0] == lidar.range_max  # beam 0 looks back (-pi): nothing there
    # counter-clockwise: the box spans +-atan(0.3/1.8) around beam "ahead"
    hits = np.flatnonzero(scan < 5.0)
    assert {ahead - 9, ahead + 9, left} <= set(hits) and ahead - 12 not in hits
    # Whatever the arm does, no beam ever hits the robot itself.
    _clear_obstacles(scene)
    rng = np.random.default_rng(0)
    lo = np.array([j.lower for j in mobile_spec.arm_joints])
    hi = np.array([j.upper for j in mobile_spec.arm_joints])
    for _ in range(15):
        for _ in range(3):
            scan = scene.step(layout.pack(arm=rng.uniform(lo, hi), grip=-1.0)).observation["scan"]
        assert np.all(scan == lidar.range_max)


def test_depth_cloud_points_lie_on_the_floor_and_the_obstacle(mobile_spec, make_scene):
    scene = make_scene(mobile_spec, task="nav_obstacles")
    scene.reset(0)
    _clear_obstacles(scene)
    scene.engine.set_object_pose("obstacle0", np.array([1.6, 0.0, 0.0]), yaw_quat(0.0))  # face at x = 1.4
    obs = scene.step(_twist(scene)).observation
    sensor = mobile_spec.sensors_of("depth")[0]
    pts = obs["depth_points"][sensor.name]
    assert pts.dtype == np.float32 and pts.ndim == 2 and pts.shape[1] == 3 and len(pts) > 1000
    floor_z = -mobile_spec.kinematic_base.height  # the floor, in base_link
    on_floor = np.abs(pts[:, 2] - floor_z) < 0.02
    on_face = np.abs(pts[:, 0] - 1.4) < 0.02
    assert on_floor.sum() > 200 and on_face.sum() > 200
    assert np.all(on_floor | on_face)  # every point is on one of the two known surfaces
    face = pts[on_face & ~on_floor]
    assert np.all(np.abs(face[:, 1]) <= 0.3 + 0.02) and np.all(face[:, 2] <= 0.8 + floor_z + 0.02)
    assert pts[:, 0].max() <= sensor.xyz[0] + sensor.range_max  # depth clipped to the sensor's range


def test_sensors_only_as_declared(mobile_spec, panda_spec, make_scene):
    arm = make_scene(panda_spec, task="lift_cube")
    obs = arm.reset(0)
    assert not {"scan", "depth_points", "base_pose"} & set(obs)
    no_depth = dataclasses.replace(mobile_spec, sensors=[s for s in mobile_spec.sensors if s.kind == "lidar_2d"])
    obs = make_scene(no_depth, task="nav_obstacles").reset(0)
    assert "scan" in obs and "depth_points" not in obs and obs["images"] == {}
    state_only = make_scene(mobile_spec, task="nav_obstacles", render_images=False).reset(0)
    assert "depth_points" not in state_only  # state-only scenes render nothing


def test_manifest_and_layout_checks(mobile_spec, panda_spec):
    with pytest.raises(ConfigError, match="nav_obstacles.*kinematic_base"):
        ManifestScene(panda_spec, "nav_obstacles")
    lidar = mobile_spec.sensors_of("lidar_2d")[0]
    two = dataclasses.replace(mobile_spec, sensors=[*mobile_spec.sensors, dataclasses.replace(lidar, name="l2")])
    with pytest.raises(ConfigError, match="2 lidar_2d"):
        ManifestScene(two, "nav_obstacles")
    wrong_root = dataclasses.replace(mobile_spec, base_link="panda_link1")
    with pytest.raises(ConfigError, match="root link 'panda_link0'"):
        ManifestScene(wrong_root, "nav_obstacles", options=SceneOptions(render_images=False))


@pytest.mark.parametrize("first", [0, 13])
def test_scripted_navigation_reaches_the_goal_in_9_of_10(mobile_spec, make_scene, count_successes, first):
    """Any 10 consecutive seeds (two windows here; benchmarks/bench_scripted.py measured seeds 0-39: 40/40)."""
    scene = make_scene(mobile_spec, task="nav_obstacles", render_images=False, privileged=True)
    assert count_successes(scene, make_policy("scripted"), range(first, first + 10)) >= 9


def test_second_mobile_robot_stretch_runs_an_episode(make_scene, count_successes):
    stretch = load_robot("stretch")
    scene = make_scene(stretch, task="nav_obstacles", privileged=True, image_size=(64, 64))
    obs = scene.reset(1)
    assert set(obs["images"]) == {"camera1"} and "head_depth" in obs["depth_points"]
    assert obs["scan"].shape == (360,) and obs["joint_positions"].shape == (len(stretch.joints),)
    scene.close()
    state_only = make_scene(stretch, task="nav_obstacles", privileged=True, render_images=False)
    assert count_successes(state_only, make_policy("scripted"), [1]) == 1
