"""The client of Meta-World's native worker (``native.py``): one process of Meta-World's provisioned
interpreter, started once and asked many times (``describe``, ``resets``, ``replay``, ``expert``); the
protocol is ``backends.native_worker``'s.
"""

from __future__ import annotations

import os

from simseam.backends import native_worker


class NativeWorker(native_worker.NativeWorker):
    """``with NativeWorker() as w: w.call("resets", task=..., ...)``. ``python``: the interpreter
    (default: the provisioned metaworld venv's; ``BackendUnavailableError`` naming the command that
    provisions it when absent). ``versions`` is asked once; ``describe`` is not kept in memory (~40 MB a task: a
    cold MT50 run in one process would hold 2 GB): ``model.described`` keeps what a batch needs on disk."""

    once = ("versions",)

    def __init__(self, python: str | os.PathLike | None = None):
        super().__init__("metaworld", "simseam.backends.metaworld_gpu.native", python)
