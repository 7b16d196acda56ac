"""A benchmark port imports MuJoCo Warp while its native worker answers ``describe``
(``warp_physics.imported_meanwhile``): checked in fresh interpreters, where nothing has imported it yet."""

from __future__ import annotations

import subprocess
import sys

import pytest

pytest.importorskip("mujoco_warp")

# the call waits (up to 120 s) until the thread's import has put mujoco_warp in sys.modules: it returns only if the
# import ran while the call was still running
DURING = r"""
import sys, time
from simseam.backends.warp_physics import imported_meanwhile
assert "mujoco_warp" not in sys.modules and "warp" not in sys.modules
def call():
    deadline = time.monotonic() + 120
    while "mujoco_warp" not in sys.modules or "warp" not in sys.modules:
        assert time.monotonic() < deadline, "mujoco_warp was not imported during the call"
        time.sleep(0.01)
    return "described"
print(imported_meanwhile(call, "mujoco_warp"))
import threading
print(sorted(t.name for t in threading.enumerate() if t.name.startswith("simseam-import")))
"""

OTHER_ENGINE = r"""
import sys
from simseam.backends.warp_physics import imported_meanwhile
print(imported_meanwhile(lambda: 7, "mujoco"), "mujoco_warp" in sys.modules)
"""

FAILING_CALL = r"""
from simseam.backends.warp_physics import imported_meanwhile
def call():
    raise ValueError("the worker died")
try:
    imported_meanwhile(call)
except ValueError as e:
    import sys
    print(repr(e), "mujoco_warp" in sys.modules)
"""


def _run(code: str) -> str:
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=300)
    assert out.returncode == 0, out.stderr[-2000:]
    return out.stdout


def test_mujoco_warp_is_imported_during_the_call_and_the_thread_is_joined_before_it_returns():
    assert _run(DURING).splitlines() == ["described", "[]"]


def test_another_engine_only_calls():
    assert _run(OTHER_ENGINE).split() == ["7", "False"]


def test_the_calls_error_comes_through_after_the_import_is_done():
    assert _run(FAILING_CALL).strip() == "ValueError('the worker died') True"
