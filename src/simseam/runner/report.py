"""The results page of one or more run directories (``simseam report``): one self-contained HTML file.

It shows, for each run side by side: success per task with its Wilson 95 % interval (a chart and a table),
when the runs share episodes their paired comparison (``runner.compare``: each run against the first), the
step and policy latency of its episodes, a few episode videos, and the run's config. Everything is
inline: the CSS, the charts (SVG drawn here), the videos (the run's own H.264 MP4 files as ``data:`` URIs,
a few per run, see ``choose_videos``). The page loads nothing from anywhere, so it opens offline, attached
to a mail, or from an archive.

One run's page goes beside it (``RUN/report.html``, written by ``simseam run`` / ``eval`` when the run
completes); several runs need ``--out FILE``. An existing page is replaced only with ``overwrite``.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path

from simseam.files import write_atomic
from simseam.runner.report_html import PAGE_HEAD, render
from simseam.runner.run_dir import CONFIG_FILE, LOG_FILE, REPORT_FILE, RUN_FILES, SUMMARY_FILE, summary_of
from simseam.seam import ConfigError

#: videos embedded per run by default; each is the run's MP4 file, base64-encoded (a third larger)
DEFAULT_VIDEOS = 6
#: run colours (Okabe-Ito: told apart with the common colour-vision deficiencies)
COLOURS = ("#0072B2", "#E69F00", "#009E73", "#CC79A7", "#56B4E9", "#D55E00", "#F0E442", "#000000")


@dataclass
class Run:
    """One run directory as the page shows it (``report_html.render`` formats these)."""

    path: Path
    label: str
    summary: dict
    colour: str
    tasks: dict[str, dict] = field(default_factory=dict)  # task_rows
    latency: dict[str, dict | None] = field(default_factory=dict)  # "step" / "policy": latency()
    videos: list[tuple[dict, Path]] = field(default_factory=list)  # (episode, its video file) embedded
    n_videos: int = 0  # the run's videos in all


def load_run(path: Path, *, incomplete: bool = False) -> dict:
    """The summary of the run in ``path`` (computed, not written); ``ConfigError`` for a directory that
    holds no run, or an unfinished one unless ``incomplete``."""
    path = Path(path)
    if not path.is_dir():
        raise ConfigError(f"{path}: {'not a directory' if path.exists() else 'does not exist'} (expected a run "
                          "directory written by simseam run or eval)")
    missing = [f for f in (CONFIG_FILE, LOG_FILE) if not (path / f).is_file()]
    if missing:
        raise ConfigError(f"{path}: not a simseam run directory (no {' or '.join(missing)})")
    summary = summary_of(path)
    written = read_json(path / SUMMARY_FILE)  # the versions that ran it, not this machine's
    if isinstance(written, dict) and written.get("versions"):
        summary["versions"] = written["versions"]
    if summary["n_episodes"] == 0:
        raise ConfigError(f"{path}: the run holds no finished episode yet")
    if not summary["complete"] and not incomplete:
        raise ConfigError(f"{path}: unfinished run ({summary['n_episodes']} of {summary['config'].get('episodes')} "
                          "episodes recorded: still running, interrupted or damaged); finish it with --resume, "
                          "or pass --incomplete to report the finished episodes")
    return summary


def read_json(path: Path):
    try:
        return json.loads(path.read_text())
    except (OSError, ValueError):
        return None


def task_name(summary: dict) -> str:
    """The task of a ``simseam run`` (one task): the spec's, else the scene file's."""
    spec_task = ((summary.get("spec") or {}).get("task") or {}).get("name")
    scene_task = (summary["config"].get("scene") or {}).get("task")
    return str(spec_task or (scene_task if isinstance(scene_task, str) else None) or "task")


def task_rows(summary: dict) -> dict[str, dict]:
    """Success per task: ``{task: {n_episodes, n_success, success_rate, success_rate_wilson95}}``, each over
    that task's own episodes (``summary.per_task``); a run of one task gives one row."""
    if summary.get("per_task"):
        return summary["per_task"]
    keys = ("n_episodes", "n_success", "success_rate", "success_rate_wilson95")
    return {task_name(summary): {k: summary[k] for k in keys}}


