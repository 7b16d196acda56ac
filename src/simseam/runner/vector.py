"""Vectorized episodes: N worker processes, each owning one rollout, driven by one batched policy.

``VectorEnv(recipe, num_envs)`` starts ``num_envs`` worker processes (``spawn``); each builds the
rollout of the same scene config (in-process MuJoCo, or a ``SidecarRollout`` whose sidecar the
worker owns) and answers ``reset`` / ``step`` / video commands over a pipe. ``run(policy, indices)``
steps every busy worker together: it waits for all replies, asks the ``PolicyBatch`` for the
actions of every environment at once (``act_batch``), and sends them out (``sync=False``: it acts
on whichever environments have answered, so no worker waits for a slower one). ``run_local`` puts
the policy inside each worker instead (policies that share no model): workers play whole episodes
and send back only their results. A worker whose episode ends takes the next episode index from
the queue. Episode ``i`` always uses seed ``seed + i``, so the per-episode results do not depend
on ``num_envs`` for a deterministic policy. A recipe may define ``rollout_for(rollout, index, seed)
-> (rollout, seed)``: ``run_local`` workers then ask it for each episode's rollout and seed base
(``simseam eval``: a worker rebuilds its sidecar when the next episode's task differs). Images
cross from a worker through a shared memory block (``_SharedImages``), not through the pipe; a
worker dies with this process (Linux).

Failures:

- a worker process that dies (killed, segfault, OOM) costs nothing: its episode goes back to the
  front of the queue, a fresh worker is started in its place, and the episode is re-run from its
  reset (at most ``max_attempts`` times; then it is recorded with its error). An episode is handed
  to ``on_done`` exactly once, when it has finished;
- a sidecar crash inside a worker costs that episode, recorded with its error, exactly as in the
  sequential loop (``runner.session``); the worker restarts its sidecar when the rollout declares
  the ``restart`` capability;
- any other error of a rollout (bad action, engine failure) stops the run and is raised here;
- Ctrl-C / SIGTERM: the workers ignore SIGINT; ``close()`` (``with`` block) ends them, dropping the
  episodes in flight; every finished episode has already been given to ``on_done``.
"""

from __future__ import annotations

import mmap
import multiprocessing as mp
import os
import signal
import time
from collections import deque
from dataclasses import dataclass
from multiprocessing import reduction
from multiprocessing.connection import wait as wait_any
from pathlib import Path
from typing import Any, Callable, Sequence

import numpy as np

from simseam.runner.episodes import EpisodeResult, partial_video_path
from simseam.seam import INFO_DIAGNOSTICS, OBS_IMAGES, CAP_RESTART, RolloutSpec, SidecarError, SimseamError, SimulationError

#: how long a worker may take to build its rollout (a cold sidecar venv boots slowly)
BOOT_TIMEOUT_S = 600.0


@dataclass(frozen=True)
class RolloutRecipe:
    """How a worker builds its rollout: a scene config (``SceneConfig.model_dump()``), the scene
    file's directory, and the options ``build_rollout`` takes. Picklable."""

    scene: dict
    base_dir: str
    privileged: bool = False
    render_images: bool = True
    seed: int = 0

    def build(self):
        from simseam.runner.scene_config import SceneConfig, build_rollout

        cfg = SceneConfig.model_validate(self.scene)
        return build_rollout(cfg, Path(self.base_dir), privileged=self.privileged,
                             render_images=self.render_images, seed=self.seed)


def default_num_envs(episodes: int, cores: int | None = None) -> int:
    """Sized to the cores this process may use and the episode count (at least 1)."""
    if cores is None:
        try:
            cores = len(os.sched_getaffinity(0))
        except AttributeError:  # not Linux
            cores = os.cpu_count() or 1
    return max(1, min(int(cores), int(episodes)))


