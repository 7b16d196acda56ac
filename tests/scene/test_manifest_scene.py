"""ManifestScene: control semantics, sensors, determinism and bad input, measured."""

import dataclasses

import numpy as np
import pytest

from simseam.scene.manifest_scene import ManifestScene, SceneOptions
from simseam.seam import (
    ConfigError,
    ControlMode,
    InvalidActionError,
    REQUIRED_OBS_KEYS,
    SimRollout,
    SimulationError,
)


def _hold(scene, grip=-1.0):
    """The no-motion Cartesian action with the given grip."""
    return scene.spec.action.pack(grip=grip)


@pytest.mark.parametrize("robot", ["panda_spec", "so101_spec"])
@pytest.mark.parametrize("axis, sign", [(2, +1.0), (1, -1.0)])
def test_cartesian_delta_moves_eef_by_commanded_distance(request, make_scene, robot, axis, sign):
    spec = request.getfixturevalue(robot)
    scene = make_scene(spec, render_images=False)
    obs = scene.reset(0)
    p0 = obs["state"][:3].copy()
    action = _hold(scene, grip=-1.0)
    action[axis] = 0.4 * sign
    n = 8
    for _ in range(n):
        obs = scene.step(action).observation
    moved = obs["state"][:3] - p0
    commanded = n * 0.4 * spec.action.max_translation
    assert sign * moved[axis] == pytest.approx(commanded, rel=0.10)
    off_axis = np.delete(moved, axis)
    assert np.all(np.abs(off_axis) < 0.1 * commanded)


def test_cartesian_rotation_delta_turns_eef_about_base_z(panda_spec, make_scene):
    from simseam.math3d import quat_to_matrix, rotation_error

    scene = make_scene(panda_spec, render_images=False, privileged=True)
    obs = scene.reset(0)
    r0 = quat_to_matrix(obs["privileged"]["eef_pose"][3:])
    action = _hold(scene)
    action[5] = 0.2  # 0.1 rad per step about base z
    for _ in range(5):
        obs = scene.step(action).observation
    for _ in range(5):
        obs = scene.step(_hold(scene)).observation
    r1 = quat_to_matrix(obs["privileged"]["eef_pose"][3:])
    turn = rotation_error(r1, r0)
    assert turn[2] == pytest.approx(0.5, rel=0.10)
    assert np.linalg.norm(turn[:2]) < 0.05


@pytest.mark.parametrize("robot", ["panda_spec", "so101_spec"])
def test_joint_position_targets_are_reached(request, make_scene, robot):
    spec = request.getfixturevalue(robot)
    scene = make_scene(spec, control_mode="joint_position", render_images=False)
    obs = scene.reset(0)
    layout = scene.spec.action
    assert layout.names[: layout.arm_dim] == tuple(j.name for j in spec.arm_joints)
    home = np.array([j.home for j in spec.arm_joints])
    upper = np.array([j.upper for j in spec.arm_joints])
    arm = np.minimum(home + 0.2, upper - 0.05)
    for _ in range(20):
        obs = scene.step(layout.pack(arm=arm, grip=-1.0)).observation
    q_arm = obs["joint_positions"][: len(arm)]
    np.testing.assert_allclose(q_arm, arm, atol=0.01)


def test_joint_position_targets_are_clipped_to_limits(panda_spec, make_scene):
    scene = make_scene(panda_spec, control_mode="joint_position", render_images=False)
    scene.reset(0)
    layout = scene.spec.action
    arm = np.full(7, 10.0)  # far outside every limit
    for _ in range(30):
        obs = scene.step(layout.pack(arm=arm, grip=-1.0)).observation
    upper = np.array([j.upper for j in panda_spec.arm_joints])
    assert np.all(obs["joint_positions"][:7] <= upper + 0.01)
    np.testing.assert_allclose(obs["joint_positions"][:7], upper, atol=0.02)


