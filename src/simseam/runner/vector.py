"""Vectorized episodes: worker processes, each owning one rollout or a few, driven by one batched policy.

``VectorEnv(recipe, num_envs)`` starts ``num_envs`` worker processes (``spawn``); each builds the
rollout of the same scene config (in-process MuJoCo, or a ``SidecarRollout`` whose sidecar the
worker owns) and answers ``reset`` / ``step`` / ``render`` / video commands over a pipe.
``envs_per_worker`` K > 1: each worker holds K environments (one pipe each) and serves their commands
in the order they come, so it steps one while the policy's action for another is on its way (the round
trip to this process, otherwise idle time of every worker, is hidden; with the ready rule or K policy
groups). The workers together are a ``BatchRollout`` (seam/batch.py): ``reset`` and ``step`` send each named worker its
command and wait for every reply (``step_send`` / ``step_receive``: the step in two halves, so the
policy acts for one group of workers while another steps); ``run(policy, indices)`` is the episode scheduler
(``runner.scheduler``) over this batch, the same loop as every other batch's. ``runner.whole_episodes.run_local`` puts
the policy inside each worker instead (policies that share no model): workers play whole episodes
and send back only their results. Episode ``i`` always uses seed ``seed + i``, so the per-episode
results do not depend on ``num_envs`` for a deterministic policy. A worker builds its rollout from a
recipe (``runner.recipe``: a scene's or a benchmark preset's) and, in ``run_local``, asks it for each
episode's rollout and seed base (``simseam eval``: a worker rebuilds its sidecar when the next
episode's task differs). The transport is the sidecar's own (``simseam.sidecar.local``,
``simseam.sidecar.compact``): images cross from a worker through a shared-memory ring of one slot
(``_SharedImages``), not through the pipe; a state-only step's reply and its action cross through a
second block laid out from the reply's template (``_StepBlock`` / ``_MainBlock``: one byte in the pipe,
no pickling).
``renderer="batched"``: the workers send their MuJoCo render state instead of images and this
process draws every worker's cameras in one batch (``runner.central_render``), in ``run`` only. A
worker dies with this process (Linux).

Failures:

- a worker process that dies (killed, segfault, OOM) costs nothing: a fresh worker is started in
  its place and the batch reports its environments as lost (``failures``: each one mid-episode, at its
  next step), so the scheduler puts those episodes back at the front of the queue and re-runs each from its reset (at most ``max_attempts``
  times; then it is recorded with its error). An episode is handed to ``on_done`` exactly once,
  when it has finished;
- a sidecar crash inside a worker costs that episode, recorded with its error, exactly as in the
  sequential loop (``runner.session``); the worker restarts its sidecar when the rollout declares
  the ``restart`` capability;
- any other error of a rollout (bad action, engine failure) stops the run and is raised here;
- Ctrl-C / SIGTERM: the workers ignore SIGINT; ``close()`` (``with`` block) ends them, dropping the
  episodes in flight; every finished episode has already been given to ``on_done``.
"""

from __future__ import annotations

import math
import mmap
import multiprocessing as mp
import os
import pickle
import select
import signal
import struct
import time
from dataclasses import dataclass
from multiprocessing import reduction
from multiprocessing.connection import wait as wait_any
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from simseam.runner.episodes import EpisodeResult, partial_video_path
from simseam.runner.recipe import BenchmarkRecipe, SceneRecipe
from simseam.runner.scheduler import WorkerFailure, lost_error, run_batch
from simseam.seam import (OBS_IMAGES, EnvFailure, CAP_RESTART, STATE_ONLY, ConfigError, RolloutSpec,
                          SidecarError,
                          SimseamError, SimulationError)
from simseam.runner.central_render import worker_request
from simseam.seam.batch import BatchStepResult, batch_actions, env_indices, per_env_requests
from simseam.sidecar.compact import learn, signature
from simseam.sidecar.local import (HAVE_MEMFD, SPIN_ENV, SlotRing, align, array_at, create_block, map_block, release,
                                   spin_until_readable)
from simseam.sidecar.wire import ALIGN

#: how long a worker may take to build its rollout (a cold sidecar venv boots slowly)
BOOT_TIMEOUT_S = 600.0


VECTOR_SPIN_ENV = "SIMSEAM_VECTOR_SPIN_US"
DEFAULT_VECTOR_SPIN_US = 2000  # about two state-only physics steps


def vector_spin_us(num_envs: int, cores: int) -> int:
    """How long a lockstep worker busy-polls its pipe for the next command, and this process each
    worker's pipe for its reply, before sleeping: ``$SIMSEAM_VECTOR_SPIN_US`` when set, else
    ``DEFAULT_VECTOR_SPIN_US`` when every worker has a core of its own besides the machine's current
    load (1-minute average), else 0. A process that sleeps between steps pays the wake-up and then
    runs on cold caches; with a core each, spinning costs nothing but that core's idle time (a
    spinning process yields its core between polls, so this process still gets one when it shares),
    while on a busy machine it takes the cores the simulators need."""
    raw = os.environ.get(VECTOR_SPIN_ENV, "").strip()
    if raw:
        try:
            value = int(raw)
        except ValueError:
            value = -1
        if not 0 <= value <= 100_000:
            raise ConfigError(f"{VECTOR_SPIN_ENV}={raw!r}: expected an integer number of microseconds, 0..100000")
        return value
    return DEFAULT_VECTOR_SPIN_US if num_envs + os.getloadavg()[0] <= cores else 0


def sidecar_spin_us(num_envs: int, cores: int) -> int | None:
    """The workers' sidecar busy-poll budget: the sidecar's own default (None) when every worker, its
    sidecar and this process have a core of their own, else 0 (spinning would steal the cores the
    simulators need)."""
    return None if 2 * num_envs + 1 <= cores else 0


def check_envs_per_worker(k: int, num_envs: int) -> None:
    """How many environments one worker process holds: 1 .. ``num_envs`` (else a ``ConfigError``)."""
    if isinstance(k, bool) or not isinstance(k, int) or not 1 <= k <= num_envs:
        raise ConfigError(f"envs per worker must be an integer in 1..{num_envs} (the environments), got {k!r}")


def usable_cores() -> int:
    """The cores this process may run on (its affinity; the machine's count where there is none)."""
    try:
        return len(os.sched_getaffinity(0))
    except AttributeError:  # not Linux
        return os.cpu_count() or 1


def default_num_envs(episodes: int, cores: int | None = None, envs_per_worker: int = 1) -> int:
    """Sized to the cores this process may use (``envs_per_worker`` environments each) and the episode
    count (at least 1)."""
    cores = usable_cores() if cores is None else cores
    return max(1, min(int(cores) * envs_per_worker, int(episodes)))


