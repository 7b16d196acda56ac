"""``simseam deploy --ros2`` against a real ROS 2 Jazzy node (rclpy + rmw_fastrtps_cpp, PyPI wheels).

Everything runs in a private network namespace with only loopback, with both sides on their
defaults (no CYCLONEDDS_URI, no ROS_AUTOMATIC_DISCOVERY_RANGE, domain 0), as a user would run
them. Peer A starts before simseam; peer B starts after simseam has run 35 s of sim time (past the
30 s after which the old unicast-only configuration stopped contacting peers). Waits are on
events (output lines, messages, sim time); timeouts are hang guards only.
"""

import math
import time
import xml.etree.ElementTree as ET

import numpy as np
import pytest

from simseam.robot.manifest import load_robot
from simseam.ros2.robot_model import RobotModel

from harness import MOBILE_SCENE, PEERS, SIMSEAM, NetNS, netns_possible, peer_env, simseam_env

SPEED = 0.3  # m/s
DISCOVERY_S = 5.0
LATE_SIM_S = 35.0
SPEC = load_robot("panda_mobile")
CAMERAS = [s.name for s in SPEC.sensors_of("rgb")]
DEPTHS = [s.name for s in SPEC.sensors_of("depth")]
CORE = ["/joint_states", "/odom", "/clock", "/scan", "/robot_description"]
ALL = CORE + [f"/{c}/{k}" for c in CAMERAS for k in ("image_raw", "camera_info")] + [f"/{d}/points" for d in DEPTHS]


@pytest.fixture(scope="module")
def live(ros_peer_python, mobile_scene_module):
    why = netns_possible()
    if why:
        pytest.skip(why)
    ns = NetNS()
    try:
        peer = ns.start([ros_peer_python, PEERS / "ros_peer.py", ",".join(CAMERAS), ",".join(DEPTHS), "peer_a"],
                        peer_env(ros_peer_python), "rclpy peer A")
        ready = peer.json()
        assert ready["event"] == "ready"
        sim = ns.start([*SIMSEAM, "deploy", "--scene", mobile_scene_module, "--ros2"], simseam_env(), "simseam")
        sim.wait_line(lambda s: "ROS 2: node /simseam" in s)
        t_participant = time.monotonic()  # simseam's DDS participant exists (the scene is built next)
        sim.wait_line(lambda s: " on mujoco" in s and "Hz" in s)
        yield {"ns": ns, "peer": peer, "sim": sim, "t_participant": t_participant, "python": ros_peer_python}
    finally:
        ns.close()


@pytest.fixture(scope="module")
def mobile_scene_module(tmp_path_factory):
    path = tmp_path_factory.mktemp("scene") / "mobile.yaml"
    path.write_text(MOBILE_SCENE)
    return path


@pytest.fixture(scope="module")
def first_report(live):
    peer = live["peer"]
    got = peer.ask(op="wait", topics=ALL, timeout=120)
    assert got["ok"], f"topics never arrived: {[t for t, v in got['first'].items() if v is None]}"
    return {"wait": got, "report": peer.ask(op="report")}


def test_discovery_peer_first_and_every_topic(live, first_report):
    first = first_report["wait"]["first"]
    # peer A was up before simseam: simseam's first messages reach it within 5 s of simseam's participant
    # (an upper bound on discovery: it includes building the scene)
    delay = first["/joint_states"] - live["t_participant"]
    print(f"discovery (ROS node first): first /joint_states {delay:.2f} s after simseam's participant came up")
    assert delay < DISCOVERY_S


def test_graph_shows_simseam_as_a_node(live):
    g = live["peer"].ask(op="graph", node="simseam", timeout=60)
    assert "/simseam" in g["nodes"], g["nodes"]
    pubs, subs = g["publishers"], g["subscribers"]
    for topic, typ in [("/joint_states", "sensor_msgs/msg/JointState"), ("/odom", "nav_msgs/msg/Odometry"),
                       ("/tf", "tf2_msgs/msg/TFMessage"), ("/tf_static", "tf2_msgs/msg/TFMessage"),
                       ("/clock", "rosgraph_msgs/msg/Clock"), ("/scan", "sensor_msgs/msg/LaserScan"),
                       ("/robot_description", "std_msgs/msg/String"),
                       ("/camera2/image_raw", "sensor_msgs/msg/Image"),
                       ("/front_depth/points", "sensor_msgs/msg/PointCloud2")]:
        assert pubs.get(topic) == [typ], (topic, pubs.get(topic))
    assert subs == {"/cmd_vel": ["geometry_msgs/msg/Twist"], "/joint_command": ["sensor_msgs/msg/JointState"],
                    "/estop": ["std_msgs/msg/Bool"]}
    assert "_CREATED_BY_BARE_DDS_APP_" not in " ".join(g["nodes"])


