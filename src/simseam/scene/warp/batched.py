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
controllers (``kernels.make_arm_kernel``), the servo ramp, ``substeps`` MuJoCo Warp steps, the
observation, success and diagnostics (``kernels.make_observe_kernel``) and the cameras (MuJoCo
Warp's batched ray tracer). On a CUDA device one control step is one captured CUDA graph.

Supported: the ``lift_cube`` and ``reach`` tasks; fixed-base arms (CARTESIAN_DELTA with >= 6 arm
joints, or JOINT_POSITION with any); RGB cameras. Other tasks, kinematic bases, lidars and depth
sensors are refused with a ``ConfigError``.
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

SUPPORTED_TASKS = ("lift_cube", "reach")
DEFAULT_NCONMAX = 96  # contacts per world (allocated for the whole batch)
DEFAULT_NJMAX = 600  # constraint rows per world
ROBOT, CUBE = 1, 2  # owner codes for the grasp test


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


class BatchedScene:
    """``num_envs`` worlds of ``task`` with ``robot`` (see the module docstring)."""

    def __init__(self, robot, task: str, num_envs: int, options=None, warp_options: WarpOptions | None = None):
        from simseam.scene.manifest_scene import ManifestScene, SceneOptions

        if task not in SUPPORTED_TASKS:
            raise ConfigError(f"engine 'mujoco_warp' runs tasks {list(SUPPORTED_TASKS)}; got {task!r}")
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
        spec = host.spec
        self._spec = dataclasses.replace(spec, engine="mujoco_warp")
        mode = spec.action.control_mode
        self._cartesian = mode == ControlMode.CARTESIAN_DELTA
        plan = host.plan
        n_arm = len(plan.arm_idx)
        if self._cartesian and n_arm < 3:
            raise ConfigError(f"engine 'mujoco_warp': Cartesian control needs >= 3 arm joints; robot "
                              f"{robot.name!r} has {n_arm} (use control_mode: joint_position)")
        self.task_name = task
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
        with wp.ScopedDevice(self.device):
            self.m = mjw.put_model(mjm)
            self.d = mjw.put_data(mjm, host.engine.data, nworld=n, nconmax=wopts.nconmax, njmax=wopts.njmax)
            self._make_buffers(host, mjm)
            self._make_cameras(host, mjm)
        self.build_s = time.perf_counter() - t0
        self._graphs: dict = {}  # name -> captured CUDA graph
        self._ran: set = set()
        self.steps = np.zeros(n, dtype=np.int64)
        self.seeds = np.full(n, -1, dtype=np.int64)
        self._host_obs: dict | None = None
        self._closed = False

    # ------------------------------------------------------------------------------------ construction
    def _make_buffers(self, host, mjm) -> None:
        n = self.num_envs
        chain, ca = host.chain, host.chain.arrays
        arm = host.arm
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
        self._lower = wp.array(chain.lower.astype(np.float32), dtype=float)
        self._upper = wp.array(chain.upper.astype(np.float32), dtype=float)
        self._max_step = wp.array(np.minimum(arm.max_step, 1e6).astype(np.float32), dtype=float)
        self._q_home = wp.array(self._home[plan.arm_idx], dtype=float)
        g = host.gripper
        self._grip_open = wp.array((g.open if g else np.zeros(0)).astype(np.float32), dtype=float)
        self._grip_closed = wp.array((g.closed if g else np.zeros(0)).astype(np.float32), dtype=float)
        names = [s.name for s in spec.action.slots]
        self._grip_slot = names.index("grip") if "grip" in names else -1
        self._arm_kernel = K.make_arm_kernel(chain.n, self._cartesian, chain.n > 6, bool(ca.prismatic.any()))
        if self._cartesian:
            self._max_t, self._max_r = float(arm.max_translation), float(arm.max_rotation)
        else:
            self._max_t = self._max_r = 0.0
        # observation constants
        from simseam.scene.controllers.arm import REANCHOR_POS, REANCHOR_ROT, ROT_WEIGHT

        self._reanchor = (REANCHOR_POS, REANCHOR_ROT, ROT_WEIGHT)
        robot = host.robot
        self._tool_body = int(mjm.body(robot.tool_parent).id)
        base_pos, base_rot = host.base_frame()
        self._tool_pos = wp.vec3(*plan.tool_pos.astype(np.float32).tolist())
        self._tool_rot = wp.mat33(*plan.tool_rot.astype(np.float32).reshape(-1).tolist())
        self._base_pos = wp.vec3(*base_pos.astype(np.float32).tolist())
        self._base_rot = wp.mat33(*base_rot.astype(np.float32).reshape(-1).tolist())
        self._rot_reference = wp.vec4(*host.rot_reference.astype(np.float32).tolist())
        manifest = robot.joint_names
        qadr = np.zeros(len(manifest), dtype=np.int32)
        vadr = np.zeros(len(manifest), dtype=np.int32)
        qadr[plan.joint_index] = layout.joint_qadr
        vadr[plan.joint_index] = layout.joint_vadr
        self._jqadr, self._jvadr = wp.array(qadr, dtype=int), wp.array(vadr, dtype=int)
        self._gqadr = wp.array(layout.joint_qadr[plan.grip_idx].astype(np.int32), dtype=int)
        from simseam.scene.tasks import reach as reach_task
        from simseam.scene.tasks.base import TABLE_TOP
        from simseam.scene.tasks.lift_cube import CUBE_HALF, LIFT_HEIGHT

        lift = self.task_name == "lift_cube"
        # lift_cube: the cube; reach: nothing to track (the observe kernel reads the tool body instead)
        self._cube_body = int(layout.object_body["cube"]) if lift else self._tool_body
        self._rest_z, self._lift = float(TABLE_TOP + CUBE_HALF), float(LIFT_HEIGHT) if lift else 1e9
        self._reach_tol = (float(reach_task.POS_TOL), float(reach_task.ROT_TOL))
        self.target_pos = wp.zeros(n, dtype=wp.vec3)  # reach: each world's target, base frame
        self.target_rot = wp.zeros(n, dtype=wp.mat33)
        self._target_np = np.zeros((n, 7))  # the same as [x y z qw qx qy qz] (privileged)
        self.pos_err = wp.zeros(n, dtype=float)
        self.rot_err = wp.zeros(n, dtype=float)
        ns = len(plan.state_names)
        self.state = wp.zeros((n, ns), dtype=float)
        self.joint_pos = wp.zeros((n, len(manifest)), dtype=float)
        self.joint_vel = wp.zeros((n, len(manifest)), dtype=float)
        self.eef_pose = wp.zeros((n, 7), dtype=float)
        self.cube_pose = wp.zeros((n, 7), dtype=float)
        self.cube_height = wp.zeros(n, dtype=float)
        self.eef_to_cube = wp.zeros(n, dtype=float)
        self.success = wp.zeros(n, dtype=int)
        self.touching = wp.zeros(n, dtype=int)
        self._observe_kernel = K.make_observe_kernel(ns - 6)
        owner = np.asarray(layout.geom_owner, dtype=np.int32)
        self._geom_owner = wp.array(owner, dtype=int)
        self._cube_code = int(layout.owner_code["cube"]) if lift else -1

    def _make_cameras(self, host, mjm) -> None:
        self.cameras: dict[str, tuple[int, int]] = {}  # feature key -> (H, W)
        self.images: dict[str, wp.array] = {}
        self.rc = None
        cams = host.plan.cameras
        if not (self.options.render_images and cams):
            return
        names = [f"cam:{name}" for name, _, _ in cams]
        res = []
        for _, key, (h, w) in cams:
            self.cameras[key] = (h, w)
            res.append((w, h))
            self.images[key] = wp.zeros((self.num_envs, h, w, 3), dtype=wp.uint8)
        from simseam.engines.mujoco.engine import GROUP_ROBOT_VISUAL, GROUP_WORLD

        self.rc = mjw.create_render_context(mjm, nworld=self.num_envs, cam_res=res, render_rgb=True,
                                            render_depth=False, cam_active=names, use_textures=True,
                                            enabled_geom_groups=[GROUP_WORLD, GROUP_ROBOT_VISUAL],
                                            background_color=(0.0, 0.0, 0.0, 1.0))
        adr = self.rc.rgb_adr.numpy()
        self._cam_adr = [(key, int(adr[i]), res[i][0]) for i, (_, key, _) in enumerate(cams)]

    # ---------------------------------------------------------------------------------------- resets
    def _placement(self, seed: int):
        """The task's randomisation for ``seed`` (its own draws, from the episode's generator)."""
        placed = {}

        class _Capture:  # receives the task's set_object_pose calls
            def set_object_pose(self, name, pos, quat):
                placed[name] = (np.asarray(pos, np.float64), np.asarray(quat, np.float64))

        self.host.task.reset(_Capture(), np.random.default_rng(seed))
        return placed

    def _make_template(self):
        """The settled reset state as a template: the settle (0.1 s of physics after placing the props)
        moves nothing that depends on where the task placed them (a cube on a flat table drops by the
        same few micrometres wherever it stands, the robot starts at home). Verified here against the
        CPU scene's real reset for two seeds; when it does not hold, resets settle on the CPU."""
        host = self.host
        layout, data = host.engine.layout, host.engine.data
        names = list(self._placement(0))
        adr = {n: (layout.object_qadr[n], layout.object_vadr[n]) for n in names}
        host.reset(0, STATE_ONLY)
        placed0 = self._placement(0)
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

    def _template_state(self, seed: int, template=None):
        (qpos, qvel, ctrl, warm), adr, drop = template or self._template
        q = qpos.copy()
        for name, (pos, quat) in self._placement(seed).items():
            a = adr[name][0]
            q[a:a + 3] = pos + drop[name]
            q[a + 3:a + 7] = quat
        return q, qvel, ctrl, warm

    def _set_targets(self, worlds, seeds, rows) -> None:
        """reach: each world's target pose, drawn by the task itself from the episode's seed."""
        from simseam.math3d import matrix_to_quat

        task = self.host.task
        k = len(worlds)
        tp, tr = np.empty((k, 1, 3), np.float32), np.empty((k, 1, 3, 3), np.float32)
        for r, seed in enumerate(seeds.tolist()):
            task.reset(None, np.random.default_rng(int(seed)))
            tp[r, 0], tr[r, 0] = task.target_pos, task.target_rot
            self._target_np[worlds[r]] = np.concatenate([task.target_pos, matrix_to_quat(task.target_rot)])
        wp.launch(K.scatter_vec3_kernel, dim=(k, 1), inputs=[wp.array(tp, dtype=wp.vec3),
                                                            rows, self.target_pos.reshape((self.num_envs, 1))])
        wp.launch(K.scatter_mat33_kernel, dim=(k, 1), inputs=[wp.array(tr, dtype=wp.mat33),
                                                             rows, self.target_rot.reshape((self.num_envs, 1))])

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
        for r, seed in enumerate(seeds.tolist()):
            if self._template is not None:  # the task's draws on the settled template (checked at build)
                qpos[r], qvel[r], ctrl[r], warm[r] = self._template_state(int(seed))
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
            if self.task_name == "reach":
                self._set_targets(worlds, seeds, rows)
            self._launch("sense", self._sense)  # sensing after a reset: one graph too
        self.steps[worlds] = 0
        self.seeds[worlds] = seeds
        self._host_obs = None

    # ---------------------------------------------------------------------------------------- step
    def step(self, actions) -> BatchStep:
        """One control step of every world. ``actions``: float32[N, action_dim] (numpy on the host,
        or a device array: torch tensor / warp array / anything with ``__dlpack__``). Host actions
        are validated (shape, finite: ``InvalidActionError`` and nothing changes); all are clipped
        to the slot bounds on the device."""
        self._check_open()
        with wp.ScopedDevice(self.device):
            self._load_actions(actions)
            self._launch("step", self._physics)
            success = self.success.numpy().astype(bool)
        self.steps += 1
        self._host_obs = None
        truncated = (self.steps >= self.max_steps) & ~success
        return BatchStep(success.astype(np.float32), success, truncated, success, self.steps.copy())

    def _use_graph(self) -> bool:
        return bool(self.wopts.graph and self.device.is_cuda)

    def _launch(self, name: str, fn) -> None:
        """Run ``fn`` (device launches only). On CUDA its first call runs directly (kernels compile
        and load outside any capture), later calls replay one CUDA graph captured on the second."""
        if not self._use_graph():
            fn()
            return
        graph = self._graphs.get(name)
        if graph is None:
            if name not in self._ran:
                self._ran.add(name)
                fn()
                return
            with wp.ScopedCapture() as cap:
                fn()
            self._graphs[name] = graph = cap.graph
        wp.capture_launch(graph)

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
        src = actions if isinstance(actions, wp.array) else wp.from_dlpack(actions)
        if tuple(src.shape) != (n, adim):
            raise InvalidActionError(f"actions must have shape ({n}, {adim}), got {tuple(src.shape)}")
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
        """Poses of the current state (mj_step leaves them one substep behind), contacts, observation."""
        m, d, n = self.m, self.d, self.num_envs
        mjw.kinematics(m, d)
        mjw.collision(m, d)
        wp.launch(self._observe_kernel, dim=n, inputs=[
            d.qpos, d.qvel, d.xpos, d.xmat, self._tool_body, self._tool_pos, self._tool_rot, self._base_pos,
            self._base_rot, self._rot_reference, self._jqadr, self._jvadr, self._gqadr, self._cube_body,
            self._rest_z, self._lift,
            self.eef_pos, self.eef_rot, self.state, self.joint_pos, self.joint_vel, self.eef_pose, self.cube_pose,
            self.cube_height, self.eef_to_cube, self.success])
        self.touching.zero_()
        if self.task_name == "lift_cube":
            wp.launch(K.grasp_kernel, dim=d.naconmax, inputs=[
                d.nacon, d.contact.geom, d.contact.worldid, self._geom_owner, ROBOT, self._cube_code, self.touching])
        else:
            wp.launch(K.reach_eval_kernel, dim=n, inputs=[
                self.eef_pos, self.eef_rot, self.target_pos, self.target_rot, *self._reach_tol,
                self.pos_err, self.rot_err, self.success])

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
        m, d = self.m, self.d
        mjw.camlight(m, d)
        mjw.refit_bvh(m, d, self.rc)
        mjw.render(m, d, self.rc)
        for key, adr, width in self._cam_adr:
            out = self.images[key]
            wp.launch(K.unpack_rgb_u8_kernel, dim=(self.num_envs, out.shape[1] * out.shape[2]),
                      inputs=[self.rc.rgb_data, adr, width, out])

    # ---------------------------------------------------------------------------------------- reading
    def device_observation(self) -> dict:
        """The batch's observation as device arrays (warp; ``wp.to_torch`` / DLPack share the memory):
        ``state``, ``joint_positions``, ``joint_velocities``, ``privileged`` (``eef_pose``, and ``cube``
        for lift_cube) and ``success``. No host copy."""
        priv = {"eef_pose": self.eef_pose}
        if self.task_name == "lift_cube":
            priv["cube"] = self.cube_pose
        return {"state": self.state, "joint_positions": self.joint_pos, "joint_velocities": self.joint_vel,
                "privileged": priv, "success": self.success}

    def host_arrays(self) -> dict[str, np.ndarray]:
        """One host copy of the batch's small observation arrays (numpy, one row per world)."""
        if self._host_obs is None:
            self._host_obs = {
                "state": self.state.numpy(), "joint_positions": self.joint_pos.numpy(),
                "joint_velocities": self.joint_vel.numpy(), "eef_pose": self.eef_pose.numpy().astype(np.float64),
                "cube": self.cube_pose.numpy().astype(np.float64), "cube_height": self.cube_height.numpy(),
                "eef_to_cube": self.eef_to_cube.numpy(), "touching": self.touching.numpy().astype(bool),
                "success": self.success.numpy().astype(bool), "position_error": self.pos_err.numpy(),
                "orientation_error": self.rot_err.numpy()}
        return self._host_obs

    def privileged_objects(self, world: int) -> dict[str, np.ndarray]:
        """``privileged['objects']`` of one world (base frame [x y z qw qx qy qz])."""
        if self.task_name == "reach":
            return {"target": self._target_np[world].copy()}
        return {"cube": self.host_arrays()["cube"][world].copy()}

    def diagnostics(self, world: int) -> dict[str, float | bool]:
        h = self.host_arrays()
        if self.task_name == "reach":
            return {"position_error": float(h["position_error"][world]),
                    "orientation_error": float(h["orientation_error"][world])}
        height = float(h["cube_height"][world])
        return {"cube_height": height, "eef_to_cube": float(h["eef_to_cube"][world]),
                "grasped": bool(h["touching"][world]) and height > 0.005}

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

