"""ROS 2 over DDS with Cyclone DDS's Python binding (no ROS installation needed).

ROS 2 conventions followed here (what rmw_cyclonedds does):

- topic ``/foo/bar`` is the DDS topic ``rt/foo/bar``; the DDS type name is
  ``<pkg>::msg::dds_::<Type>_`` (see ``msgs``); samples are XCDR1 little-endian;
- the domain is ``ROS_DOMAIN_ID`` (default 0);
- QoS (REP-2003 and the rclcpp presets): sensor data (images, camera info,
  point clouds, scans) best effort, keep last 5; ``/clock`` best effort, keep
  last 1; ``/tf`` reliable, keep last 100; ``/tf_static`` and
  ``/robot_description`` reliable, transient local, keep last 1; state topics (``/joint_states``, ``/odom``) reliable, keep
  last 10. Subscriptions (``/cmd_vel``, the joint command, ``/estop``) are
  reliable, keep last 10: they match ``ros2 topic pub`` and rclcpp's default
  publishers.

simseam is a ROS 2 node: the participant publishes ``ros_discovery_info``
(``rmw_dds_common/msg/ParticipantEntitiesInfo``, what every rmw implementation
exchanges), so ``ros2 node list`` shows ``/simseam`` and ``ros2 node info
/simseam`` its publishers and subscriptions (and rclpy's graph API the same).

Discovery (unless ``CYCLONEDDS_URI`` is set, which wins): by default, and with
``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST``, DDS stays on the loopback
interface: participant discovery (SPDP) goes to the standard multicast group on
``lo`` (which a default ROS 2 node, announcing by multicast, sends and hears on
the same machine), and also by unicast to 127.0.0.1's participant ports (what
ROS 2 nodes run with ``ROS_AUTOMATIC_DISCOVERY_RANGE=LOCALHOST`` listen on);
data is unicast. Either side may start first. ``ROS_AUTOMATIC_DISCOVERY_RANGE=
SUBNET`` (or ``SYSTEM_DEFAULT``) lets Cyclone use the network (its default
interface, multicast discovery) to reach other machines, with
``ROS_STATIC_PEERS`` (``;``-separated hosts) added as unicast peers; ``OFF``
discovers nothing outside this process. ``ROS_DOMAIN_ID`` picks the domain.
"""

from __future__ import annotations

import os
from dataclasses import dataclass

from simseam.ros2 import msgs as m
from simseam.seam import BackendUnavailableError, ConfigError

_DISCOVERY = "<Discovery><ParticipantIndex>auto</ParticipantIndex><MaxAutoParticipantIndex>32</MaxAutoParticipantIndex>{peers}</Discovery>"
LOOPBACK_XML = (
    "<CycloneDDS><Domain Id=\"any\"><General><Interfaces><NetworkInterface name=\"lo\" multicast=\"true\"/>"
    "</Interfaces><AllowMulticast>spdp</AllowMulticast><MaxMessageSize>65500B</MaxMessageSize></General>"
    + _DISCOVERY.format(peers="<Peers><Peer address=\"127.0.0.1\"/></Peers>") + "</Domain></CycloneDDS>"
)
_OFF_XML = ("<CycloneDDS><Domain Id=\"any\"><General><Interfaces><NetworkInterface name=\"lo\"/></Interfaces>"
            "<AllowMulticast>false</AllowMulticast></General></Domain></CycloneDDS>")
DISCOVERY_RANGES = ("LOCALHOST", "SUBNET", "SYSTEM_DEFAULT", "OFF")


def loopback_config() -> str:
    """The default ``CYCLONEDDS_URI`` value: DDS on 127.0.0.1 only (SPDP multicast on ``lo`` plus unicast
    to 127.0.0.1's participant ports, data unicast)."""
    return LOOPBACK_XML


def discovery_config(env=None) -> str | None:
    """The Cyclone configuration for ``ROS_AUTOMATIC_DISCOVERY_RANGE`` / ``ROS_STATIC_PEERS`` (see the module
    docstring); None: use Cyclone's own defaults (the network)."""
    env = os.environ if env is None else env
    rng = env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip().upper() or "LOCALHOST"
    if rng not in DISCOVERY_RANGES:
        raise ConfigError(f"ROS_AUTOMATIC_DISCOVERY_RANGE={rng!r}: expected one of {', '.join(DISCOVERY_RANGES)}")
    peers = [p.strip() for p in env.get("ROS_STATIC_PEERS", "").split(";") if p.strip()]
    if rng == "OFF":
        return _OFF_XML
    if rng == "LOCALHOST" and not peers:
        return LOOPBACK_XML
    if not peers:
        return None
    from xml.sax.saxutils import quoteattr

    peer_xml = "<Peers>" + "".join(f"<Peer address={quoteattr(p)}/>" for p in peers) + "</Peers>"
    return "<CycloneDDS><Domain Id=\"any\">" + _DISCOVERY.format(peers=peer_xml) + "</Domain></CycloneDDS>"


