"""The sidecar server: hosts one ``ManifestScene`` in its own process and serves it.

    python -m simseam.sidecar.server --boot BOOT.json      (what SidecarRollout spawns)
    simseam sidecar serve --boot BOOT.json                  (the same, through the CLI)

``BOOT.json`` (written by the client into its private 0700 directory, read and
deleted at start): ``{"spec": RobotSpec JSON, "task": str, "engine": str,
"options": SceneOptions fields, "endpoint": "ipc://..." | "tcp://127.0.0.1:*",
"token": str, "identity": str, "exclusive": bool, "keep_alive": bool,
"registry_dir": str | null}``. A benchmark backend's boot names it instead of a
robot and task: ``{"backend": "metaworld", "config": {...}, ...}`` (``simseam.backends``).
``"num_envs": N`` serves a batch of N environments instead of one rollout (a ``BatchRollout``,
seam/batch.py): the backend's own when it batches natively (``make_batch``), else N copies
stepped in turn in this process. A batch answers the ``batch_reset`` / ``batch_step`` /
``batch_render`` ops (every reply also carries the environments that failed since the last one);
the single-rollout ops are refused, and the other way round.

Boot progress goes to stdout as JSON lines (``{"event": "boot", "stage": ...}``,
then ``{"event": "ready", "endpoint": ..., "pid": ...}``); diagnostics go to
stderr. Every request must carry the launch token; a request that fails to
decode, or a handler that raises, gets a typed error reply and the server keeps
serving. Unless ``keep_alive``, the server exits when its parent dies.

Local fast path (``simseam.sidecar.local``): with an ``ipc://`` endpoint the server
also listens on ``local.sock`` beside it; a client that asks for it at ``hello`` gets
its path, connects, sends ``attach`` (with the token) and receives the shared-memory
ring; its requests then arrive there. One local client at a time (a new attach
replaces the previous one); the ZeroMQ socket keeps serving as before. A client that
asks at attach gets compact step messages there (``simseam.sidecar.compact``).

Imports numpy, msgpack, pyzmq and the scene layer only (plus the engine's SDK
when the scene is built): no pydantic, typer, rich or yaml.
"""

from __future__ import annotations

import argparse
import ctypes
import hmac
import json
import os
import select
import shutil
import signal
import socket
import sys
import time
import traceback
from pathlib import Path
from typing import Any

import numpy as np
import zmq

from simseam import origin
from simseam.seam import STATE_ONLY, ConfigError, ObsRequest
from simseam.sidecar import local
from simseam.sidecar.compact import COMPACT_VERSION, MAGIC, ReplyTemplates, decode_step
from simseam.sidecar.target import BackendTarget, Target, target_from_json
from simseam.sidecar.wire import PROTOCOL_VERSION, WireError, decode, encode

EXIT_BUSY = 3  # exit code: an exclusive engine is already running elsewhere
EXIT_BOOT_ERROR = 4  # exit code: the scene could not be built (the error went out as an "error" event)
EXCLUSIVE_ENGINES = ("isaac",)
SINGLE_OPS = ("reset", "step", "render")
BATCH_OPS = ("batch_reset", "batch_step", "batch_render")
TEST_HOOKS_ENV = "SIMSEAM_SIDECAR_TEST_HOOKS"  # enables the _sleep/_exit ops (tests only)


def _emit(event: str, **fields: Any) -> None:
    sys.stdout.write(json.dumps({"event": event, **fields}) + "\n")
    sys.stdout.flush()


EXIT_GRACE_S = 10  # after SIGTERM, cleanup gets this long before SIGALRM's default action ends the process


def _say(message: str) -> None:
    """One line to stderr; the client reading it may already be gone (a broken pipe is not an error)."""
    try:
        sys.stderr.write(message + "\n")
        sys.stderr.flush()
    except (OSError, ValueError):
        pass


def _exit_on_sigterm(*_: Any) -> None:
    """SIGTERM (the client's close, or its death through PR_SET_PDEATHSIG): unwind through ``serve``'s
    cleanup, which may not hang past EXIT_GRACE_S (SIGALRM's default action ends the process)."""
    signal.alarm(EXIT_GRACE_S)
    sys.exit(0)


