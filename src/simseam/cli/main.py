"""``simseam`` command line: run | eval | summarize | report | compare | collect | train | serve-policy | deploy | robots |
backends | benchmarks | sidecar | isaac | doctor."""

from __future__ import annotations

import atexit
import gc
import json
import sys
from pathlib import Path

import typer
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from simseam.cli.benchmarks import backends_app, benchmarks_app, eval_command
from simseam.cli.compare import compare
from simseam.cli.common import (CI_WIDTH_HELP, ENVS_PER_WORKER_HELP, POLICY_GROUPS_HELP, POLICY_READY_HELP,
                                EvalProgress, check_lockstep, check_seed, checked_ci_width, ci_width_line,
                                console, episodes_guard, err_console, fail, never_started, out_path, policy_kwargs,
                                print_notes,
                                redacted, sigterm_as_interrupt)
from simseam.cli.deploy import deploy
from simseam.cli.isaac import doctor, isaac_app
from simseam.cli.report import report, report_after_run
from simseam.cli.serve_policy import serve_policy
from simseam.seam import ConfigError, SimseamError

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Run robot policies in simulation.")
# What a command leaves on the heap (MuJoCo Warp's kernels and arrays, a benchmark's models: some 600,000 objects
# after a LIBERO run) goes with the process; Python's collections while it tore its modules down took 1.4 s of such
# a command's end (the last of `eval --processes K`'s processes delays the whole run by it), 0.05 s once the heap is
# frozen at exit (benchmarks/bench_exit.py). The commands close their files and children themselves; atexit
# handlers registered later (a run's own) run before this one.
atexit.register(gc.freeze)
robots_app = typer.Typer(no_args_is_help=True, help="Inspect and check robot manifests.")
app.add_typer(robots_app, name="robots")
sidecar_app = typer.Typer(no_args_is_help=True, help="Out-of-process engines.")
app.add_typer(sidecar_app, name="sidecar")
app.add_typer(isaac_app, name="isaac")
app.command("doctor")(doctor)
app.command("deploy")(deploy)
app.command("serve-policy")(serve_policy)
app.add_typer(backends_app, name="backends")
app.add_typer(benchmarks_app, name="benchmarks")
app.command("eval")(eval_command)
app.command("report")(report)
app.command("compare")(compare)


def _print_version(value: bool) -> None:
    if value:
        from simseam import origin

        console.print(origin.one_line(), soft_wrap=True, highlight=False)
        raise typer.Exit()


@app.callback()
def _root(version: bool = typer.Option(False, "--version", callback=_print_version, is_eager=True,
                                       help="Print simseam's version, the source it runs and its git revision.")) -> None:
    """Run robot policies in simulation."""
def _bar_report(report, stack):
    """A one-process run's progress (``report``, a ``JobReport``): one line per finished episode and, once the
    rollout is built (the ``opened(spec, n, where)`` returned), one bar reset for each episode (``stack``
    closes it)."""
    progress = bar = None
    steps = [1]

    def opened(spec, n, where):  # the bar starts once the scene is built (its status spinner has ended)
        nonlocal progress, bar
        steps[0] = spec.task.max_steps
        if progress is None:
            progress = stack.enter_context(Progress(TextColumn("{task.description}"), BarColumn(),
                                                    MofNCompleteColumn(), TimeElapsedColumn(), console=console,
                                                    transient=True))
            # one bar, reset for each episode: a task per episode would grow Rich's per-task caches (its
            # columns keep a rendering per task id, never dropped: 1.7 kB of resident memory an episode)
            bar = progress.add_task("", total=steps[0], visible=False)

    def start(i):
        progress.reset(bar, total=steps[0], description=f"episode {i}", visible=True)
        return lambda n: progress.update(bar, completed=n)

    def done(e, written):
        progress.update(bar, visible=False)
        step_ms = e["step_latency_ms"]["mean"]  # None when the episode took no step
        mark = "[green]success[/]" if e["success"] else "[red]failure[/]"
        console.print(
            f"episode {e['index']:3d}  seed {e['seed']:5d}  {mark}  steps {e['steps']:4d}  "
            f"reward {e['reward']:6.2f}  step " + (f"{step_ms:.2f} ms" if step_ms is not None else "-")
            + (f"  video {escape(e['video'])}" if e.get("video") else "")
            + ("" if written is None else ("  [dim]recorded[/]" if written else "  [dim]not recorded[/]")))

    def error(res, what_next):
        err_console.print(f"episode {res.index}: {res.error}; {what_next}", style="red", markup=False,
                          highlight=False)

    def save(i):  # the bar stays, its clock running, while the episode's videos are encoded
        progress.update(bar, description=f"episode {i}: writing it to the dataset (encoding)")

    report.on_episode, report.on_done, report.on_error, report.on_save = start, done, error, save
    return opened


