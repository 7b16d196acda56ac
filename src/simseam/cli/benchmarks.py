"""``simseam backends list|provision``, ``simseam benchmarks list``, ``simseam eval PRESET``."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape
from rich.table import Table

from simseam.cli.common import ENVS_PER_WORKER_HELP, POLICY_GROUPS_HELP, POLICY_READY_HELP, EvalProgress, \
    check_lockstep, check_seed, checked_ci_width, ci_width_line, console, episodes_guard, err_console, \
    fail, never_started, out_path, policy_kwargs, print_notes, redacted, CI_WIDTH_HELP
from simseam.cli.eval_processes import eval_processes, shard_args
from simseam.cli.report import report_after_run
from simseam.runner.evaluate import PRESETS
from simseam.seam import ConfigError, SimseamError

backends_app = typer.Typer(no_args_is_help=True, help="Benchmark backends: their own virtualenvs.")
benchmarks_app = typer.Typer(no_args_is_help=True, help="Benchmarks behind the seam: suites and tasks.")


@backends_app.command("list")
def backends_list() -> None:
    """Show every backend, whether its venv is provisioned here, its size and where it lives."""
    from simseam.backends import BACKENDS, NOT_AVAILABLE
    from simseam.backends.provision import marker, provision_command, venv_dir

    table = Table("backend", "status", "size", "provisioning", "benchmark")
    for name, info in BACKENDS.items():
        m = marker(name)
        if m is None:
            table.add_row(name, "[yellow]missing[/]", "-", escape(provision_command(name)), escape(info.description))
        else:
            table.add_row(name, "[green]installed[/]", f"{m['bytes'] / 2**20:.0f} MiB",
                          escape(f"{venv_dir(name)} ({m['seconds']:.0f} s)"), escape(info.description))
    for name, why in NOT_AVAILABLE.items():
        table.add_row(name, "[dim]not available[/]", "-", "-", escape(why))
    console.print(table)


@backends_app.command("provision")
def backends_provision(
    names: list[str] = typer.Argument(..., help="Backend names (simseam backends list)."),
    force: bool = typer.Option(False, "--force", help="Rebuild the venv even if it is provisioned."),
    physx_gpu: Path = typer.Option(None, "--physx-gpu", metavar="FILE", help="maniskill: place NVIDIA's PhysX "
                                   "GPU library (libPhysXGpu_64.so, a copy you have) where SAPIEN looks for it, for "
                                   "sim_backend physx_cuda (SAPIEN would download it on first use)."),
) -> None:
    """Create each backend's virtualenv from its pins (PyPI once; afterwards everything runs offline)."""
    from simseam.backends import physx_gpu as gpu
    from simseam.backends.provision import provision, python_of

    try:
        if physx_gpu is not None and names != ["maniskill"]:
            raise ConfigError(f"--physx-gpu belongs to the maniskill backend alone, got {' '.join(names)}")
        if physx_gpu is not None:
            gpu.check_library(physx_gpu.expanduser())  # a wrong file fails before minutes of provisioning
        for name in names:
            rec = provision(name, force=force, progress=lambda s: console.print(escape(s), highlight=False))
            console.print(f"[green]ok[/] {escape(name)}: {rec['bytes'] / 2**20:.0f} MiB, {rec['seconds']:.0f} s")
        if physx_gpu is not None:
            version = gpu.physx_version(python_of("maniskill"))
            dest = gpu.install(physx_gpu, version)
            console.print(f"[green]ok[/] PhysX GPU library for SAPIEN's PhysX {escape(version)}: {escape(str(dest))}")
    except SimseamError as exc:
        fail(exc)


@benchmarks_app.command("list")
def benchmarks_list(name: str = typer.Argument(None, help="One backend (default: every provisioned one).")) -> None:
    """Suites and tasks with their instructions (asked of each provisioned backend's own venv)."""
    from simseam.backends import BACKENDS, backend_info
    from simseam.backends.provision import catalog, marker, provision_command

    try:
        names = [backend_info(name).name] if name else list(BACKENDS)
        for n in names:
            if marker(n) is None:
                console.print(f"[bold]{n}[/]: not provisioned (run `{provision_command(n)}`)")
                continue
            cat = catalog(n)
            table = Table("task", "instruction", "suites", title=f"{n}: {BACKENDS[n].description}")
            for task, text in cat["tasks"].items():
                suites = ", ".join(s for s, ts in cat["suites"].items() if task in ts)
                table.add_row(escape(task), escape(text), escape(suites))
            console.print(table)
            presets = [p for p in PRESETS.values() if p.backend == n]
            for p in presets:
                console.print(f"  eval preset [bold]{p.name}[/]: {escape(p.protocol)}", highlight=False)
    except SimseamError as exc:
        fail(exc)


