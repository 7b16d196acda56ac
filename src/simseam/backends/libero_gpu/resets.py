"""LIBERO's reset states, computed by LIBERO itself (``native.resets``) and cached on disk.

A reset state is what ``backends.libero`` leaves for an episode seed after ``seed``, ``reset``,
``set_init_state(init_states[seed % 50])`` and ``settle`` of its settle steps, run by LIBERO itself. It holds the
MuJoCo state, the model arrays the reset changed (the fixtures' ``body_pos`` / ``body_quat``: LIBERO's seeded
sampler places them, the init state does not hold them), the controller's state, the observables' clock and the
init state's index. Cached per (versions, suite, task, settle, seed): episode seed ``s`` gets init state
``s % 50`` and seed ``s``'s fixtures whatever the batch, its size, or which episodes end first.

Why LIBERO settles natively: an init state holds objects up to ~14 cm above where they come to rest
(libero_spatial/5's bowl drops onto a ramekin), and where they land is chaotic. On CPU MuJoCo, the port's own
settle from LIBERO's reset state lands within 6e-13 of LIBERO's; a 1e-5 nudge of that state lands the bowl
5 cm away in one try of four, and MuJoCo Warp's float32 lands it there on every init state tried, where LIBERO's
expert then fails. Settled natively, the worlds start from the state LIBERO's own episode starts from.
"""

from __future__ import annotations

from typing import Any

from simseam.backends.libero_gpu.model import cache_dir
from simseam.backends.native_worker import cached_answers

#: what a cached reset state holds (``native.resets``' answer); another format is another folder
FORMAT = 3


class ResetCache:
    """``get(seeds)`` -> one reset state per seed after ``settle`` native settle steps, from disk or from the
    native worker (asked once for every missing one)."""

    def __init__(self, worker: Any, info: dict[str, Any], settle: int = 0):
        self.worker, self.info, self.settle = worker, info, int(settle)
        self.suite, self.task = info["suite"], int(info["task"])
        self.folder = cache_dir(info) / f"resets-v{FORMAT}" / f"{self.suite}-{self.task}" / f"settle-{self.settle}"

    def get(self, seeds: list[int]) -> list[dict[str, Any]]:
        return cached_answers(self.folder, [int(s) for s in seeds], lambda missing: self.worker.call(
            "resets", suite=self.suite, task=self.task, seeds=missing, settle=self.settle))
