"""MuJoCo Warp: N worlds of a manifest scene in one process on a GPU (or warp's CPU device).

``BatchedScene`` (batched reset / step / render, device observations) and ``WarpRollout`` (one
world behind the ``SimRollout`` seam). Needs the ``warp`` extra: ``mujoco-warp`` and ``warp-lang``.
"""

from simseam.engines.mujoco_warp.batched import BatchedScene, BatchStep, WarpOptions
from simseam.engines.mujoco_warp.rollout import WarpRollout, world_observations

__all__ = ["BatchStep", "BatchedScene", "WarpOptions", "WarpRollout", "world_observations"]
