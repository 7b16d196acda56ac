"""The one registry mechanism: a static table per kind (tasks, policies, policy schemes, scripted experts,
engines, backends, benchmark ports, eval presets), name -> ``"module:attribute"``, imported only when that
name is asked for. A table entry may also be the object itself (a contributor's addition at run time, e.g.
a test's), or a row describing it (``EngineInfo``, ``BackendInfo``) whose ``"module:attribute"`` fields
``resolve`` imports; ``add`` writes an entry. Standard library and the seam's errors only."""

from __future__ import annotations

import importlib
from typing import Any

from simseam.seam.errors import ConfigError, did_you_mean


def load(table: dict[str, Any], name: str, kind: str) -> Any:
    """The object ``table[name]`` names (importing its module on first use); a ``ConfigError`` naming
    the closest known name otherwise."""
    try:
        entry = table[name]
    except KeyError:
        raise ConfigError(f"unknown {kind} {name!r}{did_you_mean(name, table)}; known: "
                          f"{', '.join(sorted(table))}") from None
    if isinstance(entry, str):
        entry = table[name] = resolve(entry)
    return entry


def resolve(ref: str) -> Any:
    """The object ``"module:attribute"`` names, its module imported now (``"module"`` alone: the module)."""
    module, _, attr = ref.partition(":")
    obj = importlib.import_module(module)
    return getattr(obj, attr) if attr else obj


def add(table: dict[str, Any], name: str, obj: Any) -> Any:
    """Add (or replace) one entry; returns ``obj`` (so it can decorate)."""
    if not name:
        raise ValueError(f"{obj!r} has no name to register under")
    table[name] = obj
    return obj
