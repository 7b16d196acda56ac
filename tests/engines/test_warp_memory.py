"""Out of device memory for N worlds: a one-line error naming the largest N that fits, measured by allocating.

The bisection is checked on a stand-in build (exact answers); the real thing on Warp's CPU device in a child
process whose address space is capped (``RLIMIT_AS``), so that its allocations fail as a full GPU's would:
the number the error names fits when a fresh process asks for it under the same cap (what a user does next),
and the batched physics both benchmark ports use (Meta-World's and LIBERO's ``WarpPhysics``) raises it with the
task's name."""

from __future__ import annotations

import json
import subprocess
import sys

import pytest

pytest.importorskip("mujoco_warp")

from simseam.engines.mujoco_warp.memory import (  # noqa: E402
    DIM_LIMIT,
    DIM_LIMIT_TEXT,
    WorldsDoNotFit,
    _footprint,
    _sizes_at,
    allocate_empty,
    array_bytes,
    array_sizes,
    does_not_fit,
    fit_worlds,
    largest_that_fits,
    out_of_memory,
)
from simseam.seam import ConfigError  # noqa: E402


def _build_up_to(limit: int, calls: list):
    def build(k: int):
        calls.append(k)
        if k > limit:
            raise RuntimeError(f"Failed to allocate {k * 1000} bytes on device 'cuda:0'")
        return object()

    return build


def test_the_error_names_the_largest_number_of_worlds_that_allocates():
    calls = []
    with pytest.raises(WorldsDoNotFit) as info:
        fit_worlds(_build_up_to(37, calls), 4096, "Meta-World reach-v3 on MuJoCo Warp", "cuda:0")
    err = info.value
    assert isinstance(err, ConfigError) and (err.asked, err.largest) == (4096, 37)
    msg = str(err)
    assert "\n" not in msg and msg.startswith("Meta-World reach-v3 on MuJoCo Warp: 4096 worlds do not fit")
    assert "device cuda:0" in msg and "the largest number that fits is 37 (measured by allocating them)" in msg
    assert calls[0] == 4096 and 37 in calls and 38 in calls and len(calls) <= 1 + 13  # a bisection, not a scan


def test_the_native_librarys_line_for_each_failed_try_is_dropped_and_nothing_else(capfd):
    """Warp's native code prints a line on the process's stderr for each device allocation that fails: the search's
    tries that do not fit would print them above the one-line error. Those are dropped (only the build of the number
    asked, not held, prints its own); what a try that fits prints, and what a build failing otherwise prints, reach
    stderr as they would have."""
    import os

    def build(k: int):
        if k == 13:
            os.write(2, b"native: a note while building 13\n")
        if k == 99:
            os.write(2, b"native: a bad model\n")
            raise ValueError("a bad model")
        if k > 40:
            os.write(2, f"native: out of memory at {k}\n".encode())
            raise RuntimeError(f"Failed to allocate {k * 1000} bytes on device 'cuda:0'")
        return k

    with pytest.raises(WorldsDoNotFit, match="the largest number that fits is 40"):
        fit_worlds(build, 100, "task t", "cuda:0")
    assert largest_that_fits(build, 26) == 25
    with pytest.raises(ValueError, match="a bad model"):
        fit_worlds(build, 99, "task t", "cuda:0")
    err = capfd.readouterr().err
    assert [line for line in err.splitlines() if "out of memory at" in line] == ["native: out of memory at 100"]
    assert err.count("native: a note while building 13") == 1 and err.count("native: a bad model") == 1


def test_not_even_one_world_and_other_errors():
    with pytest.raises(WorldsDoNotFit, match="not even one world fits") as info:
        fit_worlds(_build_up_to(0, []), 8, "task", "cuda:0")
    assert info.value.largest == 0
    assert fit_worlds(_build_up_to(8, []), 8, "task", "cuda:0") is not None  # fits: built once

    def broken(k: int):
        raise ValueError("nconmax must be positive")

    with pytest.raises(ValueError, match="nconmax"):  # not an allocation failure: raised as it is
        fit_worlds(broken, 8, "task", "cpu")
    assert largest_that_fits(_build_up_to(5, []), 6) == 5 and largest_that_fits(_build_up_to(100, []), 6) == 5


