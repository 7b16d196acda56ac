"""Run the test suite as several pytest sessions, ``--jobs`` at a time (scripts/test's first pass).

One pytest session keeps one core busy: measured alone here, tests/engines/test_mujoco_warp.py used 99 % of
a core, tests/backends/test_libero_lerobot.py 89 %, tests/cli/test_learning_cli.py 85 % (its sidecars, peers
and CLI children included). On a 2-core machine the second core idled for most of the suite. So the suite
is cut into groups (a directory or a few slow files, each a pytest session of its own) that run two at a
time, the longest first (a group lying inside another is left out of it, wherever either is listed); the group
``tests``, less every path of the other groups, takes whatever is not listed, so no test is left out whatever
files are added (a listed path that no longer exists is dropped).
Each session writes JUnit XML; at the end the runner prints every group's closing line and wall time and
the 25 slowest tests over all of them.

    python scripts/test_groups.py [--jobs N] [-- PYTEST_ARGS...]

Given test paths (``python scripts/test_groups.py -- tests/seam -x``) it runs one session on them, as pytest
would. Exit status: the first failing group's (pytest's), 0 when all passed (a group that selected no test,
exit 5, passes when another group ran tests).
"""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
import xml.etree.ElementTree as ET
from concurrent.futures import ThreadPoolExecutor
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
#: the groups, longest first (wall seconds of each in CI warm 20, 6 December 2026, two at a time, beside the
#: Python 3.12 pass). A free slot takes the next group, so this order decides how evenly the two slots end: the
#: order before (the proof first, tests/backends late) ended the first pass ~47 s later on those figures. A group may come before a group it lies
#: in (test_policy_proof.py before tests/policies): the enclosing group ignores it wherever it is listed.
GROUPS: tuple[tuple[str, ...], ...] = (
    ("tests/backends",),  # ~435 s: the other backends' files (the ones of the groups below are excluded from it)
    ("tests/cli",),  # ~413 s
    ("tests/policies/test_policy_proof.py",),  # ~378 s: the proof's training, then nine CLI runs two at a time
    # ~332 s: Meta-World on Warp's CPU device: its batched rules, the port, its eval, the fidelity harness on a subset
    ("tests/backends/test_metaworld_rewards.py", "tests/backends/test_metaworld_gpu.py",
     "tests/backends/test_metaworld_gpu_eval.py", "tests/backends/test_metaworld_warp_fidelity.py",
     "tests/backends/test_metaworld_gpu_cameras.py"),
    # ~316 s: LIBERO's episodes on Warp's CPU device: against the CPU backend, the pairing, faults, the eval path
    ("tests/backends/test_libero_gpu_env.py",),
    ("tests/backends/test_fidelity.py",),  # ~313 s
    ("tests/engines",),  # ~250 s
    ("tests/runner",),  # ~228 s
    ("tests/backends/test_maniskill.py", "tests/backends/test_maniskill_batch.py"),  # ~204 s
    # ~182 s: LIBERO's first parts on Warp's CPU device (four suites' models), its goal predicates against
    # LIBERO's own evaluation, and its scripted expert through simseam eval
    ("tests/backends/test_libero_gpu.py", "tests/backends/test_libero_predicates.py",
     "tests/backends/test_libero_expert.py"),
    ("tests",),  # ~127 s: every test file not in another group (the groups inside it are left out of it)
    ("tests/policies",),  # ~123 s
    ("tests/sidecar",),  # ~109 s
    ("tests/ros2",),  # ~65 s
)
NO_TESTS = 5  # pytest's exit status when a session selected no test


def plan(pytest_args: list[str]) -> list[list[str]]:
    """The pytest argument lists, one per session: the groups and the rest, each with ``pytest_args``; or one
    session when ``pytest_args`` names test paths."""
    if any(Path(REPO, a.split("::")[0]).exists() for a in pytest_args if not a.startswith("-")):
        return [list(pytest_args)]
    groups = [g for g in (tuple(p for p in group if (REPO / p).exists()) for group in GROUPS) if g]
    taken = [p for g in groups for p in g]  # a renamed file is in none: the session of "tests" takes it
    if ("tests",) not in groups:
        groups.append(("tests",))
    sessions = []
    for group in groups:
        inside = [p for p in taken if p not in group and any(Path(p).is_relative_to(g) for g in group)]
        sessions.append([*group, *(f"--ignore={p}" for p in inside), *pytest_args])
    return sessions


