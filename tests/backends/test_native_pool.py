"""``NativeWorker.map``: one call per process at once (the worker and its helpers), answers in order, helpers
kept for later calls and closed with the worker; a failure in one call is raised after every worker answered,
so the next calls still pair each request with its answer. ``helpers_for`` / ``split``: how many processes and
which keys each gets."""

import os
import sys
from pathlib import Path

import pytest

from simseam.backends.native_worker import NativeWorker, helpers_for, split
from simseam.seam.errors import ConfigError, SimulationError

HERE = Path(__file__).resolve().parent


@pytest.fixture
def worker(tmp_path):
    # the worker's PYTHONPATH holds simseam alone; this interpreter wrapper adds the tests' worker module
    python = tmp_path / "python"
    python.write_text(f'#!/bin/sh\nPYTHONPATH="$PYTHONPATH:{HERE}" exec {sys.executable} "$@"\n')
    python.chmod(0o755)
    w = NativeWorker("echo", "native_echo_worker", python=python)
    yield w
    w.close()


def test_map_runs_each_call_in_its_own_process_and_keeps_the_helpers(worker):
    pids = worker.map("pid", [{}, {}, {}])
    assert len(set(pids)) == 3 and pids[0] == worker.call("pid")  # the worker itself takes the first call
    assert worker.map("echo", [{"value": k} for k in "abc"]) == ["a", "b", "c"]
    assert worker.map("pid", [{}, {}, {}]) == pids  # the same helpers, in the same order
    assert worker.map("pid", [{}, {}]) == pids[:2]
    helpers = [h._proc for h in worker._helpers]
    worker.close()
    assert all(p.poll() is not None for p in helpers)  # closed with the worker


def test_a_failed_call_is_raised_after_all_answered_and_the_workers_stay_in_step(worker):
    with pytest.raises(SimulationError, match=r"fail\(why='first'\) failed: ValueError: first"):
        worker.map("fail", [{"why": "first"}, {"why": "second"}, {"why": "third"}])
    # the second and third errors were read too: each request still gets its own answer
    assert worker.map("echo", [{"value": k} for k in (1, 2, 3)]) == [1, 2, 3]
    assert worker.call("echo", value="still paired") == "still paired"


def test_helpers_for_and_split(monkeypatch):
    monkeypatch.setenv("SIMSEAM_NATIVE_WORKERS", "3")
    assert [helpers_for(n) for n in (0, 1, 4, 5, 12, 50)] == [1, 1, 1, 2, 3, 3]
    monkeypatch.setenv("SIMSEAM_NATIVE_WORKERS", "1")
    assert helpers_for(50) == 1
    monkeypatch.delenv("SIMSEAM_NATIVE_WORKERS")
    assert helpers_for(50) == min(8, max(1, len(os.sched_getaffinity(0)) - 1))
    monkeypatch.setenv("SIMSEAM_NATIVE_WORKERS", "many")
    with pytest.raises(ConfigError, match="SIMSEAM_NATIVE_WORKERS='many'"):
        helpers_for(50)
    assert split(list(range(7)), 3) == [[0, 1, 2], [3, 4], [5, 6]]
    assert split([1, 2], 5) == [[1], [2]] and split([4], 1) == [[4]]
