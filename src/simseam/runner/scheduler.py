"""The episode scheduler over a ``BatchRollout``: N environments, one queue of episodes, one batched policy.

Environment ``j`` plays episode after episode from one queue of indices; episode ``i`` uses seed
``seed + i``, so the per-episode results do not depend on the number of environments for a
deterministic policy. When an environment's episode ends (success terminates it, the step limit
truncates it), the environment is reset alone with the next index while the others go on. Each
step the batched policy (``PolicyBatch``: ``reset(env, spec)``, ``observe_next(env)``,
``act_batch(envs, observations)``) acts for every busy environment at once, and the batch steps
exactly those, observing what each environment's policy will read next.

Pipelined lockstep (``groups`` K > 1): environment ``j`` belongs to group ``j % K``, and the groups take
turns: the scheduler receives group ``g``'s step (``step_receive``), does its bookkeeping (ended
episodes, resets, videos, callbacks), lets the policy act for its busy environments and starts their
next step (``step_send``) while the other groups' steps are in flight, so this process's work overlaps
the workers' stepping. K = 1 is plain lockstep; the per-episode results do not depend on K for a
deterministic per-environment policy. A step's ``step_ms`` is the time spent sending and receiving it.

The ready rule (``ready`` M, 1 <= M <= N; not with groups): every busy environment's step is in
flight, and each turn the scheduler receives the steps that are in once at least M are
(``step_receive(envs, at_least=M)``), does their bookkeeping, lets the policy act for those at once
and sends their next steps, while the others' steps go on. No turn waits for the slowest environment
and this process's work overlaps the stepping; the batches the policy sees vary in size and
membership, so the per-episode results equal plain lockstep's for a policy whose action for one
environment does not depend on the others in its batch (a batched network's float sums may differ
in the last bits, as between any two batch sizes). M = N is plain lockstep.

The array path: a policy with ``act_arrays(observations)`` on a batch that offers arrays
(``seam.batch.ArrayBatch``: MuJoCo Warp) gets each step's ``observation_arrays(request)`` (one array per
key for all environments, in the device's memory; ``request`` is the union of the busy environments' own
``observe_next(env)`` when the policy has it, else everything) and answers ``float32[num_envs, action_dim]``
actions as any DLPack array, which the batch steps with ``step_arrays`` (told what the next
``observation_arrays`` will ask, so that a batch whose cameras sample during the step draws them): no host
copy of observations or
actions, one policy call per step for every environment (rows of idle environments are ignored). One
group only. The per-episode results equal the per-environment dict path's for a policy that computes the
same actions from the same values (the arrays' rows are the dicts' values, exactly). There, with no
videos and no ``on_step``, the bookkeeping of a step is done on arrays (``_Tally``): every busy environment
steps in every flight, so an episode's steps, reward, success and latencies are kept per environment as
columns and written into its ``EpisodeResult`` when it ends, and a step's infos are read as one success column
(``seam.info_column``; a batch of thousands of worlds hands them out as ``InfoColumns``), not environment by
environment.

Failures (``BatchRollout.failures``): an environment whose process died loses its episode through no
fault of the episode, which goes back to the front of the queue (at most ``max_attempts`` times, then
it is recorded with its error); a crashed sidecar costs its episode, recorded with its error, as in
the sequential loop. Either way the environment then starts the next episode. Every finished
episode reaches ``on_done`` exactly once.

Videos (``video_dir``): ``episode_NNN.mp4`` per episode, written under a partial name and renamed
when the episode has finished. A batch that records its own videos (``start_video(env, path)`` before
the reset, ``finish_video(env) -> path | None`` at the end, ``drop_video(env)``: worker processes
encode their own frames) does it; for any other the scheduler writes ``render(env)`` after the reset
and after every step.
"""

from __future__ import annotations

import os
import time
from collections import deque
from dataclasses import dataclass
from pathlib import Path
from typing import Callable, Sequence

import numpy as np

from simseam.runner.episodes import EpisodeResult, partial_video_path
from simseam.seam import INFO_DIAGNOSTICS, ConfigError, ObsRequest, SimulationError, info_column, offers_arrays

_NO_IMAGES = ObsRequest.state_only()  # the array path's resets: their dicts go unread


