"""What every ``simseam`` command shares: the consoles, the one-line error exit, seeds, policy options, SIGTERM
as Ctrl-C, and the progress of many episodes."""

from __future__ import annotations

import contextlib
import os
import signal
import threading

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from simseam.seam import ConfigError, SimseamError

console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)


def fail(exc: SimseamError) -> None:
    """Print the error literally (no Rich markup: brackets in messages stay) and exit with code 2."""
    err_console.print(f"error: {type(exc).__name__}: {exc}", style="bold red", highlight=False, markup=False)
    raise typer.Exit(code=2)


#: the largest --seed: episode seeds (seed + i) stay within the 32-bit seeds NumPy and the backends take
MAX_SEED = 2**31 - 1


CI_WIDTH_HELP = ("The half-width W of the Wilson 95 % interval the summary sizes the run for: it prints how many "
                 "episodes per task a +-W interval needs at the observed rate (default 0.05: +-5 points).")


def checked_ci_width(width: float) -> float:
    """``--ci-width``, or a ``ConfigError`` naming it (outside 0..0.5)."""
    from simseam.runner.summary import needed_episodes

    needed_episodes(0.5, width)
    return width


def ci_width_line(summary: dict) -> str:
    """How many episodes a +-W interval needs at each task's observed rate, against what the run has."""
    w = summary["ci_width"]
    rows = summary.get("per_task") or {"this run": summary}
    parts = [f"{task} {t['episodes_for_ci_width']} (has {t['n_episodes']})" for task, t in rows.items()]
    return f"episodes per task for a +-{w:.0%} Wilson 95% interval at the observed rate: " + ", ".join(parts)


def print_notes(notes: list[str], what: str) -> None:
    """Name each provenance difference that does not change the episode (``--resume``, ``merge``, ``compare``)."""
    for note in notes:
        err_console.print(f"note: {what}: {note}", style="yellow", markup=False, highlight=False)


def check_seed(seed: int, episodes: int = 1) -> None:
    """Exit with a one-line error unless every episode seed, ``seed`` .. ``seed + episodes - 1``, is one the
    backends take (0 .. ``MAX_SEED``)."""
    if not 0 <= seed <= MAX_SEED:
        fail(ConfigError(f"--seed {seed}: seeds are integers from 0 to {MAX_SEED} (episode i uses seed + i)"))
    last = seed + episodes - 1
    if last > MAX_SEED:
        fail(ConfigError(f"--seed {seed} --episodes {episodes}: the last episode would use seed {last}, beyond "
                         f"{MAX_SEED}; use --seed {MAX_SEED - episodes + 1} or less (episode i uses seed + i)"))


def out_path(flag: str = "--out"):
    """The parser of an output option (``--out``, ``--record-dataset``): a path, never the empty string, which
    would otherwise be the current directory (a run, a dataset or a page written among whatever is there)."""
    from pathlib import Path

    def parse(value) -> Path:
        if isinstance(value, Path):
            return value
        if not str(value).strip():
            fail(ConfigError(f"{flag} {str(value)!r}: an empty path; name the directory or file to write "
                             f"({flag} . for the current directory)"))
        return Path(value)

    return parse


POLICY_GROUPS_HELP = ("Step the --num-envs workers in lockstep from this process, the policy acting for one of K "
                      "groups of workers while the others step (pipelined lockstep; 1..--num-envs, default 1: "
                      "plain lockstep for lerobot:/remote: policies, others run inside each worker). Results do "
                      "not depend on it. docs/evaluation.md")


POLICY_READY_HELP = ("The ready rule: every --num-envs environment's step in flight at once, the policy acting "
                     "in this process for those whose steps are in as soon as M are (1..--num-envs; no turn "
                     "waits for the slowest worker; not with --policy-groups). docs/evaluation.md")

ENVS_PER_WORKER_HELP = ("Environments in each worker process (1..--num-envs, default 1; --num-envs then defaults to "
                        "K x the cores): a worker steps one while the action for another is on its way, the "
                        "policy acting in this process. With no rule and no --num-envs named, a policy that acts "
                        "here on an in-process scene gets 2 with --policy-ready at a quarter of the workers on 8+ cores. "
                        "docs/evaluation.md")


def check_lockstep(groups: int, ready: int | None, envs_per_worker: int, num_envs: int | None, ray: bool) -> None:
    """``--policy-groups``, ``--policy-ready`` and ``--envs-per-worker``: each 1 .. ``--num-envs`` (when
    given), groups and the ready rule not together, none with ``--ray`` (a ``ConfigError``)."""
    most = num_envs or "N"
    for flag, value in (("--policy-groups", groups), ("--policy-ready", ready), ("--envs-per-worker", envs_per_worker)):
        if value is not None and (value < 1 or (num_envs is not None and value > num_envs)):
            raise ConfigError(f"{flag} {value}: expected 1..{most} (at most --num-envs)")
    if ready is not None and groups != 1:
        raise ConfigError(f"--policy-ready {ready} and --policy-groups {groups}: choose one")
    if ray and (groups > 1 or ready is not None or envs_per_worker > 1):
        raise ConfigError("--policy-groups, --policy-ready and --envs-per-worker step the workers from this "
                          "process; with --ray each Ray worker runs its own policy")


def policy_kwargs(device: str | None, n_action_steps: int | None) -> dict:
    kwargs = {}
    if device:
        kwargs["device"] = device
    if n_action_steps:
        kwargs["n_action_steps"] = n_action_steps
    return kwargs


