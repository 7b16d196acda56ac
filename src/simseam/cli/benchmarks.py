"""``simseam backends list|provision``, ``simseam benchmarks list``, ``simseam eval PRESET``."""

from __future__ import annotations

from pathlib import Path

import typer
from rich.markup import escape
from rich.table import Table

from simseam.cli.common import ENVS_PER_WORKER_HELP, POLICY_GROUPS_HELP, POLICY_READY_HELP, EvalProgress, \
    check_lockstep, check_seed, checked_ci_width, ci_width_line, close_policy, console, episodes_guard, err_console, \
    fail, never_started, out_path, policy_kwargs, print_notes, redacted, SpecProbe, CI_WIDTH_HELP
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
                              "(task_index * episodes + e) % K == i; combine the K run directories with "
                              "simseam merge."),
    engine: str = typer.Option(None, "--engine", help="mujoco_warp: the preset's environments as worlds of one "
                               "batch per task on MuJoCo Warp (Meta-World presets; state-only), in this process; "
                               "default: the preset's backend, a CPU process per environment."),
    sim_device: str = typer.Option(None, "--sim-device", help="--engine mujoco_warp: the Warp device of the "
                                   "worlds (cuda:K or cpu; default Warp's preferred one)."),
    ray_address: str = typer.Option(None, "--ray", help="Run the episodes on a Ray cluster: auto, ray://HOST:PORT or "
                                    "HOST:PORT, or local; each Ray worker owns a sidecar of the backend and its own "
                                    "policy; --num-envs then counts Ray workers (default: the cluster's CPUs)."),
    ci_width: float = typer.Option(0.05, "--ci-width", help=CI_WIDTH_HELP),
) -> None:
    """Run a benchmark's standard evaluation protocol; report per-task and overall success (Wilson 95 %)."""
    from simseam.runner.evaluate import check_engine, eval_config, eval_indices, preset, resolve_tasks
    from simseam.runner.run_dir import RunDir, default_run_dir
    from simseam.runner.sharding import check_shard_holds_episodes, parse_shard

    check_seed(seed)
    if resume and out is None:
        fail(ConfigError("--resume needs --out (the run directory to continue)"))
    try:
        shard_ik = parse_shard(shard) if shard is not None else None
        check_lockstep(policy_groups, policy_ready, envs_per_worker, num_envs, ray_address is not None)
        p = preset(preset_name)
        check_engine(p, engine)
        _check_executor(engine, sim_device, ray_address, video, lockstep_given=(policy_groups != 1 or policy_ready
                                                                                or envs_per_worker != 1))
        task_list = resolve_tasks(p, _task_subset(tasks))
        n = episodes or p.episodes
        check_seed(seed, n)  # episode e of every task uses seed + e
        default_out = out is None
        out = default_run_dir() if default_out else out
        config = {**eval_config(p, redacted(policy), task_list, n, seed, video), "ci_width": checked_ci_width(ci_width)}
        if shard_ik is not None:
            config["shard"] = list(shard_ik)
        if engine is not None:
            config["engine"] = engine
        planned = check_shard_holds_episodes(eval_indices(task_list, n, shard_ik), shard_ik, len(task_list) * n)
        from simseam.runner.provenance import for_benchmark

        config["provenance"] = for_benchmark(p.backend, policy)
        run_dir = RunDir(out, config, overwrite=overwrite, resume=resume, latest=default_out)  # written at start
    except SimseamError as exc:
        fail(exc)
    todo = [i for i in planned if i not in run_dir.done]
    if engine is not None:
        _eval_batched(p, policy, policy_kwargs(device, n_action_steps), task_list, n, run_dir, out, num_envs,
                      engine=engine, sim_device=sim_device, seed=seed, indices=planned)
        return
    if ray_address is not None:
        _eval_ray(p, policy, policy_kwargs(device, n_action_steps), task_list, n, run_dir, out, ray_address,
                  num_workers=num_envs, seed=seed, indices=planned)
        return
    if num_envs is None:
        from simseam.runner.vector import default_num_envs

        num_envs = default_num_envs(len(todo), envs_per_worker=envs_per_worker)
    num_envs = max(1, min(num_envs, len(todo) or 1))
    from simseam.runner.scheduler import Lockstep

    rule = Lockstep(policy_groups, policy_ready, envs_per_worker).fit(num_envs)
    kwargs = policy_kwargs(device, n_action_steps)
    try:
        pol, batch = _eval_policies(policy, kwargs, num_envs, rule)
    except SimseamError as exc:
        run_dir.close()
        fail(exc)
    console.print(f"eval [bold]{escape(p.name)}[/]: {len(task_list)} task(s) x {n} episode(s), policy "
                  f"[bold]{escape(policy)}[/] -> {escape(str(out))}" + ("" if config["standard"] else
                                                                      "  [yellow](non-standard: subset)[/]")
                  + (f"  shard {shard_ik[0]}/{shard_ik[1]}: {len(planned)} episode(s)" if shard_ik else ""))
    if resume:
        console.print(f"resuming: {len(run_dir.done)} episode(s) already recorded")
        print_notes(run_dir.notes, "differs from the run there (the episodes are the same)")
    if num_envs > 1:
        _eval_vector(p, policy, kwargs, pol, batch, task_list, n, run_dir, out, num_envs,
                     seed=seed, video=video, indices=planned, lockstep=rule)
        return
    _eval_sequential(p, pol, policy, task_list, n, run_dir, out, seed=seed, video=video, indices=planned)


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


