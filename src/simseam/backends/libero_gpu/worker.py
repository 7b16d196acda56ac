"""The client of LIBERO's native worker (``native.py``): one process of the LIBERO backend's provisioned
interpreter (``describe``, ``record``); the protocol is ``backends.native_worker``'s."""

from __future__ import annotations

import os

from simseam.backends import native_worker


class NativeWorker(native_worker.NativeWorker):
    """``with NativeWorker() as w: w.call("describe", suite="libero_spatial", task=0)``. ``python``: the
    interpreter (default: the provisioned libero venv's; ``BackendUnavailableError`` naming the command that
    provisions it when absent). Nothing is kept: a task's ``describe`` is tens of MB (its meshes), asked once
    by whoever builds its model."""

    once = ()

    def __init__(self, python: str | os.PathLike | None = None):
        super().__init__("libero", "simseam.backends.libero_gpu.native", python)
