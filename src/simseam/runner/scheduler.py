"""The episode scheduler over a ``BatchRollout``: N environments, one queue of episodes, one batched policy.

Environment ``j`` plays episode after episode from one queue of indices; episode ``i`` uses seed
``seed + i``, so the per-episode results do not depend on the number of environments for a
deterministic policy. When an environment's episode ends (success terminates it, the step limit
truncates it), the environment is reset alone with the next index while the others go on. Each
step the batched policy (``PolicyBatch``: ``reset(env, spec)``, ``observe_next(env)``,
``act_batch(envs, observations)``) acts for every busy environment at once, and the batch steps
exactly those, observing what each environment's policy will read next.

A policy with ``act_device(observation)`` on a batch with ``device_observation()`` /
``step_device(actions)`` (MuJoCo Warp) reads the batch's device arrays and answers device actions
for every environment: no host copy of observations or actions.
"""

from __future__ import annotations

import time
from collections import deque
from typing import Callable, Sequence

import numpy as np

from simseam.runner.episodes import EpisodeResult
from simseam.seam import INFO_DIAGNOSTICS, SimulationError


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


class _Episodes(EpisodeQueue):
    """The queue, and the episode each environment of a batch is playing."""

    def __init__(self, indices: Sequence[int], n: int, seed: int):
        super().__init__(indices, seed)
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


def run_batch(batch, policy, indices: Sequence[int], *, seed: int = 0,
              on_start: Callable[[int, int], None] | None = None,
              on_step: Callable[[int, int, int], None] | None = None,
              on_done: Callable[[EpisodeResult], None] | None = None) -> list[EpisodeResult]:
    """Run episodes ``indices`` on ``batch`` (see the module docstring). ``on_start(env, index)``,
    ``on_step(env, index, steps)`` and ``on_done(result)`` follow each episode; results in the order
    the episodes finished."""
    spec, n = batch.spec, batch.num_envs
    episodes = _Episodes(indices, n, seed)
    device = callable(getattr(policy, "act_device", None)) and callable(getattr(batch, "device_observation", None))
    obs: list = [None] * n
    results: list[EpisodeResult] = []

    def start(envs: Sequence[int]) -> None:
        started = episodes.take(envs)
        for env in started:
            policy.reset(env, spec)
            if on_start:
                on_start(env, episodes.playing[env].index)
        if started:
            got = batch.reset(started, [episodes.playing[e].seed for e in started],
                              None if device else [policy.observe_next(e) for e in started])
            for env, o in zip(started, got):
                obs[env] = o

    start(range(n))
    while busy := episodes.busy():
        t0 = time.perf_counter()
        if device:
            actions = policy.act_device(batch.device_observation())
        else:
            actions = np.asarray(policy.act_batch(busy, [obs[e] for e in busy]), dtype=np.float32)
            if actions.shape != (len(busy), spec.action_dim):
                raise SimulationError(f"act_batch returned shape {actions.shape} for {len(busy)} environments")
        policy_ms = (time.perf_counter() - t0) * 1e3
        t0 = time.perf_counter()
        if device:
            r = batch.step_device(actions, busy)
        else:
            r = batch.step(busy, actions, [policy.observe_next(e) for e in busy])
        step_ms = (time.perf_counter() - t0) * 1e3
        ended = []
        for k, env in enumerate(busy):
            res = episodes.playing[env]
            res.steps += 1
            res.reward += float(r.reward[k])
            res.step_ms.append(step_ms)
            res.policy_ms.append(policy_ms)
            res.success |= bool(r.infos[k].get(spec.task.success_key))
            obs[env] = r.observations[k]
            if on_step:
                on_step(env, res.index, res.steps)
            if r.terminated[k] or r.truncated[k] or res.steps >= spec.task.max_steps:
                res.diagnostics = dict(r.infos[k].get(INFO_DIAGNOSTICS) or {})
                ended.append(env)
        for env in ended:
            results.append(episodes.playing[env])
            if on_done:
                on_done(episodes.playing[env])
            episodes.playing[env], obs[env] = None, None
        if ended:
            start(ended)
    return results
