"""Failure handling: a dead sidecar is reported as a crash (exit code, stderr tail), during boot
and mid-episode, never as a silent timeout; a hung one hits the per-request timeout; restart()
continues with a fresh sidecar; the CLI run loop does the same, end to end.

No wall-clock synchronization: a kill waits for a readiness signal (the request is on its way),
and time bounds are hang guards far below the timeouts a crash must not wait out (>= 60 s), far
above what a prompt report needs (the client checks the process every few ms)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
from sidecar_util import actions, assert_same, kept, process_gone, running, scene_options
from typer.testing import CliRunner

from simseam.seam import SidecarError
from simseam.sidecar.client import SidecarRollout
from simseam.sidecar.errors import SidecarCrashed, SidecarTimeout
from simseam.sidecar.target import SceneTarget

REPO = Path(__file__).resolve().parents[2]
HOOKS = {"SIMSEAM_SIDECAR_TEST_HOOKS": "1"}
#: a crash must be reported promptly: this bound only separates "reported" from "waited out a
#: request/boot timeout" (those are >= 60 s in these tests); it is not a latency requirement
HANG_GUARD_S = 10.0


class _SignalWhenWaiting:
    """Wraps a rollout's socket: sets ``waiting`` once a request has been sent and the client
    polls for its reply (the readiness signal for "a request is in flight")."""

    def __init__(self, sock, waiting: threading.Event):
        self._sock, self._waiting = sock, waiting

    def poll(self, *args, **kwargs):
        self._waiting.set()
        return self._sock.poll(*args, **kwargs)

    def __getattr__(self, name):
        return getattr(self._sock, name)


def _kill9(pid: int) -> float:
    os.kill(pid, signal.SIGKILL)
    return time.monotonic()


def test_kill9_mid_episode_is_reported_as_a_crash(make_sidecar):
    rollout = make_sidecar(options=scene_options(render_images=False), request_timeout=60)
    rollout.reset(seed=0)
    rollout.step(np.zeros(7, np.float32))
    assert rollout.fast  # ipc: the local fast path (Unix socket); a crash is reported the same way
    pid = rollout.pid
    t_kill = _kill9(pid)
    with pytest.raises(SidecarCrashed) as ei:
        rollout.step(np.zeros(7, np.float32))
    elapsed = time.monotonic() - t_kill
    assert elapsed < HANG_GUARD_S, f"crash reported after {elapsed:.2f} s (waited for the request timeout?)"
    err = ei.value
    assert err.exit_code == -9 and "killed by signal 9" in str(err) and "during step" in str(err)
    assert isinstance(err, SidecarError) and not isinstance(err, SidecarTimeout)
    with pytest.raises(SidecarCrashed, match="call restart"):  # and it stays a crash, not a hang
        rollout.step(np.zeros(7, np.float32))
    assert not running(pid)


def test_kill9_while_a_request_is_in_flight_is_reported_as_a_crash(make_sidecar):
    """The sidecar dies while the client waits for its reply (a request that would take 120 s,
    with a 60 s request timeout): a crash, reported promptly, not a timeout."""
    rollout = make_sidecar(options=scene_options(render_images=False), env=HOOKS, request_timeout=60)
    rollout.reset(seed=0)
    pid, waiting, killed = rollout.pid, threading.Event(), {}
    rollout._sock = _SignalWhenWaiting(rollout._sock, waiting)

    def killer():
        if waiting.wait(HANG_GUARD_S * 6):  # the request went out and the client waits for the reply
            killed["t"] = _kill9(pid)

    thread = threading.Thread(target=killer, daemon=True)
    thread.start()
    with pytest.raises(SidecarCrashed) as ei:
        rollout._request("_sleep", {"seconds": 120})
    thread.join(HANG_GUARD_S)
    assert "t" in killed, "the client never waited for the reply"
    elapsed = time.monotonic() - killed["t"]
    assert elapsed < HANG_GUARD_S, f"crash reported {elapsed:.2f} s after the kill (waited for a timeout?)"
    assert ei.value.exit_code == -9 and "during _sleep" in str(ei.value)


def test_exit_with_code_and_stderr_is_reported(make_sidecar):
    rollout = make_sidecar(options=scene_options(render_images=False), env=HOOKS, request_timeout=60)
    rollout.reset(seed=0)
    t0 = time.monotonic()
    with pytest.raises(SidecarCrashed) as ei:
        rollout._request("_exit", {"code": 7})
    assert time.monotonic() - t0 < HANG_GUARD_S  # reported, not the 60 s request timeout
    err = ei.value
    assert err.exit_code == 7 and "exit code 7" in str(err)
    assert "simseam sidecar: exiting on request (test hook)" in err.stderr_tail
    assert err.stderr_tail.splitlines()[-1] in str(err)  # the message carries the tail too
    with pytest.raises(SidecarCrashed):
        rollout.step(np.zeros(7, np.float32))


def test_interpreter_that_dies_at_start_is_a_boot_crash(panda_json, tmp_path, client_tmp):
    """A sidecar interpreter that exits before it is ready (a wrapper standing in for an engine
    SDK that fails to import): SidecarCrashed with its exit code and stderr, not a boot timeout."""
    stamp, args = tmp_path / "exit_time", tmp_path / "args"
    wrapper = tmp_path / "python"
    wrapper.write_text(
        "#!/bin/bash\n"
        f'echo "$@" > {args}\n'
        'echo "loading engine SDK ..." >&2\n'
        'echo "boom: cannot import engine" >&2\n'
        f"date +%s.%N > {stamp}\n"
        "exit 5\n")
    wrapper.chmod(0o755)
    with pytest.raises(SidecarCrashed) as ei:
        SidecarRollout(SceneTarget(panda_json, "lift_cube", options=scene_options()), python=str(wrapper),
                       boot_timeout=60)
    t_raised = time.time()
    exited = float(stamp.read_text())
    assert t_raised - exited < HANG_GUARD_S, f"reported {t_raised - exited:.2f} s after the process exited " \
        "(waited for the 60 s boot timeout?)"
    err = ei.value
    assert err.exit_code == 5 and "while booting" in str(err) and "exit code 5" in str(err)
    assert err.stderr_tail.splitlines() == ["loading engine SDK ...", "boom: cannot import engine"]
    assert "boom: cannot import engine" in str(err)
    assert args.read_text().split()[:3] == ["-m", "simseam.sidecar.server", "--boot"]
    assert list(client_tmp.iterdir()) == []  # the private dir (and the boot file with the token) is gone


def test_interpreter_without_the_servers_packages_is_a_boot_crash(panda_json, tmp_path, monkeypatch, client_tmp):
    """A bare venv cannot host the server: ModuleNotFoundError, reported as a crash. The sidecar imports
    this process's simseam (a private link), but nothing else of this process's path: PYTHONPATH
    pointing at the source tree and this venv's packages do not leak into it and hide the problem."""
    venv = tmp_path / "bare"
    subprocess.run([getattr(sys, "_base_executable", sys.executable), "-m", "venv", "--without-pip", str(venv)],
                   check=True, timeout=120)
    monkeypatch.setenv("PYTHONPATH", str(REPO / "src"))
    t0 = time.monotonic()
    with pytest.raises(SidecarCrashed) as ei:
        SidecarRollout(SceneTarget(panda_json, "lift_cube", options=scene_options()),
                       python=str(venv / "bin" / "python"), boot_timeout=60)
    assert time.monotonic() - t0 < HANG_GUARD_S  # not the 60 s boot timeout
    err = ei.value
    assert err.exit_code == 1 and "while booting" in str(err)
    assert "No module named 'numpy'" in err.stderr_tail and "No module named 'numpy'" in str(err)
    assert list(client_tmp.iterdir()) == []


