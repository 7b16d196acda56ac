"""Run summaries: success rate with a Wilson score interval and per-episode diagnostics (summary.json)."""

from __future__ import annotations

import math
import platform
from importlib import metadata
from typing import Any



def wilson_interval(successes: int, n: int, z: float = 1.959964) -> tuple[float, float]:
    """Wilson score interval for a binomial proportion (95% by default)."""
    if n == 0:
        return 0.0, 1.0
    p = successes / n
    denom = 1 + z * z / n
    centre = (p + z * z / (2 * n)) / denom
    half = z * math.sqrt(p * (1 - p) / n + z * z / (4 * n * n)) / denom
    return max(0.0, centre - half), min(1.0, centre + half)


def _version(dist: str) -> str | None:
    try:
        return metadata.version(dist)
    except metadata.PackageNotFoundError:
        return None


def build_summary(config: dict[str, Any], spec: dict[str, Any] | None, episodes: list[dict[str, Any]]) -> dict[str, Any]:
    """``spec``: the rollout's ``RolloutSpec.to_json()``; ``episodes``: ``EpisodeResult.to_json()`` dicts.
    Besides the success rate, ``diagnostics_mean`` averages each numeric final diagnostic over the
    episodes (bools count as 0/1)."""
    n = len(episodes)
    k = sum(bool(e["success"]) for e in episodes)
    lo, hi = wilson_interval(k, n)
    diag: dict[str, list[float]] = {}
    for e in episodes:
        for name, v in (e.get("diagnostics") or {}).items():
            diag.setdefault(name, []).append(float(v))
    out = {
        "config": config,
        "spec": spec,
        "episodes": list(episodes),
        "diagnostics_mean": {name: sum(v) / len(v) for name, v in diag.items()},
        "n_episodes": n,
        "n_success": k,
        "success_rate": k / n if n else 0.0,
        "success_rate_wilson95": [lo, hi],
        "versions": {
            "simseam": _version("simseam"),
            "mujoco": _version("mujoco"),
            "python": platform.python_version(),
        },
    }
    if any("task" in e for e in episodes):  # a multi-task evaluation (simseam eval): success per task
        out["per_task"] = per_task(episodes)
        rates = [t["success_rate"] for t in out["per_task"].values()]
        out["mean_task_success_rate"] = sum(rates) / len(rates)
    return out


def per_task(episodes: list[dict[str, Any]]) -> dict[str, dict[str, Any]]:
    """``{task: {n_episodes, n_success, success_rate, success_rate_wilson95}}`` in first-seen order."""
    tasks: dict[str, list[bool]] = {}
    for e in episodes:
        tasks.setdefault(str(e.get("task")), []).append(bool(e["success"]))
    out = {}
    for name, ok in tasks.items():
        k, n = sum(ok), len(ok)
        out[name] = {"n_episodes": n, "n_success": k, "success_rate": k / n, "success_rate_wilson95":
                     list(wilson_interval(k, n))}
    return out
