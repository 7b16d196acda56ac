"""Run the engine conformance suite against a real Isaac Sim interpreter.

The suite (``conformance.py``) builds engines in-process through a ``make_engine``
fixture, but Isaac Sim lives in its own interpreter (Python 3.11/3.12 venv made by
``simseam isaac provision``). So ``TestIsaacConformance`` hands the suite
``RemoteEngine`` objects: each ``Engine`` call is forwarded to one long-lived worker
process running ``IsaacEngine`` in ``$SIMSEAM_ISAAC_PYTHON`` (one ``SimulationApp``
for the whole session, as Isaac Sim allows one per process). Calls travel over a
private ZeroMQ ipc socket in simseam's sidecar wire format (msgpack + raw ndarray
frames, no pickle); exceptions come back with their simseam type (``ConfigError``,
``SimulationError`` ...), so ``pytest.raises`` in the suite works unchanged.

    python tests/engines/isaac_remote.py ENDPOINT     (the worker; started by RemoteIsaac)

Imports here are light (numpy, zmq, simseam's wire); the worker imports the engine
only after it started.
"""

from __future__ import annotations

import atexit
import dataclasses
import os
import shutil
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path

import numpy as np

BOOT_TIMEOUT_S = 1800.0  # the first Isaac Sim boot compiles shaders and may take many minutes
CALL_TIMEOUT_S = 900.0


