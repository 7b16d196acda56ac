"""Evaluation presets: a benchmark's standard protocol, run through the seam (``simseam eval``).

A preset names a backend, its tasks, episodes per task and the per-task config (step
limit ...). Episode ``e`` of every task uses seed ``seed + e`` (Meta-World: goal variation
``e % 50``; PushT / ALOHA / ManiSkill: the native ``reset(seed)``), so a run is reproducible and every
policy sees the same initial states. Results go through ``run_dir.RunDir`` exactly as
``simseam run`` writes them (``run.json``, ``episodes.jsonl`` fsynced per episode, atomic
``summary.json``, ``--overwrite`` / ``--resume``); each episode line carries its ``task``,
and the summary adds ``per_task`` success with Wilson 95 % intervals and
``mean_task_success_rate`` (the mean of the per-task rates, as MT-style papers report)
next to the pooled rate.

Episode ``e`` of task ``ti`` has the global index ``ti * episodes + e``. ``--shard i/K`` runs the
indices with ``index % K == i`` (``eval_indices``), so every shard gets a share of every task (when
``K`` does not exceed the episodes per task); ``simseam merge`` rebuilds the eval summary from the
shards. ``run_eval_ray`` runs them on a Ray cluster (``runner.ray_eval``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable, Sequence

from simseam import registry
from simseam.runner.recipe import BenchmarkRecipe
from simseam.runner.warp_vector import BENCHMARK_PORTS
from simseam.seam import ConfigError
from simseam.seam.errors import did_you_mean

METAWORLD_MT10 = ("reach-v3", "push-v3", "pick-place-v3", "door-open-v3", "drawer-open-v3", "drawer-close-v3",
                  "button-press-topdown-v3", "peg-insert-side-v3", "window-open-v3", "window-close-v3")
#: LeRobot's Meta-World env (lerobot/envs/metaworld.py, lerobot 0.4.4) as backend options: MT1(task, seed=42), its
#: variation 0's settings, resets drawn from NumPy's global generator; corner2 moved to LeRobot's position and
#: flipped on both axes; 480x480 (Meta-World's default render size); agent_pos = the observation's first 4
METAWORLD_LEROBOT = {"max_steps": 500, "variation": "lerobot", "goal_seed": 42, "camera": "corner2",
                     "camera_pos": [0.75, 0.075, 0.7], "image_flip": True, "image_size": [480, 480],
                     "state": "agent_pos", "environment_state": False}

MANISKILL_TABLETOP = ("PickCube-v1", "PushCube-v1", "StackCube-v1", "PegInsertionSide-v1", "PullCube-v1")
#: the step limits ManiSkill's own imitation-learning baselines (examples/baselines/act and diffusion_policy,
#: "learning from motion planning generated demonstrations") evaluate with; PullCube is in neither: 100, as
#: PushCube. The limits ManiSkill registers (50; PegInsertionSide 100) are shorter than most of the
#: motion planner's own plans (PickCube 46-88 steps), so its demonstrations cannot fit them.
MANISKILL_MP_STEPS = {"PickCube-v1": 100, "PushCube-v1": 100, "StackCube-v1": 200, "PegInsertionSide-v1": 300,
                      "PullCube-v1": 100}


@dataclass(frozen=True)
class Preset:
    name: str
    backend: str
    tasks: tuple[str, ...] | None  # None: every task of the backend's ``suite`` (asked of its venv)
    episodes: int
    config: dict[str, Any] = field(default_factory=dict)
    suite: str = ""
    protocol: str = ""
    per_task: dict[str, dict[str, Any]] = field(default_factory=dict)  # a task's own fields over ``config``

    def backend_config(self, uses_images: bool, task: str | None = None) -> dict[str, Any]:
        """The backend's config for a policy (and ``task``: its ``per_task`` fields, e.g. its step limit,
        over the preset's): a backend whose cameras are off unless asked for (its ``CAMERA_OPTION``,
        ManiSkill's ``cameras``) turns them on for a policy that reads images."""
        from simseam.backends import backend_module

        option = getattr(backend_module(self.backend), "CAMERA_OPTION", None)
        return {**self.config, **(self.per_task.get(task, {}) if task else {}),
                **({option: True} if option and uses_images else {})}


