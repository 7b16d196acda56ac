"""The one registry mechanism: a static table per kind (tasks, policies, policy schemes, engines,
backends, eval presets), name -> ``"module:attribute"``, imported only when that name is asked for.
A table entry may also be the object itself (a contributor's addition at run time, e.g. a test's);
``add`` writes one. Standard library and the seam's errors only."""

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
        module, _, attr = entry.partition(":")
        entry = table[name] = getattr(importlib.import_module(module), attr)
    return entry


def add(table: dict[str, Any], name: str, obj: Any) -> Any:
    """Add (or replace) one entry; returns ``obj`` (so it can decorate)."""
    if not name:
        raise ValueError(f"{obj!r} has no name to register under")
    table[name] = obj
    return obj
