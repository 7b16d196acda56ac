"""``simseam deploy``: run a scene as a live robot (real-time paced), optionally on ROS 2."""

from __future__ import annotations

import contextlib
import json
import signal
import threading
import time
from pathlib import Path

import typer
from rich.console import Console
from rich.markup import escape

from simseam.seam import SimseamError

console = Console(soft_wrap=True)
err_console = Console(stderr=True, soft_wrap=True)


def deploy(
    scene: Path = typer.Option(..., "--scene", help="Scene YAML (robot, engine, task, control rate)."),
    ros2: bool = typer.Option(False, "--ros2/--no-ros2", help="Publish and subscribe ROS 2 topics over DDS."),
    record: Path = typer.Option(None, "--record", help="Write the topics to this MCAP file (ROS 2 schemas)."),
    overwrite: bool = typer.Option(False, "--overwrite", help="Replace the --record file if it exists."),
    foxglove: bool = typer.Option(False, "--foxglove/--no-foxglove",
                                  help="Serve the topics live to Foxglove on 127.0.0.1."),
    foxglove_port: int = typer.Option(8765, "--foxglove-port", min=0, max=65535,
                                      help="Foxglove WebSocket port (0: any free)."),
    duration: float = typer.Option(None, "--duration", min=0.0, help="Stop after S seconds of sim time "
                                   "(default: run until Ctrl-C)."),
    rtf: float = typer.Option(1.0, "--rtf", min=0.0, help="Real-time factor (0: as fast as possible)."),
    rate: list[str] = typer.Option(None, "--rate", help="Topic rate in sim Hz, NAME=HZ (repeatable): clock, "
                                   "joint_states, odom, camera, depth, scan; 0 turns one off, 'max' every tick."),
    domain_id: int = typer.Option(None, "--domain-id", min=0, max=232,
                                  help="ROS 2 domain (default: $ROS_DOMAIN_ID or 0)."),
    control_mode: str = typer.Option(None, "--control-mode", help="joint_position or cartesian_delta (default: "
                                     "the scene file's, else joint_position so /joint_command works)."),
    joint_command_topic: str = typer.Option("/joint_command", "--joint-command-topic",
                                            help="sensor_msgs/JointState topic for arm/gripper targets."),
    hold_time: float = typer.Option(0.5, "--hold-time", min=0.01, help="A motion command is obeyed for this "
                                    "long (sim s) unless repeated; then the robot holds."),
    seed: int = typer.Option(0, "--seed", help="Scene seed."),
    stats_json: Path = typer.Option(None, "--stats-json", help="Write the loop statistics here at exit."),
) -> None:
    """Run a scene as a live robot: real-time loop, ROS 2 topics, MCAP recording, Foxglove.

    Ctrl-C (or SIGTERM) stops cleanly: the recording is finalized and every
    resource released.
    """
    from simseam.cli.common import check_seed
    from simseam.hal.sim_attached import SimAttachedHAL
    from simseam.ros2.bridge import Ros2Bridge, parse_rates
    from simseam.runner.scene_config import (
        build_rollout,
        load_scene_config,
    )

    check_seed(seed)
    stop = threading.Event()
    handlers = {}

    def _stop(signum, frame):
        stop.set()

    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            handlers[sig] = signal.signal(sig, _stop)
        except ValueError:  # not the main thread (e.g. called from a test runner thread)
            pass
    rollout = hal = bridge = None
    sinks = []
    try:
        try:
            rates = parse_rates(rate)
            cfg, base_dir = load_scene_config(scene)
            mode = control_mode or cfg.control_mode or "joint_position"
            if mode not in ("joint_position", "cartesian_delta"):
                raise typer.BadParameter(f"--control-mode {mode!r}: expected joint_position or cartesian_delta")
            cfg = cfg.model_copy(update={"control_mode": mode})
            if record is not None:
                from simseam.ros2.record import McapRecorder

                sinks.append(McapRecorder(record, overwrite=overwrite))
            if foxglove:
                from simseam.ros2.record import FoxgloveServer

                fg = FoxgloveServer(port=foxglove_port)
                sinks.append(fg)
                console.print(f"foxglove: ws://127.0.0.1:{fg.port}")
            participant = None
            if ros2:
                from simseam.ros2.dds import Participant, discovery_summary

                participant = Participant(domain_id)
                console.print(f"ROS 2: node /{participant.node_name}, DDS domain {participant.domain_id}, "
                              f"discovery: {discovery_summary()}")
            with console.status("building the scene"):
                rollout = build_rollout(cfg, base_dir, seed=seed)
            hal = SimAttachedHAL.attach(rollout, target="sim", hold_time_s=hold_time, seed=seed)
            bridge = Ros2Bridge(hal, rates=rates, rtf=rtf, participant=participant, sinks=sinks,
                                joint_command_topic=joint_command_topic,
                                log=lambda msg: err_console.print(f"warning: {msg}", style="yellow", markup=False,
                                                                  highlight=False))
            sinks = []  # the bridge owns them now
            bridge.start()
        except SimseamError as exc:
            err_console.print(f"error: {type(exc).__name__}: {exc}", style="bold red", highlight=False, markup=False)
            raise typer.Exit(code=2)
        info = rollout.spec
        # the line tests and scripts wait for: the robot is live (first state published)
        console.print(f"{escape(info.describe())} at {info.control_hz:g} Hz, rtf {rtf:g}"
                      + (f", {duration:g} s" if duration is not None else ", Ctrl-C to stop"))
        try:
            with live_status(console, bridge, info.control_hz):
                stats = bridge.run(duration, stop=stop)
        except SimseamError as exc:
            err_console.print(f"error: {type(exc).__name__}: {exc}", style="bold red", highlight=False, markup=False)
            raise typer.Exit(code=2)
        console.print(f"stopped: {stats.ticks} ticks, {stats.sim_s:.2f} s sim in {stats.wall_s:.2f} s wall "
                      f"(rtf {stats.rtf:.3f}), {sum(stats.published.values())} messages"
                      + (f", recording {record}" if record is not None else ""))
        if stats_json is not None:
            stats_json.write_text(json.dumps(stats.to_json(), indent=2))
    finally:
        if bridge is not None:
            bridge.close()
        for sink in sinks:
            sink.close()
        if hal is not None:
            hal.close()
        elif rollout is not None:
            rollout.close()
        for sig, old in handlers.items():
            signal.signal(sig, old)