def _die_with_parent() -> None:
    """Linux: get SIGTERM when the parent dies (the poll loop also checks getppid)."""
    try:
        libc = ctypes.CDLL("libc.so.6", use_errno=True)
        libc.prctl(1, signal.SIGTERM)  # PR_SET_PDEATHSIG
    except OSError:
        pass


def _take_engine_lock(engine: str):
    """Machine-wide lock for engines that must be alone on the machine (GPU ownership)."""
    import fcntl

    path = Path(os.environ.get("SIMSEAM_LOCK_DIR", "/tmp")) / f"simseam-engine-{engine}.lock"
    fd = os.open(path, os.O_RDWR | os.O_CREAT, 0o666)
    try:
        fcntl.flock(fd, fcntl.LOCK_EX | fcntl.LOCK_NB)
    except BlockingIOError:
        holder = os.pread(fd, 64, 0).decode(errors="replace").strip() or "unknown"
        _say(f"simseam sidecar: engine {engine!r} is already running in another sidecar (pid {holder}); "
             f"it must be alone on this machine. Close that one first (lock file {path}).")
        sys.exit(EXIT_BUSY)
    os.ftruncate(fd, 0)
    os.pwrite(fd, str(os.getpid()).encode(), 0)
    return fd


class Server:
    def __init__(self, scene, token: str, identity: str, test_hooks: bool = False):
        self.scene = scene
        self.token = token
        self.identity = identity
        self.test_hooks = test_hooks
        self.requests = 0
        self.local_path: str | None = None  # the local fast path's socket, when this server offers one
        self.ring: local.SlotRing | None = None  # the attached local client's shared-memory ring
        self.spin_s = 0.0  # the attached local client's busy-poll budget for its next request (attach)
        self.spun = 0  # local messages that arrived while busy-polling (reported by close)
        self.templates: ReplyTemplates | None = None  # the attached client's compact replies (attach)
        self.num_envs: int | None = getattr(scene, "num_envs", None)  # a batch's (None: one rollout)

    def handle(self, frames: list, ring: "local.SlotRing | None" = None, attached: bool = False) -> tuple[list, bool]:
        """Reply frames for one request, and whether to stop serving. ``ring``: put the reply's
        large arrays into this shared-memory ring; ``attached``: the request came on a local
        connection that proved the token at attach (its requests carry none), and that connection's
        compact messages (``simseam.sidecar.compact``) apply when it negotiated them."""
        tpl = self.templates if attached else None
        try:
            if tpl is not None and frames and len(frames[0]) and frames[0][0] == MAGIC:  # a compact step request
                action, state_only = decode_step(frames)
                return self._dispatch("step", {"action": action, "observe": STATE_ONLY if state_only else None},
                                      ring, attached, tpl)
            op, body = decode(frames)
        except WireError as exc:
            return encode("error", {"kind": "WireError", "message": str(exc)}), False
        return self._dispatch(op, body, ring, attached, tpl)

    def _dispatch(self, op: str, body: Any, ring: "local.SlotRing | None", attached: bool,
                  tpl: ReplyTemplates | None = None) -> tuple[list, bool]:
        ok = tpl.encode if tpl is not None else _encode_ok  # ok(body, ring): an "ok" reply
        if attached and not isinstance(body, dict):
            return encode("error", {"kind": "WireError", "message": f"body must be a map, got {type(body).__name__}"}), False
        # compare bytes: compare_digest raises TypeError on non-ASCII str (a peer could send one)
        if not attached and (not isinstance(body, dict) or not hmac.compare_digest(str(body.get("token", "")).encode(),
                                                                                   self.token.encode())):
            return encode("error", {"kind": "AccessDenied", "message": "missing or wrong token"}), False
        self.requests += 1
        try:
            if op == "hello":
                return ok(self.hello(body)), False
            if op in BATCH_OPS or op in SINGLE_OPS:
                batch = self.num_envs is not None
                if batch != (op in BATCH_OPS):
                    raise WireError(f"{op!r}: this sidecar serves " + (f"a batch of {self.num_envs} environments"
                                                                       if batch else "one rollout"))
            if op == "batch_reset":
                obs = self.scene.reset(body.get("envs"), body.get("seeds"), self._requests(body))
                return ok({"obs": obs, "failures": self._failures()}, ring), False
            if op == "batch_step":
                r = self.scene.step(body.get("envs"), body.get("actions"), self._requests(body))
                return ok({"obs": r.observations, "reward": np.asarray(r.reward, dtype=np.float64),
                           "terminated": np.asarray(r.terminated, dtype=bool),
                           "truncated": np.asarray(r.truncated, dtype=bool), "info": list(r.infos),
                           "failures": self._failures()}, ring), False
            if op == "batch_render":
                return ok({"frame": self.scene.render(body.get("env"))}, ring), False
            if op == "reset":
                seed = body.get("seed")
                if seed is not None and (not isinstance(seed, int) or isinstance(seed, bool)):
                    raise WireError(f"reset: seed must be an int or null, got {seed!r}")
                return ok({"obs": self.scene.reset(seed, self._request(body))}, ring), False
            if op == "step":
                r = self.scene.step(body.get("action"), self._request(body))
                info = {k: v for k, v in r.info.items()}
                return ok({"obs": r.observation, "reward": r.reward, "terminated": r.terminated,
                           "truncated": r.truncated, "info": info}, ring), False
            if op == "render":
                return ok({"frame": self.scene.render()}, ring), False
            if op == "close":
                return ok({"requests": self.requests, "spun": self.spun,
                           "compact": 0 if tpl is None else tpl.compact}), True
            if self.test_hooks and op == "_sleep":
                time.sleep(float(body.get("seconds", 0)))
                return ok({}), False
            if self.test_hooks and op == "_exit":
                _say("simseam sidecar: exiting on request (test hook)")
                sys.stderr.flush()
                os._exit(int(body.get("code", 1)))
            return encode("error", {"kind": "UnknownOp", "message": f"unknown op {op!r}"}), False
        except Exception as exc:  # every handler failure becomes a typed reply
            return encode("error", {"kind": type(exc).__name__, "message": str(exc),
                                    "traceback": traceback.format_exc()}), False

    def _requests(self, body: dict):
        """A batch op's ``observe``: None, one request (a map) or one per environment (a list)."""
        observe = body.get("observe")
        if isinstance(observe, list):
            return [self._request({"observe": o}) for o in observe]
        return self._request(body)

    def _failures(self) -> dict:
        """The batch's failed environments since the last reply, as wire data."""
        return {str(env): {"message": f.message, "lost": f.lost, "what_next": f.what_next, "exitcode": f.exitcode}
                for env, f in self.scene.failures().items()}

    @staticmethod
    def _request(body: dict) -> ObsRequest:
        """The ``observe`` field of a reset/step body as an ``ObsRequest`` (None: everything; a
        compact step request's is one already)."""
        observe = body.get("observe")
        if type(observe) is ObsRequest:
            return observe
        try:
            return ObsRequest.from_json(observe)
        except ConfigError as exc:
            raise WireError(str(exc)) from None

    def hello(self, body: dict) -> dict:
        if body.get("protocol") != PROTOCOL_VERSION:
            raise WireError(f"client speaks protocol {body.get('protocol')!r}, server {PROTOCOL_VERSION}")
        out = {
            "protocol": PROTOCOL_VERSION,
            "identity": self.identity,
            "pid": os.getpid(),
            "python": sys.version.split()[0],
            "simseam": str(origin.source_dir()),  # the client checks it runs its own simseam
            "spec": self.scene.spec.to_json(),
        }
        if self.num_envs is not None:
            out["num_envs"] = self.num_envs
        if body.get("local") is True and self.local_path is not None:
            out["local"] = {"path": self.local_path}
        return out

    def attach(self, frames: list) -> tuple[list, list[int]]:
        """Reply (and the ring's fd to pass) to the first message on a local connection:
        ``attach`` with the token. Makes a fresh ring sized from the spec (the previous one,
        if any, goes: one local client at a time)."""
        try:
            op, body = decode(frames)
        except WireError as exc:
            return encode("error", {"kind": "WireError", "message": str(exc)}), []
        if not isinstance(body, dict) or not hmac.compare_digest(str(body.get("token", "")).encode(),
                                                                 self.token.encode()):
            return encode("error", {"kind": "AccessDenied", "message": "missing or wrong token"}), []
        if op != "attach":
            return encode("error", {"kind": "WireError",
                                    "message": f"the first message on the local socket must be 'attach', got {op!r}"}), []
        slots = body.get("slots", local.DEFAULT_SLOTS)
        if not isinstance(slots, int) or isinstance(slots, bool) or not 2 <= slots <= 64:
            return encode("error", {"kind": "WireError", "message": f"attach: slots must be 2..64, got {slots!r}"}), []
        compact = body.get("compact", 0)
        if not isinstance(compact, int) or isinstance(compact, bool) or compact < 0:
            return encode("error", {"kind": "WireError",
                                    "message": f"attach: compact must be a version number >= 0, got {compact!r}"}), []
        spin = body.get("spin_us", 0)
        if not isinstance(spin, int) or isinstance(spin, bool) or not 0 <= spin <= local.MAX_SPIN_US:
            return encode("error", {"kind": "WireError",
                                    "message": f"attach: spin_us must be 0..{local.MAX_SPIN_US}, got {spin!r}"}), []
        self.spin_s = spin * 1e-6
        self.detach()  # the previous local client's ring (its connection is closed by the caller)
        reply: dict = {"ring": None}
        if compact >= COMPACT_VERSION:  # the client asked for compact step messages: confirm the version spoken
            self.templates = ReplyTemplates()
            reply["compact"] = COMPACT_VERSION
        size = local.slot_bytes_for(self.scene.spec.to_json()) * (self.num_envs or 1)
        if size == 0:  # nothing large to share: the local socket alone
            return encode("ok", reply), []
        self.ring = local.SlotRing(slots, size)
        reply["ring"] = self.ring.layout()
        return encode("ok", reply), [self.ring.fd]

    def detach(self) -> None:
        self.templates = None
        if self.ring is not None:
            self.ring.close()
            self.ring = None


