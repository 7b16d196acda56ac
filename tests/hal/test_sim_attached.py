"""SimAttachedHAL, measured on MuJoCo (CPU, state-only scenes)."""

import dataclasses
import math

import numpy as np
import pytest

from simseam.hal import JointState, NotConnectedError, SimAttachedHAL
from simseam.robot.manifest import load_robot
from simseam.scene.manifest_scene import SceneOptions
from simseam.seam import ConfigError, ControlMode, InvalidActionError

HZ = 20  # the scenes' control rate: 20 ticks = 1 s of sim time


@pytest.fixture
def mobile_hal(mobile_spec, make_scene):
    def _make(**kw):
        hal = SimAttachedHAL(make_scene(mobile_spec, task="nav_obstacles", render_images=False), **kw)
        hal.connect()
        return hal

    return _make


def drive(hal, ticks, twist=None):
    """Tick ``ticks`` times, re-sending ``twist`` before each tick (a 20 Hz teleop stream)."""
    for _ in range(ticks):
        if twist is not None:
            hal.send_action(twist, ControlMode.BODY_TWIST)
        hal.tick()


def test_connect_learns_the_layout_and_state_is_in_manifest_order(mobile_spec, make_scene):
    scene = make_scene(mobile_spec, task="nav_obstacles", render_images=False)
    hal = SimAttachedHAL(scene)
    assert not hal.connected
    with pytest.raises(NotConnectedError):
        hal.read_state()
    with pytest.raises(NotConnectedError):
        hal.tick()
    hal.connect()
    assert hal.connected and hal.action_dim == scene.action_dim == 10
    assert hal.action == scene.spec.action and hal.control_hz == HZ
    assert hal.joint_names == tuple(mobile_spec.joint_names) == scene.spec.robot.joint_names
    drive(hal, 10, [0.4, 0.1, 0.3])
    st = hal.read_state()
    assert isinstance(st, JointState) and st.names == tuple(mobile_spec.joint_names)
    assert st.positions.dtype == np.float64 and st.velocities.dtype == np.float64
    assert st.positions.shape == st.velocities.shape == (len(mobile_spec.joints),)
    np.testing.assert_array_equal(st.positions[:3], hal.base_pose())  # base joints are the base pose
    assert hal.base_pose()[0] > 0.1 and hal.base_pose()[2] > 0.1
    obs = hal.last_observation()
    np.testing.assert_allclose(st.positions[3:], obs["joint_positions"][3:])
    assert st.stamp_ns == obs["sim_time_ns"] == hal.sim_time_ns() == 10 * 50_000_000
    assert hal.read_scan().shape == (360,) and hal.read_images() == {} and hal.read_depth_clouds() == {}


class _Misdescribed:
    """A rollout whose ``action_dim`` disagrees with its own spec: the HAL must refuse, not guess."""

    def __init__(self, inner, action_dim):
        self._inner = inner
        self._dim = action_dim

    def __getattr__(self, name):
        return getattr(self._inner, name)

    @property
    def action_dim(self):
        return self._dim


def test_connect_refuses_a_rollout_that_contradicts_its_spec(panda_spec, make_scene):
    scene = make_scene(panda_spec, render_images=False)
    with pytest.raises(ConfigError, match="action_dim 9"):
        SimAttachedHAL(_Misdescribed(scene, 9)).connect()


