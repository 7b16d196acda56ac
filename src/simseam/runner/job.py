"""A job and its executor: what to run, and where. ``simseam run``, ``simseam eval`` and ``simseam collect``
parse and check their options, build a ``Job`` and an ``Executor`` and call ``execute(job, executor,
report)``; nothing else of a run's plumbing lives in the command line.

- ``Job``: the recipe (``runner.recipe``: a scene file's, or an evaluation preset's tasks on their backend
  or on a batched engine), the policy spec, the episode indices to run, the seed (episode ``i`` uses
  ``seed + i``; a benchmark's episode ``e`` of each task ``seed + e``), the run directory (None: no run
  log, as ``collect``), videos, a LeRobot dataset to record, action noise.
- ``Executor``: ``inline`` (one rollout in this process, episode after episode, the parts of the job in
  turn), ``vector`` (``num_envs`` environments: worker processes, or one batch stepped from this process
  when the recipe's engine batches: MuJoCo Warp's worlds, a backend's own batch, a benchmark's port),
  ``ray`` (actors on a Ray cluster at ``address``).
- ``JobReport``: how a job tells its caller what happens (callbacks, each optional) and what it learnt
  (the run's spec, the dataset recorder).

Every executor writes the same things: ``spec.json`` once (the first rollout's spec; a resumed run keeps
the one it has), one log line per finished episode as it ends (``recipe.log_entry``), and gives the same
episode the same seed. On ``vector``, the policy acts in this process for every environment at once (one
``PolicyBatch``, ``policies.batch.batch_for``: stepped by the ``lockstep`` rule) when it shares a model or a
server, when the environments are one batch here, when the cameras are drawn here, or when the lockstep
rule steps the workers from here; otherwise each worker runs its own instance and plays whole episodes
(``runner.whole_episodes``). A policy meets the first rollout's spec before anything is written: one that
does not fit fails with the run directory as it was.
"""

from __future__ import annotations

import functools
import os
import threading
import time
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

from simseam.policies.base import PolicyTraits
from simseam.runner.recipe import BenchmarkRecipe, SceneRecipe
from simseam.runner.scheduler import Lockstep
from simseam.seam import ConfigError, RolloutSpec


def _recipe_for(job: Job, traits: PolicyTraits) -> Any:
    """The job's recipe with the scene options a policy of ``traits`` (``policies.base.PolicyTraits``) asks for:
    ground truth, cameras, the objects' state (a benchmark whose objects' state is off unless asked for turns it
    on for a policy that reads it)."""
    return job.recipe.for_policy(traits.requires_privileged, traits.uses_images, traits.reads_environment_state)

EXECUTORS = ("inline", "vector", "ray")


@dataclass
class Dataset:
    """A new LeRobot dataset the inline executor records the episodes into."""

    path: Path
    use_videos: bool = True
    overwrite: bool = False
    keep_failures: bool = True


@dataclass
class Job:
    """What to run (see the module docstring). ``recipe.render_images``: what the run itself renders
    (videos, a dataset's frames); the policy's cameras are added when it is made."""

    recipe: SceneRecipe | BenchmarkRecipe
    policy: str
    policy_kwargs: dict
    indices: list[int]
    seed: int = 0
    run_dir: Any = None
    video: bool = False
    dataset: Dataset | None = None
    action_noise: float = 0.0
    claims: Any = None  # runner.claims.TaskClaims: the run's parts (whole tasks) taken one at a time with others

    @property
    def video_dir(self) -> Path | None:
        return Path(self.run_dir.path) if self.video and self.run_dir is not None else None


@dataclass(frozen=True)
class Executor:
    """Where a job runs: ``kind`` one of ``EXECUTORS``; ``num_envs`` environments (``vector``) or Ray workers
    (``ray``; None: the cluster's CPUs); ``lockstep``: how the workers are stepped from here; ``renderer``:
    who draws the workers' cameras (``--renderer``); ``address``: the Ray cluster."""

    kind: str = "inline"
    num_envs: int | None = None
    lockstep: Lockstep = field(default_factory=Lockstep)
    renderer: str = "workers"
    address: str | None = None

    def __post_init__(self):
        if self.kind not in EXECUTORS:
            raise ConfigError(f"executor {self.kind!r}: one of {', '.join(EXECUTORS)}")


