"""ManiSkill3's own batch: N environments simulated together by one ManiSkill env, as a ``BatchRollout``.

ManiSkill is batched from the start (``gym.make(task, num_envs=N)``; one environment is the same class).
With GPU physics (``sim_backend: physx_cuda``) its N environments live in one PhysX GPU scene: a sidecar
booted with ``num_envs`` N serves them (``SidecarBatchRollout``) and the episode scheduler runs them like
any batch. On the CPU, PhysX holds one environment per env, so the same class serves one environment
there (which is how it is tested without a GPU) and ``maniskill.make_batch`` steps N CPU rollouts in turn.

Each environment's episode is the single rollout's (``ManiSkillRollout``), same spec, observation keys
and values, reward, success rule and step limit, with these choices where ManiSkill's batch differs:

- **Resets, one environment at a time.** A seeded ManiSkill reset draws the new episodes' object poses
  from ``torch.manual_seed(<first seed>)`` for all the environments reset together, so an environment's
  episode would depend on which others reset with it. Each environment is therefore reset alone
  (``env_idx=[e]``, ``seed=[s]``): seed ``s`` gives the same episode in any environment of the batch,
  whatever the others do. (GPU and CPU simulation draw from different generators and solve contacts
  differently: a seed's episode on ``physx_cuda`` is not its ``physx_cpu`` episode.)
- **Environments left out of a step** are simulated anyway (one GPU scene): they hold still, at their
  last joint targets (``pd_joint_pos``) or with a zero Cartesian delta and their last grip; the batch
  contract asks that they be reset before they are stepped again.
- **Tensors stay on the device** (ManiSkill's own ``torch`` tensors) until a step's or a reset's result
  is asked for: then only the rows of the environments named, and the cameras requested, are copied to
  host arrays, once per call.

The motion-planning expert plans per environment on the CPU: a batch with ``expert`` is N rollouts.
"""

from __future__ import annotations

from typing import Any, Sequence

import numpy as np

from simseam.seam import (
    INFO_DIAGNOSTICS,
    INFO_STEPS,
    OBS_ENV_STATE,
    OBS_IMAGES,
    OBS_JOINT_POSITIONS,
    OBS_JOINT_VELOCITIES,
    OBS_SIM_TIME_NS,
    OBS_STATE,
    OBS_TASK,
    ConfigError,
    ObsRequest,
    RolloutSpec,
    SimulationError,
)
from simseam.seam.batch import BatchStepResult, Requests, batch_actions, env_indices, per_env_requests


