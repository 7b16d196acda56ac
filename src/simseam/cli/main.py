"""``simseam`` command line: run | eval | summarize | collect | train | serve-policy | deploy | robots | backends |
benchmarks | sidecar | isaac | doctor."""

from __future__ import annotations

import contextlib
import json
import signal
import sys
from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

from simseam.cli.benchmarks import backends_app, benchmarks_app, eval_command
from simseam.cli.deploy import deploy
from simseam.cli.isaac import doctor, isaac_app
from simseam.cli.serve_policy import serve_policy
from simseam.seam import ConfigError, SimseamError

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Run robot policies in simulation.")
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
console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)


def _fail(exc: SimseamError) -> None:
    """Print the error literally (no Rich markup: brackets in messages stay) and exit with code 2."""
    err_console.print(f"error: {type(exc).__name__}: {exc}", style="bold red", highlight=False, markup=False)
    raise typer.Exit(code=2)


def _policy_kwargs(device: str | None, n_action_steps: int | None) -> dict:
    kwargs = {}
    if device:
        kwargs["device"] = device
    if n_action_steps:
        kwargs["n_action_steps"] = n_action_steps
    return kwargs


def _redacted(policy: str) -> str:
    """The policy spec as recorded in run.json: a ``token=`` in a remote: URL is never written to disk."""
    import re

    return re.sub(r"(token=)[^&#]*", r"\1<redacted>", policy)


class _Terminated(KeyboardInterrupt):
    """SIGTERM, handled like Ctrl-C: the episode in flight is dropped, the finished ones are kept."""


@contextlib.contextmanager
def _sigterm_as_interrupt():
    def on_term(signum, frame):
        raise _Terminated()

    old = signal.signal(signal.SIGTERM, on_term)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, old)


def _episodes(rollout, pol, indices, *, seed: int, video_dir: Path | None, recorder=None,
              keep_failures: bool = True, on_result=None) -> list:
    """``runner.session.run_episodes`` with a progress bar and one line per episode."""
    from simseam.runner.session import run_episodes

    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=console, transient=True) as progress:
        current = {}

        def start(i):
            current["task"] = progress.add_task(f"episode {i}", total=rollout.spec.task.max_steps)
            return lambda n: progress.update(current["task"], completed=n)

        def done(res, written):
            progress.remove_task(current.pop("task"))
            if on_result is not None:
                on_result(res)
            step_ms = res.to_json()["step_latency_ms"]["mean"]  # None when the episode took no step
            mark = "[green]success[/]" if res.success else "[red]failure[/]"
            console.print(
                f"episode {res.index:3d}  seed {res.seed:5d}  {mark}  steps {res.steps:4d}  "
                f"reward {res.reward:6.2f}  step " + (f"{step_ms:.2f} ms" if step_ms is not None else "-")
                + (f"  video {escape(res.video)}" if res.video else "")
                + ("" if written is None else ("  [dim]recorded[/]" if written else "  [dim]not recorded[/]")))

        def error(res, what_next):
            err_console.print(f"episode {res.index}: {res.error}; {what_next}", style="red", markup=False,
                              highlight=False)

        return run_episodes(rollout, pol, indices, seed=seed, video_dir=video_dir, recorder=recorder,
                            keep_failures=keep_failures, on_start=start, on_done=done, on_error=error)


def _open_run(scene: Path, policy: str, seed: int, policy_kwargs: dict, *, need_images: bool = False):
    from simseam.policies.base import make_policy
    from simseam.runner.scene_config import build_rollout, load_scene_config

    cfg, base_dir = load_scene_config(scene)
    pol = make_policy(policy, **policy_kwargs)
    with console.status("building the scene") as status:
        rollout = build_rollout(cfg, base_dir, privileged=pol.requires_privileged,
                                render_images=pol.uses_images or need_images, seed=seed,
                                progress=lambda stage: status.update(f"sidecar: {stage}"))
    return cfg, pol, rollout


def _close_policy(pol) -> None:
    close = getattr(pol, "close", None)
    if callable(close):
        close()


