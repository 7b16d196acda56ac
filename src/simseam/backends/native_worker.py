"""A native worker: one process of a benchmark's provisioned interpreter, started once and asked many times,
for the GPU ports of benchmarks (``metaworld_gpu``, ``libero_gpu``), which need what only the native env knows
(its compiled model, its resets, its controller's outputs) on the native simulator's own version.

- Client side (``NativeWorker``): started from simseam's interpreter; ``call(command, **kwargs)``, and
  ``map(command, calls)`` for slow answers asked several at once (helper processes of the same kind, one call
  each: ``helpers_for`` says how many, ``split`` what each gets).
- Native side (``serve(commands)``): the worker module's ``__main__`` answers ``(command, kwargs)`` requests
  from a table of functions until stdin closes.

The worker imports this checkout's ``simseam`` (a symlink on its path, as the sidecar does), so what it runs is
the very code ``simseam eval`` runs in that venv. Messages are pickled, length-prefixed; the protocol runs on a
private copy of stdout (fd 1 goes to stderr, so nothing the benchmark prints can corrupt it).

Also here, for the native side: ``model_arrays`` and ``option_values`` (an ``MjModel``'s numeric arrays and
options as plain data, which the port's model checks compare). Imports numpy only.
"""

from __future__ import annotations

import os
import pickle
import struct
import subprocess
import tempfile
import threading
from pathlib import Path
from typing import Any, Callable

import numpy as np

from simseam.files import write_atomic

HEADER = struct.Struct("<Q")
#: a mesh's derived arrays (polygon normals...) are not reproducible between two compiles; no reset moves them
DERIVED = ("mesh_",)
OPTION_KEYS = ("timestep", "integrator", "cone", "solver", "iterations", "ls_iterations", "tolerance",
               "ls_tolerance", "noslip_iterations", "impratio", "gravity", "o_margin", "jacobian", "disableflags",
               "enableflags", "density", "viscosity", "wind", "magnetic", "ccd_iterations")


def model_arrays(model: Any) -> dict[str, np.ndarray]:
    """Every numeric array of an ``MjModel`` (copies)."""
    out = {}
    for key in dir(model):
        if key.startswith("_"):
            continue
        try:
            value = getattr(model, key)
        except Exception:  # noqa: BLE001 - accessors that need arguments
            continue
        if isinstance(value, np.ndarray) and value.dtype.kind in "fiub":
            out[key] = value.copy()
    return out


def option_values(model: Any) -> dict[str, Any]:
    return {k: np.array(getattr(model.opt, k)).tolist() for k in OPTION_KEYS}


def changed_arrays(now: dict[str, np.ndarray], fresh: dict[str, np.ndarray]) -> dict[str, np.ndarray]:
    """The arrays of ``now`` that differ from ``fresh`` (a model's arrays as compiled), derived mesh data aside."""
    return {k: v for k, v in now.items()
            if k in fresh and not k.startswith(DERIVED) and (v.shape != fresh[k].shape or not np.array_equal(v, fresh[k]))}


# --- native side ---------------------------------------------------------------------------------------------

def _read(stream) -> Any:
    head = stream.read(HEADER.size)
    if len(head) < HEADER.size:
        return None
    return pickle.loads(stream.read(HEADER.unpack(head)[0]))


def _write(stream, obj: Any) -> None:
    blob = pickle.dumps(obj, protocol=4)
    stream.write(HEADER.pack(len(blob)) + blob)
    stream.flush()


def serve(commands: dict[str, Callable[..., Any]]) -> None:
    """Answer requests ``(command, kwargs)`` until stdin closes: ``("ok", result)`` or ``("error", text)``."""
    import warnings

    warnings.filterwarnings("ignore")
    out = os.fdopen(os.dup(1), "wb")
    os.dup2(2, 1)
    inp = os.fdopen(0, "rb")
    _write(out, ("ok", "ready"))
    while (msg := _read(inp)) is not None:
        command, kwargs = msg
        try:
            _write(out, ("ok", commands[command](**kwargs)))
        except Exception as exc:  # noqa: BLE001 - reported to the client, which raises it
            _write(out, ("error", f"{type(exc).__name__}: {exc}"))


# --- client side ---------------------------------------------------------------------------------------------