def _encode_ok(body: Any, ring: "local.SlotRing | None" = None) -> list:
    return encode("ok", body, ring)


def local_listener(path: str) -> socket.socket:
    """The local fast path's listening Unix socket (owner-only, in the private directory)."""
    try:
        os.unlink(path)
    except FileNotFoundError:
        pass
    lsock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
    old = os.umask(0o177)
    try:
        lsock.bind(path)
    finally:
        os.umask(old)
    lsock.listen(4)
    return lsock


def _is_ok(frames: list) -> bool:
    try:
        return decode(frames)[0] == "ok"
    except WireError:
        return False


def build_scene(target: Target, num_envs: int | None = None):
    """The rollout ``target`` describes; with ``num_envs``, a batch of that many (the backend's own batch
    when it has one, else copies stepped in turn)."""
    if num_envs is not None:
        if not isinstance(num_envs, int) or isinstance(num_envs, bool) or num_envs < 1:
            raise ConfigError(f"boot: num_envs must be an int >= 1, got {num_envs!r}")
        if isinstance(target, BackendTarget):
            from simseam.backends import make_backend_batch

            return make_backend_batch(target.backend, dict(target.config), num_envs)
        from simseam.seam import SyncBatchRollout

        return SyncBatchRollout([build_scene(target) for _ in range(num_envs)])
    if isinstance(target, BackendTarget):
        from simseam.backends import make_backend_rollout

        return make_backend_rollout(target.backend, dict(target.config))
    from simseam.robot.spec import RobotSpec
    from simseam.scene.manifest_scene import ManifestScene, SceneOptions

    opts = dict(target.options)
    if opts.get("image_size") is not None:
        opts["image_size"] = tuple(opts["image_size"])
    return ManifestScene(RobotSpec.from_json(target.spec), target.task, target.engine, SceneOptions(**opts))