def _building(what: str):
    """The spinner while a scene is built (a sidecar's boot stages shown in it)."""
    class Status:
        def __enter__(self):
            self.status = console.status(f"building {what}").__enter__()
            return self

        def __exit__(self, *exc):
            self.status.__exit__(*exc)

        def update(self, stage: str) -> None:
            self.status.update(f"sidecar: {stage}")

    return Status()


@app.command()
def run(
    scene: Path = typer.Option(..., "--scene", help="Scene YAML (robot, engine, task, image size, max steps)."),
    policy: str = typer.Option("scripted", "--policy", help="Policy spec: scripted, random, zero, "
                               "lerobot:<dir or hub id>, remote:ws://host:port."),
    episodes: int = typer.Option(10, "--episodes", min=1, help="Number of episodes."),
    seed: int = typer.Option(0, "--seed", help="Episode i uses seed + i (a non-negative integer)."),
    out: Path = typer.Option(None, "--out", parser=out_path(), metavar="PATH",
                             help="Output directory (run.json, episodes.jsonl, summary.json, "
                             "videos). Default: a new runs/<timestamp>, with runs/latest pointing at it."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the run already in --out (and the dataset in --record-dataset)."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run in --out (same config): skip the "
                                "episodes it already recorded."),
    video: bool = typer.Option(False, "--video/--no-video", help="Write one MP4 per episode (first RGB camera)."),
    record_dataset: Path = typer.Option(None, "--record-dataset", parser=out_path("--record-dataset"),
                                        metavar="PATH", help="Also record the episodes as a new "
                                        "LeRobot dataset in this directory."),
    keep_failures: bool = typer.Option(True, "--keep-failures/--successes-only",
                                       help="With --record-dataset: record failed episodes too."),
    videos: bool = typer.Option(True, "--dataset-videos/--dataset-images",
                                help="With --record-dataset: store camera frames as AV1 video or PNG images."),
    device: str = typer.Option(None, "--device", help="lerobot: policies: torch device (default: CUDA if present)."),
    n_action_steps: int = typer.Option(None, "--n-action-steps", min=1,
                                       help="Chunked policies: actions executed per predicted chunk."),
    num_envs: int = typer.Option(None, "--num-envs", min=1, help="Environments run at once, each in its own "
                                 "worker process; lerobot:/remote: policies act for all of them in one batch, others "
                                 "run inside each worker (default: sized to the cores and the episodes; 1 with "
                                 "--record-dataset). Results do not depend on it."),
    policy_groups: int = typer.Option(1, "--policy-groups", help=POLICY_GROUPS_HELP),
    policy_ready: int = typer.Option(None, "--policy-ready", help=POLICY_READY_HELP),
    envs_per_worker: int = typer.Option(1, "--envs-per-worker", help=ENVS_PER_WORKER_HELP),
    shard: str = typer.Option(None, "--shard", help="i/K: run only the episodes e with e % K == i (batch "
                              "schedulers, e.g. Slurm arrays); combine the K run directories with simseam merge."),
    ray_address: str = typer.Option(None, "--ray", help="Run the episodes on a Ray cluster: auto (the one on this "
                                    "machine), ray://HOST:PORT or HOST:PORT, or local (start a private one); "
                                    "--num-envs then counts Ray workers (default: the cluster's CPUs)."),
    renderer: str = typer.Option("workers", "--renderer", help="Who draws the cameras of --num-envs workers: "
                                 "workers (each its own EGL context), batched (this process, one MuJoCo Warp batch "
                                 "for all workers; in-process MuJoCo scenes, RGB cameras), auto (batched when a "
                                 "CUDA device is present and the scene is supported). docs/evaluation.md"),
    ci_width: float = typer.Option(0.05, "--ci-width", help=CI_WIDTH_HELP),
) -> None:
    """Run a policy for N episodes; every finished episode is on disk as soon as it ends."""
    from simseam.runner.job import Dataset, Job
    from simseam.runner.provenance import for_scene
    from simseam.runner.recipe import SceneRecipe
    from simseam.runner.run_dir import RunDir, default_run_dir
    from simseam.runner.scene_config import load_scene_config
    from simseam.runner.sharding import check_shard_holds_episodes, parse_shard, shard_indices

    check_seed(seed, episodes)
    if out is None and resume:
        fail(ConfigError("--resume needs --out (the run directory to continue)"))
    default_out, out = out is None, default_run_dir() if out is None else out
    try:
        shard_ik = parse_shard(shard) if shard is not None else None
        planned = check_shard_holds_episodes(shard_indices(episodes, shard_ik), shard_ik, episodes)
        check_lockstep(policy_groups, policy_ready, envs_per_worker, num_envs, ray_address is not None)
        _check_run_outputs(record_dataset, overwrite, video, num_envs, ray_address)
        cfg, base_dir = load_scene_config(scene)  # the one parse of the scene file
        _check_renderer(renderer, scene, cfg, record_dataset is not None or ray_address is not None)
        config = {"scene_file": str(scene), "scene": cfg.model_dump(mode="json"), "policy": redacted(policy),
                  "episodes": episodes, "seed": seed, "video": video,
                  "record_dataset": str(record_dataset) if record_dataset else None,
                  "ci_width": checked_ci_width(ci_width), **_run_options(shard_ik, renderer)}
        config["provenance"] = for_scene(cfg, base_dir, scene, policy)
        run_dir = RunDir(out, config, overwrite=overwrite, resume=resume, latest=default_out)  # written at start
    except SimseamError as exc:
        fail(exc)
    todo = run_dir.left(planned)
    try:
        executor = _run_executor(scene, cfg, len(todo), num_envs, ray_address, renderer, record_dataset,
                                 (policy_groups, policy_ready, envs_per_worker))
    except ConfigError as exc:
        run_dir.close()
        fail(exc)
    dataset = None if record_dataset is None else Dataset(record_dataset, videos, overwrite, keep_failures)
    recipe = SceneRecipe(cfg.model_dump(mode="json"), str(base_dir), render_images=video or bool(dataset), seed=seed)
    job = Job(recipe, policy, policy_kwargs(device, n_action_steps), todo, seed, run_dir, video, dataset)
    _run_job(job, executor, planned=len(planned))


