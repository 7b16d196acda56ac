"""The bridge in-process over DDS (loopback, private domain): joint states, clock, tf_static, estop."""

import time

import numpy as np
import pytest

from simseam.hal.sim_attached import SimAttachedHAL
from simseam.ros2 import msgs as m
from simseam.ros2.bridge import Ros2Bridge, parse_rates
from simseam.ros2.dds import CLOCK, COMMAND, STATE, TF_STATIC, Participant
from simseam.runner.scene_config import build_rollout, load_scene_config
from simseam.seam import ConfigError


@pytest.fixture
def bridge(ros_env, mobile_scene):
    cfg, base = load_scene_config(mobile_scene)

    hal = SimAttachedHAL.attach(build_rollout(cfg, base), target="sim")
    br = Ros2Bridge(hal, rtf=0, participant=Participant())
    br.start()
    yield br
    br.close()
    hal.close()


def _wait(pred, timeout=60.0, tick=None):
    """Until ``pred()`` (an event); ``timeout`` is a hang guard for a loaded machine, not a timing check."""
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        if tick is not None:
            tick()
        if pred():
            return True
        time.sleep(0.01)
    return False


def test_joint_states_clock_and_tf_static_reach_a_dds_subscriber(bridge):
    client = Participant()  # another participant on the same private domain
    try:
        js_reader = client.reader("/joint_states", m.JointState, STATE)
        clock_reader = client.reader("/clock", m.Clock, CLOCK)
        static_reader = client.reader("/tf_static", m.TFMessage, TF_STATIC)
        got_js, got_clock, got_static = [], [], []

        def drain():
            got_js.extend(s for s in js_reader.take(N=100) if isinstance(s, m.JointState))
            got_clock.extend(s for s in clock_reader.take(N=100) if isinstance(s, m.Clock))
            got_static.extend(s for s in static_reader.take(N=10) if isinstance(s, m.TFMessage))

        assert _wait(lambda: (drain(), got_js and got_clock)[1], tick=bridge.step), "no sample reached the reader"
        got_js.clear()
        got_clock.clear()
        for _ in range(25):
            bridge.step()
        now = bridge.hal.sim_time_ns()
        # reliable /joint_states: wait (event) until the sample of the current tick is here
        assert _wait(lambda: (drain(), got_js and got_js[-1].header.stamp.to_ns() == now)[1], timeout=60)
        state = bridge.hal.read_state()
        last = got_js[-1]
        urdf_names = [j.sim_name for j in bridge.spec.joints if j.role != "base"]  # the base is on /odom
        assert list(last.name) == urdf_names and list(state.names)[3:] == urdf_names
        np.testing.assert_array_equal(last.position, state.positions[3:])
        np.testing.assert_array_equal(last.velocity, state.velocities[3:])
        # best-effort /clock: whatever arrived is strictly monotonic, on the tick grid, never ahead of sim time
        stamps = [c.clock.to_ns() for c in got_clock]
        assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)
        assert all(s % bridge._dt_ns == 0 and s <= now for s in stamps)
        # /tf_static is latched (transient local): a late subscriber still gets the mounts and fixed joints
        assert _wait(lambda: (drain(), got_static)[1], timeout=60)
        frames = {t.child_frame_id for msg in got_static for t in msg.transforms}
        assert {"camera1", "camera1_optical", "front_depth", "base_scan", "panda_link0", "panda_hand"} <= frames
    finally:
        client.close()


