"""BatchedScene: N worlds of one manifest scene in one process, on MuJoCo Warp.

The semantics come from the scene itself: a host ``ManifestScene`` on the CPU MuJoCo engine is
built from the same robot, task and options, and provides

- the compiled ``MjModel`` (the very model the CPU engine steps, put on the device once),
- the ``RolloutSpec`` (action slots and bounds from the same controllers; ``engine`` says
  ``mujoco_warp``),
- what it compiled, through public views only: ``host.plan`` (``ScenePlan``: substeps and the
  servo ramp, joints, arm and gripper indices, home, tool frame, state names, cameras),
  ``host.engine.layout`` (``ModelLayout``: qpos/qvel addresses, actuators, object bodies, geom
  owners), ``host.chain.arrays`` (``ChainArrays``: the IK chain's constants), ``host.base_frame()``,
  the controllers' gains and the tasks' constants (module constants),
- each world's reset state: ``reset`` runs the host scene's own reset for the world's seed (the
  task's randomisation and the 0.1 s settle, on the CPU) and copies the settled state into that
  world's row. A reset therefore starts from exactly the CPU engine's state.

Everything per step runs batched on the device: action clipping, the Cartesian IK and the
controllers (``kernels.make_arm_kernel``), the servo ramp, ``substeps`` MuJoCo Warp steps, the robot's
observation (``kernels.make_observe_kernel``) and the cameras (MuJoCo Warp's batched ray tracer). On a
CUDA device one control step is one captured CUDA graph. The task is the scene's own task, written
once (``simseam.scene.tasks.batch``): its draws for each world's seed place the props at reset, and its
``evaluate_batch`` judges every world after each step, on views of the device state
(``task_state.WarpTaskState``: NumPy on Warp's CPU device, CuPy on CUDA). Nothing here names a task.

Supported: any task, on fixed-base arms (CARTESIAN_DELTA with >= 3 arm joints, or JOINT_POSITION with
any) with RGB cameras. Kinematic bases, lidars and depth sensors are refused with a ``ConfigError``.
"""

from __future__ import annotations

import dataclasses
import time
from dataclasses import dataclass

import numpy as np

from simseam.seam import (
    STATE_ONLY,
    BackendUnavailableError,
    ConfigError,
    ControlMode,
    InvalidActionError,
    RolloutSpec,
    SimulationError,
)

try:
    import mujoco_warp as mjw
    import warp as wp
except ImportError as exc:  # pragma: no cover - exercised only without the packages
    raise BackendUnavailableError(
        f"the mujoco_warp engine needs the 'mujoco-warp' and 'warp-lang' packages "
        f"(pip install 'simseam[warp]'): {exc}") from None

from simseam.engines.mujoco_warp import kernels as K
from simseam.engines.mujoco_warp.graphs import CudaGraphs
from simseam.engines.mujoco_warp.memory import put_worlds
from simseam.scene.warp.task_state import WarpTaskState, array_module, array_stream

DEFAULT_NCONMAX = 96  # contacts per world (allocated for the whole batch)
DEFAULT_NJMAX = 600  # constraint rows per world


@dataclass(frozen=True)
class WarpOptions:
    """``device``: a warp device (``cuda:0``, ``cpu``; default: warp's preferred one);
    ``nconmax`` / ``njmax``: contacts / constraint rows allocated per world;
    ``graph``: capture each control step as a CUDA graph (CUDA only); ``fast_reset``: reset worlds
    from the settled template when it is verified to equal the CPU reset (else settle on the CPU)."""

    device: str | None = None
    nconmax: int = DEFAULT_NCONMAX
    njmax: int = DEFAULT_NJMAX
    graph: bool = True
    fast_reset: bool = True


@dataclass
class BatchStep:
    """The result of one batched step, on the host (numpy, one row per world)."""

    reward: np.ndarray  # float32[N]
    terminated: np.ndarray  # bool[N]: success
    truncated: np.ndarray  # bool[N]: the step limit, without success
    success: np.ndarray  # bool[N]
    steps: np.ndarray  # int64[N]: control steps of each world's episode


