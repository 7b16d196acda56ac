"""N worlds of one model put on a Warp device, or a one-line error with the largest N that fits there.

``put_worlds(mjm, host, n, device, what)`` is ``mujoco_warp.put_model`` + ``put_data`` for ``n`` worlds (the
keyword arguments go to them: ``batched`` model fields to the model, ``nconmax`` / ``njmax`` to the data). When the
device's memory cannot hold them, it finds the largest number of worlds that does by allocating them (a
bisection, each try freed before the next: measured, not estimated from sizes; on CUDA the tries allocate the
arrays' sizes, below), and raises
``WorldsDoNotFit``, a ``ConfigError`` of one line naming what was asked, the device and that number. The
worlds' MuJoCo Warp data is most of a batch's memory (contacts and constraint rows per world); what a batch
allocates after it (cameras, a policy) can still run out, so the number is an upper bound for the batch. The
bisection's freed tries fragment the memory, so asking for that number again in the same process can fail;
a fresh process (what a user starts next) fits it, or nearly: on Warp's CPU device under a capped address space
two measurements named 14,823 and 12,357 worlds and each fitted exactly in a fresh process, but one named 16,029
where the next process fitted 15,707 (2 % fewer: a process's own footprint before the cap moves by a few MiB).

Where the device says how much memory is free (CUDA), the worlds' footprint is first measured on one and on two
worlds (the bytes of each of their arrays), and a number the free memory cannot hold is not built at all:
building 100,000 LIBERO worlds' data takes mujoco_warp minutes on the host before any device allocation fails,
and so does every try near the answer (tens of thousands of LIBERO worlds: on an H100 the search by building
ran past 4 minutes). The search then allocates, for k worlds, empty arrays of the sizes k worlds' arrays have
(each array's size is linear in k: its size for one world plus k - 1 times its growth from one to two),
starting where the footprint says the memory ends, a step beyond, narrowing to 1 %: each try takes
milliseconds, and the number named is one whose arrays allocated.

Recognised as out of memory: Warp's "Failed to allocate" (CUDA and CPU devices), CuPy's ``OutOfMemoryError``
and Python's ``MemoryError`` (host-side arrays), also where another exception was raised from one. Recognised as
not fitting either: Warp's limit on an array's dimensions (each below 2**31: mujoco_warp's contact and constraint
arrays are one dimension of worlds x rows, so enough worlds reach it on a GPU whose memory would hold them). The
blank arrays keep that limit (each dimension of each array grows linearly with k, as its bytes do) and are
allocated in two parts where a flat array of their bytes would exceed it: on an H100, 100,000 LIBERO worlds asked
gave a 4.3 GB contact array, which Warp refused as a dimension, not as memory.

Warp's native code prints its own line for each device allocation that fails ("Warp CUDA error 2: out of memory"),
on the process's stderr: each of the search's tries that does not fit would print one above the message. What a
try prints there is held (``_stderr_held``) and dropped only when the try ran out of memory; anything else it
printed is written back. The build of the number asked is not held (a crash there must show what it printed): where
it fails, Warp's one line stands above the message.
"""

from __future__ import annotations

import contextlib
import gc
import os
import sys
import tempfile
from typing import Any, Callable, Iterator

from simseam.seam import ConfigError


class WorldsDoNotFit(ConfigError):
    """``n`` worlds do not fit the device's memory; ``largest`` (measured) do (0: not even one)."""

    def __init__(self, message: str, asked: int, largest: int):
        super().__init__(message)
        self.asked, self.largest = asked, largest


#: from this many worlds the footprint is measured first (two small builds: negligible beside building that many)
FOOTPRINT_FROM = 1024
#: Warp's bound on each dimension of an array (``warp.types.check_array_shape``)
DIM_LIMIT = 2**31
DIM_LIMIT_TEXT = "Array shapes must not exceed the maximum representable value of a signed 32-bit integer"


def out_of_memory(exc: BaseException | None) -> bool:
    """Whether ``exc``, or an exception it was raised from, is a device or host allocation failure (Warp wraps
    NumPy's ``MemoryError`` in a ``RuntimeError`` when it copies host data to the device)."""
    seen = set()
    while exc is not None and id(exc) not in seen:
        seen.add(id(exc))
        if isinstance(exc, MemoryError) or type(exc).__name__ == "OutOfMemoryError":  # cupy's too
            return True
        if isinstance(exc, RuntimeError) and "Failed to allocate" in str(exc):
            return True
        exc = exc.__cause__ or exc.__context__
    return False


def does_not_fit(exc: BaseException | None) -> bool:
    """Whether ``exc`` says the worlds cannot be held: out of memory, or an array longer than Warp's
    ``DIM_LIMIT`` along a dimension."""
    return out_of_memory(exc) or (isinstance(exc, ValueError) and DIM_LIMIT_TEXT in str(exc))


