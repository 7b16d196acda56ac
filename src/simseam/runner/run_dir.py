"""A run's output directory: results are never lost or silently replaced.

Layout of ``DIR``::

    run.json          the run's config (what ran: scene, policy, seeds, options), written first
    spec.json         the rollout's RolloutSpec, written once the rollout is built
    episodes.jsonl    one JSON line per finished episode, appended, flushed and fsynced as it ends
    summary.json      rebuilt from episodes.jsonl, written atomically (temp file + rename)
    episode_NNN.mp4   videos (written as episode_NNN.partial.mp4, renamed when complete)
    report.html       the results page (runner/report.py), written when the run completes
    timings.jsonl     a run stepped from its process (a port's or a batched scene's): one line per part (a task's
                      batch) when its process started, when its policy was built, when the part began to open,
                      opened and finished running (epoch seconds), appended as each part ends: where the time
                      went, not results

Rules: the directory is checked when the ``RunDir`` is made (a file, or a place
where no directory can be created or written, is a ``ConfigError``), and nothing
is written there until the run starts: at the first ``write_spec`` or ``append``,
once the rollout and the policy are built. So a run that fails before it starts
(an unknown policy, a typo in the scene, an unprovisioned backend) leaves the
directory as it was: no half-made run, and an ``overwrite`` that never started
destroys nothing. A directory that already holds a run is refused unless
``overwrite`` (the old run's files are removed when the new run starts: two runs
never mix) or ``resume`` (same config required; the differences are listed
otherwise; episodes already in the log are skipped). ``rebuild_summary(DIR)``
turns the log into ``summary.json`` after any crash.
"""

from __future__ import annotations

import datetime as _dt
import json
import os
import tempfile
from pathlib import Path
from typing import Any

from simseam.files import write_atomic
from simseam.seam import ConfigError

CONFIG_FILE = "run.json"
SPEC_FILE = "spec.json"
LOG_FILE = "episodes.jsonl"
SUMMARY_FILE = "summary.json"
REPORT_FILE = "report.html"
RUN_FILES = (CONFIG_FILE, SPEC_FILE, LOG_FILE, SUMMARY_FILE)
#: when each part of a run stepped from its process (a task's batch) opened and ran: where the time went, not results
TIMING_FILE = "timings.jsonl"


def write_json_atomic(path: Path, data: Any) -> None:
    """Write JSON to ``path`` through a temp file in the same directory and a rename."""
    write_atomic(path, json.dumps(data, indent=2))


def default_run_dir(root: Path = Path("runs")) -> Path:
    """A new directory per run, ``runs/<UTC timestamp>`` (a suffix when taken)."""
    stamp = _dt.datetime.now(_dt.timezone.utc).strftime("%Y%m%d-%H%M%S")
    path = root / stamp
    n = 1
    while path.exists():
        path = root / f"{stamp}-{n}"
        n += 1
    return path


def point_latest(run: Path) -> None:
    """Make ``<parent>/latest`` a symlink to ``run`` (replaced atomically; a real directory named
    latest is left alone)."""
    latest = run.parent / "latest"
    if latest.exists() and not latest.is_symlink():
        return
    tmp = run.parent / f".latest.{os.getpid()}"
    tmp.unlink(missing_ok=True)
    os.symlink(run.name, tmp)
    os.replace(tmp, latest)


#: what a run's config records but does not decide: the path the scene file was named by (its parsed
#: contents, ``scene``, are compared instead: the same file reached through another path is the same run),
#: what can move its number (``provenance``), compared by ``runner.provenance.differences``, and the interval
#: width its summary sizes the episodes for (``ci_width``: a resumed run may ask for another)
NOT_COMPARED = ("scene_file", "provenance", "ci_width")


def provenance_check(old: dict, new: dict, what: str) -> list[str]:
    """The provenance differences of two configs as lines; a ``ConfigError`` (``what``: the refusal's
    beginning) naming those that change the episode, together with the rest."""
    from simseam.runner.provenance import describe, differences

    diff = differences(old.get("provenance"), new.get("provenance"))
    if any(d[3] for d in diff):
        raise ConfigError(f"{what} something that changes the episode:\n"
                          + "\n".join(f"  - {describe(d)}" for d in diff))
    return [describe(d) for d in diff]