def test_body_twist_moves_the_base_and_odometry_reads_it_in_the_base_frame(mobile_hal):
    hal = mobile_hal()
    assert hal.base_pose().tolist() == [0.0, 0.0, 0.0] and hal.base_twist().tolist() == [0.0, 0.0, 0.0]
    drive(hal, HZ, [0.3, 0.0, 0.0])  # 0.3 m/s for 1 s
    x, y, yaw = hal.base_pose()
    assert x == pytest.approx(0.30, abs=0.03) and abs(y) < 1e-6 and abs(yaw) < 1e-9
    np.testing.assert_allclose(hal.base_twist(), [0.3, 0.0, 0.0], atol=1e-3)
    # a quarter turn, then forward: the world motion is along +y, the odometry twist still +vx
    drive(hal, 2 * HZ, [0.0, 0.0, math.pi / 4])
    np.testing.assert_allclose(hal.base_twist(), [0.0, 0.0, math.pi / 4], atol=1e-3)
    p0 = hal.base_pose()
    assert p0[2] == pytest.approx(math.pi / 2, abs=0.02)
    drive(hal, 10, [0.3, 0.0, 0.0])
    p1 = hal.base_pose()
    assert p1[1] - p0[1] == pytest.approx(0.15, abs=0.01) and abs(p1[0] - p0[0]) < 0.01
    np.testing.assert_allclose(hal.base_twist(), [0.3, 0.0, 0.0], atol=0.01)
    vel = hal.read_state().velocities[:3]  # the base joints: world-frame rates
    np.testing.assert_allclose(vel, [0.0, 0.3, 0.0], atol=0.01)
    drive(hal, 1, [0.0, 0.2, 0.0])  # sideways in the base frame
    np.testing.assert_allclose(hal.base_twist(), [0.0, 0.2, 0.0], atol=0.01)


def test_a_command_expires_after_the_hold_time_and_sensors_stay_live(mobile_hal):
    hal = mobile_hal(hold_time_s=0.5)
    hal.send_action([0.3, 0.0, 0.0], "body_twist")  # once, then silence
    xs, stamps, scans = [], [], []
    for _ in range(30):  # 1.5 s of sim time
        hal.tick()
        xs.append(hal.base_pose()[0])
        stamps.append(hal.read_state().stamp_ns)
        scans.append(hal.read_scan())
    # applied on the ticks that start within 0.5 s of the command (10 ticks), never after
    assert xs[9] == pytest.approx(0.15, abs=0.005)
    assert xs[29] == xs[10] == xs[9]
    np.testing.assert_array_equal(hal.base_twist(), [0.0, 0.0, 0.0])
    assert stamps == [50_000_000 * (k + 1) for k in range(30)]  # idle ticks keep time moving
    assert all(s is not None and s.shape == (360,) for s in scans)
    # a new command starts it again
    drive(hal, 4, [0.3, 0.0, 0.0])
    assert hal.base_pose()[0] - xs[-1] == pytest.approx(0.06, abs=0.003)


def test_estop_latches_drops_commands_and_clears(mobile_hal):
    hal = mobile_hal()
    drive(hal, 5, [0.5, 0.0, 0.2])
    assert hal.base_twist()[0] == pytest.approx(0.5, abs=0.01)
    hal.estop()
    assert hal.estopped
    p = hal.base_pose()
    hal.tick()  # the very next tick: stopped
    assert np.linalg.norm(hal.base_pose()[:2] - p[:2]) < 1e-3 and abs(hal.base_pose()[2] - p[2]) < 1e-3
    for _ in range(3):
        hal.send_action([0.5, 0.0, 0.0], ControlMode.BODY_TWIST)
        hal.send_action([0.0, 0.0, 1.0, 0.0, 0.0, 0.0], ControlMode.CARTESIAN_DELTA)
        hal.send_action(1.0, ControlMode.GRIPPER)
        hal.tick()
    assert hal.dropped_commands == 9
    np.testing.assert_allclose(hal.base_pose(), p, atol=1e-3)
    np.testing.assert_array_equal(hal.last_action[hal.action.base], [0, 0, 0])
    np.testing.assert_array_equal(hal.last_action[hal.action.arm], np.zeros(6))
    assert hal.last_action[hal.action.grip] == -1.0  # the gripper command was dropped too
    with pytest.raises(InvalidActionError):  # still validated while engaged
        hal.send_action([0.5, 0.0], ControlMode.BODY_TWIST)
    hal.estop(False)
    assert not hal.estopped
    hal.tick()  # nothing from before the E-stop resumes
    np.testing.assert_allclose(hal.base_pose(), p, atol=1e-3)
    drive(hal, 10, [0.4, 0.0, 0.0])  # new commands are obeyed
    moved = np.linalg.norm(hal.base_pose()[:2] - p[:2])
    assert moved == pytest.approx(0.2, abs=0.01) and hal.dropped_commands == 9


def _fingers(hal):
    st = hal.read_state()
    return st.positions[[st.names.index("panda_finger_joint1"), st.names.index("panda_finger_joint2")]]