def largest_that_fits(build: Callable[[int], Any], below: int, fits: int = 0, within: float = 0.0) -> int:
    """The largest ``k`` < ``below`` for which ``build(k)`` allocates without running out of memory (0 if
    none), by bisection from ``fits`` (known to allocate, or 0) until the range is at most ``within`` of its
    lower end (0: exact); each built object is dropped, and the memory collected, before the next try."""
    lo, hi = fits, below  # build(lo) fits (or lo = 0), build(hi) does not
    while hi - lo > max(1, int(lo * within)):
        mid = (lo + hi) // 2
        if _allocates(build, mid):
            lo = mid
        else:
            hi = mid
    return lo


def _allocates(build: Callable[[int], Any], k: int) -> bool:
    """Whether ``build(k)`` allocates (the built object dropped and the memory collected after); an error other
    than running out of memory is raised."""
    try:
        built = _quietly(build, k)
    except Exception as exc:  # noqa: BLE001 - only an allocation failure says "no"; others go up
        if not does_not_fit(exc):
            raise
        gc.collect()
        return False
    del built
    gc.collect()
    return True


def _quietly(build: Callable[[int], Any], k: int) -> Any:
    """``build(k)``, what it prints on stderr dropped if it does not fit (the native library's line about the
    failed allocation), written back otherwise."""
    with _stderr_held() as drop:
        try:
            return build(k)
        except Exception as exc:
            if does_not_fit(exc):
                drop.append(True)
            raise


@contextlib.contextmanager
def _stderr_held() -> Iterator[list]:
    """The process's stderr (file descriptor 2: native libraries print there) held in a temporary file for the
    block, then written back unless the block appended to the list it is given."""
    drop: list = []
    try:
        sys.stderr.flush()
        saved = os.dup(2)
    except (OSError, ValueError, AttributeError):  # no stderr to hold (closed, or replaced without a file)
        yield drop
        return
    try:
        with tempfile.TemporaryFile() as held:
            os.dup2(held.fileno(), 2)
            try:
                yield drop
            finally:
                sys.stderr.flush()
                os.dup2(saved, 2)
                if not drop:
                    held.seek(0)
                    os.write(2, held.read())
    finally:
        os.close(saved)


def array_sizes(obj: Any, seen: set[int] | None = None) -> list[tuple[Any, int, tuple[int, ...]]]:
    """``(device, bytes, shape)`` of each Warp array held by ``obj`` (mujoco_warp's ``Model`` / ``Data``:
    dataclasses of arrays and of dataclasses; tuples and lists of them too), each array once, in a fixed order."""
    import dataclasses

    import warp as wp

    seen = set() if seen is None else seen
    if id(obj) in seen:
        return []
    seen.add(id(obj))
    if isinstance(obj, wp.array):
        return [(obj.device, int(obj.capacity or 0), tuple(int(x) for x in obj.shape))]
    if dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        return [a for f in dataclasses.fields(obj) for a in array_sizes(getattr(obj, f.name, None), seen)]
    if isinstance(obj, (tuple, list)):
        return [a for x in obj for a in array_sizes(x, seen)]
    return []


def array_bytes(obj: Any) -> int:
    """The bytes of the Warp arrays held by ``obj`` (``array_sizes``)."""
    return sum(size for _, size, _ in array_sizes(obj))


def allocate_empty(sizes: list[tuple[Any, int, tuple[int, ...]]]) -> list[Any]:
    """Uninitialised Warp arrays of those ``(device, bytes, shape)``: what a build of that many worlds allocates,
    without building anything on the host. A dimension past Warp's ``DIM_LIMIT`` is Warp's error, as the build
    would raise it; bytes past it are allocated as a block of whole MiB and the rest."""
    import warp as wp

    out = []
    for device, size, shape in sizes:
        longest = max(shape, default=0)
        if longest >= DIM_LIMIT:
            raise ValueError(f"{DIM_LIMIT_TEXT}, got {longest} in an array of {size} bytes")
        blocks = [(size,)] if size < DIM_LIMIT else [(size >> 20, 1 << 20), (size & ((1 << 20) - 1),)]
        out += [wp.empty(block, dtype=wp.uint8, device=device) for block in blocks if block[-1] > 0]
    return out


def _footprint(build: Callable[[int], Any]) -> tuple[list[tuple], list[tuple]] | str:
    """The arrays' ``(device, bytes, shape)`` of one world and of two, or the first line of the allocation failure
    when not even two worlds allocate."""
    try:
        one, two = (array_sizes(_quietly(build, k)) for k in (1, 2))
    except Exception as exc:  # noqa: BLE001 - not even two worlds allocate: the search says how many do
        if not does_not_fit(exc):
            raise
        return str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    finally:
        gc.collect()
    if len(one) != len(two):
        raise RuntimeError(f"the build of 1 and 2 worlds holds {len(one)} and {len(two)} arrays: not one layout")
    return one, two


def _sizes_at(one: list[tuple], two: list[tuple], k: int) -> list[tuple[Any, int, tuple[int, ...]]]:
    """Each array's ``(device, bytes, shape)`` for ``k`` worlds: each value its value for one world plus ``k - 1``
    times its growth to two."""
    at = lambda a, b: a + (b - a) * (k - 1)  # noqa: E731
    return [(dev, at(a, b), tuple(at(x, y) for x, y in zip(sa, sb))) for (dev, a, sa), (_, b, sb) in zip(one, two)]


