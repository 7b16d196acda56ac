"""The deploy loop: a ``SimAttachedHAL`` ticked in (scaled) real time, its sensors published
as ROS 2 topics (DDS, MCAP, Foxglove), ROS 2 commands mapped onto it.

Topics (``/<sensor>`` is the manifest sensor name):

=========================  =============================  ==============  =====================
topic                      type                           default rate    source
=========================  =============================  ==============  =====================
/clock                     rosgraph_msgs/Clock            every tick      ``hal.sim_time_ns()``
/joint_states, /tf         sensor_msgs/JointState, TF     50 Hz           ``hal.read_state()``: URDF
                                                                          joints; their link transforms
/odom, /tf                 nav_msgs/Odometry, TFMessage   50 Hz           ``hal.base_pose/twist``
/tf_static                 tf2_msgs/TFMessage             once (latched)  fixed joints, base_link, mounts
/robot_description         std_msgs/String                once (latched)  the URDF
/<cam>/image_raw           sensor_msgs/Image (rgb8)       10 Hz           ``hal.read_images()``
/<cam>/camera_info         sensor_msgs/CameraInfo         with the image  sensor intrinsics
/<depth>/points            sensor_msgs/PointCloud2        10 Hz           ``hal.read_depth_clouds()``
/scan (/<lidar>/scan)      sensor_msgs/LaserScan          10 Hz           ``hal.read_scan()``
=========================  =============================  ==============  =====================

Subscriptions: ``/cmd_vel`` (geometry_msgs/Twist: linear.x, linear.y,
angular.z -> BODY_TWIST), ``/joint_command`` (sensor_msgs/JointState, the
convention of Isaac Sim's ROS 2 bridge: positions by name -> JOINT_POSITION
for arm joints, gripper joints -> the gripper scalar), ``/estop``
(std_msgs/Bool: true latches the HAL's E-stop, false clears it). The HAL
holds a motion command for ``hold_time_s`` of sim time, then stops: a teleop
node must keep publishing (as ``ros2 topic pub -r 10`` does). Sinks that take
commands (the Foxglove server's client publishing) hand them to ``inject``:
they go through the very same path (hold time, E-stop latch, clamps).

The TF tree (``robot_model``): ``odom -> base_link`` (the kinematic base),
``base_link -> <URDF root>`` (identity, when named differently), every URDF
joint's ``parent -> child`` (fixed on ``/tf_static``, movable on ``/tf`` at the
``joint_states`` rate), and the sensor mounts.

Rates are in sim time (Hz; 0 turns a topic off; a rate at or above the
control rate publishes every tick). The loop runs at ``rtf`` x real time
(``rtf=0``: as fast as possible). On an in-process MuJoCo scene the cameras
and the depth sensor are rendered only on the ticks whose images are
published (rendering dominates a CPU step); scan and joint state are cheap and
always computed.
"""

from __future__ import annotations

import collections
import threading
import time
from dataclasses import dataclass, field
from typing import Any, Protocol

from simseam.ros2 import convert as cv
from simseam.ros2 import msgs as m
from simseam.seam import ConfigError, ControlMode, ObsRequest, SimseamError

_BURST_BYTES = 32 * 1024  # larger Image/PointCloud2 samples go out on DDS one per tick

DEFAULT_RATES: dict[str, float] = {
    "clock": float("inf"),
    "joint_states": 50.0,
    "odom": 50.0,
    "camera": 10.0,
    "depth": 10.0,
    "scan": 10.0,
}


def parse_rates(items: list[str] | None) -> dict[str, float]:
    """``["camera=5", "scan=0"]`` -> DEFAULT_RATES updated (Hz in sim time; 0 = off; ``max``/``inf``
    = every tick)."""
    rates = dict(DEFAULT_RATES)
    for item in items or []:
        key, sep, value = item.partition("=")
        key = key.strip()
        if not sep or key not in rates:
            raise ConfigError(f"--rate {item!r}: expected NAME=HZ with NAME one of {', '.join(rates)}")
        try:
            hz = float("inf") if value.strip().lower() in ("max", "inf", "tick") else float(value)
        except ValueError:
            raise ConfigError(f"--rate {item!r}: {value!r} is not a number") from None
        if hz < 0:
            raise ConfigError(f"--rate {item!r}: a rate cannot be negative")
        rates[key] = hz
    return rates


class Sink(Protocol):
    """A recorder or live viewer: receives every published message with its CDR bytes."""

    def write(self, topic: str, msg: Any, data: bytes, stamp_ns: int) -> None: ...

    def close(self) -> None: ...