def test_ik_respects_joint_limits_when_pushed_out_of_reach(panda_spec, make_scene):
    scene = make_scene(panda_spec, render_images=False)
    scene.reset(0)
    action = _hold(scene)
    action[:3] = [1.0, 0.0, 1.0]
    lower = np.array([j.lower for j in panda_spec.arm_joints])
    upper = np.array([j.upper for j in panda_spec.arm_joints])
    for _ in range(60):
        q = scene.step(action).observation["joint_positions"][:7]
        q_cmd = scene.last_ik.q
        assert np.all(q_cmd >= lower) and np.all(q_cmd <= upper)  # IK never asks for more
        assert np.all(q >= lower - 0.05) and np.all(q <= upper + 0.05)  # physics stays at the stops


@pytest.mark.parametrize("robot", ["panda_spec", "so101_spec"])
def test_gripper_convention_minus_one_open_plus_one_closed(request, make_scene, robot):
    spec = request.getfixturevalue(robot)
    scene = make_scene(spec, render_images=False)
    scene.reset(0)
    opened, closed = np.array(spec.gripper.open), np.array(spec.gripper.closed)
    for grip, expected in [(1.0, closed), (-1.0, opened), (0.0, (opened + closed) / 2)]:
        for _ in range(15):
            obs = scene.step(_hold(scene, grip=grip)).observation
        n = len(spec.gripper.joints)
        np.testing.assert_allclose(obs["state"][6:6 + n], expected, atol=0.01 * max(1.0, np.ptp([opened, closed])))


def test_observation_contract_and_images(panda_spec, make_scene):
    scene = make_scene(panda_spec, image_size=(96, 128))
    assert isinstance(scene, SimRollout)
    obs = scene.reset(3)
    assert set(REQUIRED_OBS_KEYS) <= set(obs)
    assert set(obs["images"]) == {"camera1", "camera2"}
    a, b = obs["images"]["camera1"], obs["images"]["camera2"]
    for img in (a, b):
        assert img.shape == (96, 128, 3) and img.dtype == np.uint8
        assert img.std() > 10  # not a blank frame
    assert np.abs(a.astype(int) - b.astype(int)).mean() > 10  # two different viewpoints
    assert obs["state"].dtype == np.float32 and obs["state"].shape == (9 - 1,)
    assert obs["joint_positions"].shape == (9,) and obs["joint_velocities"].dtype == np.float32
    assert obs["task"] == "lift the red cube"
    assert scene.spec.cameras == {"camera1": (96, 128), "camera2": (96, 128)}
    frame = scene.render()
    assert frame is obs["images"]["camera1"]  # the video frame re-uses the observed image


def test_cube_is_visible_in_the_third_person_camera(panda_spec, make_scene):
    """The red cube shows up as red pixels, and moves in the image when its seed moves it."""
    scene = make_scene(panda_spec)

    def red_centroid(seed):
        img = scene.reset(seed)["images"]["camera1"].astype(int)
        red = (img[..., 0] > 150) & (img[..., 1] < 80) & (img[..., 2] < 80)
        assert red.sum() > 20
        return np.argwhere(red).mean(axis=0)

    assert np.linalg.norm(red_centroid(0) - red_centroid(5)) > 3


def test_same_seed_same_observations(panda_spec, make_scene):
    def rollout(scene, seed):
        obs = scene.reset(seed)
        out = [obs]
        rng = np.random.default_rng(1)
        for _ in range(5):
            out.append(scene.step(rng.uniform(-1, 1, 7).astype(np.float32)).observation)
        return out

    s1 = make_scene(panda_spec, image_size=(64, 64), privileged=True)
    s2 = make_scene(panda_spec, image_size=(64, 64), privileged=True)
    for o1, o2 in zip(rollout(s1, 7), rollout(s2, 7)):
        np.testing.assert_array_equal(o1["state"], o2["state"])
        np.testing.assert_array_equal(o1["joint_positions"], o2["joint_positions"])
        np.testing.assert_array_equal(o1["images"]["camera2"], o2["images"]["camera2"])
        assert o1["sim_time_ns"] == o2["sim_time_ns"]
    # and a different seed places the cube elsewhere
    c7 = s1.reset(7)["privileged"]["objects"]["cube"]
    c8 = s1.reset(8)["privileged"]["objects"]["cube"]
    assert np.linalg.norm(c7[:2] - c8[:2]) > 0.005