def latency(episodes: list[dict], key: str) -> dict | None:
    """One run's latency (``key``: step_latency_ms or policy_latency_ms): the mean over all steps (the
    episodes' means weighted by their steps), the median of the episodes' p50, the largest episode p90."""
    es = [(e["steps"], e[key]) for e in episodes if (e.get(key) or {}).get("mean") is not None]
    if not es:
        return None
    steps = sum(n for n, _ in es)
    p50s = sorted(s["p50"] for _, s in es)
    return {"mean": sum(n * s["mean"] for n, s in es) / max(steps, 1), "p50": p50s[len(p50s) // 2],
            "p90": max(s["p90"] for _, s in es), "episode_means": [s["mean"] for _, s in es]}


def choose_videos(episodes: list[dict], run_dir: Path, n: int) -> list[dict]:
    """Up to ``n`` episodes whose video is in ``run_dir``: failures first, then successes, taken in turn
    from each task so that every task and outcome is seen; in episode order within each group."""
    groups: dict[tuple, list[dict]] = {}
    for e in episodes:
        if video_file(e, run_dir) is not None:
            groups.setdefault((bool(e["success"]), str(e.get("task", ""))), []).append(e)
    order = sorted(groups, key=lambda g: g[0])  # failures (False) first, tasks in first-seen order
    chosen: list[dict] = []
    while len(chosen) < n and any(groups[g] for g in order):
        for g in order:
            if groups[g] and len(chosen) < n:
                chosen.append(groups[g].pop(0))
    return sorted(chosen, key=lambda e: int(e["index"]))


def video_file(episode: dict, run_dir: Path) -> Path | None:
    """The episode's video in ``run_dir`` (by its recorded name, so a moved run directory still finds it)."""
    if not episode.get("video"):
        return None
    path = run_dir / Path(episode["video"]).name
    return path if path.is_file() else None


def labels(paths: list[Path]) -> list[str]:
    """Short names for the runs: the directory names, or the paths as given where two names are alike."""
    names = [p.resolve().name if p.name in ("", ".", "latest") else p.name for p in paths]
    return [n if names.count(n) == 1 else str(p) for n, p in zip(names, paths)]


def load_runs(paths: list[Path], *, videos: int = DEFAULT_VIDEOS, incomplete: bool = False) -> list[Run]:
    if not paths:
        raise ConfigError("no run directory given (simseam report RUN_DIR [RUN_DIR ...])")
    runs = []
    for i, (path, label) in enumerate(zip(paths, labels(paths))):
        summary = load_run(path, incomplete=incomplete)
        episodes = summary["episodes"]
        runs.append(Run(Path(path), label, summary, COLOURS[i % len(COLOURS)], tasks=task_rows(summary),
                        latency={"step": latency(episodes, "step_latency_ms"),
                                 "policy": latency(episodes, "policy_latency_ms")},
                        videos=[(e, video_file(e, Path(path))) for e in choose_videos(episodes, Path(path), videos)],
                        n_videos=sum(video_file(e, Path(path)) is not None for e in episodes)))
    return runs


def report_path(paths: list[Path], out: Path | None) -> Path:
    """Where the page goes: ``out``, else beside the one run (``RUN/report.html``)."""
    if out is not None:
        return Path(out)
    if len(paths) != 1:
        raise ConfigError(f"{len(paths)} runs on one page need --out FILE (one run's page goes beside it)")
    return Path(paths[0]) / REPORT_FILE


def write_report(paths: list[Path], out: Path | None = None, *, overwrite: bool = False,
                 videos: int = DEFAULT_VIDEOS, incomplete: bool = False) -> Path:
    """Write the page of the runs in ``paths`` (see the module docstring); returns where it went."""
    paths = [Path(p) for p in paths]
    runs = load_runs(paths, videos=videos, incomplete=incomplete)
    target = report_path(paths, out)
    check_target(target, overwrite)
    page = render(runs, paired_comparison(runs))
    write_atomic(target, page)
    return target


def paired_comparison(runs: list[Run]) -> list[dict] | None:
    """Each later run against the first (``runner.compare``), when they share episodes; None otherwise. A
    pair that ``simseam compare`` would refuse (the episodes differ) is named, not compared."""
    from simseam.runner.compare import compare_pair, pairs_any

    if len(runs) < 2 or not pairs_any([r.summary for r in runs]):
        return None
    out = []
    for r in runs[1:]:
        try:
            out.append(compare_pair(runs[0].summary, r.summary, (runs[0].label, r.label)))
        except ConfigError as exc:
            out.append({"first": runs[0].label, "second": r.label, "refused": str(exc)})
    return out


def check_target(target: Path, overwrite: bool) -> None:
    """``ConfigError`` unless the page may go to ``target``: a new file, or (with ``overwrite``) an earlier
    page. Nothing else is ever replaced, ``overwrite`` or not: a run's episode log, its config, any file."""
    if target.is_dir():
        raise ConfigError(f"--out {target}: is a directory (name the HTML file to write)")
    if not target.parent.is_dir():
        raise ConfigError(f"--out {target}: {target.parent} is not a directory")
    if target.name in RUN_FILES:
        raise ConfigError(f"--out {target}: {target.name} is a run's own file; the page goes to a file of its own "
                          "(e.g. report.html)")
    if not target.exists() and not target.is_symlink():
        return
    if not is_page(target):
        raise ConfigError(f"--out {target}: already exists and is not a simseam results page, so it is never "
                          "replaced (not even with --overwrite); choose another --out FILE")
    if not overwrite:
        raise ConfigError(f"{target} already exists (an earlier results page); pass --overwrite to replace it, "
                          "or --out FILE to write the page elsewhere")


def is_page(path: Path) -> bool:
    """Whether ``path`` is a page ``simseam report`` wrote (a regular file opening with the page's head)."""
    if path.is_symlink() or not path.is_file():
        return False
    try:
        with open(path, "rb") as f:
            head = f.read(len(PAGE_HEAD) + 16)
    except OSError:
        return False
    return head.startswith(PAGE_HEAD.encode())
