"""``simseam deploy --foxglove`` with an independent Foxglove client (@foxglove/ws-protocol under node, with
Foxglove's own ros2msg/CDR decoders), connecting late in the run as the Foxglove app does."""

import json
import math
import os
import re
import socket
import sys

import pytest

from simseam.robot.manifest import load_robot
from simseam.ros2.robot_model import RobotModel

from harness import PEERS, SIMSEAM, Proc, simseam_env

SPEED = 0.3
DRIVE_S = 2.0


def test_late_foxglove_client_decodes_everything_gets_tf_static_and_drives(mobile_scene, foxglove_client_dir):
    spec = load_robot("panda_mobile")
    frames = set(RobotModel(spec).frames()) | {s.name for s in spec.sensors}
    frames |= {f"{s.name}_optical" for s in spec.sensors if s.kind in ("rgb", "depth")}
    sim = Proc([*SIMSEAM, "deploy", "--scene", mobile_scene, "--foxglove", "--foxglove-port", "0",
                "--rate", "camera=5"], simseam_env(), "simseam")
    client = None
    try:
        url = re.search(r"ws://\S+", sim.wait_line(lambda s: "foxglove: ws://" in s)).group(0)
        sim.wait_line(lambda s: " on mujoco" in s)  # live: /tf_static and /robot_description were logged already
        env = dict(os.environ, NODE_PATH=str(foxglove_client_dir / "node_modules"))
        client = Proc(["node", PEERS / "foxglove_client.js", url, ",".join(sorted(frames)), SPEED, DRIVE_S], env,
                      "foxglove client")
        assert "clientPublish" in client.json()["capabilities"]
        out = client.json(timeout=300)
    finally:
        if client is not None:
            client.stop()
        code = sim.stop()
    assert "error" not in out, out.get("error")
    assert code == 0, sim.output()
    assert not out["decodeErrors"], out["decodeErrors"]
    expected = {"/clock", "/joint_states", "/odom", "/tf", "/tf_static", "/robot_description", "/scan",
                "/front_depth/points"} | {f"/{c}/{k}" for c in ("camera1", "camera2", "front_rgb")
                                         for k in ("image_raw", "camera_info")}
    assert expected <= set(out["channels"])
    assert all(out["counts"].get(t, 0) > 0 for t in out["channels"]), out["counts"]  # every channel decodes
    assert out["schemas"]["/tf_static"] == ["tf2_msgs/msg/TFMessage", "ros2msg", "cdr"]
    assert out["counts"]["/tf_static"] >= 1 and out["counts"]["/robot_description"] >= 1  # latched, delivered late
    missing = frames - set(out["reachable"])
    assert not missing, f"TF frames not reachable from odom: {sorted(missing)}"
    # a Twist published by the client (clientPublish, cdr) moved /odom by speed x time
    start = out["drive"]["start"]
    moving = [o for o in out["odom"] if o[0] >= start and abs(o[3] - SPEED) < 1e-6]
    assert len(moving) >= 40, f"{len(moving)} moving /odom samples"
    a, b = moving[0], moving[-1]
    dt = (b[0] - a[0]) * 1e-9
    dist = math.hypot(b[1] - a[1], b[2] - a[2])
    print(f"foxglove /cmd_vel {SPEED} m/s: /odom moved {dist:.4f} m in {dt:.3f} s sim")
    assert dist == pytest.approx(SPEED * dt, abs=0.02)


def test_foxglove_port_in_use_is_a_one_line_error(mobile_scene):
    import subprocess

    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        s.listen()
        port = s.getsockname()[1]
        res = subprocess.run([*SIMSEAM, "deploy", "--scene", str(mobile_scene), "--foxglove", "--foxglove-port",
                              str(port), "--duration", "0.1"], env=simseam_env(), capture_output=True, text=True,
                             timeout=300)
    assert res.returncode == 2, res.stdout + res.stderr
    err = res.stderr.strip()
    assert "Traceback" not in res.stdout + res.stderr
    assert len(err.splitlines()) == 1 and f"127.0.0.1:{port}" in err and "in use" in err, err