PRESETS: dict[str, Preset] = {p.name: p for p in (
    Preset("metaworld_mt10", "metaworld", METAWORLD_MT10, 50, {"max_steps": 500},
           protocol="MT10: 10 tasks x 50 episodes (MT1 goal variations 0..49), 500 steps, success = "
                    "info['success'] (the episode ends at success); mean of per-task success"),
    Preset("metaworld_mt50", "metaworld", None, 50, {"max_steps": 500}, suite="MT50",
           protocol="MT50: 50 tasks x 50 episodes, as metaworld_mt10"),
    Preset("metaworld_ml1", "metaworld", None, 50, {"max_steps": 500, "variation": "ml1"}, suite="MT50",
           protocol="ML1 per task: each of the 50 tasks x 50 episodes on ML1's held-out test goals "
                    "(metaworld.ML1(task).test_tasks, variation seed % 50), goal not observed, 500 steps, success = "
                    "info['success'] (the episode ends at success); mean of per-task success"),
    Preset("metaworld_lerobot", "metaworld", None, 50, METAWORLD_LEROBOT, suite="MT50",
           protocol="LeRobot's own Meta-World env (lerobot-eval --env.type=metaworld, obs_type pixels_agent_pos): "
                    "a 480x480 corner2 image from LeRobot's camera position, turned 180 degrees as LeRobot does, "
                    "and the 4-D agent_pos; MT1(seed=42) variation 0's settings with each reset drawn from NumPy's "
                    "global generator after np.random.seed(seed) (lerobot-eval --seed=<seed>'s first episode), "
                    "500 steps, success = info['success'] (the episode ends at success)"),
    *(Preset(suite, "libero", tuple(f"{suite}/{i}" for i in range(90 if suite == "libero_90" else 10)), 50,
             {"max_steps": steps, "settle_steps": 10},
             protocol=f"{90 if suite == 'libero_90' else 10} tasks x 50 episodes from LIBERO's fixed initial states, "
                      f"{steps} steps after 10 settle steps, 256x256 cameras (openpi's LIBERO example)")
      for suite, steps in (("libero_spatial", 220), ("libero_object", 280), ("libero_goal", 300), ("libero_10", 520),
                           ("libero_90", 400))),
    Preset("pusht", "pusht", ("pusht",), 50, {"max_steps": 300},
           protocol="50 episodes, 300 steps at 10 Hz, success = coverage > 95 % (LeRobot's gym-pusht eval)"),
    Preset("aloha_insertion", "aloha", ("insertion",), 50, {"task": "insertion", "max_steps": 400},
           protocol="50 episodes, 400 steps at 50 Hz, success = stage reward 4 (ACT / LeRobot eval)"),
    Preset("maniskill_tabletop", "maniskill", MANISKILL_TABLETOP, 50, {},
           protocol="ManiSkill3 (state, pd_ee_delta_pose, PhysX CPU): 5 shipped-asset Panda tasks x 50 episodes "
                    "(env.reset(seed)), each at the step limit ManiSkill registers (PegInsertionSide 100, the others "
                    "50), success = info['success'] at any step (the episode ends there: ManiSkill's success_once)"),
    Preset("maniskill_tabletop_mp", "maniskill", MANISKILL_TABLETOP, 50,
           {"control_mode": "pd_joint_pos", "environment_state": True},
           per_task={t: {"max_steps": n} for t, n in MANISKILL_MP_STEPS.items()},
           protocol="ManiSkill3 (state, pd_joint_pos: the motion planner's control mode, PhysX CPU), for policies "
                    "cloned from its motion-planning demonstrations: the 5 tasks x 50 episodes (env.reset(seed)), "
                    "at the step limits ManiSkill's imitation-learning baselines use (PickCube 100, PushCube 100, "
                    "StackCube 200, PegInsertionSide 300; PullCube 100), the task's part of the state also as "
                    "environment_state (what a state-based ACT reads), success = info['success'] at any step "
                    "(the episode ends there)"),
    Preset("aloha_transfer_cube", "aloha", ("transfer_cube",), 50, {"task": "transfer_cube", "max_steps": 400},
           protocol="50 episodes, 400 steps at 50 Hz, success = stage reward 4 (ACT / LeRobot eval)"),
)}


def preset(name: str) -> Preset:
    return registry.load(PRESETS, name, "eval preset")


