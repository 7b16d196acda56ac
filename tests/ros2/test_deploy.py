"""``simseam deploy --ros2 --record`` as its own process: /cmd_vel from this process moves /odom,
/estop stops it, Ctrl-C shuts down cleanly, and the MCAP decodes (mcap + rosbags) to what DDS carried."""

import os
import signal
import subprocess
import sys
import time

import pytest

from simseam.ros2 import msgs as m
from simseam.ros2.dds import COMMAND, STATE, Participant

SPEED = 0.25  # m/s, below panda_mobile's max_linear


def test_cmd_vel_moves_odom_estop_stops_it_and_the_recording_matches(ros_env, mobile_scene, tmp_path):
    mcap_path = tmp_path / "run.mcap"
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "simseam.cli.main", "deploy", "--scene", str(mobile_scene), "--ros2",
         "--record", str(mcap_path), "--rate", "camera=2", "--rate", "depth=2", "--hold-time", "0.2"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    client = Participant()
    try:
        odom_reader = client.reader("/odom", m.Odometry, STATE)
        cmd = client.writer("/cmd_vel", m.Twist, COMMAND)
        estop = client.writer("/estop", m.Bool, COMMAND)
        odoms: list = []

        def pump(seconds, twist=None):
            end = time.monotonic() + seconds
            while time.monotonic() < end:
                if twist is not None:
                    cmd.write(twist)
                odoms.extend(s for s in odom_reader.take(N=200) if isinstance(s, m.Odometry))
                time.sleep(0.05)
                assert proc.poll() is None, proc.stdout.read()

        deadline = time.monotonic() + 30
        while not odoms and time.monotonic() < deadline:  # scene build + discovery
            pump(0.2)
        assert odoms, "no /odom from the deploy process"
        pump(0.3)
        go = m.Twist(m.Vector3(SPEED, 0.0, 0.0), m.Vector3())
        pump(1.5, go)
        moving = [o for o in odoms if abs(o.twist.twist.linear.x - SPEED) < 1e-6]
        assert len(moving) >= 20, f"only {len(moving)} /odom samples while driving"
        a, b = moving[0], moving[-1]
        dt = (b.header.stamp.to_ns() - a.header.stamp.to_ns()) * 1e-9
        # the base moves at the commanded speed in sim time: the expected distance, to a millimetre
        assert b.pose.pose.position.x - a.pose.pose.position.x == pytest.approx(SPEED * dt, abs=1e-3)
        assert b.pose.pose.position.x - odoms[0].pose.pose.position.x > 0.2

        estop.write(m.Bool(True))
        pump(0.4, go)
        n_before = len(odoms)
        pump(0.8, go)  # still commanding: the E-stop holds the base
        after = odoms[n_before:]
        assert len(after) >= 10
        assert max(o.pose.pose.position.x for o in after) - min(o.pose.pose.position.x for o in after) < 1e-9
        assert all(o.twist.twist.linear.x == 0.0 for o in after)

        proc.send_signal(signal.SIGINT)  # Ctrl-C
        out, _ = proc.communicate(timeout=20)
        assert proc.returncode == 0, out
        assert "stopped:" in out
    finally:
        client.close()
        if proc.poll() is None:
            os.killpg(proc.pid, signal.SIGKILL)
            proc.wait()

    # the recording: standard MCAP + ROS 2 schemas, decoded with mcap's reader and rosbags' CDR
    from mcap.reader import make_reader
    from rosbags.typesys import Stores, get_typestore

    store = get_typestore(Stores.ROS2_HUMBLE)
    rec: dict[str, list] = {}
    with open(mcap_path, "rb") as fh:
        reader = make_reader(fh)
        for schema, channel, message in reader.iter_messages():
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            rec.setdefault(channel.topic, []).append((message.log_time, store.deserialize_cdr(message.data,
                                                                                               schema.name)))
    assert {"/clock", "/joint_states", "/odom", "/tf", "/tf_static", "/scan", "/camera1/image_raw",
            "/front_depth/points"} <= set(rec)
    by_stamp = {o.header.stamp.to_ns(): o for o in odoms}
    matched = 0
    for log_time, o in rec["/odom"]:
        stamp = o.header.stamp.sec * 10**9 + o.header.stamp.nanosec
        assert log_time == stamp
        if stamp in by_stamp:
            sent = by_stamp[stamp]
            assert o.pose.pose.position.x == sent.pose.pose.position.x
            assert o.twist.twist.linear.x == sent.twist.twist.linear.x
            matched += 1
    assert matched >= len(odoms) - 5  # every sample DDS delivered is in the file, with the same values
    clock = [c.clock.sec * 10**9 + c.clock.nanosec for _, c in rec["/clock"]]
    assert clock == sorted(clock)
    js = rec["/joint_states"][-1][1]
    assert list(js.name)[:3] == ["base_x", "base_y", "base_yaw"] and len(js.position) == 12
    img = rec["/camera1/image_raw"][-1][1]
    assert (img.height, img.width, img.encoding, len(img.data)) == (32, 32, "rgb8", 32 * 32 * 3)


def test_deploy_without_ros2_records_and_serves_foxglove(mobile_scene, tmp_path):
    """No DDS at all: the sim loop runs for --duration, records, and serves Foxglove on loopback."""
    from typer.testing import CliRunner

    from simseam.cli.main import app

    mcap_path = tmp_path / "plain.mcap"
    stats = tmp_path / "stats.json"
    res = CliRunner().invoke(app, ["deploy", "--scene", str(mobile_scene), "--record", str(mcap_path),
                                   "--foxglove", "--foxglove-port", "0", "--duration", "0.5", "--rtf", "0",
                                   "--rate", "camera=0", "--stats-json", str(stats)])
    assert res.exit_code == 0, res.output
    assert "foxglove: ws://127.0.0.1:" in res.output
    import json

    data = json.loads(stats.read_text())
    assert data["ticks"] == 25 and data["sim_s"] == pytest.approx(0.5)
    assert "/camera1/image_raw" not in data["published"] and data["published"]["/joint_states"] == 26
    from mcap.reader import make_reader

    with open(mcap_path, "rb") as fh:
        topics = {ch.topic for ch in make_reader(fh).get_summary().channels.values()}
    assert {"/clock", "/joint_states", "/odom", "/scan"} <= topics
