"""Tasks: what the robot is asked to do in a scene (props, randomisation, state, success), by name.

A task never touches control: it places the robot base, adds props through
engine primitives, draws each episode's randomisation from the episode's generator
(``sample``), defines the observation's state vector and judges each step
(``evaluate_batch``: reward, success and named diagnostics such as a distance to the
goal). The draws and the judgement are written once, batched over N worlds
(``simseam.scene.tasks.batch``): the CPU engine runs them for one world, MuJoCo Warp
for all its worlds, with no engine-specific code in the task. Tasks that constrain
nothing about the robot accept any manifest robot; others state what they need
(``required_rgb``, a forced control mode, a gripper) and ``check_robot``
rejects a robot that lacks it.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, ClassVar

import numpy as np

from simseam.engines.base import Engine, ObjectModel, Shape
from simseam.math3d import axis_angle_of
from simseam.robot.spec import RobotSpec
from simseam import registry
from simseam.scene.tasks.batch import BatchEvaluation, Draw, SceneState, TaskState
from simseam.seam import ConfigError

if TYPE_CHECKING:  # pragma: no cover
    from simseam.robot.kinematics import SerialChain
    from simseam.scene.manifest_scene import ManifestScene

TABLE_TOP = 0.8  # world z of the table surface (m)
TABLE_HALF = (0.55, 0.7, TABLE_TOP / 2)
TABLE_CENTER_X = 0.35  # table centre in front of the robot base (m)


@dataclass(slots=True)
class Evaluation:
    """A task's judgement after a control step: ``diagnostics`` maps each name in
    ``Task.diagnostics`` to a float (SI units) or a bool. Slotted, not frozen: made every step, and a
    frozen dataclass's ``__init__`` sets each field through ``object.__setattr__``."""

    reward: float
    success: bool
    diagnostics: dict[str, float | bool] = field(default_factory=dict)


