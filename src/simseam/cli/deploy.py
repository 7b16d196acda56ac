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

    check_seed(seed)
    with _stop_on_signals() as stop:
        live = _Live()
        try:
            with _exit_on_error():
                _start(live, scene, control_mode, rate, record, overwrite, foxglove, foxglove_port, ros2, domain_id,
                       seed, hold_time, rtf, joint_command_topic)
            info = live.rollout.spec
            # the line tests and scripts wait for: the robot is live (first state published)
            console.print(f"{escape(info.describe())} at {info.control_hz:g} Hz, rtf {rtf:g}"
                          + (f", {duration:g} s" if duration is not None else ", Ctrl-C to stop"))
            with _exit_on_error(), live_status(console, live.bridge, info.control_hz):
                stats = live.bridge.run(duration, stop=stop)
            console.print(f"stopped: {stats.ticks} ticks, {stats.sim_s:.2f} s sim in {stats.wall_s:.2f} s wall "
                          f"(rtf {stats.rtf:.3f}), {sum(stats.published.values())} messages"
                          + (f", recording {record}" if record is not None else ""))
            if stats_json is not None:
                stats_json.write_text(json.dumps(stats.to_json(), indent=2))
        finally:
            live.close()


@contextlib.contextmanager
def _stop_on_signals():
    """An event set by Ctrl-C or SIGTERM while the block runs (the handlers before are restored after)."""
    stop = threading.Event()
    handlers = {}
    for sig in (signal.SIGINT, signal.SIGTERM):
        try:
            handlers[sig] = signal.signal(sig, lambda signum, frame: stop.set())
        except ValueError:  # not the main thread (e.g. called from a test runner thread)
            pass
    try:
        yield stop
    finally:
        for sig, old in handlers.items():
            signal.signal(sig, old)


@contextlib.contextmanager
def _exit_on_error():
    """A ``SimseamError`` in the block: its one-line error, exit code 2."""
    try:
        yield
    except SimseamError as exc:
        err_console.print(f"error: {type(exc).__name__}: {exc}", style="bold red", highlight=False, markup=False)
        raise typer.Exit(code=2)


class _Live:
    """What a deploy opened: the rollout, the HAL over it, the bridge, and the sinks not yet handed to the
    bridge (it owns them once made); ``close`` releases whatever was opened, the bridge first."""

    def __init__(self):
        self.rollout = self.hal = self.bridge = None
        self.sinks: list = []

    def close(self) -> None:
        if self.bridge is not None:
            self.bridge.close()
        for sink in self.sinks:
            sink.close()
        if self.hal is not None:
            self.hal.close()
        elif self.rollout is not None:
            self.rollout.close()


def _start(live: _Live, scene: Path, control_mode: str | None, rate: list[str] | None, record: Path | None,
           overwrite: bool, foxglove: bool, foxglove_port: int, ros2: bool, domain_id: int | None, seed: int,
           hold_time: float, rtf: float, joint_command_topic: str) -> None:
    """Build the scene, its HAL and the bridge with its sinks into ``live``, and start the bridge."""
    from simseam.hal.sim_attached import SimAttachedHAL
    from simseam.ros2.bridge import Ros2Bridge, parse_rates
    from simseam.runner.scene_config import build_rollout

    rates = parse_rates(rate)
    cfg, base_dir = _scene_config(scene, control_mode)
    _open_sinks(live.sinks, record, overwrite, foxglove, foxglove_port)
    participant = _participant(domain_id) if ros2 else None
    with console.status("building the scene"):
        live.rollout = build_rollout(cfg, base_dir, seed=seed)
    live.hal = SimAttachedHAL.attach(live.rollout, target="sim", hold_time_s=hold_time, seed=seed)
    live.bridge = Ros2Bridge(live.hal, rates=rates, rtf=rtf, participant=participant, sinks=live.sinks,
                             joint_command_topic=joint_command_topic,
                             log=lambda msg: err_console.print(f"warning: {msg}", style="yellow", markup=False,
                                                               highlight=False))
    live.sinks = []  # the bridge owns them now
    live.bridge.start()


def _scene_config(scene: Path, control_mode: str | None):
    """The scene file's config with the control mode deploy drives (``--control-mode``, else the file's, else
    joint_position so /joint_command works), and its directory."""
    from simseam.runner.scene_config import load_scene_config

    cfg, base_dir = load_scene_config(scene)
    mode = control_mode or cfg.control_mode or "joint_position"
    if mode not in ("joint_position", "cartesian_delta"):
        raise typer.BadParameter(f"--control-mode {mode!r}: expected joint_position or cartesian_delta")
    return cfg.model_copy(update={"control_mode": mode}), base_dir


def _open_sinks(sinks: list, record: Path | None, overwrite: bool, foxglove: bool, foxglove_port: int) -> None:
    """The MCAP recorder and the Foxglove server asked for, appended to ``sinks`` as each opens."""
    if record is not None:
        from simseam.ros2.record import McapRecorder

        sinks.append(McapRecorder(record, overwrite=overwrite))
    if foxglove:
        from simseam.ros2.record import FoxgloveServer

        fg = FoxgloveServer(port=foxglove_port)
        sinks.append(fg)
        console.print(f"foxglove: ws://127.0.0.1:{fg.port}")


def _participant(domain_id: int | None):
    """This process's DDS participant (ROS 2), announced."""
    from simseam.ros2.dds import Participant, discovery_summary

    participant = Participant(domain_id)
    console.print(f"ROS 2: node /{participant.node_name}, DDS domain {participant.domain_id}, "
                  f"discovery: {discovery_summary()}")
    return participant


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
