"""``simseam`` command line: run | deploy | robots | sidecar | isaac | doctor."""

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
from simseam.seam import SimseamError

app = typer.Typer(add_completion=False, no_args_is_help=True, help="Run robot policies in simulation.")
robots_app = typer.Typer(no_args_is_help=True, help="Inspect and check robot manifests.")
app.add_typer(robots_app, name="robots")
sidecar_app = typer.Typer(no_args_is_help=True, help="Out-of-process engines.")
app.add_typer(sidecar_app, name="sidecar")
app.add_typer(isaac_app, name="isaac")
app.command("doctor")(doctor)
app.command("deploy")(deploy)
console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)


def _fail(exc: SimseamError) -> None:
    err_console.print(f"[bold red]error:[/] {type(exc).__name__}: {exc}", highlight=False, markup=True)
    raise typer.Exit(code=2)


@app.command()
def run(
    scene: Path = typer.Option(..., "--scene", help="Scene YAML (robot, engine, layout, image size, max steps)."),
    policy: str = typer.Option("scripted", "--policy", help="Policy name: scripted, random or zero."),
    episodes: int = typer.Option(10, "--episodes", min=1, help="Number of episodes."),
    seed: int = typer.Option(0, "--seed", help="Episode i uses seed + i."),
    out: Path = typer.Option(Path("runs/latest"), "--out", help="Output directory (summary.json, videos)."),
    video: bool = typer.Option(False, "--video/--no-video", help="Write one MP4 per episode (first RGB camera)."),
) -> None:
    """Run a policy for N episodes and write summary.json (+ MP4s)."""
    from simseam.policies.base import make_policy
    from simseam.runner.episodes import run_episode
    from simseam.runner.scene_config import build_rollout, load_scene_config
    from simseam.runner.summary import build_summary, write_summary

    from simseam.runner.episodes import EpisodeResult
    from simseam.seam import SidecarError

    try:
        cfg, base_dir = load_scene_config(scene)
        pol = make_policy(policy)
        with console.status("building the scene") as status:
            rollout = build_rollout(cfg, base_dir, privileged=pol.requires_privileged,
                                    render_images=pol.uses_images, seed=seed,
                                    progress=lambda stage: status.update(f"sidecar: {stage}"))
    except SimseamError as exc:
        _fail(exc)
    results = []
    try:
        info = rollout.scene
        console.print(
            f"[bold]{info.robot}[/] on [bold]{info.engine}[/], layout [bold]{info.layout}[/], "
            f"policy [bold]{policy}[/], {info.control_mode.value} ({info.action_dim}-D actions), "
            f"{episodes} episode(s)"
        )
        with Progress(TextColumn("{task.description}"), BarColumn(), MofNCompleteColumn(), TimeElapsedColumn(),
                      console=console, transient=True) as progress:
            for i in range(episodes):
                task = progress.add_task(f"episode {i}", total=rollout.task.max_steps)
                try:
                    res = run_episode(rollout, pol, index=i, seed=seed + i,
                                      video_path=out / f"episode_{i:03d}.mp4" if video else None,
                                      on_step=lambda n, t=task: progress.update(t, completed=n))
                except SidecarError as exc:  # the engine process died or hung: count it, start a fresh one
                    res = EpisodeResult(index=i, seed=seed + i, success=False, steps=0, reward=0.0,
                                        error=f"{type(exc).__name__}: {exc}")
                    err_console.print(f"[red]episode {i}: {res.error}[/]; restarting the sidecar", markup=True,
                                      highlight=False)
                    rollout.restart()
                progress.remove_task(task)
                results.append(res)
                step_ms = res.to_json()["step_latency_ms"]["mean"]  # None when the episode took no step
                mark = "[green]success[/]" if res.success else "[red]failure[/]"
                console.print(
                    f"episode {i:3d}  seed {res.seed:5d}  {mark}  steps {res.steps:4d}  "
                    f"reward {res.reward:6.2f}  step " + (f"{step_ms:.2f} ms" if step_ms is not None else "-")
                    + (f"  video {res.video}" if res.video else "")
                )
    except SimseamError as exc:
        _fail(exc)
    finally:
        rollout.close()
    config = {"scene_file": str(scene), "scene": cfg.model_dump(mode="json"), "policy": policy,
              "episodes": episodes, "seed": seed, "video": video}
    summary = build_summary(config, rollout.scene.to_json(), results)
    path = write_summary(out, summary)
    lo, hi = summary["success_rate_wilson95"]
    console.print(
        f"success {summary['n_success']}/{summary['n_episodes']} = {summary['success_rate']:.0%} "
        f"(Wilson 95% [{lo:.2f}, {hi:.2f}])  summary: {path}"
    )


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