class LocalClients:
    """The same-machine clients of one sidecar (the fast path beside zmq): connections that have not
    attached yet, and the one attached client, whose requests are served while the next comes within
    its spin. One local client at a time: the newest attached one."""

    def __init__(self, listener: socket.socket, poller: Any, server: Server):
        self.listener, self.poller, self.server = listener, poller, server
        self.conn: socket.socket | None = None
        self.pending: list[socket.socket] = []
        self.conn_poll = None  # a select.poll on conn alone: the busy-poll between its requests
        poller.register(listener, zmq.POLLIN)

    @staticmethod
    def _in(sock: socket.socket, events: dict) -> bool:
        return sock in events or sock.fileno() in events

    def handle(self, events: dict) -> bool:
        """Accept a new connection and serve every ready one; True when a request stopped the server."""
        if self._in(self.listener, events):
            new, _ = self.listener.accept()
            new.settimeout(10.0)  # a message that starts must finish: a stalled peer is dropped
            self.pending.append(new)
            self.poller.register(new, zmq.POLLIN)
        ready = [c for c in (self.conn, *self.pending) if c is not None and self._in(c, events)]
        return any(self._serve(c) for c in ready)

    def _serve(self, c: socket.socket) -> bool:
        while True:
            keep, spin, stop = self._one(c)
            if stop:
                return True
            if not keep:
                self._drop(c)
                return False
            if not (spin and local.spin_until_readable(self.conn_poll, self.server.spin_s)):
                return False
            self.server.spun += 1

    def _one(self, c: socket.socket) -> tuple[bool, bool, bool]:
        """One message of ``c``: (keep the connection, spin for the next, stop the server)."""
        try:
            msg = local.recv_message(c)
            if msg is None:
                return False, False, False
            if c is self.conn:
                reply, stop = self.server.handle(msg[0], self.server.ring, attached=True)
                local.send_message(c, reply)
                return True, True, stop
            reply, fds = self.server.attach(msg[0])  # a new connection's first message: attach, or it goes
            local.send_message(c, reply, fds)
            if _is_ok(reply):
                self._attach(c)
                return True, False, False
            return False, False, False
        except (WireError, OSError) as exc:  # garbage framing, a stalled or vanished peer
            _say(f"simseam sidecar: local connection dropped: {exc}")
            return False, False, False

    def _attach(self, c: socket.socket) -> None:
        self.pending.remove(c)
        if self.conn is not None:
            self.poller.unregister(self.conn)
            self.conn.close()
        self.conn = c
        self.conn_poll = select.poll()
        self.conn_poll.register(c, select.POLLIN)

    def _drop(self, c: socket.socket) -> None:
        self.poller.unregister(c)
        c.close()
        if c is self.conn:
            self.conn = None
            self.server.detach()
        else:
            self.pending.remove(c)

    def close(self) -> None:
        for c in (self.conn, *self.pending):
            if c is not None:
                c.close()
        self.listener.close()
        if self.server.local_path:
            try:
                os.unlink(self.server.local_path)
            except OSError:
                pass


