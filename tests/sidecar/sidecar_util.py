"""Helpers for the sidecar tests: /proc inspection (no psutil needed) and deep equality."""

from __future__ import annotations

import dataclasses
import os
import time
from pathlib import Path

import numpy as np

SESSION_ENV = "SIMSEAM_TEST_SESSION"
SERVER_MODULE = b"simseam.sidecar.server"


def scene_options(**overrides) -> dict:
    """SceneOptions fields as JSON types (what a scene file hands the sidecar client);
    default: 32x32 cameras (fast on a CPU)."""
    from simseam.scene.manifest_scene import SceneOptions

    return dataclasses.asdict(SceneOptions(**{"image_size": (32, 32), **overrides}))


def proc_stat(pid: int) -> tuple[str, int] | None:
    """(state letter, parent pid) of a process, or None when there is no such process."""
    try:
        text = Path(f"/proc/{pid}/stat").read_text()
    except (FileNotFoundError, ProcessLookupError):
        return None
    fields = text[text.rindex(")") + 2:].split()
    return fields[0], int(fields[1])


def running(pid: int) -> bool:
    """The process exists and is not a zombie (exited, waiting to be reaped)."""
    st = proc_stat(pid)
    return st is not None and st[0] not in ("Z", "X")


def process_gone(pid: int, timeout: float) -> bool:
    deadline = time.monotonic() + timeout
    while running(pid):
        if time.monotonic() > deadline:
            return False
        time.sleep(0.02)
    return True


def end_client(proc, sock_dir: Path | None) -> None:
    """A test's client subprocess: its sidecar's private directory removed (a SIGKILLed client cannot
    clean up after itself), the process killed if still running, its pipes closed."""
    if sock_dir is not None:
        import shutil

        shutil.rmtree(sock_dir, ignore_errors=True)
    if proc.poll() is None:
        proc.kill()
        proc.wait(10)
    proc.stdout.close()
    proc.stderr.close()


def cmdline(pid: int) -> bytes:
    try:
        return Path(f"/proc/{pid}/cmdline").read_bytes()
    except OSError:
        return b""


def environ(pid: int) -> dict[str, str]:
    raw = Path(f"/proc/{pid}/environ").read_bytes()
    out = {}
    for item in raw.split(b"\0"):
        if b"=" in item:
            k, _, v = item.partition(b"=")
            out[k.decode(errors="replace")] = v.decode(errors="replace")
    return out


def _pids() -> list[int]:
    return [int(p) for p in os.listdir("/proc") if p.isdigit()]


def children(pid: int) -> list[int]:
    """Running (non-zombie) children of ``pid``."""
    out = []
    for p in _pids():
        st = proc_stat(p)
        if st is not None and st[1] == pid and st[0] not in ("Z", "X"):
            out.append(p)
    return out


def marked_sidecars(marker: str) -> list[int]:
    """Running sidecar servers whose environment carries this test session's marker."""
    found = []
    for p in _pids():
        if SERVER_MODULE not in cmdline(p) or not running(p):
            continue
        try:
            if environ(p).get(SESSION_ENV) == marker:
                found.append(p)
        except OSError:
            continue
    return found


def assert_same(a, b, path: str = "obs") -> None:
    """Deep, exact equality of observation-like data (dicts, arrays incl. dtype, scalars)."""
    if isinstance(a, dict):
        assert isinstance(b, dict) and a.keys() == b.keys(), f"{path}: keys {sorted(a)} != {sorted(b)}"
        for k in a:
            assert_same(a[k], b[k], f"{path}[{k!r}]")
    elif isinstance(a, np.ndarray):
        assert isinstance(b, np.ndarray), f"{path}: {type(b).__name__} is not an ndarray"
        assert a.dtype == b.dtype and a.shape == b.shape, f"{path}: {a.dtype}{a.shape} != {b.dtype}{b.shape}"
        assert np.array_equal(a, b), f"{path}: values differ (max |diff| {np.abs(a.astype(float) - b).max()})"
    elif isinstance(a, (list, tuple)):
        assert isinstance(b, (list, tuple)) and len(a) == len(b), f"{path}: {a!r} != {b!r}"
        for i, (x, y) in enumerate(zip(a, b)):
            assert_same(x, y, f"{path}[{i}]")
    else:
        assert type(a) is type(b) and a == b, f"{path}: {a!r} != {b!r}"


def actions(seed: int, n: int, dim: int) -> list[np.ndarray]:
    """A seeded action sequence in [-1, 1] (CARTESIAN_DELTA + gripper)."""
    rng = np.random.default_rng(seed)
    return [rng.uniform(-1.0, 1.0, dim).astype(np.float32) for _ in range(n)]


def kept(x):
    """A copy of observation-like data (or a StepResult) to keep across steps: a sidecar's images are
    views into shared-memory slots that its later replies reuse (the seam's lifetime contract)."""
    import dataclasses

    if isinstance(x, np.ndarray):
        return x.copy()
    if isinstance(x, dict):
        return {k: kept(v) for k, v in x.items()}
    if isinstance(x, list):
        return [kept(v) for v in x]
    if dataclasses.is_dataclass(x) and hasattr(x, "observation"):
        return dataclasses.replace(x, observation=kept(x.observation))
    if isinstance(x, tuple) and hasattr(x, "_replace") and hasattr(x, "observation"):
        return x._replace(observation=kept(x.observation))
    return x
