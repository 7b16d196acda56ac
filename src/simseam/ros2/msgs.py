"""ROS 2 message types as Cyclone DDS IDL structs (no ROS installation needed).

Each class mirrors the ROS 2 IDL of its message field for field, with the DDS
type name ROS 2's rmw layer uses (``<pkg>::msg::dds_::<Type>_``), so a sample
written here is the same XCDR1 (plain CDR, little-endian) byte stream an
rclcpp/rclpy node writes and reads. ``tests/ros2/test_msgs.py`` checks every
type byte for byte against rosbags' CDR serializer (an independent
implementation of the same ROS message definitions).

Fixed-size arrays (``double[9]``) are ``types.array[float64, 9]``; unbounded
arrays are ``types.sequence[...]``. ``uint8[]`` payloads (image and point
cloud data) are declared ``sequence[uint8]`` (so the XTypes type object
matches ROS 2's) and take ``bytes``: ``_fast_octets`` swaps in a machine that
writes a bytes value with one memory copy (Cyclone's default packs it one
element at a time: ~6 ms for a 256x256 RGB image) and reads it back as bytes.

Only ``cyclonedds.idl`` (pure Python) is needed to build and serialize these;
a DDS participant is not (MCAP recording and Foxglove reuse them).
"""



from dataclasses import dataclass, field

from cyclonedds.idl import IdlStruct
from cyclonedds.idl import types as t
from cyclonedds.idl._machinery import KeyEnabled, PlainCdrV2SequenceOfPrimitiveMachine
from cyclonedds.idl._support import DeserializeKind, SerializeKind


def _cov() -> list[float]:
    return [0.0] * 36


# ----------------------------------------------------------- builtin / std / graph
@dataclass
class Time(IdlStruct, typename="builtin_interfaces::msg::dds_::Time_"):
    sec: t.int32 = 0
    nanosec: t.uint32 = 0

    @classmethod
    def from_ns(cls, ns: int) -> "Time":
        sec, nsec = divmod(int(ns), 1_000_000_000)
        return cls(sec, nsec)

    def to_ns(self) -> int:
        return self.sec * 1_000_000_000 + self.nanosec


@dataclass
class Header(IdlStruct, typename="std_msgs::msg::dds_::Header_"):
    stamp: Time = field(default_factory=Time)
    frame_id: str = ""


@dataclass
class Bool(IdlStruct, typename="std_msgs::msg::dds_::Bool_"):
    data: bool = False


@dataclass
class String(IdlStruct, typename="std_msgs::msg::dds_::String_"):
    data: str = ""


@dataclass
class Clock(IdlStruct, typename="rosgraph_msgs::msg::dds_::Clock_"):
    clock: Time = field(default_factory=Time)


