"""ROS 2 bridge throughput: panda_mobile at full rates, real-time paced, with a live DDS subscriber.

Scene: panda_mobile in nav_obstacles at 50 Hz control, the manifest's sensor sizes (three 256x256
RGB cameras, a 160x120 depth camera, a 360-beam lidar). Rates: cameras + camera_info 10 Hz, depth
point cloud 10 Hz, /scan 10 Hz, /joint_states, /odom, /tf 50 Hz, /clock every tick.

``--peer rclpy`` (default): the benchmark re-runs itself in a private network namespace with only
loopback (``unshare -n``, root) and starts a real ROS 2 Jazzy node (rclpy + Fast DDS, from
scripts/setup_ros_peers.sh) subscribed to every topic with the standard QoS; both sides on their
defaults (domain 0, no CYCLONEDDS_URI). The receive fraction of a topic is the share of the
messages simseam published (by stamp) that the peer received, over the steady window: from 1 s of
sim time after the peer has seen every topic to 0.5 s before the end. ``--peer cyclone``: the old
in-package DDS subscriber (counts only); ``--peer none``. ``--record`` adds an MCAP recording.
Prints a table; ``--json`` writes it.

    .venv/bin/python benchmarks/bench_ros2.py --duration 20 --json benchmarks/results/ros2.json
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

SCENE = """\
robot: panda_mobile
layout: nav_obstacles
control_hz: 50
control_mode: joint_position
max_steps: 1000000
"""

SUBSCRIBER = r"""
import sys, time
from simseam.ros2 import msgs as m
from simseam.ros2.dds import Participant, SENSOR, STATE
p = Participant()
readers = {t: p.reader(t, c, k) for t, c, k in [
    ("/camera1/image_raw", m.Image, SENSOR), ("/camera2/image_raw", m.Image, SENSOR),
    ("/front_rgb/image_raw", m.Image, SENSOR), ("/front_depth/points", m.PointCloud2, SENSOR),
    ("/scan", m.LaserScan, SENSOR), ("/joint_states", m.JointState, STATE)]}
counts = dict.fromkeys(readers, 0)
print("ready", flush=True)
end = time.monotonic() + float(sys.argv[1])
while time.monotonic() < end:
    for t, r in readers.items():
        counts[t] += sum(1 for s in r.take(N=100) if not type(s).__name__.startswith("Invalid"))
    time.sleep(0.01)
