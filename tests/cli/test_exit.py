"""A ``simseam`` command ends without Python's collections over what it leaves on the heap
(``simseam.cli.main`` freezes it at exit; benchmarks/bench_exit.py measures what that saves), and every atexit
handler registered after the CLI's import (a run's own) still runs before."""

from __future__ import annotations

import subprocess
import sys


def test_the_heap_is_frozen_at_exit_after_the_runs_own_handlers():
    probe = ("import atexit, gc; atexit.register(lambda: print('at the end, frozen', gc.get_freeze_count() > 0)); "
             "import simseam.cli.main as m; "
             "atexit.register(lambda: print('a run handler, frozen', gc.get_freeze_count() > 0)); "
             "import sys; sys.argv = ['simseam', 'robots', '--help']; m.main()")
    out = subprocess.run([sys.executable, "-c", probe], capture_output=True, text=True, timeout=120)
    assert out.returncode == 0, out.stderr
    lines = [line for line in out.stdout.splitlines() if "frozen" in line]
    assert lines == ["a run handler, frozen False", "at the end, frozen True"]