def test_hung_sidecar_hits_the_request_timeout(make_sidecar):
    """A 120 s hang against a 0.5 s request timeout: SidecarTimeout (the hang ending would return
    normally instead), raised no earlier than the limit."""
    rollout = make_sidecar(options=scene_options(render_images=False), env=HOOKS, request_timeout=60)
    rollout.reset(seed=0)  # under the long limit: on a loaded machine a reset may take more than 0.5 s
    rollout.request_timeout = 0.5
    pid = rollout.pid
    t0 = time.monotonic()
    with pytest.raises(SidecarTimeout) as ei:
        rollout._request("_sleep", {"seconds": 120})
    elapsed = time.monotonic() - t0
    assert 0.5 <= elapsed < HANG_GUARD_S * 6, elapsed  # the request's limit, not the 120 s hang
    assert "did not answer '_sleep' within 0.5 s" in str(ei.value)
    assert not isinstance(ei.value, SidecarCrashed) and running(pid)  # alive, hung: not a crash
    rollout.close()  # close() reaps a hung sidecar too
    assert process_gone(pid, timeout=HANG_GUARD_S)


def test_restart_after_a_crash_continues_with_the_next_episode(make_sidecar):
    rollout = make_sidecar()
    acts = actions(seed=4, n=5, dim=7)
    ref_obs = kept(rollout.reset(seed=11))  # copies: kept across steps (the ring's slots are reused)
    ref = [kept(rollout.step(a).observation) for a in acts]
    old = rollout.pid
    rollout.reset(seed=12)
    os.kill(old, signal.SIGKILL)
    with pytest.raises(SidecarCrashed):
        rollout.step(acts[0])
    rollout.restart()
    assert rollout.pid != old and running(rollout.pid) and not running(old)
    assert_same(rollout.reset(seed=11), ref_obs)  # the fresh sidecar serves the same scene
    for a, exp in zip(acts, ref):
        assert_same(rollout.step(a).observation, exp)
    rollout.reset(seed=12)  # and the next episode
    assert rollout.step(acts[0]).info["steps"] == 1