def _arrays_up_to(limit: int, calls: list):
    """A stand-in build of k worlds holding 500 + 1,000 k bytes of Warp arrays on the CPU device, failing above
    ``limit`` worlds as a full device does."""
    import warp as wp

    def build(k: int):
        calls.append(k)
        if k > limit:
            raise RuntimeError(f"Failed to allocate {k * 1000} bytes on device 'cuda:0'")
        return (wp.empty(125, dtype=wp.float32, device="cpu"), wp.empty(k * 250, dtype=wp.float32, device="cpu"))

    return build


def _budget(limit: int, calls: list):
    """A stand-in device allocator holding at most ``limit`` bytes (real arrays on Warp's CPU device below it)."""

    def allocate(sizes):
        total = sum(size for _, size, _ in sizes)
        calls.append(total)
        if total > limit:
            raise RuntimeError(f"Failed to allocate {total} bytes on device 'cuda:0'")
        return allocate_empty(sizes)

    return allocate


def test_a_number_the_free_memory_cannot_hold_is_never_built():
    """Where the device says what is free (CUDA), the footprint of 1 and 2 worlds rules out 10**6 without building
    it (mujoco_warp spends minutes on the host building that many), and the search allocates the arrays' sizes
    from where the memory ends, never building worlds near the answer (each such build took minutes on an H100)."""
    builds, tries = [], []
    free = 500 + 1000 * 3000 + 10  # room for 3,000 worlds by the footprint; 3,000 allocate
    with pytest.raises(WorldsDoNotFit) as info:
        fit_worlds(_arrays_up_to(10**7, builds), 10**6, "LIBERO task libero_spatial/0 on MuJoCo Warp", "cuda:0",
                   free_bytes=lambda: free, allocate=_budget(500 + 1000 * 3000, tries))
    err = info.value
    assert 2970 <= err.largest <= 3000 and err.asked == 10**6  # to 1 %
    assert builds == [1, 2] and max(tries) < 10**9 and len(tries) <= 8
    msg = str(err)
    assert "\n" not in msg and "10000000" not in msg and "1000000 worlds do not fit" in msg
    assert "0.00 MiB a world" in msg and "GiB free" in msg
    assert f"the largest number that fits is {err.largest} (measured by allocating arrays of their sizes)" in msg
    # a pessimistic footprint (the device frees more than it said): n is built after all
    builds, tries = [], []
    assert fit_worlds(_arrays_up_to(10**6, builds), 4096, "task", "cuda:0", free_bytes=lambda: 500 + 1000 * 100,
                      allocate=_budget(10**9, tries))
    assert builds == [1, 2, 4096] and len(tries) <= 14  # steps doubling from 2 % of the 100 estimated
    # not even the footprint's worlds allocate: the same error, naming none
    with pytest.raises(WorldsDoNotFit, match="not even one world fits"):
        fit_worlds(_arrays_up_to(0, []), 4096, "task", "cuda:0", free_bytes=lambda: 10**9)
    # below FOOTPRINT_FROM worlds nothing is measured first
    builds = []
    with pytest.raises(WorldsDoNotFit):
        fit_worlds(_arrays_up_to(37, builds), 1000, "task", "cuda:0", free_bytes=lambda: 0)
    assert builds[0] == 1000


