"""``simseam`` command line: run | collect | train | serve-policy | deploy | robots | sidecar | isaac | doctor."""

from __future__ import annotations

import json
import sys
from pathlib import Path

import typer
from rich.console import Console
from rich.progress import BarColumn, MofNCompleteColumn, Progress, TextColumn, TimeElapsedColumn
from rich.table import Table

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
console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)


def _fail(exc: SimseamError) -> None:
    err_console.print(f"[bold red]error:[/] {type(exc).__name__}: {exc}", highlight=False, markup=True)
    raise typer.Exit(code=2)


def _policy_kwargs(device: str | None, n_action_steps: int | None) -> dict:
    kwargs = {}
    if device:
        kwargs["device"] = device
    if n_action_steps:
        kwargs["n_action_steps"] = n_action_steps
    return kwargs


def _episode_loop(rollout, pol, *, episodes: int, seed: int, out: Path | None, video: bool, recorder=None,
                  keep_failures: bool = True) -> list:
    """Run the episodes with a progress bar and one line each; a crashed sidecar or a lost policy
    server costs that episode only (the sidecar restarts; the remote policy reconnects on reset)."""
    from simseam.policies.remote import RemotePolicyError
    from simseam.runner.episodes import EpisodeResult, run_episode
    from simseam.seam import SidecarError

    results = []
    with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                  console=console, transient=True) as progress:
        for i in range(episodes):
            task = progress.add_task(f"episode {i}", total=rollout.task.max_steps)
            written = None
            try:
                res = run_episode(rollout, pol, index=i, seed=seed + i,
                                  video_path=out / f"episode_{i:03d}.mp4" if (video and out) else None,
                                  on_step=lambda n, t=task: progress.update(t, completed=n), recorder=recorder)
                if recorder is not None:
                    written = recorder.end_episode(keep=res.success or keep_failures)
            except (SidecarError, RemotePolicyError) as exc:
                if recorder is not None:
                    recorder.end_episode(keep=False)
                res = EpisodeResult(index=i, seed=seed + i, success=False, steps=0, reward=0.0,
                                    error=f"{type(exc).__name__}: {exc}")
                what = "restarting the sidecar" if isinstance(exc, SidecarError) else "reconnecting next episode"
                err_console.print(f"[red]episode {i}: {res.error}[/]; {what}", markup=True, highlight=False)
                if isinstance(exc, SidecarError):
                    rollout.restart()
            except BaseException:
                if recorder is not None:
                    recorder.end_episode(keep=False)
                raise
            progress.remove_task(task)
            results.append(res)
            step_ms = res.to_json()["step_latency_ms"]["mean"]  # None when the episode took no step
            mark = "[green]success[/]" if res.success else "[red]failure[/]"
            console.print(
                f"episode {i:3d}  seed {res.seed:5d}  {mark}  steps {res.steps:4d}  "
                f"reward {res.reward:6.2f}  step " + (f"{step_ms:.2f} ms" if step_ms is not None else "-")
                + (f"  video {res.video}" if res.video else "")
                + ("" if written is None else ("  [dim]recorded[/]" if written else "  [dim]not recorded[/]"))
            )
    return results


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
    scene: Path = typer.Option(..., "--scene", help="Scene YAML (robot, engine, layout, image size, max steps)."),
    policy: str = typer.Option("scripted", "--policy", help="Policy spec: scripted, random, zero, "
                               "lerobot:<dir or hub id>, remote:ws://host:port."),
    episodes: int = typer.Option(10, "--episodes", min=1, help="Number of episodes."),
    seed: int = typer.Option(0, "--seed", help="Episode i uses seed + i."),
    out: Path = typer.Option(Path("runs/latest"), "--out", help="Output directory (summary.json, videos)."),
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
    """Run a policy for N episodes and write summary.json (+ MP4s, + a LeRobot dataset)."""
    from simseam.runner.summary import build_summary, write_summary

    try:
        cfg, pol, rollout = _open_run(scene, policy, seed, _policy_kwargs(device, n_action_steps),
                                      need_images=record_dataset is not None)
    except SimseamError as exc:
        _fail(exc)
    recorder = None
    results = []
    try:
        info = rollout.scene
        if record_dataset is not None:
            from simseam.runner.dataset_recorder import LeRobotRecorder

            recorder = LeRobotRecorder(record_dataset, info, use_videos=videos)
        console.print(
            f"[bold]{info.robot}[/] on [bold]{info.engine}[/], layout [bold]{info.layout}[/], "
            f"policy [bold]{policy}[/], {info.control_mode.value} ({info.action_dim}-D actions), "
            f"{episodes} episode(s)"
        )
        results = _episode_loop(rollout, pol, episodes=episodes, seed=seed, out=out, video=video,
                                recorder=recorder, keep_failures=keep_failures)
    except SimseamError as exc:
        _fail(exc)
    finally:
        if recorder is not None:
            recorder.close()
        rollout.close()
        _close_policy(pol)
    config = {"scene_file": str(scene), "scene": cfg.model_dump(mode="json"), "policy": policy,
              "episodes": episodes, "seed": seed, "video": video,
              "record_dataset": str(record_dataset) if record_dataset else None}
    summary = build_summary(config, rollout.scene.to_json(), results)
    path = write_summary(out, summary)
    lo, hi = summary["success_rate_wilson95"]
    console.print(
        f"success {summary['n_success']}/{summary['n_episodes']} = {summary['success_rate']:.0%} "
        f"(Wilson 95% [{lo:.2f}, {hi:.2f}])  summary: {path}"
    )
    if recorder is not None:
        console.print(f"dataset: {recorder.episodes_written} episode(s), {recorder.frames_written} frames "
                      f"in {record_dataset}")


