"""Engines by name: one static table. Heavy SDKs are imported only when their engine is made."""

from __future__ import annotations

import os
from dataclasses import dataclass

from simseam import registry
from simseam.engines.base import Engine, EngineOptions
from simseam.engines.isaac import SIDECAR_ENV
from simseam.seam import BackendUnavailableError, ConfigError


@dataclass(frozen=True)
class EngineInfo:
    """``factory``: what makes it, ``"module:attribute"`` (imported only when made): an ``Engine`` class
    for an engine of primitives, or for a batched engine the function that builds N worlds of a scene
    (``(robot, task, num_envs, options, device) -> BatchedScene``); ``processes``: where it may run
    (``inprocess``, ``sidecar``); ``batched``: N worlds in one process, built as a batched scene rather
    than as an ``Engine`` of primitives under a ``ManifestScene``; ``hint``: ``"module:function"`` giving
    the set-up hint when it cannot run here (optional)."""

    name: str
    factory: str
    processes: tuple[str, ...]
    batched: bool
    description: str
    hint: str = ""


ENGINES: dict[str, EngineInfo] = {
    "mujoco": EngineInfo("mujoco", "simseam.engines.mujoco.engine:MujocoEngine", ("inprocess", "sidecar"), False,
                         "MuJoCo on the CPU (the default)"),
    "isaac": EngineInfo("isaac", "simseam.engines.isaac.engine:IsaacEngine", ("sidecar",), False,
                        "Isaac Sim (PhysX, RTX cameras), in a sidecar with its own interpreter",
                        hint="simseam.engines.isaac.provision:provision_hint"),
    "mujoco_warp": EngineInfo("mujoco_warp", "simseam.scene.warp:open_batch", ("inprocess",), True,
                              "MuJoCo Warp: N worlds of a scene in one process on a GPU"),
}
ENGINE_NAMES = tuple(ENGINES)


def engine_info(name: str) -> EngineInfo:
    return registry.load(ENGINES, name, "engine")


def make_engine(name: str, options: EngineOptions | None = None) -> Engine:
    """Create an engine of primitives in this process. One that runs only in a sidecar (``isaac``) is made
    only where the sidecar server marked the process (``SIMSEAM_SIDECAR=1``); an engine whose SDK is not
    installed there fails closed (``BackendUnavailableError`` with its set-up hint). A batched engine
    (``mujoco_warp``) is no engine of primitives: ``open_batched`` builds its scenes. Nothing falls back
    to another engine."""
    info = engine_info(name)
    if info.batched:
        raise ConfigError(f"engine {name!r} runs N worlds as one batched scene ({info.factory}), not under a "
                          "ManifestScene; a scene file with engine: {name: " + name + "} builds it")
    if "inprocess" not in info.processes and os.environ.get(SIDECAR_ENV) != "1":
        raise BackendUnavailableError(
            f"engine {name!r} runs only in a sidecar process with its own interpreter, never in the client "
            f"process (engine: {{name: {name}, process: sidecar, python: ...}}). " + _hint(info))
    return registry.resolve(info.factory)(options)


def open_batched(name: str, robot, task: str, num_envs: int, options=None, device: str | None = None):
    """N worlds of a manifest scene on the batched engine ``name`` (its ``factory``)."""
    info = engine_info(name)
    if not info.batched:
        raise ConfigError(f"a batched scene needs a batched engine "
                          f"({', '.join(n for n, i in ENGINES.items() if i.batched)}), got {name!r}")
    return registry.resolve(info.factory)(robot, task, num_envs, options, device)


def _hint(info: EngineInfo) -> str:
    return registry.resolve(info.hint)() if info.hint else ""
