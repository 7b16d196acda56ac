"""Paired comparison of runs (``simseam compare A B [C ...]``, the results page's comparison section).

Two runs that played the same episodes (the same task, seed and, for a benchmark, the same init state:
episode ``e`` of a task) are compared episode by episode, each later run against the first:

- per task and over all paired episodes: both success rates with their Wilson 95 % intervals, the paired
  difference (later minus first) with Newcombe's 95 % interval for paired proportions (his method 10:
  the two Wilson intervals combined with the pairs' correlation; Statistics in Medicine 17, 1998),
  and McNemar's exact test (two-sided binomial test on the discordant pairs), its p Holm-corrected
  across the tasks;
- the episodes that only one run holds are listed (they are in no rate here);
- runs whose configs differ in something that changes the episode (the scene, the preset and its task
  config, and what ``runner.provenance`` marks so: the robot's files, the engine's or the benchmark's
  versions) are refused (``ConfigError``) unless ``force``; the policy and its checkpoint are what a
  comparison compares and may differ, and other provenance differences are named in ``notes``.

An errored episode counts as a failure, as in the run's summary.
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Any

from simseam.runner.provenance import describe, differences
from simseam.runner.run_dir import config_differences
from simseam.runner.summary import needed_episodes, wilson_interval  # noqa: F401 - needed_episodes: --ci-width
from simseam.seam import ConfigError

#: config entries that may differ between compared runs (the rest changes the episode)
MAY_DIFFER = ("policy", "episodes", "episodes_per_task", "seed", "video", "record_dataset", "shard", "renderer",
              "standard", "tasks", "scene_file", "provenance", "ci_width")
Z95 = 1.959964


def episode_key(e: dict, default_task: str) -> tuple:
    """What makes two runs' episodes the same episode: the task, the seed, and a benchmark's init state
    (the episode's number within its task)."""
    return str(e.get("task") or default_task), int(e["seed"]), e.get("episode")


def mcnemar_exact(b: int, c: int) -> float:
    """Two-sided exact McNemar p: the binomial test of ``min(b, c)`` among ``b + c`` discordant pairs at 1/2."""
    n = b + c
    if n == 0:
        return 1.0
    tail = sum(math.comb(n, i) for i in range(min(b, c) + 1)) / 2 ** n
    return min(1.0, 2 * tail)


def holm(ps: list[float]) -> list[float]:
    """Holm's step-down adjustment of ``ps`` (family-wise error), in the given order."""
    order = sorted(range(len(ps)), key=lambda i: ps[i])
    out, running = [0.0] * len(ps), 0.0
    for rank, i in enumerate(order):
        running = max(running, min(1.0, (len(ps) - rank) * ps[i]))
        out[i] = running
    return out


def paired_difference_ci(both: int, only_first: int, only_second: int, neither: int) -> tuple[float, float]:
    """Newcombe's (method 10) 95 % interval of (second's rate - first's rate) over paired episodes."""
    n = both + only_first + only_second + neither
    if n == 0:
        return -1.0, 1.0
    p1, p2 = (both + only_first) / n, (both + only_second) / n
    l1, u1 = wilson_interval(both + only_first, n, Z95)
    l2, u2 = wilson_interval(both + only_second, n, Z95)
    denom = (both + only_first) * (only_second + neither) * (both + only_second) * (only_first + neither)
    phi = (both * neither - only_first * only_second) / math.sqrt(denom) if denom else 0.0
    theta = p1 - p2  # Newcombe's orientation: first minus second
    delta = math.sqrt(max(0.0, (p1 - l1) ** 2 - 2 * phi * (p1 - l1) * (u2 - p2) + (u2 - p2) ** 2))
    eps = math.sqrt(max(0.0, (u1 - p1) ** 2 - 2 * phi * (u1 - p1) * (p2 - l2) + (p2 - l2) ** 2))
    lo, hi = theta - delta, theta + eps
    return max(-1.0, -hi), min(1.0, -lo)


def paired_stats(pairs: list[tuple[bool, bool]]) -> dict[str, Any]:
    """Rates, difference and McNemar's p of ``(first succeeded, second succeeded)`` pairs."""
    n = len(pairs)
    both = sum(a and b for a, b in pairs)
    only_first = sum(a and not b for a, b in pairs)
    only_second = sum(b and not a for a, b in pairs)
    k1, k2 = both + only_first, both + only_second
    lo, hi = paired_difference_ci(both, only_first, only_second, n - both - only_first - only_second)
    return {"n_pairs": n, "first": {"n_success": k1, "success_rate": k1 / n if n else 0.0,
                                    "success_rate_wilson95": list(wilson_interval(k1, n))},
            "second": {"n_success": k2, "success_rate": k2 / n if n else 0.0,
                       "success_rate_wilson95": list(wilson_interval(k2, n))},
            "difference": (k2 - k1) / n if n else 0.0, "difference_ci95": [lo, hi],
            "only_first_succeeded": only_first, "only_second_succeeded": only_second,
            "mcnemar_p": mcnemar_exact(only_first, only_second)}


def check_comparable(first: dict, second: dict, names: tuple[str, str], force: bool) -> list[str]:
    """``ConfigError`` for what changes the episode (unless ``force``: then named); the other notes."""
    skip = lambda c: {k: v for k, v in c.items() if k not in MAY_DIFFER}  # noqa: E731
    blocking = config_differences(skip(first), skip(second))
    notes = []
    for d in differences(first.get("provenance"), second.get("provenance")):
        if d[3] and not d[0].startswith("policy checkpoint"):
            blocking.append(describe(d))
        else:
            notes.append(describe(d).replace(" (changes the episode)", ""))
    if blocking and not force:
        raise ConfigError(f"simseam compare: {names[1]} and {names[0]} differ in what changes the episode "
                          "(pass --force to compare them anyway):\n" + "\n".join(f"  - {x}" for x in blocking))
    return [f"differs in what changes the episode (--force): {x}" for x in blocking] + notes


def _by_key(summary: dict) -> dict[tuple, dict]:
    from simseam.runner.report import task_name

    default = task_name(summary)
    return {episode_key(e, default): e for e in summary["episodes"]}


def compare_pair(first: dict, second: dict, names: tuple[str, str], *, force: bool = False) -> dict[str, Any]:
    """The paired comparison of two runs' summaries (``summary_of``), ``second`` against ``first``."""
    notes = check_comparable(first["config"], second["config"], names, force)
    a, b = _by_key(first), _by_key(second)
    shared = [k for k in a if k in b]
    tasks: dict[str, list[tuple[bool, bool]]] = {}
    for k in shared:
        tasks.setdefault(k[0], []).append((bool(a[k]["success"]), bool(b[k]["success"])))
    per_task = {t: paired_stats(p) for t, p in tasks.items()}
    for t, adj in zip(per_task, holm([s["mcnemar_p"] for s in per_task.values()])):
        per_task[t]["mcnemar_p_holm"] = adj
    only = lambda x, y: [{"task": k[0], "seed": k[1], **({"episode": k[2]} if k[2] is not None else {}),  # noqa: E731
                          "index": x[k]["index"]} for k in x if k not in y]
    return {"first": names[0], "second": names[1], "per_task": per_task,
            "overall": paired_stats([p for ps in tasks.values() for p in ps]),
            "only_in_first": only(a, b), "only_in_second": only(b, a), "notes": notes}


def compare_runs(paths: list[Path], *, force: bool = False, labels: list[str] | None = None) -> dict[str, Any]:
    """Each run after the first compared with the first (see the module docstring)."""
    from simseam.runner.report import load_run

    if len(paths) < 2:
        raise ConfigError("simseam compare needs at least two run directories (RUN_A RUN_B [RUN_C ...])")
    labels = labels or [str(p) for p in paths]
    summaries = [load_run(Path(p), incomplete=True) for p in paths]
    return {"baseline": labels[0], "comparisons": [
        compare_pair(summaries[0], s, (labels[0], label), force=force) for s, label in zip(summaries[1:], labels[1:])]}


def pairs_any(summaries: list[dict]) -> bool:
    """Whether the later runs share at least one episode with the first (the page then compares them)."""
    first = _by_key(summaries[0])
    return any(k in first for s in summaries[1:] for k in _by_key(s))
