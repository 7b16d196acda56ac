"""``MetaWorldBatchRollout``: N environments of one Meta-World v3 task on MuJoCo Warp (``MetaWorldBatch``) as
the seam's ``BatchRollout``, with the observations, reward, success, diagnostics, termination and
truncation of the CPU backend's ``MetaWorldRollout`` (``backends/metaworld.py``), so an episode's line in
``episodes.jsonl`` reads the same on either engine.

- config: the CPU backend's (``normalize_config``): ``variation``, ``goal_seed``, ``max_steps``, ``state``,
  ``environment_state``, and its cameras: ``camera`` (a name or a list: ``camera1``, ``camera2``, ...),
  ``image_size``, ``camera_pos``, ``image_flip``, ``cameras: false`` for none; the images keys, sizes and
  orientation are the CPU backend's, drawn by MuJoCo Warp's ray tracer for all the worlds at once, only
  when an observation request asks for one of them (``observe``: one request, or one per environment);
- reset: each environment's seed picks its native reset (MT1 variation ``seed % 50``, ``sampled``,
  ``lerobot``), whatever the other environments hold or which of them end first;
- step: every world's physics advances (an environment left out holds a zero action until its reset);
  ``terminated`` = Meta-World's success, ``truncated`` = not success at ``max_steps``;
- ``privileged`` (``--policy scripted``): ``expert_action`` is Meta-World's own scripted expert, asked of
  the native worker once per reset or step for all the environments in it;
- a world whose state goes non-finite: its episode ends as a failure (``failures()``, its task and
  seed in the message); the others carry on.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from simseam.backends.base import observation_spec
from simseam.backends.metaworld import (
    AGENT_POS,
    DIAGNOSTICS,
    ENV_STATE_SLOTS,
    ROBOT_JOINTS,
    STATE_NAMES,
    camera_names,
    camera_sensors,
    extra_fields,
    instruction,
    normalize_config,
    sawyer_joints,
)
from simseam.backends.metaworld_gpu.env import MetaWorldBatch
from simseam.backends.metaworld_gpu.model import described, task_model
from simseam.backends.metaworld_gpu.resets import ResetCache
from simseam.backends.native_port import NativePort
from simseam.seam import (
    INFO_STEPS,
    OBS_ENV_STATE,
    OBS_EXPERT_ACTION,
    OBS_IMAGES,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_SIM_TIME_NS,
    OBS_STATE,
    OBS_TASK,
    ActionSlot,
    ActionSpec,
    ControlMode,
    ObsRequest,
    RobotFacts,
    RolloutSpec,
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
    per_env_requests,
)

ENGINE = "mujoco_warp"


def gpu_config(config: dict[str, Any], where: str = "benchmark") -> dict[str, Any]:
    """The CPU backend's config, checked (``cameras`` off unless asked: the port renders only what is asked)."""
    return normalize_config({**config, "cameras": config.get("cameras", False)}, where)


def camera_plan(config: dict[str, Any]) -> list[tuple[str, str, tuple[int, int]]]:
    """``(camera, feature key, (H, W))`` of each camera ``config`` declares (none when ``cameras`` is off)."""
    if not config["cameras"]:
        return []
    size = tuple(config["image_size"])
    return [(name, f"camera{i + 1}", size) for i, name in enumerate(camera_names(config))]