class NativeWorker:
    """``with NativeWorker("libero", "simseam.backends.libero_gpu.native") as w: w.call("describe", ...)``.

    ``backend``: the provisioned backend whose interpreter runs ``module`` (``python`` overrides it;
    ``BackendUnavailableError`` naming the command that provisions it when absent). ``once``: commands whose
    answer is the same for the worker's life, asked once per argument set (callers only read them)."""

    once: tuple[str, ...] = ("describe",)

    def __init__(self, backend: str, module: str, python: str | os.PathLike | None = None, wait: bool = True):
        if python is None:
            from simseam.backends.provision import require

            python = require(backend)
        self.backend, self.module, self.python = backend, module, str(python)
        self._answers: dict[tuple, Any] = {}
        self._helpers: list[NativeWorker] = []
        self._lock = threading.RLock()
        self._proc = None
        self._tmp = tempfile.TemporaryDirectory(prefix=f"simseam-{backend}-native-")
        os.symlink(Path(__file__).resolve().parents[1], Path(self._tmp.name) / "simseam")
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONHOME", "VIRTUAL_ENV", "PYTHONPATH")}
        env.update(PYTHONPATH=self._tmp.name, MUJOCO_GL=env.get("MUJOCO_GL", "egl"))
        self._proc = subprocess.Popen([self.python, "-m", module], stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                      env=env)
        if wait:
            self._wait_ready()

    def _wait_ready(self) -> None:
        from simseam.seam.errors import BackendUnavailableError

        status, what = self._receive("start")
        if status != "ok":
            self.close()
            raise BackendUnavailableError(f"{self.backend} native worker ({self.python}) failed to start: {what}")

    def call(self, command: str, **kwargs: Any) -> Any:
        """Run ``command`` in the worker; its exception comes back as a ``SimulationError`` naming it. Threads
        take turns: one request and its answer at a time (a run prepares its next task from a thread)."""
        with self._lock:
            if command in self.once:
                key = (command, tuple(sorted((k, repr(v)) for k, v in kwargs.items())))
                if key not in self._answers:
                    self._answers[key] = self._call(command, **kwargs)
                return self._answers[key]
            return self._call(command, **kwargs)

    def _call(self, command: str, **kwargs: Any) -> Any:
        self._send(command, kwargs)
        return self._answer(command, kwargs)

    def map(self, command: str, calls: list[dict[str, Any]]) -> list[Any]:
        """``call(command, **kw)`` for each ``kw`` of ``calls`` at once: this worker and ``len(calls) - 1`` helper
        processes of the same interpreter and module (started when first needed, kept until ``close``: a helper's
        own state, e.g. an env it built, serves its later calls), one call each; the answers in ``calls``' order.
        Every answer is read before the first failure is raised, so the workers stay in step."""
        with self._lock:
            return self._map(command, calls)

    def _map(self, command: str, calls: list[dict[str, Any]]) -> list[Any]:
        if len(calls) <= 1:
            return [self._call(command, **kw) for kw in calls]
        fresh = [NativeWorker(self.backend, self.module, self.python, wait=False)
                 for _ in range(len(calls) - 1 - len(self._helpers))]
        try:
            for helper in fresh:  # started together, waited for together
                helper._wait_ready()
        except BaseException:
            for helper in fresh:
                helper.close()
            raise
        self._helpers += fresh
        workers = [self, *self._helpers][:len(calls)]
        for worker, kw in zip(workers, calls):
            worker._send(command, kw)
        answers, failure = [], None
        for worker, kw in zip(workers, calls):
            try:
                answers.append(worker._answer(command, kw))
            except Exception as exc:  # noqa: BLE001 - raised once every worker has answered
                failure = failure or exc
        if failure is not None:
            raise failure
        return answers

    def _send(self, command: str, kwargs: dict[str, Any]) -> None:
        from simseam.seam.errors import SimulationError

        if self._proc is None:
            raise SimulationError(f"{self.backend} native worker: called after close()")
        blob = pickle.dumps((command, kwargs), protocol=4)
        self._proc.stdin.write(HEADER.pack(len(blob)) + blob)
        self._proc.stdin.flush()

    def _answer(self, command: str, kwargs: dict[str, Any]) -> Any:
        from simseam.seam.errors import SimulationError

        status, result = self._receive(command)
        if status != "ok":
            raise SimulationError(f"{self.backend} native worker: {command}({_brief(kwargs)}) failed: {result}")
        return result

    def _receive(self, what: str) -> tuple[str, Any]:
        from simseam.seam.errors import BackendUnavailableError

        head = self._proc.stdout.read(HEADER.size)
        if len(head) < HEADER.size:
            rc = self._proc.poll()
            raise BackendUnavailableError(f"{self.backend} native worker exited (rc={rc}) during {what}; "
                                          "its stderr above says why")
        return pickle.loads(self._proc.stdout.read(HEADER.unpack(head)[0]))

    def close(self) -> None:
        for helper in getattr(self, "_helpers", []):
            helper.close()
        self._helpers = []
        if self._proc is not None:
            proc, self._proc = self._proc, None
            proc.stdin.close()
            try:
                proc.wait(timeout=30)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
            proc.stdout.close()
        self._tmp.cleanup()

    def __enter__(self) -> "NativeWorker":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