def _boot(boot: dict):
    """The scene the boot message names, and the engine lock when it needs one; an int exit code when it
    cannot be built (reported to the client as a typed error first)."""
    try:
        target = target_from_json(boot.get("target"))
    except ConfigError as exc:
        _emit("error", kind=type(exc).__name__, message=str(exc), traceback="")
        _say(f"simseam sidecar: cannot build the scene: {exc}")
        return EXIT_BOOT_ERROR
    lock = _take_engine_lock(target.engine) if boot.get("exclusive") or target.engine in EXCLUSIVE_ENGINES else None
    _emit("boot", stage=f"building {target.describe()}")
    os.environ["SIMSEAM_SIDECAR"] = "1"  # sidecar-only engines (isaac) are made only in this process
    try:
        return build_scene(target, boot.get("num_envs")), lock
    except Exception as exc:  # reported to the client as a typed error, then exit
        _emit("error", kind=type(exc).__name__, message=str(exc), traceback=traceback.format_exc())
        _say(f"simseam sidecar: cannot build the scene: {type(exc).__name__}: {exc}")
        if lock is not None:
            os.close(lock)
        return EXIT_BOOT_ERROR


def _register(boot: dict, endpoint: str) -> Path | None:
    """The registry file a client finds this sidecar by (``registry_dir``), owner-only."""
    if not boot.get("registry_dir"):
        return None
    registry = Path(boot["registry_dir"]) / f"{boot['identity']}.json"
    fd = os.open(registry, os.O_WRONLY | os.O_CREAT | os.O_TRUNC, 0o600)
    with os.fdopen(fd, "w") as f:
        json.dump({"endpoint": endpoint, "token": boot["token"], "pid": os.getpid(), "identity": boot["identity"]}, f)
    return registry