def _run_options(shard: tuple[int, int] | None, renderer: str) -> dict:
    """What run.json records of the options that only some runs give (so older runs still resume)."""
    return {**({"shard": list(shard)} if shard is not None else {}),
            **({"renderer": renderer} if renderer != "workers" else {})}


def _check_run_outputs(record_dataset: Path | None, overwrite: bool, video: bool, num_envs: int | None,
                       ray_address: str | None) -> None:
    """``simseam run``'s output options against each other (a ``ConfigError`` naming the clash)."""
    if record_dataset is not None and (num_envs or 1) > 1:
        raise ConfigError("--record-dataset records one episode at a time: it needs --num-envs 1")
    if record_dataset is not None:
        from simseam.runner.dataset_recorder import check_dataset_out

        check_dataset_out(record_dataset, overwrite, "--record-dataset")
    if ray_address is not None and (record_dataset is not None or video):
        raise ConfigError("--ray cannot be combined with --video or --record-dataset (each node would write "
                          "to its own disk)")


def _check_renderer(renderer: str, scene: Path, cfg, elsewhere: bool) -> None:
    """``--renderer`` for this scene (``elsewhere``: --record-dataset or --ray, which render in their own
    processes)."""
    from simseam.runner.central_render import RENDERERS, unsupported

    if renderer not in RENDERERS:
        raise ConfigError(f"--renderer must be one of {', '.join(RENDERERS)}, got {renderer!r}")
    if renderer == "batched" and elsewhere:
        raise ConfigError("--renderer batched serves the --num-envs workers; --record-dataset and --ray render "
                          "in their own processes (use --renderer workers)")
    if renderer == "batched" and unsupported(cfg.model_dump(mode="json")):
        raise ConfigError(f"{scene}: --renderer batched: {unsupported(cfg.model_dump(mode='json'))}")



def _run_executor(scene: Path, cfg, todo: int, num_envs: int | None, ray_address: str | None, renderer: str,
                  record_dataset: Path | None, lockstep: tuple):
    """Where ``simseam run`` runs: Ray; ``num_envs`` environments (default: the scene's batch for a
    benchmark's port to a batched engine, else sized to the cores and the episodes, 1 with a dataset); or
    this process."""
    from simseam.runner.job import Executor
    from simseam.runner.scheduler import Lockstep
    from simseam.runner.warp_vector import benchmark_on_batched_engine

    lockstep = Lockstep(*lockstep)  # --policy-groups, --policy-ready, --envs-per-worker

    if ray_address is not None:
        return Executor("ray", num_envs, address=ray_address)
    ported = benchmark_on_batched_engine(cfg)  # a benchmark's port to a batched engine: N worlds here
    if num_envs is None and ported:
        num_envs = cfg.engine.num_envs or 1
    if num_envs is None:
        from simseam.runner.vector import default_num_envs

        num_envs = 1 if record_dataset is not None else default_num_envs(todo, envs_per_worker=lockstep.envs_per_worker)
        lockstep = lockstep.or_default()  # neither a rule nor --num-envs named
    if not (num_envs > 1 or renderer == "batched" or ported):
        return Executor("inline")
    if cfg.engine.keep_alive:  # N workers cannot all adopt the one sidecar left running
        raise ConfigError(f"{scene}: engine.keep_alive keeps one sidecar for the next run to adopt, and "
                          f"{max(1, min(num_envs, todo))} environment workers would each need their own; pass "
                          "--num-envs 1 or drop keep_alive")
    return Executor("vector", num_envs, lockstep, renderer)


