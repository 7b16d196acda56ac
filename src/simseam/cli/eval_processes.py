"""``simseam eval PRESET --engine mujoco_warp --processes K [--mps]``: the run as K processes on one device, merged
(``runner.processes``)."""

from __future__ import annotations

import contextlib
import json
import shutil
import sys
from pathlib import Path

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn

from simseam.cli.common import console, err_console, fail, sigterm_as_interrupt
from simseam.seam import ConfigError, SimseamError


def eval_processes(p, args: list[str], n_tasks: int, episodes: int, out: Path, default_out: bool, processes: int,
                   mps: bool, overwrite: bool, resume: bool) -> None:
    """Run ``simseam eval`` ``args`` as ``processes`` shard processes (at most one per task) into ``out/shards``,
    each taking the next task nobody holds when it is free (``runner.claims``), then merge them into ``out``; exit
    1 when a process failed (what the others finished is merged), 130 on Ctrl-C (what every process finished is
    merged)."""
    from simseam.runner import processes as P
    from simseam.runner.run_dir import point_latest

    k = min(processes, n_tasks)
    try:
        _check_out(out, k, overwrite, resume)
        server = P.MpsServer() if mps else None
    except SimseamError as exc:
        fail(exc)
    claims = P.claims_dir(out)
    if not resume and claims.exists():  # --overwrite: the tasks are claimed afresh
        shutil.rmtree(claims)
    argvs = [[sys.executable, "-m", "simseam.cli.main", *args, "--shard", f"{i}/{k}", "--claims", str(claims),
              "--out", str(P.shard_dir(out, i)), *_keep(P.shard_dir(out, i), overwrite, resume)] for i in range(k)]
    logs = [P.shard_log(out, i) for i in range(k)]
    out.mkdir(parents=True, exist_ok=True)
    if default_out:
        point_latest(out)
    console.print(f"eval [bold]{escape(p.name)}[/] as {k} process(es) of whole tasks{' under CUDA MPS' if mps else ''}"
                  f" -> {escape(str(out))} (each: {escape(str(out / P.SHARDS))}/i, its console i.log)")
    device = args[args.index("--sim-device") + 1] if "--sim-device" in args else ""
    if device.startswith("cuda") and not mps:
        console.print("[dim]without --mps the GPU runs one process's kernels at a time (time slicing)[/]")
    total, interrupted = n_tasks * episodes, False
    try:
        with sigterm_as_interrupt(), server or contextlib.nullcontext() as env, _progress() as bar:
            task = bar.add_task("episodes", total=total)
            codes = P.run_processes(argvs, logs, P.child_env(k, env),
                                    on_poll=lambda: bar.update(task, completed=P.episodes_done(out, k)))
    except KeyboardInterrupt:
        interrupted, codes = True, [None] * k
    except SimseamError as exc:  # the MPS server did not start
        fail(exc)
    _merge(out, k, codes, logs, interrupted)


def shard_args(preset: str, policy: str, seed: int, engine: str, ci_width: float, **options) -> list[str]:
    """``simseam eval``'s arguments for each shard process: the run's own, less ``--out``, ``--processes`` and
    ``--mps`` (``options``: ``--episodes`` etc. by their parameter names; None: not given)."""
    args = ["eval", preset, "--policy", policy, "--seed", str(seed), "--engine", engine, "--ci-width", str(ci_width)]
    for name, value in options.items():
        args += [f"--{name.replace('_', '-')}", str(value)] if value is not None else []
    return args


def _check_out(out: Path, k: int, overwrite: bool, resume: bool) -> None:
    """``out`` may take the K processes' run: empty, or ``--overwrite``, or ``--resume`` of a run of K processes
    (its episodes are all in its shards, so the merge loses none)."""
    from simseam.runner import processes as P
    from simseam.runner.run_dir import CONFIG_FILE, RUN_FILES, check_writable

    check_writable(out)
    held = [f for f in RUN_FILES if (out / f).exists()]
    if held and not (overwrite or resume):
        raise ConfigError(f"--out {out} already holds a run ({', '.join(held)}); pass --overwrite to replace it, "
                          "--resume to continue it, or choose another directory")
    if resume and not overwrite and held:
        ran = [json.loads((d / CONFIG_FILE).read_text()).get("shard") for d in sorted((out / P.SHARDS).glob("*"))
               if d.name.isdigit() and (d / CONFIG_FILE).exists()]
        if not ran:
            raise ConfigError(f"--resume --processes: {out} holds a run of one process; resume it without --processes")
        before = {s[1] for s in ran if s}
        if before != {k}:
            raise ConfigError(f"--resume --processes {k}: {out} was run as {', '.join(map(str, sorted(before)))} "
                              f"process(es); resume it with that --processes (at most one per task)")


def _keep(shard: Path, overwrite: bool, resume: bool) -> list[str]:
    """A shard process's --overwrite / --resume: resumed where the shard holds a run, else started afresh."""
    from simseam.runner.run_dir import CONFIG_FILE

    if resume and (shard / CONFIG_FILE).exists():
        return ["--resume"]
    return ["--overwrite"] if overwrite else []


def _merge(out: Path, k: int, codes: list, logs: list[Path], interrupted: bool) -> None:
    """The shards that hold a run merged into ``out``, the failed processes named (exit 1), or 130 after Ctrl-C."""
    from simseam.cli.benchmarks import print_task_table
    from simseam.runner import processes as P
    from simseam.runner.run_dir import CONFIG_FILE
    from simseam.runner.sharding import merge_runs

    failed = [i for i, c in enumerate(codes) if c not in (0, None)]
    for i in failed:
        err_console.print(f"process {i}/{k} failed (exit {codes[i]}): {P.log_tail(logs[i])}  [its console: {logs[i]}]",
                          style="red", markup=False, highlight=False)
    shards = [P.shard_dir(out, i) for i in range(k) if (P.shard_dir(out, i) / CONFIG_FILE).exists()]
    if not shards:
        fail(ConfigError(f"no process started its run; no run was written to {out} (their consoles: "
                         f"{out / P.SHARDS}/i.log)"))
    try:
        summary = merge_runs(out, shards, overwrite=True)
    except SimseamError as exc:
        fail(exc)
    if summary.get("per_task"):
        print_task_table(summary, f"{summary['config'].get('preset')} ({summary['config'].get('policy')})")
    missing = summary["missing"]
    console.print(f"{len(shards)} process(es) merged: {summary['n_episodes']} episode(s)"
                  + ("; complete" if not missing else f"; [yellow]{len(missing)} planned episode(s) missing[/]")
                  + f"; summary: {escape(str(out / 'summary.json'))}")
    if not missing:
        from simseam.cli.report import report_after_run

        report_after_run(out)
    if interrupted or failed:
        raise typer.Exit(code=130 if interrupted else 1)


def _progress() -> Progress:
    return Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                    console=console, transient=True)