class Task:
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
    #: extra ground-truth names ``privileged()`` adds to ``privileged['objects']``
    privileged_extras: ClassVar[tuple[str, ...]] = ()
    #: names of the values ``evaluate`` reports besides reward and success
    diagnostics: ClassVar[tuple[str, ...]] = ()
    #: sizes of the props (metres) that privileged experts read from ``spec.task.geometry``
    geometry: ClassVar[dict[str, float]] = {}

    def __init__(self, spec: RobotSpec, reach: float, chain: "SerialChain | None" = None):
        self.spec = spec
        self.reach = reach
        self.chain = chain  # base link -> tool frame, the one the scene's IK uses
        self.params: dict[str, np.ndarray] = {}  # the episode's draws as one world's (reset)

    def check_robot(self) -> None:
        """Raise ``ConfigError`` listing what the robot lacks for this task."""
        problems = []
        if self.needs_gripper and self.spec.gripper is None:
            problems.append("a gripper")
        keys = {s.feature_key for s in self.spec.sensors_of("rgb")}
        missing = [k for k in self.required_rgb if k not in keys]
        if missing:
            problems.append(f"RGB sensors with feature keys {missing} (it has {sorted(keys) or 'none'})")
        if problems:
            raise ConfigError(f"task {self.name!r} needs robot {self.spec.name!r} to declare " + " and ".join(problems))

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

    def sample(self, rng: np.random.Generator) -> Draw:
        """The episode's random choices, from ``rng`` alone: where the props go and the other choices
        (``Draw``). The one definition of the task's reset, for every engine (a batched engine draws each
        world's from that world's own seed)."""
        return Draw()

    def reset(self, engine: Engine, rng: np.random.Generator) -> None:
        """Start an episode on one engine (after the engine reset): ``sample``'s props placed, its params
        kept as one world's (``self.params``, read by ``evaluate``)."""
        draw = self.sample(rng)
        for name, (pos, quat) in draw.poses.items():
            engine.set_object_pose(name, pos, quat)
        self.params = {k: np.asarray(v)[None] for k, v in draw.params.items()}

    def evaluate_batch(self, state: TaskState) -> BatchEvaluation:
        """Reward, success and diagnostics of N worlds after a control step (``simseam.scene.tasks.batch``)."""
        raise NotImplementedError

    def extra_poses(self, state: TaskState) -> dict[str, object]:
        """Ground truth beyond the tracked props for ``privileged['objects']`` (a target, a goal): each of
        ``privileged_extras`` as base-frame [x, y, z, qw, qx, qy, qz] float[N, 7] of ``state.xp``."""
        return {}

    def object_names(self) -> tuple[str, ...]:
        """The objects whose poses the task reports: tracked props, then its extras (a target, a goal)."""
        return tuple(self.tracked_objects) + tuple(self.privileged_extras)

    def object_poses(self, scene: "ManifestScene") -> dict[str, np.ndarray]:
        """Each of ``object_names()`` as a base-frame pose [x, y, z, qw, qx, qy, qz] (float64[7]): the one
        source of ``privileged['objects']`` and of ``environment_state``."""
        eng = scene.engine
        poses = {n: scene.to_base(*eng.object_pose(n)) for n in self.tracked_objects}
        if self.privileged_extras:
            poses.update({n: v[0] for n, v in self.extra_poses(SceneState(scene, self.params)).items()})
        return poses

    def environment_state(self, objects: dict[str, np.ndarray]) -> np.ndarray:
        """The ``environment_state`` observation from ``object_poses``' result: the poses concatenated
        in ``object_names()`` order (float32)."""
        return np.concatenate([objects[n] for n in self.object_names()]).astype(np.float32)

    def env_state_names(self) -> tuple[str, ...]:
        """Slot names of ``environment_state``: each object's base-frame pose, in ``object_names()`` order."""
        return tuple(f"{n}.{c}" for n in self.object_names() for c in ("x", "y", "z", "qw", "qx", "qy", "qz"))

    def state_names(self) -> tuple[str, ...]:
        """Slot names of the observation's ``state`` vector. Default (the LIBERO convention):
        tool position (m) and axis-angle orientation (rad, angle in [0, 2 pi), continuous through pi
        around the home orientation) in the base frame, then each gripper finger's position."""
        grip = self.spec.gripper.joints if self.spec.gripper else []
        return ("eef_pos.x", "eef_pos.y", "eef_pos.z", "eef_axis_angle.x", "eef_axis_angle.y",
                "eef_axis_angle.z", *(f"gripper_qpos.{n}" for n in grip))

    def state(self, eef_pos: list[float], eef_rot: list[list[float]], gripper_q: np.ndarray, out: np.ndarray,
              rot_reference: tuple[float, ...]) -> None:
        """Fill ``out`` (float32[len(state_names())]) from the measured tool pose (base frame, Python floats:
        the position and the rotation's rows) and the gripper finger positions; the axis-angle is continuous
        around ``rot_reference`` (the robot's home tool orientation, a quaternion of Python floats:
        ``math3d.matrix_to_axis_angle``)."""
        out[:] = [*eef_pos, *axis_angle_of(eef_rot, rot_reference), *gripper_q.tolist()]

    def evaluate(self, scene: "ManifestScene") -> Evaluation:
        """``evaluate_batch`` for the one world of ``scene`` (the CPU engine), as Python values."""
        ev = self.evaluate_batch(SceneState(scene, self.params))
        return Evaluation(float(ev.reward.item()), bool(ev.success.item()),
                          {k: v.item() for k, v in ev.diagnostics.items()})


#: every task by name (simseam.registry: "module:Class", imported when asked for)
TASKS: dict[str, str | type[Task]] = {
    "lift_cube": "simseam.scene.tasks.lift_cube:LiftCube",
    "bowl_plate": "simseam.scene.tasks.bowl_plate:BowlPlate",
    "nav_obstacles": "simseam.scene.tasks.nav_obstacles:NavObstacles",
    "reach": "simseam.scene.tasks.reach:Reach",
}


def register_task(cls: type[Task]) -> type[Task]:
    """Class decorator for a task defined outside this table: adds its row (under its ``name``)."""
    return registry.add(TASKS, cls.name, cls)


def get_task(name: str) -> type[Task]:
    return registry.load(TASKS, name, "task")