def config_differences(old: dict, new: dict, prefix: str = "") -> list[str]:
    """Human-readable differences between two configs (``key: old -> new``), ``NOT_COMPARED`` aside."""
    out = []
    for k in sorted((set(old) | set(new)) - (set(NOT_COMPARED) if not prefix else set())):
        a, b = old.get(k, "<absent>"), new.get(k, "<absent>")
        if isinstance(a, dict) and isinstance(b, dict):
            out += config_differences(a, b, f"{prefix}{k}.")
        elif a != b:
            out.append(f"{prefix}{k}: {a!r} -> {b!r}")
    return out


def check_writable(path: Path) -> None:
    """``ConfigError`` unless ``path`` is (or can be created as) a writable directory."""
    if path.exists() and not path.is_dir():
        raise ConfigError(f"--out {path}: exists and is not a directory")
    probe_dir = path
    while not probe_dir.exists():
        probe_dir = probe_dir.parent
    if not probe_dir.is_dir() or not os.access(probe_dir, os.W_OK | os.X_OK):
        raise ConfigError(f"--out {path}: {probe_dir} is not writable")
    try:  # what access() cannot tell (/proc, /sys, a read-only mount): a directory made and removed
        os.rmdir(tempfile.mkdtemp(prefix=".write-test.", dir=path if path.exists() else probe_dir))
    except OSError as exc:
        raise ConfigError(f"--out {path}: cannot {'write there' if path.exists() else 'create it'} "
                          f"({exc.strerror})") from None


class RunDir:
    """The output directory of one run (see the module docstring). ``latest``: point
    ``<parent>/latest`` at it once the run starts."""

    def __init__(self, path: Path, config: dict, *, overwrite: bool = False, resume: bool = False,
                 latest: bool = False):
        if overwrite and resume:
            raise ConfigError("--overwrite and --resume exclude each other")
        self.path = Path(path)
        check_writable(self.path)
        self.config = json.loads(json.dumps(config))  # plain JSON, as it will be read back
        self.held = [f for f in RUN_FILES if (self.path / f).exists()]
        self.resumed: list[dict] = []
        self.notes: list[str] = []  # --resume: what differs from the run there without changing the episode
        if self.held and resume:
            old = self._read_config()
            diff = config_differences(old, self.config)
            if diff:
                raise ConfigError(f"--resume {self.path}: the run there has a different config:\n"
                                  + "\n".join(f"  - {d}" for d in diff))
            self.notes = provenance_check(old, self.config, f"--resume {self.path}: the run there differs in")
            self.resumed = read_log(self.path)
        elif self.held and not overwrite:
            raise ConfigError(f"--out {self.path} already holds a run ({', '.join(self.held)}); pass --overwrite to "
                              "replace it, --resume to continue it, or choose another --out")
        self.resume, self.latest = resume, latest
        self.started = False
        self._log = None

    def start(self) -> None:
        """Write the run's start (idempotent): replace an old run (``overwrite``), the config, the empty log."""
        if self.started:
            return
        try:
            if self.held and not self.resume:
                for f in self.path.iterdir():
                    if f.name in (*RUN_FILES, REPORT_FILE, TIMING_FILE) or (f.name.startswith("episode_")
                                                                            and f.suffix == ".mp4"):
                        f.unlink()
            self.path.mkdir(parents=True, exist_ok=True)
            if not (self.resume and self.held):
                write_json_atomic(self.path / CONFIG_FILE, self.config)
                (self.path / LOG_FILE).touch()
            self._log = open(self.path / LOG_FILE, "a")
        except OSError as exc:
            raise ConfigError(f"--out {self.path}: cannot write the run there ({exc.strerror})") from None
        self.started = True
        if self.latest:
            point_latest(self.path)

    def _read_config(self) -> dict:
        try:
            return json.loads((self.path / CONFIG_FILE).read_text())
        except (OSError, ValueError) as exc:
            raise ConfigError(f"--resume {self.path}: cannot read {CONFIG_FILE}: {exc}") from None

    @property
    def done(self) -> set[int]:
        """Episode indices already in the log (skipped when resuming)."""
        return {int(e["index"]) for e in self.resumed}

    def left(self, planned) -> list[int]:
        """Of the ``planned`` episode indices, the ones not yet in the log, in order: what a resumed run still
        runs (read from the indices logged, never counted: parallel workers finish out of order)."""
        done = self.done
        return [i for i in sorted(planned) if i not in done]

    def write_spec(self, spec_json: dict) -> None:
        self.start()
        write_json_atomic(self.path / SPEC_FILE, spec_json)

    def append(self, episode: dict) -> None:
        """Record one finished episode: one line, flushed and fsynced before returning."""
        self.start()
        self._log.write(json.dumps(episode) + "\n")
        self._log.flush()
        os.fsync(self._log.fileno())

    def append_timing(self, entry: dict) -> None:
        """One part's line in ``TIMING_FILE`` (``job._stepped``): appended and flushed (not results: not fsynced)."""
        self.start()
        with open(self.path / TIMING_FILE, "a") as f:
            f.write(json.dumps(entry) + "\n")

    def summarize(self, spec_json: dict | None = None, *, interrupted: bool = False) -> dict | None:
        """``rebuild_summary`` of this run, or None when it never started and holds no earlier run to
        continue (nothing was written)."""
        if not self.started and not (self.resume and self.held):
            return None
        return rebuild_summary(self.path, spec_json, interrupted=interrupted)

    def close(self) -> None:
        if self._log is not None:
            self._log.close()