def test_the_arrays_of_k_worlds_follow_from_one_and_two():
    """What the search allocates for k worlds is what mujoco_warp's put_model + put_data allocate for k, array by
    array, per-world model fields included (the layout the fast search relies on), on Warp's CPU device; with the
    contacts and constraint rows a world fixed, as put_worlds passes them (nconmax scaled with k would not be
    linear: mujoco_warp sizes the contacts nworld x nconmax)."""
    import mujoco
    import mujoco_warp as mjw
    import warp as wp

    mjm = mujoco.MjModel.from_xml_string(XML)
    host = mujoco.MjData(mjm)
    mujoco.mj_forward(mjm, host)

    def build(k: int):
        with wp.ScopedDevice("cpu"):
            model = mjw.put_model(mjm, batch_sizes={"body_pos": k})
            return model, mjw.put_data(mjm, host, nworld=k, nconmax=8, njmax=32)

    one, two = _footprint(build)
    for k in (3, 7):
        assert _sizes_at(one, two, k) == array_sizes(build(k))
    assert array_bytes(build(7)) == sum(size for _, size, _ in _sizes_at(one, two, 7))
    blank = allocate_empty(_sizes_at(one, two, 7))
    assert [a.capacity for a in blank] == [size for _, size, _ in _sizes_at(one, two, 7) if size > 0]


def _dims_only(calls: list):
    """A stand-in device allocator with memory to spare that keeps Warp's limit on a dimension (as
    ``allocate_empty`` does), allocating nothing."""

    def allocate(sizes):
        calls.append(max(max(shape) for _, _, shape in sizes))
        if calls[-1] >= DIM_LIMIT:
            raise ValueError(f"{DIM_LIMIT_TEXT}, got {calls[-1]} in dimension 0.")
        return []

    return allocate


def test_worlds_past_warps_limit_on_a_dimension_do_not_fit():
    """mujoco_warp's contact and constraint arrays are one dimension of worlds x rows, and Warp refuses a dimension
    of 2**31 or more (on an H100, 100,000 LIBERO worlds asked: a ValueError, not out of memory). Where the memory
    would hold them, the footprint still rules such a number out, and the largest number named is exactly the
    last whose longest array stays below the limit; a build that raises Warp's error counts as not fitting."""
    builds, tries = [], []
    with pytest.raises(WorldsDoNotFit) as info:
        fit_worlds(_arrays_up_to(10**9, builds), 10**7, "LIBERO task libero_spatial/0 on MuJoCo Warp", "cuda:0",
                   free_bytes=lambda: 10**15, allocate=_dims_only(tries))
    err, limit = info.value, (DIM_LIMIT - 1) // 250  # the stand-in's long array: 250 k float32
    assert err.largest == limit and builds == [1, 2] and len(tries) <= 30
    assert "an array 2500000000 long for 10000000, past Warp's limit of 2**31 a dimension" in str(err)
    assert "GiB free" not in str(err) and "\n" not in str(err)

    def long_above(k: int):
        if k > 37:
            raise ValueError(f"{DIM_LIMIT_TEXT}, got {k * 10**8} in dimension 0.")
        return k

    with pytest.raises(WorldsDoNotFit, match="the largest number that fits is 37"):
        fit_worlds(long_above, 1000, "task", "cuda:0")
    assert does_not_fit(ValueError(DIM_LIMIT_TEXT + ", got 2147483648 in dimension 0."))
    assert not does_not_fit(ValueError("nconmax must be positive"))


def test_blank_arrays_keep_warps_limit_and_hold_their_bytes(monkeypatch):
    """``allocate_empty``: a longest dimension at the limit is Warp's error; bytes past the limit (not the longest
    dimension) are allocated as a block of whole MiB and the rest, their sum the bytes asked (the limit lowered to
    2 MiB here, so the arrays stay small)."""
    import simseam.engines.mujoco_warp.memory as memory

    monkeypatch.setattr(memory, "DIM_LIMIT", 2**21)
    blank = memory.allocate_empty([("cpu", 3 * 2**20 + 7, (1000, 3)), ("cpu", 64, (16,))])
    assert [tuple(a.shape) for a in blank] == [(3, 2**20), (7,), (64,)]
    assert sum(a.capacity for a in blank) == 3 * 2**20 + 7 + 64
    with pytest.raises(ValueError, match="signed 32-bit integer, got 2097152"):
        memory.allocate_empty([("cpu", 2**21, (2**21,))])