def redacted(policy: str) -> str:
    """The policy spec as recorded in run.json: a ``token=`` in a remote: URL is never written to disk."""
    import re

    return re.sub(r"(token=)[^&#]*", r"\1<redacted>", policy)


class Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: the episode in flight is dropped, the finished ones are kept."""


@contextlib.contextmanager
def sigterm_as_interrupt():
    def on_term(signum, frame):
        raise Terminated()

    old = signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def close_policy(pol) -> None:
    close = getattr(pol, "close", None)
    if callable(close):
        close()


class EvalProgress:
    """One progress bar over all workers: episodes done, success so far, episodes per hour; one line per
    finished episode, and per-worker failures with the episode they hit."""

    def __init__(self, console: Console, total: int):
        import time

        self._time = time
        self.total = total
        self.n = self.k = 0
        self.t0 = time.monotonic()
        self._progress = Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(),
                                  TimeElapsedColumn(), console=console, transient=True)

    def __enter__(self) -> "EvalProgress":
        self._progress.__enter__()
        self._task = self._progress.add_task(self._text(), total=self.total)
        return self

    def __exit__(self, *exc) -> None:
        self._progress.__exit__(*exc)

    def _text(self) -> str:
        hours = (self._time.monotonic() - self.t0) / 3600.0
        rate = f"{self.n / hours:,.0f} episodes/h" if self.n and hours > 0 else "- episodes/h"
        return f"episodes  success {self.k}/{self.n}  {rate}"

    def done(self, e: dict) -> None:
        """One finished episode (its ``EpisodeResult.to_json()`` entry)."""
        self.n += 1
        self.k += bool(e["success"])
        self._progress.update(self._task, completed=self.n, description=self._text())
        step_ms = e["step_latency_ms"]["mean"]
        mark = "[green]success[/]" if e["success"] else "[red]failure[/]"
        task = f"  {escape(e['task'])}" if e.get("task") else ""  # simseam eval: the preset's task
        console.print(f"episode {e['index']:3d}{task}  seed {e['seed']:5d}  {mark}  steps {e['steps']:4d}  "
                      f"reward {e['reward']:6.2f}  step " + (f"{step_ms:.2f} ms" if step_ms is not None else "-")
                      + (f"  video {escape(e['video'])}" if e.get("video") else "")
                      + (f"  [red]{escape(e['error'])}[/]" if e.get("error") else ""))

    def episode_error(self, res, what_next: str) -> None:
        err_console.print(f"episode {res.index}: {res.error}; {what_next}", style="red", markup=False,
                          highlight=False)

    def worker_failure(self, failure) -> None:
        where = f"in episode {failure.index}" if failure.index is not None else "between episodes"
        who = f"worker {failure.env}" if failure.env >= 0 else "a Ray worker"
        code = f" (exit code {failure.exitcode})" if failure.exitcode is not None else ""
        err_console.print(f"{who} died {where}{code}; {failure.what_next}; a fresh worker takes its place",
                          style="red", markup=False, highlight=False)


def never_started(out, interrupted: bool) -> None:
    """A run that ended before it started (nothing was written to ``out``): say so, exit 130 or 1."""
    err_console.print(f"interrupted before the run started; nothing was written to {out}" if interrupted else
                      f"no episode ran; nothing was written to {out}", markup=False, highlight=False)
    raise typer.Exit(code=130 if interrupted else 1)


@contextlib.contextmanager
def interrupts_deferred():
    """Ctrl-C and SIGTERM are noted on stderr and otherwise wait: for a run that is closing its environments
    and writing its summary (a second Ctrl-C there used to end the process without one)."""
    if threading.current_thread() is not threading.main_thread():  # signal handlers belong to the main thread
        yield
        return

    def note(signum, frame):
        os.write(2, b"simseam: finishing the summary first\n")

    old = {s: signal.signal(s, note) for s in (signal.SIGINT, signal.SIGTERM)}
    try:
        yield
    finally:
        for s, handler in old.items():
            signal.signal(s, handler)


@contextlib.contextmanager
def episodes_guard(run_dir, cleanup=None, spec=lambda: None, finish=None):
    """Around a run's episodes (run and eval, every executor): SIGTERM counts as Ctrl-C; Ctrl-C ends the
    run as interrupted (``guard.interrupted``); a ``SimseamError`` rebuilds the summary from the episode
    log (every finished episode kept; ``spec()`` gives the rollout's spec when known) and fails with its
    one-line message (exit 2). The run directory is closed and ``cleanup`` called whichever way it ends;
    then ``finish(interrupted)`` writes the summary. From the end of the episodes to the end of ``finish``,
    further Ctrl-C and SIGTERM wait (``interrupts_deferred``)."""
    from types import SimpleNamespace

    guard = SimpleNamespace(interrupted=False)
    error, ended = None, False
    try:
        with sigterm_as_interrupt():
            yield guard
        ended = True
    except KeyboardInterrupt:
        guard.interrupted = ended = True
    except SimseamError as exc:
        error = exc
    finally:
        with interrupts_deferred():
            run_dir.close()
            if cleanup is not None:
                cleanup()
            if error is not None:
                run_dir.summarize(spec(), interrupted=True)
            elif ended and finish is not None:
                finish(guard.interrupted)
    if error is not None:
        fail(error)