PROCESSES_OPTION = typer.Option(1, "--processes", min=1, help="--engine: K processes at once on the device, each "
                                "stepping whole tasks (--shard i/K into OUT/shards/i), merged into --out when they "
                                "end; on CUDA add --mps.")
IMAGE_SIZE_OPTION = typer.Option(None, "--image-size", min=8, max=4096, metavar="N", help="The cameras drawn at N x N "
                                 "instead of the preset's size (a policy trained on other images; a non-standard "
                                 "run, as run.json records).")
MPS_OPTION = typer.Option(False, "--mps", help="--processes on CUDA: the processes as clients of a CUDA MPS server of "
                          "this run's own, so that their kernels run side by side (without it the GPU runs one "
                          "process's kernels at a time).")

RENDER_OPTION = typer.Option(None, "--render", metavar="WHO", help="--engine mujoco_warp on a LIBERO preset, a policy "
                             "that reads images: who draws the port's cameras: warp (MuJoCo Warp's ray tracer on the "
                             "device, the default) or opengl (MuJoCo's OpenGL renderer on the host, as LIBERO draws "
                             "them: slower, its images the CPU benchmark's).")

CLAIMS_OPTION = typer.Option(None, "--claims", hidden=True, help="--processes' own: with --shard i/K and --engine, "
                             "the folder where the K processes claim whole tasks one at a time (runner.claims) "
                             "instead of task_index % K == i.")


def eval_command(
    preset_name: str = typer.Argument(..., metavar="PRESET", help=", ".join(PRESETS) + "."),
    policy: str = typer.Option(..., "--policy", help="Policy spec: scripted (Meta-World's experts), random, zero, "
                               "lerobot:<dir or hub id>, remote:ws://host:port."),
    out: Path = typer.Option(None, "--out", parser=out_path(), metavar="PATH",
                             help="Run directory (default: a new runs/<timestamp>)."),
    episodes: int = typer.Option(None, "--episodes", min=1, help="Episodes per task (default: the protocol's; "
                                 "fewer is recorded as a non-standard run)."),
    tasks: str = typer.Option(None, "--tasks", help="Comma-separated subset of the preset's tasks."),
    seed: int = typer.Option(0, "--seed", min=0, help="Episode e of each task uses seed + e."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the run already in --out."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run in --out (same config)."),
    video: bool = typer.Option(False, "--video/--no-video", help="One MP4 per episode (first camera)."),
    device: str = typer.Option(None, "--device", help="lerobot: policies: torch device."),
    n_action_steps: int = typer.Option(None, "--n-action-steps", min=1, help="Chunked policies: actions per chunk."),
    num_envs: int = typer.Option(None, "--num-envs", min=1, help="Episodes run at once, each worker process "
                                 "owning a sidecar of the backend; lerobot:/remote: policies act for all of them in "
                                 "one batch, others run inside each worker (default: sized to the cores and the "
                                 "episodes). Results do not depend on it."),
    policy_groups: int = typer.Option(1, "--policy-groups", help=POLICY_GROUPS_HELP),
    policy_ready: int = typer.Option(None, "--policy-ready", help=POLICY_READY_HELP),
    envs_per_worker: int = typer.Option(1, "--envs-per-worker", help=ENVS_PER_WORKER_HELP),
    shard: str = typer.Option(None, "--shard", help="i/K: run only the episodes whose global index "
                              "(task_index * episodes + e) % K == i (with --engine: the whole tasks with "
                              "task_index % K == i, each one batch); combine the K run directories with "
                              "simseam merge."),
    engine: str = typer.Option(None, "--engine", help="mujoco_warp: the preset's environments as worlds of one "
                               "batch per task on MuJoCo Warp (Meta-World and LIBERO presets; an image policy's "
                               "cameras drawn by MuJoCo Warp's ray tracer), in this process; "
                               "default: the preset's backend, a CPU process per environment."),
    sim_device: str = typer.Option(None, "--sim-device", help="--engine mujoco_warp: the Warp device of the "
                                   "worlds (cuda:K or cpu; default Warp's preferred one)."),
    ray_address: str = typer.Option(None, "--ray", help="Run the episodes on a Ray cluster: auto, ray://HOST:PORT or "
                                    "HOST:PORT, or local; each Ray worker owns a sidecar of the backend and its own "
                                    "policy; --num-envs then counts Ray workers (default: the cluster's CPUs)."),
    ci_width: float = typer.Option(0.05, "--ci-width", help=CI_WIDTH_HELP),
    processes: int = PROCESSES_OPTION,
    mps: bool = MPS_OPTION,
    image_size: int = IMAGE_SIZE_OPTION,
    render: str = RENDER_OPTION,
    claims: Path = CLAIMS_OPTION,
) -> None:
    """Run a benchmark's standard evaluation protocol; report per-task and overall success (Wilson 95 %)."""
    from simseam.runner.evaluate import eval_recipe, resolve_tasks
    from simseam.runner.job import Job
    from simseam.runner.run_dir import RunDir, default_run_dir
    from simseam.runner.sharding import parse_shard

    check_seed(seed)
    if resume and out is None:
        fail(ConfigError("--resume needs --out (the run directory to continue)"))
    try:
        shard_ik = parse_shard(shard) if shard is not None else None
        check_lockstep(policy_groups, policy_ready, envs_per_worker, num_envs, ray_address is not None)
        p = _checked_preset(preset_name, image_size, render, engine)
        _check_executor(engine, sim_device, ray_address, video, lockstep_given=(policy_groups != 1 or policy_ready
                                                                                or envs_per_worker != 1))
        _check_processes(processes, mps, engine, sim_device, shard)
        task_list = resolve_tasks(p, _task_subset(tasks))
        n = episodes or p.episodes
        check_seed(seed, n)  # episode e of every task uses seed + e
        default_out, out = out is None, out or default_run_dir()
        config, planned = _eval_plan(p, policy, task_list, n, seed, video, ci_width, shard_ik, engine, claims)
        if processes > 1:
            eval_processes(p, shard_args(preset_name, policy, seed, engine, ci_width, episodes=episodes, tasks=tasks,
                                         sim_device=sim_device, device=device, n_action_steps=n_action_steps,
                                         num_envs=num_envs, image_size=image_size, render=render),
                           len(task_list), n, out, default_out, processes, mps, overwrite, resume)
            return
        run_dir = RunDir(out, config, overwrite=overwrite, resume=resume, latest=default_out)  # written at start
    except SimseamError as exc:
        fail(exc)
    todo = run_dir.left(planned)
    executor = _eval_executor(len(todo), n, num_envs, engine, ray_address, policy_groups, policy_ready, envs_per_worker)
    job = Job(eval_recipe(p, task_list, n, engine, sim_device), policy, policy_kwargs(device, n_action_steps), todo,
              seed, run_dir, video, claims=_task_claims(claims, shard_ik))
    console.print(_eval_start(p, job, executor, engine, n, config, (
        f"  shard {shard_ik[0]}/{shard_ik[1]}: {len(planned)} episode(s)" if shard_ik else "")))
    _eval_job(job, executor, p, engine)


