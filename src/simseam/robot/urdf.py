"""Minimal URDF reader (standard library only): links, joints, kinematic tree.

Enough for checking manifests against a model and for the scene's own
kinematics; geometry and inertia are left to the engines.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

from simseam.seam import ConfigError

MOVABLE = ("revolute", "continuous", "prismatic")


@dataclass(frozen=True)
class UrdfJoint:
    """A URDF joint. ``xyz``/``rpy``: origin of the child frame in the parent link frame."""

    name: str
    type: str
    parent: str
    child: str
    xyz: tuple[float, float, float]
    rpy: tuple[float, float, float]
    axis: tuple[float, float, float]
    lower: float | None
    upper: float | None
    effort: float | None
    velocity: float | None


@dataclass(frozen=True)
class UrdfModel:
    name: str
    path: str
    links: tuple[str, ...]
    joints: tuple[UrdfJoint, ...]

    def joint(self, name: str) -> UrdfJoint:
        for j in self.joints:
            if j.name == name:
                return j
        raise KeyError(name)

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.joints]

    @property
    def movable_joint_names(self) -> list[str]:
        return [j.name for j in self.joints if j.type in MOVABLE]

    @property
    def root_link(self) -> str:
        children = {j.child for j in self.joints}
        roots = [link for link in self.links if link not in children]
        return roots[0] if roots else self.links[0]

    def chain(self, base_link: str, tip_link: str) -> list[UrdfJoint]:
        """Joints (fixed included) from ``base_link`` down to ``tip_link``, in order."""
        by_child = {j.child: j for j in self.joints}
        out: list[UrdfJoint] = []
        link = tip_link
        while link != base_link:
            if link not in by_child:
                raise ConfigError(
                    f"{self.path}: link {tip_link!r} is not below {base_link!r} in the kinematic tree"
                )
            j = by_child[link]
            out.append(j)
            link = j.parent
        return out[::-1]


def _floats(text: str | None, default: tuple[float, ...]) -> tuple[float, ...]:
    if text is None:
        return default
    return tuple(float(v) for v in text.split())


@lru_cache(maxsize=32)
def read_urdf(path: str | Path) -> UrdfModel:
    """Parse a URDF file. Raises ``ConfigError`` naming the file on malformed XML."""
    path = str(path)
    try:
        root = ET.parse(path).getroot()
    except (ET.ParseError, OSError) as exc:
        raise ConfigError(f"{path}: cannot read URDF: {exc}") from None
    if root.tag != "robot":
        raise ConfigError(f"{path}: root element is <{root.tag}>, expected <robot>")
    links = tuple(el.get("name", "") for el in root.findall("link"))
    joints = []
    for el in root.findall("joint"):
        try:
            joints.append(_read_joint(el))
        except ValueError as exc:
            raise ConfigError(f"{path}: joint {el.get('name', '')!r}: {exc}") from None
    return UrdfModel(name=root.get("name", ""), path=path, links=links, joints=tuple(joints))


def _link_of(el: ET.Element, tag: str) -> str:
    child = el.find(tag)
    if child is None or not child.get("link"):
        raise ValueError(f"needs a <{tag} link=\"...\"/> element")
    return child.get("link")


def _read_joint(el: ET.Element) -> UrdfJoint:
    """One <joint> element; ValueError (no file name) on a missing element or a non-number."""
    origin = el.find("origin")
    axis = el.find("axis")
    limit = el.find("limit")
    jtype = el.get("type", "fixed")
    lower = upper = effort = velocity = None
    if limit is not None:
        effort = float(limit.get("effort")) if limit.get("effort") else None
        velocity = float(limit.get("velocity")) if limit.get("velocity") else None
        if jtype != "continuous":
            lower = float(limit.get("lower", 0.0))
            upper = float(limit.get("upper", 0.0))
    return UrdfJoint(
        name=el.get("name", ""),
        type=jtype,
        parent=_link_of(el, "parent"),
        child=_link_of(el, "child"),
        xyz=_floats(origin.get("xyz") if origin is not None else None, (0.0, 0.0, 0.0)),
        rpy=_floats(origin.get("rpy") if origin is not None else None, (0.0, 0.0, 0.0)),
        axis=_floats(axis.get("xyz") if axis is not None else None, (1.0, 0.0, 0.0)),
        lower=lower,
        upper=upper,
        effort=effort,
        velocity=velocity,
    )
