"""Engines by name: one static table. Heavy SDKs are imported only when their engine is made."""

from __future__ import annotations

import os
from dataclasses import dataclass

from simseam import registry
from simseam.engines.base import Engine, EngineOptions
from simseam.seam import BackendUnavailableError, ConfigError


@dataclass(frozen=True)
class EngineInfo:
    """``module``: where it lives (imported only when made); ``processes``: where it may run
    (``inprocess``, ``sidecar``); ``batched``: N worlds in one process, built as a batched scene
    (``simseam.scene.warp``) rather than as an ``Engine`` of primitives under a ``ManifestScene``."""

    name: str
    module: str
    processes: tuple[str, ...]
    batched: bool
    description: str


ENGINES: dict[str, EngineInfo] = {
    "mujoco": EngineInfo("mujoco", "simseam.engines.mujoco.engine", ("inprocess", "sidecar"), False,
                         "MuJoCo on the CPU (the default)"),
    "isaac": EngineInfo("isaac", "simseam.engines.isaac.engine", ("sidecar",), False,
                        "Isaac Sim (PhysX, RTX cameras), in a sidecar with its own interpreter"),
    "mujoco_warp": EngineInfo("mujoco_warp", "simseam.scene.warp", ("inprocess",), True,
                              "MuJoCo Warp: N worlds of a scene in one process on a GPU"),
}
ENGINE_NAMES = tuple(ENGINES)


def engine_info(name: str) -> EngineInfo:
    return registry.load(ENGINES, name, "engine")


def make_engine(name: str, options: EngineOptions | None = None) -> Engine:
    """Create an engine in this process. ``isaac`` only ever runs in a sidecar: it is made
    only where the sidecar server marked the process (``SIMSEAM_SIDECAR=1``), and fails
    closed (``BackendUnavailableError`` with the provisioning command) when Isaac Sim is
    not installed in that interpreter. A batched engine (``mujoco_warp``) is no engine of
    primitives: its scenes are built by ``simseam.scene.warp``. Nothing falls back to another engine."""
    info = engine_info(name)
    if info.batched:
        raise ConfigError(f"engine {name!r} runs N worlds as one batched scene ({info.module}), not under a "
                          "ManifestScene; a scene file with engine: {name: " + name + "} builds it")
    if name == "isaac":
        from simseam.engines.isaac import SIDECAR_ENV
        from simseam.engines.isaac.provision import provision_hint

        if os.environ.get(SIDECAR_ENV) != "1":
            raise BackendUnavailableError(
                "engine 'isaac' runs only in a sidecar process with its own Isaac Sim interpreter, never "
                "in the client process (engine: {name: isaac, process: sidecar, python: ...}). " + provision_hint()
            )
        from simseam.engines.isaac.engine import IsaacEngine

        return IsaacEngine(options)
    from simseam.engines.mujoco.engine import MujocoEngine

    return MujocoEngine(options)
