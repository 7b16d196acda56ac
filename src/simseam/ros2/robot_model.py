"""The robot's TF tree and ``/robot_description``: what robot_state_publisher computes, without ROS.

From the RobotSpec's URDF (``spec.urdf``, resolved by ``resolve_asset``) and the
joint positions the HAL reports:

- every URDF joint is one transform ``<parent link> -> <child link>`` (its
  origin, then its motion: a rotation about ``axis`` for revolute/continuous
  joints, a translation along it for prismatic ones); fixed joints go on
  ``/tf_static`` once, movable ones on ``/tf`` with the joint states;
- movable URDF joints the HAL does not report follow their ``<mimic>`` joint
  (``multiplier * q + offset``), else sit at 0;
- REP-105: the base frame is ``base_link``. When the URDF's root link is called
  something else (the Panda's ``panda_link0``), ``base_link -> <root>`` is an
  identity on ``/tf_static``, so ``odom -> base_link -> <root> -> ...`` is one
  tree;
- a manifest's tool frame (``tcp``, a virtual link in ``spec.links``) is one more fixed
  transform ``<its parent> -> tcp`` on ``/tf_static`` (not in ``/robot_description``);
- ``/robot_description`` (std_msgs/String, transient local) is the URDF text,
  with mesh file names made absolute ``file://`` URIs (relative paths, and
  ``package://<pkg>/...`` when a folder ``<pkg>`` encloses the URDF) so a
  viewer on this machine finds them.

``/joint_states`` carries the HAL's joints that exist in the URDF, under their
URDF names; a kinematic base's virtual ``base_x/base_y/base_yaw`` are on
``/odom`` and ``/tf`` instead.
"""

from __future__ import annotations

import math
import re
import xml.etree.ElementTree as ET
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from simseam.math3d import matrix_to_quat, rpy_to_matrix
from simseam.robot.urdf import MOVABLE, UrdfModel, read_urdf
from simseam.ros2 import msgs as m

BASE_LINK = "base_link"  # REP-105


@dataclass(frozen=True)
class _Joint:
    name: str
    type: str
    parent: str
    child: str
    origin_R: np.ndarray
    origin_t: np.ndarray
    axis: np.ndarray


def _axis_angle(axis: np.ndarray, angle: float) -> np.ndarray:
    x, y, z = axis
    c, s, C = math.cos(angle), math.sin(angle), 1 - math.cos(angle)
    return np.array([[c + x * x * C, x * y * C - z * s, x * z * C + y * s],
                     [y * x * C + z * s, c + y * y * C, y * z * C - x * s],
                     [z * x * C - y * s, z * y * C + x * s, c + z * z * C]])


def _absolute_meshes(text: str, urdf_path: Path) -> str:
    base = urdf_path.parent

    def fix(match: re.Match) -> str:
        name = match.group(2)
        if name.startswith("package://"):
            pkg, _, rest = name[len("package://"):].partition("/")
            root = next((d for d in (base, *base.parents) if d.name == pkg), None)
            if root is None:
                return match.group(0)
            path = root / rest
        elif "://" in name:
            return match.group(0)
        else:
            path = (base / name).resolve()
        return f'{match.group(1)}"{path.as_uri()}"'

    return re.sub(r'(filename\s*=\s*)"([^"]*)"', fix, text)


