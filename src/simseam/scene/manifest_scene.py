"""ManifestScene: one robot (from a RobotSpec) in one layout, on any engine.

It implements the ``SimRollout`` seam. Everything that gives an action its
meaning lives here, computed the same way whatever the engine:

- JOINT_POSITION: absolute arm joint targets, clipped to the joint limits.
- CARTESIAN_DELTA: ``[dx, dy, dz, dax, day, daz]`` in [-1, 1] times the
  robot's max step (m, rad), in the robot base frame; the rotation delta is
  applied on the left (robosuite OSC_POSE / LIBERO). The delta is added to
  the previous end-effector target while the arm tracks its last command
  (within 1.5 cm / 0.1 rad), else to the measured pose (blocked or
  disturbed: no wind-up), so
  free-space motion covers exactly the commanded distance and a zero action
  holds the pose. Damped least squares IK on the arm joints (one Newton step
  per control step, warm-started), within joint limits. Joint setpoints ramp
  smoothly to the new targets over the first 60% of the control period.
- Arm joint targets never leave the joint limits, nor move faster than the
  URDF's joint velocity limits.
- Gripper: -1 fully open, +1 fully closed, linear in between, mapped to the
  manifest's open/closed finger positions.

Only the sensors the manifest declares are created, and images are rendered
only when observed. Importable with numpy alone (no pydantic).
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np

from simseam.engines.base import CameraModel, Engine, EngineOptions, RobotModel, Shape
from simseam.math3d import (
    axis_angle_to_matrix,
    matrix_to_axis_angle,
    matrix_to_quat,
    quat_to_matrix,
    rotation_error,
    rpy_to_quat,
    yaw_quat,
)
from simseam.robot.assets import resolve_asset
from simseam.robot.spec import RobotSpec
from simseam.robot.urdf import read_urdf
from simseam.scene.actions import ActionLayout
from simseam.scene.base_motion import KinematicBase
from simseam.scene.sensors import DepthCloud, Lidar2D
from simseam.scene.kinematics import SerialChain
from simseam.scene.layouts.base import get_layout
from simseam.seam import (
    ConfigError,
    ControlMode,
    Observation,
    SceneInfo,
    SimulationError,
    StepResult,
    TaskInfo,
    check_action,
)

RAMP_CHUNKS = 3  # servo setpoint updates per control step
RAMP_FRACTION = 0.6  # the setpoint reaches the new target at this fraction of the control period
REANCHOR_POS = 0.015  # m: tracking error beyond which a Cartesian delta restarts from the measured pose
REANCHOR_ROT = 0.1  # rad
SETTLE_S = 0.1  # physics time after placing props, before the first observation


@dataclass(frozen=True)
class SceneOptions:
    """Scene knobs. ``image_size`` (H, W) overrides every RGB sensor's size;
    ``render_images=False`` gives state-only observations (``images`` empty);
    ``privileged=True`` adds ground truth for scripted experts; ``seed`` seeds
    the stream used when ``reset(seed=None)``."""

    control_hz: float = 20.0
    image_size: tuple[int, int] | None = None
    max_steps: int | None = None
    control_mode: str | None = None
    render_images: bool = True
    privileged: bool = False
    render_quality: str = "lean"
    timestep: float = 0.002
    ik_iters: int = 1
    seed: int = 0


class ManifestScene:
    """A ``SimRollout`` built from a ``RobotSpec`` and a layout name."""

    def __init__(self, spec: RobotSpec, layout: str, engine: Engine | str = "mujoco",
                 options: SceneOptions | None = None):
        self.spec = spec
        self.options = opts = options or SceneOptions()
        if opts.control_hz <= 0 or opts.timestep <= 0:
            raise ConfigError("control_hz and timestep must be positive")
        urdf_path = str(resolve_asset(spec.urdf))
        urdf = read_urdf(urdf_path)
        if spec.kinematic_base is not None and urdf.root_link != spec.base_link:
            raise ConfigError(f"robot {spec.name!r}: a kinematic base moves the URDF root link "
                              f"{urdf.root_link!r}, so base_link must be it (got {spec.base_link!r})")
        layout_cls = get_layout(layout)

        mode = ControlMode.parse(opts.control_mode or layout_cls.control_mode or spec.action.control_mode)
        if layout_cls.control_mode and mode != ControlMode.parse(layout_cls.control_mode):
            raise ConfigError(
                f"layout {layout!r} requires control mode {layout_cls.control_mode!r}, got {mode.value!r}"
            )
        self.action_layout = ActionLayout.for_robot(spec, mode)

        # Engine joints: every manifest joint but the kinematic base ones.
        self._ejoints = [j for j in spec.joints if j.role != "base"]
        names = [j.name for j in self._ejoints]
        self._arm_idx = np.array([i for i, j in enumerate(self._ejoints) if j.role == "arm"])
        self._grip_idx = np.array([names.index(n) for n in spec.gripper.joints] if spec.gripper else [], dtype=int)
        lo = np.array([-np.inf if j.lower is None else j.lower for j in self._ejoints])
        hi = np.array([np.inf if j.upper is None else j.upper for j in self._ejoints])
        self._lower, self._upper = lo, hi
        self._home = np.clip(np.array([j.home for j in self._ejoints]), lo, hi)
        vmax = np.array([np.inf if j.max_velocity is None else j.max_velocity for j in self._ejoints])
        self._max_step = vmax[self._arm_idx] / opts.control_hz
        if spec.gripper:
            self._grip_open = np.asarray(spec.gripper.open, dtype=np.float64)
            self._grip_closed = np.asarray(spec.gripper.closed, dtype=np.float64)
        arm_lo = np.where(np.isfinite(lo[self._arm_idx]), lo[self._arm_idx], -2 * np.pi)
        arm_hi = np.where(np.isfinite(hi[self._arm_idx]), hi[self._arm_idx], 2 * np.pi)
        self.chain = SerialChain(urdf, spec.base_link, spec.ee_link,
                                 [self._ejoints[i].sim_name for i in self._arm_idx], arm_lo, arm_hi)
        self._rot_weight = 0.5
        self.layout = layout_cls(spec, self.chain.tabletop_reach())
        self.layout.check_robot()

        base_pos, base_yaw = self.layout.robot_base()
        self._base_pos = np.asarray(base_pos, dtype=np.float64)
        self._base_rot = quat_to_matrix(yaw_quat(base_yaw))
        self._base_start = (float(base_pos[0]), float(base_pos[1]), float(base_yaw))

        # Manifest order <-> engine joints; the kinematic base supplies the base joints.
        manifest = [j.name for j in spec.joints]
        self._eidx = np.array([manifest.index(j.name) for j in self._ejoints])
        self._kbase = None
        link_shapes = {}
        if spec.kinematic_base is not None:
            kb = spec.kinematic_base
            self._kbase = KinematicBase(kb)
            self._bidx = np.array([manifest.index(n) for n in kb.joints])
            link_shapes[spec.base_link] = [
                Shape(sh["kind"], tuple(sh["size"]), pos=tuple(sh["pos"]), rgba=tuple(sh["rgba"])) for sh in kb.shapes]
        lidars = spec.sensors_of("lidar_2d")
        if len(lidars) > 1:
            raise ConfigError(f"robot {spec.name!r} declares {len(lidars)} lidar_2d sensors; "
                              "the observation's 'scan' holds one")
        self._lidar = Lidar2D(lidars[0]) if lidars else None

        if isinstance(engine, str):
            from simseam.engines.registry import make_engine

            engine = make_engine(engine, EngineOptions(timestep=opts.timestep, render_quality=opts.render_quality))
        self.engine = engine
        engine.load_robot(
            RobotModel(
                urdf_path=urdf_path,
                joints=[j.sim_name for j in self._ejoints],
                kp=[j.kp for j in self._ejoints],
                kd=[j.kd for j in self._ejoints],
                base_pos=tuple(self._base_pos),
                base_quat=tuple(yaw_quat(base_yaw)),
                fixed_base=True,
                inertia_from_geometry=spec.inertia == "geometry",
                link_shapes=link_shapes,
            )
        )
        self.layout.build(engine)
        size = opts.image_size or self.layout.image_size
        self._rgb = []  # (sensor name, feature key)
        self._depth: list[DepthCloud] = []
        cameras = {}
        for s in spec.sensors:
            if s.kind not in ("rgb", "depth"):
                continue  # lidar_2d and friends are handled by ray casts, not cameras
            h, w = size if (size and s.kind == "rgb") else (s.height, s.width)
            engine.add_camera(CameraModel(s.name, s.parent, tuple(s.xyz), tuple(rpy_to_quat(s.rpy)), w, h, s.fovy_deg,
                                          near=s.range_min or 0.01, far=s.range_max or 10.0))
            if s.kind == "rgb":
                self._rgb.append((s.name, s.feature_key))
                cameras[s.feature_key] = (h, w)
            else:
                self._depth.append(DepthCloud(s, w, h))
        engine.build()
        self._substeps = max(1, int(round(1.0 / (opts.control_hz * engine.timestep))))
        n_chunks = min(RAMP_CHUNKS, self._substeps)
        self._chunks = np.diff(np.linspace(0, self._substeps, n_chunks + 1).round().astype(int)).tolist()
        t = np.cumsum(self._chunks) / self._substeps / RAMP_FRACTION
        self._ramp = np.where(t >= 1.0, 1.0, t * t * (3.0 - 2.0 * t)).tolist()  # smoothstep

        self._scene_info = SceneInfo(
            robot=spec.name,
            engine=engine.name,
            layout=layout,
            control_mode=mode,
            action_dim=self.action_layout.dim,
            state_dim=6 + len(self._grip_idx),
            control_hz=opts.control_hz,
            cameras=cameras if opts.render_images else {},
            joint_names=tuple(spec.joint_names),
            action_names=self.action_layout.names,
            action_scale=(spec.action.max_translation, spec.action.max_rotation),
        )
        self._task = TaskInfo(layout=layout, instruction=self.layout.instruction,
                              max_steps=opts.max_steps or self.layout.max_steps)
        self._seed_stream = np.random.default_rng(opts.seed)
        self._episode_ready = False
        self._closed = False
        self._frame: np.ndarray | None = None

    # ------------------------------------------------------------------ seam
    @property
    def action_dim(self) -> int:
        return self.action_layout.dim

    @property
    def scene(self) -> SceneInfo:
        return self._scene_info

    @property
    def task(self) -> TaskInfo:
        return self._task

    def reset(self, seed: int | None = None) -> Observation:
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
        self.layout.reset(eng, rng)
        eng.step(max(1, int(round(SETTLE_S / eng.timestep))))
        self._t0 = eng.sim_time()
        self._q_target = self._home.copy()
        self._q_sent = self._home.copy()
        self._ref: tuple[np.ndarray, np.ndarray] | None = None
        self._steps = 0
        self._episode_ready = True
        self.last_ik = None
        return self._observe()

    def step(self, action: np.ndarray) -> StepResult:
        self._check_open()
        if not self._episode_ready:
            raise SimulationError("step() called before reset() (or after the episode ended and was not reset)")
        a = check_action(action, self.action_dim)
        arm, grip, base = self.action_layout.unpack(a)
        twist = self._kbase.clip(base) if base is not None else None
        target = self._q_target
        previous = target[self._arm_idx]
        if self.action_layout.control_mode == ControlMode.JOINT_POSITION:
            q_arm = np.clip(arm, self._lower[self._arm_idx], self._upper[self._arm_idx])
        else:
            q_arm = self._cartesian_target(np.clip(arm, -1.0, 1.0))
        # Joint velocity limits: a target moves at most max_velocity * control period per step.
        target[self._arm_idx] = np.clip(q_arm, previous - self._max_step, previous + self._max_step)
        if grip is not None:
            g = (min(max(grip, -1.0), 1.0) + 1.0) * 0.5
            target[self._grip_idx] = self._grip_open + g * (self._grip_closed - self._grip_open)
        self._servo(target, twist)
        self._steps += 1
        obs = self._observe()
        reward, success = self.layout.evaluate(self)
        truncated = self._steps >= self._task.max_steps and not success
        info = {self._task.success_key: success, "steps": self._steps}
        return StepResult(obs, float(reward), bool(success), bool(truncated), info)

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

    # --------------------------------------------------------------- helpers
    def _check_open(self) -> None:
        if self._closed:
            raise SimulationError("the scene is closed")

    def eef_pose_base(self) -> tuple[np.ndarray, np.ndarray]:
        """Measured end-effector pose in the robot base frame: (pos[3], rot[3x3])."""
        p, q = self.engine.link_pose(self.spec.ee_link)
        rt = self._base_rot.T
        return rt @ (p - self._base_pos), rt @ quat_to_matrix(q)

    def to_base(self, pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
        """World pose -> base-frame [x, y, z, qw, qx, qy, qz]."""
        rt = self._base_rot.T
        return np.concatenate([rt @ (pos - self._base_pos), matrix_to_quat(rt @ quat_to_matrix(quat))])

    def _servo(self, target: np.ndarray, twist: np.ndarray | None = None) -> None:
        """Move the servo setpoints from the previous command to ``target`` along a
        smooth ramp that ends at RAMP_FRACTION of the control period, then hold.

        Stepping the setpoint (instead of jumping) lets the joints arrive at the
        target nearly at rest by the end of the period, so a Cartesian delta
        moves the end effector by the commanded distance in every direction.
        A kinematic base advances along ``twist`` chunk by chunk, teleporting the root.
        """
        eng = self.engine
        start = self._q_sent
        chunks = self._chunks
        for k in range(1, len(chunks) + 1):
            s = self._ramp[k - 1]
            eng.set_joint_targets(start + s * (target - start) if s < 1.0 else target)
            if twist is not None:
                self._kbase.advance(twist, chunks[k - 1] * eng.timestep)
                self._place_base()
            eng.step(chunks[k - 1])
        self._q_sent = target.copy()

    def _place_base(self) -> None:
        x, y, yaw = self._kbase.pose
        self._base_pos = np.array([x, y, self._base_pos[2]])
        self._base_rot = quat_to_matrix(yaw_quat(yaw))
        self.engine.set_root_pose(self._base_pos, yaw_quat(yaw))

    def base_pose(self) -> np.ndarray:
        """[x, y, yaw] of the base link in the world."""
        if self._kbase is not None:
            return self._kbase.pose.copy()
        r = self._base_rot
        return np.array([self._base_pos[0], self._base_pos[1], math.atan2(r[1, 0], r[0, 0])])

    def link_in_base(self, link: str) -> tuple[np.ndarray, np.ndarray]:
        """Measured pose of a robot link in the base frame: (rot 3x3, pos 3)."""
        if link == self.spec.base_link:
            return np.eye(3), np.zeros(3)
        p, q = self.engine.link_pose(link)
        rt = self._base_rot.T
        return rt @ quat_to_matrix(q), rt @ (p - self._base_pos)

    def _cartesian_target(self, arm: np.ndarray) -> np.ndarray:
        act = self.spec.action
        pos, rot = self._eef  # measured at the last observation; nothing moved since
        seed = self._q_target[self._arm_idx]
        fk = self.chain.forward(seed)  # the pose the last command asked for (reachable by construction)
        ref = self._ref
        if ref is None or (np.linalg.norm(fk[0][:3, 3] - pos) > REANCHOR_POS
                           or np.linalg.norm(rotation_error(fk[0][:3, :3], rot)) > REANCHOR_ROT):
            ref = (pos, rot)  # first step, blocked or disturbed: restart from the measured pose (no wind-up)
        tgt_pos = ref[0] + arm[:3] * act.max_translation
        tgt_rot = axis_angle_to_matrix(arm[3:6] * act.max_rotation) @ ref[1]
        ik = self.chain.solve(seed, tgt_pos, tgt_rot, max_iters=self.options.ik_iters, rot_weight=self._rot_weight,
                              q_rest=self._home[self._arm_idx], start_fk=fk)
        self.last_ik = ik
        self._ref = (tgt_pos, tgt_rot)
        return ik.q

    def _observe(self) -> Observation:
        eng = self.engine
        q = eng.joint_positions()
        self._eef = pos, rot = self.eef_pose_base()
        state = np.empty(self._scene_info.state_dim, dtype=np.float32)
        state[:3] = pos
        state[3:6] = matrix_to_axis_angle(rot)
        state[6:] = q[self._grip_idx]
        images = {}
        self._frame = None
        if self.options.render_images:
            for name, key in self._rgb:
                images[key] = eng.render_rgb(name)
            if self._rgb:
                self._frame = images[self._rgb[0][1]]
        n = len(self.spec.joints)
        qpos, qvel = np.empty(n, dtype=np.float32), np.empty(n, dtype=np.float32)
        qpos[self._eidx] = q
        qvel[self._eidx] = eng.joint_velocities()
        obs: Observation = {
            "images": images,
            "state": state,
            "task": self._task.instruction,
            "joint_positions": qpos,
            "joint_velocities": qvel,
            "sim_time_ns": self.sim_time_ns(),
        }
        if self._kbase is not None:
            qpos[self._bidx] = self._kbase.pose
            qvel[self._bidx] = self._kbase.velocity
            obs["base_pose"] = self._kbase.pose.astype(np.float32)
        if self._lidar is not None:
            obs["scan"] = self._lidar.scan(eng, self._base_rot, self._base_pos,
                                           *self.link_in_base(self._lidar.sensor.parent))
        if self._depth and self.options.render_images:
            obs["depth_points"] = {
                d.sensor.name: d.points(eng.render_depth(d.sensor.name), *self.link_in_base(d.sensor.parent))
                for d in self._depth}
        if self.options.privileged:
            obs["privileged"] = {
                "eef_pose": np.concatenate([pos, matrix_to_quat(rot)]),
                "objects": {**{n: self.to_base(*eng.object_pose(n)) for n in self.layout.tracked_objects},
                            **self.layout.privileged(self)},
            }
        return obs
