"""A Meta-World task's model for this interpreter's MuJoCo: compiled from Meta-World's own XML in its
provisioned venv (never copied into the repository), with what the env's ``__init__`` changes in its
model applied the same way, checked against the native model, and cached keyed by the versions.

The cache lives in ``$SIMSEAM_CACHE/metaworld_gpu/`` (default ``~/.cache/simseam``), one directory per
(metaworld version, native MuJoCo version, this MuJoCo version), one ``<task>.mjb`` plus ``<task>.json``
(the XML's sha256 and the check report) per task: a venv of another Meta-World or MuJoCo version, or a
changed XML, builds a new model; a stale one is never loaded. Beside them, ``described-<code>-<venv>/<task>.pkl``
keeps the native worker's ``describe`` of each task less the native model's arrays (``described``): a batch
whose model and description are there asks the worker only for its versions, and no env is built natively.

The checks and the cache are ``backends.warp_model``'s (shared with the LIBERO port): sizes, masses,
inertias, frames, mesh extents, options and the contacts of a settled state (a native reset's).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simseam.backends import warp_model
from simseam.backends.native_worker import DERIVED, HeldAnswers, cached_answers
from simseam.backends.warp_model import apply_fields
from simseam.seam.errors import SimulationError

PORT = "metaworld_gpu"


@dataclass
class TaskModel:
    """``model``: the compiled ``MjModel``; ``info``: the native worker's ``describe`` (constants,
    versions); ``report``: what the checks compared; ``path``: the cached ``.mjb``."""

    task: str
    model: Any
    info: dict[str, Any]
    report: dict[str, Any]
    path: Path


def cache_root() -> Path:
    return warp_model.cache_root(PORT)


def cache_dir(info: dict[str, Any]) -> Path:
    import mujoco

    return cache_root() / f"metaworld-{info['metaworld']}_native-mujoco-{info['mujoco']}_mujoco-{mujoco.__version__}"


def init_changes(info: dict[str, Any]) -> dict[str, np.ndarray]:
    """What the env's ``__init__`` changed in its model (e.g. the mocap weld's ``eq_data``)."""
    fresh, init = info["fresh"], info["init"]
    return {k: v for k, v in init.items()
            if k in fresh and not k.startswith(DERIVED) and not np.array_equal(v, fresh[k])}


def compile_model(info: dict[str, Any]) -> tuple[Any, list[str]]:
    import mujoco

    xml = info["xml"]
    if not Path(xml).is_file():
        raise SimulationError(f"Meta-World task {info['task']!r}: its model file {xml} is missing")
    model = mujoco.MjModel.from_xml_path(xml)
    notes = apply_fields(model, init_changes(info), f"Meta-World task {info['task']!r}")
    return model, notes


def check_model(model: Any, info: dict[str, Any], settled: dict[str, Any] | None) -> dict[str, Any]:
    """Compare with the native model (``info['init']``) and, given a native reset (``settled``), its contact
    pairs in that state. Returns the report; raises ``SimulationError`` listing every mismatch."""
    return warp_model.check_model(model, info["init"], info["option"], settled, f"Meta-World task {info['task']!r}")


def xml_digest(path: str) -> str:
    return warp_model.digest(Path(path).read_bytes())


def load_or_build(info: dict[str, Any], settled: dict[str, Any] | None) -> TaskModel:
    """The cached model for ``info``'s versions and XML, or a fresh compile, checked, then cached."""
    notes: list[str] = []

    def compile_here() -> Any:
        model, widened = compile_model(info)
        notes.extend(widened)
        return model

    def check(model: Any) -> dict[str, Any]:
        return dict(check_model(model, info, settled), widened=notes)

    task = info["task"]
    model, report, path = warp_model.cached_model(cache_dir(info), task, xml_digest(info["xml"]), compile_here, check,
                                                  {"xml": info["xml"]})
    return TaskModel(task, model, info, report, path)


#: ``describe``'s native model arrays: only a build of the model and its checks read them (~40 MB a task)
HEAVY = ("fresh", "init", "option")

#: the full ``describe`` answers ``described`` asked for, until ``task_model`` builds from its task's
_ASKED = HeldAnswers()


def _worker_code() -> str:
    """The digest of the code that answers ``describe`` (the worker's, the protocol's and the CPU backend's rollout
    it builds)."""
    from simseam.backends import metaworld, native_worker
    from simseam.backends.metaworld_gpu import native

    return warp_model.code_digest(native, native_worker, metaworld)


def described(worker: Any, task: str) -> dict[str, Any]:
    """The worker's ``describe`` of ``task`` less ``HEAVY``: from disk when a worker of these versions, venv and
    code described it before, else asked (about a second: Meta-World builds the task's env) and kept
    (``cached_answers``)."""
    versions = worker.call("versions")
    where = cache_dir(versions) / f"described-{_worker_code()}-{warp_model.digest(versions['prefix'].encode())[:8]}"

    def ask(missing: list[str]) -> list[dict[str, Any]]:
        answers = []
        for t in missing:
            full = worker.call("describe", task=t)
            _ASKED.hold(worker, t, full)
            answers.append({k: v for k, v in full.items() if k not in HEAVY})
        return answers

    return cached_answers(where, [task], ask)[0]


def task_model(worker: Any, info: dict[str, Any], settled: dict[str, Any] | None) -> TaskModel:
    """The model of ``described``'s ``info``: from the cache when it is there (no env built natively), else built
    from the worker's full ``describe`` (the one ``described`` just asked for, when it did) and checked
    (``load_or_build``)."""
    asked = _ASKED.take(worker, info["task"])
    cached = warp_model.load_cached(cache_dir(info), info["task"], xml_digest(info["xml"]))
    if cached is None:
        return load_or_build(asked or worker.call("describe", task=info["task"]), settled)
    model, report, path = cached
    return TaskModel(info["task"], model, info, report, path)