def _check_batched_task(task) -> None:
    """A task written for one world only (its own ``reset`` / ``evaluate``, no ``sample`` /
    ``evaluate_batch``) cannot run on N worlds: a ``ConfigError`` saying what to write."""
    from simseam.scene.tasks.base import Task

    cls = type(task)
    missing = [name for name, one in (("evaluate_batch", "evaluate"), ("sample", "reset"))
               if getattr(cls, name) is getattr(Task, name) and getattr(cls, one) is not getattr(Task, one)]
    if cls.evaluate_batch is Task.evaluate_batch and "evaluate_batch" not in missing:
        missing.append("evaluate_batch")
    if missing:
        raise ConfigError(f"engine 'mujoco_warp': task {task.name!r} is written for one world only; write its "
                          f"{' and '.join(missing)} (docs/extending.md, a task on both engines)")


class BatchedScene:
    """``num_envs`` worlds of ``task`` with ``robot`` (see the module docstring)."""

    def __init__(self, robot, task: str, num_envs: int, options=None, warp_options: WarpOptions | None = None):
        from simseam.scene.manifest_scene import ManifestScene, SceneOptions

        if int(num_envs) < 1:
            raise ConfigError(f"engine 'mujoco_warp': num_envs must be >= 1, got {num_envs}")
        self.num_envs = n = int(num_envs)
        self.options = options = options or SceneOptions()
        self.wopts = wopts = warp_options or WarpOptions()
        if robot.kinematic_base is not None:
            raise ConfigError(f"engine 'mujoco_warp': robot {robot.name!r} has a kinematic base (not supported)")
        if any(s.kind in ("lidar_2d", "depth") for s in robot.sensors):
            raise ConfigError(f"engine 'mujoco_warp': robot {robot.name!r} declares lidar or depth sensors "
                              "(only RGB cameras are supported)")
        # the reference scene on the CPU engine: semantics, model, and every reset state
        self.host = host = ManifestScene(robot, task, "mujoco", options)
        _check_batched_task(host.task)
        spec = host.spec
        self._spec = dataclasses.replace(spec, engine="mujoco_warp")
        mode = spec.action.control_mode
        self._cartesian = mode == ControlMode.CARTESIAN_DELTA
        plan = host.plan
        n_arm = len(plan.arm_idx)
        if self._cartesian and n_arm < 3:
            raise ConfigError(f"engine 'mujoco_warp': Cartesian control needs >= 3 arm joints; robot "
                              f"{robot.name!r} has {n_arm} (use control_mode: joint_position)")
        mjm = host.engine.model
        self.mjm = mjm
        self.substeps = plan.substeps
        self._chunks = list(plan.chunks)
        self._ramp = list(plan.ramp)
        self.max_steps = spec.task.max_steps

        self._template = None
        if wopts.fast_reset:
            self._template = self._make_template()
        wp.config.quiet = True
        wp.init()
        self.device = wp.get_device(wopts.device) if wopts.device else wp.get_preferred_device()
        t0 = time.perf_counter()
        host.reset(0, STATE_ONLY)
        self.xp = array_module(self.device)
        self.m, self.d = put_worlds(mjm, host.engine.data, n, self.device, f"{robot.name} {task} on MuJoCo Warp",
                                    nconmax=wopts.nconmax, njmax=wopts.njmax)
        with wp.ScopedDevice(self.device):
            self._make_buffers(host, mjm)
            self._make_cameras(host, mjm)
            with array_stream(self.xp, self.device):
                self.task_state = WarpTaskState(self)
                self._make_params()
        self._eval = None
        self.build_s = time.perf_counter() - t0
        self._graphs = CudaGraphs(self.device, wopts.graph)  # the step, the reset's sensing, the cameras
        self.steps = np.zeros(n, dtype=np.int64)
        self.seeds = np.full(n, -1, dtype=np.int64)
        self._host_obs: dict | None = None
        self._closed = False

    # ------------------------------------------------------------------------------------ construction
    def _make_buffers(self, host, mjm) -> None:
        n = self.num_envs
        ca = host.chain.arrays
        spec, plan, layout = host.spec, host.plan, host.engine.layout
        self._nej = len(plan.joints)
        self._adim = adim = spec.action.dim
        self._act_id = wp.array(layout.actuators.astype(np.int32), dtype=int)
        self._arm_idx = wp.array(plan.arm_idx.astype(np.int32), dtype=int)
        self._grip_idx = wp.array(plan.grip_idx.astype(np.int32), dtype=int)
        self._home = plan.home.astype(np.float32)
        self.target = wp.array(np.tile(self._home, (n, 1)), dtype=float)
        self.q_sent = wp.array(np.tile(self._home, (n, 1)), dtype=float)
        self.action = wp.zeros((n, adim), dtype=float)
        lo = np.array([s.low for s in spec.action.slots], dtype=np.float32)
        hi = np.array([s.high for s in spec.action.slots], dtype=np.float32)
        self._slot_lo, self._slot_hi = lo, hi
        self._lo_d, self._hi_d = wp.array(lo, dtype=float), wp.array(hi, dtype=float)
        if spec.action.norm_bounds:
            raise ConfigError("engine 'mujoco_warp': norm-bounded action slots (a kinematic base) are not supported")
        self.eef_world = wp.zeros(n, dtype=wp.vec3)
        self.eef_pos = wp.zeros(n, dtype=wp.vec3)
        self.eef_rot = wp.zeros(n, dtype=wp.mat33)
        self.ref_pos = wp.zeros(n, dtype=wp.vec3)
        self.ref_rot = wp.zeros(n, dtype=wp.mat33)
        self.ref_ok = wp.zeros(n, dtype=int)
        self._active = wp.ones(n, dtype=int)  # every world's servo runs (idle worlds hold their targets)
        # chain constants (SerialChain), in chain order
        self._chain_q = wp.array(ca.q_index.astype(np.int32), dtype=int)
        self._fixed = wp.array(ca.fixed.astype(np.float32), dtype=wp.mat44)
        self._axes = wp.array(ca.axes.astype(np.float32), dtype=wp.vec3)
        self._prism = wp.array(ca.prismatic.astype(np.int32), dtype=int)
        self._tail = wp.mat44(*ca.tail.astype(np.float32).reshape(-1).tolist())
        self._lower = wp.array(ca.lower.astype(np.float32), dtype=float)
        self._upper = wp.array(ca.upper.astype(np.float32), dtype=float)
        self._max_step = wp.array(np.minimum(plan.arm_max_step, 1e6).astype(np.float32), dtype=float)
        self._q_home = wp.array(self._home[plan.arm_idx], dtype=float)
        self._grip_open = wp.array(plan.grip_open.astype(np.float32), dtype=float)
        self._grip_closed = wp.array(plan.grip_closed.astype(np.float32), dtype=float)
        names = [s.name for s in spec.action.slots]
        self._grip_slot = names.index("grip") if "grip" in names else -1
        n_chain = len(ca.q_index)
        self._arm_kernel = K.make_arm_kernel(n_chain, self._cartesian, n_chain > 6, bool(ca.prismatic.any()))
        self._max_t, self._max_r = plan.max_translation, plan.max_rotation
        # observation constants
        from simseam.scene.controllers.arm import REANCHOR_POS, REANCHOR_ROT, ROT_WEIGHT

        self._reanchor = (REANCHOR_POS, REANCHOR_ROT, ROT_WEIGHT)
        robot = host.robot
        self._tool_body = int(mjm.body(plan.tool_link).id)
        base_pos, base_rot = host.base_frame()
        self._tool_pos = wp.vec3(*plan.tool_pos.astype(np.float32).tolist())
        self._tool_rot = wp.mat33(*plan.tool_rot.astype(np.float32).reshape(-1).tolist())
        self._base_pos = wp.vec3(*base_pos.astype(np.float32).tolist())
        self._base_rot = wp.mat33(*base_rot.astype(np.float32).reshape(-1).tolist())
        self._rot_reference = wp.vec4(*plan.rot_reference.astype(np.float32).tolist())
        manifest = robot.joint_names
        qadr = np.zeros(len(manifest), dtype=np.int32)
        vadr = np.zeros(len(manifest), dtype=np.int32)
        qadr[plan.joint_index] = layout.joint_qadr
        vadr[plan.joint_index] = layout.joint_vadr
        self._jqadr, self._jvadr = wp.array(qadr, dtype=int), wp.array(vadr, dtype=int)
        self._gqadr = wp.array(layout.joint_qadr[plan.grip_idx].astype(np.int32), dtype=int)
        ns = len(plan.state_names)
        self.state = wp.zeros((n, ns), dtype=float)
        self.joint_pos = wp.zeros((n, len(manifest)), dtype=float)
        self.joint_vel = wp.zeros((n, len(manifest)), dtype=float)
        self.eef_pose = wp.zeros((n, 7), dtype=float)
        self._observe_kernel = K.make_observe_kernel(ns - 6)
        self.geom_owner = wp.array(np.asarray(layout.geom_owner, dtype=np.int32), dtype=int)

    def _make_params(self) -> None:
        """Each world's row of the task's params (``Draw.params``), on the device; shapes from one draw."""
        xp = self.xp
        for key, value in self._draw(0).params.items():
            v = np.asarray(value)  # its own dtype: a float64 target stays exact in privileged['objects']
            self.task_state.params[key] = xp.zeros((self.num_envs, *v.shape), dtype=v.dtype)

    def _make_cameras(self, host, mjm) -> None:
        self.cameras: dict[str, tuple[int, int]] = {}  # feature key -> (H, W)
        self.images: dict[str, wp.array] = {}
        self.rc = self.camera_renderer = None
        cams = host.plan.cameras
        if not (self.options.render_images and cams):
            return
        from simseam.engines.mujoco.engine import GROUP_ROBOT_VISUAL, GROUP_WORLD
        from simseam.engines.mujoco_warp.cameras import WarpCameras

        self.camera_renderer = WarpCameras(mjm, self.num_envs, [(f"cam:{name}", key, hw) for name, key, hw in cams],
                                           device=self.device, groups=(GROUP_WORLD, GROUP_ROBOT_VISUAL),
                                           use_textures=True, background_color=(0.0, 0.0, 0.0, 1.0))
        self.cameras, self.images, self.rc = (self.camera_renderer.sizes, self.camera_renderer.images,
                                              self.camera_renderer.rc)

    # ---------------------------------------------------------------------------------------- resets
    def _draw(self, seed: int):
        """The task's draws for an episode of ``seed`` (``Task.sample`` on the episode's generator)."""
        return self.host.task.sample(np.random.default_rng(int(seed)))

    def _make_template(self):
        """The settled reset state as a template: the settle (0.1 s of physics after placing the props)
        moves nothing that depends on where the task placed them (a cube on a flat table drops by the
        same few micrometres wherever it stands, the robot starts at home). Verified here against the
        CPU scene's real reset for two seeds; when it does not hold, resets settle on the CPU."""
        host = self.host
        layout, data = host.engine.layout, host.engine.data
        names = list(self._draw(0).poses)
        adr = {n: (layout.object_qadr[n], layout.object_vadr[n]) for n in names}
        host.reset(0, STATE_ONLY)
        placed0 = self._draw(0).poses
        base = (data.qpos.copy(), data.qvel.copy(), data.ctrl.copy(), data.qacc_warmstart.copy())
        drop = {n: base[0][a:a + 3] - placed0[n][0] for n, (a, _) in adr.items()}
        template = (base, adr, drop)
        for seed in (1, 2):
            host.reset(seed, STATE_ONLY)
            got = self._template_state(seed, template)
            ok = (np.abs(got[0] - data.qpos).max() < 1e-9 and np.abs(got[1] - data.qvel).max() < 1e-9
                  and np.abs(got[3] - data.qacc_warmstart).max() < 1e-6)
            if not ok:
                return None
        return template

    def _template_state(self, seed: int, template=None, draw=None):
        (qpos, qvel, ctrl, warm), adr, drop = template or self._template
        q = qpos.copy()
        for name, (pos, quat) in (draw or self._draw(seed)).poses.items():
            a = adr[name][0]
            q[a:a + 3] = pos + drop[name]
            q[a + 3:a + 7] = quat
        return q, qvel, ctrl, warm

    def _set_params(self, worlds: np.ndarray, draws: list) -> None:
        """The reset worlds' rows of the task's params, from their draws."""
        xp, params = self.xp, self.task_state.params
        rows = xp.asarray(worlds)
        for key, arr in params.items():
            arr[rows] = xp.asarray(np.stack([np.asarray(d.params[key]) for d in draws]), dtype=arr.dtype)

    # ---------------------------------------------------------------------------------------- spec
    @property
    def spec(self) -> RolloutSpec:
        return self._spec

    @property
    def action_dim(self) -> int:
        return self._adim

    # ---------------------------------------------------------------------------------------- reset
    def reset(self, worlds, seeds) -> None:
        """Start a new episode in each of ``worlds`` with its seed (same order). Each world's state
        is the CPU scene's settled reset state for that seed. The others are untouched."""
        self._check_open()
        worlds = np.asarray(worlds, dtype=np.int64).reshape(-1)
        seeds = np.asarray(seeds, dtype=np.int64).reshape(-1)
        if worlds.shape != seeds.shape:
            raise ConfigError(f"reset: {worlds.size} worlds but {seeds.size} seeds")
        if worlds.size == 0:
            return
        if worlds.min() < 0 or worlds.max() >= self.num_envs or len(set(worlds.tolist())) != worlds.size:
            raise ConfigError(f"reset: world indices must be distinct and in [0, {self.num_envs}), got {worlds}")
        host, mjm = self.host, self.mjm
        data = host.engine.data
        k = worlds.size
        qpos = np.empty((k, mjm.nq), np.float32)
        qvel = np.empty((k, mjm.nv), np.float32)
        ctrl = np.empty((k, mjm.nu), np.float32)
        warm = np.empty((k, mjm.nv), np.float32)
        draws = [self._draw(seed) for seed in seeds.tolist()]
        for r, seed in enumerate(seeds.tolist()):
            if self._template is not None:  # the task's draws on the settled template (checked at build)
                qpos[r], qvel[r], ctrl[r], warm[r] = self._template_state(int(seed), draw=draws[r])
            else:  # the CPU scene's reset: randomisation + settle
                host.reset(int(seed), STATE_ONLY)
                qpos[r], qvel[r], ctrl[r], warm[r] = data.qpos, data.qvel, data.ctrl, data.qacc_warmstart
        with wp.ScopedDevice(self.device):
            rows = wp.array(worlds.astype(np.int32), dtype=int)
            d = self.d
            for src, dst in ((qpos, d.qpos), (qvel, d.qvel), (ctrl, d.ctrl), (warm, d.qacc_warmstart)):
                if src.shape[1]:
                    wp.launch(K.scatter_rows_kernel, dim=src.shape, inputs=[wp.array(src, dtype=float), rows, dst])
            home = np.tile(self._home, (k, 1))
            for dst in (self.target, self.q_sent):
                wp.launch(K.scatter_rows_kernel, dim=home.shape, inputs=[wp.array(home, dtype=float), rows, dst])
            wp.launch(K.reset_ref_kernel, dim=k, inputs=[rows, self.ref_ok])
            with array_stream(self.xp, self.device):
                self._set_params(worlds, draws)
            self._launch("sense", self._sense)  # sensing after a reset: one graph too
            self.task_state.new_step()
        self.steps[worlds] = 0
        self.seeds[worlds] = seeds
        self._host_obs = None

    def set_state(self, worlds, qpos, qvel) -> None:
        """Put each of ``worlds`` in a given physics state (float[k, nq], float[k, nv]: e.g. the CPU engine's
        ``data.qpos`` / ``qvel``), its task params kept; poses, contacts and the observation follow. For
        comparing the engines on the same states (``evaluate``)."""
        self._check_open()
        worlds = np.asarray(worlds, dtype=np.int64).reshape(-1)
        qpos, qvel = np.atleast_2d(qpos).astype(np.float32), np.atleast_2d(qvel).astype(np.float32)
        if qpos.shape != (worlds.size, self.mjm.nq) or qvel.shape != (worlds.size, self.mjm.nv):
            raise ConfigError(f"set_state: {worlds.size} worlds need qpos [{worlds.size}, {self.mjm.nq}] and qvel "
                              f"[{worlds.size}, {self.mjm.nv}], got {qpos.shape} and {qvel.shape}")
        with wp.ScopedDevice(self.device):
            rows = wp.array(worlds.astype(np.int32), dtype=int)
            for src, dst in ((qpos, self.d.qpos), (qvel, self.d.qvel)):
                wp.launch(K.scatter_rows_kernel, dim=src.shape, inputs=[wp.array(src, dtype=float), rows, dst])
            self._sense()
            self.task_state.new_step()
        self._host_obs = None

    def evaluate(self) -> dict:
        """The task's judgement of every world's current state, on the host: ``reward`` float[N], ``success``
        bool[N], ``diagnostics`` (name -> [N]); what a step reports."""
        with wp.ScopedDevice(self.device), array_stream(self.xp, self.device):
            self._eval = self.host.task.evaluate_batch(self.task_state)
        self._host_obs = None
        h = self.host_arrays()
        return {"reward": self._to_host(self._eval.reward).astype(np.float32), "success": h["success"],
                "diagnostics": h["diagnostics"]}

    # ---------------------------------------------------------------------------------------- step
    def step(self, actions) -> BatchStep:
        """One control step of every world. ``actions``: float32[N, action_dim] (numpy on the host,
        or a float32 device array on the scene's device: torch tensor / warp array / anything with
        ``__dlpack__``). Host actions
        are validated (shape, finite: ``InvalidActionError`` and nothing changes); all are clipped
        to the slot bounds on the device."""
        self._check_open()
        with wp.ScopedDevice(self.device):
            self._load_actions(actions)
            self._launch("step", self._physics)
            self.task_state.new_step()
            with array_stream(self.xp, self.device):
                self._eval = self.host.task.evaluate_batch(self.task_state)
                success = self._to_host(self._eval.success).astype(bool)
                reward = self._to_host(self._eval.reward).astype(np.float32)
        self.steps += 1
        self._host_obs = None
        truncated = (self.steps >= self.max_steps) & ~success
        return BatchStep(reward, success, truncated, success, self.steps.copy())

    def _launch(self, name: str, fn) -> None:
        """Run ``fn`` (device launches only): on CUDA as one captured graph (``CudaGraphs``)."""
        self._graphs.launch(name, fn)

    def _load_actions(self, actions) -> None:
        n, adim = self.num_envs, self._adim
        if isinstance(actions, np.ndarray) or isinstance(actions, (list, tuple)):
            a = np.asarray(actions, dtype=np.float32)
            if a.shape != (n, adim):
                raise InvalidActionError(f"actions must have shape ({n}, {adim}), got {a.shape}")
            if not np.all(np.isfinite(a)):
                bad = np.flatnonzero(~np.all(np.isfinite(a), axis=1)).tolist()
                raise InvalidActionError(f"actions of worlds {bad[:8]} are not finite (NaN or inf)")
            self.action.assign(np.clip(a, self._slot_lo, self._slot_hi))
            return
        try:
            src = actions if isinstance(actions, wp.array) else wp.from_dlpack(actions)
        except (TypeError, AttributeError, RuntimeError) as exc:
            raise InvalidActionError(f"actions: a {type(actions).__name__} is not a DLPack array ({exc})") from None
        if tuple(src.shape) != (n, adim) or src.dtype != wp.float32:
            raise InvalidActionError(f"actions must be float32 of shape ({n}, {adim}), got "
                                     f"{wp.types.type_repr(src.dtype)} of shape {tuple(src.shape)}")
        if src.device != self.device:
            raise InvalidActionError(f"actions are on {src.device}, the worlds on {self.device}")
        wp.copy(self.action, src)
        wp.launch(K.clip_actions_kernel, dim=(n, adim), inputs=[self.action, self._lo_d, self._hi_d])

    def _physics(self) -> None:
        """Controllers, servo ramp, substeps, then sensing: all device launches (graph-capturable)."""
        n = self.num_envs
        rp, rr, rw = self._reanchor
        wp.launch(self._arm_kernel, dim=n, inputs=[
            self.action, self.target, self.eef_pos, self.eef_rot, self.ref_pos, self.ref_rot, self.ref_ok,
            self._arm_idx, self._chain_q, self._fixed, self._axes, self._prism, self._tail, self._lower,
            self._upper, self._max_step, self._q_home, self._grip_idx, self._grip_open, self._grip_closed,
            self._grip_slot, self._max_t, self._max_r, rw, 0.02, 0.05, rp, rr])
        for s, chunk in zip(self._ramp, self._chunks):
            wp.launch(K.servo_kernel, dim=(n, self._nej),
                      inputs=[self.q_sent, self.target, float(s), self._act_id, self._active, self.d.ctrl])
            for _ in range(chunk):
                mjw.step(self.m, self.d)
        wp.launch(K.copy_rows_kernel, dim=(n, self._nej), inputs=[self.target, self.q_sent, self._active])
        self._sense()

    def _sense(self) -> None:
        """Poses of the current state (mj_step leaves them one substep behind), contacts, the robot's observation."""
        m, d, n = self.m, self.d, self.num_envs
        mjw.kinematics(m, d)
        mjw.collision(m, d)
        wp.launch(self._observe_kernel, dim=n, inputs=[
            d.qpos, d.qvel, d.xpos, d.xmat, self._tool_body, self._tool_pos, self._tool_rot, self._base_pos,
            self._base_rot, self._rot_reference, self._jqadr, self._jvadr, self._gqadr,
            self.eef_world, self.eef_pos, self.eef_rot, self.state, self.joint_pos, self.joint_vel, self.eef_pose])

    # ---------------------------------------------------------------------------------------- cameras
    def render(self) -> dict[str, "wp.array"]:
        """Render every camera of every world (device uint8[N, H, W, 3] per feature key)."""
        self._check_open()
        if self.rc is None:
            return {}
        with wp.ScopedDevice(self.device):
            self._launch("render", self._render)
        return self.images

    def _render(self) -> None:
        self.camera_renderer.render(self.m, self.d)

    # ---------------------------------------------------------------------------------------- reading
    def _to_host(self, arr) -> np.ndarray:
        return arr if self.xp is np else self.xp.asnumpy(arr)

    def object_poses(self) -> dict:
        """Every world's ``privileged['objects']`` (``Task.object_names()``: tracked props, then the task's
        extras), base-frame [x y z qw qx qy qz] float[N, 7] as arrays of ``self.xp`` on the device."""
        ts, task = self.task_state, self.host.task
        with array_stream(self.xp, self.device):
            poses = {n: ts.to_base(ts.object_pos(n), ts.object_quat(n)) for n in task.tracked_objects}
            poses.update(task.extra_poses(ts))
        return poses

    def host_arrays(self) -> dict:
        """One host copy of the batch's small observation arrays (numpy, one row per world): ``state``,
        ``joint_positions``, ``joint_velocities``, ``eef_pose``, ``objects`` (name -> [N, 7]) and, after a
        step, ``success`` and ``diagnostics`` (name -> [N])."""
        if self._host_obs is None:
            h = {"state": self.state.numpy(), "joint_positions": self.joint_pos.numpy(),
                 "joint_velocities": self.joint_vel.numpy(), "eef_pose": self.eef_pose.numpy().astype(np.float64),
                 "objects": {k: self._to_host(v).astype(np.float64) for k, v in self.object_poses().items()}}
            if self._eval is not None:
                h["success"] = self._to_host(self._eval.success).astype(bool)
                h["diagnostics"] = {k: self._to_host(v) for k, v in self._eval.diagnostics.items()}
            self._host_obs = h
        return self._host_obs

    def privileged_objects(self, world: int) -> dict[str, np.ndarray]:
        """``privileged['objects']`` of one world (base frame [x y z qw qx qy qz])."""
        return {k: v[world].copy() for k, v in self.host_arrays()["objects"].items()}

    def diagnostics(self, world: int) -> dict[str, float | bool]:
        """The task's diagnostics of one world after the last step (Python values)."""
        diags = self.host_arrays().get("diagnostics", {})
        return {k: v[world].item() for k, v in diags.items()}

    def contacts(self, a: str, b: str) -> np.ndarray:
        """bool[N]: whether ``a`` and ``b`` (props, or ``robot``) touch in each world now."""
        with array_stream(self.xp, self.device):
            return self._to_host(self.task_state.contacts(a, b)).astype(bool)

    def sim_time_ns(self, world: int) -> int:
        return int(round(float(self.steps[world]) * self.substeps * float(self.mjm.opt.timestep) * 1e9))

    def world_qpos(self, world: int) -> np.ndarray:
        return self.d.qpos.numpy()[world].astype(np.float64)

    # ---------------------------------------------------------------------------------------- life
    def _check_open(self) -> None:
        if self._closed:
            raise SimulationError("the batched scene is closed")

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._graphs.clear()
            self.host.close()

    def __enter__(self) -> "BatchedScene":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

