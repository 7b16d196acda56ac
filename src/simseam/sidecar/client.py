"""SidecarRollout: the ``SimRollout`` seam, served by a scene in another process.

The client spawns ``python -m simseam.sidecar.server`` with the configured
interpreter (its own virtualenv, its own CUDA stack), in a new process session,
with a sanitized environment (PYTHONPATH, PYTHONHOME, VIRTUAL_ENV and friends
removed), and talks to it over ZeroMQ with ``simseam.sidecar.wire``. Whatever the
interpreter, the sidecar runs this process's own simseam: its PYTHONPATH is one private
directory holding a link to this process's ``simseam`` package and nothing else, so a
clone never drives another clone's server code (``hello`` reports the directory the
sidecar imported simseam from; ``server_simseam``).

Access: by default a private ``ipc://`` socket inside a fresh 0700 directory;
with ``transport="tcp"`` a socket bound to 127.0.0.1 on a random port. Either
way every request carries a random per-launch token, and ``hello`` checks the
sidecar serves exactly this target from this simseam source (its identity: a hash of
the ``SceneTarget`` or ``BackendTarget``, ``sidecar.target``, and ``origin.source_dir()``)
before anything else is sent.

Failure handling: while waiting for a reply the client polls in 50 ms slices
and checks the process, so a sidecar that dies (crash, kill -9, import error)
raises ``SidecarCrashed`` with its exit code and the tail of its stderr within
a fraction of a second, during boot or mid-episode; a hung one raises
``SidecarTimeout`` after ``request_timeout`` seconds. ``close()``, interpreter
exit and SIGTERM reap every sidecar this process started; ``restart()`` starts
a fresh one after a crash.

Local fast path (``simseam.sidecar.local``): with the ``ipc`` transport (same machine)
``hello`` offers a plain Unix socket and shared-memory ring slots; the client switches
to them (``local=False`` keeps ZeroMQ). Large arrays of an observation (the camera
images) are then read-only views into a ring slot, valid until the slot is reused:
``local_slots - 1`` further replies that carry large arrays (default 2 slots: an
observation stays intact through the next ``step``/``reset``/``render``, not longer).
Copy what you keep longer (``np.array(obs["images"][k])``).

Reuse: one sidecar serves any number of episodes (reset does not rebuild the
scene). With ``keep_alive=True`` the sidecar outlives this client and registers
itself (endpoint, token, pid, identity) in a private per-user directory; a later
client with the same identity adopts it instead of booting a new one, and never
drives a sidecar whose identity differs: another clone's kept-alive sidecar of the
same target is never adopted (nor one whose ``hello`` names another simseam source).
"""

from __future__ import annotations

import atexit
import collections
import hashlib
import json
import os
import queue
import secrets
import shutil
import signal
import subprocess
import sys
import tempfile
import threading
import time
import weakref
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np
import zmq

from simseam import origin
from simseam.seam import (
    CAP_RESTART,
    FULL,
    STATE_ONLY,
    ConfigError,
    ObsRequest,
    Observation,
    RolloutSpec,
    StepResult,
    check_action,
)
from simseam.seam.batch import (BatchStepResult, EnvFailure, Requests, SyncStepPair, batch_actions, env_indices,
                                per_env_requests)
from simseam.sidecar.errors import (
    SidecarAccessError,
    SidecarBusy,
    SidecarCrashed,
    SidecarProtocolError,
    SidecarTimeout,
    remote_error,
)
from simseam.sidecar import local
from simseam.sidecar.target import BackendTarget, SceneTarget, Target
from simseam.sidecar.compact import ReplyDecoder, encode_step
from simseam.sidecar.local import MAX_SPIN_US, default_spin_us
from simseam.sidecar.wire import PROTOCOL_VERSION, WireError, decode, encode

SANITIZED_ENV = ("PYTHONPATH", "PYTHONHOME", "VIRTUAL_ENV", "PYTHONSTARTUP", "PYTHONUSERBASE",
                 "__PYVENV_LAUNCHER__", "CONDA_PREFIX")
POLL_SLICE_MS = 50
STDERR_LINES = 40
EXIT_BUSY = 3


def registry_dir() -> Path:
    """Per-user directory (0700) where kept-alive sidecars register themselves."""
    base = os.environ.get("XDG_RUNTIME_DIR") or os.path.join(tempfile.gettempdir(), f"simseam-{os.getuid()}")
    path = Path(base) / "simseam-sidecars"
    path.mkdir(parents=True, exist_ok=True, mode=0o700)
    os.chmod(path, 0o700)
    return path


