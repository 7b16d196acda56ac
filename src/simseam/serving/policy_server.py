"""``PolicyServer``: any simseam policy behind the openpi websocket protocol.

Wire and message flow: ``simseam.policies.openpi_wire`` (openpi's, unchanged). The server sends
its metadata on connect::

    {"server": "simseam", "protocol": "openpi-websocket", "policy": <name>,
     "requires_privileged": bool, "uses_images": bool, "chunked": bool,
     "n_action_steps": int (chunked policies that set it), "simseam_skill": <SkillContract JSON> (when known)}

then answers each observation (the ``simseam`` format of ``simseam.policies.remote``) with
``{"actions": float32[H, action_dim], "server_timing": {"infer_ms": ..., "prev_total_ms": ...}}``:
a ``ChunkedPolicy`` (anything with ``predict_chunk``) replies its chunk, any other policy one
action (``H = 1``). A request with ``simseam/reset`` rebuilds the ``RolloutSpec`` from
``simseam/spec`` and calls ``policy.reset``; the first request
of a connection must carry them.

Errors mirror openpi: the traceback goes to the client as a text frame, the connection is closed
with code 1011, the error is logged to stderr, and the server goes on serving the next client.
One client at a time (a policy keeps per-episode state): a second concurrent client waits up to
``busy_wait`` seconds, then gets a "busy" text frame and close code 1013 (try again later).
``GET /healthz`` answers 200. Binds 127.0.0.1 unless told otherwise.
"""

from __future__ import annotations

import http
import sys
import threading
import time
import traceback
from typing import Any

import numpy as np

from simseam.policies import openpi_wire as wire
from simseam.policies.contract import SkillContract
from simseam.seam import OBS_IMAGES, OBS_STATE, OBS_TASK, RolloutSpec


class ProtocolError(ValueError):
    """A client's request breaks the protocol (reported to that client, never fatal to the server)."""


def _log(msg: str) -> None:
    print(f"[simseam policy-server] {msg}", file=sys.stderr, flush=True)


def _health_check(connection: Any, request: Any) -> Any:
    if request.path == "/healthz":
        return connection.respond(http.HTTPStatus.OK, "OK\n")
    return None