def _too_big(build: Callable[[int], Any], n: int, free_bytes: Callable[[], int],
             allocate: Callable[[list], Any]) -> tuple[int, str, Callable[[int], Any]] | None:
    """``(estimate, reason, blank)`` when the footprint of 1 and 2 worlds says ``n`` worlds cannot fit in the free
    memory (``estimate``: the worlds that would; ``blank(k)``: ``allocate`` of k worlds' array sizes), else None
    (and nothing is known against trying ``n``)."""
    room = int(free_bytes())
    layout = _footprint(build)
    if isinstance(layout, str):
        return 0, layout, build
    one, two = layout
    bytes_one, bytes_two = sum(s for _, s, _ in one), sum(s for _, s, _ in two)
    per_world, fixed = bytes_two - bytes_one, 2 * bytes_one - bytes_two
    need = fixed + per_world * n
    longest = max((max(shape, default=0) for _, _, shape in _sizes_at(one, two, n)), default=0)
    if per_world <= 0 or (need <= room and longest < DIM_LIMIT):
        return None
    reasons = [f"{per_world / 2**20:.2f} MiB a world, {need / 2**30:.1f} GiB for {n}, "
               f"{room / 2**30:.1f} GiB free"] if need > room else []
    if longest >= DIM_LIMIT:
        reasons.append(f"an array {longest} long for {n}, past Warp's limit of 2**31 a dimension")
    by_dims = [(DIM_LIMIT - 1 - x) // (y - x) + 1 for (_, _, sa), (_, _, sb) in zip(one, two)
               for x, y in zip(sa, sb) if y > x]
    estimate = max(0, min(n - 1, (room - fixed) // per_world, *by_dims))
    return estimate, "; ".join(reasons), lambda k: allocate(_sizes_at(one, two, k))


def _largest_near(build: Callable[[int], Any], estimate: int, n: int) -> int:
    """The largest number of worlds up to ``n`` that allocates, searched from the footprint's ``estimate`` (steps
    of 2 % up or down, doubling, until the answer is bracketed, then bisected to 1 %); ``n`` if it does after
    all."""
    step = max(1, estimate // 50)
    if estimate and _allocates(build, estimate):
        lo, hi = estimate, min(n, estimate + step)
        while _allocates(build, hi):
            if hi == n:
                return n
            step *= 2
            lo, hi = hi, min(n, hi + step)
    else:
        hi, lo = estimate, max(0, estimate - step)
        while lo and not _allocates(build, lo):
            step *= 2
            hi, lo = lo, max(0, lo - step)
    return largest_that_fits(build, hi, fits=lo, within=0.01)


def fit_worlds(build: Callable[[int], Any], n: int, what: str, device: Any,
               free_bytes: Callable[[], int] | None = None, allocate: Callable[[list], Any] = allocate_empty) -> Any:
    """``build(n)``; out of memory: ``WorldsDoNotFit`` with the largest number of worlds ``build`` takes.
    ``free_bytes()``: the device's free memory, where it says (then ``n`` is not built when it cannot fit, and the
    search ``allocate``s the arrays' ``(device, bytes)`` instead of building)."""
    early = _too_big(build, n, free_bytes, allocate) if free_bytes is not None and n >= FOOTPRINT_FROM else None
    if early is not None:
        estimate, reason, blank = early
        largest = _largest_near(blank, estimate, n)
        if largest == n:  # the footprint was pessimistic
            return build(n)
        how = "measured by allocating arrays of their sizes"
    else:
        try:
            return build(n)  # not held: what a crash in the run's own build prints must reach stderr
        except Exception as exc:  # noqa: BLE001 - re-raised unless it is an allocation failure
            if not does_not_fit(exc):
                raise
            reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        gc.collect()
        largest, how = largest_that_fits(build, n), "measured by allocating them"
    fits = f"the largest number that fits is {largest} ({how})" if largest else "not even one world fits"
    raise WorldsDoNotFit(f"{what}: {n} worlds do not fit on device {device} ({reason}); {fits}; "
                         f"ask for fewer worlds (--num-envs) or free the device", n, largest) from None


def put_worlds(mjm: Any, host: Any, n: int, device: Any, what: str, *, batched: tuple[str, ...] = (),
               **data_sizes: Any) -> tuple[Any, Any]:
    """(``mujoco_warp.Model``, ``mujoco_warp.Data`` of ``n`` worlds from the host data ``host``) on ``device``
    (a Warp device); out of memory: ``WorldsDoNotFit`` (module docstring). ``batched``: the model fields with
    one value per world (their size follows each try's number of worlds)."""
    import mujoco_warp as mjw
    import warp as wp

    def build(k: int) -> tuple[Any, Any]:
        with wp.ScopedDevice(device):
            m = mjw.put_model(mjm, batch_sizes=dict.fromkeys(batched, k)) if batched else mjw.put_model(mjm)
            return m, mjw.put_data(mjm, host, nworld=k, **data_sizes)

    free = (lambda: wp.get_device(device).free_memory) if wp.get_device(device).is_cuda else None
    return fit_worlds(build, n, what, device, free)