def _scene_file(tmp_path: Path, name: str, engine: str) -> Path:
    path = tmp_path / name
    path.write_text(f"robot: franka_panda\nengine: {engine}\nlayout: lift_cube\nmax_steps: 60\n")
    return path


def test_cli_run_with_a_sidecar_end_to_end(tmp_path):
    """`simseam run` on a scene file with `process: sidecar`, in a subprocess: 2 episodes,
    summary.json written, and the same episodes as the in-process engine."""
    results = {}
    for kind, engine in (("sidecar", "{name: mujoco, process: sidecar, transport: tcp}"), ("inprocess", "mujoco")):
        out = tmp_path / kind
        proc = subprocess.run(
            [sys.executable, "-m", "simseam.cli.main", "run", "--scene", str(_scene_file(tmp_path, f"{kind}.yaml",
                                                                                       engine)),
             "--policy", "scripted", "--episodes", "2", "--seed", "3", "--out", str(out)],
            cwd=REPO, capture_output=True, text=True, timeout=240)
        assert proc.returncode == 0, proc.stdout + proc.stderr
        results[kind] = json.loads((out / "summary.json").read_text())
    side, local = results["sidecar"], results["inprocess"]
    assert side["config"]["scene"]["engine"]["process"] == "sidecar" and side["n_episodes"] == 2
    assert side["spec"]["backend"] == "sidecar" and local["spec"]["backend"] == "inprocess"
    assert {**side["spec"], "backend": "", "capabilities": []} == {**local["spec"], "backend": "", "capabilities": []}
    for a, b in zip(side["episodes"], local["episodes"]):
        assert a["error"] is None
        assert (a["seed"], a["success"], a["steps"], a["reward"]) == (b["seed"], b["success"], b["steps"], b["reward"])
    assert side["n_success"] == 2


def test_cli_run_loop_restarts_a_crashed_sidecar(tmp_path, monkeypatch):
    """The sidecar is killed at the start of episode 0: that episode is recorded with the crash,
    a fresh sidecar is started and episode 1 runs normally."""
    import simseam.runner.session as session
    from simseam.cli.main import app

    original = session.run_episode
    pids = []

    def run_episode(rollout, policy, *, index, **kw):
        pids.append(rollout.pid)
        if index == 0:
            os.kill(rollout.pid, signal.SIGKILL)
            assert process_gone(rollout.pid, timeout=HANG_GUARD_S)
        return original(rollout, policy, index=index, **kw)

    monkeypatch.setattr(session, "run_episode", run_episode)  # the loop run_episodes calls
    out = tmp_path / "out"
    res = CliRunner().invoke(app, ["run", "--scene", str(_scene_file(tmp_path, "s.yaml", "{process: sidecar}")),
                                   "--policy", "scripted", "--episodes", "2", "--num-envs", "1", "--out", str(out)])
    assert res.exit_code == 0, res.output
    assert "restarting the sidecar" in res.output
    summary = json.loads((out / "summary.json").read_text())
    ep0, ep1 = summary["episodes"]
    assert ep0["success"] is False and ep0["steps"] == 0 and ep0["error"].startswith("SidecarCrashed:")
    assert "killed by signal 9" in ep0["error"]
    assert ep1["error"] is None and ep1["success"] is True
    assert len(pids) == 2 and pids[0] != pids[1]
    assert process_gone(pids[1], timeout=HANG_GUARD_S)  # the CLI closed the fresh one at the end
