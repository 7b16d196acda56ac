"""A DDS reader of /tf and /tf_static (PyPI has no tf2_msgs for the rclpy peer): prints one JSON line
{child: [parent, static]} once every frame named on argv is reachable from ``odom`` (or at the deadline).
Samples are read with simseam's classes and re-decoded by rosbags' CDR deserializer."""

import json
import sys
import time

from rosbags.typesys import Stores, get_typestore

from simseam.ros2 import msgs as m
from simseam.ros2.dds import TF, TF_STATIC, Participant

want = set(sys.argv[1].split(","))
deadline = time.monotonic() + float(sys.argv[2])
store = get_typestore(Stores.ROS2_JAZZY)
p = Participant(node_name=None)
readers = {False: p.reader("/tf", m.TFMessage, TF), True: p.reader("/tf_static", m.TFMessage, TF_STATIC)}
edges: dict = {}


def reachable():
    out = {"odom"}
    changed = True
    while changed:
        changed = False
        for child, (parent, _) in edges.items():
            if parent in out and child not in out:
                out.add(child)
                changed = True
    return out


print(json.dumps({"event": "ready"}), flush=True)
while time.monotonic() < deadline and not want <= reachable():
    for static, r in readers.items():
        for s in r.take(N=100):
            if isinstance(s, m.TFMessage):
                msg = store.deserialize_cdr(s.serialize(), "tf2_msgs/msg/TFMessage")
                for t in msg.transforms:
                    edges[t.child_frame_id] = [t.header.frame_id, static]
    time.sleep(0.01)
print(json.dumps({"edges": edges, "reachable": sorted(reachable())}), flush=True)
p.close()