#: what every line of the episode log holds (``EpisodeResult.to_json``)
EPISODE_KEYS = ("index", "seed", "success", "steps")


def read_log(path: Path) -> list[dict]:
    """The finished episodes in ``DIR/episodes.jsonl``, by index (an index logged twice counts once, the
    last entry winning). A torn last line (a kill mid-write) is skipped; see ``damaged_lines``."""
    return _read_log(path)[0]


def damaged_lines(path: Path) -> list[int]:
    """Line numbers (1-based) of the log that hold no episode record, a torn last line (no newline) excepted."""
    return _read_log(path)[1]


def _read_log(path: Path) -> tuple[list[dict], list[int]]:
    log = Path(path) / LOG_FILE
    if not log.is_file():
        raise ConfigError(f"{path}: no {LOG_FILE} (not a simseam run directory)")
    by_index: dict[int, dict] = {}
    bad: list[int] = []
    text = log.read_text()
    lines = text.splitlines()
    torn = len(lines) if not text.endswith("\n") else 0  # a kill mid-write leaves a last line with no newline
    for n, line in enumerate(lines, 1):
        try:
            e = json.loads(line)
            if not isinstance(e, dict) or any(k not in e for k in EPISODE_KEYS):
                raise ValueError
            by_index[int(e["index"])] = e
        except (ValueError, TypeError):
            if line.strip() and n != torn:
                bad.append(n)
    return [by_index[i] for i in sorted(by_index)], bad


def rebuild_summary(path: Path, spec_json: dict | None = None, *, interrupted: bool = False) -> dict:
    """Rebuild ``DIR/summary.json`` from its config and episode log; returns the summary."""
    summary = summary_of(path, spec_json, interrupted=interrupted)
    write_json_atomic(Path(path) / SUMMARY_FILE, summary)
    return summary


def summary_of(path: Path, spec_json: dict | None = None, *, interrupted: bool = False) -> dict:
    """The summary of the run in ``DIR`` (its config, spec and episode log), computed and not written."""
    from simseam.runner.summary import build_summary

    path = Path(path)
    episodes, damaged = _read_log(path)
    try:
        config = json.loads((path / CONFIG_FILE).read_text())
    except (OSError, ValueError):
        config = {}
    if spec_json is None:
        try:
            spec_json = json.loads((path / SPEC_FILE).read_text())
        except (OSError, ValueError):
            spec_json = None
    summary = build_summary(config, spec_json, episodes)
    from simseam.runner.sharding import planned_indices

    planned = planned_indices(config)  # a shard's (--shard i/K) own indices
    have = {int(e["index"]) for e in episodes}
    summary["complete"] = (not interrupted and not damaged and planned is not None
                           and all(i in have for i in planned))
    if damaged:
        summary["damaged_log_lines"] = damaged
    return summary