def test_joint_states_odom_scan_clock_values(first_report):
    rep = first_report["report"]
    model = RobotModel(SPEC)
    js = rep["joint_states"]
    urdf_joints = [j.sim_name for j in SPEC.joints if j.role != "base"]
    assert js["name"] == urdf_joints  # only joints of /robot_description; the base is on /odom
    home = {j.sim_name: j.home for j in SPEC.joints}
    np.testing.assert_allclose(js["position"], [home[n] for n in js["name"]], atol=0.05)
    assert set(js["name"]) <= set(model.urdf.joint_names)

    x0, y0, vx, wz, frame, child = rep["odom"][0][1:]
    assert (frame, child) == ("odom", "base_link")
    assert abs(x0) < 1e-6 and abs(y0) < 1e-6 and vx == 0.0 and wz == 0.0

    scan = rep["scan"]
    ranges = np.array([np.nan if r is None else r for r in scan["ranges"]], dtype=float)
    assert len(ranges) == 360 and scan["range_max"] == pytest.approx(10.0)
    hits = ranges[np.isfinite(ranges)]
    assert np.isposinf(ranges).sum() > 0, "REP-117: beams without a return are +inf"
    assert len(hits) > 0 and (hits >= scan["range_min"]).all() and (hits < scan["range_max"]).all()
    assert not np.isnan(ranges).any()
    print(f"/scan: {int(np.isposinf(ranges).sum())} of 360 beams +inf, {len(hits)} hits")

    clock = rep["clock"]
    assert clock == sorted(clock) and len(set(clock)) == len(clock)  # strictly monotonic
    dt = 20_000_000  # 50 Hz control: /clock is the sim time of each tick
    assert all(c % dt == 0 for c in clock)
    js_stamps = rep["stamps"]["/joint_states"]
    # /clock equals sim time: every /joint_states stamp (sim time) within /clock's span is a tick /clock carried
    # (best-effort /clock may drop a few, so at least most of them)
    span = [s for s in js_stamps if clock[0] <= s <= clock[-1]]
    assert span and sum(s in set(clock) for s in span) >= 0.8 * len(span)


def test_images_camera_info_and_points(first_report):
    rep = first_report["report"]
    for cam in CAMERAS:
        img, info = rep[f"/{cam}/image_raw"], rep[f"/{cam}/camera_info"]
        assert (img["height"], img["width"], img["encoding"], img["step"]) == (32, 32, "rgb8", 96)
        assert img["bytes"] == 32 * 32 * 3 and img["mean"] > 0
        assert img["frame"] == info["frame"] == f"{cam}_optical"
        fovy = next(s.fovy_deg for s in SPEC.sensors if s.name == cam)
        fy = 16.0 / math.tan(math.radians(fovy) / 2)
        assert info["k"] == pytest.approx([fy, 0, 16, 0, fy, 16, 0, 0, 1]) and info["model"] == "plumb_bob"
    pc = rep["/front_depth/points"]
    assert pc["fields"] == [["x", 0, 7, 1], ["y", 4, 7, 1], ["z", 8, 7, 1]] and pc["point_step"] == 12
    assert pc["height"] == 1 and pc["width"] > 0 and pc["bytes"] == 12 * pc["width"]
    assert pc["frame"] == SPEC.base_link