def status_line(stats, control_hz: float, wall_s: float) -> str:
    """The live status of a deploy: sim time, real-time factor, messages out, commands in (and rejected)."""
    sim_s = stats.ticks / control_hz
    rtf = f"rtf {sim_s / wall_s:.2f}" if wall_s > 0 else "rtf -"
    rejected = f", {stats.rejected} rejected" if stats.rejected else ""
    return (f"live: {sim_s:.1f} s sim, {rtf}, {sum(list(stats.published.values()))} messages out, "
            f"{sum(list(stats.commands.values()))} commands in{rejected}")


@contextlib.contextmanager
def live_status(out: Console, bridge, control_hz: float, every_s: float = 0.5):
    """While the bridge runs: its ``status_line`` on ``out``, refreshed every ``every_s`` (a terminal only)."""
    done = threading.Event()
    t0 = time.perf_counter()
    with out.status(status_line(bridge.stats, control_hz, 0.0)) as status:
        def refresh():
            while not done.wait(every_s):
                try:
                    status.update(status_line(bridge.stats, control_hz, time.perf_counter() - t0))
                except RuntimeError:  # a topic's first message grew the counts mid-read: the next refresh
                    pass

        thread = threading.Thread(target=refresh, name="deploy-status", daemon=True)
        thread.start()
        try:
            yield
        finally:
            done.set()
            thread.join()