def test_gripper_closes_and_opens_and_keeps_its_last_value(panda_spec, make_scene):
    hal = SimAttachedHAL(make_scene(panda_spec, render_images=False), hold_time_s=0.2)
    hal.connect()
    assert _fingers(hal).min() > 0.035  # starts open; the HAL reads it as -1
    assert hal.base_pose() is None and hal.base_twist() is None and hal.read_scan() is None  # a fixed arm
    hal.send_action([1.0], "gripper")
    for _ in range(HZ):  # well past the hold time: the gripper keeps its last command
        hal.tick()
    assert _fingers(hal).max() < 0.005
    hal.send_action(-1.0, ControlMode.GRIPPER)
    for _ in range(HZ):
        hal.tick()
    assert _fingers(hal).min() > 0.035
    hal.send_action(3.0, ControlMode.GRIPPER)  # clipped to +1
    hal.tick()
    assert hal.last_action[hal.action.grip] == 1.0


def test_cartesian_delta_moves_the_end_effector_and_holds_when_stale(panda_spec, make_scene):
    hal = SimAttachedHAL(make_scene(panda_spec, render_images=False), hold_time_s=0.25)
    hal.connect()
    z0 = hal.last_observation()["state"][:3].copy()
    for _ in range(5):
        hal.send_action([0.0, 0.0, 0.5, 0.0, 0.0, 0.0], ControlMode.CARTESIAN_DELTA)  # 2.5 cm per tick
        hal.tick()
    z1 = hal.last_observation()["state"][:3].copy()
    assert z1[2] - z0[2] == pytest.approx(0.125, abs=0.015)
    assert np.linalg.norm(z1[:2] - z0[:2]) < 0.01
    # no new command: the last one (sent at t = 0.2 s) still applies on the ticks starting at
    # t = 0.25 .. 0.4 s (younger than the 0.25 s hold time), then the arm holds
    for _ in range(15):
        hal.tick()
    z2 = hal.last_observation()["state"][:3].copy()
    assert z2[2] - z1[2] == pytest.approx(0.1, abs=0.015)
    hal.tick()
    z3 = hal.last_observation()["state"][:3]
    assert np.linalg.norm(z3 - z2) < 2e-3


def test_joint_position_targets_are_clamped_to_limits_and_speed(panda_spec, make_scene):
    scene = make_scene(panda_spec, render_images=False, control_mode="joint_position")
    hal = SimAttachedHAL(scene, joint_limits={"panda_joint1": (-0.2, 0.2)}, max_joint_speed=0.5)
    hal.connect()
    i1, i4 = hal.joint_names.index("panda_joint1"), hal.joint_names.index("panda_joint4")
    home = hal.read_state().positions[:7].copy()  # the arm joints lead the manifest order
    target = home.copy()
    target[0] = 1.0  # beyond the 0.2 limit given here
    target[3] = -5.0  # beyond the URDF's lower limit (-3.1416), taken from the spec
    q1, applied = [], []
    for k in range(HZ):
        hal.send_action(target, "joint_position")
        hal.tick()
        if k == 0:  # the applied target moved by at most 0.5 rad/s * 50 ms
            np.testing.assert_allclose(hal.last_action[[0, 3]], [home[0] + 0.025, home[3] - 0.025], atol=1e-6)
        applied.append(hal.last_action[0])
        q1.append(hal.read_state().positions[i1])
    np.testing.assert_allclose(applied, np.minimum(home[0] + 0.025 * np.arange(1, HZ + 1), 0.2), atol=1e-6)
    q1 = np.array(q1)
    assert q1[3] == pytest.approx(0.1, abs=0.01)  # 0.2 s at 0.5 rad/s
    assert np.all(q1[:6] <= home[0] + 0.025 * np.arange(1, 7) + 0.01)  # measured: the cap + servo tracking
    assert q1[-1] == pytest.approx(0.2, abs=0.01) and q1.max() < 0.2 + 0.005  # stops at the limit
    assert hal.last_action[3] >= -3.1416 and hal.read_state().positions[i4] > -3.1416 - 0.01
    # once the command is stale, the arm holds where it was measured
    for _ in range(HZ):
        hal.tick()
    assert hal.read_state().positions[i1] == pytest.approx(0.2, abs=0.01)
    with pytest.raises(InvalidActionError, match="joint_position.*expected 7"):
        hal.send_action(target[:6], "joint_position")
    with pytest.raises(ConfigError, match="not arm joints"):
        SimAttachedHAL(scene, joint_limits={"base_x": (0, 1)}).connect()