def test_reset_without_seed_draws_a_reproducible_stream(panda_spec, make_scene):
    a = make_scene(panda_spec, render_images=False, privileged=True, seed=11)
    b = make_scene(panda_spec, render_images=False, privileged=True, seed=11)
    for _ in range(2):
        np.testing.assert_array_equal(a.reset()["privileged"]["objects"]["cube"],
                                      b.reset()["privileged"]["objects"]["cube"])


def test_sim_time_is_monotonic_from_zero(panda_spec, make_scene):
    scene = make_scene(panda_spec, render_images=False)
    assert scene.reset(0)["sim_time_ns"] == 0
    times = [scene.step(_hold(scene)).observation["sim_time_ns"] for _ in range(4)]
    assert times == [50_000_000, 100_000_000, 150_000_000, 200_000_000]
    assert scene.sim_time_ns() == times[-1]


def test_undeclared_sensors_are_absent(panda_spec, make_scene):
    bare = dataclasses.replace(panda_spec, sensors=[])
    scene = make_scene(bare)
    obs = scene.reset(0)
    assert obs["images"] == {}
    for key in ("depth_points", "scan", "base_pose", "privileged"):
        assert key not in obs
    assert scene.render() is None
    assert scene.engine._cameras == {}  # no camera was created in the engine at all


def test_state_only_renders_nothing_but_video_frames_on_demand(panda_spec, make_scene):
    scene = make_scene(panda_spec, render_images=False)
    obs = scene.reset(0)
    assert obs["images"] == {} and scene.spec.cameras == {}
    frame = scene.render()
    assert frame.shape == (256, 256, 3) and frame.std() > 10


def test_bowl_plate_is_the_libero_contract(panda_spec, make_scene):
    scene = make_scene(panda_spec, task="bowl_plate")
    obs = scene.reset(0)
    info = scene.spec
    assert info.control_mode == ControlMode.CARTESIAN_DELTA and info.action_dim == 7
    assert info.state_dim == 8 and obs["state"].shape == (8,)
    assert {k: v.shape for k, v in obs["images"].items()} == {"camera1": (256, 256, 3), "camera2": (256, 256, 3)}
    assert obs["task"] == "put the bowl on the plate"
    # eef_axis_angle: gripper pointing down is a half turn about base x
    assert np.linalg.norm(obs["state"][3:6]) == pytest.approx(np.pi, abs=0.05)



def test_the_state_orientation_runs_continuously_through_a_half_turn(panda_spec, make_scene):
    """A top-down gripper sits at a half turn about x, where an axis-angle in [0, pi] flips sign
    under millimetre motions. The state's follows the home orientation's quaternion sign, as LIBERO's
    does: rolling the tool back and forth about x moves it smoothly across pi, never by ~2 pi."""
    from simseam.math3d import axis_angle_to_matrix

    scene = make_scene(panda_spec, render_images=False)
    obs = scene.reset(0)
    seen = [obs["state"][3:6].copy()]
    for t in range(30):
        a = np.zeros(7, np.float32)
        a[3] = 0.4 if t < 8 else -0.4  # roll one way, then back past the start
        seen.append(scene.step(a).observation["state"][3:6].copy())
    seen = np.array(seen)
    assert np.abs(np.diff(seen, axis=0)).max() < 0.3  # no jump
    assert seen[:, 0].max() > np.pi + 0.05 and seen[:, 0].min() < np.pi - 0.05  # it crossed pi
    _, rot = scene.eef_pose_base()
    np.testing.assert_allclose(axis_angle_to_matrix(seen[-1]), rot, atol=1e-5)  # the same rotation