# ---------------------------------------------------------------------------------------------- worker
class _SharedImages:
    """Worker side of the image transport: an observation's images are written into one shared memory
    block (an anonymous ``memfd``, handed to the parent once over the pipe), and only their layout
    ``[(key, offset, shape, dtype)]`` travels in the message. Grown (a new block handed over) when an
    observation needs more room. Without ``memfd_create`` (not Linux) images travel in the message."""

    def __init__(self, conn, parent_pid: int):
        self.conn, self.parent_pid = conn, parent_pid
        self.mm: mmap.mmap | None = None
        self.size = 0
        self.enabled = hasattr(os, "memfd_create")

    def detach(self, obs):
        imgs = obs.get(OBS_IMAGES) if self.enabled else None
        if not imgs:
            return obs, None
        arrays = {k: np.ascontiguousarray(a) for k, a in imgs.items()}
        need = sum(a.nbytes for a in arrays.values())
        if need > self.size:
            fd = os.memfd_create("simseam-env-images")
            try:
                os.ftruncate(fd, need)
                mm = mmap.mmap(fd, need)
                self.conn.send(("shm", need))
                reduction.send_handle(self.conn, fd, self.parent_pid)
            finally:
                os.close(fd)
            if self.mm is not None:
                self.mm.close()
            self.mm, self.size = mm, need
        layout, offset = [], 0
        for key, a in arrays.items():
            self.mm[offset:offset + a.nbytes] = a.data.cast("B")
            layout.append((key, offset, a.shape, a.dtype.str))
            offset += a.nbytes
        return {**obs, OBS_IMAGES: {}}, layout


def _attach_images(mm: mmap.mmap, obs, layout):
    """Parent side: the observation with its images copied out of the shared block (the policy may keep them)."""
    images = {key: np.frombuffer(mm, dtype=np.dtype(dt), count=int(np.prod(shape)), offset=off).reshape(shape).copy()
              for key, off, shape, dt in layout}
    return {**obs, OBS_IMAGES: images}


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


def _worker_main(conn, recipe: RolloutRecipe, parent_pid: int = 0) -> None:
    """A worker process: build the rollout, then serve commands until ``close`` or the pipe ends."""
    if parent_pid:
        _die_with_parent(parent_pid)
    signal.signal(signal.SIGINT, signal.SIG_IGN)  # Ctrl-C is the parent's to handle
    images = _SharedImages(conn, parent_pid or os.getppid())
    try:
        rollout = recipe.build()
        conn.send(("ready", rollout.spec.to_json()))
    except BaseException as exc:  # noqa: BLE001  (reported to the parent, which raises it)
        conn.send(("fatal", _portable(exc)))
        return
    writer = None
    video: Path | None = None
    policy = policy_key = None  # the "episode" command's own policy (built on first use)

    def drop_video():
        nonlocal writer, video
        if writer is not None:
            writer.close()
            partial_video_path(video).unlink(missing_ok=True)
        writer, video = None, None

    try:
        while True:
            try:
                msg = conn.recv()
            except EOFError:  # the parent is gone
                return
            op = msg[0]
            try:
                if op == "reset":
                    _, seed, request, video_path = msg
                    drop_video()
                    obs = rollout.reset(seed, request)
                    if video_path is not None:
                        frame = rollout.render()
                        if frame is not None:
                            from simseam.runner.video import VideoWriter

                            video = Path(video_path)
                            writer = VideoWriter(partial_video_path(video), fps=rollout.spec.control_hz)
                            writer.append(frame)
                    obs, layout = images.detach(obs)
                    conn.send(("obs", obs, None, layout))
                elif op == "step":
                    _, action, request = msg
                    r = rollout.step(action, request)
                    if writer is not None:
                        writer.append(rollout.render())
                    obs, layout = images.detach(r.observation)
                    conn.send(("obs", obs, (r.reward, r.terminated, r.truncated, r.info), layout))
                elif op == "finish":  # the episode ended normally: keep its video
                    path = None
                    if writer is not None:
                        writer.close()
                        os.replace(partial_video_path(video), video)
                        path = str(video)
                    writer, video = None, None
                    conn.send(("ok", path))
                elif op == "episode":  # a whole episode with this worker's own policy instance
                    _, index, seed, policy_spec, video_dir = msg
                    rollout_for = getattr(recipe, "rollout_for", None)
                    if rollout_for is not None:  # a multi-task recipe (simseam eval): this episode's task
                        rollout, seed = rollout_for(rollout, index, seed)
                    if policy is None or policy_key != policy_spec:
                        from simseam.policies.base import make_policy

                        policy = make_policy(policy_spec[0], **dict(policy_spec[1]))
                        policy_key = policy_spec
                    from simseam.runner.session import run_episodes

                    errors: list[str] = []
                    res = run_episodes(rollout, policy, [index], seed=seed,
                                       video_dir=Path(video_dir) if video_dir else None,
                                       on_error=lambda r, what_next: errors.append(what_next))[0]
                    conn.send(("episode", res, errors[0] if errors else None))
                elif op == "close":
                    return
                else:
                    conn.send(("fatal", SimulationError(f"vector worker: unknown command {op!r}")))
            except SidecarError as exc:
                drop_video()
                restart = rollout.spec.can(CAP_RESTART)
                if restart:
                    try:
                        rollout.restart()
                    except SimseamError as again:
                        conn.send(("fatal", _portable(again)))
                        return
                conn.send(("episode_error", f"{type(exc).__name__}: {exc}",
                           "restarting the sidecar" if restart else "continuing"))
            except Exception as exc:  # noqa: BLE001
                conn.send(("fatal", _portable(exc)))
    finally:
        drop_video()
        rollout.close()
        close = getattr(policy, "close", None)
        if callable(close):
            close()


