"""Where a ``simseam eval`` run's time went, per process, from its ``timings.jsonl`` (the benches that time the
product's command read it: ``metaworld_warp_throughput.py --mt50-cli``, ``bench_libero_scale.py``)."""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any


def stepping(run: Path) -> dict[str, float]:
    """Each task's stepping seconds, from the run's episode log: its episodes step in one batch, so the longest
    episode's steps times its mean step latency (the step's own time: the policy's is not in it)."""
    by_task: dict[str, float] = {}
    for line in (Path(run) / "episodes.jsonl").read_text().splitlines():
        r = json.loads(line)
        secs = r["steps"] * (r["step_latency_ms"]["mean"] or 0.0) / 1e3  # none for an episode that never stepped
        by_task[r["task"]] = max(by_task.get(r["task"], 0.0), secs)
    return by_task


def per_process(run: Path, launched: float) -> list[dict[str, Any]]:
    """A row per process of the run in ``run`` (its ``timings.jsonl``: a line per task's batch, with its process's
    start and when the batch began to open, opened and finished), ``launched`` the command's start (epoch
    seconds): the seconds from the launch to the process's start, from there to its first batch opening, from
    the start to its policy built (``to_policy``, None in runs that did not record it; a policy that told what
    it reads loads while the first batch opens, so it may end after the opening began), its batches' opening
    (builds, the preparation waited for) and running (resets, steps, the episodes written; the first batch's
    includes ``waited_for_policy``, the seconds it waited for a policy still loading) summed, of which
    ``stepping`` (the episode log's), and when its last task ended; [] when the run wrote none."""
    path = Path(run) / "timings.jsonl"
    if not path.exists():
        return []
    steps = stepping(run)
    procs: dict[int, list[dict]] = {}
    for line in path.read_text().splitlines():
        t = json.loads(line)
        procs.setdefault(t["process"], []).append(t)
    rows = []
    for mine in procs.values():
        started = mine[0]["process_started"]
        ready = mine[0].get("policy_ready")  # when the process's policy was built (runs since 7 December)
        rows.append({"launch_to_process": round(started - launched, 2),
                     "process_to_first_open": round(min(t["open"] for t in mine) - started, 2),
                     "to_policy": None if ready is None else round(ready - started, 2),
                     "waited_for_policy": None if ready is None else round(max(0.0, ready - mine[0]["opened"]), 2),
                     "opening": round(sum(t["opened"] - t["open"] for t in mine), 2),
                     "running": round(sum(t["ran"] - t["opened"] for t in mine), 2),
                     "stepping": round(sum(steps.get(t["part"], 0.0) for t in mine), 2),
                     "last_done": round(max(t["ran"] for t in mine) - launched, 2), "tasks": len(mine)})
    return sorted(rows, key=lambda r: r["last_done"])