# ------------------------------------------------------------------ bad input
@pytest.mark.parametrize("bad, fragment", [
    (np.zeros(6, np.float32), "expected (7,)"),
    (np.array([0, 0, 0, np.nan, 0, 0, 0], np.float32), "action[3] is nan"),
])
def test_bad_actions_raise_and_change_nothing(panda_spec, make_scene, bad, fragment):
    scene = make_scene(panda_spec, render_images=False)
    obs = scene.reset(0)
    with pytest.raises(InvalidActionError) as exc:
        scene.step(bad)
    assert fragment in str(exc.value)
    assert scene.sim_time_ns() == 0
    np.testing.assert_array_equal(scene.engine.joint_positions().astype(np.float32), obs["joint_positions"])
    scene.step(_hold(scene))  # and the scene still works


def test_step_before_reset_and_after_close(panda_spec, make_scene):
    scene = make_scene(panda_spec, render_images=False)
    with pytest.raises(SimulationError, match="before reset"):
        scene.step(np.zeros(7, np.float32))
    scene.close()
    scene.close()  # harmless twice
    with pytest.raises(SimulationError, match="closed"):
        scene.reset(0)


def test_unknown_layout_and_engine(panda_spec):
    with pytest.raises(ConfigError, match="unknown task 'stack_cubes'.*bowl_plate, lift_cube"):
        ManifestScene(panda_spec, "stack_cubes")
    with pytest.raises(ConfigError, match="unknown engine 'gazebo'.*mujoco"):
        ManifestScene(panda_spec, "lift_cube", "gazebo")


def test_layout_rejects_robot_missing_required_cameras(panda_spec):
    one_cam = dataclasses.replace(panda_spec, sensors=[s for s in panda_spec.sensors if s.name == "camera1"])
    with pytest.raises(ConfigError, match=r"bowl_plate.*\['camera2'\]"):
        ManifestScene(one_cam, "bowl_plate")


def test_layout_forced_control_mode_conflict(panda_spec):
    with pytest.raises(ConfigError, match="requires control mode 'cartesian_delta'"):
        ManifestScene(panda_spec, "bowl_plate", options=SceneOptions(control_mode="joint_position"))


def test_environment_state_is_the_tasks_object_poses_declared_in_the_spec(panda_spec, make_scene):
    scene = make_scene(panda_spec, render_images=False, privileged=True, environment_state=True)
    field = scene.spec.observation.fields["environment_state"]
    assert scene.spec.env_state_dim == 7 and field.names[:4] == ("cube.x", "cube.y", "cube.z", "cube.qw")
    obs = scene.reset(3)
    env = obs["environment_state"]
    assert env.dtype == np.float32 and env.shape == (7,)
    np.testing.assert_allclose(env, obs["privileged"]["objects"]["cube"], atol=1e-6)
    other = scene.reset(4)["environment_state"]
    assert np.linalg.norm(env[:2] - other[:2]) > 0.005  # the seed moves the cube, and the state sees it
    plain = make_scene(panda_spec, render_images=False)
    assert plain.spec.env_state_dim is None and "environment_state" not in plain.reset(3)


def test_environment_state_of_a_task_with_a_target_lists_it(so101_spec, make_scene):
    scene = make_scene(so101_spec, task="reach", render_images=False, environment_state=True)
    names = scene.spec.observation.fields["environment_state"].names
    assert names[0].split(".")[0] == "target" and len(names) == scene.spec.env_state_dim


def test_a_scene_with_environment_state_passes_check_rollout(panda_spec, make_scene):
    from simseam.seam import check_rollout

    check_rollout(make_scene(panda_spec, render_images=False, environment_state=True, max_steps=10))