PENDING = object()  #: a reply not in yet (``_replies`` with ``need``)


# ---------------------------------------------------------------------------------------------- worker
class _SharedImages:
    """Worker side of the image transport: an observation's images are copied into a shared-memory ring of
    one slot (``simseam.sidecar.local.SlotRing``, the sidecar's; its descriptor handed to the parent once
    over the pipe), and only their layout ``[(key, offset, shape, dtype)]`` travels in the message. Made
    anew, larger, when an observation needs more room. Without ``memfd_create`` (not Linux) images travel
    in the message."""

    def __init__(self, conn, parent_pid: int):
        self.conn, self.parent_pid = conn, parent_pid
        self.ring: SlotRing | None = None
        self.enabled = HAVE_MEMFD

    def detach(self, obs):
        imgs = obs.get(OBS_IMAGES) if self.enabled else None
        if not imgs:
            return obs, None
        need = max(sum(align(a.nbytes) for a in imgs.values()), ALIGN)
        if self.ring is None or need > self.ring.slot_bytes:
            ring = SlotRing(1, need, threshold=0, name="simseam-env-images")
            try:
                self.conn.send(("shm", need))
                reduction.send_handle(self.conn, ring.fd, self.parent_pid)
            except BaseException:
                ring.close()
                raise
            if self.ring is not None:
                self.ring.close()
            self.ring = ring
        self.ring.begin()
        layout = []
        for key, a in imgs.items():
            _slot, offset = self.ring.put(a)
            layout.append((key, offset, a.shape, a.dtype.str))
        return {**obs, OBS_IMAGES: {}}, layout


# The step fast path. A state-only step's reply (observation, reward, flags, info, the render state: the
# list ``_reply_body``) is written into a second shared block laid out from its template (the sidecar's
# compact templates: ``signature`` on the worker's side, ``learn`` on the parent's), and only one byte
# travels in the pipe; the action goes the other way through the same block. A new block, its layout and
# one whole reply for the parent to learn the template from are sent (pickled, with the block's file
# descriptor) whenever the reply's signature changes; a reply no template describes (images, which cross
# through _SharedImages, an int beyond 64 bits, an object) travels pickled as before. Nothing is pickled
# on the hot path of a state-only lockstep run.
_FAST_REPLY = b"F"
_FAST_STEP = b"S"
_FAST_REQUESTS = (None, STATE_ONLY)  # the request byte after b"S" indexes this
_FAST_FRAME = struct.pack("!i", 1) + _FAST_REPLY  # how multiprocessing's Connection frames b"F"
# the framed step commands (b"S" + the request's index), written straight to the pipe
_FAST_STEP_FRAMES = tuple(struct.pack("!i", 2) + _FAST_STEP + bytes([i]) for i in range(len(_FAST_REQUESTS)))


def _rings(env: int) -> tuple[bytes, bytes]:
    """What worker ``env`` writes into the bell when its reply waits in its pipe, and in its step block:
    one native int, ``2 * env`` (+1: the block). One write of 4 bytes is atomic, so the workers' rings
    never interleave and one read takes every ring there is."""
    return struct.pack("i", 2 * env), struct.pack("i", 2 * env + 1)


def _read_message(fd: int) -> bytes:
    """One message of a ``Connection`` (4-byte big-endian size, then the payload) read straight from its
    file descriptor: a fast reply costs one ``read``. Reads exactly one message, never beyond it, so
    ``recv_handle`` finds a handle sent after it."""
    buf = os.read(fd, len(_FAST_FRAME))
    if buf == _FAST_FRAME:
        return _FAST_REPLY
    while len(buf) < 4:
        if not buf:
            raise EOFError
        more = os.read(fd, 4 - len(buf))
        if not more:
            raise EOFError
        buf += more
    size, = struct.unpack("!i", buf[:4])
    body = bytearray(buf[4:])
    if size == -1:  # over 2 GiB: an 8-byte size follows
        while len(body) < 8:
            more = os.read(fd, 8 - len(body))
            if not more:
                raise EOFError
            body += more
        size, = struct.unpack("!Q", bytes(body[:8]))
        body = body[8:]
    while len(body) < size:
        more = os.read(fd, min(size - len(body), 1 << 20))
        if not more:
            raise EOFError
        body += more
    return bytes(body)


def _reply_body(obs, result, pose) -> list:
    """A step's reply as one templated body (``_StepBlock`` / ``_MainBlock``)."""
    return [obs, result.reward, result.terminated, result.truncated, result.info, pose]


def _block_layout(action_dim: int, skeleton) -> tuple[dict, int]:
    """Where a template's parts lie in a step block, each 8-byte aligned: the action (float32), the
    scalars (``skeleton.scalars``), each array in body order; and the block's size."""
    off = align(4 * action_dim, 8)
    layout = {"action": (0, action_dim), "scalars": off, "arrays": []}
    off = align(off + skeleton.scalars.size, 8)
    for dtype, shape in skeleton.arrays:
        layout["arrays"].append(off)
        off = align(off + int(np.prod(shape, dtype=np.int64)) * dtype.itemsize, 8)
    return layout, max(off, 8)


class _StepBlock:
    """Worker side of the step fast path (see ``_reply_body``)."""

    def __init__(self, conn, parent_pid: int, action_dim: int):
        self.conn, self.parent_pid, self.action_dim = conn, parent_pid, action_dim
        self.enabled = HAVE_MEMFD
        self.sig = None
        self.mm: mmap.mmap | None = None
        self.announced = False  # the last write announced a new block over the pipe

    def action(self) -> np.ndarray:
        return self._action.copy()

    def _new_layout(self, sig: tuple, scal: list, body: list) -> bool:
        """A block for replies of signature ``sig``, handed to the parent; False (nothing sent) when
        ``scal`` does not fit its codes (an int beyond 64 bits)."""
        skeleton, _ = learn(body, "vector step reply")
        try:
            skeleton.scalars.pack(*scal)
        except struct.error:
            return False
        layout, size = _block_layout(self.action_dim, skeleton)
        fd, mm = create_block("simseam-env-step", size, sealed=True)
        try:
            self.conn.send(("block", size, {**layout, "body": body}))
            reduction.send_handle(self.conn, fd, self.parent_pid)
        finally:
            os.close(fd)
        old = self.mm
        self._action = array_at(mm, np.float32, (self.action_dim,), 0)
        self._arrays = [array_at(mm, dt, shape, off) for (dt, shape), off in zip(skeleton.arrays, layout["arrays"])]
        self._pack, self._at = skeleton.scalars.pack_into, layout["scalars"]
        self.mm, self.sig = mm, sig
        if old is not None:
            release(old)  # (views of the old block still alive somewhere: the GC frees it)
        return True

    def write(self, obs, result, pose) -> bool:
        """Write a step's reply into the block (True), or False when no template describes it."""
        if not self.enabled:
            return False
        body = _reply_body(obs, result, pose)
        walked = signature(body)
        if walked is None:
            return False
        sig, scal, arrs = walked
        self.announced = sig != self.sig
        if self.announced and not self._new_layout(sig, scal, body):
            return False
        try:
            self._pack(self.mm, self._at, *scal)
        except struct.error:  # an int beyond 64 bits: pickled, this once
            return False
        for dst, a in zip(self._arrays, arrs):
            dst[...] = a
        return True


