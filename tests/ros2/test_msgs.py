"""Every message type's CDR bytes, cross-checked against rosbags' serializer (independent code)."""

import math

import numpy as np
import pytest

from simseam.robot.manifest import load_robot
from simseam.ros2 import convert as cv
from simseam.ros2 import msgs as m
from simseam.ros2.dds import CLOCK, COMMAND, Participant, discovery_config
from simseam.ros2.robot_model import RobotModel

import rosbags.typesys as rosbags_typesys  # noqa: E402  (a missing module fails, never skips)
STORE = rosbags_typesys.get_typestore(rosbags_typesys.Stores.ROS2_JAZZY)
from rosbags.typesys.base import Nodetype


def to_rosbags(msg, ros_type=None):
    """The same message as a rosbags dataclass, driven by rosbags' own field definitions (so a field
    name, order or kind that differs from ROS 2's fails here)."""
    ros_type = ros_type or m.ros_type_name(msg)
    _, fields = STORE.fielddefs[ros_type]
    assert list(type(msg).__dataclass_fields__) == [f[0] for f in fields], ros_type
    kwargs = {}
    for name, (node, detail) in fields:
        value = getattr(msg, name)
        if node == Nodetype.NAME:
            kwargs[name] = to_rosbags(value, detail)
        elif node == Nodetype.BASE:
            kwargs[name] = value
        else:
            (sub_node, sub_detail), _ = detail
            if sub_node == Nodetype.NAME:
                kwargs[name] = [to_rosbags(v, sub_detail) for v in value]
            elif sub_detail[0] == "string":
                kwargs[name] = list(value)
            elif sub_detail[0] == "char":
                kwargs[name] = np.array(value, dtype=np.uint8)
            else:
                kwargs[name] = np.array(bytearray(value) if isinstance(value, bytes) else value, dtype=sub_detail[0])
    return STORE.types[ros_type](**kwargs)


def samples():
    spec = load_robot("panda_mobile")
    stamp = 12_345_678_901
    lidar = spec.sensors_of("lidar_2d")[0]
    rng = np.random.default_rng(0)
    odom, tf = cv.odom_msgs([1.5, -0.25, 0.7], [0.3, -0.1, 0.2], stamp, height=0.36)
    jc = m.JointState(cv.header(stamp, ""), ["panda_joint1", "panda_finger_joint1"], [0.5, 0.02], [], [])
    model = RobotModel(spec)
    names = spec.joint_names
    q = np.linspace(-1, 1, len(names))
    ranges = rng.uniform(0.1, 9, 360).astype(np.float32)
    ranges[::7] = lidar.range_max  # no return: +inf on the wire (REP-117)
    # a participant that discovers nothing (ROS_AUTOMATIC_DISCOVERY_RANGE=OFF): only its graph sample is used
    participant = Participant(7, config=discovery_config({"ROS_AUTOMATIC_DISCOVERY_RANGE": "OFF"}))
    try:
        participant.writer("/clock", m.Clock, CLOCK)
        participant.reader("/cmd_vel", m.Twist, COMMAND)
        graph = participant.graph_info()
    finally:
        participant.close()
    return {
        "std_msgs/msg/String": model.description_msg(),
        "rmw_dds_common/msg/ParticipantEntitiesInfo": graph,
        "sensor_msgs/msg/JointState (URDF joints)": model.joint_state_msg(names, q, q * 0.5, stamp),
        "tf2_msgs/msg/TFMessage (links)": m.TFMessage(model.static_transforms(stamp)
                                                      + model.moving_transforms(names, q, stamp)),
        "rosgraph_msgs/msg/Clock": cv.clock_msg(stamp),
        "std_msgs/msg/Bool": m.Bool(True),
        "geometry_msgs/msg/Twist": m.Twist(m.Vector3(0.25, -0.5, 0.0), m.Vector3(0.0, 0.0, 1.25)),
        "sensor_msgs/msg/JointState": cv.joint_state_msg(spec.joint_names, np.linspace(-1, 1, 12),
                                                         np.linspace(0, 0.5, 12), stamp),
        "sensor_msgs/msg/JointState (command)": jc,
        "nav_msgs/msg/Odometry": odom,
        "tf2_msgs/msg/TFMessage": tf,
        "tf2_msgs/msg/TFMessage (static)": cv.static_transforms(spec, stamp),
        "sensor_msgs/msg/Image": cv.image_msg(rng.integers(0, 255, (6, 5, 3), dtype=np.uint8), stamp, "cam_optical"),
        "sensor_msgs/msg/CameraInfo": cv.camera_info_msg(640, 480, 58.0, stamp, "cam_optical"),
        "sensor_msgs/msg/PointCloud2": cv.pointcloud_msg(rng.normal(size=(7, 3)).astype(np.float32), stamp,
                                                         spec.base_link),
        "sensor_msgs/msg/LaserScan": cv.scan_msg(ranges, lidar, stamp, lidar.name, 0.1),
    }


SAMPLES = samples()


