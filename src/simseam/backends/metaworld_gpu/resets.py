"""Native reset states, computed by Meta-World itself (``native.resets``) and cached on disk.

A reset state is what ``MetaWorldRollout._native_reset(seed)`` leaves: qpos, qvel, mocap pose, ctrl, act,
the solver's warm start, the observation, every model array the reset changed (against the freshly
compiled model) and the env's numeric attributes. Cached per (versions, task, variation, goal seed, key):
``key`` is ``seed % 50`` for ``mt1`` and ``ml1`` (50 fixed variations: seeds s and s + 50 are one episode) and
the seed itself for ``sampled`` and ``lerobot``. Episode i gets its own seed's state whatever the batch.
"""

from __future__ import annotations

from typing import Any

from simseam.backends.metaworld_gpu.model import cache_dir
from simseam.backends.native_worker import cached_answers

N_VARIATIONS = 50


def state_key(variation: str, seed: int) -> int:
    return int(seed) % N_VARIATIONS if variation in ("mt1", "ml1") else int(seed)


class ResetCache:
    """``get(seeds)`` -> one reset state per seed, from disk or from the native worker (asked once for
    every missing one)."""

    def __init__(self, worker: Any, info: dict[str, Any], variation: str, goal_seed: int):
        self.worker, self.info = worker, info
        self.task, self.variation, self.goal_seed = info["task"], variation, int(goal_seed)
        self.folder = cache_dir(info) / "resets" / self.task / f"{variation}-goal{self.goal_seed}"

    def get(self, seeds: list[int]) -> list[dict[str, Any]]:
        """Worlds that share a variation (``mt1`` / ``ml1``: seeds s and s + 50) share its read-only state."""
        keys = [state_key(self.variation, s) for s in seeds]
        return cached_answers(self.folder, keys, lambda missing: self.worker.call(
            "resets", task=self.task, variation=self.variation, goal_seed=self.goal_seed, seeds=missing))