class _MainBlock:
    """This process's side of a worker's step block: the reply rebuilt from its template, without
    unpickling (fresh dicts and copies of the arrays: the block is written again at the next step)."""

    def __init__(self, mm: mmap.mmap, layout: dict):
        self.mm = mm
        skeleton, _ = learn(layout["body"], "vector step reply")
        self._build, self._unpack, self._at = skeleton.build, skeleton.scalars.unpack_from, layout["scalars"]
        self.action = array_at(mm, np.float32, (layout["action"][1],), layout["action"][0])
        self._arrays = [array_at(mm, dt, shape, off) for (dt, shape), off in zip(skeleton.arrays, layout["arrays"])]

    def read(self):
        obs, reward, terminated, truncated, info, pose = self._build(self._unpack(self.mm, self._at),
                                                                     [a.copy() for a in self._arrays])
        return ("obs", obs, (reward, terminated, truncated, info), None, pose)

    def close(self) -> None:
        self.action = self._arrays = None
        release(self.mm)


def _attach_images(mm: mmap.mmap, obs, layout):
    """Parent side: the observation with its images copied out of the shared block (the policy may keep them)."""
    return {**obs, OBS_IMAGES: {key: array_at(mm, np.dtype(dt), shape, off).copy() for key, off, shape, dt in layout}}


def _die_with_parent(parent_pid: int) -> None:
    """Linux: this process gets SIGKILL when its parent dies, even by SIGKILL (PR_SET_PDEATHSIG), so a
    worker never finishes (and writes the video of) an episode that no log will record."""
    try:
        import ctypes

        ctypes.CDLL(None, use_errno=True).prctl(1, int(signal.SIGKILL))  # 1 = PR_SET_PDEATHSIG
    except (OSError, AttributeError):  # not Linux: the worker ends at its next read of the closed pipe
        return
    if os.getppid() != parent_pid:  # the parent died before prctl took effect
        os._exit(1)


class _EnvServer:
    """One environment of a worker process: its rollout, and the pipe over which it answers the parent's
    commands for that environment (``serve``). A worker holds one or several (``envs_per_worker``)."""

    def __init__(self, conn, bell_fd: int, env: int, recipe: SceneRecipe | BenchmarkRecipe, parent_pid: int):
        self.conn, self.bell_fd, self.recipe, self.parent_pid = conn, bell_fd, recipe, parent_pid
        self.in_pipe, self.in_block = _rings(env)
        self.images = _SharedImages(conn, parent_pid)
        self.rollout = self.block = None
        self.render_state = lambda: None
        self.writer = None
        self.video: Path | None = None
        self.policy = self.policy_key = None  # the "episode" command's own policy (built on first use)

    def boot(self) -> BaseException | None:
        """Build the rollout and tell the parent its spec; the error, sent to the parent too, if that fails."""
        try:
            self.rollout = rollout = self.recipe.build()
            # optional, as rollout_for: a recipe needs only build()
            if getattr(self.recipe, "pose_states", False):
                if not callable(getattr(getattr(rollout, "engine", None), "render_state", None)):
                    raise ConfigError("renderer 'batched': the workers' rollouts have no MuJoCo render state")
                self.render_state = rollout.engine.render_state
            self.block = _StepBlock(self.conn, self.parent_pid, rollout.spec.action_dim)
            self.conn.send(("ready", rollout.spec.to_json()))
            return None
        except BaseException as exc:  # noqa: BLE001  (reported to the parent, which raises it)
            exc = _portable(exc)
            self.conn.send(("fatal", exc))
            return exc

    def answer(self, msg) -> None:
        """A reset's or a step's reply through the pipe, the bell rung first (a reply larger than the pipe
        holds is read while it is written)."""
        data = reduction.ForkingPickler.dumps(msg)
        os.write(self.bell_fd, self.in_pipe)
        self.conn.send_bytes(data)

    def serve(self, buf: bytes) -> bool:
        """Carry out one command (``buf``: as it came through the pipe); False once told to close."""
        if buf[:1] == _FAST_STEP:  # a step whose action waits in the step block
            op, msg = "step", ("step", self.block.action(), _FAST_REQUESTS[buf[1]])
        else:
            msg = pickle.loads(buf)
            op = msg[0]
        if op == "close":
            return False
        send = self.answer if op in ("reset", "step") else self.conn.send
        try:
            handler = self._HANDLERS.get(op)
            if handler is None:
                send(("fatal", SimulationError(f"vector worker: unknown command {op!r}")))
            else:
                handler(self, msg)
        except SidecarError as exc:
            return self._sidecar_failed(exc, send)
        except Exception as exc:  # noqa: BLE001
            send(("fatal", _portable(exc)))
        return True

    def _sidecar_failed(self, exc: SidecarError, send) -> bool:
        """A sidecar failure costs the episode: restart the sidecar when the rollout can (False: it could
        not, the worker ends)."""
        self.drop_video()
        restart = self.rollout.spec.can(CAP_RESTART)
        if restart:
            try:
                self.rollout.restart()
            except SimseamError as again:
                send(("fatal", _portable(again)))
                return False
        send(("episode_error", f"{type(exc).__name__}: {exc}", "restarting the sidecar" if restart else "continuing"))
        return True

    def _reset(self, msg) -> None:
        _, seed, request, video_path = msg
        self.drop_video()
        obs = self.rollout.reset(seed, request)
        if video_path is not None:
            frame = self.rollout.render()
            if frame is not None:
                from simseam.runner.video import VideoWriter

                self.video = Path(video_path)
                self.writer = VideoWriter(partial_video_path(self.video), fps=self.rollout.spec.control_hz)
                self.writer.append(frame)
        obs, layout = self.images.detach(obs)
        self.answer(("obs", obs, None, layout, self.render_state()))

    def _step(self, msg) -> None:
        _, action, request = msg
        r = self.rollout.step(action, request)
        if self.writer is not None:
            self.writer.append(self.rollout.render())
        obs, layout = self.images.detach(r.observation)
        pose = self.render_state()
        if layout is not None or not self.block.write(obs, r, pose):
            self.answer(("obs", obs, (r.reward, r.terminated, r.truncated, r.info), layout, pose))
        elif self.block.announced:  # the new block's handle waits in the pipe: read it first
            os.write(self.bell_fd, self.in_pipe)
            self.conn.send_bytes(_FAST_REPLY)
        else:
            os.write(self.bell_fd, self.in_block)

    def _render(self, msg) -> None:
        self.conn.send(("frame", self.rollout.render()))

    def _finish(self, msg) -> None:
        """The episode ended normally: keep its video."""
        path = None
        if self.writer is not None:
            self.writer.close()
            os.replace(partial_video_path(self.video), self.video)
            path = str(self.video)
        self.writer, self.video = None, None
        self.conn.send(("ok", path))

    def _episode(self, msg) -> None:
        """A whole episode with this worker's own policy instance."""
        _, index, seed, policy_spec, video_dir = msg
        self.rollout, seed = self.recipe.rollout_for(self.rollout, index, seed)  # (simseam eval: this episode's task)
        if self.policy is None or self.policy_key != policy_spec:
            from simseam.policies.base import make_policy

            self.policy = make_policy(policy_spec[0], **dict(policy_spec[1]))
            self.policy_key = policy_spec
        from simseam.runner.session import run_episodes

        errors: list[str] = []
        res = run_episodes(self.rollout, self.policy, [index], seed=seed,
                           video_dir=Path(video_dir) if video_dir else None,
                           on_error=lambda r, what_next: errors.append(what_next))[0]
        self.conn.send(("episode", res, errors[0] if errors else None))

    _HANDLERS = {"reset": _reset, "step": _step, "render": _render, "finish": _finish, "episode": _episode}

    def drop_video(self) -> None:
        if self.writer is not None:
            self.writer.close()
            partial_video_path(self.video).unlink(missing_ok=True)
        self.writer, self.video = None, None

    def close(self) -> None:
        self.drop_video()
        if self.rollout is not None:
            self.rollout.close()
        close = getattr(self.policy, "close", None)
        if callable(close):
            close()