class PolicyServer:
    """Serve ``policy`` (``reset(spec)``, ``act(obs)``, optionally ``predict_chunk(obs)``).

    ``port=0`` picks a free port (read ``.port`` / ``.url`` after ``start()``). ``contract``
    (default: the policy's own ``contract`` attribute when it has one) goes into the metadata as
    ``simseam_skill``; ``metadata`` entries are added to (and override) the generated ones.
    ``start()`` / ``stop()`` run it on a background thread; ``serve_forever()`` blocks until
    ``stop()`` or Ctrl-C (KeyboardInterrupt propagates after the server is stopped).
    """

    def __init__(self, policy: Any, host: str = "127.0.0.1", port: int = 8000, *,
                 contract: SkillContract | None = None, metadata: dict[str, Any] | None = None,
                 name: str | None = None, busy_wait: float = 3.0, verbose: bool = True):
        self.policy = policy
        self.host = host
        self.port = port
        self.busy_wait = busy_wait
        self.verbose = verbose
        if contract is None and isinstance(getattr(policy, "contract", None), SkillContract):
            contract = policy.contract
        self.chunked = callable(getattr(policy, "predict_chunk", None))
        meta: dict[str, Any] = {
            "server": "simseam", "protocol": "openpi-websocket", "policy": name or type(policy).__name__,
            "requires_privileged": bool(getattr(policy, "requires_privileged", False)),
            "uses_images": bool(getattr(policy, "uses_images", True)), "chunked": self.chunked,
        }
        n = getattr(policy, "n_action_steps", None) if self.chunked else None
        if n:
            meta["n_action_steps"] = int(n)
        if contract is not None:
            meta["simseam_skill"] = contract.to_json()
        self.metadata = {**meta, **(metadata or {})}
        self._server: Any = None
        self._thread: threading.Thread | None = None
        self._busy = threading.Lock()
        self._conns: set[Any] = set()
        self._conns_lock = threading.Lock()
        self.requests = 0  #: inference requests answered, over all clients

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> "PolicyServer":
        """Bind (``port`` is then the real one) and serve on a background thread; returns self."""
        wire.require_websockets()
        from websockets.sync.server import serve

        if self._server is not None:
            return self
        self._server = serve(self._handle, self.host, self.port, compression=None, max_size=None,
                             process_request=_health_check)
        self.port = self._server.socket.getsockname()[1]
        self._thread = threading.Thread(target=self._server.serve_forever, name=f"policy-server:{self.port}",
                                        daemon=True)
        self._thread.start()
        if self.verbose:
            _log(f"serving {self.metadata['policy']} on {self.url}")
        return self

    def serve_forever(self) -> None:
        """Serve in the foreground until ``stop()`` (another thread) or Ctrl-C."""
        self.start()
        try:
            while self._thread is not None and self._thread.is_alive():
                self._thread.join(0.25)
        finally:
            self.stop()

    def stop(self) -> None:
        """Close every connection and the listening socket (the port is free when this returns)."""
        server, self._server = self._server, None
        if server is None:
            return
        with self._conns_lock:
            conns = list(self._conns)
        for conn in conns:
            try:
                conn.close(1001, "server shutting down")
            except Exception:  # noqa: BLE001  (already broken: nothing to close)
                pass
        server.shutdown()
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(5.0)
        self._thread = None
        if self.verbose:
            _log(f"stopped ({self.url})")

    def __enter__(self) -> "PolicyServer":
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    # ------------------------------------------------------------------ one client
    def _handle(self, conn: Any) -> None:
        from websockets.exceptions import ConnectionClosed

        peer = conn.remote_address
        if not self._busy.acquire(timeout=self.busy_wait):
            _log(f"{peer}: refused, another client is connected")
            try:
                conn.send("simseam policy server busy: it serves one client at a time and another one is "
                          "connected; retry when it disconnects")
                conn.close(1013, "busy: one client at a time")
            except ConnectionClosed:
                pass
            return
        with self._conns_lock:
            self._conns.add(conn)
        episode: dict[str, Any] = {}
        try:
            if self.verbose:
                _log(f"{peer}: connected")
            conn.send(wire.packb(self.metadata))
            prev_total = None
            while True:
                data = conn.recv()
                start = time.monotonic()
                try:
                    obs = self._observation(data, episode)
                    t0 = time.monotonic()
                    actions = self._infer(obs)
                    timing = {"infer_ms": (time.monotonic() - t0) * 1e3}
                    if prev_total is not None:
                        timing["prev_total_ms"] = prev_total * 1e3
                    self.requests += 1  # before the send: a client may read the count as soon as it has the reply
                    conn.send(wire.packb({"actions": actions, "server_timing": timing}))
                    prev_total = time.monotonic() - start
                except ConnectionClosed:
                    raise
                except Exception as exc:  # noqa: BLE001  (report to this client, keep serving)
                    _log(f"{peer}: error, closing this connection: {type(exc).__name__}: {exc}")
                    conn.send(traceback.format_exc())
                    conn.close(1011, "Internal server error. Traceback included in previous frame.")
                    return
        except ConnectionClosed:
            if self.verbose:
                _log(f"{peer}: disconnected")
        finally:
            with self._conns_lock:
                self._conns.discard(conn)
            self._busy.release()

    def _observation(self, data: Any, episode: dict[str, Any]) -> dict[str, Any]:
        """A request (bytes) -> the seam observation dict; resets the policy on ``simseam/reset``."""
        if isinstance(data, str):
            raise ProtocolError("got a text frame; requests are binary msgpack frames (openpi's msgpack_numpy)")
        request = wire.unpackb(data)
        if not isinstance(request, dict):
            raise ProtocolError(f"a request must be a map of observation entries, got {type(request).__name__}")
        prompt = request.get(wire.PROMPT)
        if request.get(wire.RESET):
            if wire.SPEC not in request:
                raise ProtocolError(f"{wire.RESET!r} without {wire.SPEC!r} (RolloutSpec.to_json())")
            spec = RolloutSpec.from_json(request[wire.SPEC], where=f"request field {wire.SPEC!r}")
            self.policy.reset(spec)
            episode.update(spec=spec)
        elif "spec" not in episode:
            keys = ", ".join(sorted(map(str, request))) or "none"
            raise ProtocolError(
                f"the first request on a connection must start an episode: it needs {wire.RESET!r}: True and "
                f"{wire.SPEC!r} (RolloutSpec.to_json()), and this one has neither (keys: {keys}). simseam's "
                "RemotePolicy sends them; a plain openpi client does not, so add them to its first observation")
        obs = wire.unflatten(request, wire.PREFIX)
        state = obs.get(OBS_STATE)
        if not (isinstance(state, np.ndarray) and state.dtype.kind in "fiub"):
            raise ProtocolError(f"'{wire.PREFIX}{OBS_STATE}' must be a numeric array, got {type(state).__name__}")
        images = obs.setdefault(OBS_IMAGES, {})
        for key, img in images.items():
            if not (isinstance(img, np.ndarray) and img.dtype == np.uint8 and img.ndim == 3 and img.shape[2] == 3):
                raise ProtocolError(f"'{wire.PREFIX}{OBS_IMAGES}/{key}' must be a uint8 HxWx3 array, got "
                                    f"{getattr(img, 'dtype', type(img).__name__)} {getattr(img, 'shape', '')}")
        obs[OBS_TASK] = str(prompt) if prompt is not None else episode["spec"].task.instruction
        return obs

    def _infer(self, obs: dict[str, Any]) -> np.ndarray:
        """The policy's chunk (chunked) or its one action as a chunk of one, float32[H, D]."""
        if self.chunked:
            chunk = np.asarray(self.policy.predict_chunk(obs), dtype=np.float32)
            return chunk[None, :] if chunk.ndim == 1 else chunk
        return np.asarray(self.policy.act(obs), dtype=np.float32)[None, :]