def test_estop_over_dds_stops_the_base(bridge):
    client = Participant()
    try:
        cmd = client.writer("/cmd_vel", m.Twist, COMMAND)
        estop = client.writer("/estop", m.Bool, COMMAND)
        go = m.Twist(m.Vector3(0.4, 0.0, 0.0), m.Vector3())

        def drive(n):
            for _ in range(n):
                cmd.write(go)
                bridge.step()

        x0 = bridge.hal.base_pose()[0]
        assert _wait(lambda: (drive(1), bridge.hal.base_pose()[0] > x0 + 0.02)[1], timeout=60), "never moved"
        estop.write(m.Bool(True))
        assert _wait(lambda: (drive(1), bridge.hal.estopped)[1], timeout=60)  # the event: the latch engaged
        x1 = bridge.hal.base_pose()[0]
        drive(50)  # 1 s of sim time with /cmd_vel still coming: ignored while the E-stop is latched
        assert bridge.hal.base_pose()[0] == pytest.approx(x1, abs=1e-9)
        assert bridge.stats.commands["/estop"] >= 1
        estop.write(m.Bool(False))
        assert _wait(lambda: (drive(1), not bridge.hal.estopped)[1], timeout=60)
        drive(25)  # 0.5 s sim: moving again at 0.4 m/s
        assert bridge.hal.base_pose()[0] - x1 == pytest.approx(0.4 * 0.5, abs=0.02)
    finally:
        client.close()


def test_rates_parse_and_schedule(bridge):
    assert parse_rates(["camera=5", "scan=0", "clock=max"])["camera"] == 5.0
    with pytest.raises(ConfigError):
        parse_rates(["bogus=3"])
    bridge.stats.published.clear()
    for _ in range(50):  # 1 s of sim time at 50 Hz
        bridge.step()
    pub = bridge.stats.published
    assert pub["/clock"] == 50 and pub["/joint_states"] == 50 and pub["/odom"] == 50
    assert pub["/tf"] == 100  # arm links + odom -> base_link, each at 50 Hz
    assert pub["/camera1/image_raw"] == 10 and pub["/scan"] == 10 and pub["/front_depth/points"] == 10


def test_foxglove_style_injected_commands_share_the_hal_path(bridge):
    """``inject`` (the Foxglove server's clientPublish) obeys the same hold time and E-stop latch as DDS."""
    go = m.Twist(m.Vector3(0.3, 0.0, 0.0), m.Vector3())
    x0 = bridge.hal.base_pose()[0]
    for _ in range(25):
        bridge.inject("/cmd_vel", go)
        bridge.step()
    assert bridge.hal.base_pose()[0] - x0 == pytest.approx(0.3 * 0.5, abs=0.01)
    bridge.inject("/estop", m.Bool(True))
    bridge.inject("/cmd_vel", go)
    bridge.step()
    assert bridge.hal.estopped
    x1 = bridge.hal.base_pose()[0]
    for _ in range(10):
        bridge.inject("/cmd_vel", go)
        bridge.step()
    assert bridge.hal.base_pose()[0] == pytest.approx(x1, abs=1e-9)
    bridge.inject("/estop", m.Bool(False))
    bridge.step()
    assert not bridge.hal.estopped
    with pytest.raises(ConfigError):
        bridge.inject("/bogus", go)


def test_discovery_config_follows_ros_environment():
    from simseam.ros2.dds import LOOPBACK_XML, discovery_config, discovery_summary

    assert discovery_config({}) == LOOPBACK_XML == discovery_config({"ROS_AUTOMATIC_DISCOVERY_RANGE": "localhost"})
    assert 'name="lo" multicast="true"' in LOOPBACK_XML and "<AllowMulticast>spdp" in LOOPBACK_XML
    assert discovery_config({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET"}) is None  # Cyclone's defaults: the network
    peers = discovery_config({"ROS_AUTOMATIC_DISCOVERY_RANGE": "SUBNET", "ROS_STATIC_PEERS": "10.0.0.7;robot.local"})
    assert '<Peer address="10.0.0.7"/>' in peers and '<Peer address="robot.local"/>' in peers and 'name="lo"' not in peers
    assert "<AllowMulticast>false" in discovery_config({"ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF"})
    with pytest.raises(ConfigError):
        discovery_config({"ROS_AUTOMATIC_DISCOVERY_RANGE": "everywhere"})
    assert discovery_summary({}).startswith("loopback only")