def identity_of(target: Target) -> str:
    """A sidecar's identity: its target and the simseam source serving it (this process's). Another
    clone's kept-alive sidecar of the same target registers under another name and is never adopted."""
    return hashlib.sha256(f"{target.identity()}:{origin.source_dir()}".encode()).hexdigest()[:32]


def sanitized_env(extra: dict[str, str] | None = None) -> dict[str, str]:
    env = {k: v for k, v in os.environ.items() if k not in SANITIZED_ENV}
    env.setdefault("MUJOCO_GL", "egl")
    env.update(extra or {})
    return env


_LIVE: "weakref.WeakSet[SidecarRollout]" = weakref.WeakSet()
_HOOKS_INSTALLED = False


def _reap_all(*_args: Any) -> None:
    for rollout in list(_LIVE):
        rollout._reap(graceful=False)


def _install_hooks() -> None:
    """Reap our sidecars at interpreter exit and on SIGTERM (when nobody else handles it)."""
    global _HOOKS_INSTALLED
    if _HOOKS_INSTALLED:
        return
    _HOOKS_INSTALLED = True
    atexit.register(_reap_all)
    if threading.current_thread() is threading.main_thread() and signal.getsignal(signal.SIGTERM) in (
            signal.SIG_DFL, None):
        def on_term(signum, frame):
            _reap_all()
            signal.signal(signal.SIGTERM, signal.SIG_DFL)
            os.kill(os.getpid(), signal.SIGTERM)

        signal.signal(signal.SIGTERM, on_term)


class _Process:
    """A spawned sidecar: the Popen, its boot events and the tail of its stderr."""

    def __init__(self, argv: list[str], env: dict[str, str]):
        self.popen = subprocess.Popen(argv, stdin=subprocess.DEVNULL, stdout=subprocess.PIPE,
                                      stderr=subprocess.PIPE, env=env, start_new_session=True, close_fds=True)
        self.events: queue.Queue = queue.Queue()
        self.stderr: collections.deque[str] = collections.deque(maxlen=STDERR_LINES)
        self._threads = [threading.Thread(target=self._read_stdout, daemon=True),
                         threading.Thread(target=self._read_stderr, daemon=True)]
        for t in self._threads:
            t.start()

    def _read_stdout(self) -> None:
        for line in self.popen.stdout:
            try:
                self.events.put(json.loads(line))
            except ValueError:
                self.stderr.append(line.decode(errors="replace").rstrip())

    def _read_stderr(self) -> None:
        for line in self.popen.stderr:
            self.stderr.append(line.decode(errors="replace").rstrip())

    @property
    def pid(self) -> int:
        return self.popen.pid

    def exit_code(self) -> int | None:
        return self.popen.poll()

    def stderr_tail(self) -> str:
        for t in self._threads:  # the pipes close when the process dies: drain them
            t.join(timeout=0.5)
        return "\n".join(self.stderr)

    def kill(self, graceful_s: float = 2.0) -> None:
        """SIGTERM the sidecar's process group, SIGKILL what is left after ``graceful_s``."""
        if self.popen.poll() is None:
            try:
                os.killpg(self.popen.pid, signal.SIGTERM)
            except ProcessLookupError:
                pass
            try:
                self.popen.wait(graceful_s)
            except subprocess.TimeoutExpired:
                pass
        try:
            os.killpg(self.popen.pid, signal.SIGKILL)  # stragglers of the group (engine helpers)
        except (ProcessLookupError, PermissionError):
            pass
        try:
            self.popen.wait(5)
        except subprocess.TimeoutExpired:
            pass
        for pipe in (self.popen.stdout, self.popen.stderr):
            if pipe is not None:
                pipe.close()