@app.command()
def run(
    scene: Path = typer.Option(..., "--scene", help="Scene YAML (robot, engine, task, image size, max steps)."),
    policy: str = typer.Option("scripted", "--policy", help="Policy spec: scripted, random, zero, "
                               "lerobot:<dir or hub id>, remote:ws://host:port."),
    episodes: int = typer.Option(10, "--episodes", min=1, help="Number of episodes."),
    seed: int = typer.Option(0, "--seed", min=0, help="Episode i uses seed + i (a non-negative integer)."),
    out: Path = typer.Option(None, "--out", help="Output directory (run.json, episodes.jsonl, summary.json, "
                             "videos). Default: a new runs/<timestamp>, with runs/latest pointing at it."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the run already in --out."),
    resume: bool = typer.Option(False, "--resume", help="Continue the run in --out (same config): skip the "
                                "episodes it already recorded."),
    video: bool = typer.Option(False, "--video/--no-video", help="Write one MP4 per episode (first RGB camera)."),
    record_dataset: Path = typer.Option(None, "--record-dataset", help="Also record the episodes as a new "
                                        "LeRobot dataset in this directory."),
    keep_failures: bool = typer.Option(True, "--keep-failures/--successes-only",
                                       help="With --record-dataset: record failed episodes too."),
    videos: bool = typer.Option(True, "--dataset-videos/--dataset-images",
                                help="With --record-dataset: store camera frames as AV1 video or PNG images."),
    device: str = typer.Option(None, "--device", help="lerobot: policies: torch device (default: CUDA if present)."),
    n_action_steps: int = typer.Option(None, "--n-action-steps", min=1,
                                       help="Chunked policies: actions executed per predicted chunk."),
) -> None:
    """Run a policy for N episodes; every finished episode is on disk before the next begins."""
    from simseam.runner.run_dir import RunDir, default_run_dir, point_latest, rebuild_summary
    from simseam.runner.scene_config import load_scene_config

    default_out = out is None
    if default_out and resume:
        _fail(ConfigError("--resume needs --out (the run directory to continue)"))
    out = default_run_dir() if default_out else out
    try:
        cfg, _ = load_scene_config(scene)
        config = {"scene_file": str(scene), "scene": cfg.model_dump(mode="json"), "policy": _redacted(policy),
                  "episodes": episodes, "seed": seed, "video": video,
                  "record_dataset": str(record_dataset) if record_dataset else None}
        run_dir = RunDir(out, config, overwrite=overwrite, resume=resume)  # checked before anything runs
    except SimseamError as exc:
        _fail(exc)
    if default_out:
        point_latest(out)
    todo = [i for i in range(episodes) if i not in run_dir.done]
    if resume:
        console.print(f"resuming {out}: {len(run_dir.done)} episode(s) already recorded, {len(todo)} to run")
    try:
        cfg, pol, rollout = _open_run(scene, policy, seed, _policy_kwargs(device, n_action_steps),
                                      need_images=record_dataset is not None)
    except SimseamError as exc:
        run_dir.close()
        _fail(exc)
    spec_json = rollout.spec.to_json()
    run_dir.write_spec(spec_json)
    if video and not rollout.spec.robot.sensors_of("rgb"):
        err_console.print(f"note: --video: robot {rollout.spec.robot.name!r} has no RGB camera, so no video "
                          "is written", style="yellow", markup=False, highlight=False)
    recorder = None
    interrupted = False
    try:
        with _sigterm_as_interrupt():
            if record_dataset is not None:
                from simseam.runner.dataset_recorder import LeRobotRecorder

                recorder = LeRobotRecorder(record_dataset, rollout.spec, use_videos=videos)
            console.print(f"{escape(rollout.spec.describe())}, policy [bold]{escape(policy)}[/], "
                          f"{episodes} episode(s) -> {escape(str(out))}")
            _episodes(rollout, pol, todo, seed=seed, video_dir=out if video else None, recorder=recorder,
                      keep_failures=keep_failures, on_result=lambda res: run_dir.append(res.to_json()))
    except KeyboardInterrupt:
        interrupted = True
    except SimseamError as exc:
        rebuild_summary(out, spec_json, interrupted=True)
        _fail(exc)
    finally:
        run_dir.close()
        if recorder is not None:
            recorder.close()
        rollout.close()
        _close_policy(pol)
    summary = rebuild_summary(out, spec_json, interrupted=interrupted)
    if interrupted:
        err_console.print(f"interrupted after {summary['n_episodes']} of {episodes} episodes; "
                          f"summary of the finished ones: {out / 'summary.json'}", markup=False, highlight=False)
        raise typer.Exit(code=130)
    lo, hi = summary["success_rate_wilson95"]
    console.print(
        f"success {summary['n_success']}/{summary['n_episodes']} = {summary['success_rate']:.0%} "
        f"(Wilson 95% \\[{lo:.2f}, {hi:.2f}])  summary: {escape(str(out / 'summary.json'))}"
    )
    if recorder is not None:
        console.print(f"dataset: {recorder.episodes_written} episode(s), {recorder.frames_written} frames "
                      f"in {escape(str(record_dataset))}")


@app.command()
def summarize(run: Path = typer.Argument(..., help="A run directory (holds episodes.jsonl).")) -> None:
    """Rebuild DIR/summary.json from its episode log (after a kill, or to re-read a run)."""
    from simseam.runner.run_dir import rebuild_summary

    try:
        summary = rebuild_summary(run)
    except SimseamError as exc:
        _fail(exc)
    lo, hi = summary["success_rate_wilson95"]
    console.print(f"{summary['n_episodes']} episode(s), success {summary['n_success']}/{summary['n_episodes']} "
                  f"(Wilson 95% \\[{lo:.2f}, {hi:.2f}]); {'complete' if summary['complete'] else 'incomplete'}; "
                  f"summary: {escape(str(run / 'summary.json'))}")


@app.command()
def collect(
    scene: Path = typer.Option(..., "--scene", help="Scene YAML."),
    policy: str = typer.Option("scripted", "--policy", help="Policy spec (default: the scripted expert)."),
    episodes: int = typer.Option(50, "--episodes", min=1, help="Episodes to run."),
    out: Path = typer.Option(..., "--out", help="New LeRobot dataset directory."),
    seed: int = typer.Option(0, "--seed", min=0, help="Episode i uses seed + i (a non-negative integer)."),
    keep_failures: bool = typer.Option(False, "--keep-failures/--successes-only",
                                       help="Also record episodes that did not succeed."),
    videos: bool = typer.Option(True, "--videos/--images", help="Camera frames as AV1 video or PNG images."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace --out if it exists."),
) -> None:
    """Collect demonstrations as a LeRobot dataset (images, state, action, task, fps = control rate).
    Ctrl-C or SIGTERM keeps every episode recorded so far (the dataset is finalized) and exits 130."""
    from simseam.runner.dataset_recorder import LeRobotRecorder
    from simseam.runner.run_dir import check_writable

    try:
        check_writable(out)
        if out.exists() and any(out.iterdir()) and not overwrite:
            raise ConfigError(f"dataset directory {out} already exists; pick a new --out or pass --overwrite")
        _, pol, rollout = _open_run(scene, policy, seed, {}, need_images=True)
    except SimseamError as exc:
        _fail(exc)
    results: list = []
    interrupted = False
    rec = None
    try:
        with _sigterm_as_interrupt():
            rec = LeRobotRecorder(out, rollout.spec, use_videos=videos, overwrite=overwrite)
            console.print(f"collecting {episodes} episode(s) of [bold]{escape(policy)}[/] on "
                          f"{escape(rollout.spec.describe())} into {escape(str(out))}")
            _episodes(rollout, pol, range(episodes), seed=seed, video_dir=None, recorder=rec,
                      keep_failures=keep_failures, on_result=results.append)
    except KeyboardInterrupt:
        interrupted = True
    except SimseamError as exc:
        _fail(exc)
    finally:
        if rec is not None:
            rec.close()
        rollout.close()
        _close_policy(pol)
    n_ok = sum(r.success for r in results)
    written = rec.episodes_written if rec is not None else 0
    console.print(f"dataset {escape(str(out))}: {written} episode(s), "
                  f"{rec.frames_written if rec is not None else 0} frames ({n_ok}/{len(results)} episodes succeeded)")
    if interrupted:
        err_console.print(f"interrupted after {len(results)} of {episodes} episodes; the dataset keeps the "
                          f"{written} recorded", markup=False, highlight=False)
        raise typer.Exit(code=130)
    if written == 0:
        err_console.print("no episode was recorded (all failed; --keep-failures records them anyway)",
                          style="red", markup=False, highlight=False)
        raise typer.Exit(code=1)


@app.command()
def train(
    dataset: Path = typer.Option(..., "--dataset", help="LeRobot dataset directory (from `simseam collect`)."),
    out: Path = typer.Option(..., "--out", help="Checkpoint directory (then: --policy lerobot:<out>)."),
    steps: int = typer.Option(20000, "--steps", min=1, help="Optimizer steps."),
    time_budget_s: float = typer.Option(None, "--time-budget-s", help="Stop after this many seconds."),
    batch_size: int = typer.Option(8, "--batch-size", min=1),
    lr: float = typer.Option(1e-5, "--lr", help="AdamW learning rate (backbone too)."),
    chunk_size: int = typer.Option(20, "--chunk-size", min=1, help="Actions predicted per chunk."),
    n_action_steps: int = typer.Option(10, "--n-action-steps", min=1, help="Actions executed per chunk."),
    device: str = typer.Option(None, "--device", help="torch device (default: CUDA if present, else CPU)."),
    workers: int = typer.Option(4, "--workers", min=0, help="Data-loading worker processes."),
    cache: bool = typer.Option(False, "--cache/--no-cache", help="Decode the dataset once and keep it on the "
                               "device (fast; needs the frames to fit in its memory)."),
    amp: bool = typer.Option(False, "--amp", help="bfloat16 autocast on CUDA."),
    seed: int = typer.Option(0, "--seed"),
) -> None:
    """Train a LeRobot ACT policy on a dataset; the result loads with --policy lerobot:<out>."""
    from simseam.runner.training import ActTrainConfig, train_act

    if n_action_steps > chunk_size:
        _fail(ConfigError(f"--n-action-steps ({n_action_steps}) cannot exceed --chunk-size ({chunk_size})"))
    cfg = ActTrainConfig(steps=steps, time_budget_s=time_budget_s, batch_size=batch_size, lr=lr, lr_backbone=lr,
                         chunk_size=chunk_size, n_action_steps=n_action_steps, device=device, num_workers=workers,
                         cache_on_device=cache, use_amp=amp, seed=seed, log_every=max(1, min(100, steps // 10)))
    try:
        res = train_act(dataset, out, cfg, on_log=lambda s, loss: console.print(f"step {s:7d}  loss {loss:.4f}"))
    except SimseamError as exc:
        _fail(exc)
    console.print(f"trained ACT ({res.n_params / 1e6:.1f} M params) for {res.steps} steps in {res.seconds:.0f} s "
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
        _fail(exc)
    sys.stdout.write(json.dumps(spec.to_json(), indent=2) + "\n")


@robots_app.command("check")
def robots_check(path: Path = typer.Argument(..., help="Manifest file to check against its URDF.")) -> None:
    """Validate a manifest: schema, asset references, and every joint/link against its URDF."""
    from simseam.robot.manifest import load_manifest

    try:
        spec = load_manifest(path)
    except SimseamError as exc:
        _fail(exc)
    console.print(
        f"[green]ok[/] {path}: robot {spec.name!r}, {len(spec.joints)} joints, "
        f"{len(spec.sensors)} sensors, URDF {spec.urdf}"
    )


def main() -> None:  # pragma: no cover
    app()


if __name__ == "__main__":  # pragma: no cover
    main()
