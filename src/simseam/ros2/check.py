"""``simseam doctor``'s ROS 2 and Foxglove checks: each runs a little of what ``simseam deploy`` runs.

- DDS: a Cyclone participant, configured as ``deploy``'s is, publishes a ``std_msgs/String`` on a
  ROS 2 topic and reads it back (``deploy --ros2``);
- recording: an MCAP file with one ROS 2 message is written and read back (``deploy --record``);
- Foxglove: the live server starts on a free port and answers a WebSocket upgrade for the Foxglove
  protocol (``deploy --foxglove``).
"""

from __future__ import annotations

import base64
import os
import socket
import tempfile
import time
from pathlib import Path

from simseam.runner.machine_check import Check, _version

EXTRA = "pip install 'simseam[ros2]'"
#: the subprotocol names a Foxglove client offers (the app offers both; foxglove-sdk servers take the newer)
FOXGLOVE_PROTOCOLS = ("foxglove.sdk.v1", "foxglove.websocket.v1")


def _first_line(exc: BaseException) -> str:
    return f"{type(exc).__name__}: {(str(exc).splitlines() or [''])[0][:200]}"


def check_dds(timeout: float = 10.0) -> Check:
    """A message published on a ROS 2 topic comes back to a reader of the same participant."""
    area = "ROS 2 over DDS"
    if _version("cyclonedds") is None:
        return Check(area, False, "cyclonedds is not installed", EXTRA)
    from simseam.ros2 import msgs as m
    from simseam.ros2.dds import COMMAND, Participant, domain_id_from_env

    try:
        domain = domain_id_from_env()
        p = Participant(domain, node_name=None)  # deploy's configuration (ROS_AUTOMATIC_DISCOVERY_RANGE, ...)
        try:
            reader = p.reader("/simseam_doctor", m.String, COMMAND)
            p.writer("/simseam_doctor", m.String, COMMAND).write(m.String("ping"))
            deadline = time.monotonic() + timeout
            got = []
            while not got and time.monotonic() < deadline:
                got = [s.data for s in reader.take(N=1)]
                if not got:
                    time.sleep(0.01)
        finally:
            p.close()
    except Exception as exc:  # noqa: BLE001  (any failure is the finding)
        return Check(area, False, f"cyclonedds {_version('cyclonedds')}: {_first_line(exc)}",
                     "check ROS_DOMAIN_ID and CYCLONEDDS_URI, or reinstall: " + EXTRA)
    if got != ["ping"]:
        return Check(area, False, f"cyclonedds {_version('cyclonedds')}: a message published on domain {domain} "
                                  f"did not come back within {timeout:g} s", "check CYCLONEDDS_URI")
    return Check(area, True, f"cyclonedds {_version('cyclonedds')}: publishes and reads a ROS 2 topic on domain "
                             f"{domain} (deploy --ros2)")


def check_recording() -> Check:
    """An MCAP file with one ROS 2 message (CDR, ros2msg schema) is written and read back."""
    area = "ROS 2 recording"
    missing = [d for d in ("mcap", "rosbags") if _version(d) is None]
    if missing:
        return Check(area, False, f"{', '.join(missing)} not installed", EXTRA)
    from mcap.reader import make_reader

    from simseam.ros2 import msgs as m
    from simseam.ros2.record import McapRecorder

    try:
        with tempfile.TemporaryDirectory(prefix="simseam-doctor-") as d:
            path = Path(d) / "check.mcap"
            sink = McapRecorder(path)
            msg = m.String("ping")
            sink.write("/simseam_doctor", msg, msg.serialize(), 1)
            sink.close()
            with open(path, "rb") as f:
                topics = [ch.topic for _, ch, _ in make_reader(f).iter_messages()]
    except Exception as exc:  # noqa: BLE001
        return Check(area, False, _first_line(exc), EXTRA)
    if topics != ["/simseam_doctor"]:
        return Check(area, False, f"an MCAP file read back {topics}, not the one message written", EXTRA)
    return Check(area, True, f"mcap {_version('mcap')}: writes and reads ROS 2 messages (deploy --record)")


def check_foxglove(timeout: float = 10.0) -> Check:
    """The live server starts and accepts a Foxglove WebSocket client's upgrade request."""
    area = "Foxglove live view"
    if _version("foxglove-sdk") is None:
        return Check(area, False, "foxglove-sdk is not installed", EXTRA)
    from simseam.ros2.record import FoxgloveServer

    try:
        server = FoxgloveServer(port=0)
        try:
            reply = _upgrade(server.port, timeout)
        finally:
            server.close()
    except Exception as exc:  # noqa: BLE001
        return Check(area, False, f"foxglove-sdk {_version('foxglove-sdk')}: {_first_line(exc)}", EXTRA)
    status = reply.split("\r\n", 1)[0]
    chosen = [ln.split(":", 1)[1].strip() for ln in reply.split("\r\n")
              if ln.lower().startswith("sec-websocket-protocol:")]
    if " 101 " not in status or not chosen or chosen[0] not in FOXGLOVE_PROTOCOLS:
        return Check(area, False, f"the server answered a Foxglove client with {status!r}", EXTRA)
    return Check(area, True, f"foxglove-sdk {_version('foxglove-sdk')}: the server accepts Foxglove clients "
                             "(deploy --foxglove)")


def _upgrade(port: int, timeout: float) -> str:
    """The response headers to a WebSocket upgrade asking for the Foxglove subprotocol."""
    key = base64.b64encode(os.urandom(16)).decode()
    request = (f"GET / HTTP/1.1\r\nHost: 127.0.0.1:{port}\r\nUpgrade: websocket\r\nConnection: Upgrade\r\n"
               f"Sec-WebSocket-Key: {key}\r\nSec-WebSocket-Version: 13\r\n"
               f"Sec-WebSocket-Protocol: {', '.join(FOXGLOVE_PROTOCOLS)}\r\n\r\n")
    with socket.create_connection(("127.0.0.1", port), timeout=timeout) as sock:
        sock.sendall(request.encode())
        data = b""
        while b"\r\n\r\n" not in data:
            chunk = sock.recv(4096)
            if not chunk:
                break
            data += chunk
        if b" 101 " in data.split(b"\r\n", 1)[0]:  # leave as a client does: a (masked, empty) close frame
            sock.sendall(b"\x88\x80" + os.urandom(4))
            try:
                while sock.recv(4096):
                    pass
            except OSError:
                pass
    return data.split(b"\r\n\r\n", 1)[0].decode(errors="replace")


def ros2_checks() -> list[Check]:
    return [check_dds(), check_recording(), check_foxglove()]