def _task_subset(tasks: str | None) -> list[str] | None:
    only = [t.strip() for t in tasks.split(",") if t.strip()] if tasks is not None else None
    if only == []:
        raise ConfigError(f"--tasks {tasks!r} names no task (comma-separated names or indices; leave it out "
                          "for every task)")
    return only


def _eval_policies(policy: str, kwargs: dict, num_envs: int, rule):
    """The policy, and for N > 1 environments the batch that acts for them here (one shared model, or one
    instance per environment when the ``rule`` acts here), or None (the policy runs in each worker)."""
    from simseam.policies.base import make_policy

    pol = make_policy(policy, **kwargs)
    if num_envs <= 1:
        return pol, None
    from simseam.policies.batch import shared_batch

    batch = shared_batch(pol, num_envs, lambda: make_policy(policy, **kwargs))
    if batch is None and rule.acts_here:  # the policy acts here, one instance per environment
        from simseam.policies.batch import PerEnvPolicies

        made = [pol]
        batch = PerEnvPolicies(lambda: made.pop() if made else make_policy(policy, **kwargs), num_envs)
    return pol, batch


def _eval_sequential(p, pol, policy: str, task_list: list[str], n: int, run_dir, out: Path, *, seed: int,
                     video: bool, indices: list[int]) -> None:
    """``simseam eval`` on one environment here, episode after episode, then the summary."""
    from simseam.runner.evaluate import run_eval

    def done(res, task):
        mark = "[green]success[/]" if res.success else "[red]fail[/]"
        console.print(f"  {escape(task)} episode {res.index % n}: {mark} in {res.steps} steps"
                      + (f"  [red]{escape(res.error)}[/]" if res.error else ""), highlight=False)

    def error(res, what_next):
        err_console.print(f"episode {res.index}: {res.error}; {what_next}", style="red", markup=False)

    with episodes_guard(run_dir, lambda: close_policy(pol), finish=_summary(p, policy, run_dir)):
        run_eval(p, pol, policy, task_list, n, run_dir, seed=seed, video_dir=out if video else None,
                 progress=lambda s: console.print(f"[dim]{escape(s)}[/]", highlight=False),
                 on_done=done, on_error=error, indices=indices)


def _eval_vector(p, policy: str, kwargs: dict, pol, batch, task_list: list[str], n: int, run_dir, out: Path,
                 num_envs: int, *, seed: int, video: bool, indices: list[int], lockstep) -> None:
    """``simseam eval --num-envs N`` (N > 1): the episodes on N environments in worker processes
    (``run_eval_vector``; a policy ``batch`` stepped by the ``lockstep`` rule), then the summary. Progress
    as ``simseam run --num-envs``."""
    from simseam.runner.evaluate import run_eval_vector

    privileged = pol.requires_privileged
    where = "one batched policy, one task at a time" if batch is not None else "a policy in each worker"
    if batch is not None:
        where += lockstep.describe()
    todo = len([i for i in indices if i not in run_dir.done])
    # nothing shared (batch None): each worker runs its own instance; this one meets the specs first
    cleanup = batch.close if batch is not None else lambda: close_policy(pol)
    with episodes_guard(run_dir, cleanup, finish=_summary(p, policy, run_dir)), \
            EvalProgress(console, total=todo) as progress:
        def start(vec):
            console.print(f"[dim]{escape(p.backend)}: {vec.num_envs} environments ({where})[/]", highlight=False)

        run_eval_vector(p, task_list, n, run_dir, num_envs, policy=policy, policy_kwargs=kwargs,
                        policy_batch=batch, privileged=privileged, uses_images=pol.uses_images, seed=seed,
                        video_dir=out if video else None, on_start=start,
                        on_done=lambda res, task: progress.done({**res.to_json(), "task": task}),
                        on_error=progress.episode_error, on_worker_failure=progress.worker_failure,
                        indices=indices, check=pol.reset, lockstep=lockstep)


