"""Vectorized episodes on MuJoCo Warp: N worlds in one process instead of N worker processes.

``WarpVectorEnv`` offers the vector runner's interface (``spec``, ``num_envs``, ``run(policy,
indices, seed=..., on_start, on_step, on_done, ...)``, ``close``) over one ``BatchedScene``: its
worlds as a ``BatchRollout`` (``WarpBatchRollout``; environment ``j`` is world ``j``) run by the
episode scheduler (``runner.scheduler``), with the same per-environment semantics as the worker
processes. A policy with ``act_device(state)`` gets the batch's device arrays instead
(``BatchedScene.device_observation()``, no host copy). ``make_vector_env`` picks it for scenes
whose engine is ``mujoco_warp``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable, Sequence

from simseam.runner.episodes import EpisodeResult
from simseam.runner.scheduler import run_batch
from simseam.seam import ConfigError


def build_batched_scene(cfg, base_dir: Path, num_envs: int | None = None, *, privileged: bool = False,
                        render_images: bool = True, seed: int = 0, device: str | None = None):
    """The ``BatchedScene`` a scene file with ``engine: {name: mujoco_warp, num_envs: N}`` describes."""
    from simseam.scene.warp import BatchedScene, WarpOptions
    from simseam.runner.scene_config import check_engine, resolve_robot, scene_options

    eng = cfg.engine
    if not check_engine(cfg).batched:
        raise ConfigError(f"a batched scene needs a batched engine (mujoco_warp), got {eng.name!r}")
    n = num_envs or eng.num_envs or 1
    options = scene_options(cfg, privileged=privileged, render_images=render_images, seed=seed)
    return BatchedScene(resolve_robot(cfg, base_dir), cfg.task, n, options,
                        WarpOptions(device=device or eng.device))


class WarpVectorEnv:
    """``num_envs`` worlds of one scene on MuJoCo Warp behind the vector runner's interface."""

    def __init__(self, batch):
        from simseam.scene.warp import WarpBatchRollout

        self.batch = batch
        self.rollout = WarpBatchRollout(batch)
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
        """Run episodes ``indices`` with the episode scheduler (``runner.scheduler``); callbacks as the
        vector runner's (no worker can fail here: ``max_attempts``, ``on_error`` and
        ``on_worker_failure`` go unused)."""
        if video_dir is not None:
            raise ConfigError("engine 'mujoco_warp': videos are not recorded in batched runs (drop --video)")
        return run_batch(self.rollout, policy, indices, seed=seed, on_start=on_start, on_step=on_step,
                         on_done=on_done)


def make_vector_env(cfg, base_dir: Path, num_envs: int, recipe_factory: Callable | None = None, **kwargs):
    """The vector environment for a scene: ``WarpVectorEnv`` (N worlds, one process) when its engine is
    ``mujoco_warp``, else the vector runner's worker processes (``recipe_factory()`` -> VectorEnv)."""
    from simseam.engines.registry import engine_info

    if cfg.benchmark is None and engine_info(cfg.engine.name).batched:
        return WarpVectorEnv.from_config(cfg, base_dir, num_envs, **kwargs)
    if recipe_factory is None:
        raise ConfigError(f"engine {cfg.engine.name!r} runs vectorized through worker processes (runner.vector)")
    return recipe_factory()
