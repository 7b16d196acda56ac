"""``runner.claims``: the whole tasks that the K processes of ``simseam eval --processes K`` take one at a time.

Races are run between real processes started together; the end-to-end run (two processes of Meta-World's port
claiming two tasks, merged into the unsharded run's episodes) is in tests/backends/test_metaworld_gpu_eval.py."""

from __future__ import annotations

import json
import subprocess
import sys
from pathlib import Path

from simseam.runner.claims import TaskClaims
from simseam.runner.job import _after

SRC = Path(__file__).resolve().parents[2] / "src"

RACER = """
import json, sys
sys.path.insert(0, {src!r})
from simseam.runner.claims import TaskClaims
claims = TaskClaims({folder!r}, int(sys.argv[1]))
print("ready", flush=True)
sys.stdin.readline()  # every racer waits here until all are ready, then they claim at once
print(json.dumps([t for t in range({tasks}) if claims.take(t)]), flush=True)
"""


def test_racing_processes_each_task_taken_by_exactly_one(tmp_path):
    folder, tasks, k = tmp_path / "claims", 200, 4
    code = RACER.format(src=str(SRC), folder=str(folder), tasks=tasks)
    procs = [subprocess.Popen([sys.executable, "-c", code, str(i)], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                              text=True) for i in range(k)]
    try:
        for p in procs:
            assert p.stdout.readline().strip() == "ready"
        for p in procs:
            p.stdin.write("go\n")
            p.stdin.flush()
        taken = [json.loads(p.stdout.readline()) for p in procs]
    finally:
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait()
    every = sorted(t for mine in taken for t in mine)
    assert every == list(range(tasks)), "a task taken twice or by nobody"
    holders = TaskClaims(folder, 0)
    for i, mine in enumerate(taken):
        assert all(holders.holder(t) == i for t in mine)
    assert not [p for p in folder.iterdir() if not p.name.startswith("task-")]  # no temporary file left behind


def test_a_resumed_process_takes_back_its_own_tasks_and_the_free_ones_only(tmp_path):
    a, b = TaskClaims(tmp_path, 0), TaskClaims(tmp_path, 1)
    assert a.take(0) and b.take(1)
    assert not a.take(1) and not b.take(0)  # held by the other
    again = TaskClaims(tmp_path, 0)  # process 0 of a resumed run
    assert again.take(0) and not again.take(1) and again.take(2)
    assert [a.holder(t) for t in range(4)] == [0, 1, 0, None]


def test_the_part_prepared_ahead_is_the_next_one_nobody_holds(tmp_path):
    class Part:
        def __init__(self, task):
            self.first_task = task

    parts = [(Part(t), [t], 0) for t in range(4)]
    assert _after(parts, 0, None) is parts[1] and _after(parts, 3, None) is None  # no claims: the next in order
    mine, other = TaskClaims(tmp_path, 0), TaskClaims(tmp_path, 1)
    mine.take(0)
    other.take(1)
    assert _after(parts, 0, mine) is parts[2]  # task 1 is the other's: prepare task 2 (not claimed by preparing)
    assert mine.holder(2) is None
    other.take(2)
    other.take(3)
    assert _after(parts, 0, mine) is None