def _checked_preset(name: str, image_size: int | None, render: str | None, engine: str | None):
    """The preset ``simseam eval`` runs: its cameras' ``--image-size``, its ``--engine`` (one with a port of it)
    and that port's ``--render``, each checked."""
    from simseam.runner.evaluate import check_engine, preset, with_image_size, with_render

    p = with_image_size(preset(name), image_size)
    check_engine(p, engine)
    return with_render(p, render, engine)


def _eval_plan(p, policy: str, task_list: list[str], n: int, seed: int, video: bool, ci_width: float,
               shard_ik: tuple[int, int] | None, engine: str | None, claims: Path | None = None
               ) -> tuple[dict, list[int]]:
    """An eval's config (what its run.json records) and the episode indices it plans (its shard's; with
    ``claims``: every task's, of which it runs those it claims), checked."""
    from simseam.runner.evaluate import eval_config, eval_indices
    from simseam.runner.provenance import for_benchmark
    from simseam.runner.sharding import CLAIMED, check_shard_holds_episodes

    _check_claims(claims, shard_ik, engine)
    claimed = claims is not None
    whole_tasks = shard_ik is not None and engine is not None  # a port's task is one batch: shards take tasks
    config = {**eval_config(p, redacted(policy), task_list, n, seed, video), "ci_width": checked_ci_width(ci_width),
              **({"shard": list(shard_ik)} if shard_ik is not None else {}),
              **({"shard_unit": n} if whole_tasks else {}),
              **({"dealing": CLAIMED} if claimed else {}),
              **({"engine": engine} if engine is not None else {})}
    planned = check_shard_holds_episodes(eval_indices(task_list, n, None if claimed else shard_ik, whole_tasks),
                                         shard_ik, len(task_list) * n, n if whole_tasks else 1)
    config["provenance"] = for_benchmark(p.backend, policy)
    return config, planned