def _worker_main(conns, bell, envs: Sequence[int], recipe: SceneRecipe | BenchmarkRecipe, parent_pid: int = 0,
                 sidecar_spin_us: int | None = None, spin_us: int = 0) -> None:
    """A worker process: build the rollouts of ``envs`` (one pipe each in ``conns``), then serve their
    commands until ``close`` or a pipe ends. ``bell``: the write end of the pipe every worker rings
    (``_rings``) when a reply to a reset or a step is there; ``sidecar_spin_us``: the busy-poll budget of a
    sidecar rollout's local path (unless the user's environment sets it); ``spin_us``: this worker's
    busy-poll for its next command."""
    if sidecar_spin_us is not None:
        os.environ.setdefault(SPIN_ENV, str(sidecar_spin_us))
    if parent_pid:
        _die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    servers = [_EnvServer(conn, bell.fileno(), env, recipe, parent_pid or os.getppid())
               for conn, env in zip(conns, envs)]
    try:
        for j, server in enumerate(servers):
            error = server.boot()
            if error is not None:  # the environments not built yet report it too
                for later in servers[j + 1:]:
                    later.conn.send(("fatal", error))
                return
        _serve(servers, spin_us * 1e-6)
    finally:
        for server in servers:
            server.close()


def _serve(servers: list[_EnvServer], spin_s: float) -> None:
    """Each environment's commands, in the order they come, until every one is closed or a pipe ends
    (the parent is gone). With ``spin_s``, each wait busy-polls that long before sleeping."""
    poll = select.poll()
    by_fd = {}
    for server in servers:
        by_fd[server.conn.fileno()] = server
        poll.register(server.conn.fileno(), select.POLLIN)
    while by_fd:
        if spin_s:
            spin_until_readable(poll, spin_s)
        for fd, _ in poll.poll():
            server = by_fd[fd]
            try:
                buf = server.conn.recv_bytes()
            except EOFError:  # the parent is gone
                return
            if not server.serve(buf):
                poll.unregister(fd)
                del by_fd[fd]


def _portable(exc: BaseException) -> BaseException:
    """The exception if it survives pickling, else a SimulationError carrying its text."""
    import pickle

    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001
        return SimulationError(f"{type(exc).__name__}: {exc}")


# ---------------------------------------------------------------------------------------------- parent
BOOTING, IDLE, BUSY = "booting", "idle", "busy"
WORKER_DIED = "worker process died"


@dataclass
class _Slot:
    env: int
    proc: Any = None
    conn: Any = None
    state: str = BOOTING
    boot_deadline: float = 0.0
    index: int | None = None  # run_local: the episode the worker is playing
    worker: int = 0  # the worker process that holds this environment (``envs_per_worker`` share one)
    video: str | None = None  # the video the worker records from its next reset (start_video)
    recording: bool = False  # the worker is recording this episode's video
    mm: Any = None  # the worker's shared image block, mapped here
    block: Any = None  # the worker's step block (_MainBlock)
    # the central renderer (renderer="batched"): what the policy asked for, the worker's render state,
    # and this episode's video (written here)
    want: Any = None
    pose: Any = None
    writer: Any = None
    video_path: Any = None
    fd: int = -1  # conn's file descriptor
    sentinel: int = -1  # the process's sentinel (readable when it has ended)
    waiter: Any = None  # a select.poll on conn and the sentinel: waiting for its reply
    stepping: bool = False  # a step sent (step_send), its reply not yet received (step_receive)
    rung: int | None = None  # its ring (see _rings), read while other workers' replies were awaited
    # its episode died with its worker, which another environment of that worker found dead: a fresh
    # worker holds it now, and its next step reports the loss (a reset starts over)
    orphaned: bool = False
    orphan_exitcode: int | None = None