class _Status:
    """A status that shows nothing."""

    def __enter__(self) -> "_Status":
        return self

    def __exit__(self, *exc) -> None:
        pass

    def update(self, text: str) -> None:
        pass


@dataclass
class JobReport:
    """What a job tells its caller. ``status(what)``: a context (with ``update(stage)``) around building a
    rollout (``what``: ``recipe.describe()``); ``on_envs(spec, n, where)``: environments ready (their spec,
    None for Ray's before they start; how many; where the policy acts, in words); ``on_episode(index)``: an
    episode starts in this process (inline), may return a per-step callback; ``on_done(entry, written)``: an
    episode's log line (``written``: whether the dataset kept it, None without one); ``on_error(result,
    what_next)``: a sidecar's or a policy server's failure cost an episode; ``on_worker_failure``; ``on_save(i)``:
    the dataset encodes episode ``i``. Filled in by ``execute``: ``spec_json`` (the first rollout's), ``dataset``
    (the recorder, closed when ``execute`` ends), ``envs`` (what the episodes run on now: the rollout, the
    ``VectorEnv`` or batch; None on Ray)."""

    status: Callable[[str], Any] = lambda what: _Status()  # noqa: E731
    on_envs: Callable[[RolloutSpec | None, int, str], None] | None = None
    on_episode: Callable[[int], Callable[[int], None] | None] | None = None
    on_done: Callable[[dict, bool | None], None] | None = None
    on_error: Callable[[Any, str], None] | None = None
    on_worker_failure: Callable[[Any], None] | None = None
    on_save: Callable[[int], None] | None = None
    spec_json: dict | None = None
    dataset: Any = None
    envs: Any = None


class _Log:
    """What every executor writes: the run's spec once, each finished episode's log line."""

    def __init__(self, job: Job, report: JobReport):
        from simseam.runner.run_dir import SPEC_FILE

        self.job, self.report, rd = job, report, job.run_dir
        self.spec_written = rd is None or (rd.resume and (Path(rd.path) / SPEC_FILE).exists())
        #: when this process's policy was built (epoch seconds; the timing lines say it: a model's import and
        #: load is part of a process's start)
        self.policy_ready: float | None = None

    def spec(self, spec_json: dict) -> None:
        if self.report.spec_json is None:
            self.report.spec_json = spec_json
        if not self.spec_written:
            self.job.run_dir.write_spec(spec_json)
            self.spec_written = True

    def timing(self, entry: dict) -> None:
        if self.job.run_dir is not None:
            self.job.run_dir.append_timing(entry)

    def episode(self, entry: dict, written: bool | None = None) -> None:
        entry = self.job.recipe.log_entry(entry, self.job.seed)
        if self.job.run_dir is not None:
            self.job.run_dir.append(entry)
        if self.report.on_done:
            self.report.on_done(entry, written)


def execute(job: Job, executor: Executor, report: JobReport | None = None) -> None:
    """Run ``job`` on ``executor`` (see the module docstring); every finished episode is in the run's log
    (and ``report.on_done``) before this returns or raises. Ctrl-C drops the episodes in flight."""
    report = report or JobReport()
    if not job.indices:
        return
    run = {"inline": _inline, "vector": _vector, "ray": _ray}[executor.kind]
    run(job, executor, report, _Log(job, report))


def _close(policy) -> None:
    close = getattr(policy, "close", None)
    if callable(close):
        close()


def _inline(job: Job, executor: Executor, report: JobReport, log: _Log) -> None:
    """One rollout in this process, episode after episode; a benchmark's tasks one after another."""
    from simseam.policies.base import make_policy
    from simseam.runner.session import run_episodes

    policy = make_policy(job.policy, **job.policy_kwargs)
    rollout = None
    try:
        recipe = _recipe_for(job, PolicyTraits.of(policy))
        for part, indices, seed in recipe.parts(job.indices, job.seed):
            with report.status(part.describe()) as status:
                rollout = part.build(progress=status.update)
            if job.action_noise > 0:
                from simseam.runner.action_noise import ActionNoise

                rollout = ActionNoise(rollout, job.action_noise)
            policy.reset(rollout.spec)  # the policy's contract, before anything is written
            _start_dataset(job, report, rollout.spec)
            log.spec(rollout.spec.to_json())
            report.envs = rollout
            if report.on_envs:
                report.on_envs(rollout.spec, 1, "")
            run_episodes(rollout, policy, indices, seed=seed, video_dir=job.video_dir, recorder=report.dataset,
                         keep_failures=job.dataset.keep_failures if job.dataset else True,
                         on_start=report.on_episode, on_done=lambda res, kept: log.episode(res.to_json(), kept),
                         on_error=report.on_error, on_save=report.on_save, keep=False)
            rollout.close()
            rollout = None
    finally:
        if report.dataset is not None:
            report.dataset.close()
        if rollout is not None:
            rollout.close()
        _close(policy)


