"""The sidecar runs in another interpreter: its own virtualenv, on another Python version
when the machine has one (3.12 <-> 3.11), selected by a scene file; and the server needs
nothing but numpy, msgpack and pyzmq (plus the engine SDK).

The venvs are built once by ``sidecar_venvs.py``: their packages in a venv cached outside the
clone (first run: pip, from its cache or the package registry), the venv the sidecar runs in per
clone under ``.cache/`` without pip (later runs: stamp files, nothing made). The build happens in
session fixtures, outside every test's own work.
"""

from __future__ import annotations

import os
import subprocess
import sys

import pytest
import sidecar_venvs
from sidecar_util import actions, assert_same

from simseam.runner.scene_config import build_rollout, load_scene_config
from simseam.sidecar.client import SidecarRollout


@pytest.fixture(scope="session")
def full_venv():
    """(python, (major, minor)) of the engine venv: numpy, msgpack, pyzmq, mujoco, so101 assets, simseam."""
    return sidecar_venvs.sidecar_venv("full")


@pytest.fixture(scope="session")
def lean_venv():
    """(python, (major, minor)) of a venv with only numpy, msgpack, pyzmq and simseam (--no-deps)."""
    return sidecar_venvs.sidecar_venv("lean")


def _scene(tmp_path, name: str, engine: str) -> tuple:
    path = tmp_path / name
    path.write_text(f"robot: so101\nengine: {engine}\nlayout: lift_cube\nimage_size: [32, 32]\nmax_steps: 12\n")
    return load_scene_config(path)


def test_full_episode_in_another_interpreter_matches_in_process(full_venv, tmp_path):
    python, version = full_venv
    want = f"{version[0]}.{version[1]}"
    if sidecar_venvs.base_python()[1] != sys.version_info[:2]:
        assert version != sys.version_info[:2]  # the machine has another Python: the sidecar runs on it
    cfg, base = _scene(tmp_path, "remote.yaml", f"{{name: mujoco, process: sidecar, python: {python}}}")
    local_cfg, _ = _scene(tmp_path, "local.yaml", "mujoco")
    remote = build_rollout(cfg, base)
    local = build_rollout(local_cfg, base)
    try:
        assert isinstance(remote, SidecarRollout)
        assert remote.server_python.rsplit(".", 1)[0] == want  # hello reports the sidecar's Python
        assert remote.fast and remote._slots is not None  # the local fast path, images in the shared ring
        exe = os.path.realpath(f"/proc/{remote.pid}/exe")
        assert os.path.basename(exe).startswith(f"python{want}") or exe == os.path.realpath(python)
        assert remote.spec.to_json() | {"backend": "", "capabilities": []} == local.spec.to_json() | {
            "backend": "", "capabilities": []}
        assert remote.spec.robot.name == "so101" and remote.spec.cameras == {"camera1": (32, 32), "camera2": (32, 32)}
        assert_same(remote.reset(seed=2), local.reset(seed=2))
        steps = 0
        for a in actions(seed=9, n=100, dim=remote.action_dim):
            r, lo = remote.step(a), local.step(a)
            assert_same(r.observation, lo.observation, f"step {steps}")
            assert (r.reward, r.terminated, r.truncated) == (lo.reward, lo.terminated, lo.truncated)
            # float64 diagnostics: the two interpreters' numpy builds (IK's linear algebra) may differ in
            # the last bits of the state, which float32 observations do not show
            assert {k: v for k, v in r.info.items() if k != "diagnostics"} == {
                k: v for k, v in lo.info.items() if k != "diagnostics"}
            assert r.info["diagnostics"] == pytest.approx(lo.info["diagnostics"], rel=1e-9, abs=1e-12)
            steps += 1
            if r.terminated or r.truncated:
                break
        assert steps == 12 and r.truncated  # a full episode, to its step limit
        assert r.observation["images"]["camera2"].std() > 5
        # the next episode on the same sidecar
        pid = remote.pid
        assert_same(remote.reset(seed=3), local.reset(seed=3))
        assert remote.pid == pid
    finally:
        remote.close()
        local.close()


def test_server_imports_with_numpy_msgpack_pyzmq_only(lean_venv):
    python, _ = lean_venv
    forbidden = ["pydantic", "typer", "rich", "yaml", "mujoco", "simseam.cli", "simseam.runner",
                 "simseam.policies", "simseam.robot.manifest"]
    code = (
        "import importlib.util, sys\n"
        "import simseam.sidecar.server, simseam.sidecar.wire\n"
        f"loaded = [m for m in {forbidden!r} if m in sys.modules]\n"
        "installed = [m for m in ('pydantic', 'typer', 'rich', 'yaml', 'mujoco') if importlib.util.find_spec(m)]\n"
        "print(loaded, installed, simseam.sidecar.server.__file__)\n"
    )
    out = subprocess.run([str(python), "-c", code], capture_output=True, text=True, timeout=60, env=_clean_env())
    assert out.returncode == 0, out.stderr
    where = out.stdout.split()[-1]
    assert out.stdout.startswith("[] []"), out.stdout  # nothing else was imported, nothing else is installed
    assert where.startswith(str(sidecar_venvs.REPO / "src")), where  # the working tree's code
    # the server's command line works there too
    out = subprocess.run([str(python), "-m", "simseam.sidecar.server", "--help"], capture_output=True, text=True,
                         timeout=60, env=_clean_env())
    assert out.returncode == 0 and "--boot" in out.stdout, out.stderr


def test_venv_cache_is_reused_without_pip(full_venv, lean_venv, monkeypatch):
    """A second run finds the stamp files: no venv is created, pip is never run (offline, fast)."""
    calls = []
    real = subprocess.run

    def spy(argv, *a, **kw):
        calls.append([str(x) for x in argv])
        return real(argv, *a, **kw)

    monkeypatch.setattr(sidecar_venvs.subprocess, "run", spy)
    assert sidecar_venvs.sidecar_venv("full") == full_venv
    assert sidecar_venvs.sidecar_venv("lean") == lean_venv
    assert not [c for c in calls if "pip" in c or "venv" in c], calls


def _clean_env() -> dict:
    return {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
