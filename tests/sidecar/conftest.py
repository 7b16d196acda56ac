"""Fixtures for the sidecar tests: real sidecar processes, and a guard that none outlive the session.

Every process this test session starts (sidecars, subprocess clients and their sidecars)
inherits ``SIMSEAM_TEST_SESSION=<random>`` in its environment (the sidecar's environment is
sanitized, not emptied). At the end of the session the guard scans ``/proc`` for
``simseam.sidecar.server`` processes carrying this session's marker: there must be none
(other sessions' sidecars, e.g. a benchmark running beside us, are never touched).
"""

from __future__ import annotations

import os
import secrets
import shutil
import signal
import time

import pytest
from sidecar_util import SESSION_ENV, marked_sidecars, process_gone, scene_options

os.environ[SESSION_ENV] = secrets.token_hex(8)


@pytest.fixture(scope="session", autouse=True)
def no_orphan_sidecars():
    """Session guard: every sidecar this session started is gone at the end (no orphans)."""
    yield
    deadline = time.monotonic() + 10.0
    left = marked_sidecars(os.environ[SESSION_ENV])
    while left and time.monotonic() < deadline:  # a just-closed sidecar may still be exiting
        time.sleep(0.05)
        left = marked_sidecars(os.environ[SESSION_ENV])
    for pid in left:  # clean up before failing, so the next run starts clean
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    assert not left, f"sidecar processes started by this test session are still running: {left}"


@pytest.fixture(scope="session")
def panda_json(panda_spec):
    return panda_spec.to_json()


@pytest.fixture(scope="session")
def so101_json(so101_spec):
    return so101_spec.to_json()


@pytest.fixture
def make_sidecar(panda_json):
    """Factory for SidecarRollouts (default: Panda lift_cube, two 32x32 cameras), each closed and
    reaped at the end of the test; the test fails if one of them is still alive after that."""
    from simseam.sidecar.client import SidecarRollout
    from simseam.sidecar.target import SceneTarget

    made: list[SidecarRollout] = []
    pids: set[int] = set()  # every sidecar process seen (kept-alive ones forget theirs on close())
    dirs: list[str] = []

    def _make(spec_json=None, layout="lift_cube", options=None, **kwargs) -> SidecarRollout:
        kwargs.setdefault("boot_timeout", 60.0)
        kwargs.setdefault("request_timeout", 30.0)
        r = SidecarRollout(SceneTarget(spec_json or panda_json, layout, "mujoco",
                                       scene_options() if options is None else options), **kwargs)
        made.append(r)
        pids.add(r.pid)
        if r._keep_alive and r._dir:  # a kept-alive sidecar's private dir outlives its client: ours to remove
            dirs.append(r._dir)
        return r

    yield _make
    pids.update(r.pid for r in made if r.pid is not None)
    for r in made:
        if r._keep_alive and r._sock is not None and r._adopted_pid is None and r._proc is not None:
            try:  # a kept-alive sidecar that this test started: ask it to exit
                r._request("close", {}, timeout=2.0)
            except Exception:
                pass
        popen = r._proc.popen if r._proc is not None else None
        r.close()
        if popen is not None:
            try:
                popen.wait(5)
            except Exception:
                pass
    stuck = [pid for pid in sorted(pids) if not process_gone(pid, timeout=60.0)]  # a hang guard only
    for pid in stuck:
        try:
            os.kill(pid, signal.SIGKILL)
        except ProcessLookupError:
            pass
    for d in dirs:
        shutil.rmtree(d, ignore_errors=True)
    assert not stuck, f"sidecars still alive after the test closed them: {stuck}"


@pytest.fixture
def client_tmp(monkeypatch):
    """A fresh, empty temp dir for the client (where it makes each sidecar's private 0700 dir).
    Short on purpose: an ipc socket path must fit in sockaddr_un (107 bytes)."""
    import tempfile
    from pathlib import Path

    d = Path(tempfile.mkdtemp(prefix="ss-"))
    monkeypatch.setattr(tempfile, "tempdir", str(d))
    yield d
    shutil.rmtree(d, ignore_errors=True)
