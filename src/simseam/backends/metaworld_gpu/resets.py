"""Native reset states, computed by Meta-World itself (``native.resets``) and cached on disk.

A reset state is what ``MetaWorldRollout._native_reset(seed)`` leaves: qpos, qvel, mocap pose, ctrl, act,
the solver's warm start, the observation, every model array the reset changed (against the freshly
compiled model) and the env's numeric attributes. Cached per (versions, task, variation, goal seed, key):
``key`` is ``seed % 50`` for ``mt1`` and ``ml1`` (50 fixed variations: seeds s and s + 50 are one episode) and
the seed itself for ``sampled`` and ``lerobot``. Episode i gets its own seed's state whatever the batch.
"""

from __future__ import annotations

import os
import pickle
from pathlib import Path
from typing import Any

from simseam.backends.metaworld_gpu.model import cache_dir

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

    def _path(self, key: int) -> Path:
        return self.folder / f"{key}.pkl"

    def get(self, seeds: list[int]) -> list[dict[str, Any]]:
        keys = [state_key(self.variation, s) for s in seeds]
        missing = sorted({k for k in keys if not self._path(k).is_file()})
        if missing:
            # mt1 / ml1: the key is a seed of that variation; sampled / lerobot: the seed itself
            fresh = self.worker.call("resets", task=self.task, variation=self.variation, goal_seed=self.goal_seed,
                                     seeds=missing)
            self.folder.mkdir(parents=True, exist_ok=True)
            for key, state in zip(missing, fresh):
                tmp = self._path(key).with_suffix(".partial")
                tmp.write_bytes(pickle.dumps(state, protocol=4))
                os.replace(tmp, self._path(key))
        loaded = {k: pickle.loads(self._path(k).read_bytes()) for k in dict.fromkeys(keys)}
        return [loaded[k] for k in keys]  # worlds that share a variation share its (read-only) state
