"""HAL readings -> ROS 2 messages, and ROS 2 commands -> HAL actions (no DDS here).

Frames (REP-105 / REP-103):

- ``odom`` -> ``base_link`` (REP-105): the kinematic base pose, with z = the
  base height, published on ``/tf`` and ``/odom`` (twist in the base frame, as
  nav_msgs/Odometry specifies). ``base_link`` coincides with the URDF's root
  link (``robot_model``: an identity ``base_link -> <root>`` on ``/tf_static``
  when the root has another name).
- ``<sensor.parent>`` -> ``<sensor.name>``: each sensor mount (REP-103: +x
  forward) on ``/tf_static``; cameras add ``<sensor.name>_optical`` (z forward,
  x right, y down), the frame their Image/CameraInfo are stamped in.
- Every URDF link: ``robot_model`` (what robot_state_publisher computes from
  ``/robot_description`` and ``/joint_states``; simseam publishes it itself).
- Depth point clouds are in the manifest's ``base_link`` (what the HAL reports). The scan is
  stamped in ``<sensor.name>`` when the lidar is mounted on ``base_link`` with
  no roll/pitch (its origin is the mount, beam 0 at -pi about base_link's z);
  otherwise in ``base_link``.

Ranges follow REP-117: a beam with no return within ``range_max`` is ``+inf``
in the LaserScan (the simulator's scan reports such a beam as ``range_max``;
the conversion happens here).

All stamps are sim time (nodes run with ``use_sim_time:=true`` on ``/clock``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simseam.math3d import rpy_to_quat
from simseam.ros2 import msgs as m

# camera mount (REP-103, x forward) -> optical frame (z forward, x right, y down)
_OPTICAL_RPY = (-math.pi / 2, 0.0, -math.pi / 2)


def quat_msg(wxyz) -> m.Quaternion:
    w, x, y, z = (float(v) for v in wxyz)
    return m.Quaternion(x, y, z, w)


def header(stamp_ns: int, frame_id: str) -> m.Header:
    return m.Header(m.Time.from_ns(stamp_ns), frame_id)


def clock_msg(stamp_ns: int) -> m.Clock:
    return m.Clock(m.Time.from_ns(stamp_ns))


def joint_state_msg(names, positions, velocities, stamp_ns: int) -> m.JointState:
    return m.JointState(header(stamp_ns, ""), list(names), [float(v) for v in positions],
                        [float(v) for v in velocities], [])


def odom_msgs(pose, twist, stamp_ns: int, base_link: str = "base_link", height: float = 0.0,
              odom_frame: str = "odom") -> tuple[m.Odometry, m.TFMessage]:
    """``/odom`` and the ``/tf`` odom -> base_link for a base at ``pose`` [x, y, yaw] moving at
    ``twist`` [vx, vy, wz] (base frame)."""
    x, y, yaw = (float(v) for v in pose)
    q = m.Quaternion(0.0, 0.0, math.sin(yaw / 2), math.cos(yaw / 2))
    vx, vy, wz = (float(v) for v in (twist if twist is not None else (0.0, 0.0, 0.0)))
    hdr = header(stamp_ns, odom_frame)
    odom = m.Odometry(hdr, base_link,
                      m.PoseWithCovariance(m.Pose(m.Point(x, y, float(height)), q)),
                      m.TwistWithCovariance(m.Twist(m.Vector3(vx, vy, 0.0), m.Vector3(0.0, 0.0, wz))))
    tf = m.TFMessage([m.TransformStamped(header(stamp_ns, odom_frame), base_link,
                                         m.Transform(m.Vector3(x, y, float(height)), q))])
    return odom, tf


def _tf(stamp_ns: int, parent: str, child: str, xyz, wxyz) -> m.TransformStamped:
    return m.TransformStamped(header(stamp_ns, parent), child,
                              m.Transform(m.Vector3(*(float(v) for v in xyz)), quat_msg(wxyz)))


def static_transforms(spec, stamp_ns: int = 0) -> m.TFMessage:
    """Every sensor mount (and camera optical frame) as one ``/tf_static`` message."""
    out = []
    for s in spec.sensors:
        out.append(_tf(stamp_ns, s.parent, s.name, s.xyz, rpy_to_quat(s.rpy)))
        if s.kind in ("rgb", "depth"):
            out.append(_tf(stamp_ns, s.name, optical_frame(s), (0.0, 0.0, 0.0), rpy_to_quat(_OPTICAL_RPY)))
    return m.TFMessage(out)


def optical_frame(sensor) -> str:
    return f"{sensor.name}_optical"


def scan_frame(sensor, base_link: str) -> str:
    level = abs(sensor.rpy[0]) < 1e-9 and abs(sensor.rpy[1]) < 1e-9 and abs(sensor.rpy[2]) < 1e-9
    return sensor.name if sensor.parent == base_link and level else base_link


def image_msg(img: np.ndarray, stamp_ns: int, frame_id: str) -> m.Image:
    img = np.ascontiguousarray(img, dtype=np.uint8)
    h, w = img.shape[:2]
    return m.Image(header(stamp_ns, frame_id), h, w, "rgb8", 0, w * 3, img.tobytes())


def camera_info_msg(width: int, height: int, fovy_deg: float, stamp_ns: int, frame_id: str) -> m.CameraInfo:
    """A distortion-free pinhole with square pixels (the renderer's camera)."""
    fy = (height / 2.0) / math.tan(math.radians(fovy_deg) / 2.0)
    fx, cx, cy = fy, width / 2.0, height / 2.0
    k = [fx, 0.0, cx, 0.0, fy, cy, 0.0, 0.0, 1.0]
    r = [1.0, 0.0, 0.0, 0.0, 1.0, 0.0, 0.0, 0.0, 1.0]
    p = [fx, 0.0, cx, 0.0, 0.0, fy, cy, 0.0, 0.0, 0.0, 1.0, 0.0]
    return m.CameraInfo(header(stamp_ns, frame_id), height, width, "plumb_bob", [0.0] * 5, k, r, p)


_XYZ_FIELDS = [m.PointField("x", 0, 7, 1), m.PointField("y", 4, 7, 1), m.PointField("z", 8, 7, 1)]  # 7: FLOAT32


def pointcloud_msg(points: np.ndarray, stamp_ns: int, frame_id: str) -> m.PointCloud2:
    """An unorganized xyz float32 cloud (height 1)."""
    pts = np.ascontiguousarray(points, dtype="<f4").reshape(-1, 3)
    n = pts.shape[0]
    return m.PointCloud2(header(stamp_ns, frame_id), 1, n, list(_XYZ_FIELDS), False, 12, 12 * n,
                         pts.tobytes(), bool(np.isfinite(pts).all()))


def scan_msg(ranges: np.ndarray, sensor, stamp_ns: int, frame_id: str, scan_time: float = 0.0) -> m.LaserScan:
    """Beam 0 at -pi, counter-clockwise, over 360 deg (or the sensor's fov centred on its heading).
    REP-117: a beam at (or beyond) ``range_max`` had no return and reads ``+inf``."""
    n = len(ranges)
    ranges = np.asarray(ranges, dtype=np.float32).copy()
    ranges[ranges >= np.float32(sensor.range_max)] = np.inf
    if sensor.fov_deg >= 360.0:
        a0, inc = -math.pi, 2 * math.pi / n
    else:
        fov = math.radians(sensor.fov_deg)
        a0, inc = -fov / 2, fov / max(n - 1, 1)
        if frame_id != sensor.name:
            a0 += float(sensor.rpy[2])
    return m.LaserScan(header(stamp_ns, frame_id), a0, a0 + inc * (n - 1), inc, 0.0, float(scan_time),
                       float(sensor.range_min), float(sensor.range_max),
                       ranges.tolist(), [])


# ----------------------------------------------------------------------- commands
@dataclass(frozen=True)
class JointCommandMap:
    """How a ``sensor_msgs/JointState`` on the joint command topic becomes HAL commands.

    ``position`` entries are matched to joints by ``name``; an empty ``name``
    list means "the arm joints in manifest order". Arm joints not named keep
    their measured position. A gripper joint's position is mapped linearly to
    the gripper scalar (its ``open`` position -> -1, ``closed`` -> +1). Unknown
    names are ignored (and counted by the bridge).
    """

    arm: tuple[str, ...]
    gripper: dict[str, tuple[float, float]]  # name -> (open, closed)

    @classmethod
    def from_spec(cls, spec) -> JointCommandMap:
        grip = {}
        if spec.gripper is not None:
            for name, lo, hi in zip(spec.gripper.joints, spec.gripper.open, spec.gripper.closed):
                grip[name] = (float(lo), float(hi))
        return cls(tuple(j.name for j in spec.arm_joints), grip)

    def split(self, msg: m.JointState, measured: dict[str, float]):
        """``(arm_targets | None, gripper_scalar | None, unknown_names)``."""
        names = list(msg.name) or list(self.arm[: len(msg.position)])
        if len(names) != len(msg.position):
            raise ValueError(f"joint command has {len(names)} names and {len(msg.position)} positions")
        arm_cmd, grip, unknown = {}, None, []
        for name, pos in zip(names, msg.position):
            if name in self.arm:
                arm_cmd[name] = float(pos)
            elif name in self.gripper:
                lo, hi = self.gripper[name]
                if grip is None and hi != lo:
                    grip = max(-1.0, min(1.0, -1.0 + 2.0 * (float(pos) - lo) / (hi - lo)))
            else:
                unknown.append(name)
        arm = None
        if arm_cmd:
            arm = np.array([arm_cmd.get(n, measured.get(n, 0.0)) for n in self.arm], dtype=np.float64)
        return arm, grip, unknown