class EpisodeQueue:
    """The episodes still to run (episode ``i`` uses seed ``seed + i``), and how often each was lost with
    the worker that ran it: every executor's queue and its one retry rule (worker processes, Ray)."""

    def __init__(self, indices: Sequence[int], seed: int = 0, max_attempts: int = 3):
        self.todo = deque(indices)
        self.seed = seed
        self.max_attempts = max_attempts
        self.attempts: dict[int, int] = {}

    def __bool__(self) -> bool:
        return bool(self.todo)

    def next(self) -> int:
        return self.todo.popleft()

    def new_result(self, index: int) -> EpisodeResult:
        return EpisodeResult(index=index, seed=self.seed + index, success=False, steps=0, reward=0.0)

    def lost(self, index: int, error: Callable[[int], str]) -> tuple[str, EpisodeResult | None]:
        """Episode ``index`` was lost with its worker: it goes back to the front of the queue, or after
        ``max_attempts`` losses it is recorded as an error (``error(times)`` says what happened). Returns
        what happens next, in words, and the error result when there is one."""
        n = self.attempts[index] = self.attempts.get(index, 0) + 1
        if n < self.max_attempts:
            self.todo.appendleft(index)
            return f"episode {index} goes back to the queue (attempt {n + 1} of {self.max_attempts})", None
        res = self.new_result(index)
        res.error = error(n)
        return f"episode {index} failed {n} times; recorded as an error", res


@dataclass
class WorkerFailure:
    """An environment's process that died: which environment (-1: a Ray worker), in which episode (None:
    between episodes), its exit code, and what happens next."""

    env: int
    index: int | None
    exitcode: int | None
    what_next: str


def lost_error(message: str, times: int, exitcode: int | None) -> str:
    """The error of an episode lost ``times`` times with its process."""
    return f"{message} {times} times" + (f" (last exit code {exitcode})" if exitcode is not None else "")


class _Episodes(EpisodeQueue):
    """The queue, and the episode each environment of a batch is playing."""

    def __init__(self, indices: Sequence[int], n: int, seed: int, max_attempts: int):
        super().__init__(indices, seed, max_attempts)
        self.playing: list[EpisodeResult | None] = [None] * n

    def busy(self) -> list[int]:
        return [e for e, r in enumerate(self.playing) if r is not None]

    def take(self, envs: Sequence[int]) -> list[int]:
        """Give the next episodes to ``envs`` (in order, while the queue lasts); the envs that got one."""
        started = []
        for env in envs:
            if not self.todo:
                break
            self.playing[env] = self.new_result(self.next())
            started.append(env)
        return started


class _Tally:
    """The array path's bookkeeping as columns over the environments (every busy environment steps in every
    flight there): each one's steps, summed reward and success in its episode so far, and where the episode began
    on the run's timeline of step and policy latencies (one entry a flight, shared by every environment in it).
    ``settle`` writes them into the episode's ``EpisodeResult``: the same values the per-environment loop gives
    (the reward summed in float64 in step order)."""

    def __init__(self, n: int):
        self.steps = np.zeros(n, dtype=np.int64)
        self.reward = np.zeros(n, dtype=np.float64)
        self.success = np.zeros(n, dtype=bool)
        self.begin = np.zeros(n, dtype=np.int64)  # on the timeline, counted from the run's first flight
        self.step_ms: list[float] = []
        self.policy_ms: list[float] = []
        self.dropped = 0  # timeline entries before every playing episode's begin, let go

    def start(self, envs: Sequence[int], playing: Sequence[object]) -> None:
        """New episodes on ``envs``; the timeline kept from the oldest playing episode's beginning on."""
        idx = np.asarray(envs, dtype=np.int64)
        self.steps[idx], self.reward[idx], self.success[idx] = 0, 0.0, False
        self.begin[idx] = self.dropped + len(self.step_ms)
        if len(self.step_ms) > 4096:  # a long run: what no playing episode needs goes
            live = [e for e, res in enumerate(playing) if res is not None]
            gone = int(self.begin[live].min()) - self.dropped
            del self.step_ms[:gone], self.policy_ms[:gone]
            self.dropped += gone

    def add(self, idx: np.ndarray, reward: np.ndarray, success: np.ndarray, step_ms: float, policy_ms: float) -> None:
        """One flight of ``idx``: its rewards and success flags (one per environment) and its latencies."""
        self.steps[idx] += 1
        self.reward[idx] += reward
        self.success[idx] |= success
        self.step_ms.append(step_ms)
        self.policy_ms.append(policy_ms)

    def settle(self, env: int, res: EpisodeResult) -> None:
        start, steps = int(self.begin[env]) - self.dropped, int(self.steps[env])
        res.steps, res.reward, res.success = steps, float(self.reward[env]), bool(self.success[env])
        res.step_ms, res.policy_ms = self.step_ms[start:start + steps], self.policy_ms[start:start + steps]


