"""LIBERO's reset states, computed by LIBERO itself (``native.resets``) and cached on disk.

A reset state is what ``backends.libero`` leaves right before its settle steps for an episode seed: ``seed``,
``reset``, ``set_init_state(init_states[seed % 50])``. It holds the MuJoCo state, the model arrays the reset
changed (the fixtures' ``body_pos`` / ``body_quat``: LIBERO's seeded sampler places them, the init state does
not hold them), the controller's state and the init state's index. Cached per (versions, suite, task, seed):
episode seed ``s`` gets init state ``s % 50`` and seed ``s``'s fixtures whatever the batch, its size, or which
episodes end first.
"""

from __future__ import annotations

import os
import pickle
from pathlib import Path
from typing import Any

from simseam.backends.libero_gpu.model import cache_dir

#: what a cached reset state holds (``native.resets``' answer); another format is another folder
FORMAT = 2


class ResetCache:
    """``get(seeds)`` -> one reset state per seed, from disk or from the native worker (asked once for every
    missing one)."""

    def __init__(self, worker: Any, info: dict[str, Any]):
        self.worker, self.info = worker, info
        self.suite, self.task = info["suite"], int(info["task"])
        self.folder = cache_dir(info) / f"resets-v{FORMAT}" / f"{self.suite}-{self.task}"

    def _path(self, seed: int) -> Path:
        return self.folder / f"{seed}.pkl"

    def get(self, seeds: list[int]) -> list[dict[str, Any]]:
        seeds = [int(s) for s in seeds]
        missing = sorted({s for s in seeds if not self._path(s).is_file()})
        if missing:
            fresh = self.worker.call("resets", suite=self.suite, task=self.task, seeds=missing)
            self.folder.mkdir(parents=True, exist_ok=True)
            for seed, state in zip(missing, fresh):
                tmp = self._path(seed).with_suffix(".partial")
                tmp.write_bytes(pickle.dumps(state, protocol=4))
                os.replace(tmp, self._path(seed))
        loaded = {s: pickle.loads(self._path(s).read_bytes()) for s in dict.fromkeys(seeds)}
        return [loaded[s] for s in seeds]
