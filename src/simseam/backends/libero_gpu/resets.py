"""LIBERO's reset states, computed by LIBERO itself (``native.resets``) and cached on disk.

A reset state is what ``backends.libero`` leaves for an episode seed after ``seed``, ``reset``,
``set_init_state(init_states[seed % 50])`` and ``settle`` of its settle steps, run by LIBERO itself. It holds the
MuJoCo state, the model arrays the reset changed (the fixtures' ``body_pos`` / ``body_quat``: LIBERO's seeded
sampler places them, the init state does not hold them), the controller's state, the observables' clock and the
init state's index. Cached per (versions, suite, task, settle, seed): episode seed ``s`` gets init state
``s % 50`` and seed ``s``'s fixtures whatever the batch, its size, or which episodes end first. The seeds missing
from the cache are reset by several LIBERO processes at once, each a contiguous run of them in order; where
LIBERO's sampler places a seed's fixtures depends on the resets its env ran before, so the first run that asks
for a seed fixes its placement, as it did with one process.

Why LIBERO settles natively: an init state holds objects up to ~14 cm above where they come to rest
(libero_spatial/5's bowl drops onto a ramekin), and where they land is chaotic. On CPU MuJoCo, the port's own
settle from LIBERO's reset state lands within 6e-13 of LIBERO's; a 1e-5 nudge of that state lands the bowl
5 cm away in one try of four, and MuJoCo Warp's float32 lands it there on every init state tried, where LIBERO's
expert then fails. Settled natively, the worlds start from the state LIBERO's own episode starts from.
"""

from __future__ import annotations

from typing import Any

from simseam.backends.libero_gpu.model import cache_dir
from simseam.backends.native_worker import cached_answers, helpers_for, split

#: what a cached reset state holds (``native.resets``' answer); another format is another folder
FORMAT = 3


class ResetCache:
    """``get(seeds)`` -> one reset state per seed after ``settle`` native settle steps, from disk or from the
    native worker and its helpers (asked once for every missing one)."""

    def __init__(self, worker: Any, info: dict[str, Any], settle: int = 0):
        self.worker, self.info, self.settle = worker, info, int(settle)
        self.suite, self.task = info["suite"], int(info["task"])
        self.folder = cache_dir(info) / f"resets-v{FORMAT}" / f"{self.suite}-{self.task}" / f"settle-{self.settle}"

    def get(self, seeds: list[int]) -> list[dict[str, Any]]:
        return cached_answers(self.folder, [int(s) for s in seeds], self._ask)

    def _ask(self, missing: list[int]) -> list[dict[str, Any]]:
        """The missing seeds' resets, by LIBERO in several processes at once (``native_worker.helpers_for``: one
        per 4 seeds, at most the cores less one; a reset takes LIBERO about a second, and a task's 50 one after
        another were most of a GPU batch's wall time), each process a contiguous run of the seeds in order."""
        runs = split(missing, helpers_for(len(missing)))
        answers = self.worker.map("resets", [dict(suite=self.suite, task=self.task, seeds=run, settle=self.settle)
                                             for run in runs])
        return [state for run in answers for state in run]