def test_modes_the_rollout_cannot_express_and_bad_commands(panda_spec, mobile_hal, make_scene):
    arm = SimAttachedHAL(make_scene(panda_spec, render_images=False))
    arm.connect()
    with pytest.raises(ConfigError, match="'cartesian_delta' control mode.*'joint_position'"):
        arm.send_action(np.zeros(7), ControlMode.JOINT_POSITION)
    with pytest.raises(ConfigError, match="no kinematic base"):
        arm.send_action([0.1, 0.0, 0.0], "body_twist")
    with pytest.raises(ConfigError, match="unknown control mode"):
        arm.send_action([0.1], "velocity")
    joint = SimAttachedHAL(make_scene(panda_spec, render_images=False, control_mode="joint_position"))
    joint.connect()
    with pytest.raises(ConfigError, match="cannot express 'cartesian_delta'"):
        joint.send_action(np.zeros(6), "cartesian_delta")
    hal = mobile_hal()
    with pytest.raises(InvalidActionError, match="body_twist.*expected 3"):
        hal.send_action([0.1, 0.0], "body_twist")
    with pytest.raises(InvalidActionError, match="cartesian_delta.*expected 6"):
        hal.send_action(np.zeros(7), "cartesian_delta")
    with pytest.raises(InvalidActionError, match="gripper.*expected 1"):
        hal.send_action([1.0, 1.0], "gripper")
    with pytest.raises(InvalidActionError, match=r"body_twist command\[1\] is nan"):
        hal.send_action([0.1, float("nan"), 0.0], "body_twist")
    with pytest.raises(InvalidActionError, match="not numeric"):
        hal.send_action("fast", "body_twist")
    hal.tick()  # nothing was stored
    assert hal.base_pose().tolist() == [0.0, 0.0, 0.0]
    assert set(hal.supported_modes()) == {ControlMode.CARTESIAN_DELTA, ControlMode.GRIPPER, ControlMode.BODY_TWIST}


def test_a_sim_scene_cannot_attach_to_real_hardware(panda_spec, make_scene):
    scene = make_scene(panda_spec, render_images=False)
    for target in ("real", "hardware", "REAL"):
        with pytest.raises(ConfigError, match="a sim scene cannot attach to a real-hardware HAL"):
            SimAttachedHAL.attach(scene, target=target)
    with pytest.raises(ConfigError, match="unknown HAL target"):
        SimAttachedHAL.attach(scene, target="gazebo")
    hal = SimAttachedHAL.attach(scene, hold_time_s=0.1)
    assert isinstance(hal, SimAttachedHAL) and hal.hold_time_s == 0.1
    hal.connect()
    hal.close()
    assert not hal.connected
    with pytest.raises(NotConnectedError):
        hal.tick()


def test_works_over_a_sidecar_rollout(mobile_spec):
    from simseam.sidecar.client import SidecarRollout
    from simseam.sidecar.target import SceneTarget

    rollout = SidecarRollout(SceneTarget(mobile_spec.to_json(), "nav_obstacles", "mujoco",
                                         dataclasses.asdict(SceneOptions(render_images=False))))
    try:
        hal = SimAttachedHAL.attach(rollout)
        hal.connect()
        assert hal.action_dim == rollout.action_dim == 10
        assert hal.joint_names == tuple(mobile_spec.joint_names)
        drive(hal, 10, [0.3, 0.0, 0.0])
        assert hal.base_pose()[0] == pytest.approx(0.15, abs=0.015)
        np.testing.assert_allclose(hal.base_twist(), [0.3, 0.0, 0.0], atol=0.01)
        assert hal.read_scan().shape == (360,) and hal.read_state().stamp_ns == 500_000_000
    finally:
        rollout.close()
