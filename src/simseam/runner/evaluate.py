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
``K`` does not exceed the episodes per task); on a batched engine's port, where a task's episodes are the
worlds of one batch, it runs the whole tasks with ``ti % K == i`` instead; ``simseam merge`` rebuilds the eval summary from the
shards. ``eval_recipe`` is what a run's ``Job`` runs (``runner.job``: inline, worker processes, a batched
engine's port, Ray).
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from typing import Any, Sequence

from simseam import registry
from simseam.runner.recipe import BenchmarkRecipe, policy_options
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
        return {**self.config, **(self.per_task.get(task, {}) if task else {}), **policy_options(self.backend, uses_images)}


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


#: the backends whose config sizes their cameras (``image_size``: [height, width])
SIZED_CAMERAS = ("libero", "maniskill", "metaworld", "pusht")


def with_image_size(p: Preset, size: int | None) -> Preset:
    """``p`` with its cameras drawn at ``size`` x ``size`` (``simseam eval --image-size``: a non-standard run, as
    its config records), or ``p`` as it is (None)."""
    if size is None:
        return p
    if p.backend not in SIZED_CAMERAS:
        raise ConfigError(f"--image-size: the {p.backend} backend of preset {p.name} does not size its cameras "
                          f"(the presets of {', '.join(SIZED_CAMERAS)} do)")
    return replace(p, config={**p.config, "image_size": [int(size), int(size)]})


def with_render(p: Preset, render: str | None, engine: str | None) -> Preset:
    """``p`` with its port's cameras drawn by ``render`` (``simseam eval --render``: LIBERO's port on MuJoCo
    Warp draws them with Warp's ray tracer, ``warp``, or MuJoCo's OpenGL renderer on the host, ``opengl``), or ``p``
    as it is (None). Only a port with that choice takes it (its ``RENDERERS``); the run stays standard: the
    protocol is the same, and run.json records the renderer in its task config."""
    if render is None:
        return p
    if engine is None:
        raise ConfigError("--render: only with --engine (a port's renderer); the preset's own backend draws its "
                          "cameras as its benchmark does")
    from simseam.runner.warp_vector import benchmark_port

    renderers = getattr(benchmark_port(engine, p.backend), "RENDERERS", ())
    if not renderers:
        with_choice = [b for b in BENCHMARK_PORTS[engine] if getattr(benchmark_port(engine, b), "RENDERERS", ())]
        raise ConfigError(f"--render: the {engine} port of {p.backend} draws its cameras one way only (ports with "
                          f"a choice: {', '.join(with_choice) or 'none'})")
    if render not in renderers:
        raise ConfigError(f"--render: one of {', '.join(renderers)}, got {render!r}")
    return replace(p, config={**p.config, "render": render})


#: task-config keys that choose how an engine draws, not what the protocol is (a run with them stays standard)
RENDER_KEYS = ("render",)


def _protocol_config(config: dict) -> dict:
    return {k: v for k, v in config.items() if k not in RENDER_KEYS}


def eval_config(p: Preset, policy: str, tasks: list[str], episodes: int, seed: int, video: bool) -> dict:
    """What run.json records (``--resume`` requires the same)."""
    return {"preset": p.name, "backend": p.backend, "protocol": p.protocol, "standard": episodes == p.episodes
            and (p.tasks is None or list(p.tasks) == tasks)
            and _protocol_config(p.config) == _protocol_config(PRESETS[p.name].config),
            "policy": policy, "tasks": tasks,
            "episodes": episodes * len(tasks), "episodes_per_task": episodes, "seed": seed, "video": video,
            "task_config": p.config, **({"per_task_config": p.per_task} if p.per_task else {})}


def eval_indices(tasks: Sequence[str], episodes: int, shard: tuple[int, int] | None = None,
                 whole_tasks: bool = False) -> list[int]:
    """The global episode indices a run (or its shard ``(i, K)``: ``index % K == i``; with ``whole_tasks``, a
    batched port's, ``task_index % K == i``) plans, task-major."""
    from simseam.runner.sharding import shard_indices

    return shard_indices(len(tasks) * episodes, shard, episodes if whole_tasks else 1)


def eval_recipe(p: Preset, tasks: Sequence[str], episodes: int, engine: str | None = None,
                device: str | None = None) -> BenchmarkRecipe:
    """The recipe of a run of the preset's ``tasks``, ``episodes`` each: the backend's sidecars, or with
    ``engine`` its port to that batched engine (on ``device``)."""
    return BenchmarkRecipe(p.backend, dict(p.config), tuple(tasks), episodes, per_task=p.per_task, engine=engine,
                           device=device)


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
