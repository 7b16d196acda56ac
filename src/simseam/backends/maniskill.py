"""ManiSkill3 behind the seam (``benchmark: {name: maniskill, task: PickCube-v1}``).

Native environment: ``gym.make(task, num_envs=1, obs_mode="state", sim_backend="physx_cpu",
control_mode=...)`` from ``mani-skill`` 3.0.1 (SAPIEN 3, PhysX on the CPU). Episode ``seed``
is ManiSkill's own ``env.reset(seed=seed)`` (it reseeds the task's randomisation, and
reconfigures the tasks that randomise their assets, e.g. PegInsertionSide's peg sizes).

Rendering. SAPIEN renders through Vulkan and needs a device with descriptor indexing,
timeline semaphores and extended dynamic state: a GPU's driver, or on a CPU the Mesa 25
lavapipe that ``simseam.backends.software_vulkan`` provisions (set-up does; Debian 12's own
lavapipe 22.3 lacks descriptor indexing), which the sidecar is started with. Where it finds
none, ManiSkill runs physics only: it drops every visual
shape (``scene.can_render()`` is false), yet its task builders still construct
``sapien.render.RenderMaterial`` objects first, which raise "failed to find a rendering
device". ``allow_physics_only()`` then replaces that one class by an inert stand-in whose
instances ManiSkill stores in the visual records it discards; nothing else changes (the
same workaround is applied to the native env the fidelity tests compare against). Tasks
that call methods on those materials (PullCubeTool, PlugCharger, PushT) cannot run so.

Mapping to the seam:

- action, ``control_mode: pd_ee_delta_pose`` (default): CARTESIAN_DELTA ``[dx, dy, dz, dax,
  day, daz, grip]`` in [-1, 1], ManiSkill's own normalised action: 0.1 m and 0.1 rad per step
  at 1, translation in the robot base frame, rotation about base-aligned axes at the TCP
  (ManiSkill's ``root_translation:root_aligned_body_rotation``);
  ``control_mode: pd_joint_pos``: JOINT_POSITION, the 7 arm joint targets (rad, within the
  joint limits) + grip (what ManiSkill's motion-planning experts emit);
  ``grip`` follows the seam's convention (-1 open, +1 closed): it is ManiSkill's normalised
  gripper command negated (ManiSkill: -1 closed, +1 open);
- ``state``: ManiSkill's ``obs_mode="state"`` vector, bit for bit (float32 natively): the
  agent's qpos and qvel, then the task's extra state, each slot named after its key
  (``agent.qpos.0``, ``extra.tcp_pose.3``, ...);
- ``joint_positions`` / ``joint_velocities``: the Panda's 7 arm and 2 finger joints;
- ``environment_state`` (``environment_state: true``): the task's part of ``state``, the ``extra.*``
  slots (PickCube: ``is_grasped``, the TCP pose, the goal, the cube's pose, their differences) in the
  same order, bit for bit, world frame as ManiSkill gives them; what LeRobot's ACT reads as
  ``observation.environment_state`` (it needs a camera or that) for a state-based policy;
- ``images``: none unless ``cameras: true``; then ``camera1`` = ManiSkill's ``base_camera`` at
  ``image_size`` (default 128x128), rendered only when requested, and only where SAPIEN can
  render; elsewhere ``cameras: true`` fails at once with one line naming the cause;
- ``expert_action`` (privileged rollouts: ``--policy scripted``, needs ``pd_joint_pos``): ManiSkill's
  motion-planning solution for the task (``mani_skill.examples.motionplanning``, mplib), planned
  at each reset on a twin environment with the same seed and replayed step by step;
- ``reward``: the task's ``normalized_dense`` reward (ManiSkill's default); ``success``:
  ``info["success"]``; diagnostics: the other scalar ``info`` entries of the task;
- ``max_steps``: the step limit ManiSkill registers for the task unless set.

ManiSkill does not tell: joint speed limits, camera intrinsics without a renderer, a
language instruction (the instruction is the task's name in words).

Imports numpy and simseam.seam at module level; mani_skill, sapien and torch only in
``make_rollout`` / ``catalog``.
"""

from __future__ import annotations

import re
import sys
from typing import Any

import numpy as np