@dataclass
class BridgeStats:
    ticks: int = 0
    sim_s: float = 0.0
    wall_s: float = 0.0
    published: dict[str, int] = field(default_factory=dict)
    commands: dict[str, int] = field(default_factory=dict)
    rejected: int = 0
    step_ms_max: float = 0.0

    @property
    def rtf(self) -> float:
        return self.sim_s / self.wall_s if self.wall_s > 0 else 0.0

    def to_json(self) -> dict:
        return {"ticks": self.ticks, "sim_s": self.sim_s, "wall_s": self.wall_s, "rtf": self.rtf,
                "published": dict(self.published), "commands": dict(self.commands), "rejected": self.rejected,
                "step_ms_max": self.step_ms_max}


class Ros2Bridge:
    """Drive ``hal`` and publish its sensors (see the module docstring).

    ``participant``: a ``dds.Participant`` (None: no DDS, e.g. ``simseam deploy`` without
    ``--ros2``); ``sinks``: MCAP recorder / Foxglove server; ``spec``: the robot's facts
    (default: ``hal.rollout.spec.robot``, a ``RobotFacts``).
    """

    def __init__(self, hal, *, spec=None, rates: dict[str, float] | None = None, rtf: float = 1.0,
                 participant=None, sinks: list[Sink] | tuple = (), joint_command_topic: str = "/joint_command",
                 render_on_demand: bool = True, log=None):
        if rtf < 0:
            raise ConfigError(f"rtf must be >= 0 (0: as fast as possible), got {rtf}")
        self.hal = hal
        self.spec = spec if spec is not None else hal.rollout.spec.robot
        self.rates = dict(DEFAULT_RATES, **(rates or {}))
        self.rtf = float(rtf)
        self.participant = participant
        self.sinks = list(sinks)
        self.stats = BridgeStats()
        self._log = log or (lambda msg: None)
        self._warned: set[str] = set()
        self._subs = None
        self._joint_topic = joint_command_topic
        self._render_on_demand = render_on_demand
        self._cams = {s.feature_key: s for s in self.spec.sensors_of("rgb")}
        self._depths = {s.name: s for s in self.spec.sensors_of("depth")}
        lidars = self.spec.sensors_of("lidar_2d")
        self._lidar = lidars[0] if lidars else None
        self._has_base = self.spec.base is not None
        self._height = self.spec.base.height if self._has_base else 0.0
        self._next: dict[str, int] = {}
        self._jmap = cv.JointCommandMap.from_spec(self.spec)
        self._started = False
        self._injected: list[tuple[str, Any]] = []
        self._dds_queue: collections.deque = collections.deque()
        self._inject_lock = threading.Lock()
        self._model = None
        try:
            from simseam.ros2.robot_model import RobotModel

            self._model = RobotModel(self.spec)
        except SimseamError as exc:
            self._log(f"no TF tree / robot_description for {self.spec.name}: {exc}")

    @property
    def command_topics(self) -> dict[str, type]:
        """The topics this bridge obeys, with their message classes (for sinks that take commands)."""
        return {"/cmd_vel": m.Twist, self._joint_topic: m.JointState, "/estop": m.Bool}

    def inject(self, topic: str, msg) -> None:
        """A command from outside DDS (e.g. a Foxglove client's publish); thread-safe; applied on the next
        tick exactly like the same message arriving over DDS."""
        if topic not in self.command_topics:
            raise ConfigError(f"{topic!r} is not a command topic ({', '.join(self.command_topics)})")
        with self._inject_lock:
            self._injected.append((topic, msg))

    # ------------------------------------------------------------------ set-up
    def start(self) -> None:
        if self._started:
            return
        if not getattr(self.hal, "connected", False):
            self.hal.connect()
        self._dt_ns = int(round(1e9 / float(self.hal.control_hz)))
        if self.participant is not None:
            from simseam.ros2.dds import CommandSubscriber

            self._subs = CommandSubscriber(self.participant, joint_command=self._joint_topic)
        for sink in self.sinks:
            if hasattr(sink, "accept_commands"):
                sink.accept_commands(self.command_topics, self.inject)
        now = self.hal.sim_time_ns()
        self._next = {k: now for k in self.rates}
        tf_static = cv.static_transforms(self.spec, now)
        if self._model is not None:
            tf_static.transforms[:0] = self._model.static_transforms(now)
            self._emit("/robot_description", self._model.description_msg(), now, "latched")
        if tf_static.transforms:
            self._emit("/tf_static", tf_static, now, "tf_static")
        self._started = True
        self._publish(now)  # the state at connect, so subscribers see the robot before the first tick

    # ------------------------------------------------------------------ publish
    def _emit(self, topic: str, msg, stamp_ns: int, qos_kind: str) -> None:
        if self.participant is not None:
            if isinstance(msg, (m.Image, m.PointCloud2)) and len(msg.data) > _BURST_BYTES:
                # one large sample per tick on DDS: a burst of several (3 images + a cloud, ~0.8 MB) overflows a
                # receiver's default UDP buffer and best-effort fragments are lost (measured with rclpy/Fast DDS)
                self._dds_queue.append((topic, msg, qos_kind))
            else:
                self.participant.writer(topic, type(msg), qos_kind).write(msg)
        if self.sinks:
            data = msg.serialize()
            for sink in self.sinks:
                sink.write(topic, msg, data, stamp_ns)
        self.stats.published[topic] = self.stats.published.get(topic, 0) + 1

    def _due(self, key: str, now: int) -> bool:
        hz = self.rates.get(key, 0.0)
        if hz <= 0:
            return False
        if hz == float("inf"):
            return True
        if now + self._dt_ns // 2 < self._next[key]:  # half a tick of slack: 50 Hz on a 50 Hz loop is every tick
            return False
        period = int(round(1e9 / hz))
        self._next[key] += period
        if self._next[key] <= now:  # fell behind (first call, a pause): restart the schedule from now
            self._next[key] = now + period
        return True

    def _will_be_due(self, key: str, now: int) -> bool:
        hz = self.rates.get(key, 0.0)
        return hz > 0 and (hz == float("inf") or now + self._dt_ns // 2 >= self._next[key])

    def _flush_dds(self) -> None:
        """Write the oldest queued large sample (its stamp stays its capture time); drop samples that a newer
        one on the same topic already superseded."""
        q = self._dds_queue
        while q and any(t == q[0][0] for t, _, _ in list(q)[1:]):
            q.popleft()
        if q and self.participant is not None:
            topic, msg, kind = q.popleft()
            self.participant.writer(topic, type(msg), kind).write(msg)

    def _publish(self, now: int) -> None:
        from simseam.ros2.dds import CLOCK, SENSOR, STATE, TF

        self._flush_dds()
        hal = self.hal
        if self._due("clock", now):
            self._emit("/clock", cv.clock_msg(now), now, CLOCK)
        if self._due("joint_states", now):
            js = hal.read_state()
            if self._model is not None:
                self._emit("/joint_states", self._model.joint_state_msg(js.names, js.positions, js.velocities,
                                                                        js.stamp_ns), js.stamp_ns, STATE)
                moving = self._model.moving_transforms(js.names, js.positions, js.stamp_ns)
                if moving:
                    self._emit("/tf", m.TFMessage(moving), js.stamp_ns, TF)
            else:
                self._emit("/joint_states", cv.joint_state_msg(js.names, js.positions, js.velocities, js.stamp_ns),
                           js.stamp_ns, STATE)
        if self._has_base and self._due("odom", now):
            pose = hal.base_pose()
            if pose is not None:
                odom, tf = cv.odom_msgs(pose, hal.base_twist(), now, "base_link", self._height)
                self._emit("/odom", odom, now, STATE)
                self._emit("/tf", tf, now, TF)
        if self._cams and self._due("camera", now):
            for key, img in hal.read_images().items():
                s = self._cams.get(key)
                if s is None:
                    continue
                frame = cv.optical_frame(s)
                self._emit(f"/{s.name}/image_raw", cv.image_msg(img, now, frame), now, SENSOR)
                h, w = img.shape[:2]
                self._emit(f"/{s.name}/camera_info", cv.camera_info_msg(w, h, s.fovy_deg, now, frame), now, SENSOR)
        if self._depths and self._due("depth", now):
            for name, pts in hal.read_depth_clouds().items():
                if name in self._depths:
                    self._emit(f"/{name}/points", cv.pointcloud_msg(pts, now, self.spec.base_link), now, SENSOR)
        if self._lidar is not None and self._due("scan", now):
            ranges = hal.read_scan()
            if ranges is not None:
                s = self._lidar
                hz = self.rates["scan"]
                scan_time = 1.0 / min(hz, float(hal.control_hz))
                msg = cv.scan_msg(ranges, s, now, cv.scan_frame(s, self.spec.base_link), scan_time)
                self._emit("/scan", msg, now, SENSOR)

    # ----------------------------------------------------------------- commands
    def _reject(self, what: str, exc: Exception) -> None:
        self.stats.rejected += 1
        if what not in self._warned:
            self._warned.add(what)
            self._log(f"ignoring {what}: {exc}")

    def _count(self, key: str) -> None:
        self.stats.commands[key] = self.stats.commands.get(key, 0) + 1

    def _poll_commands(self):
        from simseam.ros2.dds import Commands

        cmds = self._subs.poll() if self._subs is not None else Commands()
        with self._inject_lock:
            injected, self._injected = self._injected, []
        for topic, msg in injected:  # after DDS's: the newest wins, E-stop events keep their order
            if topic == "/estop":
                cmds.estop = [*(cmds.estop or []), bool(msg.data)]
            elif topic == "/cmd_vel":
                cmds.twist = msg
            else:
                cmds.joint = msg
        return cmds

    def _apply_commands(self) -> None:
        if self._subs is None and not self._injected:
            return
        cmds = self._poll_commands()
        hal = self.hal
        if cmds.estop:
            for engaged in cmds.estop:
                hal.estop(engaged)
                self._count("/estop")
        if cmds.twist is not None:
            t = cmds.twist
            try:
                hal.send_action([t.linear.x, t.linear.y, t.angular.z], ControlMode.BODY_TWIST)
                self._count("/cmd_vel")
            except (SimseamError, ValueError) as exc:
                self._reject("/cmd_vel", exc)
        if cmds.joint is not None:
            try:
                js = hal.read_state()
                measured = dict(zip(js.names, (float(v) for v in js.positions)))
                arm, grip, unknown = self._jmap.split(cmds.joint, measured)
                if unknown:
                    self._reject(f"{self._joint_topic} names {unknown}", ValueError("not arm or gripper joints"))
                if arm is not None:
                    hal.send_action(arm, ControlMode.JOINT_POSITION)
                if grip is not None:
                    hal.send_action([grip], ControlMode.GRIPPER)
                self._count(self._joint_topic)
            except (SimseamError, ValueError) as exc:
                self._reject(self._joint_topic, exc)

    # --------------------------------------------------------------------- loop
    def _gate_rendering(self, next_now: int) -> None:
        """Ask the coming tick for camera images / depth clouds only when their topics will be
        published (an observation request: honoured in-process and through a sidecar alike)."""
        if not self._render_on_demand:
            return
        cams = bool(self._cams) and self._will_be_due("camera", next_now)
        depth = bool(self._depths) and self._will_be_due("depth", next_now)
        self.hal.observe(ObsRequest(images=None if cams else frozenset(), depth=depth))

    def step(self) -> None:
        """One control tick: commands in, ``hal.tick()``, due topics out."""
        if not self._started:
            self.start()
        t0 = time.perf_counter()
        self._apply_commands()
        self._gate_rendering(self.hal.sim_time_ns() + self._dt_ns)
        self.hal.tick()
        self._publish(self.hal.sim_time_ns())
        self.stats.ticks += 1
        self.stats.step_ms_max = max(self.stats.step_ms_max, (time.perf_counter() - t0) * 1e3)

    def run(self, duration_s: float | None = None, stop: threading.Event | None = None) -> BridgeStats:
        """Tick until ``duration_s`` of sim time has passed (None: forever), ``stop`` is set, or
        KeyboardInterrupt (which is re-raised after the stats are final)."""
        self.start()
        sim0 = self.hal.sim_time_ns()
        wall0 = time.perf_counter()
        end_ns = None if duration_s is None else sim0 + int(round(duration_s * 1e9))
        anchor_wall, anchor_sim = wall0, sim0
        try:
            while (end_ns is None or self.hal.sim_time_ns() < end_ns) and not (stop is not None and stop.is_set()):
                self.step()
                if self.rtf > 0:
                    target = anchor_wall + (self.hal.sim_time_ns() - anchor_sim) * 1e-9 / self.rtf
                    delay = target - time.perf_counter()
                    if delay > 0:
                        if stop is not None:
                            stop.wait(delay)
                        else:
                            time.sleep(delay)
                    elif delay < -1.0:  # more than a second behind: do not sprint to catch up
                        anchor_wall, anchor_sim = time.perf_counter(), self.hal.sim_time_ns()
        finally:
            self.stats.sim_s = (self.hal.sim_time_ns() - sim0) * 1e-9
            self.stats.wall_s = time.perf_counter() - wall0
        return self.stats

    def close(self) -> None:
        """Close the sinks and the participant (the HAL belongs to the caller)."""
        for sink in self.sinks:
            try:
                sink.close()
            except Exception as exc:  # pragma: no cover
                self._log(f"closing {type(sink).__name__}: {exc}")
        self.sinks = []
        if self.participant is not None:
            self.participant.close()
            self.participant = None
