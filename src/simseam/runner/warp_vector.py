"""Vectorized episodes without worker processes: N worlds on MuJoCo Warp, or a benchmark's own batch.

``WarpVectorEnv`` is the episode scheduler's ``BatchVectorEnv`` over one ``BatchedScene``'s worlds
(``WarpBatchRollout``; environment ``j`` is world ``j``), with the same per-environment semantics as the
worker processes. A policy with ``act_arrays(observations)`` gets the batch's observations as device
arrays instead (``WarpBatchRollout.observation_arrays()``, no host copy; runner.scheduler). ``make_vector_env`` picks it for scenes whose
engine is ``mujoco_warp``, a sidecar batch (``SidecarBatchRollout``) for a benchmark whose backend
simulates the environments together (ManiSkill3 on ``physx_cuda``), a benchmark's port to a batched engine
(``engine: mujoco_warp`` with ``benchmark: {name: metaworld}``: ``MetaWorldBatchRollout``; ``libero``:
``LiberoBatchRollout``), and the worker
processes otherwise.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable

from simseam import registry
from simseam.runner.scheduler import BatchVectorEnv
from simseam.seam import ConfigError


def build_batched_scene(cfg, base_dir: Path, num_envs: int | None = None, *, privileged: bool = False,
                        render_images: bool = True, seed: int = 0, device: str | None = None):
    """The batched scene a scene file with ``engine: {name: mujoco_warp, num_envs: N}`` describes, built by
    the engine table's factory for its engine."""
    from simseam.engines.registry import open_batched
    from simseam.runner.scene_config import check_engine, resolve_robot, scene_options

    eng = cfg.engine
    check_engine(cfg)
    n = num_envs or eng.num_envs or 1
    options = scene_options(cfg, privileged=privileged, render_images=render_images, seed=seed)
    return open_batched(eng.name, resolve_robot(cfg, base_dir), cfg.task, n, options, device or eng.device)


class WarpVectorEnv(BatchVectorEnv):
    """``num_envs`` worlds of one scene on MuJoCo Warp behind the vector runner's interface."""

    def __init__(self, scene):
        from simseam.scene.warp import WarpBatchRollout

        super().__init__(WarpBatchRollout(scene))
        self.scene = scene

    @classmethod
    def from_config(cls, cfg, base_dir: Path, num_envs: int | None = None, **kwargs) -> "WarpVectorEnv":
        return cls(build_batched_scene(cfg, base_dir, num_envs, **kwargs))

    def run(self, policy, indices, *, video_dir: Path | None = None, **kwargs):
        if video_dir is not None:
            raise ConfigError("engine 'mujoco_warp': videos are not recorded in batched runs (drop --video)")
        return super().run(policy, indices, **kwargs)


#: batched engines that run a benchmark of their own: engine -> {benchmark (backend): its port, the
#: ``BatchRollout`` class (simseam.registry: "module:attribute", imported when asked for)}
BENCHMARK_PORTS: dict[str, dict[str, Any]] = {
    "mujoco_warp": {"metaworld": "simseam.backends.metaworld_gpu.rollout:MetaWorldBatchRollout",
                    "libero": "simseam.backends.libero_gpu.rollout:LiberoBatchRollout"},
}


def benchmark_port(engine: str, benchmark: str):
    """The ``BatchRollout`` class of ``benchmark``'s port to the batched ``engine`` (a ``ConfigError`` naming
    the ports there are otherwise)."""
    return registry.load(BENCHMARK_PORTS.get(engine, {}), benchmark, f"benchmark port to {engine}")


def benchmark_on_batched_engine(cfg) -> bool:
    """Whether the scene is a ``benchmark:`` on a batched engine (``engine: mujoco_warp`` with
    ``benchmark: {name: metaworld, ...}``: its port, N worlds in this process); an engine with no port of
    that benchmark is a one-line error."""
    if cfg.benchmark is None or cfg.engine.name not in BENCHMARK_PORTS:
        return False
    if cfg.benchmark.name not in BENCHMARK_PORTS[cfg.engine.name]:
        raise ConfigError(f"engine {cfg.engine.name}: benchmark {cfg.benchmark.name!r} has no {cfg.engine.name} "
                          f"port; benchmarks with one: {', '.join(BENCHMARK_PORTS[cfg.engine.name])}")
    return True


def open_benchmark_batch(cfg, num_envs: int | None, *, privileged: bool = False, render_images: bool = True):
    """The ``BatchRollout`` of a benchmark scene on its batched engine (Meta-World on MuJoCo Warp):
    ``num_envs`` worlds (default the scene's ``engine.num_envs``, else 1) on ``engine.device``."""
    from simseam.runner.scene_config import benchmark_config

    config = {**benchmark_config(cfg, render_images), "name": cfg.benchmark.name}
    n = num_envs or cfg.engine.num_envs or 1
    return benchmark_port(cfg.engine.name, cfg.benchmark.name).open({k: v for k, v in config.items() if k != "name"}, n, privileged=privileged,
                                      device=cfg.engine.device)


def batched_in_one_process(cfg, render_images: bool = True) -> bool:
    """Whether ``make_vector_env`` gives this scene's environments as one batch (MuJoCo Warp's worlds, a
    backend's own batch), stepped from this process, rather than as worker processes."""
    from simseam.backends import backend_module
    from simseam.engines.registry import engine_info

    if cfg.benchmark is None:
        return engine_info(cfg.engine.name).batched
    if benchmark_on_batched_engine(cfg):
        return True
    from simseam.runner.scene_config import benchmark_config

    native = getattr(backend_module(cfg.benchmark.name), "batches_natively", None)
    return native is not None and native(benchmark_config(cfg, render_images))


def make_vector_env(cfg, base_dir: Path, num_envs: int, recipe_factory: Callable | None = None, *,
                    privileged: bool = False, render_images: bool = True, seed: int = 0):
    """The vector environment for a scene: ``WarpVectorEnv`` (N worlds, one process) when its engine is
    ``mujoco_warp``; one sidecar holding the backend's own batch when its benchmark simulates the
    environments together (``batches_natively(config)``); else the worker processes (``recipe_factory()``
    -> VectorEnv)."""
    if not batched_in_one_process(cfg, render_images):
        if recipe_factory is None:
            raise ConfigError(f"engine {cfg.engine.name!r} runs vectorized through worker processes (runner.vector)")
        return recipe_factory()
    if cfg.benchmark is None:
        return WarpVectorEnv.from_config(cfg, base_dir, num_envs, privileged=privileged,
                                         render_images=render_images, seed=seed)
    if benchmark_on_batched_engine(cfg):
        return BatchVectorEnv(open_benchmark_batch(cfg, num_envs, privileged=privileged,
                                                   render_images=render_images))
    from simseam.runner.scene_config import benchmark_config
    from simseam.sidecar.benchmark import open_benchmark

    config = benchmark_config(cfg, render_images)
    return BatchVectorEnv(open_benchmark(cfg.benchmark.name, config, privileged=privileged, num_envs=num_envs,
                                         boot_timeout=max(cfg.engine.boot_timeout_s, 300.0),
                                         request_timeout=max(cfg.engine.request_timeout_s, 120.0)))
