"""Shards and merges: one evaluation split over independent jobs (Slurm arrays, several machines).

``simseam run --shard i/K`` runs the episodes ``e`` with ``e % K == i`` of the run's ``--episodes``
(seed ``seed + e`` as always, so a shard's episode is the same episode the whole run would play)
and records ``shard: [i, K]`` in its ``run.json``. ``simseam merge OUT DIR...`` combines run
directories into one:

- their configs must agree on everything but the shard (differences are listed: a ``ConfigError``);
- each episode index is counted once: an index in several directories (a shard re-run, or the
  same directory given twice) keeps one entry, and two entries that disagree on the result are a
  ``ConfigError`` unless ``prefer_first``;
- their ``provenance`` (``runner.provenance``) must agree on what changes the episode (the engine's
  or the benchmark's packages, the scene, robot and checkpoint files' contents); the rest that differs
  (simseam's revision, the GPU, the renderer) is named in ``provenance_notes``;
- the merged ``summary.json`` is ``complete`` when every planned index is there; the missing ones
  are listed;
- the runs' ``timings.jsonl`` lines (where a stepped run's time went, per part) are put together in the merged
  run's.

``simseam eval --shard i/K`` shards the same way over the global episode index ``task_index *
episodes_per_task + e`` (its config's ``episodes`` is the total), except on a batched engine's port (``--engine
mujoco_warp``), where a task's episodes are one batch: there shard ``i`` runs the whole tasks with ``task_index
% K == i`` (``shard_unit``: the episodes per task, in the config); the merged summary is rebuilt by
the one summary code path, so it holds the eval summary (``per_task`` with Wilson intervals,
``mean_task_success_rate``) one unsharded run writes, and the missing episodes are also listed per
task (``missing_by_task``: ``{task: [e, ...]}``). An eval run's ``spec.json`` is the spec of the task
it started with, so the shards' specs are compared without their ``task`` part and the merge keeps
the spec of the run holding the lowest index (the first task's, as an unsharded run's).

``simseam eval --processes K`` runs K such shards whose processes claim whole tasks one at a time instead
(``runner.claims``; their configs say ``dealing: claims``): a claimed shard's config does not say which episodes
it holds, and the merge plans them all.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Sequence

from simseam.seam import ConfigError

#: a shard's ``dealing`` when the K processes of ``simseam eval --processes`` claim whole tasks one at a time
#: (``runner.claims``): which tasks it runs depends on timing, so its config does not say its episodes
CLAIMED = "claims"

#: fields of an episode entry that say what happened (timings and video paths may differ between re-runs)
RESULT_FIELDS = ("seed", "success", "steps", "reward", "error")


def parse_shard(text: str) -> tuple[int, int]:
    """``"i/K"`` -> (i, K) with 0 <= i < K; anything else is a ``ConfigError``."""
    i, sep, k = str(text).strip().partition("/")
    try:
        i_, k_ = int(i), int(k)
    except ValueError:
        i_ = k_ = -1
    if not sep or k_ < 1 or not 0 <= i_ < k_:
        raise ConfigError(f"--shard {text!r}: expected i/K with 0 <= i < K, e.g. 0/4")
    return i_, k_


def shard_indices(episodes: int, shard: tuple[int, int] | None, unit: int = 1) -> list[int]:
    """The episode indices a shard runs (all of them without a shard): ``e`` with ``(e // unit) % K == i``
    (``unit`` > 1: whole runs of ``unit`` consecutive episodes, a batched port's whole tasks)."""
    if shard is None:
        return list(range(episodes))
    i, k = shard
    return [e for e in range(episodes) if (e // max(1, unit)) % k == i]


def check_shard_holds_episodes(planned: list[int], shard: tuple[int, int] | None, total: int,
                               unit: int = 1) -> list[int]:
    """``planned``, or a ``ConfigError`` when a shard holds none of the ``total`` episodes (a run of
    nothing would otherwise report 0/0 as complete)."""
    if not planned and shard is not None:
        rule = f"e % {shard[1]} == i" if unit <= 1 else f"(e // {unit}) % {shard[1]} == i: whole tasks"
        raise ConfigError(f"--shard {shard[0]}/{shard[1]}: none of the {total} episode(s) falls in this shard "
                          f"(shard i runs the episodes e with {rule})")
    return planned


def planned_indices(config: dict) -> list[int] | None:
    """The indices a run's config plans (its shard's: ``shard_unit`` whole tasks at a time for a batched port),
    or None when the config does not say (a shard whose tasks were claimed: the merged run plans them all)."""
    n = config.get("episodes")
    shard = config.get("shard")
    if not isinstance(n, int) or (shard and config.get("dealing") == CLAIMED):
        return None
    return shard_indices(n, tuple(shard) if shard else None, int(config.get("shard_unit", 1)))


def merge_runs(out: Path, dirs: Sequence[Path], *, overwrite: bool = False, prefer_first: bool = False) -> dict:
    """Merge run directories into ``out`` (see the module docstring); returns the merged summary."""
    from simseam.runner.run_dir import (CONFIG_FILE, RUN_FILES, SPEC_FILE, check_writable, rebuild_summary,
                                        write_json_atomic)

    if not dirs:
        raise ConfigError("simseam merge: name at least one run directory to merge")
    out = Path(out)
    configs, specs = _read_runs(dirs)
    base, notes = _common_config(dirs, configs)
    multi_task = isinstance(base.get("tasks"), list)  # simseam eval: each run's spec is its first task's
    _check_specs(dirs, specs, multi_task)
    merged, source = _merged_episodes(dirs, prefer_first)
    check_writable(out)
    held = [f for f in RUN_FILES if (out / f).exists()]
    if held and not overwrite:
        raise ConfigError(f"simseam merge: {out} already holds a run ({', '.join(held)}); pass --overwrite or "
                          "choose another output directory")
    out.mkdir(parents=True, exist_ok=True)
    write_json_atomic(out / CONFIG_FILE, base)
    known = [s for s in specs if s is not None]
    spec = known[0] if known else None
    if multi_task and merged:  # the spec of the run holding the first episode: the first task's, as one run's
        first = specs[[Path(d) for d in dirs].index(source[min(merged)])]
        spec = first if first is not None else spec
    if spec is not None:
        write_json_atomic(out / SPEC_FILE, spec)
    _write_log(out, merged)
    _merge_timings(out, dirs)
    summary = rebuild_summary(out, spec)
    _missing(summary, base, merged)
    summary["merged_from"] = [str(d) for d in dirs]
    summary["provenance_notes"] = notes
    write_json_atomic(out / "summary.json", summary)
    return summary


def _merge_timings(out: Path, dirs: Sequence[Path]) -> None:
    """The runs' ``TIMING_FILE`` lines, one after another, into ``out``'s (none: no file)."""
    from simseam.runner.run_dir import TIMING_FILE

    lines = [line for d in dirs if (Path(d) / TIMING_FILE).exists()
             for line in (Path(d) / TIMING_FILE).read_text().splitlines() if line.strip()]
    target = Path(out) / TIMING_FILE
    if lines:
        target.write_text("\n".join(lines) + "\n")
    elif target.exists():
        target.unlink()


def _read_runs(dirs: Sequence[Path]) -> tuple[list[dict], list[dict | None]]:
    """Each run's ``run.json`` (required) and ``spec.json`` (None when absent)."""
    from simseam.runner.run_dir import CONFIG_FILE, SPEC_FILE

    configs, specs = [], []
    for d in map(Path, dirs):
        try:
            configs.append(json.loads((d / CONFIG_FILE).read_text()))
        except (OSError, ValueError) as exc:
            raise ConfigError(f"simseam merge: {d}: cannot read {CONFIG_FILE} ({exc})") from None
        try:
            specs.append(json.loads((d / SPEC_FILE).read_text()))
        except (OSError, ValueError):
            specs.append(None)
    return configs, specs


def _common_config(dirs: Sequence[Path], configs: list[dict]) -> tuple[dict, list[str]]:
    """The runs' one config (shards aside), or a ``ConfigError`` naming what differs; with the notes of what
    moved without changing the episode."""
    from simseam.runner.run_dir import config_differences, provenance_check

    base = {k: v for k, v in configs[0].items() if k != "shard"}
    for d, c in zip(dirs[1:], configs[1:]):
        diff = config_differences(base, {k: v for k, v in c.items() if k != "shard"})
        if diff:
            raise ConfigError(f"simseam merge: {d} ran a different config than {dirs[0]}:\n"
                              + "\n".join(f"  - {x}" for x in diff))
    notes = [f"{d}: {note}" for d, c in zip(dirs[1:], configs[1:])
             for note in provenance_check(configs[0], c, f"simseam merge: {d} differs from {dirs[0]} in")]
    return base, notes


def _check_specs(dirs: Sequence[Path], specs: list[dict | None], multi_task: bool) -> None:
    def comparable(spec: dict) -> dict:
        return {k: v for k, v in spec.items() if k != "task"} if multi_task else spec

    known = [s for s in specs if s is not None]
    for d, s in zip(dirs, specs):
        if s is not None and comparable(s) != comparable(known[0]):
            raise ConfigError(f"simseam merge: {d}: its spec.json differs from {dirs[specs.index(known[0])]}'s "
                              "(a different simulator or robot behind the same scene file)")


def _merged_episodes(dirs: Sequence[Path], prefer_first: bool) -> tuple[dict[int, dict], dict[int, Path]]:
    """One entry per episode index over the runs, with the run each came from; the same index with other
    results is a ``ConfigError`` unless ``prefer_first``."""
    from simseam.runner.run_dir import read_log

    merged: dict[int, dict] = {}
    source: dict[int, Path] = {}
    for d in dirs:
        for e in read_log(Path(d)):
            i = int(e["index"])
            if i in merged:
                a = {k: merged[i].get(k) for k in RESULT_FIELDS}
                b = {k: e.get(k) for k in RESULT_FIELDS}
                if a != b and not prefer_first:
                    raise ConfigError(f"simseam merge: episode {i} is in {source[i]} and {d} with different results "
                                      f"({a} vs {b}); pass --prefer-first to keep the first")
                continue
            merged[i], source[i] = e, Path(d)
    return merged, source


def _write_log(out: Path, merged: dict[int, dict]) -> None:
    from simseam.runner.run_dir import LOG_FILE

    tmp = out / (LOG_FILE + ".merging")
    with open(tmp, "w") as f:
        for i in sorted(merged):
            f.write(json.dumps(merged[i]) + "\n")
        f.flush()
    tmp.replace(out / LOG_FILE)


def _missing(summary: dict, base: dict, merged: dict[int, dict]) -> None:
    """The planned episodes no run holds (``missing``; per task for shards of ``simseam eval``)."""
    planned = planned_indices(base) or []
    summary["missing"] = [i for i in planned if i not in merged]
    tasks, per_task = base.get("tasks"), base.get("episodes_per_task")
    if isinstance(tasks, list) and isinstance(per_task, int) and per_task > 0:  # shards of simseam eval
        by_task: dict[str, list[int]] = {}
        for i in summary["missing"]:
            by_task.setdefault(str(tasks[i // per_task]), []).append(i % per_task)
        summary["missing_by_task"] = by_task