class _Videos:
    """Each environment's video of its episode in ``video_dir`` (see the module docstring)."""

    def __init__(self, batch, video_dir: Path | None):
        self.batch, self.dir = batch, video_dir
        self.own = video_dir is not None and callable(getattr(batch, "start_video", None))
        self.writers: dict[int, tuple] = {}  # env -> (VideoWriter, path): the frames the scheduler writes

    def start(self, env: int, index: int) -> None:
        if self.dir is None:
            return
        path = self.dir / f"episode_{index:03d}.mp4"
        if self.own:
            self.batch.start_video(env, path)
        else:
            self.writers[env] = (None, path)

    def frame(self, env: int) -> None:
        if env not in self.writers:
            return
        writer, path = self.writers[env]
        frame = self.batch.render(env)
        if frame is None:
            return
        if writer is None:
            from simseam.runner.video import VideoWriter

            writer = VideoWriter(partial_video_path(path), fps=self.batch.spec.control_hz)
            self.writers[env] = (writer, path)
        writer.append(frame)

    def finish(self, env: int) -> str | None:
        if self.dir is None:
            return None
        if self.own:
            return self.batch.finish_video(env)
        writer, path = self.writers.pop(env, (None, None))
        if writer is None:
            return None
        writer.close()
        os.replace(partial_video_path(path), path)
        return str(path)

    def drop(self, env: int) -> None:
        if self.dir is None:
            return
        if self.own:
            self.batch.drop_video(env)
            return
        writer, path = self.writers.pop(env, (None, None))
        if writer is not None:
            writer.close()
            partial_video_path(path).unlink(missing_ok=True)

    def close(self) -> None:
        for env in list(self.writers):
            self.drop(env)


#: the fewest usable cores on which a run that names no lockstep rule gets ``default_lockstep``'s (it was measured
#: on 16; on fewer cores this process's own work per step takes a core the workers need, and no rule held)
DEFAULT_RULE_MIN_CORES = 8


@dataclass(frozen=True)
class Lockstep:
    """How worker processes are stepped from this process: ``groups`` policy groups or the ready rule
    ``ready`` (``run_batch``), ``envs_per_worker`` environments in each worker (``VectorEnv``). ``auto``: the
    run named no rule and no environment count, so where the policy acts here it gets ``default_lockstep``'s."""

    groups: int = 1
    ready: int | None = None
    envs_per_worker: int = 1
    auto: bool = False

    @property
    def acts_here(self) -> bool:
        """Whether the policy must act in this process (anything but plain lockstep)."""
        return self.groups > 1 or self.ready is not None or self.envs_per_worker > 1

    def fit(self, num_envs: int) -> "Lockstep":
        """Each number capped at ``num_envs`` (fewer episodes than environments asked for)."""
        return Lockstep(min(self.groups, num_envs), None if self.ready is None else min(self.ready, num_envs),
                        min(self.envs_per_worker, num_envs), self.auto)

    def or_default(self) -> "Lockstep":
        """This rule, or ``auto`` when it is plain lockstep (a run whose command named no rule and no
        environment count: the job then picks ``default_lockstep``'s where the policy acts here)."""
        return Lockstep(auto=True) if self == Lockstep() else self

    def describe(self) -> str:
        """For a run's first line ('' for plain lockstep)."""
        words = f", {self.groups} policy groups" if self.groups > 1 else ""
        if self.ready is not None:
            words += f", acting once {self.ready} step{' is' if self.ready == 1 else 's are'} in"
        if self.envs_per_worker > 1:
            words += f", {self.envs_per_worker} environments per worker"
        return words


