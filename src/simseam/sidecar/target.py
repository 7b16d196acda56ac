"""What a sidecar serves: plain data, made on the client side and carried in the sidecar's boot file.

- ``SceneTarget``: a manifest scene: the robot (``RobotSpec.to_json()``), the task, the engine and the
  ``SceneOptions`` fields (JSON types);
- ``BackendTarget``: a benchmark backend (``simseam.backends``) and its normalized config.

A recipe (``runner.recipe``: a scene file or an evaluation preset) resolves to one of these wherever
its rollout lives in a sidecar: ``SidecarRollout(target, ...)`` boots the sidecar with
``target.to_json()`` and the sidecar builds the rollout from ``target_from_json``. Two sidecars of the
same ``identity()`` are interchangeable (a kept-alive sidecar is adopted only by a client of its
identity).
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass, field
from typing import Any

from simseam.seam.errors import ConfigError


@dataclass(frozen=True)
class SceneTarget:
    """A manifest scene: ``spec`` a ``RobotSpec.to_json()``, ``options`` ``SceneOptions`` fields."""

    spec: dict
    task: str
    engine: str = "mujoco"
    options: dict = field(default_factory=dict)

    def to_json(self) -> dict[str, Any]:
        return {"kind": "scene", "spec": self.spec, "task": self.task, "engine": self.engine,
                "options": dict(self.options)}

    def identity(self) -> str:
        return _hash({"spec": self.spec, "task": self.task, "engine": self.engine, "options": self.options})

    def describe(self) -> str:
        return f"task {self.task!r} on engine {self.engine!r}"


@dataclass(frozen=True)
class BackendTarget:
    """A benchmark backend with its config (``normalize_config``'d by the client)."""

    backend: str
    config: dict

    @property
    def engine(self) -> str:  # the simulator the sidecar runs: the backend's own
        return self.backend

    @property
    def task(self) -> str:
        return str(self.config.get("task", self.backend))

    def to_json(self) -> dict[str, Any]:
        return {"kind": "backend", "backend": self.backend, "config": dict(self.config)}

    def identity(self) -> str:
        return _hash({"backend": self.backend, "config": self.config})

    def describe(self) -> str:
        return f"benchmark {self.backend!r}"


Target = SceneTarget | BackendTarget


def target_from_json(data: Any) -> Target:
    """The target a boot file carries (``to_json()``'s output); a ``ConfigError`` for anything else."""
    if not isinstance(data, dict) or data.get("kind") not in ("scene", "backend"):
        raise ConfigError(f"boot: target must be an object with kind 'scene' or 'backend', got {data!r:.200}")
    try:
        if data["kind"] == "backend":
            return BackendTarget(str(data["backend"]), dict(data.get("config") or {}))
        return SceneTarget(dict(data["spec"]), str(data["task"]), str(data.get("engine", "mujoco")),
                           dict(data.get("options") or {}))
    except (KeyError, TypeError, ValueError) as exc:
        raise ConfigError(f"boot: target {data.get('kind')!r} is missing or mistypes {exc}") from None


def _hash(what: dict) -> str:
    blob = json.dumps(what, sort_keys=True, separators=(",", ":"))
    return hashlib.sha256(blob.encode()).hexdigest()[:24]