def _check_claims(claims: Path | None, shard_ik: tuple[int, int] | None, engine: str | None) -> None:
    if claims is not None and (shard_ik is None or engine is None):
        raise ConfigError("--claims: only with --shard i/K and --engine (the whole tasks a run of --processes "
                          "deals)")


def _task_claims(claims: Path | None, shard_ik: tuple[int, int] | None):
    from simseam.runner.claims import TaskClaims

    return TaskClaims(claims, shard_ik[0]) if claims is not None else None


def _eval_start(p, job, executor, engine: str | None, n: int, config: dict, shard: str) -> str:
    """The first line of ``simseam eval``: what runs, where, into which directory (``shard``: which share)."""
    tasks, policy, out = job.recipe.tasks, escape(job.policy), escape(str(job.run_dir.path))
    if engine is not None:
        return (f"eval [bold]{escape(p.name)}[/] on [bold]{escape(engine)}[/]: {len(tasks)} task(s) x {n} "
                f"episode(s), policy [bold]{policy}[/], {executor.num_envs} world(s) per task -> {out}")
    if executor.kind == "ray":
        return (f"eval [bold]{escape(p.name)}[/]: {len(job.indices)} episode(s) of {len(tasks)} task(s), policy "
                f"[bold]{policy}[/] on Ray ({escape(executor.address)}) -> {out}")
    return (f"eval [bold]{escape(p.name)}[/]: {len(tasks)} task(s) x {n} episode(s), policy [bold]{policy}[/] -> "
            f"{out}" + ("" if config["standard"] else "  [yellow](non-standard: subset)[/]") + shard)


def _eval_executor(todo: int, episodes: int, num_envs: int | None, engine: str | None, ray_address: str | None,
                   *lockstep: int | None):
    """Where ``simseam eval`` runs: a batched engine (``--num-envs`` worlds per task, default the task's
    episodes), Ray, ``--num-envs`` environments (default: sized to the cores and the episodes), or this
    process."""
    from simseam.runner.job import Executor
    from simseam.runner.scheduler import Lockstep

    if engine is not None:
        return Executor("vector", max(1, num_envs or episodes))
    if ray_address is not None:
        return Executor("ray", num_envs, address=ray_address)
    rule = Lockstep(*lockstep)
    if num_envs is None:
        from simseam.runner.vector import default_num_envs

        num_envs = default_num_envs(todo, envs_per_worker=rule.envs_per_worker)
        rule = rule.or_default()  # neither a rule nor --num-envs named
    num_envs = max(1, min(num_envs, todo or 1))
    return Executor("vector" if num_envs > 1 else "inline", num_envs, rule)


def _eval_job(job, executor, p, engine: str | None) -> None:
    """``simseam eval``'s job on its executor: progress, one line per episode, Ctrl-C, errors, the summary."""
    import contextlib

    from simseam.runner.job import JobReport, execute

    if job.run_dir.resume:
        console.print(f"resuming: {len(job.run_dir.done)} episode(s) already recorded")
        print_notes(job.run_dir.notes, "differs from the run there (the episodes are the same)")
    report = JobReport(status=lambda task: _Starting(p.backend, task))
    with episodes_guard(job.run_dir, finish=_summary(p, job.policy, job.run_dir, job.claims is not None)), \
            contextlib.ExitStack() as stack:
        if executor.kind == "inline":
            report.on_done, report.on_error = _task_episode_line, _episode_error
        else:
            progress = stack.enter_context(EvalProgress(console, total=len(job.indices)))
            report.on_done = lambda entry, written: progress.done(entry)
            report.on_error, report.on_worker_failure = progress.episode_error, progress.worker_failure

        def opened(spec, n, where):
            if engine is not None:
                console.print(f"[dim]{escape(spec.task.name)}: {n} world(s) on {escape(engine)}[/]", highlight=False)
            elif executor.kind == "vector":
                console.print(f"[dim]{escape(p.backend)}: {n} environments ({where})[/]", highlight=False)

        report.on_envs = opened
        execute(job, executor, report)


def _task_episode_line(entry: dict, written) -> None:
    mark = "[green]success[/]" if entry["success"] else "[red]fail[/]"
    console.print(f"  {escape(entry['task'])} episode {entry['episode']}: {mark} in {entry['steps']} steps"
                  + (f"  [red]{escape(entry['error'])}[/]" if entry.get("error") else ""), highlight=False)


def _episode_error(res, what_next: str) -> None:
    err_console.print(f"episode {res.index}: {res.error}; {what_next}", style="red", markup=False)