def test_robot_description_and_the_whole_tf_tree(live, first_report):
    text = first_report["report"]["robot_description"]
    root = ET.fromstring(text)
    model = RobotModel(SPEC)
    links = [el.get("name") for el in root.findall("link")]
    assert links == list(model.urdf.links)
    frames = set(links) | {"base_link"} | {s.name for s in SPEC.sensors} | {f"{c}_optical" for c in CAMERAS}
    probe = live["ns"].start([*SIMSEAM[:1], PEERS / "tf_probe.py", ",".join(sorted(frames)), "120"],
                             simseam_env(), "tf probe")
    probe.json()  # ready
    tf = probe.json(timeout=150)
    missing = frames - set(tf["reachable"])
    assert not missing, f"not reachable from odom: {sorted(missing)}"
    edges = tf["edges"]
    assert edges["base_link"] == ["odom", False]
    assert edges["panda_link0"] == ["base_link", True]  # REP-105 base_link -> URDF root, identity
    assert edges["camera2"] == ["panda_hand", True]  # the wrist camera hangs off the arm
    assert edges["panda_hand"] == ["panda_link8", True] and edges["panda_link7"] == ["panda_link6", False]


def _moving(odom, speed):
    return [o for o in odom if abs(o[3] - speed) < 1e-6]


def test_cmd_vel_moves_odom_and_estop_latches(live):
    peer = live["peer"]
    got = peer.ask(op="drive", vx=SPEED, sim_s=2.0)
    assert got["ok"], "the /cmd_vel publisher never matched simseam's subscription"
    rep = peer.ask(op="report")
    moving = [o for o in _moving(rep["odom"], SPEED) if got["sim0"] <= o[0]]
    assert len(moving) >= 50, f"{len(moving)} moving /odom samples: {got} {rep['odom'][-5:]}"
    a, b = moving[0], moving[-1]
    dt = (b[0] - a[0]) * 1e-9
    dist = math.hypot(b[1] - a[1], b[2] - a[2])
    print(f"/cmd_vel {SPEED} m/s: /odom moved {dist:.4f} m in {dt:.3f} s sim (expected {SPEED * dt:.4f})")
    assert dist == pytest.approx(SPEED * dt, abs=0.02)

    # E-stop: latched while /cmd_vel keeps coming; released by false
    assert peer.ask(op="estop", value=True)["ok"]
    got = peer.ask(op="drive", vx=SPEED, sim_s=1.5)
    rep = peer.ask(op="report")
    during = [o for o in rep["odom"] if got["sim0"] <= o[0] <= got["sim1"]]
    assert len(during) >= 50
    xs = [o[1] for o in during]
    assert max(xs) - min(xs) < 2 * SPEED * 0.02 + 1e-9  # at most one tick in flight, then held
    assert all(o[3] == 0.0 for o in during[2:]), "the base moved under E-stop"
    assert peer.ask(op="estop", value=False)["ok"]
    got = peer.ask(op="drive", vx=SPEED, sim_s=1.0)
    rep = peer.ask(op="report")
    after = [o for o in _moving(rep["odom"], SPEED) if o[0] >= got["sim0"]]
    assert len(after) >= 20 and after[-1][1] - after[0][1] > 0.1, "released E-stop: no motion"


def test_discovery_ros_node_started_late(live):
    """Peer B starts after simseam has run LATE_SIM_S of sim time; it must discover simseam within 5 s."""
    peer_a = live["peer"]
    assert peer_a.ask(op="wait_clock", sim_s=LATE_SIM_S, timeout=600)["ok"]
    t_spawn = time.monotonic()
    peer_b = live["ns"].start([live["python"], PEERS / "ros_peer.py", "", "", "peer_b"],
                              peer_env(live["python"]), "rclpy peer B")
    ready = peer_b.json()
    got = peer_b.ask(op="wait", topics=["/joint_states", "/odom", "/robot_description"], timeout=120)
    assert got["ok"]
    assert ready["event"] == "ready"
    delay = got["first"]["/joint_states"] - t_spawn  # from launching the ROS process (imports included)
    print(f"discovery (ROS node {LATE_SIM_S:g} s after simseam): first /joint_states {delay:.2f} s after its launch, "
          f"{got['first']['/joint_states'] - ready['t']:.2f} s after its node came up")
    assert delay < DISCOVERY_S
    g = peer_b.ask(op="graph", node="simseam", timeout=60)
    assert "/simseam" in g["nodes"]
    peer_b.ask(op="quit")
    # and simseam stops cleanly on Ctrl-C
    assert live["sim"].stop() == 0, live["sim"].output()
    assert "stopped:" in live["sim"].output()
