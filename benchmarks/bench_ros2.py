"""ROS 2 bridge throughput: panda_mobile at full rates, real-time paced, with a live DDS subscriber.

Scene: panda_mobile in nav_obstacles at 50 Hz control, the manifest's sensor sizes (three 256x256
RGB cameras, a 160x120 depth camera, a 360-beam lidar). Rates: cameras + camera_info 10 Hz, depth
point cloud 10 Hz, /scan 10 Hz, /joint_states, /odom, /tf 50 Hz, /clock every tick. A second
process subscribes to every image, the scan and the joint states over DDS (loopback, private
domain) and counts what it receives, so the numbers include real delivery, not just writes.
``--record`` adds an MCAP recording. Prints a table; ``--json`` writes it.

    .venv/bin/python benchmarks/bench_ros2.py --duration 20
"""

from __future__ import annotations

import argparse
import json
import os
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
    ap.add_argument("--no-subscriber", action="store_true")
    ap.add_argument("--rtf", type=float, default=1.0, help="0: as fast as possible (shows the headroom)")
    ap.add_argument("--json", type=Path, default=None)
    args = ap.parse_args()

    from simseam.hal.sim_attached import SimAttachedHAL
    from simseam.ros2.bridge import DEFAULT_RATES, Ros2Bridge
    from simseam.ros2.dds import Participant, loopback_config
    from simseam.ros2.record import McapRecorder
    from simseam.runner.scene_config import (
        build_rollout,
        load_scene_config,
        resolve_robot,
    )

    os.environ["ROS_DOMAIN_ID"] = str(150 + os.getpid() % 50)
    os.environ["CYCLONEDDS_URI"] = loopback_config()
    tmp = Path(tempfile.mkdtemp(prefix="simseam_bench_ros2_"))
    (tmp / "scene.yaml").write_text(SCENE)
    cfg, base = load_scene_config(tmp / "scene.yaml")
    spec = resolve_robot(cfg, base)
    hal = SimAttachedHAL.attach(build_rollout(cfg, base), target="sim")
    sinks = [McapRecorder(tmp / "bench.mcap")] if args.record else []
    bridge = Ros2Bridge(hal, spec=spec, rtf=args.rtf, participant=Participant(), sinks=sinks)
    sub = None
    if not args.no_subscriber:
        sub = subprocess.Popen([sys.executable, "-c", SUBSCRIBER, str(args.duration + 8)], stdout=subprocess.PIPE,
                               text=True, env=dict(os.environ))
        assert sub.stdout.readline().strip() == "ready"
    bridge.start()
    time.sleep(1.0)  # discovery
    load0 = os.getloadavg()[0]
    stats = bridge.run(args.duration)
    received = None
    if sub is not None:
        out, _ = sub.communicate(timeout=args.duration + 30)
        received = eval(out.strip().splitlines()[-1], {})  # our own child's repr of a dict of ints
    bridge.close()
    hal.close()
    sim = stats.sim_s
    rows = [("control ticks", stats.ticks, f"{stats.ticks / sim:.1f} Hz sim"),
            ("sim seconds", f"{sim:.2f}", ""), ("wall seconds", f"{stats.wall_s:.2f}", ""),
            ("real-time factor", f"{stats.rtf:.3f}", f"paced at {args.rtf:g} (0: unpaced)"),
            ("slowest tick", f"{stats.step_ms_max:.1f} ms", "")]
    for topic in ("/joint_states", "/odom", "/clock", "/camera1/image_raw", "/camera2/image_raw",
                  "/front_rgb/image_raw", "/front_depth/points", "/scan"):
        n = stats.published.get(topic, 0)
        got = "" if received is None or topic not in received else f"received {received[topic]}"
        rows.append((f"published {topic}", n, f"{n / sim:.1f} Hz  {got}"))
    print(f"bench_ros2: panda_mobile, {os.cpu_count()} CPUs, MUJOCO_GL={os.environ['MUJOCO_GL']}, "
          f"rates {DEFAULT_RATES}, record={args.record}, loadavg before {load0:.2f}")
    for name, value, note in rows:
        print(f"  {name:32s} {value!s:>10s}  {note}")
    if args.json:
        args.json.write_text(json.dumps({"stats": stats.to_json(), "received": received,
                                         "cpu_count": os.cpu_count(), "record": args.record}, indent=2))


if __name__ == "__main__":
    main()
