"""A real ROS 2 Jazzy node (rclpy, Fast DDS) that talks to ``simseam deploy --ros2``.

Runs in the ROS venv (scripts/setup_ros_peers.sh), never imports simseam. Subscribes to every
topic simseam publishes (tf2_msgs is not on PyPI: /tf and /tf_static are checked by a DDS probe),
and answers JSON-line requests on stdin with JSON lines on stdout:

    {"op": "wait", "topics": [...], "timeout": s}      until each topic has a message
    {"op": "graph", "node": "simseam", "timeout": s}    until that node shows its topics in the graph
    {"op": "wait_clock", "sim_s": t, "timeout": s}      until /clock reaches t (sim seconds)
    {"op": "drive", "vx": v, "wz": w, "sim_s": d}       publish /cmd_vel (~20 Hz) for d sim seconds
    {"op": "estop", "value": bool}                      publish /estop once (reliable), once matched
    {"op": "report"}                                    what arrived (see ``report``)
    {"op": "quit"}

Times are ``time.monotonic()`` (system-wide), stamps sim-time nanoseconds.
"""

import json
import sys
import threading
import time

import rclpy
from geometry_msgs.msg import Twist
from nav_msgs.msg import Odometry
from rclpy.executors import SingleThreadedExecutor
from rclpy.qos import DurabilityPolicy, QoSProfile, ReliabilityPolicy, qos_profile_sensor_data
from rosgraph_msgs.msg import Clock
from sensor_msgs.msg import CameraInfo, Image, JointState, LaserScan, PointCloud2
from std_msgs.msg import Bool, String

CAMERAS = sys.argv[1].split(",") if len(sys.argv) > 1 and sys.argv[1] else []
DEPTHS = sys.argv[2].split(",") if len(sys.argv) > 2 and sys.argv[2] else []
NODE = sys.argv[3] if len(sys.argv) > 3 else "simseam_test_peer"

RELIABLE10 = QoSProfile(depth=10, reliability=ReliabilityPolicy.RELIABLE)
LATCHED = QoSProfile(depth=1, reliability=ReliabilityPolicy.RELIABLE, durability=DurabilityPolicy.TRANSIENT_LOCAL)

lock = threading.Lock()
first: dict = {}
stamps: dict = {}
last: dict = {}
odom: list = []
clock: list = []


def ns(t) -> int:
    return t.sec * 1_000_000_000 + t.nanosec


def on(topic):
    def cb(msg):
        now = time.monotonic()
        stamp = ns(msg.clock) if topic == "/clock" else ns(msg.header.stamp) if hasattr(msg, "header") else 0
        with lock:
            first.setdefault(topic, now)
            stamps.setdefault(topic, []).append(stamp)
            last[topic] = msg
            if topic == "/odom":
                p, v = msg.pose.pose.position, msg.twist.twist
                odom.append([stamp, p.x, p.y, v.linear.x, v.angular.z, msg.header.frame_id, msg.child_frame_id])
            elif topic == "/clock":
                clock.append(stamp)
    return cb


rclpy.init()
node = rclpy.create_node(NODE)
subs = [(t, JointState, RELIABLE10) for t in ["/joint_states"]] + [
    ("/odom", Odometry, RELIABLE10), ("/clock", Clock, qos_profile_sensor_data),
    ("/scan", LaserScan, qos_profile_sensor_data), ("/robot_description", String, LATCHED)]
for cam in CAMERAS:
    subs += [(f"/{cam}/image_raw", Image, qos_profile_sensor_data), (f"/{cam}/camera_info", CameraInfo,
                                                                      qos_profile_sensor_data)]
for d in DEPTHS:
    subs.append((f"/{d}/points", PointCloud2, qos_profile_sensor_data))
for topic, cls, qos in subs:
    node.create_subscription(cls, topic, on(topic), qos)
cmd_pub = node.create_publisher(Twist, "/cmd_vel", RELIABLE10)
estop_pub = node.create_publisher(Bool, "/estop", RELIABLE10)
executor = SingleThreadedExecutor()
executor.add_node(node)
spinner = threading.Thread(target=executor.spin, daemon=True)
spinner.start()


def reply(**kw):
    sys.stdout.write(json.dumps(kw) + "\n")
    sys.stdout.flush()


def wait_for(pred, timeout):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        with lock:
            if pred():
                return True
        time.sleep(0.01)
    return False


def sim_now():
    return clock[-1] if clock else (odom[-1][0] if odom else None)


def wait_matched(pub, timeout=30.0):
    end = time.monotonic() + timeout
    while pub.get_subscription_count() == 0 and time.monotonic() < end:
        time.sleep(0.01)
    return pub.get_subscription_count() > 0


