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


@pytest.fixture
def run_native(tmp_path):
    """``run_native(backend, config, seed, actions) -> dict of arrays`` from the native env (its own venv)."""

    def run(backend: str, config: dict, seed: int, actions: np.ndarray) -> dict:
        python = backend_python(backend)
        np.save(tmp_path / "actions.npy", np.asarray(actions, dtype=np.float32))
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME")}
        env.setdefault("MUJOCO_GL", "egl")
        if backend == "maniskill":  # SAPIEN renders with the same Vulkan driver as simseam's sidecar
            from simseam.backends.software_vulkan import sidecar_env

            env.update(sidecar_env())
        env["PYGAME_HIDE_SUPPORT_PROMPT"] = "1"
        out = subprocess.run([python, str(HERE / "native_episode.py"), backend, json.dumps(config), str(seed),
                              str(tmp_path / "actions.npy"), str(tmp_path / "native.npz")],
                             capture_output=True, text=True, env=env, timeout=280)
        assert out.returncode == 0, f"native {backend} episode failed:\n{out.stderr[-3000:]}"
        with np.load(tmp_path / "native.npz") as z:
            return {k: z[k] for k in z.files}

    return run


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
