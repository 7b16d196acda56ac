"""No orphans: close(), interpreter exit, SIGTERM (and even SIGKILL) of the client reap
every sidecar it started. Processes are found through /proc (no psutil needed)."""

from __future__ import annotations

import os
import select
import signal
import subprocess
import sys
import textwrap
from pathlib import Path

import pytest
from sidecar_util import (SERVER_MODULE, children, cmdline, end_client, proc_stat, process_gone, running,
                          scene_options)

CLIENT = textwrap.dedent("""
    import sys, time
    from simseam.robot.manifest import load_robot
    from simseam.sidecar.client import SidecarRollout
    from simseam.sidecar.target import SceneTarget

    r = SidecarRollout(SceneTarget(load_robot("franka_panda").to_json(), "lift_cube", options={"render_images": False}))
    r.reset(0)
    print(r.pid, r.endpoint, flush=True)
    if sys.argv[1] == "exit":
        sys.exit(0)  # no close(): the interpreter's exit must reap the sidecar
    time.sleep(120)  # waits for a signal
""")


def _readline(proc: subprocess.Popen, timeout: float) -> str:
    ready, _, _ = select.select([proc.stdout], [], [], timeout)
    if not ready:
        proc.kill()
        proc.wait(10)
        pytest.fail(f"the client printed nothing within {timeout} s; stderr:\n{proc.stderr.read()}")
    return proc.stdout.readline()


def test_close_leaves_no_child_process(make_sidecar):
    rollout = make_sidecar(options=scene_options(render_images=False))
    pid = rollout.pid
    assert pid in children(os.getpid()) and SERVER_MODULE in cmdline(pid)
    rollout.reset(seed=0)
    d = Path(rollout.endpoint[len("ipc://"):]).parent
    rollout.close()
    assert proc_stat(pid) is None  # exited *and* reaped: not even a zombie is left
    assert [p for p in children(os.getpid()) if SERVER_MODULE in cmdline(p)] == []
    assert not d.exists()
    rollout.close()  # twice is harmless


@pytest.mark.parametrize("how", ["exit", "sigterm", "sigkill"])
def test_client_exit_and_signals_reap_the_sidecar(how, tmp_path):
    """(a) the client exits without close(), (b) it gets SIGTERM, (c) it is SIGKILLed (the sidecar's
    parent-death signal and its parent watch take over): the sidecar is gone within seconds, and so is the
    private folder of its sockets."""
    proc = subprocess.Popen([sys.executable, "-c", CLIENT, how], stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True, cwd=tmp_path)
    try:
        pid_text, endpoint = _readline(proc, timeout=60).split()
        sidecar, sock_dir = int(pid_text), Path(endpoint[len("ipc://"):]).parent
        assert running(sidecar) and SERVER_MODULE in cmdline(sidecar)
        assert proc_stat(sidecar)[1] == proc.pid  # the client's child, not ours
        if how == "sigterm":
            proc.send_signal(signal.SIGTERM)
        elif how == "sigkill":
            proc.kill()
        code = proc.wait(30)
        assert code == {"exit": 0, "sigterm": -signal.SIGTERM, "sigkill": -signal.SIGKILL}[how], proc.stderr.read()
        if how != "sigkill":  # the client itself killed and waited for it before exiting (atexit / SIGTERM hook)
            assert proc_stat(sidecar) is None, f"sidecar {sidecar} outlived its client ({how})"
            assert not sock_dir.exists()
        # a hang guard only (on a loaded machine the sidecar's exit can take seconds); it normally goes at once
        assert process_gone(sidecar, timeout=60.0), f"sidecar {sidecar} outlived its client ({how})"
        assert not sock_dir.exists()  # after a SIGKILLed client, the sidecar removed its private folder itself
    finally:
        end_client(proc, sock_dir if "sock_dir" in locals() else None)
