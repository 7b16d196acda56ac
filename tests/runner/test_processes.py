"""``runner.processes``: the K processes of ``simseam eval --processes K`` and the MPS server of ``--mps``.

The MPS control daemon exists only beside NVIDIA's driver; here a stand-in program on PATH records what it is
asked (its arguments, the pipe and log folders it is given, what it reads on stdin), which is all simseam does with
the real one (which ran on an H100: docs/benchmarks.md). The processes are real Python processes."""

from __future__ import annotations

import json
import os
import stat
import sys
import time
from pathlib import Path

import pytest

from simseam.runner import processes as P
from simseam.seam import ConfigError


def _stand_in(tmp_path: Path, exit_code: int = 0) -> tuple[Path, Path]:
    """An ``nvidia-cuda-mps-control`` that appends one JSON line per call to ``calls.jsonl``."""
    calls = tmp_path / "calls.jsonl"
    prog = tmp_path / "bin" / P.MPS_CONTROL
    prog.parent.mkdir()
    prog.write_text(f"""#!{sys.executable}
import json, os, sys
stdin = "" if sys.argv[1:] == ["-d"] else sys.stdin.read()
with open({str(calls)!r}, "a") as f:
    f.write(json.dumps({{"argv": sys.argv[1:], "stdin": stdin,
                        "pipe": os.environ.get("CUDA_MPS_PIPE_DIRECTORY"), "log": os.environ.get("CUDA_MPS_LOG_DIRECTORY"),
                        "dirs_exist": all(os.path.isdir(os.environ.get(k, "")) for k in
                                          ("CUDA_MPS_PIPE_DIRECTORY", "CUDA_MPS_LOG_DIRECTORY"))}}) + "\\n")
sys.exit({exit_code} if sys.argv[1:] == ["-d"] else 0)
""")
    prog.chmod(prog.stat().st_mode | stat.S_IEXEC)
    return prog, calls


def _calls(path: Path) -> list[dict]:
    return [json.loads(line) for line in path.read_text().splitlines()]


def test_the_mps_server_is_the_runs_own_and_quits_however_the_run_ends(tmp_path, monkeypatch):
    prog, calls = _stand_in(tmp_path)
    monkeypatch.setenv("PATH", f"{prog.parent}{os.pathsep}{os.environ['PATH']}")
    with pytest.raises(RuntimeError, match="the run failed"):
        with P.MpsServer() as env:
            folder = Path(env["CUDA_MPS_PIPE_DIRECTORY"]).parent
            assert folder.is_dir() and Path(env["CUDA_MPS_LOG_DIRECTORY"]).parent == folder
            raise RuntimeError("the run failed")
    start, quit_ = _calls(calls)
    assert start["argv"] == ["-d"] and start["dirs_exist"] and start["pipe"] == env["CUDA_MPS_PIPE_DIRECTORY"]
    assert quit_ == dict(start, argv=[], stdin="quit\n")  # the same daemon (same folders) told to quit
    assert not folder.exists()  # its folders go with it


def test_mps_without_the_program_or_a_daemon_that_does_not_start_is_a_one_line_error(tmp_path, monkeypatch):
    monkeypatch.setenv("PATH", str(tmp_path / "nothing"))
    with pytest.raises(ConfigError, match="nvidia-cuda-mps-control is not on PATH"):
        P.MpsServer()
    prog, calls = _stand_in(tmp_path, exit_code=3)
    with pytest.raises(ConfigError, match=r"-d failed \(exit 3\)") as err:
        with P.MpsServer(control=str(prog)):
            pass
    assert "\n" not in str(err.value) and len(_calls(calls)) == 1  # nothing to quit


def test_ctrl_c_reaches_every_process_and_each_ends_its_own_way(tmp_path):
    """``run_processes`` passes a Ctrl-C on to each process still running (SIGINT), waits for all, then raises
    it: each process ends as it would on a Ctrl-C of its own (here: it writes that it did)."""
    ready = [tmp_path / f"ready{i}" for i in range(2)]
    ended = [tmp_path / f"ended{i}" for i in range(2)]
    child = ("import pathlib, sys, time\n"
             "pathlib.Path(sys.argv[1]).touch()\n"
             "try:\n    time.sleep(600)\n"
             "except KeyboardInterrupt:\n    pathlib.Path(sys.argv[2]).write_text('interrupted')\n    sys.exit(130)\n")
    argvs = [[sys.executable, "-c", child, str(r), str(e)] for r, e in zip(ready, ended)]

    def poll():
        if all(r.exists() for r in ready):  # both started: now the user presses Ctrl-C
            raise KeyboardInterrupt

    with pytest.raises(KeyboardInterrupt):
        P.run_processes(argvs, [tmp_path / f"{i}.log" for i in range(2)], dict(os.environ), on_poll=poll,
                        poll_s=0.05)
    assert [e.read_text() for e in ended] == ["interrupted", "interrupted"]


def test_exit_codes_logs_and_the_episodes_counted(tmp_path):
    out = tmp_path / "run"
    argvs = [[sys.executable, "-c", "print('fine')"], [sys.executable, "-c", "import sys; print('bad input'); sys.exit(2)"]]
    logs = [P.shard_log(out, i) for i in range(2)]
    assert P.run_processes(argvs, logs, dict(os.environ), poll_s=0.05) == [0, 2]
    assert P.log_tail(logs[1]) == "bad input"
    for i, n in ((0, 3), (1, 2)):
        P.shard_dir(out, i).mkdir(parents=True)
        (P.shard_dir(out, i) / "episodes.jsonl").write_text("{}\n" * n)
    assert P.episodes_done(out, 2) == 5 and P.episodes_done(out, 3) == 5  # a shard not started counts none


def test_the_processes_share_the_cores_among_their_native_workers(monkeypatch):
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(16)))
    assert P.child_env(4, {})["SIMSEAM_NATIVE_WORKERS"] == "3"
    assert P.child_env(32, {})["SIMSEAM_NATIVE_WORKERS"] == "1"
    assert P.child_env(4, {"SIMSEAM_NATIVE_WORKERS": "8"})["SIMSEAM_NATIVE_WORKERS"] == "8"  # the user's stays


def test_the_processes_share_the_cores_among_their_thread_pools(monkeypatch):
    """K processes each with a thread pool of every core (PyTorch's, OpenMP's default) would oversubscribe the
    machine K times over: each gets its share, and a value the user set stays."""
    monkeypatch.setattr(os, "sched_getaffinity", lambda pid: set(range(16)))
    assert [P.child_env(k, {})["OMP_NUM_THREADS"] for k in (1, 4, 10, 32)] == ["16", "4", "1", "1"]
    assert P.child_env(4, {"OMP_NUM_THREADS": "2"})["OMP_NUM_THREADS"] == "2"


def test_the_last_process_end_is_noticed_at_once(tmp_path):
    """The run is over when its last process ends, not at the next poll: with polls a minute apart, two quick
    processes return long before the first poll would come round (the merge follows at once)."""
    argvs = [[sys.executable, "-c", "pass"], [sys.executable, "-c", "import sys; sys.exit(3)"]]
    polls = []
    t0 = time.monotonic()
    codes = P.run_processes(argvs, [tmp_path / f"{i}.log" for i in range(2)], dict(os.environ),
                            on_poll=lambda: polls.append(1), poll_s=60.0)
    assert codes == [0, 3] and time.monotonic() - t0 < 30.0
    assert 1 <= len(polls) <= 2  # one per process it waited on
