"""Layouts: the task part of a scene (props, randomisation, success), by name.

A layout never touches control: it places the robot base, adds props through
engine primitives, randomises them from the episode's generator and judges
success. Layouts that constrain nothing about the robot ("free-axis") accept
any manifest robot; others state what they need (``required_rgb``, a forced
control mode) and ``check_robot`` rejects a robot that lacks it.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, ClassVar

import numpy as np

from simseam.engines.base import Engine, ObjectModel, Shape
from simseam.robot.spec import RobotSpec
from simseam.seam import ConfigError

if TYPE_CHECKING:  # pragma: no cover
    from simseam.scene.manifest_scene import ManifestScene

TABLE_TOP = 0.8  # world z of the table surface (m)
TABLE_HALF = (0.55, 0.7, TABLE_TOP / 2)
TABLE_CENTER_X = 0.35  # table centre in front of the robot base (m)


class Layout:
    """Base class. Subclasses set the class attributes and override the hooks."""

    name: ClassVar[str] = ""
    instruction: ClassVar[str] = ""
    max_steps: ClassVar[int] = 200
    image_size: ClassVar[tuple[int, int] | None] = None  # (H, W) forced default for RGB cameras
    required_rgb: ClassVar[tuple[str, ...]] = ()
    control_mode: ClassVar[str | None] = None  # None: the robot's own default
    needs_gripper: ClassVar[bool] = True
    #: props whose poses ``privileged['objects']`` reports
    tracked_objects: ClassVar[tuple[str, ...]] = ()

    def __init__(self, spec: RobotSpec, reach: float):
        self.spec = spec
        self.reach = reach

    def check_robot(self) -> None:
        """Raise ``ConfigError`` listing what the robot lacks for this layout."""
        problems = []
        if self.needs_gripper and self.spec.gripper is None:
            problems.append("a gripper")
        keys = {s.feature_key for s in self.spec.sensors_of("rgb")}
        missing = [k for k in self.required_rgb if k not in keys]
        if missing:
            problems.append(f"RGB sensors with feature keys {missing} (it has {sorted(keys) or 'none'})")
        if problems:
            raise ConfigError(f"layout {self.name!r} needs robot {self.spec.name!r} to declare " + " and ".join(problems))

    def robot_base(self) -> tuple[np.ndarray, float]:
        """World position of the robot base link and its yaw (rad)."""
        return np.array([0.0, 0.0, TABLE_TOP]), 0.0

    def workspace(self) -> tuple[float, float]:
        """(x centre, half width) of the reachable tabletop strip, in the base frame (m)."""
        return 0.6 * self.reach, 0.15 * self.reach

    def build(self, engine: Engine) -> None:
        """Add the ground, the table and the props (build phase)."""
        engine.add_ground()
        engine.add_object(
            ObjectModel(
                "table",
                [Shape("box", TABLE_HALF, rgba=(0.62, 0.48, 0.34, 1.0))],
                pos=(TABLE_CENTER_X, 0.0, TABLE_TOP / 2),
                dynamic=False,
            )
        )

    def reset(self, engine: Engine, rng: np.random.Generator) -> None:
        """Place the props for a new episode (after the engine reset)."""

    def privileged(self, scene: "ManifestScene") -> dict[str, np.ndarray]:
        """Extra ground truth for ``privileged['objects']`` (base frame [x, y, z, qw, qx, qy, qz])."""
        return {}

    def evaluate(self, scene: "ManifestScene") -> tuple[float, bool]:
        """(reward, success) after a control step."""
        raise NotImplementedError


_LAYOUTS: dict[str, type[Layout]] = {}


def register_layout(cls: type[Layout]) -> type[Layout]:
    """Class decorator: make a layout available by its ``name``."""
    if not cls.name:
        raise ValueError(f"{cls.__name__} has no name")
    _LAYOUTS[cls.name] = cls
    return cls


def layout_names() -> list[str]:
    _load_builtin()
    return sorted(_LAYOUTS)


def get_layout(name: str) -> type[Layout]:
    _load_builtin()
    try:
        return _LAYOUTS[name]
    except KeyError:
        raise ConfigError(f"unknown layout {name!r}; known layouts: {', '.join(sorted(_LAYOUTS))}") from None


def _load_builtin() -> None:
    from simseam.scene.layouts import bowl_plate, lift_cube, nav_obstacles  # noqa: F401  (registers them)