def _run_job(job, executor, *, planned: int) -> None:
    """``simseam run``'s job on its executor: progress, one line per episode, Ctrl-C, errors, the summary."""
    import contextlib

    from simseam.runner.job import JobReport, execute

    out, policy, todo = job.run_dir.path, job.policy, len(job.indices)
    if job.run_dir.resume:
        console.print(f"resuming {out}: {len(job.run_dir.done)} episode(s) already recorded, {todo} to run")
        print_notes(job.run_dir.notes, "differs from the run there (the episodes are the same)")
    report = JobReport(status=_building)
    finish = lambda interrupted: _finish_run(job.run_dir, report.spec_json, interrupted, planned)  # noqa: E731
    with episodes_guard(job.run_dir, spec=lambda: report.spec_json, finish=finish), contextlib.ExitStack() as stack:
        if executor.kind == "inline":
            bar = _bar_report(report, stack)
        else:
            progress = stack.enter_context(EvalProgress(console, total=todo))
            report.on_done = lambda entry, written: progress.done(entry)
            report.on_error, report.on_worker_failure = progress.episode_error, progress.worker_failure

        def opened(spec, n, where):
            if executor.kind == "inline":
                bar(spec, n, where)
            if job.video and spec is not None and not spec.robot.sensors_of("rgb"):
                err_console.print(f"note: --video: robot {spec.robot.name!r} has no RGB camera, so no video "
                                  "is written", style="yellow", markup=False, highlight=False)
            what = f"{escape(spec.describe())}, " if spec is not None else ""
            on = "" if executor.kind == "inline" else (f" on {escape(where)}" if spec is None else
                                                       f" on {n} environments ({escape(where)})")
            console.print(f"{what}policy [bold]{escape(policy)}[/], {todo} episode(s){on} -> {escape(str(out))}")

        report.on_envs = opened
        execute(job, executor, report)
    dataset = report.dataset
    if dataset is not None and dataset.discarded:
        console.print(f"dataset: no episode recorded, so no dataset was left in {escape(str(job.dataset.path))}")
    elif dataset is not None:
        console.print(f"dataset: {dataset.episodes_written} episode(s), {dataset.frames_written} frames "
                      f"in {escape(str(job.dataset.path))}")


def _finish_run(run_dir, spec_json, interrupted: bool, planned: int) -> None:
    out = run_dir.path
    summary = run_dir.summarize(spec_json, interrupted=interrupted)
    if summary is None:
        never_started(out, interrupted)
    if interrupted:
        err_console.print(f"interrupted after {summary['n_episodes']} of {planned} episodes; "
                          f"summary of the finished ones: {out / 'summary.json'}", markup=False, highlight=False)
        raise typer.Exit(code=130)
    lo, hi = summary["success_rate_wilson95"]
    console.print(
        f"success {summary['n_success']}/{summary['n_episodes']} = {summary['success_rate']:.0%} "
        f"(Wilson 95% \\[{lo:.2f}, {hi:.2f}])  summary: {escape(str(out / 'summary.json'))}"
    )
    console.print(ci_width_line(summary), markup=False, highlight=False)
    if summary["complete"]:
        report_after_run(out)


@app.command()
def summarize(run: Path = typer.Argument(..., help="A run directory (holds episodes.jsonl).")) -> None:
    """Rebuild DIR/summary.json from its episode log (after a kill, or to re-read a run)."""
    from simseam.runner.run_dir import rebuild_summary

    try:
        summary = rebuild_summary(run)
    except SimseamError as exc:
        fail(exc)
    if summary.get("damaged_log_lines"):
        lines = summary["damaged_log_lines"]
        err_console.print(f"warning: {run / 'episodes.jsonl'}: line(s) {', '.join(map(str, lines[:10]))} hold no "
                          "episode record (skipped); the run counts as incomplete", markup=False, highlight=False)
    lo, hi = summary["success_rate_wilson95"]
    console.print(f"{summary['n_episodes']} episode(s), success {summary['n_success']}/{summary['n_episodes']} "
                  f"(Wilson 95% \\[{lo:.2f}, {hi:.2f}]); {'complete' if summary['complete'] else 'incomplete'}; "
                  f"summary: {escape(str(run / 'summary.json'))}")