class VectorEnv:
    """``num_envs`` rollouts built from ``recipe``, at most ``envs_per_worker`` to a worker process (environment
    ``j`` in worker ``j % num_workers``, so that any first few environments, which the scheduler fills first
    when there are fewer episodes than environments, lie on as many workers as they can; see the module
    docstring): a ``BatchRollout``
    (seam/batch.py). ``spec`` is the rollout's spec (from the first environment ready). Use as a context
    manager, or call ``close()``."""

    def __init__(self, recipe: SceneRecipe | BenchmarkRecipe, num_envs: int, *, start_method: str = "spawn",
                 boot_timeout: float = BOOT_TIMEOUT_S, renderer: str = "workers", render_device: str | None = None,
                 envs_per_worker: int = 1):
        if num_envs < 1:
            raise SimulationError(f"num_envs must be >= 1, got {num_envs}")
        check_envs_per_worker(envs_per_worker, num_envs)
        if renderer not in ("workers", "batched"):
            raise ConfigError(f"VectorEnv: renderer must be 'workers' or 'batched', got {renderer!r}")
        self.num_envs = num_envs
        self.boot_timeout = boot_timeout
        self._ctx = mp.get_context(start_method)
        self.envs_per_worker = envs_per_worker
        self.num_workers = -(-num_envs // envs_per_worker)
        self.slots = [_Slot(env=j, worker=j % self.num_workers) for j in range(num_envs)]
        self.spec: RolloutSpec | None = None
        self.restarts = 0  #: workers started again after one died
        self._failures: dict[int, EnvFailure] = {}
        self._closed = False
        self.renderer = renderer
        self.central = None  #: the central renderer (runner.central_render.CentralRenderer) with "batched"
        if renderer == "batched":  # workers observe no images but send their render state
            import dataclasses

            from simseam.runner.central_render import CentralRenderer

            recipe = dataclasses.replace(recipe, render_images=True, pose_states=True)
            self.central = CentralRenderer(recipe, num_envs, device=render_device)
        self.recipe = recipe
        # the bell (see _rings): every worker's replies to resets and steps announced on one pipe, read here
        # with the workers' sentinels through one poll
        self._bell_r, self._bell_w = self._ctx.Pipe(duplex=False)
        self._bell = self._bell_r.fileno()
        os.set_blocking(self._bell, False)
        self._poll = select.poll()
        self._poll.register(self._bell, select.POLLIN)
        self._sentinels: dict[int, list[_Slot]] = {}  # the sentinels in the poll, and their workers' environments
        self._dead: set[int] = set()  # environments whose worker was found dead while nothing was asked of it
        cores = usable_cores()
        self.sidecar_spin_us = sidecar_spin_us(num_envs, cores)
        self.spin_us = vector_spin_us(self.num_workers, cores)  # lockstep only: run_local workers wait for whole episodes
        try:
            for w in range(self.num_workers):
                self._spawn(w)
            self._wait_booted(self.slots[:1])  # the spec, and a config error before anything else starts
        except BaseException:
            self.close()
            raise

    # -- processes
    def _members(self, worker: int) -> list[_Slot]:
        """The environments worker process ``worker`` holds."""
        return self.slots[worker::self.num_workers]

    def _spawn(self, worker: int) -> None:
        """Start worker process ``worker``, one pipe per environment it holds."""
        members = self._members(worker)
        old = members[0].sentinel
        if self._sentinels.pop(old, None) is not None:  # the dead worker's, still open
            self._poll.unregister(old)
        pipes = [self._ctx.Pipe() for _ in members]
        envs = [s.env for s in members]
        proc = self._ctx.Process(target=_worker_main, daemon=True,
                                 args=([child for _, child in pipes], self._bell_w, envs, self.recipe, os.getpid(),
                                       self.sidecar_spin_us, self.spin_us),
                                 name="simseam-env-" + "-".join(map(str, envs)))
        proc.start()
        for s, (parent, child) in zip(members, pipes):
            child.close()
            self._attach(s, proc, parent)
        self._poll.register(proc.sentinel, select.POLLIN)
        self._sentinels[proc.sentinel] = members

    def _attach(self, s: _Slot, proc, conn) -> None:
        """``s`` is now held by the fresh worker ``proc``, over ``conn``."""
        self._dead.discard(s.env)
        s.proc, s.conn, s.state = proc, conn, BOOTING
        s.fd, s.sentinel = conn.fileno(), proc.sentinel
        s.waiter = select.poll()
        s.waiter.register(s.fd, select.POLLIN)
        s.waiter.register(s.sentinel, select.POLLIN)
        if s.mm is not None:
            s.mm.close()
        if s.block is not None:
            s.block.close()
        s.mm = s.block = s.rung = None
        s.recording = False
        s.boot_deadline = time.monotonic() + self.boot_timeout

    def _wait_booted(self, slots: Sequence[_Slot]) -> None:
        for s in slots:
            while s.state == BOOTING:
                ready = wait_any([s.conn, s.proc.sentinel], timeout=max(0.0, s.boot_deadline - time.monotonic()))
                if not ready:
                    raise SimulationError(f"vector worker {s.env} did not build its rollout within "
                                          f"{self.boot_timeout:g} s")
                msg = self._recv(s)
                if msg is None:
                    raise SimulationError(f"vector worker {s.env} died while building its rollout "
                                          f"(exit code {s.proc.exitcode})")
                if msg[0] != "nothing":
                    self._on_boot(s, msg)

    def _on_boot(self, s: _Slot, msg) -> None:
        if msg[0] == "fatal":
            raise msg[1]
        spec = RolloutSpec.from_json(msg[1], where=f"vector worker {s.env}")
        if self.spec is None:
            self.spec = spec
        s.state = IDLE

    def _recv(self, s: _Slot, readable: bool = False):
        """The worker's next message, or None when it died (pipe closed)."""
        try:
            if readable or s.conn.poll():
                pipe = s.conn.fileno()
                while True:
                    buf = _read_message(pipe)
                    if buf == _FAST_REPLY:  # a step reply waiting in the step block
                        return s.block.read()
                    msg = pickle.loads(buf)
                    if msg[0] not in ("shm", "block"):
                        break
                    fd = reduction.recv_handle(s.conn)  # a (new) shared block: its file descriptor follows
                    mm = map_block(fd, msg[1], writable=msg[0] == "block", sealed=True, where=f"vector worker {s.env}")
                    if msg[0] == "shm":
                        if s.mm is not None:
                            s.mm.close()
                        s.mm = mm
                    else:
                        if s.block is not None:
                            s.block.close()
                        s.block = _MainBlock(mm, msg[2])
                if msg[0] == "obs" and msg[3]:
                    msg = (msg[0], _attach_images(s.mm, msg[1], msg[3]), msg[2], None, msg[4])
                return msg
        except (EOFError, OSError):
            return None
        if not s.proc.is_alive():
            return None
        return ("nothing",)

    def _reply(self, s: _Slot):
        """The worker's reply to the command just sent (not a reset or a step: those ring the bell), waiting
        for it, or None when the worker died."""
        while True:
            ready = s.waiter.poll()  # its pipe, or its end (the sentinel)
            msg = self._recv(s, readable=any(fd == s.fd for fd, _ in ready))
            if msg is None or msg[0] != "nothing":
                return msg

    def _replies(self, slots: list[_Slot], spin: bool = False, need: int | None = None) -> list:
        """The workers' replies to the resets or steps sent to ``slots``, in their order (None: the worker
        died), each read as soon as its worker rings the bell (a slow worker does not hold up reading the
        others'); a reply that rang while other workers' were awaited is taken from ``rung``. With
        ``spin``, each wait busy-polls up to ``spin_us`` before sleeping. ``need``: return once that many
        are in, with every other reply already rung; ``PENDING`` marks those not in yet."""
        out: list = [PENDING] * len(slots)
        waiting = {}
        for j, s in enumerate(slots):
            if s.rung is not None:
                out[j], s.rung = self._read_ring(s, s.rung), None
            elif s.env in self._dead or s.orphaned:
                out[j] = None
            else:
                waiting[s.env] = j
        spin_s = self.spin_us * 1e-6 if spin else 0.0
        least = len(slots) - (len(slots) if need is None else need)  # how many may stay out
        while len(waiting) > least:
            for fd, _ in self._events(spin_s):
                if fd == self._bell:
                    self._rung(slots, waiting, out)
                else:
                    self._ended(fd, slots, waiting, out)
        if waiting:
            self._rung(slots, waiting, out)  # every reply there is by now
        return out

    def _events(self, spin_s: float) -> list:
        """The next events of the bell and the sentinels, busy-polling up to ``spin_s`` before sleeping."""
        if spin_s:
            deadline = time.perf_counter() + spin_s
            while not (ready := self._poll.poll(0)) and time.perf_counter() < deadline:
                os.sched_yield()
            if ready:
                return ready
        return self._poll.poll()

    def _bell_rings(self) -> list[int]:
        """Every ring in the bell now (see ``_rings``), taken out of it."""
        rings: list[int] = []
        while True:
            try:
                got = os.read(self._bell, 4096)
            except BlockingIOError:
                return rings
            rings += memoryview(got).cast("i").tolist()
            if len(got) < 4096:
                return rings

    def _rung(self, slots: list[_Slot], waiting: dict[int, int], out: list) -> None:
        """Every ring in the bell: a reply of a worker in ``waiting`` is read into ``out``; any other
        worker's (its step in flight, pipelined) is kept in its ``rung`` for its own receive."""
        for ring in self._bell_rings():
            j = waiting.pop(ring >> 1, None)
            if j is None:
                self.slots[ring >> 1].rung = ring
            else:
                out[j] = self._read_ring(slots[j], ring)

    def _read_ring(self, s: _Slot, ring: int):
        """The reply ``ring`` announced: in the worker's step block, or in its pipe."""
        return s.block.read() if ring & 1 else self._recv(s, readable=True)

    def _ended(self, sentinel: int, slots: list[_Slot], waiting: dict[int, int], out: list) -> None:
        """A worker process ended: a reply it rang for before it died is read; for each of its environments
        that owed one, the entry in ``out`` stays None; any other finds it dead (``_dead``) at its next
        reset or step, or the receive of its step in flight."""
        self._rung(slots, waiting, out)
        self._poll.unregister(sentinel)
        for s in self._sentinels.pop(sentinel):
            j = waiting.pop(s.env, None)
            if j is None:
                self._dead.add(s.env)
            else:
                out[j] = None

    def _replace(self, s: _Slot) -> int | None:
        """``s``'s worker died: a fresh one takes its place. Its other environments' episodes died with it
        (``orphaned``). Returns the dead one's exit code."""
        members = self._members(s.worker)
        for m in members:
            try:
                m.conn.close()
            except OSError:
                pass
        s.proc.join(5.0)  # its pipes closed: it is gone or going
        if s.proc.is_alive():
            s.proc.kill()
            s.proc.join(5.0)
        exitcode = s.proc.exitcode
        self._keep_rings(skip={m.env for m in members})  # what it rang before it died is moot now
        for m in members:
            self._drop_central_video(m)
            m.index = None
            m.orphaned, m.orphan_exitcode = m is not s, exitcode
        self._spawn(s.worker)
        self.restarts += 1
        return exitcode

    def _keep_rings(self, skip: set[int]) -> None:
        """Every ring in the bell kept for its environment's own receive (``rung``), those of ``skip``
        dropped."""
        for ring in self._bell_rings():
            if ring >> 1 not in skip:
                self.slots[ring >> 1].rung = ring

    def _lost(self, s: _Slot) -> None:
        """``s``'s worker died: its environment's episode is lost (``failures``), a fresh worker takes its
        place (unless another of its environments already found it dead: ``orphaned``)."""
        if s.orphaned:
            s.orphaned, exitcode = False, s.orphan_exitcode
        else:
            exitcode = self._replace(s)
        self._failures[s.env] = EnvFailure(WORKER_DIED, lost=True, what_next="a fresh worker takes its place",
                                           exitcode=exitcode)

    def _answer(self, s: _Slot, msg):
        """A reset's or a step's reply as (observation, (reward, terminated, truncated, info)), or None
        when the environment failed (recorded in ``failures``)."""
        if msg is None:
            self._lost(s)
            return None
        if msg[0] == "fatal":
            raise msg[1]
        if msg[0] == "episode_error":
            s.recording = False
            self._drop_central_video(s)
            self._failures[s.env] = EnvFailure(msg[1], what_next=msg[2])
            return None
        if self.central is not None:
            s.pose = msg[4]
        return msg[1], msg[2]

    def pids(self) -> list[int]:
        """The worker processes' ids, by environment."""
        return [s.proc.pid for s in self.slots]

    # -- the batch (seam/batch.py)
    def reset(self, envs: Sequence[int], seeds: Sequence[int | None], observe=None) -> list:
        self._check_open()
        idx = self._envs(envs, "reset")
        seeds = list(seeds)
        if len(seeds) != len(idx):
            raise ConfigError(f"reset: {len(idx)} environments but {len(seeds)} seeds")
        requests = per_env_requests(observe, len(idx), "reset")
        slots = [self.slots[e] for e in idx]
        self._check_idle(slots, "reset")
        self._wait_booted(slots)
        for s, seed, want in zip(slots, seeds, requests):
            s.orphaned = False  # a new episode: nothing of the one its dead worker held is owed
            video, s.video = s.video, None
            if self.central is not None:  # this process draws the frames (and writes the video)
                s.want, want = want, worker_request(want)
                self._open_central_video(s, video)
                video = None
            s.recording = video is not None
            self._send(s, ("reset", seed, want, video))
        answers = [self._answer(s, msg) for s, msg in zip(slots, self._replies(slots))]
        out = [None if a is None else a[0] for a in answers]
        self._draw(slots, out)
        return out

    def step(self, envs: Sequence[int], actions, observe=None) -> BatchStepResult:
        idx = self._envs(envs, "step")
        self.step_send(idx, actions, observe)
        return self.step_receive(idx)

    def step_send(self, envs: Sequence[int], actions, observe=None) -> None:
        """Start the step of ``envs``: each worker gets its action (``step_receive`` collects the replies)."""
        self._check_open()
        idx = self._envs(envs, "step")
        k = len(idx)
        a = np.asarray(actions, dtype=np.float32)
        # one reduction finds a NaN or an infinity (a sum that only overflows goes the slow way and passes)
        if a.shape != (k, self.spec.action_dim) or not math.isfinite(np.add.reduce(a, axis=None)):
            batch_actions(self.spec, actions, k)  # the InvalidActionError naming the row
        requests = per_env_requests(observe, k, "step")
        slots = [self.slots[e] for e in idx]
        self._check_idle(slots, "step_send")
        central = self.central
        for s, row, want in zip(slots, a, requests):
            if central is not None:
                s.want, want = want, worker_request(want)
            s.stepping = True
            if not s.orphaned:  # (an orphan's receive reports its loss)
                self._step(s, row, want)

    def step_receive(self, envs: Sequence[int], at_least: int | None = None) -> BatchStepResult:
        """The results of the steps ``step_send`` started for ``envs``, waiting for exactly those workers;
        with ``at_least``, for that many of them (and every other one that is in by then)."""
        idx = self._envs(envs, "step_receive")
        slots = [self.slots[e] for e in idx]
        if not all(s.stepping for s in slots):
            raise ConfigError(f"step_receive: envs {[s.env for s in slots if not s.stepping]} have no step in flight")
        if at_least is not None and not 1 <= at_least <= len(idx):
            raise ConfigError(f"step_receive: at_least must be in 1..{len(idx)}, got {at_least!r}")
        replies = self._replies(slots, spin=bool(self.spin_us), need=at_least)
        if at_least is not None:
            got = [j for j, m in enumerate(replies) if m is not PENDING]
            if len(got) < len(idx):
                idx, slots, replies = [idx[j] for j in got], [slots[j] for j in got], [replies[j] for j in got]
        central = self.central
        obs, rewards, terminated, truncated, infos = [], [], [], [], []
        for s, msg in zip(slots, replies):
            s.stepping = False
            if msg is not None and msg[0] == "obs" and central is None:  # the usual reply, as _answer takes it
                o, (reward, term, trunc, info) = msg[1], msg[2]
            else:
                x = self._answer(s, msg)
                o, (reward, term, trunc, info) = (None, (0.0, False, False, {})) if x is None else x
            obs.append(o)
            rewards.append(reward)
            terminated.append(term)
            truncated.append(trunc)
            infos.append(info)
        self._draw(slots, obs)
        return BatchStepResult(np.array(idx, dtype=np.int64), obs, np.array(rewards, dtype=np.float64),
                               np.array(terminated, dtype=bool), np.array(truncated, dtype=bool), infos)

    @staticmethod
    def _check_idle(slots: list[_Slot], where: str) -> None:
        if any(s.stepping for s in slots):
            raise ConfigError(f"{where}: envs {[s.env for s in slots if s.stepping]} have a step in flight")

    def _envs(self, envs: Sequence[int], where: str) -> list[int]:
        """``envs`` as a list of distinct indices in ``[0, num_envs)`` (``env_indices``' rule; a list of
        Python ints, what the scheduler passes, is checked without numpy)."""
        if type(envs) is list:
            n = self.num_envs
            if all(type(e) is int and 0 <= e < n for e in envs) and len(set(envs)) == len(envs):
                return envs
        return env_indices(envs, self.num_envs, where).tolist()

    def render(self, env: int) -> np.ndarray | None:
        self._check_open()
        (e,) = env_indices([env], self.num_envs, "render").tolist()
        s = self.slots[e]
        if self.central is not None:
            return None if s.pose is None else self.central.render([s.pose])[self.central.video_key][0]
        self._send(s, ("render",))
        msg = self._reply(s)
        if msg is None:
            self._lost(s)
            return None
        if msg[0] == "fatal":
            raise msg[1]
        return msg[1]

    def failures(self) -> dict[int, EnvFailure]:
        out, self._failures = self._failures, {}
        return out

    def _check_open(self) -> None:
        if self._closed:
            raise SimulationError("the batch is closed")

    # -- videos: each worker encodes its own (the central renderer: this process)
    def start_video(self, env: int, path: Path) -> None:
        """Record the next episode of ``env`` (from its next reset) as ``path``."""
        self.slots[env].video = str(path)

    def finish_video(self, env: int) -> str | None:
        """The episode of ``env`` ended: its video, complete (None: no camera, or the worker died)."""
        s = self.slots[env]
        if s.writer is not None:
            s.writer.close()
            os.replace(partial_video_path(s.video_path), s.video_path)
            path, s.writer, s.video_path = str(s.video_path), None, None
            return path
        if not s.recording:
            return None
        s.recording = False
        self._send(s, ("finish",))
        reply = self._reply(s)
        if reply is None:  # died before its video was complete: the episode stands, its video is lost
            self._lost(s)
            self._failures.pop(env, None)
            return None
        if reply[0] == "fatal":
            raise reply[1]
        return reply[1]

    def drop_video(self, env: int) -> None:
        """The episode of ``env`` did not finish: no video (the worker drops its own at the next reset)."""
        s = self.slots[env]
        s.video = None
        self._drop_central_video(s)

    def _open_central_video(self, s: _Slot, video: str | None) -> None:
        self._drop_central_video(s)
        if video is not None:
            from simseam.runner.video import VideoWriter

            s.video_path = Path(video)
            s.writer = VideoWriter(partial_video_path(s.video_path), fps=self.spec.control_hz)

    def _drop_central_video(self, s: _Slot) -> None:
        if s.writer is not None:
            s.writer.close()
            partial_video_path(s.video_path).unlink(missing_ok=True)
        s.writer = s.video_path = None

    def _draw(self, slots: list[_Slot], obs: list) -> None:
        """The central renderer: the frames of ``slots`` that are due (a video, or images the policy asked
        for) in one call, into the observations and the videos."""
        if self.central is None:
            return
        due = [j for j, (s, o) in enumerate(zip(slots, obs)) if o is not None and (
            s.writer is not None or s.want is None or s.want.images is None or bool(s.want.images))]
        if not due:
            return
        images = self.central.render([slots[j].pose for j in due])
        for k, j in enumerate(due):
            s = slots[j]
            if s.writer is not None:
                s.writer.append(images[self.central.video_key][k])
            obs[j][OBS_IMAGES] = {key: images[key][k] for key in self.central.keys
                                  if s.want is None or s.want.wants_image(key)}

    def close(self) -> None:
        """End every worker (politely, then by force); idempotent."""
        self._closed = True
        for s in self.slots:
            if s.conn is not None:
                try:
                    s.conn.send(("close",))
                except (OSError, ValueError):
                    pass
        deadline = time.monotonic() + 10.0
        for s in self.slots:
            if s.proc is None:
                continue
            s.proc.join(max(0.0, deadline - time.monotonic()))
            if s.proc.is_alive():
                s.proc.terminate()
                s.proc.join(5.0)
            if s.proc.is_alive():
                s.proc.kill()
                s.proc.join(5.0)
            if s.conn is not None:
                s.conn.close()
            if s.mm is not None:
                s.mm.close()
            if s.block is not None:
                s.block.close()
            self._drop_central_video(s)
            s.proc, s.conn, s.mm, s.block = None, None, None, None
        self._bell_r.close()
        self._bell_w.close()
        if self.central is not None:
            self.central.close()
            self.central = None

    def __enter__(self) -> "VectorEnv":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- episodes
    def run(self, policy, indices: Sequence[int], *, seed: int = 0, video_dir: Path | None = None,
            max_attempts: int = 3, groups: int = 1, ready: int | None = None,
            on_start: Callable[[int, int], None] | None = None,
            on_step: Callable[[int, int, int], None] | None = None,
            on_done: Callable[[EpisodeResult], None] | None = None,
            on_error: Callable[[EpisodeResult, str], None] | None = None,
            on_worker_failure: Callable[[WorkerFailure], None] | None = None,
            keep: bool = True) -> list[EpisodeResult]:
        """Run the episodes ``indices`` on the workers with ``policy`` (a ``PolicyBatch`` of at least
        ``num_envs`` environments), stepped together: the episode scheduler (``runner.scheduler``) over
        this batch; ``groups`` > 1: pipelined lockstep (the policy acts for one group of workers while the
        others step; see ``runner.scheduler``); ``ready`` M: the policy acts for the workers whose steps are
        in as soon as M are (see ``runner.scheduler``). Callbacks: ``on_start(env, index)``, ``on_step(env, index, steps)``, ``on_done(result)``
        (once per episode, as it finishes: order may differ from ``indices``), ``on_error(result,
        what_next)`` (a sidecar failure cost the episode), ``on_worker_failure``; ``keep`` as ``run_batch``'s."""
        return run_batch(self, policy, indices, seed=seed, video_dir=video_dir, max_attempts=max_attempts,
                         groups=groups, ready=ready, on_start=on_start, on_step=on_step, on_done=on_done, on_error=on_error,
                         on_worker_failure=on_worker_failure, keep=keep)

    # -- whole episodes: the policy inside each worker (runner.whole_episodes.run_local plays them)
    def idle_envs(self) -> list[int]:
        """The environments whose worker waits for its next whole episode."""
        return [s.env for s in self.slots if s.state == IDLE]

    def playing(self) -> bool:
        """Whether a worker plays a whole episode."""
        return any(s.state == BUSY for s in self.slots)

    def send_episode(self, env: int, index: int, seed: int, policy_key: tuple, video_dir: str | None) -> None:
        """Environment ``env``'s worker plays episode ``index`` (seed ``seed + index``, or its recipe's
        ``rollout_for`` base) with its own instance of the policy spec ``policy_key`` (spec, kwargs items)."""
        s = self.slots[env]
        s.index, s.state = index, BUSY
        self._send(s, ("episode", index, seed, policy_key, video_dir))

    def episode_events(self) -> list:
        """Wait until a worker that boots or plays reports: the episodes returned (``Returned``) and the
        workers lost with theirs (``Lost``; a fresh worker takes its place); a worker's own error raised."""
        from simseam.runner.whole_episodes import Lost, Returned

        watch = [s for s in self.slots if s.state in (BUSY, BOOTING)]
        ready = set(wait_any([c for s in watch for c in (s.conn, s.proc.sentinel)]))
        events: list = []
        for s in watch:
            if s.conn not in ready and s.proc.sentinel not in ready:
                continue
            msg = self._recv(s, readable=s.conn in ready)
            if msg is not None and msg[0] == "nothing":
                continue
            if s.state == BOOTING:
                if msg is None:
                    raise SimulationError(f"vector worker {s.env} died while building its rollout "
                                          f"(exit code {s.proc.exitcode})")
                self._on_boot(s, msg)
                continue
            if msg is None:  # the worker died mid-episode: a fresh one takes its place
                i, env = s.index, s.env
                exitcode = self._replace(s)
                events.append(Lost(env, i, lambda n, code=exitcode: lost_error(WORKER_DIED, n, code),
                                   lambda what, env=env, i=i, code=exitcode: WorkerFailure(
                                       env=env, index=i, exitcode=code, what_next=what)))
                continue
            if msg[0] == "fatal":
                raise msg[1]
            index, s.index, s.state = s.index, None, IDLE
            if msg[0] == "episode_error":  # a sidecar error escaped the worker's episode loop
                events.append(Returned(s.env, index, None, msg[2], error=msg[1]))
            else:
                events.append(Returned(s.env, index, msg[1], msg[2]))
        return events

    def _step(self, s: _Slot, action: np.ndarray, request) -> None:
        """A step command: through the step block (one byte in the pipe) when the worker has one and the
        request is one of the two it knows by number, else pickled."""
        block = s.block
        if (block is not None and (request is None or request is STATE_ONLY or request == STATE_ONLY)
                and getattr(action, "shape", None) == block.action.shape):
            block.action[:] = action
            try:
                os.write(s.fd, _FAST_STEP_FRAMES[0 if request is None else 1])
            except (OSError, ValueError):
                pass  # a dead worker: its sentinel tells the loop
            return
        self._send(s, ("step", action, request))

    def _send(self, s: _Slot, msg) -> None:
        try:
            s.conn.send(msg)
        except (OSError, ValueError):
            pass  # a dead worker: its sentinel tells the loop
