"""``SimseamVectorEnv``: a gymnasium ``VectorEnv`` over a ``BatchRollout`` (N environments of one scene).

Observations are batched arrays, one per key with the environment index first (the batched
``observation_space``: ``gymnasium.vector.utils.batch_space`` of ``SimseamEnv``'s space): host NumPy copies by
default. ``device_arrays=True`` returns the batch's own ``observation_arrays`` leaves instead (DLPack arrays in
the device's memory on a GPU engine, for ``torch.from_dlpack`` / ``jax.dlpack.from_dlpack``, as ManiSkill3 and
Isaac Lab hand out torch tensors): no copy, valid until the next ``step`` / ``reset`` (copy what you keep), and
``step`` then also takes actions as any float32 DLPack array on the batch's device (``step_arrays``). A batch
that does not offer arrays (separate CPU rollouts, ``SyncBatchRollout``) has its dict observations stacked.

- ``reset(seed=None, options=None)``: ``seed`` an int gives environment ``i`` the episode seed ``seed + i``
  (gymnasium's rule, so ``reset(seed=s)`` equals ``SyncVectorEnv`` over ``SimseamEnv`` reset with ``s``), a
  list one seed per environment; each environment's later episodes draw their seeds from its own generator
  seeded by it, exactly as ``SimseamEnv`` does. ``options={"reset_mask": bool[N]}`` resets only those
  environments (the ``DISABLED`` autoreset mode's way).
- ``step(actions)``: ``float32[N, action_dim]``; a wrong shape or a non-finite entry raises
  ``InvalidActionError`` naming the row and nothing is applied; out-of-bounds entries are clipped.
  Success terminates; the scene's ``max_steps`` truncates.
- Autoreset (``metadata["autoreset_mode"]``, gymnasium 1.x; ``autoreset_mode=`` picks it):
  ``NEXT_STEP`` (default, as ``SyncVectorEnv``): the step after an environment's episode ended resets it,
  ignoring its action, and returns its first observation with reward 0 and not terminated / truncated.
  ``SAME_STEP``: an environment whose episode ends is reset in the same step; the returned observation is
  the new episode's, the last one is in ``info["final_obs"]`` (object array, ``_final_obs`` mask) with its
  info in ``info["final_info"]``. ``DISABLED``: nothing is reset until ``reset(options={"reset_mask": ...})``.
- ``info``: ``is_success`` (bool[N]) and ``episode_seed`` (int64[N], at the resets), each with gymnasium's
  ``_key`` mask of the environments it holds for.
- ``render()``: with ``render_mode="rgb_array"``, a tuple of each environment's ``uint8[H, W, 3]`` frame.
"""

from __future__ import annotations

from typing import Any

import gymnasium as gym
import numpy as np
from gymnasium.utils import seeding
from gymnasium.vector import AutoresetMode
from gymnasium.vector.utils import batch_space

from simseam.gym.spaces import action_space, observation_space
from simseam.seam import (
    ConfigError,
    InvalidActionError,
    ObsRequest,
    array_fields,
    host_array,
    info_column,
    offers_arrays,
    stack_observations,
)
from simseam.seam.batch import batch_actions


def open_batch(scene: Any, num_envs: int, *, privileged: bool = False, render_images: bool = True,
               **overrides: Any):
    """The ``BatchRollout`` of ``num_envs`` environments of a scene file (or ``SceneConfig``): MuJoCo Warp's
    worlds for ``engine: mujoco_warp`` (observations as device arrays), else ``num_envs`` separate rollouts."""
    from simseam.engines.registry import engine_info
    from simseam.gym.env import _scene_config
    from simseam.runner.scene_config import build_rollout
    from simseam.seam import SyncBatchRollout

    cfg, base_dir = _scene_config(scene, overrides)
    if isinstance(num_envs, bool) or not isinstance(num_envs, int) or num_envs < 1:
        raise ConfigError(f"num_envs must be a positive int, got {num_envs!r}")
    if cfg.benchmark is None and engine_info(cfg.engine.name).batched:
        from simseam.runner.warp_vector import build_batched_scene
        from simseam.scene.warp import WarpBatchRollout

        return WarpBatchRollout(build_batched_scene(cfg, base_dir, num_envs, privileged=privileged,
                                                    render_images=render_images))
    rollouts = []
    try:
        for _ in range(num_envs):
            rollouts.append(build_rollout(cfg, base_dir, privileged=privileged, render_images=render_images))
        return SyncBatchRollout(rollouts)
    except BaseException:
        for r in rollouts:
            r.close()
        raise


