"""ROS 2 over DDS with Cyclone DDS's Python binding (no ROS installation needed).

ROS 2 conventions followed here (what rmw_cyclonedds does):

- topic ``/foo/bar`` is the DDS topic ``rt/foo/bar``; the DDS type name is
  ``<pkg>::msg::dds_::<Type>_`` (see ``msgs``); samples are XCDR1 little-endian;
- the domain is ``ROS_DOMAIN_ID`` (default 0);
- QoS (REP-2003 and the rclcpp presets): sensor data (images, camera info,
  point clouds, scans) best effort, keep last 5; ``/clock`` best effort, keep
  last 1; ``/tf`` reliable, keep last 100; ``/tf_static`` reliable, transient
  local, keep last 1; state topics (``/joint_states``, ``/odom``) reliable, keep
  last 10. Subscriptions (``/cmd_vel``, the joint command, ``/estop``) are
  reliable, keep last 10: they match ``ros2 topic pub`` and rclcpp's default
  publishers.

Network: unless ``CYCLONEDDS_URI`` is set, the participant is configured for
the loopback interface only, multicast off, with 127.0.0.1 as its unicast
discovery peer (simseam makes no network traffic leave the machine by default).
ROS 2 nodes on the same machine discover it when they run with the same
``CYCLONEDDS_URI`` (``loopback_config()`` prints it); set your own
``CYCLONEDDS_URI`` to publish on a real network.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from simseam.ros2 import msgs as m
from simseam.seam import BackendUnavailableError, ConfigError

LOOPBACK_XML = (
    "<CycloneDDS><Domain Id=\"any\"><General><Interfaces><NetworkInterface name=\"lo\"/></Interfaces>"
    "<AllowMulticast>false</AllowMulticast></General><Discovery><ParticipantIndex>auto</ParticipantIndex>"
    "<MaxAutoParticipantIndex>64</MaxAutoParticipantIndex><Peers><Peer address=\"127.0.0.1\"/></Peers>"
    "</Discovery></Domain></CycloneDDS>"
)


def loopback_config() -> str:
    """A ``CYCLONEDDS_URI`` value that keeps DDS on 127.0.0.1 (multicast off, unicast discovery)."""
    return LOOPBACK_XML


def domain_id_from_env(default: int = 0) -> int:
    raw = os.environ.get("ROS_DOMAIN_ID", "").strip()
    if not raw:
        return default
    try:
        value = int(raw)
    except ValueError:
        raise ConfigError(f"ROS_DOMAIN_ID={raw!r} is not an integer (0..232)") from None
    if not 0 <= value <= 232:
        raise ConfigError(f"ROS_DOMAIN_ID={value} is outside 0..232")
    return value


def dds_topic(name: str) -> str:
    """``/cmd_vel`` -> ``rt/cmd_vel`` (ROS 2's topic prefix)."""
    return "rt/" + name.lstrip("/")


# QoS kinds of the topics this bridge uses
SENSOR, CLOCK, TF, TF_STATIC, STATE, COMMAND = "sensor", "clock", "tf", "tf_static", "state", "command"


def qos(kind: str):
    from cyclonedds.core import Policy, Qos
    from cyclonedds.util import duration

    reliable = Policy.Reliability.Reliable(duration(milliseconds=100))
    if kind == SENSOR:
        return Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(5), Policy.Durability.Volatile)
    if kind == CLOCK:
        return Qos(Policy.Reliability.BestEffort, Policy.History.KeepLast(1), Policy.Durability.Volatile)
    if kind == TF:
        return Qos(reliable, Policy.History.KeepLast(100), Policy.Durability.Volatile)
    if kind == TF_STATIC:
        return Qos(reliable, Policy.History.KeepLast(1), Policy.Durability.TransientLocal)
    if kind in (STATE, COMMAND):
        return Qos(reliable, Policy.History.KeepLast(10), Policy.Durability.Volatile)
    raise ValueError(f"unknown QoS kind {kind!r}")


def _import_cyclone():
    try:
        import cyclonedds.domain  # noqa: F401
    except ImportError as exc:
        raise BackendUnavailableError(
            f"ROS 2 over DDS needs the cyclonedds package ({exc}); install it with: pip install 'simseam[ros2]'"
        ) from None


class Participant:
    """One DDS participant on a ROS domain, with writers and readers made on demand."""

    def __init__(self, domain_id: int | None = None, *, config: str | None = None):
        _import_cyclone()
        from cyclonedds.domain import Domain, DomainParticipant

        self.domain_id = domain_id_from_env() if domain_id is None else int(domain_id)
        if config is None and not os.environ.get("CYCLONEDDS_URI"):
            config = LOOPBACK_XML
        # A Domain object carries the configuration; it must outlive the participant.
        self._domain = Domain(self.domain_id, config) if config else None
        self.dp = DomainParticipant(self.domain_id)
        self._topics: dict[str, object] = {}
        self._writers: dict[str, object] = {}
        self._readers: list[object] = []

    def _topic(self, name: str, cls: type):
        from cyclonedds.topic import Topic

        key = dds_topic(name)
        if key not in self._topics:
            self._topics[key] = Topic(self.dp, key, cls)
        return self._topics[key]

    def writer(self, name: str, cls: type, kind: str):
        from cyclonedds.pub import DataWriter

        if name not in self._writers:
            self._writers[name] = DataWriter(self.dp, self._topic(name, cls), qos=qos(kind))
        return self._writers[name]

    def reader(self, name: str, cls: type, kind: str):
        from cyclonedds.sub import DataReader

        r = DataReader(self.dp, self._topic(name, cls), qos=qos(kind))
        self._readers.append(r)
        return r

    def close(self) -> None:
        """Delete readers, writers, topics and the participant now (DDS says goodbye to its peers)."""
        entities = [*self._readers, *self._writers.values(), *self._topics.values(), self.dp]
        self._readers, self._writers, self._topics, self.dp = [], {}, {}, None
        for entity in entities:
            if entity is not None:
                try:
                    entity.__del__()  # cyclonedds deletes an entity in __del__ and unregisters it (idempotent)
                except Exception:  # pragma: no cover - best effort at shutdown
                    pass
        self._domain = None


@dataclass
class Commands:
    """What arrived on the command topics since the last poll (the latest of each)."""

    twist: m.Twist | None = None
    joint: m.JointState | None = None
    estop: list[bool] | None = None


class CommandSubscriber:
    """Non-blocking subscriptions to ``/cmd_vel`` (geometry_msgs/Twist), the joint command
    topic (sensor_msgs/JointState) and ``/estop`` (std_msgs/Bool)."""

    def __init__(self, participant: Participant, *, cmd_vel: str = "/cmd_vel",
                 joint_command: str = "/joint_command", estop: str = "/estop"):
        self._twist = participant.reader(cmd_vel, m.Twist, COMMAND) if cmd_vel else None
        self._joint = participant.reader(joint_command, m.JointState, COMMAND) if joint_command else None
        self._estop = participant.reader(estop, m.Bool, COMMAND) if estop else None

    @staticmethod
    def _take(reader, cls: type) -> list:
        if reader is None:
            return []
        return [s for s in reader.take(N=64) if isinstance(s, cls)]  # skips dispose/unregister notices

    def poll(self) -> Commands:
        out = Commands()
        twists = self._take(self._twist, m.Twist)
        if twists:
            out.twist = twists[-1]
        joints = self._take(self._joint, m.JointState)
        if joints:
            out.joint = joints[-1]
        stops = self._take(self._estop, m.Bool)
        if stops:
            out.estop = [bool(s.data) for s in stops]
        return out
