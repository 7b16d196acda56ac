"""N worlds of one model put on a Warp device, or a one-line error with the largest N that fits there.

``put_worlds(mjm, host, n, device, what)`` is ``mujoco_warp.put_model`` + ``put_data`` for ``n`` worlds (the
keyword arguments go to them: ``batched`` model fields to the model, ``nconmax`` / ``njmax`` to the data). When the
device's memory cannot hold them, it finds the largest number of worlds that does by allocating them (a
bisection over ``put_data``, each try freed before the next: measured, not estimated from sizes), and raises
``WorldsDoNotFit``, a ``ConfigError`` of one line naming what was asked, the device and that number. The
worlds' MuJoCo Warp data is most of a batch's memory (contacts and constraint rows per world); what a batch
allocates after it (cameras, a policy) can still run out, so the number is an upper bound for the batch. The
bisection's freed tries fragment the memory, so asking for that number again in the same process can fail;
a fresh process (what a user starts next) fits it (on Warp's CPU device under a capped address space: two
measurements named 14,823 and 12,357 worlds, and each fitted exactly in a fresh process).

Recognised as out of memory: Warp's "Failed to allocate" (CUDA and CPU devices), CuPy's ``OutOfMemoryError``
and Python's ``MemoryError`` (host-side arrays), also where another exception was raised from one.
"""

from __future__ import annotations

import gc
from typing import Any, Callable

from simseam.seam import ConfigError


class WorldsDoNotFit(ConfigError):
    """``n`` worlds do not fit the device's memory; ``largest`` (measured) do (0: not even one)."""

    def __init__(self, message: str, asked: int, largest: int):
        super().__init__(message)
        self.asked, self.largest = asked, largest


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


def largest_that_fits(build: Callable[[int], Any], below: int) -> int:
    """The largest ``k`` < ``below`` for which ``build(k)`` allocates without running out of memory (0 if
    none), by bisection; each built object is dropped, and the memory collected, before the next try."""
    lo, hi = 0, below  # build(lo) fits (or lo = 0), build(hi) does not
    while hi - lo > 1:
        mid = (lo + hi) // 2
        try:
            built = build(mid)
        except Exception as exc:  # noqa: BLE001 - only an allocation failure narrows the range; others go up
            if not out_of_memory(exc):
                raise
            hi = mid
        else:
            del built
            lo = mid
        gc.collect()
    return lo


def fit_worlds(build: Callable[[int], Any], n: int, what: str, device: Any) -> Any:
    """``build(n)``; out of memory: ``WorldsDoNotFit`` with the largest number of worlds ``build`` takes."""
    try:
        return build(n)
    except Exception as exc:  # noqa: BLE001 - re-raised unless it is an allocation failure
        if not out_of_memory(exc):
            raise
        reason = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    gc.collect()
    largest = largest_that_fits(build, n)
    fits = (f"the largest number that fits is {largest} (measured by allocating them)" if largest
            else "not even one world fits")
    raise WorldsDoNotFit(f"{what}: {n} worlds do not fit in the memory of device {device} ({reason}); {fits}; "
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

    return fit_worlds(build, n, what, device)
