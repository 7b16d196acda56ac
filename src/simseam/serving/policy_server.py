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

Several clients at once: ``batch`` (a ``PolicyBatch`` of ``max_clients`` environments, e.g.
``make_policy_batch(spec, n)``) gives every connected client its own episode state (its own slot:
``reset`` per slot, its own chunk queue). Requests from all clients go to one batcher thread that
collects up to ``max_batch_size`` of them, waiting at most ``max_wait_ms`` after the first, and answers
them with one ``act_batch`` (one forward pass for ``lerobot:``); a request that fails is retried
alone, so one client's bad observation costs only that client its connection. Without ``batch`` the
server holds ``policy`` in one slot: one client at a time. A client beyond the free slots waits up to
``busy_wait`` seconds, then gets a "busy" text frame and close code 1013 (try again later).
``GET /healthz`` answers 200 (no token needed).

Exposure (the server runs whatever observations a client sends through the policy; no TLS):

- it binds 127.0.0.1 unless told otherwise, and refuses a non-loopback ``host`` unless
  ``allow_remote=True`` (``ConfigError``);
- with a ``token`` (always, when not on loopback: one is generated, read ``.token`` / ``.client_url``)
  the opening handshake must present it, as ``Authorization: Api-Key <token>`` (openpi-client's
  ``api_key``; ``Bearer`` works too) or as ``?token=<token>`` in the URL; otherwise HTTP 401 with a
  one-line reason, before any message is read;
- a message over ``max_message_bytes`` closes that connection (code 1009) before it is read into
  memory, and the decoder refuses arrays whose header disagrees with their data; the server serves on;
- a client that sends nothing for ``idle_timeout`` seconds while holding the client slot is
  disconnected (code 1008) so that the next client can connect; ``None`` or 0: never;
- ``stop()`` (and Ctrl-C in ``serve_forever``) closes every connection, those waiting for the slot
  included, each within ``close_timeout`` seconds, and returns without waiting for a policy call
  still running (``active_handlers()`` says whether one is).
"""

from __future__ import annotations

import hmac
import http
import queue
import secrets
import sys
import threading
import time
import traceback
from typing import Any
from urllib.parse import parse_qsl, urlsplit

import numpy as np

from simseam.policies import openpi_wire as wire
from simseam.policies.contract import SkillContract
from simseam.seam import OBS_IMAGES, OBS_STATE, OBS_TASK, ConfigError, RolloutSpec

#: default bound on one websocket message (a request with several full-HD cameras fits easily)
DEFAULT_MAX_MESSAGE_BYTES = wire.DEFAULT_MAX_MESSAGE_BYTES
#: default seconds a connected client may stay silent before it is dropped (frees the one client slot)
DEFAULT_IDLE_TIMEOUT_S = 60.0


class ProtocolError(ValueError):
    """A client's request breaks the protocol (reported to that client, never fatal to the server)."""


def _log(msg: str) -> None:
    print(f"[simseam policy-server] {msg}", file=sys.stderr, flush=True)