from simseam.math3d import matrix_to_rpy, quat_to_matrix
from simseam.backends.base import BenchmarkRollout, check_image_size, check_int, check_keys, observation_spec
from simseam.seam import (
    OBS_ENV_STATE,
    OBS_EXPERT_ACTION,
    OBS_IMAGES,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_STATE,
    ActionSlot,
    ActionSpec,
    ConfigError,
    ControlMode,
    FieldSpec,
    GripperFacts,
    JointFacts,
    ObsRequest,
    RobotFacts,
    RolloutSpec,
    SensorFacts,
    TaskSpec,
)
from simseam.seam.errors import BackendUnavailableError

NAME = "maniskill"
HAS_EXPERT = True  # mani_skill.examples.motionplanning (mplib), for EXPERT_TASKS
CAMERA_OPTION = "cameras"  # state-only unless asked: eval turns it on for a policy that reads images
ENV_STATE_OPTION = "environment_state"  # off unless asked: eval turns it on for a policy that reads it
#: table-top Panda tasks whose assets ship in the wheel and that run physics-only (checked here)
TASKS = ("PickCube-v1", "PushCube-v1", "StackCube-v1", "PegInsertionSide-v1", "PullCube-v1", "LiftPegUpright-v1",
         "PokeCube-v1", "PlaceSphere-v1", "RollBall-v1")
#: tasks with a motion-planning solution in mani_skill.examples.motionplanning.panda.solutions
EXPERT_TASKS = {"PickCube-v1": "solvePickCube", "PushCube-v1": "solvePushCube", "StackCube-v1": "solveStackCube",
                "PegInsertionSide-v1": "solvePegInsertionSide", "PullCube-v1": "solvePullCube",
                "LiftPegUpright-v1": "solveLiftPegUpright", "PlaceSphere-v1": "solvePlaceSphere"}
CONTROL_MODES = ("pd_ee_delta_pose", "pd_joint_pos")
SIM_BACKENDS = ("physx_cpu", "physx_cuda")
DEFAULTS = {"control_mode": "pd_ee_delta_pose", "max_steps": 0, "cameras": False, "image_size": [128, 128],
            "expert": False, "environment_state": False, "sim_backend": "physx_cpu"}
SKIP_INFO = ("success", "elapsed_steps", "reconfigure")


def normalize_config(config: dict[str, Any], where: str = "benchmark") -> dict[str, Any]:
    check_keys(config, {"name", "task", *DEFAULTS}, where)
    task = config.get("task")
    if task not in TASKS:
        raise ConfigError(f"{where}.task: one of ManiSkill's shipped-asset tasks {list(TASKS)} is required, "
                          f"got {task!r}")
    out = {**DEFAULTS, **{k: v for k, v in config.items() if k != "name"}}
    for key in ("expert", "cameras", "environment_state"):
        if not isinstance(out[key], bool):
            raise ConfigError(f"{where}.{key}: expected true or false, got {out[key]!r}")
    if out["expert"]:
        if task not in EXPERT_TASKS:
            raise ConfigError(f"{where}: ManiSkill ships no motion-planning solution for {task}; "
                              f"those with one: {sorted(EXPERT_TASKS)}")
        if "control_mode" not in config:
            out["control_mode"] = "pd_joint_pos"  # what the motion planner's actions are
        elif out["control_mode"] != "pd_joint_pos":
            raise ConfigError(f"{where}.control_mode: the motion-planning expert emits pd_joint_pos actions, "
                              f"got {out['control_mode']!r}")
    if out["sim_backend"] not in SIM_BACKENDS:
        raise ConfigError(f"{where}.sim_backend: {out['sim_backend']!r}; one of {list(SIM_BACKENDS)} (physx_cuda: "
                          "ManiSkill's GPU physics, N environments in one sidecar)")
    if out["expert"] and out["sim_backend"] != "physx_cpu":
        raise ConfigError(f"{where}: the motion-planning expert plans on the CPU (sim_backend physx_cpu), got "
                          f"{out['sim_backend']!r}")
    if out["control_mode"] not in CONTROL_MODES:
        raise ConfigError(f"{where}.control_mode: {out['control_mode']!r} is not supported; one of "
                          f"{list(CONTROL_MODES)}")
    out["image_size"] = check_image_size(out["image_size"], where)
    out["max_steps"] = check_int(out["max_steps"], f"{where}.max_steps", low=0)
    return out


