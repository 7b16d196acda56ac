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


#: the half-width of the Wilson 95 % interval a summary sizes its episodes for (``--ci-width``)
DEFAULT_CI_WIDTH = 0.05
MAX_EPISODES = 1_000_000


def needed_episodes(rate: float, half_width: float, z: float = 1.959964) -> int:
    """Episodes a task needs for a Wilson 95 % interval of half-width ``half_width`` at success rate ``rate``:
    the smallest n whose interval at k = round(rate * n) is that narrow (at most ``MAX_EPISODES``)."""
    from simseam.seam import ConfigError

    if not 0 < half_width < 0.5:
        raise ConfigError(f"--ci-width {half_width!r}: a half-width between 0 and 0.5 (e.g. 0.05 for +-5 points)")
    rate = min(max(rate, 0.0), 1.0)

    def narrow(n: int) -> bool:
        lo, hi = wilson_interval(round(rate * n), n, z)
        return (hi - lo) / 2 <= half_width

    lo, hi = 1, MAX_EPISODES
    if not narrow(hi):
        return hi
    while lo < hi:  # the half-width shrinks as n grows (up to the rounding of k): bisect on it
        mid = (lo + hi) // 2
        lo, hi = (mid + 1, hi) if not narrow(mid) else (lo, mid)
    return lo


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
    width = float(config.get("ci_width") or DEFAULT_CI_WIDTH)
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
        # how many episodes a +-width interval needs at this rate (per task: per_task's)
        "ci_width": width,
        "episodes_for_ci_width": needed_episodes(k / n if n else 0.0, width),
        "versions": {
            "simseam": _version("simseam"),
            "mujoco": _version("mujoco"),
            "python": platform.python_version(),
        },
    }
    if any("task" in e for e in episodes):  # a multi-task evaluation (simseam eval): success per task
        out["per_task"] = per_task(episodes, width)
        rates = [t["success_rate"] for t in out["per_task"].values()]
        out["mean_task_success_rate"] = sum(rates) / len(rates)
    return out


def per_task(episodes: list[dict[str, Any]], width: float = DEFAULT_CI_WIDTH) -> dict[str, dict[str, Any]]:
    """``{task: {n_episodes, n_success, success_rate, success_rate_wilson95, episodes_for_ci_width}}`` in
    first-seen order (the last: the episodes a +-``width`` interval needs at the task's rate)."""
    tasks: dict[str, list[bool]] = {}
    for e in episodes:
        tasks.setdefault(str(e.get("task")), []).append(bool(e["success"]))
    out = {}
    for name, ok in tasks.items():
        k, n = sum(ok), len(ok)
        out[name] = {"n_episodes": n, "n_success": k, "success_rate": k / n, "success_rate_wilson95":
                     list(wilson_interval(k, n)), "episodes_for_ci_width": needed_episodes(k / n, width)}
    return out