def discovery_summary(env=None) -> str:
    """One line for the deploy banner: where DDS discovery reaches."""
    env = os.environ if env is None else env
    if env.get("CYCLONEDDS_URI"):
        return "CYCLONEDDS_URI"
    rng = env.get("ROS_AUTOMATIC_DISCOVERY_RANGE", "").strip().upper() or "LOCALHOST"
    peers = env.get("ROS_STATIC_PEERS", "").strip()
    where = {"LOCALHOST": "loopback only (ROS_AUTOMATIC_DISCOVERY_RANGE=SUBNET to reach other machines)",
             "OFF": "off", "SUBNET": "the network", "SYSTEM_DEFAULT": "the network"}.get(rng, rng)
    return where + (f", static peers {peers}" if peers else "")


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
LATCHED = "latched"  # /robot_description: reliable, transient local, keep last 1 (robot_state_publisher's)
GRAPH = "graph"  # ros_discovery_info: reliable, transient local, keep last 1 (rmw_dds_common's)


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
    if kind in (TF_STATIC, LATCHED, GRAPH):
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


def _gid(entity) -> m.Gid:
    """An entity's DDS GUID as an rmw GID (Jazzy: the 16 GUID bytes, as rmw_fastrtps and rmw_cyclonedds use)."""
    return m.Gid(list(entity.guid.bytes))


class Participant:
    """One DDS participant on a ROS domain, with writers and readers made on demand.

    ``node_name`` (None: none): the ROS 2 node this participant is, announced on ``ros_discovery_info``
    with every reader and writer made here; ``config``: a Cyclone XML configuration (default:
    ``discovery_config()``, unless ``CYCLONEDDS_URI`` is set).
    """

    def __init__(self, domain_id: int | None = None, *, config: str | None = None,
                 node_name: str | None = "simseam", namespace: str = "/"):
        _import_cyclone()
        from cyclonedds.core import Policy, Qos
        from cyclonedds.domain import Domain, DomainParticipant

        self.domain_id = domain_id_from_env() if domain_id is None else int(domain_id)
        if config is None and not os.environ.get("CYCLONEDDS_URI"):
            config = discovery_config()
        # A Domain object carries the configuration; it must outlive the participant.
        self._domain = Domain(self.domain_id, config) if config else None
        # the user data every rmw participant carries (its security enclave)
        self.dp = DomainParticipant(self.domain_id, qos=Qos(Policy.Userdata(b"enclave=/;")))
        self._topics: dict[str, object] = {}
        self._writers: dict[str, object] = {}
        self._readers: list[object] = []
        self.node_name, self.namespace = node_name, namespace
        self._graph_writer = None
        if node_name:
            from cyclonedds.pub import DataWriter
            from cyclonedds.topic import Topic

            topic = Topic(self.dp, "ros_discovery_info", m.ParticipantEntitiesInfo)
            self._topics["ros_discovery_info"] = topic
            self._graph_writer = DataWriter(self.dp, topic, qos=qos(GRAPH))
            self._announce()

    def graph_info(self) -> m.ParticipantEntitiesInfo:
        """This participant's ``ros_discovery_info`` sample: one node with its readers and writers."""
        node = m.NodeEntitiesInfo(self.namespace, self.node_name or "",
                                  [_gid(r) for r in self._readers], [_gid(w) for w in self._writers.values()])
        return m.ParticipantEntitiesInfo(_gid(self.dp), [node] if self.node_name else [])

    def _announce(self) -> None:
        if self._graph_writer is not None:
            self._graph_writer.write(self.graph_info())

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
            self._announce()
        return self._writers[name]

    def reader(self, name: str, cls: type, kind: str):
        from cyclonedds.sub import DataReader

        r = DataReader(self.dp, self._topic(name, cls), qos=qos(kind))
        self._readers.append(r)
        self._announce()
        return r

    def close(self) -> None:
        """Delete readers, writers, topics and the participant now (DDS says goodbye to its peers)."""
        entities = [*self._readers, *self._writers.values(), self._graph_writer, *self._topics.values(), self.dp]
        self._readers, self._writers, self._topics, self.dp, self._graph_writer = [], {}, {}, None, None
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