class RobotModel:
    """The URDF tree of ``spec`` and the ROS messages it gives (see the module docstring)."""

    def __init__(self, spec):
        from simseam.robot.assets import resolve_asset

        self.spec = spec
        self.path = Path(resolve_asset(spec.urdf))
        self.urdf: UrdfModel = read_urdf(self.path)
        raw = self.path.read_text()
        self.description = _absolute_meshes(raw, self.path)
        self.root = self.urdf.root_link
        self.links = list(self.urdf.links)
        self.joints = [_Joint(j.name, j.type, j.parent, j.child, rpy_to_matrix(j.rpy), np.asarray(j.xyz, float),
                              np.asarray(j.axis, float) / (np.linalg.norm(j.axis) or 1.0))
                       for j in self.urdf.joints]
        for link in getattr(spec, "links", ()):  # a manifest's tool frame (tcp): a virtual link fixed to a URDF link
            if link.name not in self.links and link.parent in self.links:
                self.links.append(link.name)
                self.joints.append(_Joint(link.joint, "fixed", link.parent, link.name, rpy_to_matrix(link.rpy),
                                          np.asarray(link.xyz, float), np.array([0.0, 0.0, 1.0])))
        self.mimic: dict[str, tuple[str, float, float]] = {}
        for el in ET.fromstring(raw).findall("joint"):
            mim = el.find("mimic")
            if mim is not None and mim.get("joint"):
                self.mimic[el.get("name", "")] = (mim.get("joint"), float(mim.get("multiplier", 1.0)),
                                                  float(mim.get("offset", 0.0)))
        urdf_joints = set(self.urdf.joint_names)
        #: manifest joint name -> URDF joint name, for the HAL joints that are in the URDF
        self.state_joints = {j.name: j.sim_name for j in spec.joints if j.sim_name in urdf_joints}

    # ------------------------------------------------------------- messages
    def description_msg(self) -> m.String:
        return m.String(self.description)

    def frames(self) -> list[str]:
        """Every frame the tree names: the URDF links (and ``base_link``)."""
        return ([BASE_LINK] if BASE_LINK not in self.links else []) + self.links

    def _transform(self, j: _Joint, q: float, stamp_ns: int) -> m.TransformStamped:
        R, t = j.origin_R, j.origin_t
        if j.type in ("revolute", "continuous"):
            R = R @ _axis_angle(j.axis, q)
        elif j.type == "prismatic":
            t = t + R @ (j.axis * q)
        w, x, y, z = matrix_to_quat(R)
        return m.TransformStamped(m.Header(m.Time.from_ns(stamp_ns), j.parent), j.child,
                                  m.Transform(m.Vector3(*(float(v) for v in t)),
                                              m.Quaternion(float(x), float(y), float(z), float(w))))

    def static_transforms(self, stamp_ns: int) -> list[m.TransformStamped]:
        """Fixed joints, and ``base_link -> <root>`` when the root is not ``base_link``."""
        out = []
        if BASE_LINK not in self.links:
            out.append(m.TransformStamped(m.Header(m.Time.from_ns(stamp_ns), BASE_LINK), self.root, m.Transform()))
        out += [self._transform(j, 0.0, stamp_ns) for j in self.joints if j.type not in MOVABLE]
        return out

    def joint_positions(self, names, positions) -> dict[str, float]:
        """URDF joint name -> position, from the HAL's (manifest) names."""
        return {self.state_joints[n]: float(p) for n, p in zip(names, positions) if n in self.state_joints}

    def moving_transforms(self, names, positions, stamp_ns: int) -> list[m.TransformStamped]:
        q = self.joint_positions(names, positions)
        out = []
        for j in self.joints:
            if j.type not in MOVABLE:
                continue
            if j.name in q:
                v = q[j.name]
            elif j.name in self.mimic:
                src, mult, off = self.mimic[j.name]
                v = mult * q.get(src, 0.0) + off
            else:
                v = 0.0
            out.append(self._transform(j, v, stamp_ns))
        return out

    def joint_state_msg(self, names, positions, velocities, stamp_ns: int) -> m.JointState:
        """``/joint_states``: the HAL joints that exist in ``/robot_description``, under their URDF names."""
        keep = [(self.state_joints[n], float(p), float(v)) for n, p, v in zip(names, positions, velocities)
                if n in self.state_joints]
        return m.JointState(m.Header(m.Time.from_ns(stamp_ns), ""), [k[0] for k in keep], [k[1] for k in keep],
                            [k[2] for k in keep], [])
