"""ManifestScene: one robot (from a RobotSpec) doing one task, on any engine.

It implements the ``SimRollout`` seam by composing parts that each own one concern:

- controllers (``scene.controllers``): the arm (joint targets or Cartesian
  deltas through the scene's own IK), the gripper and the kinematic base each
  own their action slots, meaning and bounds; ``spec.action.clip`` is applied
  once, before they see an action;
- the task (``scene.tasks``): props, randomisation, the state vector, success
  and diagnostics;
- sensors (``scene.sensors``): lidar ray casts and depth clouds from engine primitives;
- the engine: primitives only (load, step, read, render, cast rays).

Because control semantics live here, an action means the same on every engine.
Joint servo setpoints ramp smoothly to each new target over the first 60% of
the control period. Only declared sensors exist, and cameras render only when
an observation request asks for them. Importable with numpy alone (no pydantic).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simseam.engines.base import CameraModel, Engine, EngineOptions, RobotModel, Shape
from simseam.math3d import (make_transform, matrix_to_quat, quat_to_matrix, rpy_to_matrix, rpy_to_quat, sign_reference,
                            yaw_quat)
from simseam.robot.assets import resolve_asset
from simseam.robot.spec import RobotSpec
from simseam.robot.urdf import read_urdf
from simseam.scene import describe
from simseam.scene.base_motion import KinematicBase
from simseam.scene.controllers import ArmController, CartesianDeltaArm, Gripper, JointPositionArm, TwistBase
from simseam.robot.kinematics import SerialChain
from simseam.scene.sensors import DepthCloud, Lidar2D
from simseam.scene.tasks.base import get_task
from simseam.seam import (
    INFO_DIAGNOSTICS,
    INFO_STEPS,
    OBS_BASE_POSE,
    OBS_DEPTH_POINTS,
    OBS_ENV_STATE,
    OBS_IMAGES,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_LINK_POSES,
    OBS_PRIVILEGED,
    OBS_SCAN,
    OBS_SIM_TIME_NS,
    OBS_STATE,
    OBS_TASK,
    ActionSpec,
    ConfigError,
    ControlMode,
    ObsRequest,
    Observation,
    RolloutSpec,
    SimulationError,
    StepResult,
    TaskSpec,
)

RAMP_CHUNKS = 3  # servo setpoint updates per control step
RAMP_FRACTION = 0.6  # the setpoint reaches the new target at this fraction of the control period
SETTLE_S = 0.1  # physics time after placing props, before the first observation
_FULL = ObsRequest()


def _as_slice(idx: np.ndarray) -> slice | np.ndarray:
    """``idx`` as a slice when it is a run of consecutive indices (a view, cheaper per step), else itself."""
    if idx.size and np.array_equal(idx, np.arange(idx[0], idx[0] + idx.size)):
        return slice(int(idx[0]), int(idx[0]) + idx.size)
    return idx


@dataclass(frozen=True)
class SceneOptions:
    """Scene knobs. ``image_size`` (H, W) overrides every RGB sensor's size;
    ``render_images=False`` builds a state-only scene (no images, no depth clouds);
    ``privileged=True`` adds ground truth for scripted experts; ``environment_state=True``
    adds the task's object state (``environment_state``, what a state-based learned policy
    reads); ``seed`` seeds the stream used when ``reset(seed=None)``."""

    control_hz: float = 20.0
    image_size: tuple[int, int] | None = None
    max_steps: int | None = None
    control_mode: str | None = None
    render_images: bool = True
    privileged: bool = False
    environment_state: bool = False
    render_quality: str = "lean"
    timestep: float = 0.002
    ik_iters: int = 1
    seed: int = 0


@dataclass(frozen=True)
class ScenePlan:
    """What a built scene compiled, fixed for its life: the public description another implementation of
    the same scene reads (the MuJoCo Warp batch) instead of the scene's internals.

    ``substeps`` physics steps per control step, run in ``chunks`` with the servo setpoint at ``ramp``
    of the way to the new target after each; ``joints``: the engine's joints (the manifest's, less a
    kinematic base), ``joint_index[k]``: joint k's place in the manifest; ``arm_idx`` / ``grip_idx``:
    the arm's and the gripper's joints among ``joints``; ``home``: their reset positions; the tool frame
    (``tool_pos``, ``tool_rot``) on the tool link; ``state_names``: the task's state vector;
    ``cameras``: the RGB cameras as (sensor name, feature key, (H, W)); the controllers' constants:
    ``arm_max_step`` (each arm joint's most per control step), ``max_translation`` / ``max_rotation``
    (a Cartesian arm's step per unit action; 0 in joint mode), ``grip_open`` / ``grip_closed`` (the
    fingers' positions; empty without a gripper); ``rot_reference``: the home tool orientation the
    state's axis-angle stays continuous around (wxyz); ``tool_link``: the link the tool frame rides on."""

    substeps: int
    chunks: tuple[int, ...]
    ramp: tuple[float, ...]
    joints: tuple
    joint_index: np.ndarray
    arm_idx: np.ndarray
    grip_idx: np.ndarray
    home: np.ndarray
    tool_pos: np.ndarray
    tool_rot: np.ndarray
    state_names: tuple[str, ...]
    cameras: tuple[tuple[str, str, tuple[int, int]], ...]
    arm_max_step: np.ndarray
    max_translation: float
    max_rotation: float
    grip_open: np.ndarray
    grip_closed: np.ndarray
    rot_reference: np.ndarray
    tool_link: str


class ManifestScene:
    """A ``SimRollout`` built from a ``RobotSpec`` and a task name."""

    def __init__(self, robot: RobotSpec, task: str, engine: Engine | str = "mujoco",
                 options: SceneOptions | None = None):
        self.robot = robot
        self.options = opts = options or SceneOptions()
        if opts.control_hz <= 0 or opts.timestep <= 0:
            raise ConfigError("control_hz and timestep must be positive")
        self._urdf_path = str(resolve_asset(robot.urdf))
        self._urdf = read_urdf(self._urdf_path)
        if robot.kinematic_base is not None and self._urdf.root_link != robot.base_link:
            raise ConfigError(f"robot {robot.name!r}: a kinematic base moves the URDF root link "
                              f"{self._urdf.root_link!r}, so base_link must be it (got {robot.base_link!r})")
        self._above_base = self._links_above_base()
        task_cls = get_task(task)
        mode = ControlMode.parse(opts.control_mode or task_cls.control_mode or robot.action.control_mode)
        if task_cls.control_mode and mode != ControlMode.parse(task_cls.control_mode):
            raise ConfigError(f"task {task!r} requires control mode {task_cls.control_mode!r}, got {mode.value!r}")
        self._index_joints()
        tcp = robot.tcp
        # The tool frame: a URDF link, or a manifest tcp fixed to one (composed here, engines never see it).
        self._tool_parent = robot.tool_parent  # what every step reads the measured tool frame from
        self._tool_rot = rpy_to_matrix(tcp.rpy) if tcp else np.eye(3)
        self._tool_pos = np.asarray(tcp.xyz, dtype=np.float64) if tcp else np.zeros(3)
        self._tip_offset = make_transform(self._tool_pos, self._tool_rot) if tcp else None
        self.chain = SerialChain(self._urdf, robot.base_link, robot.tool_parent,
                                 [self._ejoints[i].sim_name for i in self._arm_idx],
                                 self._arm_bounds(self._lower), self._arm_bounds(self._upper, +1),
                                 tip_offset=self._tip_offset)
        #: the home tool orientation (base frame, a quaternion of fixed sign): the state's axis-angle
        #: is continuous around it (``math3d.matrix_to_axis_angle``)
        self.rot_reference = sign_reference(matrix_to_quat(self.chain.forward(self._home[self._arm_idx])[0][:3, :3]))
        self._rot_reference = tuple(self.rot_reference.tolist())  # as Task.state takes it
        self.task = task_cls(robot, self.chain.tabletop_reach(), self.chain)
        self.task.check_robot()
        self._make_controllers(mode)
        # where each controller's slots lie in an action, read from the spec once (every step splits one)
        spec = self.action_spec
        self._act_arm, self._act_grip, self._act_base = spec.arm, spec.grip, spec.base
        base_pos, base_yaw = self.task.robot_base()
        self._base_pos = np.asarray(base_pos, dtype=np.float64)
        self._base_rot = quat_to_matrix(yaw_quat(base_yaw))
        self._base_turned = base_yaw != 0.0  # else _base_rot is the identity: base frame = world frame shifted
        self._base_start = (float(base_pos[0]), float(base_pos[1]), float(base_yaw))
        lidars = robot.sensors_of("lidar_2d")
        if len(lidars) > 1:
            raise ConfigError(f"robot {robot.name!r} declares {len(lidars)} lidar_2d sensors; "
                              "the observation's 'scan' holds one")
        self._lidar = Lidar2D(lidars[0]) if lidars else None
        self.engine = self._build_engine(engine, base_yaw)
        if isinstance(self.arm, CartesianDeltaArm):
            self.arm.chain = self._ik_chain()
        self._link_frame = getattr(self.engine, "link_frame", None)  # an optional engine primitive
        self._substeps = max(1, int(round(1.0 / (opts.control_hz * self.engine.timestep))))
        n_chunks = min(RAMP_CHUNKS, self._substeps)
        self._chunks = np.diff(np.linspace(0, self._substeps, n_chunks + 1).round().astype(int)).tolist()
        t = np.cumsum(self._chunks) / self._substeps / RAMP_FRACTION
        self._ramp = np.where(t >= 1.0, 1.0, t * t * (3.0 - 2.0 * t)).tolist()  # smoothstep
        self._spec = self._describe(task)
        self.plan = ScenePlan(self._substeps, tuple(self._chunks), tuple(self._ramp), tuple(self._ejoints),
                              self._eidx.copy(), self._arm_idx.copy(), self._grip_idx.copy(), self._home.copy(),
                              self._tool_pos.copy(), self._tool_rot.copy(), tuple(self._state_names),
                              tuple((n, k, self._sizes[n]) for n, k in self._rgb), *self._controller_plan())
        self._seed_stream = np.random.default_rng(opts.seed)
        self._episode_ready = False
        self._closed = False
        self._frame: np.ndarray | None = None

    # ------------------------------------------------------------ construction
    def _controller_plan(self) -> tuple:
        """``ScenePlan``'s controller constants (see its docstring), in its field order."""
        arm, g = self.arm, self.gripper
        none = np.zeros(0)
        return (np.asarray(arm.max_step, float).copy(), float(getattr(arm, "max_translation", 0.0)),
                float(getattr(arm, "max_rotation", 0.0)), (g.open if g else none).copy(),
                (g.closed if g else none).copy(), self.rot_reference.copy(), self.robot.tool_parent)

    def _index_joints(self) -> None:
        """Engine joints (every manifest joint but the kinematic base's), their limits and roles."""
        robot = self.robot
        self._ejoints = [j for j in robot.joints if j.role != "base"]
        names = [j.name for j in self._ejoints]
        self._arm_idx = np.array([i for i, j in enumerate(self._ejoints) if j.role == "arm"], dtype=int)
        self._grip_idx = np.array([names.index(n) for n in robot.gripper.joints] if robot.gripper else [], dtype=int)
        self._arm_sel, self._grip_sel = _as_slice(self._arm_idx), _as_slice(self._grip_idx)  # what every step indexes with
        self._lower = np.array([-np.inf if j.lower is None else j.lower for j in self._ejoints])
        self._upper = np.array([np.inf if j.upper is None else j.upper for j in self._ejoints])
        self._home = np.clip(np.array([j.home for j in self._ejoints]), self._lower, self._upper)
        vmax = np.array([np.inf if j.max_velocity is None else j.max_velocity for j in self._ejoints])
        self._max_step = vmax[self._arm_idx] / self.options.control_hz
        manifest = robot.joint_names
        self._eidx = np.array([manifest.index(j.name) for j in self._ejoints], dtype=int)
        self._eidx_whole = bool(np.array_equal(self._eidx, np.arange(len(manifest))))  # the manifest's, in order
        self._bidx = (np.array([manifest.index(n) for n in robot.kinematic_base.joints])
                      if robot.kinematic_base is not None else None)

    def _links_above_base(self) -> dict[str, tuple[np.ndarray, np.ndarray]]:
        """URDF links above the base link (e.g. a root 'world' link, which MuJoCo merges into its world):
        fixed to the base, so their pose in the base frame is constant: (rot, pos)."""
        by_child = {j.child: j for j in self._urdf.joints}
        out, t, link = {}, np.eye(4), self.robot.base_link
        while link in by_child:
            j = by_child[link]
            t = make_transform(j.xyz, rpy_to_matrix(j.rpy)) @ t  # child in parent
            link = j.parent
            inv = np.linalg.inv(t)  # parent in base
            out[link] = (inv[:3, :3].copy(), inv[:3, 3].copy())
        return out

    def _arm_bounds(self, bound: np.ndarray, sign: int = -1) -> np.ndarray:
        b = bound[self._arm_idx]
        return np.where(np.isfinite(b), b, sign * 2 * np.pi)  # IK needs finite bounds

    def _make_controllers(self, mode: ControlMode) -> None:
        robot = self.robot
        arm_names = [self._ejoints[i].name for i in self._arm_idx]
        lo, hi = self._lower[self._arm_idx], self._upper[self._arm_idx]
        if mode == ControlMode.JOINT_POSITION:
            units = ["m" if self._urdf.joint(self._ejoints[i].sim_name).type == "prismatic" else "rad"
                     for i in self._arm_idx]
            self.arm: ArmController = JointPositionArm(arm_names, lo, hi, self._max_step, units)
        elif mode == ControlMode.CARTESIAN_DELTA:
            self.arm = CartesianDeltaArm(arm_names, lo, hi, self._max_step, chain=self.chain,
                                         q_home=self._home[self._arm_idx],
                                         max_translation=robot.action.max_translation,
                                         max_rotation=robot.action.max_rotation, ik_iters=self.options.ik_iters)
        else:
            raise ConfigError(f"robot {robot.name!r}: control mode {mode.value!r} cannot drive an arm; "
                              "use joint_position or cartesian_delta")
        self.gripper = Gripper(robot.gripper) if robot.gripper else None
        self.twist = TwistBase(robot.kinematic_base) if robot.kinematic_base is not None else None
        self._kbase = KinematicBase(robot.kinematic_base) if robot.kinematic_base is not None else None
        parts = [p for p in (self.arm, self.gripper, self.twist) if p is not None]
        self.action_spec = ActionSpec(mode, tuple(s for p in parts for s in p.slots),
                                      self.twist.norm_bounds if self.twist else (),
                                      robot.action.max_translation if mode == ControlMode.CARTESIAN_DELTA else 0.0,
                                      robot.action.max_rotation if mode == ControlMode.CARTESIAN_DELTA else 0.0)

    def _build_engine(self, engine: Engine | str, base_yaw: float) -> Engine:
        robot, opts = self.robot, self.options
        if isinstance(engine, str):
            from simseam.engines.registry import make_engine

            engine = make_engine(engine, EngineOptions(timestep=opts.timestep, render_quality=opts.render_quality))
        link_shapes = {}
        if robot.kinematic_base is not None:
            link_shapes[robot.base_link] = [Shape(sh["kind"], tuple(sh["size"]), pos=tuple(sh["pos"]),
                                                  rgba=tuple(sh["rgba"])) for sh in robot.kinematic_base.shapes]
        engine.load_robot(RobotModel(
            urdf_path=self._urdf_path, joints=[j.sim_name for j in self._ejoints], kp=[j.kp for j in self._ejoints],
            kd=[j.kd for j in self._ejoints], base_pos=tuple(self._base_pos), base_quat=tuple(yaw_quat(base_yaw)),
            fixed_base=True, inertia_from_geometry=robot.inertia == "geometry", link_shapes=link_shapes,
            collision_primitives=robot.collision == "primitives",
            box_links=tuple(self._urdf.joint(self._ejoints[i].sim_name).child for i in self._grip_idx)))
        self.task.build(engine)
        size = opts.image_size or self.task.image_size
        self._rgb: list[tuple[str, str]] = []  # (sensor name, feature key)
        self._depth: list[DepthCloud] = []
        self._cameras: dict[str, tuple[int, int]] = {}  # feature key -> (H, W)
        self._sizes: dict[str, tuple[int, int]] = {}  # sensor name -> (H, W)
        for s in robot.sensors:
            if s.kind not in ("rgb", "depth"):
                continue  # lidar_2d is a ray cast, not a camera
            h, w = size if (size and s.kind == "rgb") else (s.height, s.width)
            engine.add_camera(CameraModel(s.name, s.parent, tuple(s.xyz), tuple(rpy_to_quat(s.rpy)), w, h, s.fovy_deg,
                                          near=s.range_min or 0.01, far=s.range_max or 10.0))
            self._sizes[s.name] = (h, w)
            if s.kind == "rgb":
                self._rgb.append((s.name, s.feature_key))
                self._cameras[s.feature_key] = (h, w)
            else:
                self._depth.append(DepthCloud(s, w, h))
        engine.build()
        return engine

    def _ik_chain(self) -> SerialChain:
        """The chain the Cartesian arm solves on: the engine's own kinematics of it when the engine offers
        them (``chain_forward``; MuJoCo's C: a few microseconds a step, where numpy takes tens; with its
        Cholesky solve for the damped least squares system when it has one) and they
        agree with the URDF chain's to 1e-9 at home and at 8 seeded configurations within the limits;
        else the URDF chain (``forward_source`` says which)."""
        chain, make = self.chain, getattr(self.engine, "chain_forward", None)
        if make is None:
            return chain
        try:
            fk = make(self.robot.base_link, self.robot.tool_parent,
                      [self._ejoints[i].sim_name for i in self._arm_idx], self._tip_offset)
        except ConfigError:  # the engine's model lacks a link or joint of the chain (merged, renamed)
            return chain
        samples = np.random.default_rng(0).uniform(chain.lower, chain.upper, (8, chain.n))
        for q in (self._home[self._arm_idx], *samples):
            if not all(np.allclose(a, b, rtol=0.0, atol=1e-9) for a, b in zip(chain.forward(q), fk.forward(q))):
                return chain
        return chain.with_forward(fk.forward, self.engine.name, getattr(fk, "dls_solve", None),
                                  getattr(fk, "forward_rows", None))

    def _describe(self, task: str) -> RolloutSpec:
        opts = self.options
        facts = describe.robot_facts(self.robot, self._urdf, self._sizes)
        t = self.task
        privileged = t.object_names() if opts.privileged else None
        self._state_names = t.state_names()
        self._state_dim = len(self._state_names)
        env_state = t.env_state_names() if opts.environment_state else None
        if env_state == ():
            raise ConfigError(f"task {task!r} tracks no object: it has no environment_state to observe")
        obs = describe.observation_spec(facts, self._cameras, self._state_names, privileged,
                                        renders=opts.render_images, env_state_names=env_state)
        task_spec = TaskSpec(task, t.instruction, max_steps=opts.max_steps or t.max_steps,
                             diagnostics=tuple(t.diagnostics), geometry=tuple(t.geometry.items()))
        return describe.rollout_spec(robot=facts, observation=obs, action=self.action_spec, task=task_spec,
                                     engine=self.engine.name, control_hz=opts.control_hz, privileged=opts.privileged)

    # -------------------------------------------------------------------- seam
    @property
    def spec(self) -> RolloutSpec:
        return self._spec

    @property
    def action_dim(self) -> int:
        return self.action_spec.dim

    def reset(self, seed: int | None = None, observe: ObsRequest | None = None) -> Observation:
        self._check_open()
        if seed is None:
            seed = int(self._seed_stream.integers(0, 2**31 - 1))
        rng = np.random.default_rng(seed)
        eng = self.engine
        eng.reset()
        if self._kbase is not None:
            self._kbase.reset(*self._base_start)
            self._place_base()
        eng.set_joint_positions(self._home)
        self.task.reset(eng, rng)
        eng.step(max(1, int(round(SETTLE_S / eng.timestep))))
        self._t0 = eng.sim_time()
        self._q_target = self._home.copy()
        self._q_sent = self._home.copy()
        self.arm.reset()
        self._steps = 0
        self._episode_ready = True
        return self._observe(observe or _FULL)

    def step(self, action: np.ndarray, observe: ObsRequest | None = None) -> StepResult:
        self._check_open()
        if not self._episode_ready:
            raise SimulationError("step() called before reset()")
        a = self.action_spec.clip(self.action_spec.validate(action))
        target = self._q_target
        target[self._arm_sel] = self.arm.targets(a[self._act_arm], target[self._arm_sel], self._eef)
        if self.gripper is not None:
            target[self._grip_sel] = self.gripper.targets(float(a[self._act_grip]))
        self._servo(target, None if self._act_base is None else a[self._act_base])
        self._steps += 1
        obs = self._observe(observe or _FULL)
        ev = self.task.evaluate(self)
        truncated = self._steps >= self._spec.task.max_steps and not ev.success
        info = {self._spec.task.success_key: ev.success, INFO_STEPS: self._steps, INFO_DIAGNOSTICS: ev.diagnostics}
        return StepResult(obs, float(ev.reward), bool(ev.success), bool(truncated), info)

    def render(self) -> np.ndarray | None:
        """Frame of the first RGB camera (re-used if the current step already rendered it)."""
        self._check_open()
        if not self._rgb:
            return None
        if self._frame is None:
            self._frame = self.engine.render_rgb(self._rgb[0][0])
        return self._frame

    def sim_time_ns(self) -> int:
        return int(round((self.engine.sim_time() - getattr(self, "_t0", 0.0)) * 1e9))

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self.engine.close()

    def __enter__(self) -> "ManifestScene":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    # ------------------------------------------------------------ measurements
    @property
    def last_ik(self):
        """The last Cartesian step's IK result (None in joint-position mode or before a step)."""
        return getattr(self.arm, "last_ik", None)

    def _tool_world(self) -> tuple[np.ndarray, np.ndarray]:
        """Measured tool frame in the world: (pos[3], rot[3x3]); a tcp's offset composed on its parent link."""
        if self._link_frame is not None:
            p, r = self._link_frame(self._tool_parent)
        else:
            p, q = self.engine.link_pose(self._tool_parent)
            r = quat_to_matrix(q)
        if self.robot.tcp is None:
            return p, r
        return p + r @ self._tool_pos, r @ self._tool_rot

    def eef_pose_base(self) -> tuple[np.ndarray, np.ndarray]:
        """Measured tool pose in the robot base frame: (pos[3], rot[3x3])."""
        p, r = self._tool_world()
        if not self._base_turned:  # rotating by the identity: the same numbers
            return p - self._base_pos, r
        rt = self._base_rot.T
        return rt @ (p - self._base_pos), rt @ r

    def eef_position_world(self) -> np.ndarray:
        """Measured tool position in the world (pos[3]): ``eef_pose_world()[0]`` without its rotation."""
        p, q = self.engine.link_pose(self._tool_parent)
        return p if self.robot.tcp is None else p + quat_to_matrix(q) @ self._tool_pos

    def eef_pose_world(self) -> tuple[np.ndarray, np.ndarray]:
        """Measured tool pose in the world: (pos[3], quat wxyz[4])."""
        p, r = self._tool_world()
        return p, matrix_to_quat(r)

    def to_base(self, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
        """World pose -> base-frame [x, y, z, qw, qx, qy, qz]."""
        rt = self._base_rot.T
        return np.concatenate([rt @ (pos - self._base_pos), matrix_to_quat(rt @ quat_to_matrix(quat))])

    def base_pose(self) -> np.ndarray:
        """[x, y, yaw] of the base link in the world."""
        if self._kbase is not None:
            return self._kbase.pose.copy()
        r = self._base_rot
        return np.array([self._base_pos[0], self._base_pos[1], math.atan2(r[1, 0], r[0, 0])])

    def base_frame(self) -> tuple[np.ndarray, np.ndarray]:
        """The base link's frame in the world now: (position[3], rotation 3x3)."""
        return self._base_pos.copy(), self._base_rot.copy()

    def link_in_base(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """Measured pose of a robot link in the base frame: (rot 3x3, pos 3)."""
        if link == self.robot.base_link:
            return np.eye(3), np.zeros(3)
        if link in self._above_base:
            rot, pos = self._above_base[link]
            return rot.copy(), pos.copy()
        if self.robot.tcp is not None and link == self.robot.tcp.name:
            p, r = self._tool_world()
        else:
            p, q = self.engine.link_pose(link)
            r = quat_to_matrix(q)
        rt = self._base_rot.T
        return rt @ r, rt @ (p - self._base_pos)

    # ----------------------------------------------------------------- helpers
    def _check_open(self) -> None:
        if self._closed:
            raise SimulationError("the scene is closed")

    def _servo(self, target: np.ndarray, twist: np.ndarray | None) -> None:
        """Move the servo setpoints from the previous command to ``target`` along a
        smooth ramp that ends at RAMP_FRACTION of the control period, then hold.

        Stepping the setpoint (instead of jumping) lets the joints arrive at the
        target nearly at rest by the end of the period, so a Cartesian delta
        moves the end effector by the commanded distance in every direction.
        A kinematic base advances along ``twist`` chunk by chunk, teleporting the root.
        """
        eng = self.engine
        start = self._q_sent
        delta = target - start
        chunks = self._chunks
        for k in range(1, len(chunks) + 1):
            s = self._ramp[k - 1]
            eng.set_joint_targets(start + s * delta if s < 1.0 else target)
            if twist is not None:
                self._kbase.advance(twist, chunks[k - 1] * eng.timestep)
                self._place_base()
            eng.step(chunks[k - 1])
        self._q_sent = target.copy()

    def _place_base(self) -> None:
        x, y, yaw = self._kbase.pose
        self._base_pos = np.array([x, y, self._base_pos[2]])
        self._base_rot = quat_to_matrix(yaw_quat(yaw))
        self._base_turned = yaw != 0.0
        self.engine.set_root_pose(self._base_pos, yaw_quat(yaw))

    def _observe(self, request: ObsRequest) -> Observation:
        """The observation keys ``self.spec.observation`` declares, narrowed by ``request``."""
        eng = self.engine
        q = eng.joint_positions()
        pos, rot = self.eef_pose_base()
        self._eef = eef = pos.tolist(), rot.tolist()  # for the task's state and the next step's Cartesian arm
        state = np.empty(self._state_dim, dtype=np.float32)
        self.task.state(*eef, q[self._grip_sel], state, self._rot_reference)
        images = {}
        self._frame = None
        if self.options.render_images:
            for name, key in self._rgb:
                if request.wants_image(key):
                    images[key] = eng.render_rgb(name)
            if self._rgb and self._rgb[0][1] in images:
                self._frame = images[self._rgb[0][1]]
        if self._eidx_whole:
            qpos, qvel = q.astype(np.float32), eng.joint_velocities().astype(np.float32)
        else:
            n = len(self.robot.joints)
            qpos, qvel = np.empty(n, dtype=np.float32), np.empty(n, dtype=np.float32)
            qpos[self._eidx] = q
            qvel[self._eidx] = eng.joint_velocities()
        obs: Observation = {
            OBS_IMAGES: images,
            OBS_STATE: state,
            OBS_TASK: self._spec.task.instruction,
            OBS_JOINT_POSITIONS: qpos,
            OBS_JOINT_VELOCITIES: qvel,
            OBS_SIM_TIME_NS: self.sim_time_ns(),
        }
        if self._kbase is not None:
            qpos[self._bidx] = self._kbase.pose
            qvel[self._bidx] = self._kbase.velocity
            obs[OBS_BASE_POSE] = self._kbase.pose.astype(np.float32)
        if self._lidar is not None:
            obs[OBS_SCAN] = self._lidar.scan(eng, self._base_rot, self._base_pos,
                                             *self.link_in_base(self._lidar.sensor.parent))
        if self._depth and self.options.render_images and request.depth:
            obs[OBS_DEPTH_POINTS] = {
                d.sensor.name: d.points(eng.render_depth(d.sensor.name), *self.link_in_base(d.sensor.parent))
                for d in self._depth}
        if request.link_poses:
            poses = {}
            for link in self._spec.robot.links:
                rot_l, pos_l = self.link_in_base(link.name)
                poses[link.name] = np.concatenate([pos_l, matrix_to_quat(rot_l)]).astype(np.float32)
            obs[OBS_LINK_POSES] = poses
        if self.options.privileged or self.options.environment_state:
            objects = self.task.object_poses(self)
            if self.options.environment_state:
                obs[OBS_ENV_STATE] = self.task.environment_state(objects)
            if self.options.privileged:
                obs[OBS_PRIVILEGED] = {"eef_pose": np.concatenate([pos, matrix_to_quat(rot)]), "objects": objects}
        return obs