class SidecarRollout:
    """A ``SimRollout`` whose scene lives in a sidecar process.

    ``target``: what it serves (``sidecar.target``): a ``SceneTarget`` (a manifest scene) or a
    ``BackendTarget`` (a benchmark backend, whose interpreter gets this process's ``simseam`` package on
    its path, a symlink in the private directory, so a backend venv needs no copy of it); the rest says
    how. ``python``: the sidecar's interpreter (default: this one). ``progress``: called with each boot
    stage (a str).

    ``local`` (default True): with ``transport="ipc"``, use the local fast path the sidecar offers
    (Unix socket + shared-memory ring of ``local_slots`` slots; ``self.fast`` says whether it was
    taken). Lifetime contract there: the observation's large arrays (images, anything of 1 kB or
    more) are read-only views into a ring slot, valid until that slot is reused, i.e. through
    ``local_slots - 1`` further image-carrying replies (default: the previous observation stays
    intact while the next step runs; the one before it does not). ``render()`` returns such a
    view too. Copy what you keep longer; the episode loop's recorders do. ``spin_us``: on the local
    path, how long each side busy-polls for the other's next message before sleeping (default:
    ``local.default_spin_us()``: 1000 with at least 4 usable cores, else 0; ``$SIMSEAM_SIDECAR_SPIN_US``).
    ``compact`` (default True): on the local path, ask the sidecar for compact step messages
    (``simseam.sidecar.compact``: a state-only or default step request as one binary frame, replies
    as templates; ``self.compact`` says whether it agreed); the observations are the same either way.
    """

    _num_envs: int | None = None  # a batch's environments (SidecarBatchRollout); None: one rollout
    _want_local = False  # (class defaults: a client made with __new__ speaks plain ZeroMQ)
    _spin_us = 0
    _slots: list | None = None
    _decoder: ReplyDecoder | None = None
    fast = False
    compact = False

    def __init__(self, target: Target, *, python: str | None = None, transport: str = "ipc", boot_timeout: float = 120.0,
                 request_timeout: float = 30.0, keep_alive: bool = False, exclusive: bool = False,
                 progress: Callable[[str], None] | None = None, env: dict[str, str] | None = None,
                 local: bool = True, local_slots: int = local.DEFAULT_SLOTS, spin_us: int | None = None,
                 compact: bool = True):
        if transport not in ("ipc", "tcp"):
            raise ConfigError(f"sidecar transport must be 'ipc' or 'tcp', got {transport!r}")
        if not isinstance(local_slots, int) or not 2 <= local_slots <= 64:
            raise ConfigError(f"sidecar local_slots must be an int in 2..64, got {local_slots!r}")
        self._want_local = bool(local) and transport == "ipc"
        self._want_compact = bool(compact)
        self._local_slots = local_slots
        try:
            self._spin_us = default_spin_us() if spin_us is None else int(spin_us)
        except ValueError as exc:
            raise ConfigError(str(exc)) from None
        if not 0 <= self._spin_us <= MAX_SPIN_US:
            raise ConfigError(f"sidecar spin_us must be 0..{MAX_SPIN_US}, got {spin_us!r}")
        self._slots: list | None = None  # the shared-memory ring's slots, when on the local path
        self.fast = False  # whether requests use the local fast path
        self.compact = False  # whether step messages may travel compact on it
        self._decoder = None
        if not isinstance(target, (SceneTarget, BackendTarget)):
            raise ConfigError(f"a sidecar serves a SceneTarget or a BackendTarget, got {type(target).__name__}")
        self.target = target
        self._engine = target.engine
        self._python = python or sys.executable
        self._transport = transport
        self._boot_timeout = boot_timeout
        self.request_timeout = request_timeout
        self._keep_alive = keep_alive
        self._exclusive = exclusive
        self._progress = progress or (lambda stage: None)
        self._extra_env = env
        self.identity = identity_of(target)
        self._ctx = zmq.Context.instance()
        self._sock: zmq.Socket | None = None
        self._proc: _Process | None = None
        self._adopted_pid: int | None = None
        self._dir: str | None = None
        self._closed = False
        self._frame: np.ndarray | None = None
        _install_hooks()
        _LIVE.add(self)
        if keep_alive and self._adopt():
            return
        self._start()

    # ------------------------------------------------------------------ boot
    def _start(self) -> None:
        if not shutil.which(self._python) and not os.path.exists(self._python):
            if self._engine == "isaac":  # the interpreter is the provisioned Isaac Sim venv
                from simseam.engines.isaac.provision import provision_hint
                from simseam.seam import BackendUnavailableError

                raise BackendUnavailableError(f"Isaac Sim is not provisioned here: the sidecar interpreter "
                                              f"{self._python!r} does not exist. {provision_hint()}")
            if isinstance(self.target, BackendTarget):
                from simseam.backends.provision import require

                require(self.target.backend)  # raises with the provisioning command
            raise ConfigError(f"sidecar interpreter {self._python!r} not found")
        self._dir = tempfile.mkdtemp(prefix="simseam-sidecar-")  # 0700
        os.chmod(self._dir, 0o700)
        self._token = secrets.token_hex(16)
        endpoint = f"ipc://{self._dir}/scene.sock" if self._transport == "ipc" else "tcp://127.0.0.1:*"
        boot = {"target": self.target.to_json(), "endpoint": endpoint, "token": self._token, "identity": self.identity,
                "exclusive": self._exclusive, "keep_alive": self._keep_alive,
                "registry_dir": str(registry_dir()) if self._keep_alive else None}
        if self._num_envs is not None:
            boot["num_envs"] = self._num_envs
        env = dict(self._extra_env or {})
        # every sidecar runs this process's simseam package (a backend's venv holds none; the default
        # interpreter's venv may be shared by clones and an Isaac venv installed from another checkout)
        src = Path(self._dir) / "src"
        src.mkdir()
        os.symlink(origin.source_dir(), src / "simseam")
        env["PYTHONPATH"] = str(src)
        if isinstance(self.target, BackendTarget):
            env.setdefault("PYGAME_HIDE_SUPPORT_PROMPT", "1")
        boot_path = Path(self._dir) / "boot.json"
        fd = os.open(boot_path, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600)
        with os.fdopen(fd, "w") as f:
            json.dump(boot, f)
        self._progress(f"starting sidecar ({self._python})")
        self._proc = _Process([self._python, "-m", "simseam.sidecar.server", "--boot", str(boot_path)],
                              sanitized_env(env))
        try:
            endpoint = self._await_ready()
            self._connect(endpoint)
            self._hello()
        except BaseException:  # a failed boot leaves nothing behind: no process, no private dir
            self._discard_failed_boot()
            raise

    def _discard_failed_boot(self) -> None:
        if self._sock is not None:
            self._sock.close(0)
            self._sock = None
        if self._proc is not None:  # e.g. ready, then hello failed: killed even if keep_alive
            self._proc.kill(graceful_s=0.2)
            self._proc = None
        if self._dir is not None:
            shutil.rmtree(self._dir, ignore_errors=True)
            self._dir = None
        _LIVE.discard(self)

    def _await_ready(self) -> str:
        deadline = time.monotonic() + self._boot_timeout
        while True:
            try:
                ev = self._proc.events.get(timeout=POLL_SLICE_MS / 1000)
            except queue.Empty:
                ev = None
            if ev is not None:
                if ev.get("event") == "boot":
                    self._progress(str(ev.get("stage")))
                elif ev.get("event") == "ready":
                    return str(ev["endpoint"])
                elif ev.get("event") == "error":
                    self._proc.kill()
                    self._proc = None
                    raise remote_error(str(ev.get("kind")), str(ev.get("message")), str(ev.get("traceback", "")))
                continue
            code = self._proc.exit_code()
            if code is not None:
                self._crashed("while booting")
            if time.monotonic() > deadline:
                tail = self._proc.stderr_tail()
                self._proc.kill()
                self._proc = None
                raise SidecarTimeout(f"sidecar did not become ready within {self._boot_timeout:.0f} s"
                                     + (f"; its stderr ends with:\n{tail}" if tail else ""))

    def _connect(self, endpoint: str) -> None:
        sock = self._ctx.socket(zmq.REQ)
        sock.setsockopt(zmq.LINGER, 0)
        sock.setsockopt(zmq.REQ_RELAXED, 1)
        sock.setsockopt(zmq.REQ_CORRELATE, 1)
        sock.connect(endpoint)
        self._sock = sock
        self.endpoint = endpoint

    def _hello(self) -> None:
        info = self._request("hello", {"protocol": PROTOCOL_VERSION, "client_pid": os.getpid(),
                                       "local": self._want_local}, during="hello")
        if info.get("identity") != self.identity:
            self._sock.close(0)
            self._sock = None
            raise SidecarAccessError(
                f"the sidecar at {self.endpoint} serves scene {info.get('identity')!r}, not {self.identity!r}; "
                "it was not driven")
        if info.get("simseam") != str(origin.source_dir()):  # e.g. another clone's kept-alive sidecar
            self._sock.close(0)
            self._sock = None
            raise SidecarAccessError(f"the sidecar at {self.endpoint} runs simseam from {info.get('simseam')}, "
                                     f"not from {origin.source_dir()}; it was not driven")
        try:
            spec = RolloutSpec.from_json(info.get("spec"), where=f"the sidecar at {self.endpoint}: hello's spec")
        except ConfigError as exc:
            raise SidecarProtocolError(str(exc)) from None
        if info.get("num_envs") != self._num_envs:
            raise SidecarProtocolError(f"the sidecar at {self.endpoint} serves num_envs={info.get('num_envs')!r}, "
                                       f"this client asked for {self._num_envs!r}")
        caps = tuple(dict.fromkeys((*spec.capabilities, CAP_RESTART)))
        self._spec = spec.replace(backend="sidecar", capabilities=caps)
        self.server_pid = int(info["pid"])
        self.server_python = info.get("python")
        self.server_simseam = info["simseam"]
        offer = info.get("local")
        if self._want_local and isinstance(offer, dict) and isinstance(offer.get("path"), str):
            self._attach(offer["path"])

    def _attach(self, path: str) -> None:
        """Switch to the local fast path the sidecar offered (Unix socket + shared-memory ring)."""
        try:
            chan = local.LocalChannel(path, self._token, self._local_slots, timeout=self.request_timeout,
                                      spin_us=self._spin_us, compact=self._want_compact)
        except WireError as exc:
            raise SidecarProtocolError(f"the sidecar's local fast path at {path}: {exc}") from None
        except OSError as exc:  # e.g. another mount namespace: ZeroMQ still works
            self._progress(f"local fast path unavailable ({exc}); staying on ZeroMQ")
            return
        self._sock.close(0)
        self._sock = chan
        self._slots = chan.slots
        self.fast = True
        if chan.compact:
            self._decoder = ReplyDecoder(chan.slots)
            chan.on_stale = self._decoder.learn  # a dropped reply may announce a template
            self.compact = True

    def _adopt(self) -> bool:
        """Adopt a kept-alive sidecar of the same identity, if one is registered and alive."""
        entry_path = registry_dir() / f"{self.identity}.json"
        try:
            entry = json.loads(entry_path.read_text())
            pid = int(entry["pid"])
            os.kill(pid, 0)
        except (OSError, ValueError, KeyError):
            return False
        self._token = str(entry["token"])
        self._adopted_pid = pid
        self._connect(str(entry["endpoint"]))
        try:
            self._hello()
        except (SidecarAccessError, SidecarTimeout, SidecarCrashed, SidecarProtocolError):
            if self._sock is not None:
                self._sock.close(0)
                self._sock = None
            self._adopted_pid = None
            return False
        self._progress(f"adopted running sidecar pid {pid}")
        return True

    # --------------------------------------------------------------- requests
    def _alive_code(self) -> int | None:
        """None while the sidecar lives, else its exit code (-1 if unknown: adopted)."""
        if self._proc is not None:
            return self._proc.exit_code()
        if self._adopted_pid is not None:
            try:
                os.kill(self._adopted_pid, 0)
                return None
            except ProcessLookupError:
                return -1
            except PermissionError:
                return None
        return -1

    def _local_lost(self, during: str) -> None:
        """The local connection ended: a crash (the usual case: the process is exiting), else the
        sidecar dropped us. Raises either way."""
        deadline = time.monotonic() + 5.0  # the kernel closes the socket just before the exit is visible
        while self._alive_code() is None and time.monotonic() < deadline:
            if self._proc is not None:
                try:
                    self._proc.popen.wait(POLL_SLICE_MS / 1000)
                except subprocess.TimeoutExpired:
                    pass
            else:
                time.sleep(POLL_SLICE_MS / 1000)
        if self._alive_code() is not None:
            self._crashed(during)
        self._sock.close(0)
        self._sock = None
        raise SidecarCrashed(f"the sidecar closed the local connection {during} while still running "
                             "(another client attached to it?); call restart()")

    def _crashed(self, during: str) -> None:
        proc, self._proc = self._proc, None
        code = proc.exit_code() if proc is not None else None
        tail = proc.stderr_tail() if proc is not None else ""
        if proc is not None:
            proc.kill(graceful_s=0)
        if self._sock is not None:
            self._sock.close(0)
            self._sock = None
        if code == EXIT_BUSY:
            raise SidecarBusy(tail or "the engine is already running in another sidecar")
        how = f"exit code {code}" if code is not None and code >= 0 else (
            f"killed by signal {-code}" if code is not None else "gone")
        raise SidecarCrashed(f"sidecar crashed {during} ({how})" + (f"; its stderr ends with:\n{tail}" if tail else ""),
                             exit_code=code, stderr_tail=tail)

    def _request(self, op: str, body: dict | None, during: str | None = None, timeout: float | None = None,
                 frames: list | None = None) -> Any:
        """The reply body to request ``op`` with ``body`` (or the request's ready ``frames``: a compact
        step request)."""
        if self._closed:
            raise SidecarCrashed("the sidecar rollout is closed")
        if self._sock is None:
            raise SidecarCrashed("the sidecar is gone (crashed earlier); call restart()")
        if frames is None:
            if not self.fast:  # the local connection proved the token once, at attach
                body["token"] = self._token
            frames = encode(op, body)
        during = during or f"during {op}"
        try:
            self._sock.send_multipart(frames, copy=False)
            deadline = time.monotonic() + (self.request_timeout if timeout is None else timeout)
            while not self._sock.poll(POLL_SLICE_MS):
                if self._alive_code() is not None:
                    self._crashed(during)
                if time.monotonic() > deadline:
                    raise SidecarTimeout(f"the sidecar did not answer {op!r} within "
                                         f"{self.request_timeout if timeout is None else timeout:.1f} s (hung?)")
            frames = self._sock.recv_multipart(copy=False)
            kind, reply = decode(frames, self._slots) if self._decoder is None else self._decoder.decode(frames)
        except WireError as exc:
            raise SidecarProtocolError(f"malformed reply to {op!r}: {exc}") from None
        except OSError:  # the local connection broke (BrokenPipe, reset, closed): the sidecar died?
            self._local_lost(during)
        if kind == "error":
            if reply.get("kind") == "AccessDenied":
                raise SidecarAccessError(f"the sidecar refused {op!r}: {reply.get('message')}")
            if reply.get("kind") == "WireError" and op == "hello":
                raise SidecarProtocolError(str(reply.get("message")))
            raise remote_error(str(reply.get("kind")), str(reply.get("message")), str(reply.get("traceback", "")))
        return reply

    # ------------------------------------------------------------------- seam
    @property
    def spec(self) -> RolloutSpec:
        return self._spec

    @property
    def action_dim(self) -> int:
        return self._spec.action.dim

    def reset(self, seed: int | None = None, observe: ObsRequest | None = None) -> Observation:
        body = {"seed": None if seed is None else int(seed)}
        if observe is not None:
            body["observe"] = observe.to_json()
        reply = self._request("reset", body)
        obs = reply["obs"]
        self._sim_time = int(obs["sim_time_ns"])
        self._frame = self._first_image(obs)
        return obs

    def step(self, action: np.ndarray, observe: ObsRequest | None = None) -> StepResult:
        a = check_action(action, self.action_dim)  # fail fast, locally, before a round trip
        if self._decoder is not None and (observe is None or observe == STATE_ONLY or observe == FULL):
            r = self._request("step", None, frames=encode_step(a, observe == STATE_ONLY))  # one binary frame
        else:
            body = {"action": a}
            if observe is not None:
                body["observe"] = observe.to_json()
            r = self._request("step", body)
        obs = r["obs"]
        self._sim_time = int(obs["sim_time_ns"])
        self._frame = self._first_image(obs)
        return StepResult(obs, float(r["reward"]), bool(r["terminated"]), bool(r["truncated"]), dict(r["info"]))

    def _first_image(self, obs: Observation) -> np.ndarray | None:
        """The first RGB camera's frame when this observation carries it (render() re-uses it)."""
        first = next(iter(self._spec.cameras), None)
        return (obs.get("images") or {}).get(first) if first is not None else None

    def render(self) -> np.ndarray | None:
        if self._frame is None:
            self._frame = self._request("render", {})["frame"]
        return self._frame

    def sim_time_ns(self) -> int:
        return getattr(self, "_sim_time", 0)

    # -------------------------------------------------------------- lifecycle
    @property
    def pid(self) -> int | None:
        return self._proc.pid if self._proc is not None else self._adopted_pid

    def restart(self) -> None:
        """Start a fresh sidecar (same scene) after a crash or a hang."""
        self._reap(graceful=False)
        self._closed = False
        _LIVE.add(self)
        self._start()

    def close(self) -> None:
        """Ask the sidecar to exit, then reap it (kept-alive sidecars are left running)."""
        if self._closed:
            return
        if self._sock is not None and not self._keep_alive:
            try:
                self._request("close", {}, timeout=2.0)
            except Exception:
                pass
        self._reap(graceful=True)

    def _reap(self, graceful: bool) -> None:
        self._closed = True
        if self._sock is not None:
            self._sock.close(0)
            self._sock = None
        self._slots = None
        self.fast = False
        self.compact = False
        if self._decoder is not None:
            self._decoder.slots = None  # the mapping goes with the last observation that views it
        self._decoder = None
        self._frame = None
        if self._proc is not None and not self._keep_alive:
            self._proc.kill(graceful_s=2.0 if graceful else 0.2)
        self._proc = None
        if self._dir is not None and not self._keep_alive:
            shutil.rmtree(self._dir, ignore_errors=True)
        self._dir = None
        _LIVE.discard(self)

    def __enter__(self) -> "SidecarRollout":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