def _portable(exc: BaseException) -> BaseException:
    """The exception if it survives pickling, else a SimulationError carrying its text."""
    import pickle

    try:
        pickle.loads(pickle.dumps(exc))
        return exc
    except Exception:  # noqa: BLE001
        return SimulationError(f"{type(exc).__name__}: {exc}")


# ---------------------------------------------------------------------------------------------- parent
BOOTING, IDLE, RESETTING, ACTING, STEPPING = "booting", "idle", "resetting", "acting", "stepping"


@dataclass
class _Slot:
    env: int
    proc: Any = None
    conn: Any = None
    state: str = BOOTING
    boot_deadline: float = 0.0
    index: int | None = None
    result: EpisodeResult | None = None
    obs: Any = None
    sent_at: float = 0.0
    generation: int = 0
    video: bool = False
    mm: Any = None  # the worker's shared image block, mapped here


@dataclass
class WorkerFailure:
    """A worker that died: which one, in which episode, its exit code, and what happens next."""

    env: int
    index: int | None
    exitcode: int | None
    what_next: str


class VectorEnv:
    """``num_envs`` worker processes each holding a rollout built from ``recipe`` (see the module
    docstring). ``spec`` is the rollout's spec (from the first worker ready). Use as a context
    manager, or call ``close()``."""

    def __init__(self, recipe: RolloutRecipe, num_envs: int, *, start_method: str = "spawn",
                 boot_timeout: float = BOOT_TIMEOUT_S):
        if num_envs < 1:
            raise SimulationError(f"num_envs must be >= 1, got {num_envs}")
        self.recipe = recipe
        self.num_envs = num_envs
        self.boot_timeout = boot_timeout
        self._ctx = mp.get_context(start_method)
        self.slots = [_Slot(env=j) for j in range(num_envs)]
        self.spec: RolloutSpec | None = None
        self.restarts = 0  #: workers started again after one died
        try:
            for s in self.slots:
                self._spawn(s)
            self._wait_booted(self.slots[:1])  # the spec, and a config error before anything else starts
        except BaseException:
            self.close()
            raise

    # -- processes
    def _spawn(self, s: _Slot) -> None:
        parent, child = self._ctx.Pipe()
        proc = self._ctx.Process(target=_worker_main, args=(child, self.recipe, os.getpid()), daemon=True,
                                 name=f"simseam-env-{s.env}")
        proc.start()
        child.close()
        s.proc, s.conn, s.state = proc, parent, BOOTING
        if s.mm is not None:
            s.mm.close()
        s.mm = None
        s.boot_deadline = time.monotonic() + self.boot_timeout
        s.generation += 1

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
                msg = s.conn.recv()
                if msg[0] == "shm":  # a (new) shared image block: its file descriptor follows
                    fd = reduction.recv_handle(s.conn)
                    try:
                        if s.mm is not None:
                            s.mm.close()
                        s.mm = mmap.mmap(fd, msg[1])
                    finally:
                        os.close(fd)
                    msg = s.conn.recv()
                if msg[0] == "obs" and msg[3]:
                    msg = (msg[0], _attach_images(s.mm, msg[1], msg[3]), msg[2], None)
                return msg
        except (EOFError, OSError):
            return None
        if not s.proc.is_alive():
            return None
        return ("nothing",)

    def pids(self) -> list[int]:
        """The worker processes' ids, by environment."""
        return [s.proc.pid for s in self.slots]

    def close(self) -> None:
        """End every worker (politely, then by force); idempotent."""
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
            s.proc, s.conn, s.mm = None, None, None

    def __enter__(self) -> "VectorEnv":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()

    # -- episodes
    def run(self, policy, indices: Sequence[int], *, seed: int = 0, video_dir: Path | None = None,
            max_attempts: int = 3, sync: bool = True,
            on_start: Callable[[int, int], None] | None = None,
            on_step: Callable[[int, int, int], None] | None = None,
            on_done: Callable[[EpisodeResult], None] | None = None,
            on_error: Callable[[EpisodeResult, str], None] | None = None,
            on_worker_failure: Callable[[WorkerFailure], None] | None = None) -> list[EpisodeResult]:
        """Run the episodes ``indices`` on the workers with ``policy`` (a ``PolicyBatch`` of at least
        ``num_envs`` environments). ``sync``: every busy worker answers before the policy acts on all of
        them (the largest batches); else the policy acts on whichever environments have answered
        (no worker waits for a slower one; smaller batches). Per-environment results are the same. Callbacks: ``on_start(env, index)``, ``on_step(env, index, steps)``,
        ``on_done(result)`` (once per episode, as it finishes: order may differ from ``indices``),
        ``on_error(result, what_next)`` (a sidecar failure cost the episode), ``on_worker_failure``."""
        if getattr(policy, "n", self.num_envs) < self.num_envs:
            raise SimulationError(f"the policy batch holds {policy.n} environment(s), the vector env "
                                  f"{self.num_envs}")
        spec = self.spec
        max_steps = spec.task.max_steps
        key = spec.task.success_key
        todo = deque(indices)
        attempts: dict[int, int] = {}
        results: list[EpisodeResult] = []

        def finish(s: _Slot, res: EpisodeResult) -> None:
            s.state, s.index, s.result, s.obs = IDLE, None, None, None
            results.append(res)
            if on_done:
                on_done(res)

        def worker_died(s: _Slot) -> None:
            i = s.index
            try:
                s.conn.close()
            except OSError:
                pass
            s.proc.join(5.0)  # its pipe closed: it is gone or going
            if s.proc.is_alive():
                s.proc.kill()
                s.proc.join(5.0)
            exitcode = s.proc.exitcode
            what = "no episode in flight"
            if i is not None:
                attempts[i] = attempts.get(i, 0) + 1
                if attempts[i] < max_attempts:
                    todo.appendleft(i)
                    what = f"episode {i} goes back to the queue (attempt {attempts[i] + 1} of {max_attempts})"
                else:
                    what = f"episode {i} failed {attempts[i]} times; recorded as an error"
            s.index, s.result, s.obs = None, None, None
            self._spawn(s)
            self.restarts += 1
            if on_worker_failure:
                on_worker_failure(WorkerFailure(env=s.env, index=i, exitcode=exitcode, what_next=what))
            if i is not None and attempts[i] >= max_attempts:
                res = EpisodeResult(index=i, seed=seed + i, success=False, steps=0, reward=0.0,
                                    error=f"worker process died {attempts[i]} times (last exit code {exitcode})")
                results.append(res)
                if on_done:
                    on_done(res)

        def handle(s: _Slot, msg) -> None:
            if msg is None and s.state == BOOTING:
                raise SimulationError(f"vector worker {s.env} died while building its rollout "
                                      f"(exit code {s.proc.exitcode})")
            if msg is None:
                return worker_died(s)
            if msg[0] == "nothing":
                return
            if s.state == BOOTING:
                return self._on_boot(s, msg)
            if msg[0] == "fatal":
                raise msg[1]
            if msg[0] == "episode_error":
                res = EpisodeResult(index=s.index, seed=seed + s.index, success=False, steps=0, reward=0.0,
                                    error=msg[1])
                if on_error:
                    on_error(res, msg[2])
                return finish(s, res)
            res = s.result
            if s.state == RESETTING:
                s.obs, s.state = msg[1], ACTING
                return
            # STEPPING
            obs = msg[1]
            reward, terminated, truncated, info = msg[2]
            res.step_ms.append((time.perf_counter() - s.sent_at) * 1e3)
            res.steps += 1
            res.reward += float(reward)
            res.diagnostics = dict(info.get(INFO_DIAGNOSTICS) or {})
            if info.get(key):
                res.success = True
            if on_step:
                on_step(s.env, s.index, res.steps)
            if terminated or truncated or res.steps >= max_steps:
                if s.video:
                    try:
                        s.conn.send(("finish",))
                        reply = s.conn.recv()
                    except (EOFError, OSError):  # died before its video was complete: play it again
                        return worker_died(s)
                    if reply[0] == "fatal":
                        raise reply[1]
                    res.video = reply[1]
                return finish(s, res)
            s.obs, s.state = obs, ACTING

        def start(s: _Slot, i: int) -> None:
            policy.reset(s.env, spec)
            video = str(video_dir / f"episode_{i:03d}.mp4") if video_dir is not None else None
            s.index, s.state, s.video = i, RESETTING, video is not None
            s.result = EpisodeResult(index=i, seed=seed + i, success=False, steps=0, reward=0.0)
            if on_start:
                on_start(s.env, i)
            self._send(s, ("reset", seed + i, policy.observe_next(s.env), video))

        while True:
            for s in self.slots:
                if s.state == IDLE and todo:
                    start(s, todo.popleft())
            busy = [s for s in self.slots if s.state in (RESETTING, STEPPING)]
            booting = [s for s in self.slots if s.state == BOOTING]
            acting = [s for s in self.slots if s.state == ACTING]
            if (busy and (sync or not acting)) or (booting and not acting):
                if not busy and not todo:  # nothing left for the booting workers to do
                    break
                watch = busy + booting
                timeout = None
                if booting:
                    timeout = max(0.0, min(s.boot_deadline for s in booting) - time.monotonic())
                ready = set(wait_any([c for s in watch for c in (s.conn, s.proc.sentinel)], timeout=timeout))
                if not ready:
                    late = [s.env for s in booting if time.monotonic() >= s.boot_deadline]
                    raise SimulationError(f"vector worker(s) {late} did not build their rollout within "
                                          f"{self.boot_timeout:g} s")
                for s in watch:
                    if s.conn in ready:
                        handle(s, self._recv(s, readable=True))
                    elif s.proc.sentinel in ready:
                        handle(s, self._recv(s))
                continue
            if acting:
                t0 = time.perf_counter()
                actions = np.asarray(policy.act_batch([s.env for s in acting], [s.obs for s in acting]),
                                     dtype=np.float32)
                ms = (time.perf_counter() - t0) * 1e3
                if actions.shape[0] != len(acting):
                    raise SimulationError(f"act_batch returned {actions.shape[0]} actions for {len(acting)} "
                                          "environments")
                for s, a in zip(acting, actions):
                    s.result.policy_ms.append(ms)
                    s.state, s.obs = STEPPING, None
                    self._send(s, ("step", a, policy.observe_next(s.env)))
                continue
            break
        return results

    def run_local(self, policy: str, policy_kwargs: dict | None, indices: Sequence[int], *, seed: int = 0,
                  video_dir: Path | None = None, max_attempts: int = 3,
                  on_done: Callable[[EpisodeResult], None] | None = None,
                  on_error: Callable[[EpisodeResult, str], None] | None = None,
                  on_worker_failure: Callable[[WorkerFailure], None] | None = None) -> list[EpisodeResult]:
        """Like ``run``, with the policy inside each worker: every worker builds its own instance of the
        policy spec (``make_policy(policy, **policy_kwargs)``) and plays whole episodes, sending back only
        results, as N independent processes would (the fastest way for policies that share no model:
        no round trip to this process per step). Same seeds, same failure handling as ``run``."""
        spec_key = (policy, tuple(sorted((policy_kwargs or {}).items())))
        todo = deque(indices)
        attempts: dict[int, int] = {}
        results: list[EpisodeResult] = []

        def done(res: EpisodeResult) -> None:
            results.append(res)
            if on_done:
                on_done(res)

        while todo or any(s.state == STEPPING for s in self.slots):
            for s in self.slots:
                if s.state == IDLE and todo:
                    s.index, s.state = todo.popleft(), STEPPING
                    self._send(s, ("episode", s.index, seed, spec_key, str(video_dir) if video_dir else None))
            watch = [s for s in self.slots if s.state in (STEPPING, BOOTING)]
            if not any(s.state == STEPPING for s in watch) and not todo:
                break
            ready = set(wait_any([c for s in watch for c in (s.conn, s.proc.sentinel)]))
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
                if msg is None:  # the worker died mid-episode: the episode goes back to the queue
                    i = s.index
                    s.conn.close()
                    s.proc.join(5.0)
                    if s.proc.is_alive():
                        s.proc.kill()
                        s.proc.join(5.0)
                    exitcode = s.proc.exitcode
                    attempts[i] = attempts.get(i, 0) + 1
                    again = attempts[i] < max_attempts
                    if again:
                        todo.appendleft(i)
                    s.index = None
                    self._spawn(s)
                    self.restarts += 1
                    if on_worker_failure:
                        on_worker_failure(WorkerFailure(
                            env=s.env, index=i, exitcode=exitcode,
                            what_next=(f"episode {i} goes back to the queue (attempt {attempts[i] + 1} of "
                                       f"{max_attempts})") if again else
                            f"episode {i} failed {attempts[i]} times; recorded as an error"))
                    if not again:
                        done(EpisodeResult(index=i, seed=seed + i, success=False, steps=0, reward=0.0,
                                           error=f"worker process died {attempts[i]} times (last exit code "
                                                 f"{exitcode})"))
                    continue
                if msg[0] == "fatal":
                    raise msg[1]
                _, res, what_next = msg
                s.index, s.state = None, IDLE
                if what_next is not None and on_error:
                    on_error(res, what_next)
                done(res)
        return results

    def _send(self, s: _Slot, msg) -> None:
        s.sent_at = time.perf_counter()
        try:
            s.conn.send(msg)
        except (OSError, ValueError):
            pass  # a dead worker: its sentinel tells the loop
