"""Episodes on a Ray cluster (``simseam run --ray auto|ADDRESS``; ``ray`` from PyPI, the ``ray`` extra).

Each Ray worker is an actor that holds one rollout (built from the scene config, its sidecar
included: the actor owns it) and its own policy instance (a ``remote:`` policy shares one batching
``serve-policy`` among all of them). The driver (the ``simseam run`` process) hands episode indices to
idle actors and writes each result into the run's episode log as it arrives; episode ``i`` uses seed
``seed + i`` wherever it runs.

The actor asks its recipe (``runner.recipe``) for each episode's rollout and seed base
(``rollout_for``), as the vector workers do: ``simseam eval --ray`` passes a ``BenchmarkRecipe``, so an
actor owns one sidecar of the benchmark's backend and replaces it only when the next episode's task
differs (episode ``i = ti * n + e`` runs with ``seed + e``).

Fault tolerance: an actor that dies (its process, or the node under it) fails its task with a Ray
actor/node error; the driver puts that episode back at the front of the queue (at most
``max_attempts`` tries, then it is recorded with its error), starts a replacement actor (Ray places
it on a live node; it takes episodes once it has built its rollout) and goes on. Results are keyed
by episode index and only the driver writes the log, so nothing is lost or counted twice. An error
the rollout raises (a ``SimseamError`` other than a sidecar crash, which costs only its episode as
in the sequential loop) stops the run and is raised here.

All nodes need the same Python environment with simseam installed (or a ``runtime_env``); ``--video``
is refused (each node would write its own disk).
"""

from __future__ import annotations

import os
from typing import Any, Callable, Sequence

from simseam.runner.recipe import BenchmarkRecipe, SceneRecipe
from simseam.runner.scheduler import EpisodeQueue, WorkerFailure
from simseam.runner.whole_episodes import Lost, Returned, play
from simseam.seam import ConfigError, RolloutSpec, SimulationError


def _import_ray():
    try:
        import ray
    except ImportError as exc:
        raise ConfigError(f"--ray needs Ray ({exc}); install it with `pip install 'simseam[ray]'`") from None
    return ray


class EpisodeWorker:
    """A Ray actor: one rollout and one policy; ``run(i, seed)`` plays episode ``i`` (seed ``seed + i``,
    or the recipe's ``rollout_for`` says which rollout and seed base)."""

    def __init__(self, recipe: SceneRecipe | BenchmarkRecipe, policy: str, policy_kwargs: dict):
        from simseam.policies.base import make_policy

        self.recipe = recipe
        self.policy = make_policy(policy, **policy_kwargs)
        self.rollout = recipe.build()

    def ready(self) -> dict:
        """The rollout's spec, and where this actor runs."""
        import ray

        return {"spec": self.rollout.spec.to_json(), "node": ray.get_runtime_context().get_node_id(),
                "pid": os.getpid()}

    def run(self, index: int, seed: int) -> dict:
        from simseam.runner.session import run_episodes

        self.rollout, seed = self.recipe.rollout_for(self.rollout, index, seed)  # (simseam eval: its task's)
        return run_episodes(self.rollout, self.policy, [index], seed=seed)[0].to_json()

    def close(self) -> None:
        self.rollout.close()
        close = getattr(self.policy, "close", None)
        if callable(close):
            close()


def run_on_ray(address: str, recipe: SceneRecipe | BenchmarkRecipe, policy: str, policy_kwargs: dict, indices: Sequence[int], *,
               seed: int = 0, num_workers: int | None = None, max_attempts: int = 3,
               on_spec: Callable[[dict], None] | None = None,
               check: Callable[[RolloutSpec], None] | None = None,
               on_done: Callable[[dict], None] | None = None,
               on_worker_failure: Callable[[WorkerFailure], None] | None = None,
               keep: bool = True) -> list[dict]:
    """Run the episodes ``indices`` on the Ray cluster at ``address`` (``auto``: the one on this
    machine; ``local``: start a private one); returns the episode entries (``EpisodeResult.to_json()``)
    in the order they finished (none with ``keep=False``: each reaches ``on_done``, memory stays flat).
    ``on_spec(spec_json)`` is called once the first actor is ready, after ``check(spec)`` (the caller's
    policy meets the rollouts' spec there: a policy that does not fit fails before anything is written)."""
    ray = _import_ray()
    _connect(ray, address)
    cpus = int(ray.cluster_resources().get("CPU", 1))
    pool = _ActorPool(ray, ray.remote(num_cpus=1, max_restarts=0)(EpisodeWorker), (recipe, policy, policy_kwargs),
                      seed, on_spec=on_spec, check=check)
    try:
        pool.start(max(1, min(num_workers or cpus, len(indices))))
        return play(pool, EpisodeQueue(indices, seed, max_attempts), on_done=on_done,
                    on_worker_failure=on_worker_failure, keep=keep)
    finally:
        pool.close()
        ray.shutdown()