class SimseamVectorEnv(gym.vector.VectorEnv):
    """N environments of a scene as a gymnasium ``VectorEnv`` (see the module docstring).

    Args:
        scene: a scene file path or ``SceneConfig`` (with ``num_envs``), or None with ``batch``.
        num_envs: how many environments.
        batch: an open ``BatchRollout`` to wrap instead (closed with the env).
        privileged, render_images, render_mode: as ``SimseamEnv``'s.
        device_arrays: return the batch's own DLPack arrays instead of NumPy copies.
        autoreset_mode: an ``AutoresetMode`` (or its value); default ``NEXT_STEP``.
        **overrides: SceneConfig fields replacing the file's.
    """

    def __init__(self, scene: Any = None, num_envs: int | None = None, *, batch: Any = None,
                 privileged: bool = False, render_images: bool = True, render_mode: str | None = None,
                 device_arrays: bool = False, autoreset_mode: AutoresetMode | str = AutoresetMode.NEXT_STEP,
                 **overrides: Any):
        mode = AutoresetMode(autoreset_mode)
        if (scene is None) == (batch is None):
            raise ConfigError("SimseamVectorEnv takes a scene (and num_envs) or a batch, not both")
        self._closed = True
        self.batch = batch if batch is not None else open_batch(
            scene, num_envs, privileged=privileged, render_images=render_images, **overrides)
        self._closed = False
        spec = self.batch.spec
        self.num_envs = n = self.batch.num_envs
        modes = ["rgb_array"] if spec.robot.sensors_of("rgb") else []
        if render_mode is not None and render_mode not in modes:
            self.close()
            raise ConfigError(f"render_mode {render_mode!r} is not supported by robot {spec.robot.name!r}; "
                              f"supported: {modes or 'none (it has no RGB camera)'}")
        self.render_mode = render_mode
        self.metadata = {"render_modes": modes, "render_fps": float(spec.control_hz), "autoreset_mode": mode}
        self.single_action_space = action_space(spec)
        self.action_space = batch_space(self.single_action_space, n)
        self.single_observation_space = observation_space(spec, privileged=privileged)
        self.observation_space = batch_space(self.single_observation_space, n)
        self._arrays = offers_arrays(self.batch)
        self._device = bool(device_arrays)
        self._request = ObsRequest(images=None if spec.cameras else frozenset(), depth=False)
        self._fields = array_fields(spec, self._request)
        self._last = [None] * n  # the dict observations (a batch without arrays)
        self._rngs = [seeding.np_random()[0] for _ in range(n)]
        self._ended = np.zeros(n, dtype=bool)  # NEXT_STEP: reset at the next step

    # ------------------------------------------------------------------ gym API
    def reset(self, *, seed: int | list[int] | None = None, options: dict[str, Any] | None = None):
        n = self.num_envs
        seeds = [seed + i for i in range(n)] if isinstance(seed, int) else seed
        if seeds is not None and len(seeds) != n:
            raise ConfigError(f"reset: {len(seeds)} seeds for {n} environments")
        options = dict(options or {})
        mask = np.asarray(options.pop("reset_mask", np.ones(n, dtype=bool)), dtype=bool)
        if options or mask.shape != (n,):
            raise ConfigError(f"reset options: only reset_mask (bool[{n}]) is defined, got {sorted(options)} "
                              f"and a mask of shape {mask.shape}")
        envs = np.flatnonzero(mask)
        given = [None if seeds is None else seeds[e] for e in envs]
        for e, s in zip(envs, given):
            if s is not None:
                self._rngs[e] = seeding.np_random(int(s))[0]
        info = self._reset(envs, given)
        self._ended[envs] = False
        return self._observation(), info

    def step(self, actions):
        n, mode = self.num_envs, self.metadata["autoreset_mode"]
        a = self._actions(actions)
        resetting = self._ended.copy() if mode == AutoresetMode.NEXT_STEP else np.zeros(n, dtype=bool)
        stepped = np.flatnonzero(~resetting)
        reward, terminated, truncated = np.zeros(n), np.zeros(n, dtype=bool), np.zeros(n, dtype=bool)
        success = np.zeros(n, dtype=bool)
        if stepped.size:
            r = self._step(stepped, a)
            reward[stepped], terminated[stepped], truncated[stepped] = r.reward, r.terminated, r.truncated
            key = self.batch.spec.task.success_key
            success[stepped] = info_column(r.infos, key)
        info: dict[str, Any] = {"is_success": success, "_is_success": ~resetting}
        ended = terminated | truncated
        if mode == AutoresetMode.SAME_STEP and ended.any():
            info.update(self._final(ended, info))
            resetting = ended
        if resetting.any():
            info.update(self._reset(np.flatnonzero(resetting), [None] * int(resetting.sum())))
        self._ended = ended if mode == AutoresetMode.NEXT_STEP else np.zeros(n, dtype=bool)
        return self._observation(), reward, terminated, truncated, info

    def render(self) -> tuple[np.ndarray | None, ...] | None:
        if self.render_mode != "rgb_array":
            return None
        return tuple(self.batch.render(e) for e in range(self.num_envs))

    def close_extras(self, **kwargs: Any) -> None:
        if not self._closed:
            self._closed = True
            self.batch.close()

    # ----------------------------------------------------------------- helpers
    def _actions(self, actions: Any):
        """``actions`` checked: float32[N, dim] NumPy (``InvalidActionError`` naming the row); with
        ``device_arrays``, any other DLPack array goes to the batch as it is."""
        if self._device and self._arrays and not isinstance(actions, (np.ndarray, list, tuple)):
            return actions
        try:
            return batch_actions(self.batch.spec, actions, self.num_envs)
        except InvalidActionError as exc:
            raise InvalidActionError(f"{exc}; this env's action_space is {self.action_space}") from None

    def _step(self, envs: np.ndarray, actions: Any):
        if self._arrays:
            return self.batch.step_arrays(envs.tolist(), actions, self._request)
        r = self.batch.step(envs.tolist(), actions[envs], self._request)
        for e, o in zip(envs.tolist(), r.observations):
            self._last[e] = o
        return r

    def _reset(self, envs: np.ndarray, seeds: list) -> dict[str, Any]:
        """Reset ``envs``: a given seed, else one drawn from the environment's own generator."""
        n = self.num_envs
        episode = np.zeros(n, dtype=np.int64)
        for e, s in zip(envs.tolist(), seeds):
            episode[e] = int(s) if s is not None else int(self._rngs[e].integers(0, 2**31 - 1))
        got = self.batch.reset(envs.tolist(), episode[envs].tolist(),
                               ObsRequest.state_only() if self._arrays else self._request)
        if not self._arrays:
            for e, o in zip(envs.tolist(), got):
                self._last[e] = o
        mask = np.zeros(n, dtype=bool)
        mask[envs] = True
        return {"episode_seed": episode, "_episode_seed": mask}

    def _arrays_now(self) -> dict[str, Any]:
        return (self.batch.observation_arrays(self._request) if self._arrays
                else stack_observations(self._last, self._fields))

    def _observation(self) -> dict[str, Any]:
        return _select(self._arrays_now(), self.single_observation_space, copy=not self._device)

    def _final(self, ended: np.ndarray, info: dict[str, Any]) -> dict[str, Any]:
        """SAME_STEP: the ended environments' last observations and infos, before their reset."""
        obs = _select(self._arrays_now(), self.single_observation_space, copy=True)
        final_obs = np.full(self.num_envs, None, dtype=object)
        final_info = np.full(self.num_envs, None, dtype=object)
        for e in np.flatnonzero(ended).tolist():
            final_obs[e] = _row(obs, e)
            final_info[e] = {"is_success": bool(info["is_success"][e])}
        return {"final_obs": final_obs, "_final_obs": ended.copy(), "final_info": final_info,
                "_final_info": ended.copy()}


def _select(arrays: dict, space: gym.spaces.Dict, *, copy: bool) -> dict:
    """The keys of ``space`` from batched ``arrays``: host NumPy copies (``copy``), or the leaves as they are."""
    out = {}
    for key, sub in space.spaces.items():
        v = arrays[key]
        if isinstance(sub, gym.spaces.Dict):
            out[key] = _select(v, sub, copy=copy)
        elif copy:
            out[key] = np.array(host_array(v) if not isinstance(v, np.ndarray) else v, dtype=sub.dtype, copy=True)
        else:
            out[key] = v
    return out


def _row(obs: dict, e: int) -> dict:
    return {k: _row(v, e) if isinstance(v, dict) else v[e] for k, v in obs.items()}


__all__ = ["SimseamVectorEnv", "open_batch"]
