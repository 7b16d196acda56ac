"""Where bridge messages go besides DDS: an MCAP file and a live Foxglove server.

Both carry the same topics as DDS with ROS 2 schemas: channel message encoding
``cdr`` (the very bytes a ROS 2 node puts on the wire) and schema encoding
``ros2msg`` (the message definition with its dependencies, as rosbag2's MCAP
storage writes it). Foxglove Studio and ``rosbags`` read them without any
simseam code; ``ros2 bag play FILE.mcap`` replays them. Log times are sim time.
"""

from __future__ import annotations

import json
import threading
from pathlib import Path

from simseam.ros2.msgs import ros2msg_schema, ros_type_name
from simseam.seam import BackendUnavailableError, ConfigError


class McapRecorder:
    """Write messages to ``path`` (MCAP, zstd-compressed chunks)."""

    def __init__(self, path: str | Path, *, overwrite: bool = False):
        try:
            from mcap.writer import CompressionType, Writer
        except ImportError as exc:
            raise BackendUnavailableError(f"--record needs the mcap package ({exc}); "
                                          "install it with: pip install 'simseam[ros2]'") from None
        self.path = Path(path)
        if self.path.is_dir():
            raise ConfigError(f"--record {self.path}: is a directory; name the MCAP file to write (e.g. "
                              f"{self.path / 'session.mcap'})")
        if self.path.exists() and not overwrite:
            raise ConfigError(f"--record {self.path}: the file exists; choose another or pass --overwrite")
        try:
            self.path.parent.mkdir(parents=True, exist_ok=True)
            self._fh = open(self.path, "wb")
        except OSError as exc:
            raise ConfigError(f"--record {self.path}: cannot write it ({exc.strerror})") from None
        self._w = Writer(self._fh, compression=CompressionType.ZSTD)
        self._w.start(profile="ros2", library="simseam")
        self._schemas: dict[str, int] = {}
        self._channels: dict[str, int] = {}
        self._seq: dict[int, int] = {}

    def _channel(self, topic: str, ros_type: str) -> int:
        ch = self._channels.get(topic)
        if ch is None:
            sid = self._schemas.get(ros_type)
            if sid is None:
                sid = self._schemas[ros_type] = self._w.register_schema(
                    name=ros_type, encoding="ros2msg", data=ros2msg_schema(ros_type).encode())
            ch = self._channels[topic] = self._w.register_channel(topic=topic, message_encoding="cdr",
                                                                   schema_id=sid)
            self._seq[ch] = 0
        return ch

    def write(self, topic: str, msg, data: bytes, stamp_ns: int) -> None:
        ch = self._channel(topic, ros_type_name(msg))
        self._w.add_message(channel_id=ch, log_time=int(stamp_ns), publish_time=int(stamp_ns), data=data,
                            sequence=self._seq[ch])
        self._seq[ch] += 1

    def close(self) -> None:
        if self._fh is not None:
            self._w.finish()
            self._fh.close()
            self._fh = None


#: topics a ROS 2 subscriber gets on connecting (transient local): a Foxglove client gets their last
#: message whenever it subscribes
LATCHED_TOPICS = ("/tf_static", "/robot_description")


def _from_json(cls: type, value):
    """A message class instance from a JSON object (Foxglove's ``json`` client publishing)."""
    import dataclasses
    import typing

    if not dataclasses.is_dataclass(cls):
        return value
    if not isinstance(value, dict):
        raise ValueError(f"expected a JSON object for {cls.__name__}, got {type(value).__name__}")
    hints = typing.get_type_hints(cls, include_extras=True)
    kwargs = {}
    for f in dataclasses.fields(cls):
        if f.name not in value:
            continue
        hint = hints[f.name]
        if dataclasses.is_dataclass(hint):
            kwargs[f.name] = _from_json(hint, value[f.name])
        else:
            kwargs[f.name] = value[f.name]
    return cls(**kwargs)