def test_what_counts_as_out_of_memory():
    assert out_of_memory(MemoryError()) and out_of_memory(RuntimeError("Failed to allocate 8 bytes on device 'cpu'"))
    try:
        try:
            raise MemoryError("Unable to allocate 3.6 GiB")
        except MemoryError as inner:
            raise RuntimeError("Failed to convert input data to an array") from inner
    except RuntimeError as wrapped:  # Warp wraps NumPy's failure when it copies host data over
        assert out_of_memory(wrapped)
    assert not out_of_memory(RuntimeError("kernel launch failed")) and not out_of_memory(ValueError("x"))


XML = """<mujoco><worldbody><body><freejoint/><geom type="box" size=".1 .1 .1"/></body>
<body pos="0 0 1"><freejoint/><geom type="sphere" size=".1"/></body></worldbody></mujoco>"""

CHILD = r"""
import gc, json, resource, sys
import mujoco, warp as wp
wp.config.quiet = True
wp.init()
from simseam.backends.warp_physics import WarpPhysics
from simseam.engines.mujoco_warp.memory import WorldsDoNotFit, put_worlds
XML = '''<mujoco><worldbody><body><freejoint/><geom type="box" size=".1 .1 .1"/></body>
<body pos="0 0 1"><freejoint/><geom type="sphere" size=".1"/></body></worldbody></mujoco>'''
mjm = mujoco.MjModel.from_xml_string(XML)
host = mujoco.MjData(mjm)
mujoco.mj_forward(mjm, host)
cpu = wp.get_device("cpu")
put_worlds(mjm, host, 4, cpu, "warm-up")  # every module loaded before the cap
size = int(next(line.split()[1] for line in open("/proc/self/status") if line.startswith("VmSize"))) * 1024
resource.setrlimit(resource.RLIMIT_AS, (size + 400 * 2**20, resource.RLIM_INFINITY))
out = {}
if sys.argv[1] == "ask":  # a fresh process asks for the number another one's error named
    m, d = put_worlds(mjm, host, int(sys.argv[2]), cpu, "the number named")
    out["fits"] = d.nworld
else:
    try:
        put_worlds(mjm, host, 10**7, cpu, "two bodies")
    except WorldsDoNotFit as e:
        out.update(message=str(e), largest=e.largest)
    gc.collect()
    try:
        WarpPhysics(mjm, 10**7, "cpu", what="Meta-World reach-v3 on MuJoCo Warp")
    except WorldsDoNotFit as e:
        out["physics"] = str(e)
print(json.dumps(out))
"""


def _child(*args: str) -> dict:
    done = subprocess.run([sys.executable, "-c", CHILD, *args], capture_output=True, text=True, timeout=600)
    assert done.returncode == 0, done.stderr[-3000:]
    return json.loads(done.stdout.strip().splitlines()[-1])


def test_on_warps_cpu_device_with_its_memory_capped():
    out = _child("measure")
    assert 100 < out["largest"] < 10**7
    assert "\n" not in out["message"] and "10000000 worlds do not fit on device cpu" in out["message"]
    assert f"the largest number that fits is {out['largest']}" in out["message"]
    assert out["physics"].startswith("Meta-World reach-v3 on MuJoCo Warp: 10000000 worlds do not fit")
    # what a user does next: start again asking for the number named; it fits under the same cap (less 5 %:
    # the fresh process's own footprint before the cap differs by a few MiB, ~30 KiB a world; idle, both name
    # 14,576, but in a full test run one child named 16,029 and the next fitted 15,707, 2.0 % fewer)
    asked = int(out["largest"] * 0.95)
    assert _child("ask", str(asked))["fits"] == asked
