"""Vectorized episodes on MuJoCo Warp: N worlds in one process instead of N worker processes.

``WarpVectorEnv`` offers the vector runner's interface (``spec``, ``num_envs``, ``run(policy,
indices, seed=..., on_start, on_step, on_done, ...)``, ``close``) over one ``BatchedScene``, with
the same per-environment semantics: environment ``j`` is world ``j``; episode ``i`` uses seed
``seed + i``; a world whose episode ends (success or step limit) is reset alone, with the next
episode's seed, while the others go on; the batched policy (``act_batch(envs, observations)``, as
the vector runner's ``PolicyBatch``) sees one observation per busy world, honouring each world's
``observe_next()``. A policy with ``act_device(state)`` gets the batch's device arrays instead
(``BatchedScene.device_observation()``, no host copy). ``make_vector_env`` picks it for scenes
whose engine is ``mujoco_warp``.
"""

from __future__ import annotations

import time
from collections import deque
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from simseam.runner.episodes import EpisodeResult
from simseam.seam import ConfigError, SimulationError


def build_batched_scene(cfg, base_dir: Path, num_envs: int | None = None, *, privileged: bool = False,
                        render_images: bool = True, seed: int = 0, device: str | None = None):
    """The ``BatchedScene`` a scene file with ``engine: {name: mujoco_warp, num_envs: N}`` describes."""
    from simseam.scene.warp import BatchedScene, WarpOptions
    from simseam.runner.scene_config import resolve_robot, scene_options

    eng = cfg.engine
    if eng.name != "mujoco_warp":
        raise ConfigError(f"a batched scene needs engine 'mujoco_warp', got {eng.name!r}")
    if eng.process != "inprocess":
        raise ConfigError("engine 'mujoco_warp' runs in-process (process: sidecar is not supported)")
    n = num_envs or eng.num_envs or 1
    options = scene_options(cfg, privileged=privileged, render_images=render_images, seed=seed)
    return BatchedScene(resolve_robot(cfg, base_dir), cfg.task, n, options,
                        WarpOptions(device=device or eng.device))


class WarpVectorEnv:
    """``num_envs`` worlds of one scene on MuJoCo Warp behind the vector runner's interface."""

    def __init__(self, batch):
        self.batch = batch
        self.num_envs = batch.num_envs
        self.spec = batch.spec
        self.restarts = 0  # the vector runner's counter of restarted workers: there are none here

    @classmethod
    def from_config(cls, cfg, base_dir: Path, num_envs: int | None = None, **kwargs) -> "WarpVectorEnv":
        return cls(build_batched_scene(cfg, base_dir, num_envs, **kwargs))

    def close(self) -> None:
        self.batch.close()

    def __enter__(self) -> "WarpVectorEnv":
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def run(self, policy, indices: Sequence[int], *, seed: int = 0, video_dir: Path | None = None,
            max_attempts: int = 3,
            on_start: Callable[[int, int], None] | None = None,
            on_step: Callable[[int, int, int], None] | None = None,
            on_done: Callable[[EpisodeResult], None] | None = None,
            on_error: Callable[[EpisodeResult, str], None] | None = None,
            on_worker_failure=None) -> list[EpisodeResult]:
        """Run episodes ``indices`` (see the module docstring); callbacks as the vector runner's."""
        from simseam.scene.warp import world_observations

        if video_dir is not None:
            raise ConfigError("engine 'mujoco_warp': videos are not recorded in batched runs (drop --video)")
        batch, spec = self.batch, self.spec
        n = self.num_envs
        todo = deque(indices)
        index: list[int | None] = [None] * n
        res: list[EpisodeResult | None] = [None] * n
        obs: list = [None] * n
        results: list[EpisodeResult] = []
        device_policy = callable(getattr(policy, "act_device", None))
        idle = np.zeros((n, spec.action_dim), dtype=np.float32)  # idle worlds hold (zero delta)
        if spec.action.control_mode.value == "joint_position":
            idle = None  # joint targets: idle worlds get their last commanded targets below

        def start(worlds: list[int]) -> None:
            picked = []
            for w in worlds:
                if not todo:
                    break
                i = todo.popleft()
                index[w] = i
                res[w] = EpisodeResult(index=i, seed=seed + i, success=False, steps=0, reward=0.0)
                policy.reset(w, spec)
                if on_start:
                    on_start(w, i)
                picked.append(w)
            if not picked:
                return
            batch.reset(picked, [seed + index[w] for w in picked])
            if not device_policy:
                for w, o in zip(picked, world_observations(batch, picked, [policy.observe_next(w) for w in picked])):
                    obs[w] = o

        start(list(range(n)))
        last = np.zeros((n, spec.action_dim), dtype=np.float32)
        while any(i is not None for i in index):
            busy = [w for w in range(n) if index[w] is not None]
            t0 = time.perf_counter()
            if device_policy:
                acts = policy.act_device(batch.device_observation())
            else:
                got = np.asarray(policy.act_batch(busy, [obs[w] for w in busy]), dtype=np.float32)
                if got.shape != (len(busy), spec.action_dim):
                    raise SimulationError(f"act_batch returned shape {got.shape} for {len(busy)} environments")
                acts = idle.copy() if idle is not None else last.copy()
                acts[busy] = got
                last = acts
            policy_ms = (time.perf_counter() - t0) * 1e3
            t0 = time.perf_counter()
            r = batch.step(acts)
            step_ms = (time.perf_counter() - t0) * 1e3
            ended = []
            for w in busy:
                e = res[w]
                e.steps += 1
                e.reward += float(r.reward[w])
                e.step_ms.append(step_ms)
                e.policy_ms.append(policy_ms)
                if r.success[w]:
                    e.success = True
                if on_step:
                    on_step(w, index[w], e.steps)
                if r.terminated[w] or r.truncated[w] or e.steps >= spec.task.max_steps:
                    ended.append(w)
            for w in ended:
                e = res[w]
                e.diagnostics = batch.diagnostics(w)
                results.append(e)
                if on_done:
                    on_done(e)
                index[w], res[w], obs[w] = None, None, None
            cont = [w for w in busy if w not in ended]
            if cont and not device_policy:
                for w, o in zip(cont, world_observations(batch, cont, [policy.observe_next(w) for w in cont])):
                    obs[w] = o
            if ended:
                start(ended)
        return results


def make_vector_env(cfg, base_dir: Path, num_envs: int, recipe_factory: Callable | None = None, **kwargs):
    """The vector environment for a scene: ``WarpVectorEnv`` (N worlds, one process) when its engine is
    ``mujoco_warp``, else the vector runner's worker processes (``recipe_factory()`` -> VectorEnv)."""
    if cfg.engine.name == "mujoco_warp":
        return WarpVectorEnv.from_config(cfg, base_dir, num_envs, **kwargs)
    if recipe_factory is None:
        raise ConfigError(f"engine {cfg.engine.name!r} runs vectorized through worker processes (runner.vector)")
    return recipe_factory()