def _start_dataset(job: Job, report: JobReport, spec: RolloutSpec) -> None:
    """The job's dataset recorder, once: made before the first episode, so one that cannot start replaces
    nothing."""
    if job.dataset is None or report.dataset is not None:
        return
    from simseam.runner.dataset_recorder import LeRobotRecorder

    d = job.dataset
    report.dataset = LeRobotRecorder(d.path, spec, use_videos=d.use_videos, overwrite=d.overwrite)


def _vector(job: Job, executor: Executor, report: JobReport, log: _Log) -> None:
    """``num_envs`` environments: the policy acting here for all of them (one batch, each part of the job
    on its own environments in turn), or inside each worker (whole episodes, every part on one set)."""
    from simseam.policies.base import make_policy, predict_traits
    from simseam.policies.batch import batch_for

    traits = predict_traits(job.policy, job.policy_kwargs) if job.recipe.steps_here() else None
    if traits is not None:
        try:
            _stepped_while_loading(job, executor, traits, report, log)
            return
        except _TraitsDiffer:
            pass  # nothing was written: the run starts again, the policy made first
    probe = make_policy(job.policy, **job.policy_kwargs)
    log.policy_ready = time.time()
    batch = None
    try:
        recipe = _recipe_for(job, PolicyTraits.of(probe))
        n, rule, renderer = _batch_shape(job, executor, recipe)
        here = recipe.steps_here()
        chosen = ""
        default = (_default_rule(job, probe, n) if rule.auto and not here and renderer == "workers"
                   and recipe.engine_in_worker() else None)  # no rule named
        if default is not None:
            batch, n, rule, chosen = default
        else:
            batch = batch_for(probe, job.policy, n, job.policy_kwargs,
                              acts_here=here or renderer == "batched" or rule.acts_here)
        if batch is None:
            first, probe = probe, None
            _whole_episodes(job, recipe, n, first, report, log)
            return
        probe = None  # the batch owns it
        ready = batch
        _stepped(job, recipe, lambda: ready, n, rule, renderer, _where(recipe, renderer, rule) + chosen, report, log)
    finally:
        if batch is not None:
            batch.close()
        if probe is not None:
            _close(probe)


def _batch_shape(job: Job, executor: Executor, recipe) -> tuple[int, Lockstep, str]:
    """How many environments a vector run of ``recipe`` steps, by which lockstep rule, with which renderer."""
    n = max(1, min(executor.num_envs or 1, len(job.indices)))
    rule = executor.lockstep.fit(n)
    if recipe.steps_here() and rule.envs_per_worker > 1:
        raise ConfigError(f"--envs-per-worker {rule.envs_per_worker}: {recipe.describe()} steps its {n} "
                          "environments in one batch in this process, not in worker processes")
    return n, rule, recipe.renderer_for(executor.renderer)


def _where(recipe, renderer: str, rule: Lockstep) -> str:
    """Where a stepped run's policy acts, for the run's first line."""
    return ("one batched policy" + recipe.parts_in_turn + (", cameras drawn here in one batch"
                                                           if renderer == "batched" else "") + rule.describe())


class _TraitsDiffer(Exception):
    """The policy, once made, asks the scene for other things than its files told (``predict_traits``)."""