# ------------------------------------------------------------------ values on the wire
def _to_wire(value):
    if dataclasses.is_dataclass(value) and not isinstance(value, type):  # the engine models (engines/base.py)
        return {"__dc__": type(value).__name__,
                "fields": {f.name: _to_wire(getattr(value, f.name)) for f in dataclasses.fields(value)}}
    if isinstance(value, (list, tuple)):
        return [_to_wire(v) for v in value]
    if isinstance(value, dict):
        return {k: _to_wire(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return np.ascontiguousarray(value)
    return value


def _from_wire(value):
    from simseam.engines import base

    if isinstance(value, dict) and "__dc__" in value:
        cls = getattr(base, value["__dc__"])
        fields = {k: _from_wire(v) for k, v in value["fields"].items()}
        types = {f.name: f.type for f in dataclasses.fields(cls)}
        for k, v in fields.items():  # the models use tuples; msgpack brings lists
            if isinstance(v, list) and "tuple" in str(types.get(k, "")):
                fields[k] = tuple(v)
        return cls(**fields)
    if isinstance(value, list):
        return [_from_wire(v) for v in value]
    if isinstance(value, dict):
        return {k: _from_wire(v) for k, v in value.items()}
    if isinstance(value, np.ndarray):
        return np.array(value)  # writable copy
    return value


# ------------------------------------------------------------------ the worker (in the Isaac interpreter)
def worker(endpoint: str) -> int:
    import zmq

    from simseam.sidecar.wire import decode, encode

    ctx = zmq.Context()
    sock = ctx.socket(zmq.PAIR)
    sock.connect(endpoint)
    engines: dict[int, object] = {}
    next_id = 0
    sock.send_multipart(encode("hello", {"python": sys.version.split()[0], "executable": sys.executable}))
    while True:
        op, body = decode(sock.recv_multipart())
        try:
            if op == "exit":
                sock.send_multipart(encode("ok", {}))
                return 0
            if op == "new":
                from simseam.engines.isaac.engine import IsaacEngine

                options = _from_wire(body.get("options"))
                engines[next_id] = IsaacEngine(options)
                sock.send_multipart(encode("ok", {"id": next_id}))
                next_id += 1
                continue
            engine = engines[body["id"]]
            method = body["method"]
            if method == "timestep":
                result = engine.timestep
            else:
                result = getattr(engine, method)(*_from_wire(body.get("args", [])))
                if method == "close":
                    engines.pop(body["id"], None)
            if isinstance(result, tuple):
                result = list(result)
            sock.send_multipart(encode("ok", {"result": _to_wire(result)}))
        except Exception as exc:
            sock.send_multipart(encode("error", {"kind": type(exc).__name__, "message": str(exc),
                                                 "traceback": traceback.format_exc()}))


# ------------------------------------------------------------------ the client (in the test interpreter)
class RemoteIsaac:
    """One worker process running ``IsaacEngine`` in ``python`` (an Isaac Sim interpreter)."""

    def __init__(self, python: str):
        import zmq

        from simseam.sidecar.client import sanitized_env

        self._dir = tempfile.mkdtemp(prefix="simseam-isaac-remote-")
        self.log_path = Path(self._dir) / "worker.log"
        self._ctx = zmq.Context.instance()
        self._sock = self._ctx.socket(zmq.PAIR)
        self._sock.setsockopt(zmq.LINGER, 0)
        endpoint = f"ipc://{self._dir}/worker.sock"
        self._sock.bind(endpoint)
        self._log = open(self.log_path, "wb")  # noqa: SIM115 - the worker writes to it for the whole session
        self._proc = subprocess.Popen([python, str(Path(__file__).resolve()), endpoint], stdin=subprocess.DEVNULL,
                                      stdout=self._log, stderr=subprocess.STDOUT, env=sanitized_env(),
                                      start_new_session=True)
        self.hello = self._recv(BOOT_TIMEOUT_S, "starting")[1]

    def _tail(self) -> str:
        try:
            return "\n".join(self.log_path.read_text(errors="replace").splitlines()[-40:])
        except OSError:
            return ""

    def _recv(self, timeout: float, what: str):
        from simseam.sidecar.wire import decode

        deadline = time.monotonic() + timeout
        while not self._sock.poll(200):
            if self._proc.poll() is not None:
                raise RuntimeError(f"the Isaac worker died (exit {self._proc.returncode}) while {what}; "
                                   f"its log ({self.log_path}) ends with:\n{self._tail()}")
            if time.monotonic() > deadline:
                raise TimeoutError(f"the Isaac worker did not answer within {timeout:.0f} s while {what}")
        return decode(self._sock.recv_multipart())

    def request(self, op: str, body: dict, timeout: float = CALL_TIMEOUT_S):
        from simseam import seam
        from simseam.sidecar.wire import encode

        self._sock.send_multipart(encode(op, _to_wire(body)))
        rop, reply = self._recv(timeout, f"running {op} {body.get('method', '')}")
        if rop == "error":
            cls = getattr(seam, reply["kind"], None)
            if isinstance(cls, type) and issubclass(cls, Exception):
                raise cls(reply["message"])
            raise RuntimeError(f"{reply['kind']} in the Isaac worker: {reply['message']}\n{reply['traceback']}")
        return _from_wire(reply)

    def close(self) -> None:
        try:
            if self._proc.poll() is None:
                self.request("exit", {}, timeout=60)
                self._proc.wait(60)
        except Exception:
            pass
        finally:
            if self._proc.poll() is None:
                self._proc.kill()
                self._proc.wait(60)
            self._sock.close(0)
            self._log.close()
            shutil.rmtree(self._dir, ignore_errors=True)  # its log's tail is in every error the worker raised


class RemoteEngine:
    """An ``Engine`` whose calls run in the Isaac worker."""

    name = "isaac"

    def __init__(self, remote: RemoteIsaac, options=None):
        self._remote = remote
        self._id = remote.request("new", {"options": options}, timeout=BOOT_TIMEOUT_S)["id"]
        self._closed = False

    def _call(self, method: str, *args):
        return self._remote.request("call", {"id": self._id, "method": method, "args": list(args)})["result"]

    @property
    def timestep(self) -> float:
        return self._call("timestep")

    def load_robot(self, robot):
        self._call("load_robot", robot)

    def add_ground(self):
        self._call("add_ground")

    def add_object(self, obj):
        self._call("add_object", obj)

    def add_camera(self, camera):
        self._call("add_camera", camera)

    def build(self):
        self._call("build")

    def reset(self):
        self._call("reset")

    def set_joint_positions(self, q):
        self._call("set_joint_positions", np.asarray(q, dtype=np.float64))

    def set_joint_targets(self, q):
        self._call("set_joint_targets", np.asarray(q, dtype=np.float64))

    def joint_positions(self):
        return self._call("joint_positions")

    def joint_velocities(self):
        return self._call("joint_velocities")

    def link_pose(self, link):
        pos, quat = self._call("link_pose", link)
        return pos, quat

    def set_root_pose(self, pos, quat):
        self._call("set_root_pose", np.asarray(pos, dtype=np.float64), np.asarray(quat, dtype=np.float64))

    def object_pose(self, name):
        pos, quat = self._call("object_pose", name)
        return pos, quat

    def set_object_pose(self, name, pos, quat):
        self._call("set_object_pose", name, np.asarray(pos, dtype=np.float64), np.asarray(quat, dtype=np.float64))

    def object_velocity(self, name):
        return self._call("object_velocity", name)

    def step(self, n_substeps):
        self._call("step", int(n_substeps))

    def sim_time(self):
        return self._call("sim_time")

    def render_rgb(self, camera):
        return self._call("render_rgb", camera)

    def render_depth(self, camera):
        return self._call("render_depth", camera)

    def cast_rays(self, origin, directions, max_dist):
        return self._call("cast_rays", np.asarray(origin, dtype=np.float64),
                          np.asarray(directions, dtype=np.float64), float(max_dist))

    def contacts_between(self, a, b):
        return self._call("contacts_between", a, b)

    def close(self):
        if not self._closed:
            self._closed = True
            self._call("close")


_SHARED: dict[str, RemoteIsaac] = {}


def shared(python: str) -> RemoteIsaac:
    """The session's worker for ``python`` (started on first use, stopped at exit)."""
    if python not in _SHARED:
        _SHARED[python] = RemoteIsaac(python)
        atexit.register(_SHARED[python].close)
    return _SHARED[python]


if __name__ == "__main__":
    os.environ.setdefault("SIMSEAM_SIDECAR", "1")  # like a sidecar: this process hosts the Isaac engine
    sys.exit(worker(sys.argv[1]))