print(repr(counts), flush=True)
"""


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--duration", type=float, default=20.0, help="sim seconds")
    ap.add_argument("--record", action="store_true", help="also record MCAP")
    ap.add_argument("--peer", choices=("rclpy", "cyclone", "none"), default="rclpy")
    ap.add_argument("--no-subscriber", action="store_true", help="same as --peer none")
    ap.add_argument("--rtf", type=float, default=1.0, help="0: as fast as possible (shows the headroom)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()
    if args.no_subscriber:
        args.peer = "none"
    if args.peer == "rclpy" and not os.environ.get("SIMSEAM_BENCH_IN_NETNS"):
        # re-run inside a private network namespace with only loopback (both sides on their defaults)
        if shutil.which("unshare") is None:
            sys.exit("--peer rclpy needs unshare (util-linux) and root")
        inner = f"ip link set lo up && exec {sys.executable} {' '.join(map(str, sys.argv))}"
        env = dict(os.environ, SIMSEAM_BENCH_IN_NETNS="1")
        env = {k: v for k, v in env.items() if not k.startswith(("ROS_", "CYCLONEDDS"))}
        sys.exit(subprocess.call(["unshare", "-n", "sh", "-c", inner], env=env))

    from simseam.hal.sim_attached import SimAttachedHAL
    from simseam.ros2.bridge import DEFAULT_RATES, Ros2Bridge
    from simseam.ros2.dds import Participant, loopback_config
    from simseam.ros2.record import McapRecorder
    from simseam.runner.scene_config import (
        build_rollout,
        load_scene_config,
        resolve_robot,
    )

    if args.peer != "rclpy":  # outside a namespace: a private domain, loopback only
        os.environ["ROS_DOMAIN_ID"] = str(150 + os.getpid() % 50)
        os.environ["CYCLONEDDS_URI"] = loopback_config()
    tmp = Path(tempfile.mkdtemp(prefix="simseam_bench_ros2_"))
    (tmp / "scene.yaml").write_text(SCENE)
    cfg, base = load_scene_config(tmp / "scene.yaml")
    spec = resolve_robot(cfg, base)
    hal = SimAttachedHAL.attach(build_rollout(cfg, base), target="sim")
    sinks = [McapRecorder(tmp / "bench.mcap")] if args.record else []
    bridge = Ros2Bridge(hal, rtf=args.rtf, participant=Participant(), sinks=sinks)
    published_stamps: dict[str, list[int]] = {}
    emit = bridge._emit

    def counting_emit(topic, msg, stamp_ns, qos_kind):  # what simseam published, by stamp
        published_stamps.setdefault(topic, []).append(int(stamp_ns))
        emit(topic, msg, stamp_ns, qos_kind)

    bridge._emit = counting_emit
    sub = peer = None
    cams = [s.name for s in spec.sensors_of("rgb")]
    depths = [s.name for s in spec.sensors_of("depth")]
    if args.peer == "cyclone":
        sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, str(args.duration + 8)], stdout=subprocess.PIPE,
                               text=True, env=dict(os.environ))
        assert sub.stdout.readline().strip() == "ready"
    elif args.peer == "rclpy":
        sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "ros2" / "peers"))
        from harness import PEERS, Proc, peer_env, pinned_dir

        ros_py = pinned_dir("ros-jazzy", "ros-peer-pins.txt") / "bin" / "python"
        if not ros_py.exists():
            sys.exit(f"no ROS 2 peer at {ros_py}: run bash scripts/setup_ros_peers.sh")
        peer = Proc([ros_py, PEERS / "ros_peer.py", ",".join(cams), ",".join(depths), "bench_peer"],
                    peer_env(ros_py), "rclpy peer")
        assert peer.json()["event"] == "ready"
    bridge.start()
    if sub is not None:
        time.sleep(1.0)  # discovery (the in-package subscriber has no readiness report)
    load0 = os.getloadavg()[0]
    stats = bridge.run(args.duration)
    received = fractions = None
    if sub is not None:
        out, _ = sub.communicate(timeout=args.duration + 30)
        received = eval(out.strip().splitlines()[-1], {})  # our own child's repr of a dict of ints
    if peer is not None:
        rep = peer.ask(op="report")
        peer.ask(op="quit")
        peer.stop()
        t_end = hal.sim_time_ns()
        got_stamps = rep["stamps"]
        # the steady window starts 1 s of sim time after every periodic topic has reached the peer
        periodic = [t for t in got_stamps if t != "/robot_description" and got_stamps[t]]
        t0 = max(min(got_stamps[t]) for t in periodic) + 1_000_000_000
        t1 = t_end - 500_000_000
        received, fractions = {}, {}
        for topic, stamps_out in published_stamps.items():
            if topic in ("/tf", "/tf_static") or topic not in got_stamps:
                continue
            sent = {s for s in stamps_out if t0 <= s <= t1}
            got = {s for s in got_stamps[topic] if t0 <= s <= t1}
            received[topic] = len(got & sent)
            fractions[topic] = (len(got & sent), len(sent))
    bridge.close()
    hal.close()
    sim = stats.sim_s
    rows = [("control ticks", stats.ticks, f"{stats.ticks / sim:.1f} Hz sim"),
            ("sim seconds", f"{sim:.2f}", ""), ("wall seconds", f"{stats.wall_s:.2f}", ""),
            ("real-time factor", f"{stats.rtf:.3f}", f"paced at {args.rtf:g} (0: unpaced)"),
            ("slowest tick", f"{stats.step_ms_max:.1f} ms", "")]
    topics = ["/joint_states", "/odom", "/tf", "/clock", "/scan", "/robot_description", "/tf_static",
              *[f"/{c}/{k}" for c in cams for k in ("image_raw", "camera_info")], *[f"/{d}/points" for d in depths]]
    for topic in topics:
        n = stats.published.get(topic, 0)
        got = ""
        if fractions is not None and topic in fractions:
            k, of = fractions[topic]
            got = f"rclpy received {k}/{of} = {k / of:.3f}" if of else ""
        elif received is not None and topic in received:
            got = f"received {received[topic]}"
        rows.append((f"published {topic}", n, f"{n / sim:.1f} Hz  {got}"))
    print(f"bench_ros2: panda_mobile, {os.cpu_count()} CPUs, MUJOCO_GL={os.environ['MUJOCO_GL']}, peer {args.peer}, "
          f"rates {DEFAULT_RATES}, record={args.record}, loadavg before {load0:.2f}")
    for name, value, note in rows:
        print(f"  {name:40s} {value!s:>10s}  {note}")
    if args.json:
        args.json.parent.mkdir(parents=True, exist_ok=True)
        args.json.write_text(json.dumps({"stats": stats.to_json(), "received": received, "peer": args.peer,
                                         "receive_fraction": None if fractions is None else
                                         {t: {"received": k, "published": of, "fraction": k / of if of else None}
                                          for t, (k, of) in fractions.items()},
                                         "cpu_count": os.cpu_count(), "record": args.record}, indent=2))


if __name__ == "__main__":
    main()
