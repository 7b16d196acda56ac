"""Whole episodes per worker: the one queue-and-dispatch loop of the executors whose workers each hold their
own policy instance and play whole episodes, sending back only results: the worker processes
(``run_local`` over a ``runner.vector.VectorEnv``) and Ray's actors (``runner.ray_eval``).

``play(workers, queue)`` hands each idle worker the next episode index of an ``EpisodeQueue``
(``runner.scheduler``: episode ``i`` uses seed ``seed + i`` wherever it runs), waits for what the workers
report and applies the one retry rule: an episode lost with its worker goes back to the front of the queue
(``EpisodeQueue.lost``: at most ``max_attempts`` tries, then it is recorded with its error), the worker
having been replaced by the pool. Every finished episode reaches ``on_done`` exactly once.

A pool of workers answers ``idle()`` (the workers ready for an episode), ``send(worker, index)``,
``busy()`` (an episode in flight), ``wait()`` (what happened since: ``Returned`` and ``Lost`` events; it
starts a fresh worker in place of a lost one, and raises an error that must stop the run) and
``as_result(EpisodeResult)`` (an error result as the pool reports its results: an ``EpisodeResult`` for the
worker processes, its JSON entry for Ray).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Protocol, Sequence

from simseam.runner.episodes import EpisodeResult
from simseam.runner.scheduler import EpisodeQueue, WorkerFailure
from simseam.seam import ConfigError


@dataclass
class Returned:
    """A worker finished episode ``index``: its ``result``, or None with the ``error`` that escaped the
    worker's episode loop (recorded under the episode); ``what_next`` when an error cost the episode."""

    worker: Any
    index: int
    result: Any = None
    what_next: str | None = None
    error: str | None = None


@dataclass
class Lost:
    """A worker was lost (a fresh one takes its place) with episode ``index`` in flight (None: between
    episodes). ``error(times)``: the error of an episode lost that often; ``failure(what_next)``: the
    ``WorkerFailure`` to report."""

    worker: Any
    index: int | None
    error: Callable[[int], str]
    failure: Callable[[str], WorkerFailure]


class EpisodeWorkers(Protocol):
    """A pool of workers that play whole episodes (see the module docstring)."""

    def idle(self) -> list: ...

    def send(self, worker, index: int) -> None: ...

    def busy(self) -> bool: ...

    def wait(self) -> list[Returned | Lost]: ...

    def as_result(self, res: EpisodeResult) -> Any: ...


def play(workers: EpisodeWorkers, queue: EpisodeQueue, *, on_done: Callable[[Any], None] | None = None,
         on_error: Callable[[Any, str], None] | None = None,
         on_worker_failure: Callable[[WorkerFailure], None] | None = None, keep: bool = True) -> list:
    """Run every episode of ``queue`` on ``workers``; returns the results in the order they finished (none
    with ``keep=False``: each reaches ``on_done``, memory stays flat). ``on_error(result, what_next)``: an
    error (a sidecar's) cost the episode; ``on_worker_failure``: a worker was lost."""
    results: list = []

    def finish(res) -> None:
        if keep:
            results.append(res)
        if on_done:
            on_done(res)

    while queue or workers.busy():
        for worker in workers.idle():
            if not queue:
                break
            workers.send(worker, queue.next())
        if not workers.busy() and not queue:
            break
        for event in workers.wait():
            if isinstance(event, Lost):
                what, res = ("no episode in flight", None) if event.index is None else \
                    queue.lost(event.index, event.error)
                if on_worker_failure:
                    on_worker_failure(event.failure(what))
                if res is not None:
                    finish(workers.as_result(res))
                continue
            res = event.result
            if res is None:
                res = workers.as_result(queue.new_result(event.index))
                res.error = event.error
            if event.what_next is not None and on_error:
                on_error(res, event.what_next)
            finish(res)
    return results


class _WorkerProcesses:
    """A ``VectorEnv``'s workers as a pool of whole-episode workers: each plays with its own instance of
    the policy spec ``policy_key`` (made on its first episode)."""

    def __init__(self, vec, policy_key: tuple, seed: int, video_dir: Path | None):
        self.vec, self.policy_key, self.seed = vec, policy_key, seed
        self.video_dir = str(video_dir) if video_dir else None

    def idle(self) -> list[int]:
        return self.vec.idle_envs()

    def send(self, env: int, index: int) -> None:
        self.vec.send_episode(env, index, self.seed, self.policy_key, self.video_dir)

    def busy(self) -> bool:
        return self.vec.playing()

    def wait(self) -> list[Returned | Lost]:
        return self.vec.episode_events()

    def as_result(self, res: EpisodeResult) -> EpisodeResult:
        return res


def run_local(vec, policy: str, policy_kwargs: dict | None, indices: Sequence[int], *, seed: int = 0,
              video_dir: Path | None = None, max_attempts: int = 3,
              on_done: Callable[[EpisodeResult], None] | None = None,
              on_error: Callable[[EpisodeResult, str], None] | None = None,
              on_worker_failure: Callable[[WorkerFailure], None] | None = None,
              keep: bool = True) -> list[EpisodeResult]:
    """The episodes ``indices`` on ``vec``'s worker processes (a ``VectorEnv``), the policy inside each
    worker: every worker builds its own instance of the policy spec (``make_policy(policy,
    **policy_kwargs)``) and plays whole episodes, sending back only results, as N independent processes
    would (the fastest way for policies that share no model: no round trip to this process per step).
    Same seeds, same failure handling as ``VectorEnv.run``."""
    if vec.central is not None:
        raise ConfigError("renderer 'batched' draws the frames in this process, so it steps the workers "
                          "together (run); run_local keeps the policy and its cameras inside each worker")
    if vec.envs_per_worker > 1:
        raise ConfigError(f"{vec.envs_per_worker} environments per worker hide the round trip of a policy "
                          "acting in this process (run); run_local plays whole episodes in each worker, "
                          "where one environment per worker is fastest")
    policy_key = (policy, tuple(sorted((policy_kwargs or {}).items())))
    return play(_WorkerProcesses(vec, policy_key, seed, video_dir), EpisodeQueue(indices, seed, max_attempts),
                on_done=on_done, on_error=on_error, on_worker_failure=on_worker_failure, keep=keep)