class _PolicyAhead:
    """The run's policy made, and its batch for ``n`` environments built, on a thread while the first batch of
    environments opens: a torch policy's imports and checkpoint (19-21 s a process on a GPU machine running ten)
    beside the engine's start. ``batch()`` waits for it (and raises what making it raised); ``close()`` waits and
    closes what was made."""

    def __init__(self, job: Job, n: int, log: _Log):
        self._job, self._n, self._log = job, n, log
        self._made = self._error = None
        self._thread = threading.Thread(target=self._make, name="simseam-policy", daemon=True)
        self._thread.start()

    def _make(self) -> None:
        from simseam.policies.base import make_policy
        from simseam.policies.batch import batch_for

        job = self._job
        try:
            probe = make_policy(job.policy, **job.policy_kwargs)
            traits = PolicyTraits.of(probe)
            try:
                self._made = traits, batch_for(probe, job.policy, self._n, job.policy_kwargs, acts_here=True)
            except BaseException:
                _close(probe)
                raise
            self._log.policy_ready = time.time()
        except BaseException as exc:  # noqa: BLE001 - raised again where the run waits for the policy
            self._error = exc

    def batch(self, expected) -> Any:
        self._thread.join()
        if self._error is not None:
            raise self._error
        traits, batch = self._made
        if traits != expected:
            raise _TraitsDiffer(f"told {expected}, made {traits}")
        return batch

    def close(self) -> None:
        self._thread.join()
        if self._made is not None:
            self._made[1].close()


def _stepped_while_loading(job: Job, executor: Executor, traits, report: JobReport, log: _Log) -> None:
    """A run on a batched engine whose policy told its ``traits`` before it was made (``predict_traits``): the
    scene's options come from them, and the policy loads while the first part's batch opens (``_PolicyAhead``).
    Raises ``_TraitsDiffer`` before anything is written if the made policy differs from what it told."""
    recipe = _recipe_for(job, traits)
    n, rule, renderer = _batch_shape(job, executor, recipe)
    ahead = _PolicyAhead(job, n, log)
    try:
        _stepped(job, recipe, lambda: ahead.batch(traits), n, rule, renderer, _where(recipe, renderer, rule),
                 report, log)
    finally:
        ahead.close()


def _default_rule(job: Job, probe, workers: int) -> tuple[Any, int, Lockstep, str] | None:
    """A run that named no lockstep rule: when ``default_lockstep`` has one here and the policy shares a model or
    a server (so it acts here), the batch for that rule's environments, their number, the rule and a note for
    the run's first line; else None (the caller chooses as for any run)."""
    from simseam.policies.base import make_policy
    from simseam.policies.batch import shared_batch
    from simseam.runner.scheduler import default_lockstep
    from simseam.runner.vector import usable_cores

    cores = usable_cores()
    rule, envs = default_lockstep(workers, len(job.indices), cores)
    if not rule.acts_here:
        return None
    batch = shared_batch(probe, envs, lambda: make_policy(job.policy, **job.policy_kwargs))
    return None if batch is None else (batch, envs, rule, f" (the default on {cores} cores)")


def _whole_episodes(job: Job, recipe, n: int, probe, report: JobReport, log: _Log) -> None:
    """Every part on one set of ``n`` worker processes, each with its own policy instance (a worker switches
    to the next episode's rollout itself: ``recipe.rollout_for``); ``probe`` meets their spec, then closes."""
    from simseam.runner.whole_episodes import run_local

    first, _, _ = recipe.parts(job.indices, job.seed)[0]
    try:
        envs = first.open_envs(n)
    except BaseException:
        _close(probe)
        raise
    with envs:
        try:
            probe.reset(envs.spec)  # the policy's contract, before anything is written
        finally:
            _close(probe)  # made only for that: a remote: probe would hold a server's client slot
        log.spec(envs.spec.to_json())
        report.envs = envs
        if report.on_envs:
            report.on_envs(envs.spec, envs.num_envs, "a policy in each worker")
        run_local(envs, job.policy, job.policy_kwargs, job.indices, seed=job.seed, video_dir=job.video_dir,
                  on_done=lambda res: log.episode(res.to_json()), on_error=report.on_error,
                  on_worker_failure=report.on_worker_failure, keep=False)


