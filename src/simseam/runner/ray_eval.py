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
from simseam.seam import ConfigError, RolloutSpec, SimseamError, SimulationError


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
    from ray.exceptions import GetTimeoutError, RayActorError, RayTaskError

    lost_errors: tuple = (RayActorError,)
    for name in ("NodeDiedError", "WorkerCrashedError", "ActorUnavailableError", "OwnerDiedError",
                 "ObjectLostError"):
        if hasattr(ray.exceptions, name):
            lost_errors += (getattr(ray.exceptions, name),)
    env = {"env_vars": {"MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}}
    try:
        ray.init(address=None if address == "local" else address, ignore_reinit_error=True, log_to_driver=False,
                 logging_level="warning", runtime_env=env, configure_logging=True)
    except (ConnectionError, ValueError, RuntimeError) as exc:
        raise ConfigError(f"--ray {address}: cannot connect to a Ray cluster: {exc}") from None
    cpus = int(ray.cluster_resources().get("CPU", 1))
    n = max(1, min(num_workers or cpus, len(indices)))
    Actor = ray.remote(num_cpus=1, max_restarts=0)(EpisodeWorker)

    def cause(exc: BaseException) -> BaseException:
        inner = getattr(exc, "cause", None)
        return inner if isinstance(inner, BaseException) else SimulationError(str(exc).splitlines()[0])

    starting: dict[Any, Any] = {}  # ready-ref -> actor (building its rollout)
    idle: list = []
    busy: dict[Any, tuple] = {}  # result-ref -> (actor, index)
    todo = EpisodeQueue(indices, seed, max_attempts)
    results: list[dict] = []
    spec_seen = False
    actor_ids: dict[Any, int] = {}
    nodes: dict[Any, str] = {}  # actor -> the Ray node id it runs on
    next_id = [0]

    def finished(entry: dict) -> None:
        if keep:
            results.append(entry)
        if on_done:
            on_done(entry)

    def new_actor():
        a = Actor.remote(recipe, policy, policy_kwargs)
        actor_ids[a] = next_id[0]
        next_id[0] += 1
        starting[a.ready.remote()] = a

    def failed(actor, index, exc) -> None:
        try:
            ray.kill(actor)
        except Exception:  # noqa: BLE001  (already gone)
            pass
        what, res = "no episode in flight", None
        if index is not None:
            what, res = todo.lost(index, lambda n: f"Ray worker lost {n} times ({type(exc).__name__})")
        if res is not None:
            entry = res.to_json()
            finished(entry)
        if on_worker_failure:
            node = nodes.get(actor)
            on_worker_failure(WorkerFailure(env=-1, index=index, exitcode=None,
                                            what_next=f"{what} ({type(exc).__name__}; it ran on Ray node "
                                                      f"{node[:12] if node else 'unknown'})"))
        if todo:
            new_actor()

    try:
        for _ in range(n):
            new_actor()
        while todo or busy:
            while idle and todo:
                actor = idle.pop()
                i = todo.next()
                busy[actor.run.remote(i, seed)] = (actor, i)
            waiting = list(busy) + list(starting)
            if not waiting:
                raise SimulationError("no Ray worker is left to run the remaining episodes")
            try:
                ready, _ = ray.wait(waiting, num_returns=1, timeout=None)
            except GetTimeoutError:  # pragma: no cover - timeout=None
                continue
            ref = ready[0]
            if ref in starting:
                actor = starting.pop(ref)
                try:
                    info = ray.get(ref)
                except lost_errors as exc:
                    failed(actor, None, exc)
                    continue
                except RayTaskError as exc:
                    raise cause(exc) from None
                nodes[actor] = info["node"]
                if not spec_seen:
                    spec_seen = True
                    if check is not None:
                        check(RolloutSpec.from_json(info["spec"]))
                    if on_spec:
                        on_spec(info["spec"])
                idle.append(actor)
                continue
            actor, i = busy.pop(ref)
            try:
                entry = ray.get(ref)
            except lost_errors as exc:
                failed(actor, i, exc)
                continue
            except RayTaskError as exc:
                raise cause(exc) from None
            entry["worker"] = {"ray_node": nodes.get(actor), "actor": actor_ids.get(actor)}
            finished(entry)
            idle.append(actor)
        return results
    except SimseamError:
        raise
    finally:
        for actor in [*idle, *(a for a, _ in busy.values()), *starting.values()]:
            try:
                ray.kill(actor)
            except Exception:  # noqa: BLE001
                pass
        ray.shutdown()
