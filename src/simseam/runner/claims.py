"""Whole tasks taken one at a time by the processes of one run (``simseam eval --processes K``).

A port's task is one batch, so a run of K processes deals whole tasks. Dealt in advance (task ``ti`` to the
process ``ti % K``), a process that drew the short tasks idles while another steps its long ones. Claimed, each
process takes the next task nobody holds when it is free: ``TaskClaims.take`` creates the task's claim file in a
folder the K processes share, atomically and only if it is not there (``os.link`` of a file already holding the
owner's number, so a kill never leaves a claim without its owner). Which process runs a task then depends on
timing, never what the task's episodes are: episode ``e`` of a task keeps its seed and its world in the task's
batch.

A resumed run (``--resume``) keeps the folder: a process takes back the tasks it claimed before (whose episodes
its own run directory holds, all or some) and claims the ones nobody holds; the tasks of another process wait
for that process.
"""

from __future__ import annotations

import os
import tempfile
from pathlib import Path
from typing import Callable, Iterable, TypeVar

T = TypeVar("T")


class TaskClaims:
    """Claims of the tasks (by their index in the run's task list) in ``folder``, for process ``owner``."""

    def __init__(self, folder: str | os.PathLike, owner: int):
        self.folder, self.owner = Path(folder), int(owner)
        self.folder.mkdir(parents=True, exist_ok=True)

    def _path(self, task: int) -> Path:
        return self.folder / f"task-{int(task)}"

    def holder(self, task: int) -> int | None:
        """The process holding ``task``, or None when nobody claimed it."""
        try:
            return int(self._path(task).read_text())
        except FileNotFoundError:
            return None

    def take(self, task: int) -> bool:
        """Whether this process runs ``task``: claimed now, or by this process before (a resumed run)."""
        fd, tmp = tempfile.mkstemp(dir=self.folder, prefix=".claim-")
        try:
            with os.fdopen(fd, "w") as f:
                f.write(str(self.owner))
            os.link(tmp, self._path(task))  # fails if the claim exists: one process wins
            return True
        except FileExistsError:
            return self.holder(task) == self.owner
        finally:
            os.unlink(tmp)

    def unclaimed(self, parts: Iterable[T], task_of: Callable[[T], int]) -> T | None:
        """The first of ``parts`` nobody holds yet (what a process may prepare ahead: it claims it only when it
        gets there, and whoever runs it reads what the preparation left in the disk caches), or None."""
        return next((p for p in parts if self.holder(task_of(p)) is None), None)