def _eval_batched(p, policy: str, kwargs: dict, task_list: list[str], n: int, run_dir, out: Path,
                  num_envs: int | None, *, engine: str, sim_device: str | None, seed: int, indices: list[int]) -> None:
    """``simseam eval --engine mujoco_warp``: each task's episodes as the worlds of one batch
    (``run_eval_batched``; ``--num-envs`` worlds, default the task's episodes), the policy stepped for all of
    them at once (its own batch, or one instance per world). Progress and summary as the vector path."""
    from simseam.policies.batch import make_policy_batch
    from simseam.runner.evaluate import run_eval_batched

    todo = len([i for i in indices if i not in run_dir.done])
    worlds = max(1, num_envs or n)
    batch = None
    try:
        batch = make_policy_batch(policy, worlds, **kwargs)
        if batch.uses_images:
            raise ConfigError(f"--engine {engine}: the port is state-only; policy {policy!r} reads images")
    except SimseamError as exc:
        if batch is not None:
            batch.close()
        run_dir.close()
        fail(exc)
    console.print(f"eval [bold]{escape(p.name)}[/] on [bold]{escape(engine)}[/]: {len(task_list)} task(s) x {n} "
                  f"episode(s), policy [bold]{escape(policy)}[/], {worlds} world(s) per task -> {escape(str(out))}")
    with episodes_guard(run_dir, batch.close, finish=_summary(p, policy, run_dir)), \
            EvalProgress(console, total=todo) as progress:
        def start(vec):
            console.print(f"[dim]{escape(vec.spec.task.name)}: {vec.num_envs} world(s) on {escape(engine)}[/]",
                          highlight=False)

        run_eval_batched(p, task_list, n, run_dir, worlds, policy_batch=batch, engine=engine, device=sim_device,
                         privileged=batch.requires_privileged, seed=seed, on_start=start,
                         on_done=lambda res, task: progress.done({**res.to_json(), "task": task}),
                         on_error=progress.episode_error, indices=indices, check=lambda spec: batch.reset(0, spec))


def _eval_ray(p, policy: str, kwargs: dict, task_list: list[str], n: int, run_dir, out: Path, address: str, *,
              num_workers: int | None, seed: int, indices: list[int]) -> None:
    """``simseam eval --ray ADDRESS``: the episodes on Ray actors (``run_eval_ray``), each owning a sidecar
    of the backend and its own policy; results streamed into the episode log. Progress as ``run --ray``."""
    from simseam.runner.evaluate import run_eval_ray

    todo = [i for i in indices if i not in run_dir.done]
    probe = None
    with episodes_guard(run_dir, lambda: probe and probe.close(), finish=_summary(p, policy, run_dir)):
        probe = SpecProbe(policy, kwargs)  # meets the first actor's spec before anything is written
        console.print(f"eval [bold]{escape(p.name)}[/]: {len(todo)} episode(s) of {len(task_list)} task(s), policy "
                      f"[bold]{escape(policy)}[/] on Ray ({escape(address)}) -> {escape(str(out))}")
        if run_dir.done:
            console.print(f"resuming: {len(run_dir.done)} episode(s) already recorded")
        with EvalProgress(console, total=len(todo)) as progress:
            run_eval_ray(p, task_list, n, run_dir, address, policy=policy, policy_kwargs=kwargs,
                         privileged=probe.requires_privileged, uses_images=probe.uses_images, seed=seed,
                         num_workers=num_workers, indices=indices, check=probe.check,
                         on_done=progress.done, on_worker_failure=progress.worker_failure)


def _summary(p, policy: str, run_dir):
    """The ``finish`` of an eval's ``episodes_guard``: its summary."""
    return lambda interrupted: _eval_summary(p, policy, run_dir, interrupted)


def _eval_summary(p, policy: str, run_dir, interrupted: bool) -> None:
    out = run_dir.path
    summary = run_dir.summarize(interrupted=interrupted)
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
