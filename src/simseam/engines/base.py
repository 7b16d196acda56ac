"""The Engine protocol: simulator primitives, nothing more.

Control semantics (IK, gripper mapping, action slots) live in the scene; an
engine only offers the primitives below, so the same scene code means the same
thing on every engine. Imports: numpy and the standard library only.

Lifecycle: construct -> ``load_robot`` / ``add_*`` (build phase) -> ``build()``
-> ``reset()`` / state calls / ``step()`` (run phase) -> ``close()``.

Conventions:
- World frame: z up, metres, seconds, radians. Quaternions are ``[w, x, y, z]``.
- Joint arrays are in the order of ``RobotModel.joints`` (the manifest order,
  minus kinematic base joints).
- A camera or ray mount frame follows REP-103: +x is the viewing direction.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Protocol, runtime_checkable

import numpy as np


@dataclass(frozen=True)
class RobotModel:
    """What an engine needs to load a robot.

    ``urdf_path``: absolute path. ``joints``: simulator joint names to actuate,
    in order. ``kp``/``kd``: position gains per joint (None: engine default;
    kd None means critically damped). ``fixed_base``: weld the root link to the
    world at ``base_pos``/``base_quat`` (it can still be teleported with
    ``set_root_pose``); otherwise the root is free. ``inertia_from_geometry``
    replaces the URDF's link masses and inertias with those of the collision
    geometry at 1000 kg/m^3 (for models that ship placeholder inertias).
    ``link_shapes`` adds primitive geometry (visible, colliding, part of the
    robot: never hit by its own rays) to named links, e.g. a mobile chassis.
    ``collision_primitives``: collision meshes collide as primitives fitted to them (capsules; boxes
    on ``box_links``); the meshes keep their mass but stop colliding.
    """

    urdf_path: str
    joints: list[str]
    kp: list[float | None]
    kd: list[float | None]
    base_pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    base_quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    fixed_base: bool = True
    gravity_compensation: bool = True
    inertia_from_geometry: bool = False
    color: tuple[float, float, float, float] | None = None
    link_shapes: dict[str, list["Shape"]] = field(default_factory=dict)
    collision_primitives: bool = False
    box_links: tuple[str, ...] = ()


@dataclass(frozen=True)
class Shape:
    """A primitive shape of an object, posed in the object's frame.

    ``kind``: box (``size`` = half extents x, y, z), sphere (``size`` = [r]),
    cylinder (``size`` = [r, half_height], axis along z).
    """

    kind: str
    size: tuple[float, ...]
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    rgba: tuple[float, float, float, float] = (0.8, 0.8, 0.8, 1.0)


@dataclass(frozen=True)
class ObjectModel:
    """A rigid object made of primitive shapes.

    ``dynamic`` objects are free bodies of total ``mass`` kg; static ones are
    welded to the world (tables, obstacles, fixtures). ``friction`` is the
    sliding friction coefficient.
    """

    name: str
    shapes: list[Shape]
    pos: tuple[float, float, float] = (0.0, 0.0, 0.0)
    quat: tuple[float, float, float, float] = (1.0, 0.0, 0.0, 0.0)
    dynamic: bool = True
    mass: float = 0.1
    friction: float = 1.0


@dataclass(frozen=True)
class CameraModel:
    """A camera attached to a robot link (or ``"world"``).

    ``pos``/``quat``: mount pose in the parent frame (REP-103 mount frame:
    +x forward, +y left, +z up). ``fovy_deg``: vertical field of view. Depth
    is valid between ``near`` and ``far`` metres.
    """

    name: str
    parent: str
    pos: tuple[float, float, float]
    quat: tuple[float, float, float, float]
    width: int
    height: int
    fovy_deg: float
    near: float = 0.01
    far: float = 10.0


@dataclass(frozen=True)
class EngineOptions:
    """Engine-independent physics/render options.

    ``timestep``: physics step (s). ``render_quality``: "lean" (no shadows,
    reflections or MSAA) or "full".
    """

    timestep: float = 0.002
    render_quality: str = "lean"
    extra: dict = field(default_factory=dict)


@runtime_checkable
class Engine(Protocol):
    """Primitives every engine provides. See the module docstring for conventions."""

    name: str

    # build phase
    def load_robot(self, robot: RobotModel) -> None: ...
    def add_ground(self) -> None: ...
    def add_object(self, obj: ObjectModel) -> None: ...
    def add_camera(self, camera: CameraModel) -> None: ...
    def build(self) -> None: ...

    # run phase
    @property
    def timestep(self) -> float: ...
    def reset(self) -> None:
        """Restore the state right after ``build()`` (sim time 0)."""
    def set_joint_positions(self, q: np.ndarray) -> None:
        """Teleport robot joints (and their targets) to ``q``; zero velocities."""
    def set_joint_targets(self, q: np.ndarray) -> None:
        """Position-servo targets for every robot joint."""
    def joint_positions(self) -> np.ndarray: ...
    def joint_velocities(self) -> np.ndarray: ...
    def link_pose(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """World pose of a robot link frame: (pos[3], quat wxyz[4])."""
    def set_root_pose(self, pos: np.ndarray, quat: np.ndarray) -> None:
        """Teleport the robot's root link (the kinematic base moves the robot this way)."""
    def object_pose(self, name: str) -> tuple[np.ndarray, np.ndarray]: ...
    def set_object_pose(self, name: str, pos: np.ndarray, quat: np.ndarray) -> None:
        """Teleport a dynamic object and zero its velocity."""
    def object_velocity(self, name: str) -> np.ndarray:
        """Linear (3) + angular (3) world velocity of a dynamic object."""
    def step(self, n_substeps: int) -> None: ...
    def sim_time(self) -> float: ...
    def render_rgb(self, camera: str) -> np.ndarray:
        """uint8[H, W, 3] image of a camera added with ``add_camera``."""
    def render_depth(self, camera: str) -> np.ndarray:
        """float32[H, W] metric depth along the optical axis (metres)."""
    def cast_rays(self, origin: np.ndarray, directions: np.ndarray, max_dist: float) -> np.ndarray:
        """float64[N] hit distances from one world-frame origin along unit
        ``directions`` (N, 3); ``max_dist`` where nothing is hit. The robot's
        own bodies are never hit."""
    def contacts_between(self, a: str, b: str) -> bool:
        """Whether objects/robot ``a`` and ``b`` touch now (``"robot"`` names the robot)."""
    def close(self) -> None: ...

    # optional, looked up with getattr (an engine without it leaves the scene on SerialChain):
    # chain_forward(base_link, tip_link, joints, tip_offset) -> an object whose forward(q) returns
    # what SerialChain.forward returns, computed by the engine (MuJoCo: its C kinematics)
    # link_frame(link) -> (pos[3], rotation 3x3): link_pose with the rotation as a matrix, for engines
    # that hold one (MuJoCo's xmat); the scene converts link_pose's quaternion otherwise