class SidecarBatchRollout(SyncStepPair, SidecarRollout):
    """A ``BatchRollout`` (seam/batch.py) of ``num_envs`` environments served by one sidecar: the backend's
    own batch when it simulates them together (ManiSkill3's GPU physics), else ``num_envs`` copies the
    sidecar steps in turn. Same boot, transport, crash handling and arguments as ``SidecarRollout``
    (``keep_alive`` aside). Environments that fail alone inside the sidecar come back from ``failures()``;
    a sidecar that crashes raises, as a single rollout's does (the whole batch is in it)."""

    def __init__(self, num_envs: int, *args: Any, **kwargs: Any):
        if not isinstance(num_envs, int) or isinstance(num_envs, bool) or num_envs < 1:
            raise ConfigError(f"a sidecar batch needs num_envs >= 1, got {num_envs!r}")
        if kwargs.get("keep_alive"):
            raise ConfigError("a sidecar batch cannot be kept alive (keep_alive): it is one run's")
        self._num_envs = num_envs
        self._failed: dict[int, EnvFailure] = {}
        super().__init__(*args, **{**kwargs, "compact": False})

    @property
    def num_envs(self) -> int:
        return self._num_envs

    def reset(self, envs: Sequence[int], seeds: Sequence[int | None], observe: Requests = None) -> list[Observation]:
        idx = env_indices(envs, self._num_envs, "reset").tolist()
        seeds = [None if s is None else int(s) for s in seeds]
        if len(seeds) != len(idx):
            raise ConfigError(f"reset: {len(idx)} environments but {len(seeds)} seeds")
        body = {"envs": idx, "seeds": seeds, "observe": _requests_json(observe, len(idx), "reset")}
        reply = self._request("batch_reset", body)
        self._note_failures(reply)
        return list(reply["obs"])

    def step(self, envs: Sequence[int], actions: np.ndarray, observe: Requests = None) -> BatchStepResult:
        idx = env_indices(envs, self._num_envs, "step")
        a = batch_actions(self.spec, actions, idx.size)  # fail fast, locally, before a round trip
        body = {"envs": idx.tolist(), "actions": a, "observe": _requests_json(observe, idx.size, "step")}
        r = self._request("batch_step", body)
        self._note_failures(r)
        return BatchStepResult(idx, list(r["obs"]), np.asarray(r["reward"], dtype=np.float64),
                               np.asarray(r["terminated"], dtype=bool), np.asarray(r["truncated"], dtype=bool),
                               [dict(i) for i in r["info"]])

    def render(self, env: int) -> np.ndarray | None:  # type: ignore[override]
        (e,) = env_indices([env], self._num_envs, "render").tolist()
        return self._request("batch_render", {"env": e})["frame"]

    def failures(self) -> dict[int, EnvFailure]:
        out, self._failed = self._failed, {}
        return out

    def _note_failures(self, reply: dict) -> None:
        for env, f in (reply.get("failures") or {}).items():
            self._failed[int(env)] = EnvFailure(str(f["message"]), bool(f["lost"]), str(f["what_next"]),
                                                f.get("exitcode"))

    def __enter__(self) -> "SidecarBatchRollout":
        return self


def _requests_json(observe: Requests, k: int, where: str):
    """A batch op's observation requests as wire data: None, one request, or one per environment."""
    if observe is None or isinstance(observe, ObsRequest):
        return None if observe is None else observe.to_json()
    return [None if q is None else q.to_json() for q in per_env_requests(observe, k, where)]