def _brief(kwargs: dict[str, Any]) -> str:
    return ", ".join(f"{k}={v!r}" for k, v in kwargs.items() if isinstance(v, (str, int, float)))


def helpers_for(items: int, per_process: int = 4) -> int:
    """How many native processes to ask ``items`` slow answers of at once (``NativeWorker.map``): one per
    ``per_process`` items, at most ``SIMSEAM_NATIVE_WORKERS`` (default: the cores this process may use less one,
    at most 8; each process builds its own env: LIBERO's take about a GB each)."""
    limit = os.environ.get("SIMSEAM_NATIVE_WORKERS", "")
    if limit and not (limit.isdigit() and int(limit) >= 1):
        from simseam.seam.errors import ConfigError

        raise ConfigError(f"SIMSEAM_NATIVE_WORKERS={limit!r}: expected a whole number >= 1")
    cap = int(limit) if limit else min(8, max(1, len(os.sched_getaffinity(0)) - 1))
    return max(1, min(cap, -(-int(items) // per_process)))


def split(keys: list[Any], parts: int) -> list[list[Any]]:
    """``keys`` in ``parts`` contiguous runs of near-equal length (the first ones longer), none empty."""
    parts = max(1, min(int(parts), len(keys)))
    size, extra = divmod(len(keys), parts)
    cuts = [i * size + min(i, extra) for i in range(parts + 1)]
    return [keys[a:b] for a, b in zip(cuts, cuts[1:])]


class HeldAnswers:
    """Full answers a port asked of a native worker once and reads again soon, by (the worker's interpreter, key)
    until taken: a task's ``describe``, which its kept description is cut from and, on a machine where the task's
    model is not cached yet, its model is built from (Meta-World or LIBERO would otherwise build the task's env a
    second time). At most ``limit`` are held (a task's and the one a run prepares beside it: tens of MB each),
    behind a lock (a run's prefetch thread asks beside its main thread)."""

    def __init__(self, limit: int = 2):
        self.limit, self._held, self._lock = limit, {}, threading.Lock()

    def hold(self, worker: Any, key: Any, answer: Any) -> None:
        with self._lock:
            self._held[(_interpreter(worker), key)] = answer
            while len(self._held) > self.limit:
                self._held.pop(next(iter(self._held)))

    def take(self, worker: Any, key: Any) -> Any:
        """The answer held for ``key`` of this worker's interpreter (no longer held), or None."""
        with self._lock:
            return self._held.pop((_interpreter(worker), key), None)


def _interpreter(worker: Any) -> str:
    return str(getattr(worker, "python", id(worker)))


def cached_answers(folder: Path, keys: list[Any], ask: Callable[[list[Any]], list[Any]]) -> list[Any]:
    """One answer per key of ``keys`` (in order), each kept in ``folder/<key>.pkl``: the keys not there yet are
    asked of the native worker at once (``ask(missing)``, one answer per missing key in order) and written
    atomically (a killed writer leaves no partial file under the final name); keys repeated share one answer."""
    missing = sorted({k for k in keys if not (folder / f"{k}.pkl").is_file()})
    if missing:
        folder.mkdir(parents=True, exist_ok=True)
        for key, answer in zip(missing, ask(missing)):
            write_atomic(folder / f"{key}.pkl", pickle.dumps(answer, protocol=4))
    loaded = {k: pickle.loads((folder / f"{k}.pkl").read_bytes()) for k in dict.fromkeys(keys)}
    return [loaded[k] for k in keys]