def _connect(ray, address: str) -> None:
    env = {"env_vars": {"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}}
    try:
        ray.init(address=None if address == "local" else address, ignore_reinit_error=True, log_to_driver=False,
                 logging_level="warning", runtime_env=env, configure_logging=True)
    except (ConnectionError, ValueError, RuntimeError) as exc:
        raise ConfigError(f"--ray {address}: cannot connect to a Ray cluster: {exc}") from None


def _lost_errors(ray) -> tuple:
    """The exceptions that mean a Ray actor (or its node) is gone, whichever this Ray version has."""
    from ray.exceptions import RayActorError

    lost: tuple = (RayActorError,)
    for name in ("NodeDiedError", "WorkerCrashedError", "ActorUnavailableError", "OwnerDiedError",
                 "ObjectLostError"):
        if hasattr(ray.exceptions, name):
            lost += (getattr(ray.exceptions, name),)
    return lost


def _cause(exc: BaseException) -> BaseException:
    """The exception an episode worker raised, out of Ray's wrapper."""
    inner = getattr(exc, "cause", None)
    return inner if isinstance(inner, BaseException) else SimulationError(str(exc).splitlines()[0])


class _ActorPool:
    """Ray actors as a pool of whole-episode workers (``runner.whole_episodes``): actors starting (building
    their rollout), idle, busy; a lost actor is replaced by a new one."""

    def __init__(self, ray, actor_class, make_args: tuple, seed: int, *, on_spec, check):
        self.ray, self.actor_class, self.make_args, self.seed = ray, actor_class, make_args, seed
        self.on_spec, self.check = on_spec, check
        self.lost = _lost_errors(ray)
        self.starting: dict[Any, Any] = {}  # ready-ref -> actor (building its rollout)
        self.idle_actors: list = []
        self.running: dict[Any, tuple] = {}  # result-ref -> (actor, index)
        self.spec_seen = False
        self.actor_ids: dict[Any, int] = {}
        self.nodes: dict[Any, str] = {}  # actor -> the Ray node id it runs on

    def start(self, n: int) -> None:
        for _ in range(n):
            self._new_actor()

    def idle(self) -> list:
        return self.idle_actors[::-1]  # the last to come back goes first

    def send(self, actor, index: int) -> None:
        self.idle_actors.remove(actor)
        self.running[actor.run.remote(index, self.seed)] = (actor, index)

    def busy(self) -> bool:
        return bool(self.running)

    def as_result(self, res) -> dict:
        return res.to_json()

    def wait(self) -> list:
        waiting = list(self.running) + list(self.starting)
        if not waiting:
            raise SimulationError("no Ray worker is left to run the remaining episodes")
        ready, _ = self.ray.wait(waiting, num_returns=1, timeout=None)
        ref = ready[0]
        return self._started(ref) if ref in self.starting else self._returned(ref)

    def _get(self, ref, actor, index):
        """``ray.get(ref)``, or a ``Lost`` event when the actor was lost; an episode's own error re-raised."""
        from ray.exceptions import RayTaskError

        try:
            return self.ray.get(ref)
        except self.lost as exc:
            return self._failed(actor, index, exc)
        except RayTaskError as exc:
            raise _cause(exc) from None

    def _started(self, ref) -> list:
        actor = self.starting.pop(ref)
        info = self._get(ref, actor, None)
        if isinstance(info, Lost):
            return [info]
        self.nodes[actor] = info["node"]
        if not self.spec_seen:
            self.spec_seen = True
            if self.check is not None:
                self.check(RolloutSpec.from_json(info["spec"]))
            if self.on_spec:
                self.on_spec(info["spec"])
        self.idle_actors.append(actor)
        return []

    def _returned(self, ref) -> list:
        actor, i = self.running.pop(ref)
        entry = self._get(ref, actor, i)
        if isinstance(entry, Lost):
            return [entry]
        entry["worker"] = {"ray_node": self.nodes.get(actor), "actor": self.actor_ids.get(actor)}
        self.idle_actors.append(actor)
        return [Returned(actor, i, entry)]

    def _new_actor(self) -> None:
        a = self.actor_class.remote(*self.make_args)
        self.actor_ids[a] = len(self.actor_ids)
        self.starting[a.ready.remote()] = a

    def _failed(self, actor, index, exc) -> Lost:
        """The actor is gone: killed for good, a new one started in its place."""
        try:
            self.ray.kill(actor)
        except Exception:  # noqa: BLE001  (already gone)
            pass
        node, kind = self.nodes.get(actor), type(exc).__name__
        self._new_actor()
        return Lost(actor, index, lambda n: f"Ray worker lost {n} times ({kind})",
                    lambda what: WorkerFailure(env=-1, index=index, exitcode=None,
                                               what_next=f"{what} ({kind}; it ran on Ray node "
                                                         f"{node[:12] if node else 'unknown'})"))

    def close(self) -> None:
        for actor in [*self.idle_actors, *(a for a, _ in self.running.values()), *self.starting.values()]:
            try:
                self.ray.kill(actor)
            except Exception:  # noqa: BLE001
                pass
