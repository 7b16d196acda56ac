"""Which simseam this process runs: its source directory, its version and, in a git checkout, its revision.

Standard library only (a sidecar's interpreter imports it). ``source_dir()`` is the package directory with
symlinks resolved, so a sidecar that imports this process's simseam through a private link reports the
same directory as this process (``sidecar/client.py`` compares them).
"""

from __future__ import annotations

import functools
import re
import subprocess
from importlib import metadata
from pathlib import Path

GIT_TIMEOUT_S = 10.0


def source_dir() -> Path:
    """The simseam package directory this process imports (resolved)."""
    return Path(__file__).resolve().parent


def checkout_root() -> Path | None:
    """The source checkout holding this package (``pyproject.toml`` next to ``src/simseam``), if any."""
    root = source_dir().parents[1]
    return root if (root / "pyproject.toml").is_file() and source_dir().parent.name == "src" else None


def version() -> str | None:
    """The version of this source: its checkout's ``pyproject.toml`` when it has one, else the
    installed distribution's (an editable install's metadata may belong to another clone)."""
    root = checkout_root()
    if root is not None:
        found = re.search(r'(?m)^version\s*=\s*"([^"]+)"', (root / "pyproject.toml").read_text())
        if found:
            return found.group(1)
    try:
        return metadata.version("simseam")
    except metadata.PackageNotFoundError:
        return None


def _git(root: Path, *args: str) -> str | None:
    try:
        out = subprocess.run(["git", "-C", str(root), *args], capture_output=True, text=True,
                             timeout=GIT_TIMEOUT_S)
    except (OSError, subprocess.TimeoutExpired):
        return None
    return out.stdout if out.returncode == 0 else None


@functools.lru_cache(maxsize=1)
def revision() -> dict | None:
    """``{"commit": sha, "dirty": bool}`` of the checkout this package lies in (dirty: a tracked file
    differs from the commit), or None outside a git checkout or without git."""
    root = checkout_root()
    if root is None or not (root / ".git").exists():
        return None
    sha = _git(root, "rev-parse", "HEAD")
    status = _git(root, "status", "--porcelain", "--untracked-files=no")
    if sha is None or status is None:
        return None
    return {"commit": sha.strip(), "dirty": bool(status.strip())}


def describe() -> dict:
    """What a run records as simseam itself: version, source directory and revision."""
    return {"version": version(), "source": str(source_dir()), "revision": revision()}


def one_line() -> str:
    """``simseam 0.1.0 from /path/src/simseam (git abc1234, modified)``: ``simseam --version``."""
    rev = revision()
    git = "" if rev is None else f", git {rev['commit'][:12]}" + (" with local changes" if rev["dirty"] else "")
    return f"simseam {version() or '(unknown version)'} from {source_dir()}{git}"