class _Starting:
    """A benchmark's sidecar starting for one task: a line, and a line per stage of its boot."""

    def __init__(self, backend: str, task: str):
        self.backend, self.what = backend, task

    def __enter__(self) -> "_Starting":
        console.print(f"[dim]{escape(self.backend)}: starting {escape(self.what)}[/]", highlight=False)
        return self

    def __exit__(self, *exc) -> None:
        pass

    def update(self, stage: str) -> None:
        console.print(f"[dim]{escape(self.what)}: {escape(stage)}[/]", highlight=False)


def _check_executor(engine: str | None, sim_device: str | None, ray_address: str | None, video: bool,
                    lockstep_given: bool) -> None:
    """The executor options of ``simseam eval`` against each other (a ``ConfigError`` naming the clash)."""
    if ray_address is not None and video:
        raise ConfigError("--ray cannot be combined with --video (each node would write to its own disk)")
    if engine is not None and (ray_address is not None or video or lockstep_given):
        raise ConfigError(f"--engine {engine}: its worlds step together in this process; drop --ray, --video, "
                          "--policy-groups, --policy-ready and --envs-per-worker")
    if sim_device is not None and engine is None:
        raise ConfigError("--sim-device belongs to --engine mujoco_warp")


def _check_processes(processes: int, mps: bool, engine: str | None, sim_device: str | None,
                     shard: str | None) -> None:
    """``--processes`` and ``--mps`` against the other options (a ``ConfigError`` naming the clash)."""
    if processes > 1 and engine is None:
        raise ConfigError(f"--processes {processes} belongs to --engine mujoco_warp (a CPU backend's environments are "
                          "processes already: --num-envs)")
    if processes > 1 and shard is not None:
        raise ConfigError(f"--processes {processes} runs the shards itself (--shard i/{processes} each); drop --shard")
    if mps and processes < 2:
        raise ConfigError("--mps shares the GPU among the processes of --processes K (K > 1)")
    if mps and sim_device is not None and not sim_device.startswith("cuda"):
        raise ConfigError(f"--mps is CUDA's; --sim-device {sim_device} is not a CUDA device")


def _task_subset(tasks: str | None) -> list[str] | None:
    only = [t.strip() for t in tasks.split(",") if t.strip()] if tasks is not None else None
    if only == []:
        raise ConfigError(f"--tasks {tasks!r} names no task (comma-separated names or indices; leave it out "
                          "for every task)")
    return only


def _summary(p, policy: str, run_dir, claimed: bool = False):
    """The ``finish`` of an eval's ``episodes_guard``: its summary (``claimed``: a process of ``--processes`` that
    claims its tasks, which may find every task held by the others)."""
    return lambda interrupted: _eval_summary(p, policy, run_dir, interrupted, claimed)


def _eval_summary(p, policy: str, run_dir, interrupted: bool, claimed: bool = False) -> None:
    out = run_dir.path
    summary = run_dir.summarize(interrupted=interrupted)
    if summary is None and claimed and not interrupted:
        console.print("every task was claimed by the run's other processes: none ran here")
        return
    if summary is None:
        never_started(out, interrupted)
    print_task_table(summary, f"{p.name} ({policy})")
    console.print(ci_width_line(summary), markup=False, highlight=False)
    console.print(f"summary: {escape(str(out / 'summary.json'))}")
    if summary["complete"]:
        report_after_run(out)
    if interrupted:
        raise typer.Exit(code=130)


def print_task_table(summary: dict, title: str) -> None:
    """An eval summary's per-task success, the pooled rate and the mean of the tasks' rates."""
    table = Table("task", "success", "rate", "Wilson 95%", f"episodes for +-{summary['ci_width']:.0%}",
                  title=escape(title))
    for task, t in (summary.get("per_task") or {}).items():
        lo, hi = t["success_rate_wilson95"]
        table.add_row(escape(task), f"{t['n_success']}/{t['n_episodes']}", f"{t['success_rate']:.1%}",
                      f"[{lo:.2f}, {hi:.2f}]", str(t["episodes_for_ci_width"]))
    lo, hi = summary["success_rate_wilson95"]
    table.add_row("[bold]all (pooled)[/]", f"{summary['n_success']}/{summary['n_episodes']}",
                  f"{summary['success_rate']:.1%}", f"[{lo:.2f}, {hi:.2f}]")
    if summary.get("per_task"):
        table.add_row("[bold]mean of tasks[/]", "", f"{summary['mean_task_success_rate']:.1%}", "")
    console.print(table)