class ManiSkillBatch:
    """``num_envs`` environments of one ManiSkill task in one ManiSkill env (see the module docstring)."""

    def __init__(self, config: dict[str, Any], num_envs: int):
        from simseam.backends.maniskill import ManiSkillRollout

        if config["expert"]:
            raise ConfigError("maniskill: the motion-planning expert plans per environment: a batch with an "
                              "expert is N rollouts (maniskill.make_batch)")
        if config["sim_backend"] == "physx_cpu" and num_envs != 1:
            raise ConfigError(f"maniskill: physx_cpu simulates one environment per env, got num_envs {num_envs}; "
                              "use sim_backend physx_cuda")
        import torch

        self._torch = torch
        self._one = ManiSkillRollout(config, num_envs=num_envs)  # the env, its spec and its key names
        self._env, self._u = self._one.env, self._one._u
        self._n = num_envs
        self._state = self._u.get_obs()  # [N, D] on the env's device (ManiSkillRollout reset them all, seed 0)
        self._steps = np.zeros(num_envs, dtype=np.int64)
        self._started = np.zeros(num_envs, dtype=bool)
        self._hold = np.zeros((num_envs, self._one.spec.action.dim), dtype=np.float32)
        self._joint_mode = self._one._joint_mode
        self._seeds = np.random.default_rng()
        self._closed = False

    @property
    def spec(self) -> RolloutSpec:
        return self._one.spec

    @property
    def num_envs(self) -> int:
        return self._n

    def reset(self, envs: Sequence[int], seeds: Sequence[int | None], observe: Requests = None) -> list[dict]:
        self._check_open()
        idx = env_indices(envs, self._n, "reset").tolist()
        seeds = list(seeds)
        if len(seeds) != len(idx):
            raise ConfigError(f"reset: {len(idx)} environments but {len(seeds)} seeds")
        requests = per_env_requests(observe, len(idx), "reset")
        for e, seed in zip(idx, seeds):
            seed = int(self._seeds.integers(0, 2**31 - 1)) if seed is None else int(seed)
            env_idx = self._torch.tensor([e], device=self._u.device)
            self._state, _ = self._env.reset(seed=[seed], options={"env_idx": env_idx})
            self._steps[e], self._started[e] = 0, True
            self._hold[e] = 0.0
            if self._joint_mode:  # hold the arm where the reset put it, gripper open
                self._hold[e, :7] = self._u.agent.robot.get_qpos()[e, :7].cpu().numpy()
                self._hold[e, -1] = -1.0
        return self._observations(idx, requests)

    def step(self, envs: Sequence[int], actions: np.ndarray, observe: Requests = None) -> BatchStepResult:
        self._check_open()
        idx = env_indices(envs, self._n, "step")
        if not self._started[idx].all():
            raise SimulationError(f"step() of envs {idx[~self._started[idx]].tolist()} before their reset()")
        a = batch_actions(self.spec, actions, idx.size)
        a = np.stack([self.spec.action.clip(row) for row in a]).astype(np.float32) if idx.size else a
        requests = per_env_requests(observe, idx.size, "step")
        full = self._hold.copy()
        full[idx] = a
        self._hold[idx] = a if self._joint_mode else 0.0
        if not self._joint_mode:
            self._hold[idx, -1] = a[:, -1]  # a Cartesian delta holds still; the grip keeps its command
        native = full.copy()
        native[:, -1] = -native[:, -1]  # the seam's grip (+1 closed) -> ManiSkill's (-1 closed)
        self._state, reward, _term, _trunc, info = self._env.step(self._torch.as_tensor(native, device=self._u.device))
        self._steps[idx] += 1
        rows = self._torch.as_tensor(idx, device=self._u.device)
        success = info["success"][rows].cpu().numpy().astype(bool)
        diagnostics = {k: info[k][rows].cpu().numpy() for k in self._one._diagnostics}
        key, limit = self.spec.task.success_key, self.spec.task.max_steps
        infos = [{key: bool(success[j]), INFO_STEPS: int(self._steps[e]),
                  INFO_DIAGNOSTICS: {k: float(v[j]) for k, v in diagnostics.items()}} for j, e in enumerate(idx.tolist())]
        truncated = ~success & (self._steps[idx] >= limit)
        return BatchStepResult(idx, self._observations(idx.tolist(), requests),
                               reward[rows].cpu().numpy().astype(np.float64), success.copy(), truncated, infos)

    def _observations(self, idx: list[int], requests: list[ObsRequest | None]) -> list[dict]:
        """The observations of environments ``idx``: their rows copied to the host, once per call."""
        rows = self._torch.as_tensor(idx, device=self._u.device)
        robot = self._u.agent.robot
        state = self._state[rows].cpu().numpy().astype(np.float32)
        qpos = robot.get_qpos()[rows].cpu().numpy().astype(np.float32)
        qvel = robot.get_qvel()[rows].cpu().numpy().astype(np.float32)
        cameras = list(self.spec.observation.images)
        wanted = [[k for k in cameras if (q or ObsRequest()).wants_image(k)] for q in requests]
        rgb = self._rgb(rows) if any(wanted) else None
        env_slots = self._one._env_slots
        hz = float(self._u.control_freq)
        out = []
        for j, e in enumerate(idx):
            obs = {OBS_IMAGES: {k: np.ascontiguousarray(rgb[j]) for k in wanted[j]},
                   OBS_STATE: state[j], OBS_JOINT_POSITIONS: qpos[j], OBS_JOINT_VELOCITIES: qvel[j]}
            if env_slots is not None:
                obs[OBS_ENV_STATE] = state[j][env_slots]
            obs[OBS_TASK] = self.spec.task.instruction
            obs[OBS_SIM_TIME_NS] = int(round(self._steps[e] / hz * 1e9))
            out.append(obs)
        return out

    def _rgb(self, rows) -> np.ndarray:
        """The camera's frames of ``rows`` (uint8[k, H, W, 3]), rendered for the whole batch once."""
        from simseam.backends.maniskill import camera_rgb

        return camera_rgb(self._u)[rows].cpu().numpy().astype(np.uint8)

    def render(self, env: int) -> np.ndarray | None:
        self._check_open()
        (e,) = env_indices([env], self._n, "render").tolist()
        if not self.spec.observation.images or not self._started[e]:
            return None
        return np.ascontiguousarray(self._rgb(self._torch.as_tensor([e], device=self._u.device))[0])

    def failures(self) -> dict:
        return {}  # one env, one process: the environments do not fail alone

    def close(self) -> None:
        if not self._closed:
            self._closed = True
            self._one.close()

    def _check_open(self) -> None:
        if self._closed:
            raise SimulationError("the batch is closed")
