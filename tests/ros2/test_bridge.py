"""The bridge in-process over DDS (loopback, private domain): joint states, clock, tf_static, estop."""

import time

import numpy as np
import pytest

from simseam.hal.sim_attached import SimAttachedHAL
from simseam.ros2 import msgs as m
from simseam.ros2.bridge import Ros2Bridge, parse_rates
from simseam.ros2.dds import CLOCK, COMMAND, STATE, TF_STATIC, Participant
from simseam.runner.scene_config import build_rollout, load_scene_config, resolve_robot
from simseam.seam import ConfigError


@pytest.fixture
def bridge(ros_env, mobile_scene):
    cfg, base = load_scene_config(mobile_scene)
    spec = resolve_robot(cfg, base)
    hal = SimAttachedHAL.attach(build_rollout(cfg, base), target="sim")
    br = Ros2Bridge(hal, spec=spec, rtf=0, participant=Participant())
    br.start()
    yield br
    br.close()
    hal.close()


def _wait(pred, timeout=5.0, tick=None):
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
            time.sleep(0.002)
        assert _wait(lambda: (drain(), got_js and got_js[-1].header.stamp.to_ns() == bridge.hal.sim_time_ns())[1])
        state = bridge.hal.read_state()
        last = got_js[-1]
        assert list(last.name) == list(bridge.spec.joint_names) == list(state.names)
        np.testing.assert_array_equal(last.position, state.positions)
        np.testing.assert_array_equal(last.velocity, state.velocities)
        stamps = [c.clock.to_ns() for c in got_clock]
        assert stamps == sorted(stamps) and len(set(stamps)) == len(stamps)  # strictly monotonic
        assert stamps[-1] == bridge.hal.sim_time_ns()
        # /tf_static is latched (transient local): a late subscriber still gets the sensor mounts
        frames = {t.child_frame_id for msg in got_static for t in msg.transforms}
        assert {"camera1", "camera1_optical", "front_depth", "base_scan"} <= frames
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
                time.sleep(0.003)
                bridge.step()

        x0 = bridge.hal.base_pose()[0]
        assert _wait(lambda: (drive(1), bridge.hal.base_pose()[0] > x0 + 0.02)[1]), "the base never moved"
        estop.write(m.Bool(True))
        assert _wait(lambda: (drive(1), bridge.hal.estopped)[1])
        bridge.step()
        x1 = bridge.hal.base_pose()[0]
        drive(15)  # /cmd_vel keeps coming: ignored while the E-stop is latched
        assert bridge.hal.base_pose()[0] == pytest.approx(x1, abs=1e-9)
        assert bridge.stats.commands["/estop"] >= 1
        estop.write(m.Bool(False))
        assert _wait(lambda: (drive(1), bridge.hal.base_pose()[0] > x1 + 0.02)[1]), "cleared E-stop: no motion"
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
    assert pub["/camera1/image_raw"] == 10 and pub["/scan"] == 10 and pub["/front_depth/points"] == 10
