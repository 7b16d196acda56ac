"""The one error hierarchy. Messages say what was wrong, where, and what to do."""

from __future__ import annotations

import difflib
from typing import Iterable


class SimseamError(Exception):
    """Base of every error simseam raises on purpose."""


class ConfigError(SimseamError, ValueError):
    """A manifest, scene file, name or option is wrong. The message says where."""


class InvalidActionError(SimseamError, ValueError):
    """An action has the wrong shape, dtype or non-finite values. Nothing was applied."""


class BackendUnavailableError(SimseamError):
    """An engine or renderer cannot run here (not installed, no GL, no GPU)."""


class SimulationError(SimseamError):
    """The simulator failed while building or stepping the scene."""


class SidecarError(SimseamError):
    """Transport-level failure talking to an out-of-process engine."""


def did_you_mean(name: str, known: Iterable[str]) -> str:
    """`` (did you mean 'x'?)`` for the closest of ``known`` to a mistyped ``name``, or ``""``."""
    close = difflib.get_close_matches(str(name), [str(k) for k in known], n=1, cutoff=0.6)
    return f" (did you mean {close[0]!r}?)" if close else ""