class MetaWorldBatchRollout(NativePort):
    """``num_envs`` environments of ``config['task']`` (``worker``: a started ``NativeWorker``, shared)."""

    WORKER = "simseam.backends.metaworld_gpu.worker:NativeWorker"
    check_config = staticmethod(gpu_config)  # a scene file's ``benchmark:`` fields, as this port reads them

    def __init__(self, config: dict[str, Any], num_envs: int, worker: Any, *, privileged: bool = False,
                 device: str | None = None, engine: str = ENGINE):
        self.config = gpu_config(config)
        self._start(worker)
        self.privileged = bool(privileged)
        c = self.config
        self.world = MetaWorldBatch(c["task"], num_envs, worker, engine=engine, device=device,
                                    variation=c["variation"], goal_seed=c["goal_seed"], cameras=camera_plan(c),
                                    camera_pos=c["camera_pos"], image_flip=c["image_flip"])
        names = self.world.names
        self._qadr = np.array([names.joint_qpos[j][0] for j in ROBOT_JOINTS])
        self._vadr = np.array([names.joint_qvel[j][0] for j in ROBOT_JOINTS])
        self._spec = self._make_spec()
        self._dt_ns = self._spec_dt_ns()
        self._started = np.zeros(num_envs, dtype=bool)

    @classmethod
    def prefetch(cls, config: dict[str, Any], seeds: Sequence[int], worker: Any) -> None:
        """Ask ``worker`` now for what a batch of ``config`` will first need of Meta-World: the task's description
        (``model.described``, kept on disk), the reset states of ``seeds`` and of seed 0 (the model's settled
        state) into the reset cache on disk, and the task's model compiled, checked and cached when it is not. A
        run calls it from a thread for its next task while this one steps, so that no env is built natively
        between two tasks' batches."""
        c = gpu_config(config)
        info = described(worker, c["task"])
        states = ResetCache(worker, info, c["variation"], c["goal_seed"]).get(sorted({0, *map(int, seeds)}))
        task_model(worker, info, states[0])  # seed 0's: the settled state the model is checked in

    def _make_spec(self) -> RolloutSpec:
        c, info, m = self.config, self.world.info, self.world.model.model
        joints = sawyer_joints(m)
        extra = extra_fields(self.privileged, c["environment_state"])
        step = float(info["action_scale"])
        slots = tuple(ActionSlot(k, "arm", -1.0, 1.0, f"{step} m") for k in ("dx", "dy", "dz"))
        cams = {key: size for _, key, size in camera_plan(c)}
        return RolloutSpec(
            robot=RobotFacts(name="sawyer", base_link="world", tool_link="hand", joints=joints,
                             sensors=self._sensors() if cams else ()),
            task=TaskSpec(name=c["task"], instruction=instruction(c["task"]), max_steps=c["max_steps"],
                          diagnostics=DIAGNOSTICS),
            observation=observation_spec(cams, STATE_NAMES[:AGENT_POS] if c["state"] == "agent_pos" else STATE_NAMES,
                                         ROBOT_JOINTS, extra),
            action=ActionSpec(ControlMode.CARTESIAN_DELTA,
                              (*slots, ActionSlot("grip", "grip", -1.0, 1.0, "-1 open, +1 closed")),
                              max_translation=step),
            engine=f"metaworld-{info['metaworld']}/{ENGINE}-mujoco-{_mujoco_version()}",
            control_hz=1.0 / (float(m.opt.timestep) * int(info["frame_skip"])),
            backend="inprocess",
            capabilities=("privileged",) if self.privileged else (),
        )

    def _sensors(self) -> tuple:
        """The cameras' ``SensorFacts`` as the CPU backend declares them, from seed 0's reset state."""
        import mujoco

        m = self.world.model.model
        d = mujoco.MjData(m)
        state = self.world.resets.get([0])[0]
        for key in ("qpos", "mocap_pos", "mocap_quat"):
            getattr(d, key)[...] = state[key]
        mujoco.mj_kinematics(m, d)
        mujoco.mj_camlight(m, d)
        return camera_sensors(m, d, self.config)

    def _spec_dt_ns(self) -> int:
        return int(round(float(self.world.model.model.opt.timestep) * int(self.world.info["frame_skip"]) * 1e9))

    # ------------------------------------------------------------------------------------------ episodes
    def reset(self, envs: Sequence[int], seeds: Sequence[int | None], observe=None) -> list[dict[str, Any]]:
        idx, seeds = self._reset_seeds(envs, seeds)
        if idx.size:
            self.world.reset(idx, seeds)
        self._started[idx] = True
        return self._observations(idx, per_env_requests(observe, idx.size, "reset"))

    def step(self, envs: Sequence[int], actions: np.ndarray, observe=None) -> BatchStepResult:
        idx = self._stepped(envs)
        requests = per_env_requests(observe, idx.size, "step")
        a = batch_actions(self._spec, actions, idx.size)
        full = np.zeros((self.num_envs, 4), dtype=np.float32)  # the others hold still until their reset
        full[idx] = a
        return self._result(idx, self.world.step(full), lambda: self._observations(idx, requests))

    def step_arrays(self, envs: Sequence[int], actions: Any, observe: ObsRequest | None = None) -> BatchStepResult:
        """One control step of every world with ``actions`` float32[num_envs, 4] (any DLPack array; on the worlds'
        device: no host copy), the result for ``envs`` with empty observations (read them with
        ``observation_arrays``); the worlds outside ``envs`` take their rows too, their episodes do not advance.
        ``observe`` goes unused: the cameras draw when ``observation_arrays`` asks."""
        idx = self._stepped(envs)
        a = array_actions(self.world.xp, actions, (self.num_envs, 4))
        return self._result(idx, self.world.step(a), lambda: [{} for _ in range(idx.size)])

    def _result(self, idx: np.ndarray, r: dict[str, Any], observations) -> BatchStepResult:
        """``idx``'s part of the step ``r`` (``MetaWorldBatch.step``): a world newly non-finite ends its episode as a
        failure; ``observations()`` after that."""
        success = r["success"][idx]
        steps = self.world.steps[idx]
        for e in np.flatnonzero(r["errors"][idx]):
            env = int(idx[e])
            self._failures[env] = EnvFailure(self.world.error_message(env))
            self._started[env] = False
        infos = InfoColumns({self._spec.task.success_key: success, INFO_STEPS: steps},
                            {k: r["diagnostics"][k][idx] for k in DIAGNOSTICS})
        truncated = ~success & (steps >= self._spec.task.max_steps)
        return BatchStepResult(idx, observations(), r["reward"][idx].astype(np.float64), success.copy(), truncated,
                               infos)

    def _images(self, idx: np.ndarray, requests: list) -> list[dict[str, np.ndarray]]:
        """Each of ``idx``'s requested images: one render of every world when any is asked (none otherwise),
        then one host copy of the asked keys' rows."""
        keys = list(self._spec.observation.images)
        wanted = [[k for k in keys if (r or ObsRequest()).wants_image(k)] for r in requests]
        asked = [k for k in keys if any(k in w for w in wanted)]
        if not asked:
            return [{} for _ in wanted]
        images = self.world.render()
        rows = {k: _host(images[k][self.world.physics.device_xp.asarray(idx)]) for k in asked}
        return [{k: np.ascontiguousarray(rows[k][i]) for k in w} for i, w in enumerate(wanted)]

    def _observations(self, idx: np.ndarray, requests: list) -> list[dict[str, Any]]:
        """The seam's observation of each of ``idx`` (one host copy of the batch's arrays), with the images
        ``requests`` ask for."""
        if not idx.size:
            return []
        full = _host(self.world.obs)[idx]
        poses = self.world.physics.poses()
        qpos, qvel = _host(poses.qpos)[idx], _host(poses.qvel)[idx]
        state = full[:, :AGENT_POS] if self.config["state"] == "agent_pos" else full
        expert = (np.asarray(self.worker.call("expert", task=self.config["task"], obs=full), dtype=np.float32)
                  if self.privileged else None)
        text, out, images = self._spec.task.instruction, [], self._images(idx, requests)
        for i, w in enumerate(idx.tolist()):
            obs = {OBS_IMAGES: images[i], OBS_STATE: state[i].astype(np.float32), OBS_TASK: text,
                   OBS_JOINT_POSITIONS: qpos[i, self._qadr].astype(np.float32),
                   OBS_JOINT_VELOCITIES: qvel[i, self._vadr].astype(np.float32),
                   OBS_SIM_TIME_NS: int(self.world.steps[w]) * self._dt_ns}
            if self.config["environment_state"]:
                obs[OBS_ENV_STATE] = full[i, list(ENV_STATE_SLOTS)].astype(np.float32)
            if expert is not None:
                obs[OBS_EXPERT_ACTION] = expert[i]
            out.append(obs)
        return out

    # ------------------------------------------------------------------------------------------ arrays
    def observation_arrays(self, observe: ObsRequest | None = None) -> dict[str, Any]:
        """Every environment's observation as one array per key in the worlds' device memory (CuPy on CUDA, NumPy on
        Warp's CPU device; seam/batch.py "Observations as arrays"): the dicts' values, exactly, from the same
        arrays; the images drawn now for every world when asked. Rows of environments never reset: unspecified."""
        self._check_open()
        xp, n = self.world.physics.device_xp, self.num_envs
        fields = array_fields(self._spec, observe)
        full = xp.asarray(self.world.obs)
        poses = self.world.physics.poses()
        values: dict[str, Any] = {
            OBS_STATE: full[:, :AGENT_POS] if self.config["state"] == "agent_pos" else full,
            OBS_JOINT_POSITIONS: xp.asarray(poses.qpos)[:, xp.asarray(self._qadr)],
            OBS_JOINT_VELOCITIES: xp.asarray(poses.qvel)[:, xp.asarray(self._vadr)],
            OBS_SIM_TIME_NS: xp.asarray(self.world.steps * self._dt_ns)}
        if OBS_ENV_STATE in fields:
            values[OBS_ENV_STATE] = full[:, xp.asarray(list(ENV_STATE_SLOTS))]
        if OBS_EXPERT_ACTION in fields:
            values[OBS_EXPERT_ACTION] = xp.asarray(self._expert_rows())
        wanted = fields.get(OBS_IMAGES, {})
        images = self.world.render() if wanted else {}
        values[OBS_IMAGES] = {k: xp.ascontiguousarray(images[k]) for k in wanted}
        return conform_arrays(xp, values, fields, n)

    def _expert_rows(self) -> np.ndarray:
        """float32[num_envs, 4]: Meta-World's scripted expert's action for each started environment (one worker
        call), zeros for the others."""
        out = np.zeros((self.num_envs, 4), dtype=np.float32)
        rows = np.flatnonzero(self._started)
        if rows.size:
            obs = _host(self.world.obs)[rows]
            out[rows] = np.asarray(self.worker.call("expert", task=self.config["task"], obs=obs), dtype=np.float32)
        return out

    # ------------------------------------------------------------------------------------------- the rest
    def render(self, env: int) -> np.ndarray | None:
        """``env``'s first camera now (None without cameras)."""
        self._check_open()
        env_indices([env], self.num_envs, "render")
        keys = list(self._spec.observation.images)
        if not keys:
            return None
        return np.ascontiguousarray(_host(self.world.render()[keys[0]][env]))



def _host(a: Any) -> np.ndarray:
    return a.get() if hasattr(a, "get") else np.asarray(a)


def _mujoco_version() -> str:
    import mujoco

    return mujoco.__version__