@app.command()
def merge(
    out: Path = typer.Option(..., "--out", parser=out_path(), metavar="PATH",
                             help="New run directory for the merged run."),
    runs: list[Path] = typer.Argument(..., help="Run directories to merge (e.g. the K shards of --shard i/K)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a run already in --out."),
    prefer_first: bool = typer.Option(False, "--prefer-first", help="An episode recorded with different results "
                                      "in two directories keeps the first (default: refuse)."),
) -> None:
    """Merge run directories (shards of one evaluation) into one: configs must agree, each episode counts once."""
    from simseam.runner.sharding import merge_runs

    try:
        summary = merge_runs(out, runs, overwrite=overwrite, prefer_first=prefer_first)
    except SimseamError as exc:
        fail(exc)
    print_notes(summary.get("provenance_notes") or [], "the merged runs differ (the episodes are the same)")
    if summary.get("per_task"):  # shards of simseam eval: the eval summary's per-task table
        from simseam.cli.benchmarks import print_task_table

        print_task_table(summary, f"{summary['config'].get('preset')} ({summary['config'].get('policy')}), merged")
    lo, hi = summary["success_rate_wilson95"]
    missing = summary["missing"]
    console.print(f"merged {len(runs)} run(s): {summary['n_episodes']} episode(s), success {summary['n_success']}/"
                  f"{summary['n_episodes']} (Wilson 95% \\[{lo:.2f}, {hi:.2f}]); "
                  + ("complete" if not missing else f"[yellow]{len(missing)} planned episode(s) missing: "
                     f"{missing[:20]}{' ...' if len(missing) > 20 else ''}[/]")
                  + f"; summary: {escape(str(out / 'summary.json'))}")
    for task, es in (summary.get("missing_by_task") or {}).items():  # eval shards: which task's episodes
        console.print(f"  [yellow]{escape(task)}: episode(s) {escape(str(es[:20]))}{' ...' if len(es) > 20 else ''} "
                      "missing[/]")


@app.command()
def collect(
    scene: Path = typer.Option(..., "--scene", help="Scene YAML."),
    policy: str = typer.Option("scripted", "--policy", help="Policy spec (default: the scripted expert)."),
    episodes: int = typer.Option(50, "--episodes", min=1, help="Episodes to run."),
    out: Path = typer.Option(..., "--out", parser=out_path(), metavar="PATH",
                             help="New LeRobot dataset directory."),
    seed: int = typer.Option(0, "--seed", help="Episode i uses seed + i (a non-negative integer)."),
    keep_failures: bool = typer.Option(False, "--keep-failures/--successes-only",
                                       help="Also record episodes that did not succeed."),
    videos: bool = typer.Option(True, "--videos/--images", help="Camera frames as AV1 video or PNG images."),
    cameras: bool = typer.Option(True, "--cameras/--no-cameras",
                                 help="Record the cameras, or state alone (a state-based policy's data: fast, "
                                      "nothing rendered)."),
    action_noise: float = typer.Option(0.0, "--action-noise", min=0.0,
                                       help="Execute each action with Gaussian noise of this standard deviation "
                                            "(action units; gripper untouched) while recording the policy's own "
                                            "action: demonstrations that show recoveries (0: off)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the LeRobot dataset already in --out (never other files)."),
) -> None:
    """Collect demonstrations as a LeRobot dataset (images, state, action, task, fps = control rate).
    Ctrl-C or SIGTERM keeps every episode recorded so far (the dataset is finalized) and exits 130."""
    import contextlib
    from collections import Counter

    from simseam.runner.dataset_recorder import check_dataset_out
    from simseam.runner.job import Dataset, Executor, Job, JobReport, execute
    from simseam.runner.recipe import SceneRecipe
    from simseam.runner.scene_config import load_scene_config

    check_seed(seed, episodes)
    try:
        check_dataset_out(out, overwrite)
        cfg, base_dir = load_scene_config(scene)
    except SimseamError as exc:
        fail(exc)
    job = Job(SceneRecipe(cfg.model_dump(mode="json"), str(base_dir), render_images=cameras, seed=seed), policy, {},
              list(range(episodes)), seed, dataset=Dataset(out, videos, overwrite, keep_failures),
              action_noise=action_noise)
    counts = Counter()  # episodes run and succeeded (counts only: a long collection keeps its memory flat)
    report = JobReport(status=_building)
    interrupted = False
    try:
        with sigterm_as_interrupt(), contextlib.ExitStack() as stack:
            bar = _bar_report(report, stack)
            shown = report.on_done

            def opened(spec, n, where):
                bar(spec, n, where)
                console.print(f"collecting {episodes} episode(s) of [bold]{escape(policy)}[/] on "
                              f"{escape(spec.describe())} into {escape(str(out))}"
                              + (f" (action noise {action_noise:g})" if action_noise > 0 else ""))

            def done(entry, written):
                counts.update(run=1, ok=int(entry["success"]))
                shown(entry, written)

            report.on_envs, report.on_done = opened, done
            execute(job, Executor("inline"), report)
    except KeyboardInterrupt:
        interrupted = True
    except SimseamError as exc:  # the dataset keeps every episode recorded before (finalized)
        fail(exc)
    _collect_end(report.dataset, out, counts, episodes, interrupted)


