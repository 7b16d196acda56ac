"""Where bridge messages go besides DDS: an MCAP file and a live Foxglove server.

Both carry the same topics as DDS with ROS 2 schemas: channel message encoding
``cdr`` (the very bytes a ROS 2 node puts on the wire) and schema encoding
``ros2msg`` (the message definition with its dependencies, as rosbag2's MCAP
storage writes it). Foxglove Studio and ``rosbags`` read them without any
simseam code; ``ros2 bag play FILE.mcap`` replays them. Log times are sim time.
"""

from __future__ import annotations

from pathlib import Path

from simseam.ros2.msgs import ros2msg_schema, ros_type_name
from simseam.seam import BackendUnavailableError


class McapRecorder:
    """Write messages to ``path`` (MCAP, zstd-compressed chunks)."""

    def __init__(self, path: str | Path):
        try:
            from mcap.writer import CompressionType, Writer
        except ImportError as exc:
            raise BackendUnavailableError(f"--record needs the mcap package ({exc}); "
                                          "install it with: pip install 'simseam[ros2]'") from None
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self._fh = open(self.path, "wb")
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


class FoxgloveServer:
    """Serve messages live over the Foxglove WebSocket protocol on 127.0.0.1."""

    def __init__(self, port: int = 8765, host: str = "127.0.0.1"):
        try:
            import foxglove
        except ImportError as exc:
            raise BackendUnavailableError(f"--foxglove needs the foxglove-sdk package ({exc}); "
                                          "install it with: pip install 'simseam[ros2]'") from None
        self._fg = foxglove
        self._ctx = foxglove.Context()
        self._server = foxglove.start_server(name="simseam", host=host, port=port, context=self._ctx)
        self.port = self._server.port
        self._channels: dict[str, object] = {}

    def write(self, topic: str, msg, data: bytes, stamp_ns: int) -> None:
        ch = self._channels.get(topic)
        if ch is None:
            ros_type = ros_type_name(msg)
            schema = self._fg.Schema(name=ros_type, encoding="ros2msg", data=ros2msg_schema(ros_type).encode())
            ch = self._channels[topic] = self._fg.Channel(topic, message_encoding="cdr", schema=schema,
                                                          context=self._ctx)
        ch.log(data, log_time=int(stamp_ns))

    def close(self) -> None:
        if self._server is not None:
            self._server.stop()
            self._server = None
