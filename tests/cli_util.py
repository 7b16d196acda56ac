"""``simseam`` as a user types it, in a subprocess: the one helper every command-line test shares."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]


def cli_env(**extra: str) -> dict[str, str]:
    """The environment of a ``simseam`` child: headless rendering (EGL unless set), no hub downloads, unbuffered
    output (a reader sees each line as it is printed)."""
    return dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), HF_HUB_OFFLINE="1", PYTHONUNBUFFERED="1",
                **extra)


def simseam(*args, cwd: Path | str = REPO, timeout: float = 600) -> subprocess.CompletedProcess:
    """``python -m simseam.cli.main ARGS`` run to its end with its output captured (``timeout``: a hang guard)."""
    return subprocess.run([sys.executable, "-m", "simseam.cli.main", *map(str, args)], cwd=cwd, env=cli_env(),
                          capture_output=True, text=True, timeout=timeout)
