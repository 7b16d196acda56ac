"""Fixtures for the benchmark backends: their provisioned venvs (scripts/bootstrap.sh provisions
them in set-up; a missing one FAILS the test with the command to run, it is never skipped)."""

from __future__ import annotations

import json
import os
import subprocess
from pathlib import Path

import numpy as np
import pytest
from backend_util import backend_python

HERE = Path(__file__).resolve().parent


class _NativeEpisode:
    """A native episode running in its own process (the backend's venv); ``result()`` waits for its arrays."""

    def __init__(self, backend: str, proc: subprocess.Popen, out: Path, log: Path):
        self.backend, self.proc, self.out, self.log = backend, proc, out, log
        self._arrays: dict | None = None

    def result(self) -> dict:
        if self._arrays is None:
            rc = self.proc.wait(timeout=280)
            assert rc == 0, f"native {self.backend} episode failed:\n{self.log.read_text()[-3000:]}"
            with np.load(self.out) as z:
                self._arrays = {k: z[k] for k in z.files}
        return self._arrays


@pytest.fixture
def run_native(tmp_path):
    """``run_native(backend, config, seed, actions) -> dict of arrays`` from the native env (its own venv).
    ``run_native.start(...)`` starts the same episode and returns at once (``.result()`` waits for it): the
    peer, mostly importing its simulator, runs while the test drives the seam's side."""
    started = []

    def start(backend: str, config: dict, seed: int, actions: np.ndarray) -> _NativeEpisode:
        python = backend_python(backend)
        k = len(started)
        np.save(tmp_path / f"actions{k}.npy", np.asarray(actions, dtype=np.float32))
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
        env.setdefault("MUJOCO_GL", "egl")
        if backend == "maniskill":  # SAPIEN renders with the same Vulkan driver as simseam's sidecar
            from simseam.backends.software_vulkan import sidecar_env

            env.update(sidecar_env())
        env["PYGAME_HIDE_SUPPORT_PROMPT"] = "1"
        log = tmp_path / f"native{k}.log"
        with log.open("w") as f:  # a file, not a pipe: nobody reads it while the test runs
            proc = subprocess.Popen([python, str(HERE / "native_episode.py"), backend, json.dumps(config), str(seed),
                                     str(tmp_path / f"actions{k}.npy"), str(tmp_path / f"native{k}.npz")],
                                    stdout=subprocess.DEVNULL, stderr=f, env=env)
        started.append(proc)
        return _NativeEpisode(backend, proc, tmp_path / f"native{k}.npz", log)

    def run(backend: str, config: dict, seed: int, actions: np.ndarray) -> dict:
        return start(backend, config, seed, actions).result()

    run.start = start
    yield run
    for proc in started:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


@pytest.fixture
def open_backend():
    """``open_backend(name, config, privileged=False, num_envs=None)``: a SidecarRollout (a SidecarBatchRollout of
    ``num_envs``), closed after the test."""
    from simseam.sidecar.benchmark import open_benchmark

    opened = []

    def make(name: str, config: dict, privileged: bool = False, num_envs: int | None = None):
        backend_python(name)
        r = open_benchmark(name, config, privileged=privileged, num_envs=num_envs)
        opened.append(r)
        return r

    yield make
    for r in opened:
        r.close()