def serve(boot: dict) -> int:
    keep_alive = bool(boot.get("keep_alive"))
    parent = None if keep_alive else os.getppid()  # before the (slow) build: a parent gone meanwhile is seen
    if not keep_alive:
        _die_with_parent()
    signal.signal(signal.SIGTERM, _exit_on_sigterm)
    booted = _boot(boot)
    if isinstance(booted, int):
        return booted
    scene, lock = booted
    ctx = zmq.Context()
    sock = ctx.socket(zmq.REP)
    sock.setsockopt(zmq.LINGER, 0)
    registry = server = clients = None
    try:
        sock.bind(boot["endpoint"])
        endpoint = sock.getsockopt_string(zmq.LAST_ENDPOINT)
        registry = _register(boot, endpoint)
        server = Server(scene, boot["token"], boot["identity"], test_hooks=os.environ.get(TEST_HOOKS_ENV) == "1")
        poller = zmq.Poller()
        poller.register(sock, zmq.POLLIN)
        if endpoint.startswith("ipc://") and hasattr(os, "memfd_create"):  # same machine: offer the fast path
            listener = local_listener(os.path.join(os.path.dirname(endpoint[len("ipc://"):]), "local.sock"))
            server.local_path = listener.getsockname()
            clients = LocalClients(listener, poller, server)
        _emit("ready", endpoint=endpoint, pid=os.getpid(), identity=boot["identity"])
        return _loop(sock, poller, server, clients, parent)
    finally:  # a second SIGTERM must not cut this short: a context left unterminated hangs the exit
        signal.signal(signal.SIGTERM, signal.SIG_IGN)
        # the private folder of its sockets goes with it: a client that closes it removes the folder too, but a
        # client that died, or a kept-alive sidecar's, cannot; first, before anything that could outlast the
        # exit's grace period (SIGALRM ends the process)
        _remove_private_dir(boot["endpoint"])
        sock.close(0)
        ctx.destroy(0)
        if clients is not None:
            clients.close()
        if server is not None:
            server.detach()
        if registry is not None:
            registry.unlink(missing_ok=True)
        scene.close()
        if lock is not None:
            os.close(lock)


def _remove_private_dir(endpoint: str) -> None:
    if endpoint.startswith("ipc://"):
        shutil.rmtree(os.path.dirname(endpoint[len("ipc://"):]), ignore_errors=True)


def _loop(sock: Any, poller: Any, server: Server, clients: LocalClients | None, parent: int | None) -> int:
    """Serve zmq and local requests until one stops the server or the ``parent`` process (when given) goes."""
    parent_checked = time.monotonic()  # when the loop last checked that its parent is alive
    while True:
        events = dict(poller.poll(500))
        now = time.monotonic()
        if not events or now - parent_checked >= 0.5:  # also while events keep coming
            parent_checked = now
            if parent is not None and os.getppid() != parent:
                _say("simseam sidecar: parent process is gone, exiting")
                return 0
        if not events:
            continue
        if sock in events:
            reply, stop = server.handle(sock.recv_multipart(copy=False))
            sock.send_multipart(reply, copy=False)
            if stop:
                return 0
        if clients is not None and clients.handle(events):
            return 0


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(prog="simseam sidecar serve", description="Serve one scene over the sidecar wire.")
    ap.add_argument("--boot", required=True, help="boot file (JSON) written by the client; deleted once read")
    args = ap.parse_args(argv)
    path = Path(args.boot)
    try:
        boot = json.loads(path.read_text())
    except (OSError, ValueError) as exc:
        _say(f"simseam sidecar: cannot read boot file {path}: {exc}")
        return 2
    path.unlink(missing_ok=True)
    return serve(boot)


if __name__ == "__main__":
    sys.exit(main())
