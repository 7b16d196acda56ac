"""Engines by name. Heavy SDKs are imported only when their engine is made."""

from __future__ import annotations

import os

from simseam.engines.base import Engine, EngineOptions
from simseam.seam import BackendUnavailableError, ConfigError

ENGINE_NAMES = ("mujoco", "isaac")


def make_engine(name: str, options: EngineOptions | None = None) -> Engine:
    """Create an engine in this process. ``isaac`` only ever runs in a sidecar: it is made
    only where the sidecar server marked the process (``SIMSEAM_SIDECAR=1``), and fails
    closed (``BackendUnavailableError`` with the provisioning command) when Isaac Sim is
    not installed in that interpreter. Nothing falls back to another engine."""
    if name == "mujoco":
        from simseam.engines.mujoco.engine import MujocoEngine

        return MujocoEngine(options)
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
    raise ConfigError(f"unknown engine {name!r}; known engines: {', '.join(ENGINE_NAMES)}")