# ------------------------------------------------------------------- geometry_msgs
@dataclass
class Vector3(IdlStruct, typename="geometry_msgs::msg::dds_::Vector3_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Point(IdlStruct, typename="geometry_msgs::msg::dds_::Point_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0


@dataclass
class Quaternion(IdlStruct, typename="geometry_msgs::msg::dds_::Quaternion_"):
    x: t.float64 = 0.0
    y: t.float64 = 0.0
    z: t.float64 = 0.0
    w: t.float64 = 1.0


@dataclass
class Pose(IdlStruct, typename="geometry_msgs::msg::dds_::Pose_"):
    position: Point = field(default_factory=Point)
    orientation: Quaternion = field(default_factory=Quaternion)


@dataclass
class PoseWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::PoseWithCovariance_"):
    pose: Pose = field(default_factory=Pose)
    covariance: t.array[t.float64, 36] = field(default_factory=_cov)


@dataclass
class Twist(IdlStruct, typename="geometry_msgs::msg::dds_::Twist_"):
    linear: Vector3 = field(default_factory=Vector3)
    angular: Vector3 = field(default_factory=Vector3)


@dataclass
class TwistWithCovariance(IdlStruct, typename="geometry_msgs::msg::dds_::TwistWithCovariance_"):
    twist: Twist = field(default_factory=Twist)
    covariance: t.array[t.float64, 36] = field(default_factory=_cov)


@dataclass
class Transform(IdlStruct, typename="geometry_msgs::msg::dds_::Transform_"):
    translation: Vector3 = field(default_factory=Vector3)
    rotation: Quaternion = field(default_factory=Quaternion)


@dataclass
class TransformStamped(IdlStruct, typename="geometry_msgs::msg::dds_::TransformStamped_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    transform: Transform = field(default_factory=Transform)


@dataclass
class TFMessage(IdlStruct, typename="tf2_msgs::msg::dds_::TFMessage_"):
    transforms: t.sequence[TransformStamped] = field(default_factory=list)


# ------------------------------------------------------------------------ nav_msgs
@dataclass
class Odometry(IdlStruct, typename="nav_msgs::msg::dds_::Odometry_"):
    header: Header = field(default_factory=Header)
    child_frame_id: str = ""
    pose: PoseWithCovariance = field(default_factory=PoseWithCovariance)
    twist: TwistWithCovariance = field(default_factory=TwistWithCovariance)


# --------------------------------------------------------------------- sensor_msgs
@dataclass
class JointState(IdlStruct, typename="sensor_msgs::msg::dds_::JointState_"):
    header: Header = field(default_factory=Header)
    name: t.sequence[str] = field(default_factory=list)
    position: t.sequence[t.float64] = field(default_factory=list)
    velocity: t.sequence[t.float64] = field(default_factory=list)
    effort: t.sequence[t.float64] = field(default_factory=list)


@dataclass
class Image(IdlStruct, typename="sensor_msgs::msg::dds_::Image_"):
    header: Header = field(default_factory=Header)
    height: t.uint32 = 0
    width: t.uint32 = 0
    encoding: str = ""
    is_bigendian: t.uint8 = 0
    step: t.uint32 = 0
    data: t.sequence[t.uint8] = b""


@dataclass
class RegionOfInterest(IdlStruct, typename="sensor_msgs::msg::dds_::RegionOfInterest_"):
    x_offset: t.uint32 = 0
    y_offset: t.uint32 = 0
    height: t.uint32 = 0
    width: t.uint32 = 0
    do_rectify: bool = False


@dataclass
class CameraInfo(IdlStruct, typename="sensor_msgs::msg::dds_::CameraInfo_"):
    header: Header = field(default_factory=Header)
    height: t.uint32 = 0
    width: t.uint32 = 0
    distortion_model: str = ""
    d: t.sequence[t.float64] = field(default_factory=list)
    k: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    r: t.array[t.float64, 9] = field(default_factory=lambda: [0.0] * 9)
    p: t.array[t.float64, 12] = field(default_factory=lambda: [0.0] * 12)
    binning_x: t.uint32 = 0
    binning_y: t.uint32 = 0
    roi: RegionOfInterest = field(default_factory=RegionOfInterest)


@dataclass
class PointField(IdlStruct, typename="sensor_msgs::msg::dds_::PointField_"):
    name: str = ""
    offset: t.uint32 = 0
    datatype: t.uint8 = 0
    count: t.uint32 = 0


@dataclass
class PointCloud2(IdlStruct, typename="sensor_msgs::msg::dds_::PointCloud2_"):
    header: Header = field(default_factory=Header)
    height: t.uint32 = 0
    width: t.uint32 = 0
    fields: t.sequence[PointField] = field(default_factory=list)
    is_bigendian: bool = False
    point_step: t.uint32 = 0
    row_step: t.uint32 = 0
    data: t.sequence[t.uint8] = b""
    is_dense: bool = False


@dataclass
class LaserScan(IdlStruct, typename="sensor_msgs::msg::dds_::LaserScan_"):
    header: Header = field(default_factory=Header)
    angle_min: t.float32 = 0.0
    angle_max: t.float32 = 0.0
    angle_increment: t.float32 = 0.0
    time_increment: t.float32 = 0.0
    scan_time: t.float32 = 0.0
    range_min: t.float32 = 0.0
    range_max: t.float32 = 0.0
    ranges: t.sequence[t.float32] = field(default_factory=list)
    intensities: t.sequence[t.float32] = field(default_factory=list)


# ---------------------------------------------------------------- rmw_dds_common
# The ROS graph information every rmw implementation exchanges on the DDS topic
# ``ros_discovery_info``: which nodes a participant hosts and which readers and
# writers (by DDS GUID) belong to each node. Jazzy's Gid is 16 bytes.
@dataclass
class Gid(IdlStruct, typename="rmw_dds_common::msg::dds_::Gid_"):
    data: t.array[t.uint8, 16] = field(default_factory=lambda: [0] * 16)


@dataclass
class NodeEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::NodeEntitiesInfo_"):
    node_namespace: str = ""
    node_name: str = ""
    reader_gid_seq: t.sequence[Gid] = field(default_factory=list)
    writer_gid_seq: t.sequence[Gid] = field(default_factory=list)


@dataclass
class ParticipantEntitiesInfo(IdlStruct, typename="rmw_dds_common::msg::dds_::ParticipantEntitiesInfo_"):
    gid: Gid = field(default_factory=Gid)
    node_entities_info_seq: t.sequence[NodeEntitiesInfo] = field(default_factory=list)


class _OctetSequenceMachine(PlainCdrV2SequenceOfPrimitiveMachine):
    """``sequence<uint8>`` from/to ``bytes`` in one copy (same wire bytes as the default machine)."""

    def __init__(self, max_length=None):
        super().__init__(t.uint8, max_length)

    def serialize(self, buffer, value, serialize_kind=SerializeKind.DataSample, key_enabled=KeyEnabled.InKeylist):
        buffer.align(4)
        buffer.write("I", 4, len(value))
        if len(value):
            buffer.write_bytes(bytes(value))

    def deserialize(self, buffer, deserialize_kind=DeserializeKind.DataSample, key_enabled=KeyEnabled.InKeylist):
        buffer.align(4)
        n = buffer.read("I", 4)
        return buffer.read_bytes(n) if n else b""


def _fast_octets(cls: type, member: str) -> None:
    cls.__idl__.populate()
    for machine in (cls.__idl__.v1_machine, cls.__idl__.v2_machine):
        members = getattr(machine, "members_machines", None)
        if members is not None and member in members:
            members[member] = _OctetSequenceMachine()


_fast_octets(Image, "data")
_fast_octets(PointCloud2, "data")

#: Every message class this package publishes or subscribes, by ROS type name.
ROS_TYPES: dict[str, type] = {
    "builtin_interfaces/msg/Time": Time,
    "std_msgs/msg/Header": Header,
    "std_msgs/msg/Bool": Bool,
    "std_msgs/msg/String": String,
    "rosgraph_msgs/msg/Clock": Clock,
    "geometry_msgs/msg/Vector3": Vector3,
    "geometry_msgs/msg/Point": Point,
    "geometry_msgs/msg/Quaternion": Quaternion,
    "geometry_msgs/msg/Pose": Pose,
    "geometry_msgs/msg/PoseWithCovariance": PoseWithCovariance,
    "geometry_msgs/msg/Twist": Twist,
    "geometry_msgs/msg/TwistWithCovariance": TwistWithCovariance,
    "geometry_msgs/msg/Transform": Transform,
    "geometry_msgs/msg/TransformStamped": TransformStamped,
    "tf2_msgs/msg/TFMessage": TFMessage,
    "nav_msgs/msg/Odometry": Odometry,
    "sensor_msgs/msg/JointState": JointState,
    "sensor_msgs/msg/Image": Image,
    "sensor_msgs/msg/RegionOfInterest": RegionOfInterest,
    "sensor_msgs/msg/CameraInfo": CameraInfo,
    "sensor_msgs/msg/PointField": PointField,
    "sensor_msgs/msg/PointCloud2": PointCloud2,
    "sensor_msgs/msg/LaserScan": LaserScan,
    "rmw_dds_common/msg/Gid": Gid,
    "rmw_dds_common/msg/NodeEntitiesInfo": NodeEntitiesInfo,
    "rmw_dds_common/msg/ParticipantEntitiesInfo": ParticipantEntitiesInfo,
}
_NAME_OF = {cls: name for name, cls in ROS_TYPES.items()}


def ros_type_name(msg_or_cls) -> str:
    """``sensor_msgs/msg/Image`` for ``Image`` or an instance of it."""
    cls = msg_or_cls if isinstance(msg_or_cls, type) else type(msg_or_cls)
    return _NAME_OF[cls]


_MSGDEFS: dict[str, str] = {}


def ros2msg_schema(ros_type: str) -> str:
    """The ``ros2msg`` schema text of a type (the .msg file plus its dependencies, separated
    the way rosbag2's MCAP storage writes them), from rosbags' bundled ROS 2 definitions."""
    if ros_type not in _MSGDEFS:
        from rosbags.typesys import Stores, get_typestore

        store = get_typestore(Stores.ROS2_JAZZY)
        _MSGDEFS[ros_type] = store.generate_msgdef(ros_type, ros_version=2)[0]
    return _MSGDEFS[ros_type]