def closing_line(log: str) -> str:
    lines = [ln for ln in log.strip().splitlines() if ln.strip()]
    return lines[-1].strip("= ") if lines else "(no output)"


def slowest(xml_paths: list[Path], n: int = 25) -> list[tuple[float, str]]:
    """The ``n`` slowest test cases over every session's JUnit XML (setup, call and teardown together)."""
    cases = []
    for path in xml_paths:
        if path.exists():
            for case in ET.parse(path).getroot().iter("testcase"):
                cases.append((float(case.get("time", 0.0)), f"{case.get('classname')}::{case.get('name')}"))
    return sorted(cases, reverse=True)[:n]


class Runner:
    def __init__(self, python: str, sessions: list[list[str]], workdir: Path):
        self.python, self.sessions, self.workdir = python, sessions, workdir
        self.procs: list[subprocess.Popen] = []
        self.print_lock = threading.Lock()
        self.stopping = False

    def run_one(self, k: int) -> tuple[int, float, str]:
        args = self.sessions[k]
        cmd = [self.python, "-m", "pytest", "-q", "-p", "no:cacheprovider", f"--junitxml={self.workdir / f'{k}.xml'}",
               *args]
        log = self.workdir / f"{k}.log"
        t0 = time.monotonic()
        with log.open("w") as out:
            if self.stopping:
                return 130, 0.0, "not started (interrupted)"
            proc = subprocess.Popen(cmd, cwd=REPO, stdout=out, stderr=subprocess.STDOUT, start_new_session=True)
            self.procs.append(proc)
            rc = proc.wait()
        wall, text = time.monotonic() - t0, log.read_text(errors="replace")
        with self.print_lock:  # a finished session's whole log at once, never interleaved
            print(f"[simseam] pytest {' '.join(args)}  ({wall:.0f} s, exit {rc})", flush=True)
            print(text, end="" if text.endswith("\n") else "\n", flush=True)
        return rc, wall, closing_line(text)

    def stop(self) -> None:
        self.stopping = True
        for proc in self.procs:
            if proc.poll() is None:
                os.killpg(proc.pid, signal.SIGINT)  # pytest's own Ctrl-C: fixtures clean up their processes


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--jobs", type=int, default=2, help="pytest sessions at once (default 2)")
    ap.add_argument("pytest_args", nargs=argparse.REMAINDER, help="after --: passed to every pytest session")
    ns = ap.parse_args(argv)
    pytest_args = ns.pytest_args[1:] if ns.pytest_args[:1] == ["--"] else ns.pytest_args
    sessions = plan(pytest_args)
    t0 = time.monotonic()
    with tempfile.TemporaryDirectory(prefix="simseam-test-groups-") as tmp:
        runner = Runner(sys.executable, sessions, Path(tmp))
        pool = ThreadPoolExecutor(max_workers=max(1, ns.jobs))
        try:
            results = list(pool.map(runner.run_one, range(len(sessions))))
        except KeyboardInterrupt:
            runner.stop()
            pool.shutdown(wait=True, cancel_futures=True)
            return 130
        pool.shutdown()
        top = slowest([Path(tmp) / f"{k}.xml" for k in range(len(sessions))])
    print(f"[simseam] {len(sessions)} pytest sessions, {ns.jobs} at a time: {time.monotonic() - t0:.0f} s wall")
    for args, (rc, wall, line) in zip(sessions, results):
        print(f"  {wall:7.1f} s  exit {rc}  {' '.join(a for a in args if not a.startswith('--ignore'))}: {line}")
    print("[simseam] the 25 slowest tests over all sessions (setup + call + teardown):")
    for seconds, name in top:
        print(f"  {seconds:7.2f} s  {name}")
    codes = [rc for rc, _, _ in results]
    failed = [rc for rc in codes if rc not in (0, NO_TESTS)]
    if failed:
        return failed[0]
    return NO_TESTS if all(rc == NO_TESTS for rc in codes) else 0


if __name__ == "__main__":
    sys.exit(main())