def default_lockstep(workers: int, episodes: int, cores: int) -> tuple[Lockstep, int]:
    """The rule, and the environments, of a run that names neither (``Lockstep.auto``) when its policy acts in
    this process over ``workers`` worker processes (sized to the cores) that run their engines themselves (no
    sidecar: ``engine_in_worker``): on ``DEFAULT_RULE_MIN_CORES`` or more
    cores, two environments per worker and the ready rule at a quarter of the workers (16 cores: ``--num-envs 32
    --envs-per-worker 2 --policy-ready 4``, the rule that held 0.8 of bare processes in three calls on each of two
    machines, 0.78-0.87 in all seven of 6 December; docs/evaluation.md), at most one environment per episode; on
    fewer, plain lockstep."""
    if cores < DEFAULT_RULE_MIN_CORES or workers < 2 or episodes < 2:
        return Lockstep(), workers
    envs = min(2 * workers, episodes)
    procs = -(-envs // 2)
    return Lockstep(ready=max(1, procs // 4), envs_per_worker=2), envs


def check_ready(ready: int | None, num_envs: int, groups: int = 1) -> None:
    """The ready rule's batch: None (off) or 1 .. ``num_envs``, and not with policy groups (a ``ConfigError``)."""
    if ready is None:
        return
    if isinstance(ready, bool) or not isinstance(ready, int) or not 1 <= ready <= num_envs:
        raise ConfigError(f"--policy-ready must be an integer in 1..{num_envs} (the environments), got {ready!r}")
    if groups != 1:
        raise ConfigError(f"--policy-ready {ready} and --policy-groups {groups}: choose one")


def check_groups(groups: int, num_envs: int) -> None:
    """The number of policy groups of a lockstep run: 1 .. ``num_envs`` (else a ``ConfigError``)."""
    if isinstance(groups, bool) or not isinstance(groups, int) or not 1 <= groups <= num_envs:
        raise ConfigError(f"policy groups must be an integer in 1..{num_envs} (the environments), got {groups!r}")


def run_batch(batch, policy, indices: Sequence[int], *, seed: int = 0, video_dir: Path | None = None,
              max_attempts: int = 3, groups: int = 1, ready: int | None = None,
              on_start: Callable[[int, int], None] | None = None,
              on_step: Callable[[int, int, int], None] | None = None,
              on_done: Callable[[EpisodeResult], None] | None = None,
              on_error: Callable[[EpisodeResult, str], None] | None = None,
              on_worker_failure: Callable[[WorkerFailure], None] | None = None,
              keep: bool = True) -> list[EpisodeResult]:
    """Run episodes ``indices`` on ``batch`` (see the module docstring). ``groups``: the pipelined lockstep's
    number of groups (1: every environment steps together); ``ready`` M: the policy acts for the
    environments whose steps are in as soon as M of them are (see the module docstring; not with groups).
    ``on_start(env, index)``, ``on_step(env, index,
    steps)`` and ``on_done(result)`` follow each episode; ``on_error(result, what_next)``: a sidecar failure
    cost the episode; ``on_worker_failure``: an environment's process died. Results in the order the
    episodes finished (none with ``keep=False``: a long run that takes each result through ``on_done``
    keeps its memory flat)."""
    n = batch.num_envs
    if getattr(policy, "n", n) < n:
        raise SimulationError(f"the policy batch holds {policy.n} environment(s), the batch {n}")
    check_groups(groups, n)
    check_ready(ready, n, groups)
    device = callable(getattr(policy, "act_arrays", None)) and offers_arrays(batch)
    if device and (groups > 1 or ready):
        raise ConfigError("an array policy (act_arrays) steps every environment at once: it takes policy groups 1 "
                          "and no --policy-ready")
    run = _BatchRun(batch, policy, _Episodes(indices, n, seed, max_attempts), _Videos(batch, video_dir), device,
                    _Callbacks(on_start, on_step, on_done, on_error, on_worker_failure), keep)
    try:
        run.start(range(n))
        if ready:
            _run_ready(run.send, run.turn, ready, n)
        else:
            _run_groups(run, groups, n)
    finally:
        run.videos.close()
    return run.results


@dataclass(frozen=True)
class _Callbacks:
    """``run_batch``'s callbacks (each may be None)."""

    on_start: Callable[[int, int], None] | None
    on_step: Callable[[int, int, int], None] | None
    on_done: Callable[[EpisodeResult], None] | None
    on_error: Callable[[EpisodeResult, str], None] | None
    on_worker_failure: Callable[[WorkerFailure], None] | None


class _BatchRun:
    """One ``run_batch``: the episodes each environment plays, their last observations, the results kept."""

    def __init__(self, batch, policy, episodes: _Episodes, videos: _Videos, device: bool, calls: _Callbacks,
                 keep: bool):
        self.batch, self.policy, self.spec = batch, policy, batch.spec
        self.episodes, self.videos, self.device, self.calls, self.keep = episodes, videos, device, calls, keep
        self.obs: list = [None] * batch.num_envs
        self.results: list[EpisodeResult] = []
        columns = device and videos.dir is None and calls.on_step is None
        self.tally = _Tally(batch.num_envs) if columns else None  # the array path's bookkeeping as columns

    def finish(self, env: int, res: EpisodeResult) -> None:
        self.episodes.playing[env], self.obs[env] = None, None
        if self.keep:
            self.results.append(res)
        if self.calls.on_done:
            self.calls.on_done(res)

    def failed(self, env: int, f) -> None:
        """``env``'s episode ended by a failure of the environment (``EnvFailure``)."""
        episodes, calls = self.episodes, self.calls
        index = episodes.playing[env].index
        episodes.playing[env], self.obs[env] = None, None
        self.videos.drop(env)
        if f.lost:
            what, res = episodes.lost(index, lambda times: lost_error(f.message, times, f.exitcode))
            if calls.on_worker_failure:
                calls.on_worker_failure(WorkerFailure(env=env, index=index, exitcode=f.exitcode, what_next=what))
        else:
            res = episodes.new_result(index)
            res.error = f.message
            if calls.on_error:
                calls.on_error(res, f.what_next)
        if res is not None:
            self.finish(env, res)

    def start(self, envs: Sequence[int]) -> None:
        """Start the next episodes on ``envs`` (again on those whose reset failed, while the queue lasts)."""
        episodes, policy = self.episodes, self.policy
        while started := episodes.take(envs):
            if self.tally is not None:
                self.tally.start(started, episodes.playing)
            for env in started:
                policy.reset(env, self.spec)
                self.videos.start(env, episodes.playing[env].index)
                if self.calls.on_start:
                    self.calls.on_start(env, episodes.playing[env].index)
            got = self.batch.reset(started, [episodes.playing[e].seed for e in started],
                                   _NO_IMAGES if self.device else [policy.observe_next(e) for e in started])
            fails = self.batch.failures()
            for env, o in zip(started, got):
                if env in fails:
                    self.failed(env, fails[env])
                else:
                    self.obs[env] = o
                    self.videos.frame(env)
            envs = [e for e in started if e in fails]  # start them again with the next episodes

    def send(self, members: list[int]) -> _Flight | None:
        """The policy acts for the busy environments of ``members`` and their step starts (None: none busy)."""
        busy = [e for e in members if self.episodes.playing[e] is not None]
        return _send(self.batch, self.policy, busy, self.obs, self.device) if busy else None

    def turn(self, flight: _Flight, at_least: int | None = None) -> list[int]:
        """Receive ``flight``'s step (``at_least``: as soon as that many are in), finish the episodes that
        ended, start the next ones; the environments received."""
        if self.tally is not None:
            got, ended = _receive_tallied(self.batch, flight, self.episodes, self.tally, self.failed)
        else:
            got, ended = _receive(self.batch, flight, self.obs, self.episodes, self.videos, self.device, self.failed,
                                  self.calls.on_step, at_least)
        for env, res in ended:
            res.video = self.videos.finish(env)
            self.finish(env, res)
        free = [env for env in got if self.episodes.playing[env] is None]  # ended, or failed in the step
        if free:
            self.start(free)
        return got


def _run_groups(run: _BatchRun, groups: int, n: int) -> None:
    """Lockstep in ``groups`` turns (1: every environment steps together): group ``g`` is every
    ``groups``-th environment from ``g``; while one group's step is received, the others' are in flight."""
    members = [list(range(g, n, groups)) for g in range(groups)]
    flights = [run.send(m) for m in members]
    while any(flights):
        for g, flight in enumerate(flights):
            if flight is not None:
                run.turn(flight)
                flights[g] = run.send(members[g])


def _union_request(policy, envs: list[int]) -> ObsRequest | None:
    """What the array path's ``observation_arrays`` asks for ``envs``: the union of their ``observe_next``
    (everything when the policy has none)."""
    ask = getattr(policy, "observe_next", None)
    return ObsRequest.union([ask(e) for e in envs]) if callable(ask) else None


def _run_ready(send: Callable, turn: Callable, ready: int, n: int) -> None:
    """The ready rule's loop: every busy environment's step is in flight; each turn receives at least
    ``ready`` of them (fewer only when fewer are in flight), and the policy acts for those at once."""
    sent: dict[int, _Flight] = {}  # each environment in flight -> the send that started its step
    first = send(list(range(n)))
    sent.update(dict.fromkeys(first.envs, first) if first else {})
    while sent:
        got = turn(_Flight(list(sent), 0.0, sends=sent), min(ready, len(sent)))
        for env in got:
            del sent[env]
        nxt = send(got)
        if nxt is not None:
            sent.update(dict.fromkeys(nxt.envs, nxt))


@dataclass
class _Flight:
    """A group's step in flight: its environments, the policy's time for them and the send's, and (the
    array path, stepped at the receive) the policy's actions for every environment."""

    envs: list[int]
    policy_ms: float
    send_ms: float = 0.0
    device_actions: object = None
    next_request: ObsRequest | None = None  # the array path: what the observation after the step will ask
    sends: dict | None = None  # the ready rule: each environment's own send (its policy and send times)


def _send(batch, policy, envs: list[int], obs: list, device: bool) -> _Flight:
    """The policy acts for ``envs`` and their step starts (``step_send``; the array path keeps the actions)."""
    t0 = time.perf_counter()
    if device:
        actions = policy.act_arrays(batch.observation_arrays(_union_request(policy, envs)))
        return _Flight(envs, (time.perf_counter() - t0) * 1e3, device_actions=actions,
                       next_request=_union_request(policy, envs))
    actions = np.asarray(policy.act_batch(envs, [obs[e] for e in envs]), dtype=np.float32)
    if actions.shape != (len(envs), batch.spec.action_dim):
        raise SimulationError(f"act_batch returned shape {actions.shape} for {len(envs)} environments")
    t1 = time.perf_counter()
    batch.step_send(envs, actions, [policy.observe_next(e) for e in envs])
    return _Flight(envs, (t1 - t0) * 1e3, (time.perf_counter() - t1) * 1e3)


def _receive(batch, flight: _Flight, obs: list, episodes: _Episodes, videos: _Videos, device: bool,
             failed: Callable, on_step, at_least: int | None = None) -> tuple[list[int], list[tuple[int, EpisodeResult]]]:
    """The end of one control step of ``flight``'s environments (``at_least``: of those in once that many
    are); the environments received, and the episodes that ended with their environments."""
    spec = batch.spec
    t0 = time.perf_counter()
    if device:
        r = batch.step_arrays(flight.envs, flight.device_actions, flight.next_request)
    elif at_least is None:
        r = batch.step_receive(flight.envs)
    else:
        r = batch.step_receive(flight.envs, at_least=at_least)
    wait_ms = (time.perf_counter() - t0) * 1e3
    busy = flight.envs if at_least is None else r.envs.tolist()
    step_ms, policy_ms = flight.send_ms + wait_ms, flight.policy_ms
    fails = batch.failures()
    ended = []
    playing, success_key, max_steps = episodes.playing, spec.task.success_key, spec.task.max_steps
    frames = videos.writers  # the environments whose frames the scheduler writes (none: skip the call)
    # Python scalars once per step (the same values a per-element float()/bool() of the arrays gives)
    rewards, terminated, truncated = np.asarray(r.reward).tolist(), np.asarray(r.terminated).tolist(), \
        np.asarray(r.truncated).tolist()
    observations, infos = r.observations, r.infos
    for k, env in enumerate(busy):
        if fails and env in fails:
            failed(env, fails[env])
            continue
        res = playing[env]
        res.steps += 1
        res.reward += rewards[k]
        if flight.sends is not None:
            own = flight.sends[env]
            step_ms, policy_ms = own.send_ms + wait_ms, own.policy_ms
        res.step_ms.append(step_ms)
        res.policy_ms.append(policy_ms)
        info = infos[k]
        if info.get(success_key):
            res.success = True
        obs[env] = observations[k]
        if frames:
            videos.frame(env)
        if on_step:
            on_step(env, res.index, res.steps)
        if terminated[k] or truncated[k] or res.steps >= max_steps:
            res.diagnostics = dict(info.get(INFO_DIAGNOSTICS) or {})
            ended.append((env, res))
    return busy, ended


def _receive_tallied(batch, flight: _Flight, episodes: _Episodes, tally: _Tally,
                     failed: Callable) -> tuple[list[int], list[tuple[int, EpisodeResult]]]:
    """``_receive`` on the array path, its bookkeeping on columns (``_Tally``): only the environments whose
    episodes end or fail are visited one by one."""
    task = batch.spec.task
    t0 = time.perf_counter()
    r = batch.step_arrays(flight.envs, flight.device_actions, flight.next_request)
    wait_ms = (time.perf_counter() - t0) * 1e3
    busy, fails = flight.envs, batch.failures()
    idx = np.asarray(busy, dtype=np.int64)
    tally.add(idx, np.asarray(r.reward, dtype=np.float64), info_column(r.infos, task.success_key),
              flight.send_ms + wait_ms, flight.policy_ms)
    over = np.asarray(r.terminated, dtype=bool) | np.asarray(r.truncated, dtype=bool) | (tally.steps[idx] >= task.max_steps)
    if fails:
        over |= np.fromiter((env in fails for env in busy), dtype=bool, count=len(busy))
    ended = []
    for k in np.flatnonzero(over).tolist():
        env = busy[k]
        if fails and env in fails:
            failed(env, fails[env])
            continue
        res = episodes.playing[env]
        tally.settle(env, res)
        res.diagnostics = dict(r.infos[k].get(INFO_DIAGNOSTICS) or {})
        ended.append((env, res))
    return busy, ended


class BatchVectorEnv:
    """The vector runner's interface (``spec``, ``num_envs``, ``run``, ``close``, ``restarts``) over any
    ``BatchRollout``: ``run`` is ``run_batch``. What ``simseam run --num-envs`` drives when the environments
    come batched (MuJoCo Warp's worlds, a backend's own batch in one sidecar) instead of as worker
    processes (``runner.vector.VectorEnv``, the same interface)."""

    def __init__(self, batch):
        self.batch = batch
        self.spec = batch.spec
        self.num_envs = batch.num_envs
        self.restarts = 0  # the worker processes' counter of restarted workers: none here

    def run(self, policy, indices: Sequence[int], *, seed: int = 0, video_dir: Path | None = None,
            max_attempts: int = 3, groups: int = 1, ready: int | None = None, on_start=None, on_step=None,
            on_done=None, on_error=None, on_worker_failure=None, keep: bool = True) -> list[EpisodeResult]:
        if groups != 1:  # a batched simulator keeps simulating the environments left out of a step
            raise ConfigError(f"policy groups {groups}: pipelined lockstep needs worker processes; these "
                              f"{self.num_envs} environments step together in one batch (use 1 group)")
        if ready is not None:
            raise ConfigError(f"--policy-ready {ready}: acting on the environments that are in needs worker "
                              f"processes; these {self.num_envs} environments step together in one batch")
        return run_batch(self.batch, policy, indices, seed=seed, video_dir=video_dir, max_attempts=max_attempts,
                         on_start=on_start, on_step=on_step, on_done=on_done, on_error=on_error,
                         on_worker_failure=on_worker_failure, keep=keep)

    def close(self) -> None:
        self.batch.close()

    def __enter__(self) -> "BatchVectorEnv":
        return self

    def __exit__(self, *exc) -> None:
        self.close()
