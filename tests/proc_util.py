"""Processes seen through /proc, for tests that check what a run leaves behind."""

from __future__ import annotations

import os
import signal
import time
from pathlib import Path


def _stat(pid) -> list[str] | None:
    """The fields of /proc/PID/stat after the command name (state first), or None when it is gone."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except OSError:
        return None
    return text[text.rindex(")") + 2:].split()


def children(pid: int) -> list[int]:
    """Live (not zombie) processes whose parent is ``pid``."""
    out = []
    for p in os.listdir("/proc"):
        if p.isdigit():
            fields = _stat(p)
            if fields is not None and int(fields[1]) == pid and fields[0] not in ("Z", "X"):
                out.append(int(p))
    return out


def descendants(pid: int) -> list[int]:
    out, todo = [], [pid]
    while todo:
        for c in children(todo.pop()):
            out.append(c)
            todo.append(c)
    return out


def exited(pid: int, timeout: float = 60.0) -> bool:
    """The process exits (or is a zombie) within ``timeout`` (a hang guard; it normally takes
    milliseconds). One still there then is killed, never left behind, and False is returned."""
    deadline = time.monotonic() + timeout
    while True:
        fields = _stat(pid)
        if fields is None or fields[0] in ("Z", "X"):
            return True
        if time.monotonic() > deadline:
            os.kill(pid, signal.SIGKILL)
            return False
        time.sleep(0.02)