def instruction(task: str) -> str:
    """ManiSkill has no language instructions: the task's name in words ("peg insertion side")."""
    return re.sub(r"(?<!^)(?=[A-Z])", " ", task.removesuffix("-v1")).lower()


def allow_physics_only() -> bool:
    """Whether SAPIEN can render here; where it cannot, let ManiSkill build its scenes physics-only
    (see the module docstring): ``sapien.render.RenderMaterial`` becomes an inert stand-in."""
    import sapien
    import sapien.wrapper.urdf_loader  # noqa: F401  (binds RenderMaterial by name: patched below too)

    try:
        sapien.render.RenderMaterial()
        return True
    except RuntimeError as exc:
        if "rendering device" not in str(exc):
            raise

    class PhysicsOnlyMaterial:
        """Stands in for a visual material ManiSkill builds and then drops (no renderer)."""

        def __init__(self, *args: Any, **kwargs: Any) -> None:
            pass

    original = sapien.pysapien.render.RenderMaterial
    sapien.render.RenderMaterial = sapien.pysapien.render.RenderMaterial = PhysicsOnlyMaterial
    for name, module in list(sys.modules.items()):  # modules that bound the class by name (sapien's URDF loader)
        if name.split(".")[0] in ("sapien", "mani_skill") and getattr(module, "RenderMaterial", None) is original:
            module.RenderMaterial = PhysicsOnlyMaterial
    return False


def catalog() -> dict[str, Any]:
    """Suites and tasks (run in the backend's venv by ``simseam benchmarks list``)."""
    import mani_skill.envs  # noqa: F401  (registers the tasks)
    from mani_skill.utils.registration import REGISTERED_ENVS

    return {"suites": {"shipped-assets": list(TASKS), "motion-planning experts": list(EXPERT_TASKS)},
            "tasks": {t: f"{instruction(t)} ({REGISTERED_ENVS[t].max_episode_steps} steps)" for t in TASKS}}


def state_names(tree: dict, prefix: str = "") -> list[str]:
    """Slot names of ManiSkill's flattened state, in its order (``agent.qpos.0``, ...)."""
    names: list[str] = []
    for key, value in tree.items():
        path = f"{prefix}.{key}" if prefix else key
        if isinstance(value, dict):
            names += state_names(value, path)
        else:
            n = int(np.prod(tuple(value.shape[1:]))) if len(value.shape) > 1 else 1
            names += [path] if n == 1 and len(value.shape) <= 1 else [f"{path}.{i}" for i in range(n)]
    return names


def joint_slots(names: list[str], n: int) -> tuple[slice, slice] | None:
    """Where ManiSkill's state vector holds the robot's ``n`` joint positions and velocities (its agent's
    ``qpos`` and ``qvel``, read from the robot when the state was computed), or None when it does not."""
    out = []
    for key in ("agent.qpos", "agent.qvel"):
        want = [f"{key}.{i}" for i in range(n)]
        start = names.index(want[0]) if want[0] in names else -1
        if start < 0 or names[start:start + n] != want:
            return None
        out.append(slice(start, start + n))
    return out[0], out[1]


def camera_rgb(u, name: str = "base_camera"):
    """Camera ``name``'s RGB frames (a uint8 torch tensor [num_envs, H, W, 3]) of the unwrapped env ``u``:
    exactly ``u.get_sensor_images()[name]["rgb"]``, rendering only that camera's colour texture. ManiSkill's
    ``get_sensor_images`` captures every sensor and, in the state observation modes, downloads each camera's
    depth texture too and turns it into a picture: a second GPU read-back and sync per step that nobody reads.
    Same steps otherwise: hide the hidden objects, update the render, capture, read, convert."""
    from mani_skill.sensors.camera import camera_observations_to_images

    for obj in u._hidden_objects:
        obj.hide_visual()
    u.scene.update_render(update_sensors=True, update_human_render_cameras=False)
    sensor = u.scene.sensors[name]
    sensor.capture()
    return camera_observations_to_images(sensor.get_obs(rgb=True, depth=False, position=False,
                                                        segmentation=False))["rgb"]