def resolve_tasks(p: Preset, only: list[str] | None) -> list[str]:
    if p.tasks is None:
        from simseam.backends.provision import catalog

        tasks = list(catalog(p.backend)["suites"][p.suite])
    else:
        tasks = list(p.tasks)
    if only:
        unknown = [t for t in only if t not in tasks]
        if unknown:
            raise ConfigError(f"--tasks: {unknown} not in preset {p.name!r}{did_you_mean(unknown[0], tasks)} "
                              f"(its tasks: {', '.join(tasks)})")
        tasks = [t for t in tasks if t in only]
    return tasks


def eval_config(p: Preset, policy: str, tasks: list[str], episodes: int, seed: int, video: bool) -> dict:
    """What run.json records (``--resume`` requires the same)."""
    return {"preset": p.name, "backend": p.backend, "protocol": p.protocol, "standard": episodes == p.episodes
            and (p.tasks is None or list(p.tasks) == tasks), "policy": policy, "tasks": tasks,
            "episodes": episodes * len(tasks), "episodes_per_task": episodes, "seed": seed, "video": video,
            "task_config": p.config, **({"per_task_config": p.per_task} if p.per_task else {})}


def eval_indices(tasks: Sequence[str], episodes: int, shard: tuple[int, int] | None = None) -> list[int]:
    """The global episode indices a run (or its shard ``(i, K)``: ``index % K == i``) plans, task-major."""
    from simseam.runner.sharding import shard_indices

    return shard_indices(len(tasks) * episodes, shard)


def _spec_writer(run_dir) -> Callable[[dict], None]:
    """Writes an eval run's ``spec.json`` once: the spec of the task the run started with. A resumed run
    keeps the one it has (the task it resumes with may be another), so a run's, a shard's and a merge's
    ``spec.json`` do not depend on where it was interrupted."""
    from simseam.runner.run_dir import SPEC_FILE

    written = [(Path(run_dir.path) / SPEC_FILE).exists()]

    def write(spec_json: dict) -> None:
        if not written[0]:
            run_dir.write_spec(spec_json)
            written[0] = True

    return write


def _todo(tasks: Sequence[str], episodes: int, run_dir, indices: Sequence[int] | None) -> list[int]:
    done = run_dir.done
    planned = range(len(tasks) * episodes) if indices is None else sorted(indices)
    return [i for i in planned if i not in done]


