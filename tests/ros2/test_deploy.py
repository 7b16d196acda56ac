"""``simseam deploy --ros2 --record`` as its own process: /cmd_vel from this process moves /odom, Ctrl-C
shuts down cleanly, and the MCAP decodes (mcap + rosbags) to what DDS carried. (The E-stop over DDS: the
real ROS 2 peer test and test_bridge.)"""

import os
import signal
import subprocess
import sys
import time

import pytest

from simseam.ros2 import msgs as m
from simseam.ros2.dds import COMMAND, STATE, Participant

SPEED = 0.25  # m/s, below panda_mobile's max_linear


def test_cmd_vel_moves_odom_and_the_recording_matches(ros_env, mobile_scene, tmp_path):
    mcap_path = tmp_path / "run.mcap"
    env = dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), PYTHONUNBUFFERED="1")
    proc = subprocess.Popen(
        [sys.executable, "-m", "simseam.cli.main", "deploy", "--scene", str(mobile_scene), "--ros2",
         "--record", str(mcap_path), "--rate", "camera=2", "--rate", "depth=2", "--hold-time", "0.2"],
        env=env, stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, start_new_session=True)
    client = Participant(node_name="simseam_test_client")
    try:
        odom_reader = client.reader("/odom", m.Odometry, STATE)
        cmd = client.writer("/cmd_vel", m.Twist, COMMAND)
        odoms: list = []

        def pump_until(pred, twist=None, guard_s=120.0):
            """Drain /odom (and keep commanding) until ``pred()``: an event, with a hang guard."""
            end = time.monotonic() + guard_s
            while not pred():
                assert time.monotonic() < end, f"no progress: {len(odoms)} /odom samples"
                assert proc.poll() is None, proc.stdout.read()
                if twist is not None:
                    cmd.write(twist)
                odoms.extend(s for s in odom_reader.take(N=200) if isinstance(s, m.Odometry))
                time.sleep(0.02)

        pump_until(lambda: len(odoms) >= 5)  # scene build + discovery
        go = m.Twist(m.Vector3(SPEED, 0.0, 0.0), m.Vector3())
        moving = lambda: [o for o in odoms if abs(o.twist.twist.linear.x - SPEED) < 1e-6]  # noqa: E731
        pump_until(lambda: len(moving()) >= 50, go)  # 1 s of sim time under way
        a, b = moving()[0], moving()[-1]
        dt = (b.header.stamp.to_ns() - a.header.stamp.to_ns()) * 1e-9
        # the base moves at the commanded speed in sim time: the expected distance, to a millimetre
        assert b.pose.pose.position.x - a.pose.pose.position.x == pytest.approx(SPEED * dt, abs=1e-3)

        proc.send_signal(signal.SIGINT)  # Ctrl-C
        out, _ = proc.communicate(timeout=60)
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

    store = get_typestore(Stores.ROS2_JAZZY)
    rec: dict[str, list] = {}
    with open(mcap_path, "rb") as fh:
        reader = make_reader(fh)
        for schema, channel, message in reader.iter_messages():
            assert schema.encoding == "ros2msg" and channel.message_encoding == "cdr"
            rec.setdefault(channel.topic, []).append((message.log_time, store.deserialize_cdr(message.data,
                                                                                               schema.name)))
    assert {"/clock", "/joint_states", "/odom", "/tf", "/tf_static", "/scan", "/camera1/image_raw",
            "/front_depth/points", "/robot_description"} <= set(rec)
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
    assert matched == len(by_stamp)  # every sample DDS delivered is in the file, with the same values
    clock = [c.clock.sec * 10**9 + c.clock.nanosec for _, c in rec["/clock"]]
    assert clock == sorted(clock)
    js = rec["/joint_states"][-1][1]
    assert list(js.name)[0] == "panda_joint1" and len(js.position) == 9  # URDF joints; the base is on /odom
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
    assert data["published"]["/robot_description"] == 1 and data["published"]["/tf_static"] == 1
    from mcap.reader import make_reader

    with open(mcap_path, "rb") as fh:
        topics = {ch.topic for ch in make_reader(fh).get_summary().channels.values()}
    assert {"/clock", "/joint_states", "/odom", "/scan"} <= topics


def test_bad_recording_and_port_input_is_one_line_and_overwrites_nothing(mobile_scene, tmp_path):
    """--record naming a directory or an existing file (kept unless --overwrite), a port out of range."""
    from cli_util import simseam

    folder = tmp_path / "runs"
    folder.mkdir()
    old = tmp_path / "old.mcap"
    old.write_bytes(b"earlier recording")
    for args, fragment in ((["--record", folder], f"--record {folder}: is a directory"),
                           (["--record", old], f"--record {old}: the file exists; choose another or pass --overwrite"),
                           (["--foxglove", "--foxglove-port", "70000"], "less than or equal to 65535"),
                           (["--foxglove", "--foxglove-port", "-5"], "greater than or equal to 0")):
        proc = simseam("deploy", "--scene", mobile_scene, "--duration", "0.1", *args, timeout=120)
        assert proc.returncode == 2 and fragment in " ".join(proc.stderr.replace("│", " ").split()), proc.stderr
        assert "Traceback" not in proc.stderr
    assert old.read_bytes() == b"earlier recording"
    proc = simseam("deploy", "--scene", mobile_scene, "--duration", "0.1", "--record", old, "--overwrite", timeout=120)
    assert proc.returncode == 0, proc.stderr
    assert old.read_bytes()[:8] == b"\x89MCAP0\r\n"  # replaced by a recording


def test_deploy_shows_a_live_status_line_on_a_terminal():
    """While deploy runs, a terminal shows its sim time, real-time factor and message counts, refreshed
    (catches: nothing on screen between the start line and 'stopped:')."""
    import io
    from types import SimpleNamespace

    from rich.console import Console

    from simseam.cli.deploy import live_status, status_line
    from simseam.ros2.bridge import BridgeStats

    stats = BridgeStats(ticks=40, published={"/joint_states": 40, "/tf": 60}, commands={"/joint_command": 3},
                        rejected=1)
    assert status_line(stats, 20.0, 2.0) == "live: 2.0 s sim, rtf 1.00, 100 messages out, 3 commands in, 1 rejected"
    screen = io.StringIO()
    bridge = SimpleNamespace(stats=BridgeStats())
    with live_status(Console(file=screen, force_terminal=True, width=120), bridge, 20.0, every_s=0.02):
        bridge.stats.ticks = 10
        time.sleep(0.3)
    assert "live: 0.5 s sim" in screen.getvalue()