def _stepped(job: Job, recipe, policy: Callable[[], Any], n: int, lockstep: Lockstep, renderer: str, where: str,
             report: JobReport, log: _Log) -> None:
    """Each part on its own environments (at most ``n``), stepped together from here with the policy batch
    ``policy()`` (asked for once the first part's environments are open: it may still be loading) by the
    ``lockstep`` rule."""
    shared, ahead, batch = recipe.shared(), None, None
    parts = recipe.parts(job.indices, job.seed)
    try:
        for k, (part, indices, seed) in enumerate(parts):
            if job.claims is not None and not job.claims.take(part.first_task):
                continue  # another process of the run holds this task
            m = max(1, min(n, len(indices)))
            rule = lockstep.fit(m)
            # started while the part before ran. The first part is not prepared ahead: its batch opens first, so
            # that worlds the device cannot hold fail at once, before thousands of resets are asked of LIBERO
            wait, ahead, opening = ahead, None, time.time()
            if wait is not None:
                wait()
            with part.open_envs(m, renderer=renderer, envs_per_worker=rule.envs_per_worker,
                                shared=shared) as envs:
                opened = time.time()
                ahead = _prefetch(_after(parts, k, job.claims), shared)  # the next part's, while this one steps
                batch = policy() if batch is None else batch
                batch.reset(0, envs.spec)  # the policy's contract, before anything is written
                log.spec(envs.spec.to_json())
                report.envs = envs
                if report.on_envs:
                    report.on_envs(envs.spec, envs.num_envs, where)
                envs.run(batch, indices, seed=seed, video_dir=job.video_dir, groups=rule.groups, ready=rule.ready,
                         on_done=lambda res: log.episode(res.to_json()), on_error=report.on_error,
                         on_worker_failure=report.on_worker_failure, keep=False)
            log.timing({"part": part.describe(), "episodes": len(indices), "process": os.getpid(),
                        "process_started": process_started(), "policy_ready": log.policy_ready, "open": opening,
                        "opened": opened, "ran": time.time()})
    finally:
        if ahead is not None:
            ahead()
        if shared is not None:
            shared.close()


@functools.lru_cache(maxsize=1)
def process_started() -> float | None:
    """When this process started (epoch seconds, to the clock tick; Linux's /proc), or None where it cannot say."""
    try:
        ticks = int(Path("/proc/self/stat").read_text().rsplit(")", 1)[1].split()[19])  # field 22: starttime
        boot = time.time() - float(Path("/proc/uptime").read_text().split()[0])  # to 10 ms (btime: whole seconds)
        return boot + ticks / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError):
        return None


def _after(parts: list, k: int, claims) -> tuple | None:
    """The part a run prepares while part ``k`` steps: the next, or with ``claims`` the next nobody holds yet (it
    is claimed only when this process gets there; if another takes it first, that one reads what the preparation
    left in the disk caches); None when there is none."""
    later = parts[k + 1:]
    if claims is None:
        return later[0] if later else None
    return claims.unclaimed(later, lambda p: p[0].first_task)


def _prefetch(item: tuple | None, shared) -> Callable[[], None] | None:
    """A part's preparation started in a thread (``recipe.prefetch``) while the part before it steps; the wait
    for it, or None (no part, or nothing to prepare)."""
    if item is None:
        return None
    part, indices, seed = item
    prefetch = getattr(part, "prefetch", None)
    return prefetch(indices, seed, shared) if prefetch is not None else None


class _SpecProbe:
    """A policy instance made only to meet a run's spec, for executors whose policies live elsewhere (Ray
    actors): ``check(spec)`` resets it on the first rollout's spec, then closes it at once (a ``remote:``
    probe would otherwise hold one of the server's client slots for the whole run)."""

    def __init__(self, policy: str, kwargs: dict):
        from simseam.policies.base import make_policy

        self.policy = make_policy(policy, **kwargs)

    def check(self, spec: RolloutSpec) -> None:
        try:
            self.policy.reset(spec)
        finally:
            self.close()

    def close(self) -> None:
        if self.policy is not None:
            _close(self.policy)
            self.policy = None


def _ray(job: Job, executor: Executor, report: JobReport, log: _Log) -> None:
    """Ray actors, each with its own rollout (a benchmark's: replaced when the task changes) and policy."""
    from simseam.runner.ray_eval import run_on_ray

    probe = _SpecProbe(job.policy, job.policy_kwargs)  # meets the first actor's spec before anything is written
    try:
        recipe = _recipe_for(job, PolicyTraits.of(probe.policy))
        first, _, _ = recipe.parts(job.indices, job.seed)[0]
        if report.on_envs:
            report.on_envs(None, executor.num_envs or 0, f"Ray ({executor.address})")
        run_on_ray(executor.address, first, job.policy, job.policy_kwargs, job.indices, seed=job.seed,
                   num_workers=executor.num_envs, on_spec=log.spec, check=probe.check, on_done=log.episode,
                   on_worker_failure=report.on_worker_failure, keep=False)
    finally:
        probe.close()