def run_eval(p: Preset, policy, policy_name: str, tasks: list[str], episodes: int, run_dir, *, seed: int = 0,
             video_dir: Path | None = None, progress: Callable[[str], None] = lambda s: None,
             on_start=None, on_done=None, on_error=None, indices: Sequence[int] | None = None) -> None:
    """Run the preset's episodes not yet in ``run_dir`` (a ``RunDir``; of ``indices`` only, when given:
    a shard's); every finished one is appended to its log (with ``task`` and ``episode``) before the
    next starts."""
    from simseam.sidecar.benchmark import open_benchmark
    from simseam.runner.session import run_episodes

    todo = _todo(tasks, episodes, run_dir, indices)
    write_spec = _spec_writer(run_dir)
    for ti, task in enumerate(tasks):
        indices = [i for i in todo if i // episodes == ti]
        if not indices:
            continue
        cfg = {**p.backend_config(policy.uses_images, task), "task": task}
        progress(f"{p.backend}: starting {task}")
        rollout = open_benchmark(p.backend, cfg, privileged=policy.requires_privileged,
                                 progress=lambda s: progress(f"{task}: {s}"))
        try:
            policy.reset(rollout.spec)  # a policy that does not fit the benchmark fails before the run starts
            write_spec(rollout.spec.to_json())

            def record(res, written, task=task, ti=ti):
                run_dir.append({**res.to_json(), "task": task, "episode": res.index - ti * episodes})
                if on_done:
                    on_done(res, task)

            # episode index i = ti * episodes + e runs with seed + e
            run_episodes(rollout, policy, indices, seed=seed - ti * episodes, video_dir=video_dir,
                         on_start=on_start, on_done=record, on_error=on_error, keep=False)
        finally:
            rollout.close()


def _eval_entry(entry: dict, tasks: Sequence[str], episodes: int, seed: int) -> dict:
    """An episode's log line with its ``task`` and ``episode`` (index within the task)."""
    ti, e = divmod(int(entry["index"]), episodes)
    if entry.get("error") and entry.get("steps") == 0:  # recorded by a parent (its worker was lost too often):
        entry = {**entry, "seed": seed + e}             # the task's seed, not seed + the global index
    return {**entry, "task": tasks[ti], "episode": e}


def _recorder(run_dir, tasks: Sequence[str], episodes: int, seed: int, on_done) -> Callable[[Any], None]:
    """What a batched eval does with each finished episode (an ``EpisodeResult``): its log line with its
    ``task`` and ``episode`` appended to the run, then ``on_done(result, task)``."""
    def record(res) -> None:
        entry = _eval_entry(res.to_json(), tasks, episodes, seed)
        run_dir.append(entry)
        if on_done:
            on_done(res, entry["task"])

    return record


def run_eval_vector(p: Preset, tasks: list[str], episodes: int, run_dir, num_envs: int, *, policy: str,
                    policy_kwargs: dict, policy_batch=None, privileged: bool = False, uses_images: bool = False,
                    seed: int = 0, video_dir: Path | None = None, on_start: Callable[[Any], None] | None = None,
                    on_done=None, on_error=None, on_worker_failure=None, indices: Sequence[int] | None = None,
                    check: Callable[[Any], None] | None = None, lockstep=None) -> None:
    """``run_eval`` on ``num_envs`` worker processes (``runner.vector``), each owning one sidecar of the
    backend. The episodes not yet in ``run_dir`` are queued in task-major order (all of task 0, then
    task 1, ...), so a worker changes task (closes its sidecar and starts one for the next task) at
    most once per task boundary.

    - ``policy_batch`` None (scripted, zero, random: nothing shared): one policy instance inside each
      worker, whole episodes at a time (``VectorEnv.run_local``), all tasks on one set of workers;
    - a ``PolicyBatch`` (``lerobot:``, ``remote:``, or one instance per environment): stepped together in
      this process by the ``lockstep`` rule (``runner.scheduler.Lockstep``: policy groups, the ready rule,
      environments per worker; each capped at the environments), one vector env per task (each task's
      spec, its instruction included, reaches the policy at every reset).

    Every finished episode is appended to the log with ``task`` and ``episode`` (index within its
    task) as it ends, whatever the order; ``on_start(vec)`` gets each ``VectorEnv`` once its first worker
    is ready. ``indices``: run only these (a shard's), as ``run_eval``. ``check(spec)`` (the policy's
    reset, say) meets each vector env's spec before anything is written: a policy that does not fit the
    benchmark fails before the run starts.
    """
    from simseam.runner.scheduler import Lockstep
    from simseam.runner.vector import VectorEnv

    todo = _todo(tasks, episodes, run_dir, indices)
    if not todo:
        return
    spec_once = _spec_writer(run_dir)

    record = _recorder(run_dir, tasks, episodes, seed, on_done)

    def write_spec(vec):
        if check is not None:
            check(vec.spec)
        spec_once(vec.spec.to_json())

    common = dict(video_dir=video_dir, on_done=record, on_error=on_error, on_worker_failure=on_worker_failure,
                  keep=False)
    if policy_batch is None:
        n = max(1, min(num_envs, len(todo)))
        recipe = BenchmarkRecipe(p.backend, p.backend_config(uses_images), tuple(tasks), episodes, privileged,
                            first_task=todo[0] // episodes, per_task=p.per_task)
        with VectorEnv(recipe, n) as vec:
            write_spec(vec)
            if on_start:
                on_start(vec)
            vec.run_local(policy, policy_kwargs, todo, seed=seed, **common)
        return
    for ti in range(len(tasks)):
        indices = [i for i in todo if i // episodes == ti]
        if not indices:
            continue
        n = max(1, min(num_envs, len(indices)))
        rule = (lockstep or Lockstep()).fit(n)
        with VectorEnv(BenchmarkRecipe(p.backend, p.backend_config(uses_images), tuple(tasks), episodes, privileged,
                                  first_task=ti, per_task=p.per_task), n, envs_per_worker=rule.envs_per_worker) as vec:
            write_spec(vec)
            if on_start:
                on_start(vec)
            vec.run(policy_batch, indices, seed=seed - ti * episodes, groups=rule.groups, ready=rule.ready, **common)


def run_eval_ray(p: Preset, tasks: list[str], episodes: int, run_dir, address: str, *, policy: str,
                 policy_kwargs: dict, privileged: bool = False, uses_images: bool = False, seed: int = 0,
                 num_workers: int | None = None,
                 indices: Sequence[int] | None = None, on_done: Callable[[dict], None] | None = None,
                 on_worker_failure=None, check: Callable[[Any], None] | None = None) -> None:
    """``run_eval`` on the Ray cluster at ``address`` (``runner.ray_eval.run_on_ray``): each actor holds
    its own policy instance (``policy`` is a spec) and one sidecar of the backend (an ``BenchmarkRecipe``,
    replaced when the next episode's task differs). Each finished episode is appended to the log with
    ``task`` and ``episode`` as it arrives (``on_done(entry)`` after); a lost actor's episode re-runs
    elsewhere. ``indices``: run only these (a shard's). ``check(spec)``: as ``run_eval_vector``'s, on the
    first actor's spec, before anything is written."""
    from simseam.runner.ray_eval import run_on_ray

    todo = _todo(tasks, episodes, run_dir, indices)
    if not todo:
        return
    recipe = BenchmarkRecipe(p.backend, p.backend_config(uses_images), tuple(tasks), episodes, privileged,
                        first_task=todo[0] // episodes, per_task=p.per_task)

    def record(entry):
        entry = _eval_entry(entry, tasks, episodes, seed)
        run_dir.append(entry)
        if on_done:
            on_done(entry)

    run_on_ray(address, recipe, policy, policy_kwargs, todo, seed=seed, num_workers=num_workers,
               on_spec=_spec_writer(run_dir), check=check, on_done=record, on_worker_failure=on_worker_failure,
               keep=False)


#: eval engines beside the preset's own backend: engine -> the backends with a port to it
ENGINE_PORTS = BENCHMARK_PORTS


def check_engine(p: Preset, engine: str | None) -> None:
    """``--engine``: None (the preset's backend, one CPU process per environment) or an engine with a port of
    the preset's benchmark; else a one-line error naming the presets that have one."""
    if engine is None:
        return
    if engine not in ENGINE_PORTS:
        raise ConfigError(f"--engine {engine!r}: one of {list(ENGINE_PORTS)} (leave it out for the preset's own "
                          "backend)")
    if p.backend not in ENGINE_PORTS[engine]:
        ported = [q.name for q in PRESETS.values() if q.backend in ENGINE_PORTS[engine]]
        raise ConfigError(f"--engine {engine}: preset {p.name!r} has no {engine} port; presets with one: "
                          f"{', '.join(ported)}")


def run_eval_batched(p: Preset, tasks: list[str], episodes: int, run_dir, num_envs: int, *, policy_batch,
                     engine: str = "mujoco_warp", device: str | None = None, privileged: bool = False,
                     seed: int = 0, on_start=None, on_done=None, on_error=None,
                     indices: Sequence[int] | None = None, check: Callable[[Any], None] | None = None) -> None:
    """``run_eval`` on ``engine``'s batch (Meta-World on MuJoCo Warp: ``MetaWorldBatchRollout``), one batch of
    ``min(num_envs, episodes left)`` worlds per task, the tasks one after another (each task is its own
    model), all driven by ``policy_batch`` in this process. Episode ``e`` of a task gets seed ``seed + e``
    whichever world runs it and whenever the others end; every finished episode is appended to the log as
    ``run_eval`` writes it (``task``, ``episode``); a world that goes non-finite ends its episode as an error
    (``on_error``) and the others carry on."""
    from simseam.backends.metaworld_gpu.rollout import MetaWorldBatchRollout
    from simseam.backends.metaworld_gpu.worker import NativeWorker
    from simseam.runner.scheduler import BatchVectorEnv

    todo = _todo(tasks, episodes, run_dir, indices)
    spec_once = _spec_writer(run_dir)

    record = _recorder(run_dir, tasks, episodes, seed, on_done)

    with NativeWorker() as worker:
        for ti, task in enumerate(tasks):
            mine = [i for i in todo if i // episodes == ti]
            if not mine:
                continue
            cfg = {**p.backend_config(False, task), "task": task, "cameras": False}
            batch = MetaWorldBatchRollout(cfg, max(1, min(num_envs, len(mine))), worker, privileged=privileged,
                                          device=device)
            with BatchVectorEnv(batch) as vec:
                if check is not None:
                    check(vec.spec)
                spec_once(vec.spec.to_json())
                if on_start:
                    on_start(vec)
                vec.run(policy_batch, mine, seed=seed - ti * episodes, on_done=record, on_error=on_error, keep=False)