def require_gpu_physics() -> None:
    """``sim_backend: physx_cuda`` fails closed here, before SAPIEN is asked for GPU physics (it would try
    to download NVIDIA's PhysX GPU library): without that library (``simseam.backends.physx_gpu``), or
    without a CUDA GPU."""
    import sapien.physx
    import torch

    from simseam.backends.physx_gpu import require_library

    require_library(sapien.physx.version())
    if not torch.cuda.is_available():
        raise BackendUnavailableError("maniskill: sim_backend physx_cuda needs an NVIDIA GPU with its driver, and "
                                      "torch sees none here; use sim_backend physx_cpu")


class ManiSkillRollout(BenchmarkRollout):
    """One ManiSkill3 environment (``num_envs`` 1); ``num_envs`` > 1 builds the one GPU-simulated env that
    ``ManiSkillBatch`` (``backends.maniskill_batch``) drives by index: the spec is the same."""

    def __init__(self, config: dict[str, Any], num_envs: int = 1):
        if config.get("sim_backend", "physx_cpu") == "physx_cuda":
            require_gpu_physics()
        self.can_render = allow_physics_only()
        import gymnasium as gym
        import mani_skill.envs  # noqa: F401  (registers the tasks)
        import torch

        torch.set_num_threads(1)  # one env, one core: ManiSkill's tensors are tiny
        self._torch = torch
        self.config = config
        task = config["task"]
        h, w = config["image_size"]
        if config["cameras"] and not self.can_render:
            raise BackendUnavailableError(
                "maniskill: cameras need a Vulkan device SAPIEN can render with, and there is none here "
                "(SAPIEN needs descriptor indexing and extended dynamic state: a GPU driver, or on a CPU "
                "`python -m simseam.backends.software_vulkan` for Mesa 25's lavapipe); or cameras: false")
        self._kwargs = dict(obs_mode="state", control_mode=config["control_mode"],
                            sim_backend=config.get("sim_backend", "physx_cpu"), num_envs=num_envs, render_mode=None,
                            render_backend="gpu" if config["cameras"] else "none",
                            sensor_configs=dict(width=w, height=h))
        self.env = gym.make(task, **self._kwargs)
        self._u = self.env.unwrapped
        self._plan_env = None
        self._expert_actions: list[np.ndarray] = []
        self._expert_result: bool | None = None
        if config["expert"]:
            from mani_skill.examples.motionplanning.panda import solutions

            self._solve = getattr(solutions, EXPERT_TASKS[task])
        joints = [j.name for j in self._u.agent.robot.get_active_joints()]
        self._obs, self._info = self._flat(*self.env.reset(seed=0))  # the first observation (no plan yet)
        self._t = 0
        names = state_names(self._u.get_obs(unflattened=True))
        if len(names) != self._obs.shape[0]:
            raise RuntimeError(f"maniskill {task}: {len(names)} state names for a {self._obs.shape[0]}-D state")
        self._joints = joint_slots(names, len(joints))  # joint positions / velocities: slices of the state
        info = self._info
        self._diagnostics = tuple(k for k, v in info.items()
                                  if k not in SKIP_INFO and hasattr(v, "shape") and tuple(v.shape) == (1,))
        super().__init__(self._describe(names, joints))

    def _describe(self, names: list[str], joints: list[str]) -> RolloutSpec:
        """The spec of the env just reset: its state ``names``, its active ``joints`` (7 arm, then the gripper's)."""
        import mani_skill
        import sapien
        from mani_skill.utils.registration import REGISTERED_ENVS

        config, task, robot = self.config, self.config["task"], self._u.agent.robot
        limits = robot.get_qlimits()[0].cpu().numpy().astype(np.float64)
        action = self._action_spec(joints)
        grip_cfg = self._u.agent.controller.configs["gripper"]
        cameras = {"camera1": tuple(config["image_size"])} if config["cameras"] else {}
        extra = {OBS_EXPERT_ACTION: FieldSpec("float32", (action.dim,), presence="declared")} \
            if config["expert"] else {}
        self._env_slots = None
        if config["environment_state"]:
            self._env_slots = np.array([i for i, n in enumerate(names) if n.startswith("extra.")], dtype=np.int64)
            extra[OBS_ENV_STATE] = FieldSpec("float32", (len(self._env_slots),), "declared",
                                             "ManiSkill's task state (world frame)",
                                             tuple(names[i] for i in self._env_slots))
        return RolloutSpec(
            robot=RobotFacts(name=self._u.agent.uid, base_link=robot.get_links()[0].name,
                             tool_link=self._u.agent.tcp.name,
                             joints=tuple(JointFacts(j, "arm" if i < 7 else "gripper", float(limits[i, 0]),
                                                     float(limits[i, 1])) for i, j in enumerate(joints)),
                             gripper=GripperFacts(tuple(joints[7:]), (float(grip_cfg.upper),) * 2,
                                                  (float(grip_cfg.lower),) * 2),
                             sensors=self._camera_sensors()),
            task=TaskSpec(name=task, instruction=instruction(task),
                          max_steps=config["max_steps"] or int(REGISTERED_ENVS[task].max_episode_steps),
                          diagnostics=self._diagnostics),
            observation=observation_spec(cameras, tuple(names), tuple(joints), extra),
            action=action,
            engine=f"maniskill-{mani_skill.__version__}/sapien-{sapien.__version__}/{self._kwargs['sim_backend']}",
            control_hz=float(self._u.control_freq),
            backend="inprocess",
            capabilities=("privileged",) if config["expert"] else (),
        )

    def _action_spec(self, joints: list[str]) -> ActionSpec:
        """pd_joint_pos: the 7 arm joints' targets within the env's action bounds; otherwise ManiSkill's
        normalized end-effector deltas (scaled by its arm controller's bounds); then the grip."""
        low, high = (np.asarray(x, dtype=np.float64) for x in (self.env.action_space.low, self.env.action_space.high))
        self._joint_mode = self.config["control_mode"] == "pd_joint_pos"
        if self._joint_mode:
            arm = tuple(ActionSlot(j, "arm", float(lo), float(hi), "rad") for j, lo, hi in
                        zip(joints[:7], low[:7], high[:7]))
            return ActionSpec(ControlMode.JOINT_POSITION, arm + (ActionSlot("grip", "grip", -1.0, 1.0,
                                                                              "-1 open, +1 closed"),))
        arm_cfg = self._u.agent.controller.configs["arm"]
        rot = "rad (about base-aligned axes at the TCP)"
        return ActionSpec(ControlMode.CARTESIAN_DELTA,
                          tuple(ActionSlot(n, "arm", -1.0, 1.0, f"{arm_cfg.pos_upper} m" if i < 3 else
                                           f"{arm_cfg.rot_upper} {rot}")
                                for i, n in enumerate(("dx", "dy", "dz", "dax", "day", "daz")))
                          + (ActionSlot("grip", "grip", -1.0, 1.0, "-1 open, +1 closed"),),
                          max_translation=float(arm_cfg.pos_upper), max_rotation=float(arm_cfg.rot_upper))

    def _camera_sensors(self) -> tuple[SensorFacts, ...]:
        """The base camera's mount and intrinsics when cameras are on (SAPIEN looks along +x)."""
        if not self.config["cameras"]:
            return ()
        h, w = self.config["image_size"]
        cam = self._u._sensor_configs["base_camera"]
        pose = np.asarray(cam.pose.raw_pose[0], dtype=np.float64)  # [x y z qw qx qy qz]; SAPIEN looks along +x
        return (SensorFacts(name="base_camera", kind="rgb", parent="world",
                            xyz=tuple(float(x) for x in pose[:3]),
                            rpy=tuple(float(a) for a in matrix_to_rpy(quat_to_matrix(pose[3:]))),
                            feature_key="camera1", width=w, height=h,
                            fovy_deg=float(np.degrees(float(np.asarray(cam.fov).reshape(-1)[0])))),)

    # ---------------------------------------------------------------- native
    def _native_reset(self, seed: int) -> None:
        self._obs, self._info = self._flat(*self.env.reset(seed=seed))
        self._t = 0
        if self.config["expert"]:
            self._plan(seed)

    def _flat(self, obs, info):
        return obs[0].cpu().numpy(), info

    def _plan(self, seed: int) -> None:
        """ManiSkill's motion-planning solution for this seed, on a twin env; its actions are replayed."""
        import gymnasium as gym

        if self._plan_env is None:
            self._plan_env = gym.make(self.config["task"], **self._kwargs)
        recorded: list[np.ndarray] = []
        step = self._plan_env.step

        def record(action):
            recorded.append(np.asarray(action, dtype=np.float64).copy())
            return step(action)

        self._plan_env.step = record
        try:
            result = self._solve(self._plan_env, seed=seed)
        finally:
            del self._plan_env.step
        self._expert_result = result != -1 and bool(result[-1]["success"].item())
        self._expert_actions = recorded

    def _to_native(self, action: np.ndarray) -> np.ndarray:
        a = np.asarray(action, dtype=np.float32).copy()
        a[-1] = -a[-1]  # the seam's grip (+1 closed) -> ManiSkill's (-1 closed)
        return a

    def _native_step(self, action: np.ndarray):
        obs, reward, _term, _trunc, info = self.env.step(self._to_native(action))
        self._obs, self._info = self._flat(obs, info)
        self._t += 1
        diagnostics = {k: float(info[k][0]) for k in self._diagnostics}
        return float(reward[0]), bool(info["success"][0]), diagnostics

    def expert_action(self) -> np.ndarray:
        if not self._expert_actions:
            return np.zeros(self.action_dim, np.float32)
        a = self._expert_actions[min(self._t, len(self._expert_actions) - 1)].astype(np.float32)
        a[-1] = -a[-1]
        return a

    def _observe_native(self, request: ObsRequest) -> dict[str, Any]:
        state = np.array(self._obs, dtype=np.float32)
        if self._joints is not None:  # the state's own copy of get_qpos / get_qvel, read when it was computed
            qpos, qvel = state[self._joints[0]].copy(), state[self._joints[1]].copy()
        else:
            qpos = self._u.agent.robot.get_qpos()[0].cpu().numpy().astype(np.float32)
            qvel = self._u.agent.robot.get_qvel()[0].cpu().numpy().astype(np.float32)
        obs = {
            OBS_IMAGES: {k: self._render_camera(k) for k in self.spec.observation.images if request.wants_image(k)},
            OBS_STATE: state,
            OBS_JOINT_POSITIONS: qpos,
            OBS_JOINT_VELOCITIES: qvel,
        }
        if self.config["expert"]:
            obs[OBS_EXPERT_ACTION] = self.expert_action()
        if self._env_slots is not None:
            obs[OBS_ENV_STATE] = obs[OBS_STATE][self._env_slots]
        return obs

    def _render_camera(self, key: str) -> np.ndarray:
        return np.ascontiguousarray(camera_rgb(self._u)[0].cpu().numpy().astype(np.uint8))

    def _sim_time_s(self) -> float:
        return self._t / float(self._u.control_freq)

    def _native_close(self) -> None:
        self.env.close()
        if self._plan_env is not None:
            self._plan_env.close()


def make_rollout(config: dict[str, Any]) -> ManiSkillRollout:
    import logging

    logging.getLogger("mani_skill").setLevel(logging.ERROR)  # "no render device" warnings, once per env
    return ManiSkillRollout(config)


def batches_natively(config: dict[str, Any]) -> bool:
    """Whether N environments of ``config`` run as ManiSkill's own batch in one sidecar (``simseam run
    --num-envs N``), rather than one sidecar each: with GPU physics."""
    return config.get("sim_backend") == "physx_cuda"


def make_batch(config: dict[str, Any], num_envs: int):
    """``num_envs`` environments in this process (a sidecar booted with ``num_envs``): ManiSkill's own batch
    (``ManiSkillBatch``: one env simulating them together) with GPU physics, or for one environment; on
    the CPU, where PhysX simulates one environment per env, and for the expert (it plans per environment),
    ``num_envs`` rollouts stepped in turn."""
    from simseam.backends.maniskill_batch import ManiSkillBatch
    from simseam.seam import SyncBatchRollout

    if config["sim_backend"] == "physx_cuda" or (num_envs == 1 and not config["expert"]):
        return ManiSkillBatch(config, num_envs)
    return SyncBatchRollout([make_rollout(config) for _ in range(num_envs)])
