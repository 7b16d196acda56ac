"""Run summaries: success rate with a Wilson score interval, written as summary.json."""

from __future__ import annotations

import json
import math
import platform
from importlib import metadata
from pathlib import Path
from typing import Any

from simseam.runner.episodes import EpisodeResult


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


def build_summary(config: dict[str, Any], scene: dict[str, Any], episodes: list[EpisodeResult]) -> dict[str, Any]:
    n = len(episodes)
    k = sum(e.success for e in episodes)
    lo, hi = wilson_interval(k, n)
    return {
        "config": config,
        "scene": scene,
        "episodes": [e.to_json() for e in episodes],
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


def write_summary(out_dir: Path, summary: dict[str, Any]) -> Path:
    out_dir.mkdir(parents=True, exist_ok=True)
    path = out_dir / "summary.json"
    path.write_text(json.dumps(summary, indent=2))
    return path
