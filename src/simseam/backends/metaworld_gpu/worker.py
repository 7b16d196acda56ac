"""The client of the native worker (``native.py``): one process of Meta-World's provisioned interpreter,
started once and asked many times (``describe``, ``resets``, ``replay``, ``expert``).

The worker imports this checkout's ``simseam`` (a symlink on its path, as the sidecar does), so the reset
it performs is the very code ``simseam eval metaworld_*`` runs.
"""

from __future__ import annotations

import os
import pickle
import subprocess
import tempfile
from pathlib import Path
from typing import Any

from simseam.backends.metaworld_gpu.native import HEADER
from simseam.seam.errors import BackendUnavailableError, SimulationError


class NativeWorker:
    """``with NativeWorker() as w: w.call("resets", task=..., ...)``. ``python``: the interpreter
    (default: the provisioned metaworld venv's; ``BackendUnavailableError`` naming the command that
    provisions it when absent)."""

    def __init__(self, python: str | os.PathLike | None = None):
        if python is None:
            from simseam.backends.provision import require

            python = require("metaworld")
        self.python = str(python)
        self._described: dict[str, Any] = {}
        self._tmp = tempfile.TemporaryDirectory(prefix="simseam-mwgpu-")
        os.symlink(Path(__file__).resolve().parents[2], Path(self._tmp.name) / "simseam")
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONHOME", "VIRTUAL_ENV", "PYTHONPATH")}
        env.update(PYTHONPATH=self._tmp.name, MUJOCO_GL=env.get("MUJOCO_GL", "egl"))
        self._proc = subprocess.Popen([self.python, "-m", "simseam.backends.metaworld_gpu.native"],
                                      stdin=subprocess.PIPE, stdout=subprocess.PIPE, env=env)
        status, what = self._receive("start")
        if status != "ok":
            raise BackendUnavailableError(f"metaworld native worker ({self.python}) failed to start: {what}")

    def call(self, command: str, **kwargs: Any) -> Any:
        """Run ``command`` in the worker; its exception comes back as a ``SimulationError`` naming it.
        ``describe`` is asked once per task (its answer is the same for the worker's life; callers only read it)."""
        if command == "describe":
            key = kwargs["task"]
            if key not in self._described:
                self._described[key] = self._call(command, **kwargs)
            return self._described[key]
        return self._call(command, **kwargs)

    def _call(self, command: str, **kwargs: Any) -> Any:
        if self._proc is None:
            raise SimulationError("metaworld native worker: called after close()")
        blob = pickle.dumps((command, kwargs), protocol=4)
        self._proc.stdin.write(HEADER.pack(len(blob)) + blob)
        self._proc.stdin.flush()
        status, result = self._receive(command)
        if status != "ok":
            raise SimulationError(f"metaworld native worker: {command}({_brief(kwargs)}) failed: {result}")
        return result

    def _receive(self, what: str) -> tuple[str, Any]:
        head = self._proc.stdout.read(HEADER.size)
        if len(head) < HEADER.size:
            rc = self._proc.poll()
            raise BackendUnavailableError(f"metaworld native worker exited (rc={rc}) during {what}; "
                                          "its stderr above says why")
        return pickle.loads(self._proc.stdout.read(HEADER.unpack(head)[0]))

    def close(self) -> None:
        if self._proc is not None:
            proc, self._proc = self._proc, None
            proc.stdin.close()
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            proc.stdout.close()
        self._tmp.cleanup()

    def __enter__(self) -> "NativeWorker":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _brief(kwargs: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v!r}" for k, v in kwargs.items() if isinstance(v, (str, int, float)))