@pytest.mark.parametrize("label", list(SAMPLES))
def test_cdr_bytes_match_rosbags(label):
    msg = SAMPLES[label]
    ours = msg.serialize()
    ref = bytes(STORE.serialize_cdr(to_rosbags(msg), m.ros_type_name(msg)))
    assert ours[:4] == b"\x00\x01\x00\x00"  # CDR little-endian (XCDR1), as rmw_cyclonedds writes
    assert ours == ref
    # and rosbags reads our bytes back to the same values; Cyclone reads its own
    back = STORE.deserialize_cdr(ours, m.ros_type_name(msg))
    assert type(msg).deserialize(ours).serialize() == ours
    assert back.__msgtype__ == m.ros_type_name(msg)


def test_every_published_type_is_covered():
    published = {"rosgraph_msgs/msg/Clock", "std_msgs/msg/Bool", "geometry_msgs/msg/Twist",
                 "sensor_msgs/msg/JointState", "nav_msgs/msg/Odometry", "tf2_msgs/msg/TFMessage",
                 "sensor_msgs/msg/Image", "sensor_msgs/msg/CameraInfo", "sensor_msgs/msg/PointCloud2",
                 "sensor_msgs/msg/LaserScan"}
    published |= {"std_msgs/msg/String", "rmw_dds_common/msg/ParticipantEntitiesInfo"}
    assert published <= {label.split(" ")[0] for label in SAMPLES}
    assert set(m.ROS_TYPES) <= {label.split(" ")[0] for label in SAMPLES} | {
        "builtin_interfaces/msg/Time", "std_msgs/msg/Header", "geometry_msgs/msg/Vector3", "geometry_msgs/msg/Point",
        "geometry_msgs/msg/Quaternion", "geometry_msgs/msg/Pose", "geometry_msgs/msg/PoseWithCovariance",
        "geometry_msgs/msg/TwistWithCovariance", "geometry_msgs/msg/Transform", "geometry_msgs/msg/TransformStamped",
        "sensor_msgs/msg/RegionOfInterest", "sensor_msgs/msg/PointField", "rmw_dds_common/msg/Gid",
        "rmw_dds_common/msg/NodeEntitiesInfo"}  # nested in the samples above


def test_dds_type_names_follow_ros2():
    assert m.JointState.__idl_typename__ == "sensor_msgs::msg::dds_::JointState_"
    for name, cls in m.ROS_TYPES.items():
        pkg, _, typ = name.split("/")
        assert cls.__idl_typename__ == f"{pkg}::msg::dds_::{typ}_"


def test_values_survive_the_round_trip():
    msg = SAMPLES["nav_msgs/msg/Odometry"]
    back = STORE.deserialize_cdr(msg.serialize(), "nav_msgs/msg/Odometry")
    assert back.pose.pose.position.x == 1.5 and back.child_frame_id == "base_link"
    assert math.isclose(2 * math.atan2(back.pose.pose.orientation.z, back.pose.pose.orientation.w), 0.7)
    assert back.twist.twist.linear.x == 0.3 and back.header.stamp.sec == 12 and back.header.stamp.nanosec == 345_678_901
    img = SAMPLES["sensor_msgs/msg/Image"]
    assert m.Image.deserialize(img.serialize()).data == img.data
    # REP-117: the 52 beams at range_max are +inf on the wire, the others keep their range
    scan = STORE.deserialize_cdr(SAMPLES["sensor_msgs/msg/LaserScan"].serialize(), "sensor_msgs/msg/LaserScan")
    assert np.isposinf(scan.ranges[::7]).all() and len(scan.ranges[::7]) == 52
    assert np.isfinite(np.delete(scan.ranges, np.arange(0, 360, 7))).all() and scan.range_max == 10.0
    graph = STORE.deserialize_cdr(SAMPLES["rmw_dds_common/msg/ParticipantEntitiesInfo"].serialize(),
                                  "rmw_dds_common/msg/ParticipantEntitiesInfo")
    node = graph.node_entities_info_seq[0]
    assert (node.node_namespace, node.node_name) == ("/", "simseam")
    assert len(node.writer_gid_seq) == 1 and len(node.reader_gid_seq) == 1
    assert bytes(graph.gid.data)[:12] == bytes(node.writer_gid_seq[0].data)[:12]  # same GUID prefix


def test_joint_command_mapping():
    spec = load_robot("panda_mobile")
    jmap = cv.JointCommandMap.from_spec(spec)
    measured = {j.name: 0.1 for j in spec.joints}
    msg = m.JointState(cv.header(0, ""), ["panda_joint2", "panda_finger_joint1", "bogus"], [0.5, 0.0, 1.0], [], [])
    arm, grip, unknown = jmap.split(msg, measured)
    assert arm.tolist() == [0.1, 0.5, 0.1, 0.1, 0.1, 0.1, 0.1] and grip == 1.0 and unknown == ["bogus"]
    arm, grip, _ = jmap.split(m.JointState(position=[0.0] * 7), measured)  # no names: arm order
    assert arm.tolist() == [0.0] * 7 and grip is None