@app.command()
def collect(
    scene: Path = typer.Option(..., "--scene", help="Scene YAML."),
    policy: str = typer.Option("scripted", "--policy", help="Policy spec (default: the scripted expert)."),
    episodes: int = typer.Option(50, "--episodes", min=1, help="Episodes to run."),
    out: Path = typer.Option(..., "--out", help="New LeRobot dataset directory."),
    seed: int = typer.Option(0, "--seed", help="Episode i uses seed + i."),
    keep_failures: bool = typer.Option(False, "--keep-failures/--successes-only",
                                       help="Also record episodes that did not succeed."),
    videos: bool = typer.Option(True, "--videos/--images", help="Camera frames as AV1 video or PNG images."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace --out if it exists."),
) -> None:
    """Collect demonstrations as a LeRobot dataset (images, state, action, task, fps = control rate)."""
    from simseam.runner.dataset_recorder import LeRobotRecorder

    try:
        _, pol, rollout = _open_run(scene, policy, seed, {}, need_images=True)
    except SimseamError as exc:
        _fail(exc)
    try:
        with LeRobotRecorder(out, rollout.scene, use_videos=videos, overwrite=overwrite) as rec:
            info = rollout.scene
            console.print(f"collecting {episodes} episode(s) of [bold]{policy}[/] on [bold]{info.robot}[/] / "
                          f"[bold]{info.layout}[/] into {out}")
            results = _episode_loop(rollout, pol, episodes=episodes, seed=seed, out=None, video=False,
                                    recorder=rec, keep_failures=keep_failures)
    except SimseamError as exc:
        _fail(exc)
    finally:
        rollout.close()
        _close_policy(pol)
    n_ok = sum(r.success for r in results)
    console.print(f"dataset {out}: {rec.episodes_written} episode(s), {rec.frames_written} frames "
                  f"({n_ok}/{len(results)} episodes succeeded)")
    if rec.episodes_written == 0:
        err_console.print("[red]no episode was recorded[/] (all failed; --keep-failures records them anyway)")
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
