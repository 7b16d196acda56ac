"""Engines by name. Heavy SDKs are imported only when their engine is made."""

from __future__ import annotations

from simseam.engines.base import Engine, EngineOptions
from simseam.seam import BackendUnavailableError, ConfigError

ENGINE_NAMES = ("mujoco", "isaac")


def make_engine(name: str, options: EngineOptions | None = None) -> Engine:
    """Create an engine in this process. ``isaac`` only ever runs in a sidecar."""
    if name == "mujoco":
        from simseam.engines.mujoco.engine import MujocoEngine

        return MujocoEngine(options)
    if name == "isaac":
        raise BackendUnavailableError(
            "engine 'isaac' runs only in a sidecar process with its own Isaac Sim installation, "
            "which this release does not provide yet; use engine 'mujoco'"
        )
    raise ConfigError(f"unknown engine {name!r}; known engines: {', '.join(ENGINE_NAMES)}")