def presented_token(request: Any) -> str | None:
    """The token a handshake request carries: ``Authorization: Api-Key <t>`` (openpi-client's
    ``api_key``) or ``Bearer <t>``, else a ``token`` query parameter; None when it has none."""
    auth = request.headers.get("Authorization")
    if auth:
        scheme, _, value = auth.strip().partition(" ")
        if scheme.lower() in ("api-key", "bearer") and value.strip():
            return value.strip()
    for key, value in parse_qsl(urlsplit(request.path).query, keep_blank_values=True):
        if key == wire.TOKEN_QUERY:
            return value
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
                 name: str | None = None, busy_wait: float = 3.0, verbose: bool = True,
                 allow_remote: bool = False, token: str | None = None,
                 max_message_bytes: int = DEFAULT_MAX_MESSAGE_BYTES,
                 idle_timeout: float | None = DEFAULT_IDLE_TIMEOUT_S, close_timeout: float = 2.0,
                 batch: Any = None, max_batch_size: int | None = None, max_wait_ms: float = 2.0):
        wire.check_bind_host(host)
        if not wire.is_loopback(host) and not allow_remote:
            raise ConfigError(f"refusing to serve on {host!r}: not a loopback address, and the policy server runs "
                              "any client's observations through the policy over plain websockets; to serve other "
                              "machines opt in with allow_remote=True (serve-policy --allow-remote), which also "
                              "requires a token")
        if token is not None and not token.strip():
            raise ConfigError("the policy server's token must not be empty")
        if token is None and not wire.is_loopback(host):
            token = secrets.token_urlsafe(24)
        if max_message_bytes < 1024:
            raise ConfigError(f"max_message_bytes must be >= 1024, got {max_message_bytes}")
        from simseam.policies.batch import PerEnvPolicies

        if batch is None:
            batch = PerEnvPolicies(lambda: policy, 1)
        if max_batch_size is not None and max_batch_size < 1:
            raise ConfigError(f"max_batch_size must be >= 1, got {max_batch_size}")
        if max_wait_ms < 0:
            raise ConfigError(f"max_wait_ms must be >= 0, got {max_wait_ms}")
        self.policy = policy
        self.batch = batch
        self.max_clients = int(batch.n)
        self.max_batch_size = int(max_batch_size or batch.n)
        self.max_wait_s = float(max_wait_ms) / 1e3
        self.host = host
        self.port = port
        self.busy_wait = busy_wait
        self.verbose = verbose
        self.token = token
        self.max_message_bytes = int(max_message_bytes)
        self.idle_timeout = float(idle_timeout) if idle_timeout else None
        self.close_timeout = float(close_timeout)
        if contract is None and isinstance(getattr(policy, "contract", None), SkillContract):
            contract = policy.contract
        self.chunked = callable(getattr(policy, "predict_chunk", None))
        meta: dict[str, Any] = {
            "server": "simseam", "protocol": "openpi-websocket", "policy": name or type(policy).__name__,
            "requires_privileged": bool(getattr(policy, "requires_privileged", False)),
            "uses_images": bool(getattr(policy, "uses_images", True)), "chunked": self.chunked,
            "max_message_bytes": self.max_message_bytes, "max_clients": self.max_clients,
            "max_batch_size": self.max_batch_size,
        }
        n = getattr(policy, "n_action_steps", None) if self.chunked else None
        if n:
            meta["n_action_steps"] = int(n)
        if contract is not None:
            meta["simseam_skill"] = contract.to_json()
        self.metadata = {**meta, **(metadata or {})}
        self._server: Any = None
        self._thread: threading.Thread | None = None
        self._free_slots: queue.Queue[int] = queue.Queue()
        for slot in range(self.max_clients):
            self._free_slots.put(slot)
        self._requests: queue.Queue = queue.Queue()
        self._batcher: threading.Thread | None = None
        #: inference batches run, and the size of each (the last 1000)
        self.batches = 0
        self.batch_sizes: list[int] = []
        self._stopping = threading.Event()
        self._conns: set[Any] = set()
        self._handlers: set[threading.Thread] = set()
        self._conns_lock = threading.Lock()
        self.requests = 0  #: inference requests answered, over all clients
        self.refused = 0  #: handshakes refused for a missing or wrong token

    @property
    def url(self) -> str:
        host = f"[{self.host}]" if ":" in self.host else self.host
        return f"ws://{host}:{self.port}"

    @property
    def client_url(self) -> str:
        """``url``, with ``?token=...`` when the server requires one (what ``remote:`` takes)."""
        return f"{self.url}?{wire.TOKEN_QUERY}={self.token}" if self.token else self.url

    def active_handlers(self) -> list[threading.Thread]:
        """Connection handlers still running (after ``stop()``: one stuck in a policy call)."""
        with self._conns_lock:
            return [t for t in self._handlers if t.is_alive()]

    # ------------------------------------------------------------------ lifecycle
    def start(self) -> "PolicyServer":
        """Bind (``port`` is then the real one) and serve on a background thread; returns self."""
        wire.require_websockets()
        from websockets.sync.server import serve

        if self._server is not None:
            return self
        self._stopping.clear()
        self._server = serve(self._handle, self.host, self.port, compression=None, max_size=self.max_message_bytes,
                             process_request=self._process_request, close_timeout=self.close_timeout)
        self.port = self._server.socket.getsockname()[1]
        self._thread = threading.Thread(target=self._server.serve_forever, name=f"policy-server:{self.port}",
                                        daemon=True)
        self._thread.start()
        self._batcher = threading.Thread(target=self._batch_loop, name=f"policy-batcher:{self.port}", daemon=True)
        self._batcher.start()
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
        self._stopping.set()  # clients waiting for the slot give up at once
        # websockets' shutdown() closes the listening socket, then closes every open connection (1001)
        # and waits, without a bound, until every handler has returned: a handler inside a long policy
        # call would hold stop() (and Ctrl-C) hostage. So: shutdown() on a helper thread, our own close
        # of every connection (those still handshaking or waiting for the slot too), bounded waits.
        shutdown = threading.Thread(target=server.shutdown, kwargs={"code": 1001, "reason": "server shutting down"},
                                    name=f"policy-server-shutdown:{self.port}", daemon=True)
        shutdown.start()
        with self._conns_lock:
            conns = list(self._conns)
        closers = [threading.Thread(target=_close_quietly, args=(c, 1001, "server shutting down"), daemon=True)
                   for c in conns]
        for t in closers:
            t.start()
        deadline = time.monotonic() + self.close_timeout + 1.0
        for t in (*closers, shutdown):
            t.join(max(0.0, deadline - time.monotonic()))
        if self._thread is not None and self._thread is not threading.current_thread():
            self._thread.join(max(0.5, deadline - time.monotonic()))  # ends once the listening socket is closed
        self._thread = None
        if self._batcher is not None and self._batcher is not threading.current_thread():
            self._batcher.join(1.0)
        self._batcher = None
        busy = self.active_handlers()
        if busy and self.verbose:
            _log(f"stopped; {len(busy)} request(s) still inside the policy were not waited for")
        elif self.verbose:
            _log(f"stopped ({self.url})")

    def __enter__(self) -> "PolicyServer":
        return self.start()

    def __exit__(self, *exc: Any) -> None:
        self.stop()

    # ------------------------------------------------------------------ one client
    def _process_request(self, connection: Any, request: Any) -> Any:
        """Before the upgrade: the health check, then the token (HTTP 401 and a reason without it)."""
        if urlsplit(request.path).path == "/healthz":
            return connection.respond(http.HTTPStatus.OK, "OK\n")
        if self.token is None:
            return None
        got = presented_token(request)
        if got is not None and hmac.compare_digest(got.encode(), self.token.encode()):
            return None
        self.refused += 1
        why = "no token" if got is None else "a wrong token"
        _log(f"{connection.remote_address}: refused, {why}")
        return connection.respond(http.HTTPStatus.UNAUTHORIZED,
                                  f"simseam policy server: {why}; this server requires the token that serve-policy "
                                  f"printed, as remote:ws://HOST:PORT?{wire.TOKEN_QUERY}=TOKEN or the header "
                                  "'Authorization: Api-Key TOKEN' (openpi-client: api_key=TOKEN)\n")

    def _acquire_slot(self) -> int | None:
        """Wait up to ``busy_wait`` s for a free client slot; None when all are taken or stopping."""
        deadline = time.monotonic() + self.busy_wait
        while not self._stopping.is_set():
            try:
                slot = self._free_slots.get(timeout=max(0.0, min(0.1, deadline - time.monotonic())))
            except queue.Empty:
                if time.monotonic() >= deadline:
                    return None
                continue
            if not self._stopping.is_set():
                return slot
            self._free_slots.put(slot)
            return None
        return None

    def _handle(self, conn: Any) -> None:
        with self._conns_lock:
            self._conns.add(conn)
            self._handlers.add(threading.current_thread())
        try:
            self._serve_client(conn)
        finally:
            with self._conns_lock:
                self._conns.discard(conn)
                self._handlers.discard(threading.current_thread())

    def _serve_client(self, conn: Any) -> None:
        from websockets.exceptions import ConnectionClosed

        peer = conn.remote_address
        slot = self._acquire_slot()
        if slot is None:
            if self._stopping.is_set():
                _close_quietly(conn, 1001, "server shutting down")
                return
            n = self.max_clients
            _log(f"{peer}: refused, all {n} client slot(s) are taken")
            try:
                conn.send(f"simseam policy server busy: it serves {n} client(s) at a time and "
                          f"{'another one is' if n == 1 else 'that many are'} connected; retry when one disconnects")
                conn.close(1013, f"busy: {n} client(s) at a time")
            except ConnectionClosed:
                pass
            return
        episode: dict[str, Any] = {}
        try:
            if self.verbose:
                _log(f"{peer}: connected")
            conn.send(wire.packb(self.metadata))
            prev_total = None
            while True:
                try:
                    data = conn.recv(timeout=self.idle_timeout)
                except TimeoutError:
                    _log(f"{peer}: idle for {self.idle_timeout:g} s, disconnected (frees the client slot)")
                    _close_quietly(conn, 1008, f"idle for more than {self.idle_timeout:g} s; reconnect to go on")
                    return
                start = time.monotonic()
                try:
                    obs = self._observation(data, episode, slot)
                    t0 = time.monotonic()
                    actions = self._submit(slot, obs)
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
        except ConnectionClosed as exc:
            if exc.sent is not None and exc.sent.code == 1009:
                _log(f"{peer}: sent a message over the {self.max_message_bytes}-byte limit; connection closed (1009)")
            elif self.verbose:
                _log(f"{peer}: disconnected")
        finally:
            self._free_slots.put(slot)

    def _observation(self, data: Any, episode: dict[str, Any], slot: int = 0) -> dict[str, Any]:
        """A request (bytes) -> the seam observation dict; resets the policy on ``simseam/reset``."""
        if isinstance(data, str):
            raise ProtocolError("got a text frame; requests are binary msgpack frames (openpi's msgpack_numpy)")
        request = wire.unpackb(data, max_bytes=self.max_message_bytes)
        if not isinstance(request, dict):
            raise ProtocolError(f"a request must be a map of observation entries, got {type(request).__name__}")
        prompt = request.get(wire.PROMPT)
        if request.get(wire.RESET):
            if wire.SPEC not in request:
                raise ProtocolError(f"{wire.RESET!r} without {wire.SPEC!r} (RolloutSpec.to_json())")
            spec = RolloutSpec.from_json(request[wire.SPEC], where=f"request field {wire.SPEC!r}")
            self.batch.reset(slot, spec)
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

    def _submit(self, slot: int, obs: dict[str, Any]) -> np.ndarray:
        """Queue one request for the batcher and wait for its answer (or its exception)."""
        job = _Job(slot, obs)
        self._requests.put(job)
        while not job.done.wait(0.25):
            if self._stopping.is_set():
                raise ConnectionError("server shutting down")
        if job.error is not None:
            raise job.error
        return job.result

    def _batch_loop(self) -> None:
        """Collect up to ``max_batch_size`` requests (waiting ``max_wait_s`` after the first), answer them together."""
        while not self._stopping.is_set():
            try:
                first = self._requests.get(timeout=0.25)
            except queue.Empty:
                continue
            jobs = [first]
            deadline = time.monotonic() + self.max_wait_s
            while len(jobs) < self.max_batch_size:
                try:
                    jobs.append(self._requests.get(timeout=max(0.0, deadline - time.monotonic())))
                except queue.Empty:
                    break
            self.batches += 1
            self.batch_sizes = (self.batch_sizes + [len(jobs)])[-1000:]
            try:
                for job, out in zip(jobs, self._infer_many(jobs)):
                    job.result = out
            except Exception:  # noqa: BLE001  (one bad request: find it, answer the others)
                for job in jobs:
                    try:
                        job.result = self._infer_many([job])[0]
                    except Exception as exc:  # noqa: BLE001  (goes to that client)
                        job.error = exc
            for job in jobs:
                job.done.set()

    def _infer_many(self, jobs: list["_Job"]) -> list[np.ndarray]:
        """Each request's chunk (a chunked policy's ``predict_chunk``) or its one action as a chunk of
        one (``act_batch`` over the requests' slots), float32[H, D]."""
        policies = getattr(self.batch, "policies", None)
        if self.chunked and policies is not None:
            out = []
            for job in jobs:
                chunk = np.asarray(policies[job.slot].predict_chunk(job.obs), dtype=np.float32)
                out.append(chunk[None, :] if chunk.ndim == 1 else chunk)
            return out
        actions = np.asarray(self.batch.act_batch([j.slot for j in jobs], [j.obs for j in jobs]), dtype=np.float32)
        return [a[None, :] for a in actions]


class _Job:
    """One client request waiting for the batcher."""

    def __init__(self, slot: int, obs: dict[str, Any]):
        self.slot, self.obs = slot, obs
        self.done = threading.Event()
        self.result: np.ndarray | None = None
        self.error: BaseException | None = None


def _close_quietly(conn: Any, code: int, reason: str) -> None:
    """Close a connection (bounded by its close_timeout); a broken one has nothing left to close."""
    try:
        conn.close(code, reason)
    except Exception:  # noqa: BLE001
        pass
