"""A manifest scene batched on MuJoCo Warp: N worlds in one process on a GPU (or warp's CPU device).

``BatchedScene`` (batched reset / step / render) and ``WarpRollout`` (one
world behind the ``SimRollout`` seam), ``WarpBatchRollout`` (the worlds behind the ``BatchRollout`` seam,
observations as device arrays through ``world_arrays``). The scene's semantics come from the CPU ``ManifestScene``;
the physics and the kernels from ``simseam.engines.mujoco_warp``. Needs the ``warp`` extra:
``mujoco-warp`` and ``warp-lang``.
"""

from simseam.scene.warp.batched import BatchedScene, BatchStep, WarpOptions
from simseam.scene.warp.rollout import WarpBatchRollout, WarpRollout, world_arrays, world_observations


def open_batch(robot, task: str, num_envs: int, options=None, device: str | None = None) -> BatchedScene:
    """The engine table's factory for ``mujoco_warp`` (``engines.registry.open_batched``): ``num_envs``
    worlds of ``task`` with ``robot`` on ``device`` (default: warp's preferred one)."""
    return BatchedScene(robot, task, num_envs, options, WarpOptions(device=device))


__all__ = ["BatchStep", "BatchedScene", "WarpBatchRollout", "WarpOptions", "WarpRollout", "open_batch",
           "world_arrays", "world_observations"]