def graph(name, timeout):
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        nodes = node.get_node_names_and_namespaces()
        if (name, "/") in nodes:
            pubs = dict(node.get_publisher_names_and_types_by_node(name, "/"))
            subs_ = dict(node.get_subscriber_names_and_types_by_node(name, "/"))
            if "/joint_states" in pubs and "/cmd_vel" in subs_:
                return {"nodes": [f"{n_[1].rstrip('/')}/{n_[0]}" for n_ in nodes], "publishers": pubs,
                        "subscribers": subs_, "topics": dict(node.get_topic_names_and_types())}
        time.sleep(0.05)
    return {"nodes": [f"{n_[1].rstrip('/')}/{n_[0]}" for n_ in node.get_node_names_and_namespaces()],
            "topics": dict(node.get_topic_names_and_types()), "publishers": {}, "subscribers": {}}


def report():
    with lock:
        out = {"first": dict(first), "stamps": {k: list(v) for k, v in stamps.items()}, "odom": list(odom),
               "clock": list(clock)}
        js = last.get("/joint_states")
        if js is not None:
            out["joint_states"] = {"name": list(js.name), "position": list(js.position),
                                   "velocity": list(js.velocity)}
        scan = last.get("/scan")
        if scan is not None:
            out["scan"] = {"frame": scan.header.frame_id, "ranges": [r if r == r else None for r in scan.ranges],
                           "range_min": scan.range_min, "range_max": scan.range_max,
                           "angle_min": scan.angle_min, "angle_increment": scan.angle_increment}
        rd = last.get("/robot_description")
        if rd is not None:
            out["robot_description"] = rd.data
        for cam in CAMERAS:
            img, info = last.get(f"/{cam}/image_raw"), last.get(f"/{cam}/camera_info")
            if img is not None:
                out[f"/{cam}/image_raw"] = {"frame": img.header.frame_id, "height": img.height, "width": img.width,
                                            "encoding": img.encoding, "step": img.step, "bytes": len(img.data),
                                            "mean": sum(bytes(img.data)) / max(len(img.data), 1)}
            if info is not None:
                out[f"/{cam}/camera_info"] = {"frame": info.header.frame_id, "height": info.height,
                                              "width": info.width, "k": list(info.k), "p": list(info.p),
                                              "model": info.distortion_model}
        for d in DEPTHS:
            pc = last.get(f"/{d}/points")
            if pc is not None:
                out[f"/{d}/points"] = {"frame": pc.header.frame_id, "width": pc.width, "height": pc.height,
                                       "point_step": pc.point_step, "bytes": len(pc.data),
                                       "fields": [[f.name, f.offset, f.datatype, f.count] for f in pc.fields]}
    return out


reply(event="ready", t=time.monotonic(), node=NODE)
for line in sys.stdin:
    req = json.loads(line)
    op = req["op"]
    timeout = float(req.get("timeout", 60.0))
    if op == "wait":
        ok = wait_for(lambda: all(t in first for t in req["topics"]), timeout)
        with lock:
            reply(ok=ok, first={t: first.get(t) for t in req["topics"]}, t=time.monotonic())
    elif op == "graph":
        reply(**graph(req.get("node", "simseam"), timeout))
    elif op == "wait_clock":
        ok = wait_for(lambda: sim_now() is not None and sim_now() >= req["sim_s"] * 1e9, timeout)
        reply(ok=ok, sim_ns=sim_now())
    elif op == "drive":
        matched = wait_matched(cmd_pub) and wait_for(lambda: sim_now() is not None, timeout)
        with lock:
            t0 = sim_now()
        msg = Twist()
        msg.linear.x, msg.angular.z = float(req.get("vx", 0.0)), float(req.get("wz", 0.0))
        end = time.monotonic() + timeout
        sent = 0
        while time.monotonic() < end:
            cmd_pub.publish(msg)
            sent += 1
            with lock:
                if sim_now() >= t0 + req["sim_s"] * 1e9:
                    break
            time.sleep(0.05)
        with lock:
            reply(ok=matched, sim0=t0, sim1=sim_now(), sent=sent)
    elif op == "estop":
        matched = wait_matched(estop_pub)
        estop_pub.publish(Bool(data=bool(req["value"])))
        with lock:
            reply(ok=matched, sim_ns=sim_now())
    elif op == "report":
        reply(**report())
    elif op == "quit":
        reply(ok=True)
        break
executor.shutdown()
node.destroy_node()
rclpy.shutdown()