class FoxgloveServer:
    """Serve messages live over the Foxglove WebSocket protocol on 127.0.0.1.

    - ``/tf_static`` and ``/robot_description`` behave as latched: a client gets their last message
      whenever it subscribes (on the bridge's next tick), as a transient-local ROS 2 subscriber does.
    - ``clientPublish``: a client may advertise and publish the bridge's command topics (``/cmd_vel``,
      the joint command, ``/estop``) in ``cdr`` (ROS 2 schemas) or ``json``; they reach the HAL through
      ``Ros2Bridge.inject``, the same path as DDS commands (hold time, E-stop latch, clamps).
    - A port in use is a ``ConfigError`` (one line).
    """

    def __init__(self, port: int = 8765, host: str = "127.0.0.1"):
        try:
            import foxglove
            from foxglove.websocket import Capability
        except ImportError as exc:
            raise BackendUnavailableError(f"--foxglove needs the foxglove-sdk package ({exc}); "
                                          "install it with: pip install 'simseam[ros2]'") from None
        self._fg = foxglove
        self._ctx = foxglove.Context()
        self._lock = threading.Lock()
        self._latched: dict[str, tuple[bytes, int]] = {}
        self._pending: set[str] = set()
        self._client_channels: dict[tuple[int, int], tuple[str, str]] = {}
        self._command_topics: dict[str, type] = {}
        self._on_command = None
        self.stats = {"client_messages": 0, "client_rejected": 0, "latched_resent": 0}
        self.errors: list[str] = []
        try:
            self._server = foxglove.start_server(
                name="simseam", host=host, port=port, context=self._ctx, server_listener=self,
                capabilities=[Capability.ClientPublish], supported_encodings=["cdr", "json"])
        except RuntimeError as exc:
            raise ConfigError(f"Foxglove server on {host}:{port}: {str(exc).replace('FoxgloveError: ', '')} "
                              f"(pick another with --foxglove-port, 0 for any free port)") from None
        self.port = self._server.port
        self._channels: dict[str, object] = {}

    # ------------------------------------------------------------ server -> clients
    def write(self, topic: str, msg, data: bytes, stamp_ns: int) -> None:
        ch = self._channel(topic, msg)
        ch.log(data, log_time=int(stamp_ns))
        if topic in LATCHED_TOPICS:
            with self._lock:
                self._latched[topic] = (data, int(stamp_ns))
        if self._pending:
            self._resend_latched()

    def _channel(self, topic: str, msg):
        ch = self._channels.get(topic)
        if ch is None:
            ros_type = ros_type_name(msg)
            schema = self._fg.Schema(name=ros_type, encoding="ros2msg", data=ros2msg_schema(ros_type).encode())
            ch = self._channels[topic] = self._fg.Channel(topic, message_encoding="cdr", schema=schema,
                                                          context=self._ctx)
        return ch

    def _resend_latched(self) -> None:
        with self._lock:
            pending, self._pending = self._pending, set()
            items = [(t, self._latched[t]) for t in pending if t in self._latched]
        for topic, (data, stamp) in items:
            self._channels[topic].log(data, log_time=stamp)
            self.stats["latched_resent"] += 1

    # --------------------------------------------------- ServerListener callbacks
    def on_subscribe(self, client, channel) -> None:
        # Delivered from the bridge's thread on its next write, once this subscription is in place.
        if channel.topic in LATCHED_TOPICS:
            with self._lock:
                self._pending.add(channel.topic)

    def accept_commands(self, topics: dict[str, type], callback) -> None:
        """Let clients publish ``topics`` (name -> message class); each decoded message goes to ``callback(
        topic, msg)`` (``Ros2Bridge`` calls this at start)."""
        self._command_topics = dict(topics)
        self._on_command = callback

    def on_client_advertise(self, client, channel) -> None:
        with self._lock:
            self._client_channels[(client.id, channel.id)] = (channel.topic, channel.encoding)

    def on_client_unadvertise(self, client, client_channel_id: int) -> None:
        with self._lock:
            self._client_channels.pop((client.id, client_channel_id), None)

    def _reject(self, why: str) -> None:
        self.stats["client_rejected"] += 1
        if len(self.errors) < 20:
            self.errors.append(why)

    def on_message_data(self, client, client_channel_id: int, data: bytes) -> None:
        try:
            with self._lock:
                topic, encoding = self._client_channels.get((client.id, client_channel_id), (None, None))
            cls = self._command_topics.get(topic)
            if cls is None or self._on_command is None:
                self._reject(f"client publish on {topic!r}: not a command topic "
                             f"({', '.join(self._command_topics) or 'none'})")
                return
            if encoding == "cdr":
                msg = cls.deserialize(bytes(data))
            elif encoding == "json":
                msg = _from_json(cls, json.loads(bytes(data)))
            else:
                self._reject(f"client publish on {topic}: encoding {encoding!r} (cdr or json)")
                return
            self._on_command(topic, msg)
            self.stats["client_messages"] += 1
        except Exception as exc:  # a malformed message must not take the server down
            self._reject(f"client publish on {topic}: {type(exc).__name__}: {exc}")

    def close(self) -> None:
        if self._server is not None:
            self._server.stop()
            self._server = None