def _collect_end(rec, out: Path, counts, episodes: int, interrupted: bool) -> None:
    """What ``collect`` says when it ends: the dataset, or that nothing was kept (and nothing left in ``out``,
    so the same command can run again); exit 130 when interrupted, 1 when no episode was recorded."""
    n_run, n_ok = counts["run"], counts["ok"]
    written = rec.episodes_written if rec is not None else 0
    if written:
        console.print(f"dataset {escape(str(out))}: {written} episode(s), {rec.frames_written} frames "
                      f"({n_ok}/{n_run} episodes succeeded)")
    elif rec is not None:
        console.print(f"dataset {escape(str(out))}: no episode recorded, so no dataset was left there "
                      f"({n_ok}/{n_run} episodes succeeded)")
    if interrupted:
        err_console.print(f"interrupted after {n_run} of {episodes} episodes; " + (
            f"the dataset keeps the {written} recorded" if written else "nothing was recorded"),
            markup=False, highlight=False)
        raise typer.Exit(code=130)
    if written == 0:
        err_console.print(f"no episode was recorded (all {n_run} failed; --keep-failures records them "
                          f"anyway); nothing was left in {out}, so the same command can run again",
                          style="red", markup=False, highlight=False)
        raise typer.Exit(code=1)


@app.command()
def train(
    dataset: Path = typer.Option(..., "--dataset", help="LeRobot dataset directory (from `simseam collect`)."),
    out: Path = typer.Option(..., "--out", parser=out_path(), metavar="PATH",
                             help="Checkpoint directory (then: --policy lerobot:<out>)."),
    steps: int = typer.Option(20000, "--steps", min=1, help="Optimizer steps."),
    time_budget_s: float = typer.Option(None, "--time-budget-s", help="Stop after this many seconds."),
    batch_size: int = typer.Option(8, "--batch-size", min=1),
    policy_type: str = typer.Option("act", "--policy-type", help="act (LeRobot's ACT) or diffusion (LeRobot's "
                                    "Diffusion Policy: needs observation.state and cameras of one size, or the "
                                    "object state)."),
    lr: float = typer.Option(None, "--lr", help="AdamW learning rate, backbone too (default: act 1e-5, "
                             "diffusion 1e-4)."),
    lr_schedule: str = typer.Option("constant", "--lr-schedule",
                                    help="constant, or cosine: decays the rate to 0 at --steps."),
    chunk_size: int = typer.Option(20, "--chunk-size", min=1, help="Actions predicted per chunk."),
    n_action_steps: int = typer.Option(None, "--n-action-steps", min=1, help="Actions executed per chunk "
                                       "(default: act 10, diffusion 8)."),
    warmup_steps: int = typer.Option(0, "--warmup-steps", min=0, help="Linear learning-rate warm-up steps."),
    horizon: int = typer.Option(16, "--horizon", min=1, help="diffusion: actions denoised per prediction, from the "
                                "oldest observation read (a multiple of 2**len(--down-dims))."),
    n_obs_steps: int = typer.Option(2, "--n-obs-steps", min=1, help="diffusion: observations read per prediction."),
    down_dims: str = typer.Option("256,512,1024", "--down-dims", help="diffusion: the U-Net's widths, "
                                  "comma-separated."),
    inference_steps: int = typer.Option(10, "--inference-steps", min=1, help="diffusion: DDIM sampler steps per "
                                        "prediction."),
    temporal_ensemble: float = typer.Option(None, "--temporal-ensemble", min=0.0,
                                            help="ACT's temporal ensembling coefficient for inference (e.g. 0.01; "
                                                 "needs --n-action-steps 1): each step averages the overlapping "
                                                 "chunks' actions."),
    dim_model: int = typer.Option(512, "--dim-model", min=8, help="Transformer width (ACT's default 512)."),
    ff_dim: int = typer.Option(3200, "--ff-dim", min=8, help="Transformer feed-forward width (ACT's default 3200)."),
    encoder_layers: int = typer.Option(4, "--encoder-layers", min=1, help="Transformer encoder layers."),
    vae: bool = typer.Option(True, "--vae/--no-vae", help="ACT's VAE objective (off: plain regression of the "
                             "chunk, for one-mode demonstrations such as a scripted expert's)."),
    device: str = typer.Option(None, "--device", help="torch device (default: CUDA if present, else CPU)."),
    workers: int = typer.Option(None, "--workers", min=0, help="Data-loading worker processes (default: one per "
                                "core beyond the training process's, at most 4; 1 on a 2-core machine)."),
    cache: bool = typer.Option(False, "--cache/--no-cache", help="Decode the dataset once and keep it on the "
                               "device (fast; needs the frames to fit in its memory)."),
    amp: bool = typer.Option(False, "--amp", help="bfloat16 autocast on CUDA."),
    seed: int = typer.Option(0, "--seed", help="Random seed (a non-negative integer)."),
    checkpoint_every: int = typer.Option(None, "--checkpoint-every", min=1,
                                         help="Save a resumable checkpoint every N steps (out/checkpoints/)."),
    state_std_floor: float = typer.Option(None, "--state-std-floor", min=0.0,
                                          help="The smallest spread the normaliser gives each state input "
                                               "(observation.state, observation.environment_state), in its units "
                                               "(m, rad): an input at rest in the demonstrations is otherwise "
                                               "scaled by ~1e8, and another engine's float32 jitter reads as "
                                               "hundreds of deviations (e.g. 1e-3; default: the data's own)."),
    state_noise: float = typer.Option(None, "--state-noise", min=0.0,
                                      help="Gaussian noise of this std (the input's units: m, rad) added to every "
                                           "state input of every training sample, so the policy learns that "
                                           "changes of this size mean nothing (e.g. another engine's float32 "
                                           "jitter, 1e-5); the normaliser's spread is the noisy data's."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace a training run already in --out."),
    resume: bool = typer.Option(False, "--resume", help="Continue from the newest checkpoint in --out up to "
                                "--steps in total."),
) -> None:
    """Train a LeRobot ACT or Diffusion Policy on a dataset; the result loads with --policy lerobot:<out>.
    Ctrl-C or SIGTERM saves a checkpoint of the steps done (continue with --resume) and exits 130."""
    check_seed(seed)
    cfg = _train_config(steps=steps, time_budget_s=time_budget_s, batch_size=batch_size, policy_type=policy_type, lr=lr,
                        lr_schedule=lr_schedule, chunk_size=chunk_size, n_action_steps=n_action_steps,
                        warmup_steps=warmup_steps, horizon=horizon, n_obs_steps=n_obs_steps, down_dims=down_dims,
                        inference_steps=inference_steps, temporal_ensemble=temporal_ensemble, dim_model=dim_model,
                        ff_dim=ff_dim, encoder_layers=encoder_layers, vae=vae, device=device, workers=workers,
                        cache=cache, amp=amp, seed=seed, checkpoint_every=checkpoint_every,
                        state_std_floor=state_std_floor, state_noise=state_noise)
    _train_and_report(dataset, out, cfg, overwrite, resume)


def _train_config(*, steps: int, time_budget_s: float | None, batch_size: int, policy_type: str, lr: float | None,
                  lr_schedule: str, chunk_size: int, n_action_steps: int | None, warmup_steps: int, horizon: int,
                  n_obs_steps: int, down_dims: str, inference_steps: int, temporal_ensemble: float | None,
                  dim_model: int, ff_dim: int, encoder_layers: int, vae: bool, device: str | None,
                  workers: int | None, cache: bool, amp: bool, seed: int, checkpoint_every: int | None,
                  state_std_floor: float | None = None, state_noise: float | None = None):
    """``simseam train``'s options as a ``TrainConfig`` (a bad combination exits 2 with its reason)."""
    from simseam.runner.training import TrainConfig, default_loader_workers

    if policy_type == "act" and n_action_steps is None:
        n_action_steps = 10
    if policy_type == "act" and n_action_steps > chunk_size:
        fail(ConfigError(f"--n-action-steps ({n_action_steps}) cannot exceed --chunk-size ({chunk_size})"))
    try:
        dims = tuple(int(d) for d in down_dims.split(","))
    except ValueError:
        fail(ConfigError(f"--down-dims {down_dims!r}: expected comma-separated integers, e.g. 256,512,1024"))
    return TrainConfig(steps=steps, time_budget_s=time_budget_s, batch_size=batch_size, lr=lr, lr_backbone=lr,
                       lr_schedule=lr_schedule, policy_type=policy_type, warmup_steps=warmup_steps,
                       horizon=horizon, n_obs_steps=n_obs_steps, down_dims=dims, inference_steps=inference_steps,
                       chunk_size=chunk_size, n_action_steps=n_action_steps, dim_model=dim_model,
                       temporal_ensemble_coeff=temporal_ensemble,
                       dim_feedforward=ff_dim, n_encoder_layers=encoder_layers, use_vae=vae,
                       device=device, num_workers=default_loader_workers() if workers is None else workers,
                       cache_on_device=cache, use_amp=amp, seed=seed, log_every=max(1, min(100, steps // 10)),
                       checkpoint_every=checkpoint_every, state_std_floor=state_std_floor,
                       state_noise=state_noise)


def _train_and_report(dataset: Path, out: Path, cfg, overwrite: bool, resume: bool) -> None:
    """Train, printing the loss as it goes and the checkpoint at the end; Ctrl-C or SIGTERM: the checkpoint
    saved, exit 130."""
    from simseam.runner.training import train_act

    try:
        with sigterm_as_interrupt():
            res = train_act(dataset, out, cfg, overwrite=overwrite, resume=resume,
                            on_log=lambda s, loss: console.print(f"step {s:7d}  loss {loss:.4f}"))
    except SimseamError as exc:
        fail(exc)
    except KeyboardInterrupt:
        from simseam.runner.training import latest_checkpoint

        ckpt = latest_checkpoint(out)
        err_console.print("interrupted; " + (f"checkpoint {ckpt} (continue with --resume)" if ckpt else
                                             "no step finished, nothing saved"), markup=False, highlight=False)
        raise typer.Exit(code=130)
    if res.resumed_from:
        console.print(f"resumed from step {res.resumed_from}")
    kind = "ACT" if cfg.policy_type == "act" else "Diffusion Policy"
    console.print(f"trained {kind} ({res.n_params / 1e6:.1f} M params) for {res.steps} steps in {res.seconds:.0f} s "
                  f"on {res.device}; checkpoint: {out}  (run it: --policy lerobot:{out})")


@sidecar_app.command("serve")
def sidecar_serve(boot: Path = typer.Option(..., "--boot", help="Boot file (JSON) written by the client.")) -> None:
    """Serve one scene over the sidecar wire (normally spawned by the client, not by hand)."""
    from simseam.sidecar.server import main as serve_main

    raise typer.Exit(code=serve_main(["--boot", str(boot)]))


@robots_app.command("list")
def robots_list() -> None:
    """List the built-in robots."""
    from simseam.robot.manifest import builtin_manifests, parse_manifest

    table = Table("name", "joints (arm+gripper)", "sensors", "description")
    for name, path in builtin_manifests().items():
        m = parse_manifest(path)
        arm = sum(j.role == "arm" for j in m.joints)
        grip = sum(j.role == "gripper" for j in m.joints)
        sensors = ", ".join(f"{s.name}:{s.kind}" for s in m.sensors) or "-"
        table.add_row(name, f"{arm}+{grip}", sensors, m.description)
    console.print(table)


@robots_app.command("show")
def robots_show(name: str = typer.Argument(..., help="Built-in robot name or manifest path.")) -> None:
    """Print a robot's validated spec (JSON)."""
    from simseam.robot.manifest import load_robot

    try:
        spec = load_robot(name)
    except SimseamError as exc:
        fail(exc)
    sys.stdout.write(json.dumps(spec.to_json(), indent=2) + "\n")


@robots_app.command("check")
def robots_check(path: Path = typer.Argument(..., help="Manifest file (or a built-in robot's name) to check "
                                             "against its URDF.")) -> None:
    """Validate a manifest: schema, assets, every joint/link against its URDF, home and gripper positions
    within the joint limits; then build the robot headless in MuJoCo as `run` does (meshes, inertias,
    cameras, holding still) and warn about what would surprise (no visual geometry, unreadable meshes)."""
    from simseam.runner.robot_check import check_robot

    try:
        report = check_robot(path)
    except SimseamError as exc:
        fail(exc)
    spec = report.spec
    for w in report.warnings:
        console.print(f"[yellow]warning[/] {path}: {w}", soft_wrap=True)
    arm = len(spec.arm_joints)
    grip = f"gripper {len(spec.gripper.joints)} joint(s)" if spec.gripper else "no gripper"
    tool = (f"tcp {spec.tcp.name!r} on {spec.tcp.parent}" if spec.tcp else f"tool link {spec.ee_link}")
    console.print(
        f"[green]ok[/] {path}: robot {spec.name!r}, {arm} arm joints, {grip}, {tool}, "
        f"{len(spec.sensors)} sensors; built in MuJoCo: {report.visual_geoms} visual geoms, "
        f"tabletop reach {report.tabletop_reach:.2f} m; URDF {spec.urdf}", soft_wrap=True
    )


def main() -> None:  # pragma: no cover
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
