"""Recipes: how a process that holds no rollout yet builds one. Plain data (picklable, JSON-able), the one
shape that the worker processes (``runner.vector``), the Ray actors (``runner.ray_eval``) and the
command line pass around.

- ``SceneRecipe``: a scene file's config (``SceneConfig.model_dump()``), its directory and the options
  ``build_rollout`` takes: an in-process scene, a sidecar, or a ``benchmark:`` scene's backend sidecar;
- ``BenchmarkRecipe``: an evaluation preset's backend, config and tasks: the backend's sidecar for the
  task of each episode index (``simseam eval``).

Both answer ``build(progress)`` (the first rollout) and ``rollout_for(rollout, index, seed) -> (rollout,
seed_base)``: the rollout episode ``index`` runs on and the base its seed counts from (episode ``i``
runs with ``seed_base + i``). A scene's is always the same rollout; a benchmark's changes task at task
boundaries (``i = task_index * episodes + e`` runs with ``seed + e``). This module is the one home of
that mapping: ``parts(indices, seed)`` splits a run's episodes by the rollout they run on (one part for a
scene, one per task for a benchmark: what executors that step a batch of one rollout run one after
another), ``log_entry`` gives an episode's line in the run's log (a benchmark's names its ``task`` and
``episode`` within it) and ``for_policy`` adds what a policy needs (privileged state, cameras).
"""

from __future__ import annotations

import dataclasses
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Callable, Sequence



@dataclass(frozen=True)
class SceneRecipe:
    """A scene file's rollout: its config, the file's directory and ``build_rollout``'s options."""

    scene: dict
    base_dir: str
    privileged: bool = False
    render_images: bool = True
    seed: int = 0
    #: add the MuJoCo render state (``engine.render_state()``) to every observation a worker sends, for the
    #: central renderer (``VectorEnv(renderer="batched")``)
    pose_states: bool = False

    def build(self, progress: Callable[[str], None] | None = None):
        """The scene's rollout (``progress(stage)``: a sidecar's boot stages)."""
        from simseam.runner.scene_config import SceneConfig, build_rollout

        cfg = SceneConfig.model_validate(self.scene)
        return build_rollout(cfg, Path(self.base_dir), privileged=self.privileged,
                             render_images=self.render_images, seed=self.seed, progress=progress)

    def rollout_for(self, rollout, index: int, seed: int):
        return rollout, seed

    def for_policy(self, privileged: bool, uses_images: bool, reads_environment_state: bool = False) -> "SceneRecipe":
        """This recipe for a policy: its privileged state, its cameras rendered (besides what the run
        itself renders: videos, a dataset's frames). A scene file says itself whether it gives the objects'
        state (the policy's contract check names it when it does not)."""
        return dataclasses.replace(self, privileged=privileged, render_images=self.render_images or uses_images)

    def parts(self, indices: Sequence[int], seed: int) -> list[tuple["SceneRecipe", list[int], int]]:
        """``(recipe, indices, seed_base)`` per rollout the episodes run on: a scene's one."""
        return [(self, list(indices), seed)] if indices else []

    def log_entry(self, entry: dict, seed: int) -> dict:
        """An episode's line in the run's log (``EpisodeResult.to_json()``): as it is."""
        return entry

    def describe(self) -> str:
        """What ``build`` builds, in words."""
        return "the scene"

    #: the words that say how the parts of a run take turns (``parts``): a scene has one
    parts_in_turn = ""

    def _config(self):
        from simseam.runner.scene_config import SceneConfig

        return SceneConfig.model_validate(self.scene)

    def steps_here(self) -> bool:
        """Whether ``open_envs`` gives the environments as one batch stepped from this process (MuJoCo
        Warp's worlds, a backend's own batch, a benchmark's port to a batched engine)."""
        from simseam.runner.warp_vector import batched_in_one_process

        return batched_in_one_process(self._config(), self.render_images)

    def engine_in_worker(self) -> bool:
        """Whether each environment's engine runs inside its worker process (in-process MuJoCo, no sidecar): the
        case the default lockstep rule was measured on (``runner.scheduler.default_lockstep``)."""
        cfg = self._config()
        return cfg.benchmark is None and cfg.engine.process != "sidecar"

    def renderer_for(self, asked: str) -> str:
        """Who draws the worker processes' cameras (``--renderer``: workers, batched or auto)."""
        from simseam.runner.central_render import choose_renderer

        return choose_renderer(asked, self.scene, self.render_images)

    def open_envs(self, n: int, *, renderer: str = "workers", envs_per_worker: int = 1, shared=None):
        """``n`` environments of the scene: one batch in this process when ``steps_here()``, else worker
        processes (``runner.vector.VectorEnv``, ``envs_per_worker`` to a process)."""
        from simseam.runner.vector import VectorEnv
        from simseam.runner.warp_vector import make_vector_env

        return make_vector_env(self._config(), Path(self.base_dir), n,
                               lambda: VectorEnv(self, n, renderer=renderer, envs_per_worker=envs_per_worker),
                               privileged=self.privileged, render_images=self.render_images, seed=self.seed)

    def shared(self):
        """What the environments of every part share (none for a scene), closed with the run."""
        return None


def policy_options(backend: str, uses_images: bool, reads_environment_state: bool = False) -> dict:
    """The config a backend needs for a policy: its cameras (``CAMERA_OPTION``) for a policy that reads images,
    its objects' state (``ENV_STATE_OPTION``: LIBERO's and ManiSkill's are off unless asked for) for one that
    reads ``environment_state``; {} for neither."""
    from simseam.backends import backend_module

    module = backend_module(backend)
    camera, state = getattr(module, "CAMERA_OPTION", None), getattr(module, "ENV_STATE_OPTION", None)
    return {**({camera: True} if camera and uses_images else {}),
            **({state: True} if state and reads_environment_state else {})}


@dataclass
class BenchmarkRecipe:
    """A preset's tasks on its backend: the sidecar for ``tasks[first_task]`` at boot, replaced only when
    the next episode's task differs. ``per_task``: a task's own fields over ``config`` (the preset's)."""

    backend: str
    config: dict
    tasks: tuple[str, ...]
    episodes: int
    privileged: bool = False
    first_task: int = 0
    per_task: dict = field(default_factory=dict)
    #: a batched engine with a port of the benchmark (``mujoco_warp`` for Meta-World and LIBERO: each task's
    #: episodes as the worlds of one batch in this process), and its device; None: the backend's sidecars
    engine: str | None = None
    device: str | None = None
    #: the policy reads images: the engine's port draws the benchmark's cameras (its own renderer); without
    #: it the port renders nothing (the backend's sidecars draw their cameras either way)
    images: bool = False

    def task_config(self, ti: int) -> dict:
        """The backend's config of task ``ti``: its own fields over the preset's, and its name."""
        task = self.tasks[ti]
        return {**self.config, **self.per_task.get(task, {}), "task": task}

    def _open(self, ti: int, progress: Callable[[str], None] | None = None):
        from simseam.sidecar.benchmark import open_benchmark

        rollout = open_benchmark(self.backend, self.task_config(ti), privileged=self.privileged, progress=progress)
        self._task = ti
        return rollout

    def build(self, progress: Callable[[str], None] | None = None):
        """The sidecar of ``tasks[first_task]`` (``progress(stage)``: its boot stages)."""
        return self._open(self.first_task, progress)

    def task_of(self, index: int) -> tuple[int, int]:
        """Episode ``index``'s task (its index in ``tasks``) and its episode within that task."""
        return divmod(int(index), self.episodes)

    def rollout_for(self, rollout, index: int, seed: int):
        ti, _ = self.task_of(index)
        if ti != getattr(self, "_task", None):
            self._task = None
            rollout.close()
            rollout = self._open(ti)
        return rollout, seed - ti * self.episodes

    def for_policy(self, privileged: bool, uses_images: bool, reads_environment_state: bool = False) -> "BenchmarkRecipe":
        """This recipe for a policy: its privileged state; a backend whose cameras are off unless asked for
        (its ``CAMERA_OPTION``, ManiSkill's ``cameras``) turns them on for a policy that reads images, and so
        does a batched engine's port (drawn by the engine's renderer: MuJoCo Warp's ray tracer); one whose
        objects' state is off unless asked for (``ENV_STATE_OPTION``) turns it on for a policy that reads it."""
        options = policy_options(self.backend, uses_images, reads_environment_state)
        return dataclasses.replace(self, config={**self.config, **options}, privileged=privileged,
                                   images=uses_images)

    def parts(self, indices: Sequence[int], seed: int) -> list[tuple["BenchmarkRecipe", list[int], int]]:
        """``(recipe, indices, seed_base)`` per task the episodes belong to, task-major: episode ``e`` of
        task ``ti`` (index ``ti * episodes + e``) runs with ``seed + e``."""
        by_task: dict[int, list[int]] = {}
        for i in sorted(indices):
            by_task.setdefault(self.task_of(i)[0], []).append(i)
        return [(dataclasses.replace(self, first_task=ti), mine, seed - ti * self.episodes)
                for ti, mine in by_task.items()]

    def log_entry(self, entry: dict, seed: int) -> dict:
        """An episode's line in the run's log with its ``task`` and ``episode`` (its index within the task)."""
        ti, e = self.task_of(entry["index"])
        if entry.get("error") and entry.get("steps") == 0:  # recorded by a parent (its worker was lost too often):
            entry = {**entry, "seed": seed + e}             # the task's seed, not seed + the global index
        return {**entry, "task": self.tasks[ti], "episode": e}

    def describe(self) -> str:
        """What ``build`` builds, in words: the task of its sidecar."""
        return self.tasks[self.first_task]

    parts_in_turn = ", one task at a time"

    def steps_here(self) -> bool:
        return self.engine is not None

    def engine_in_worker(self) -> bool:
        """False: a preset's environments are its backend's sidecars (or one batch here)."""
        return False

    def renderer_for(self, asked: str) -> str:
        return "workers"

    def shared(self):
        """What every task's batch on the engine shares (the port's ``shared()``: its benchmark's native worker,
        which answers resets); None for the backend's sidecars."""
        if self.engine is None:
            return None
        from simseam.runner.warp_vector import benchmark_port

        return benchmark_port(self.engine, self.backend).shared()

    def open_envs(self, n: int, *, renderer: str = "workers", envs_per_worker: int = 1, shared=None):
        """``n`` environments of ``tasks[first_task]``: a batch of ``n`` worlds on the engine (``shared``:
        from ``shared()``), else worker processes each owning a sidecar of the backend."""
        if self.engine is None:
            from simseam.runner.vector import VectorEnv

            return VectorEnv(self, n, envs_per_worker=envs_per_worker)
        from simseam.runner.scheduler import BatchVectorEnv
        from simseam.runner.warp_vector import benchmark_port

        port = benchmark_port(self.engine, self.backend)
        return BatchVectorEnv(port(self._port_config(), n, shared, privileged=self.privileged, device=self.device))

    def _port_config(self) -> dict:
        return {**self.task_config(self.first_task), **({} if self.images else {"cameras": False})}

    def prefetch(self, indices: Sequence[int], seed: int, shared) -> Callable[[], None] | None:
        """Start, in a thread, what this task's batch on the engine will first ask its benchmark's native worker
        (``shared``; the port's ``prefetch``, e.g. LIBERO's resets of the episodes' seeds ``seed + i``), so that
        it overlaps the previous task's steps; returns the wait for that thread, or None (no engine, or a port
        with nothing to prepare). A failure there is left to the batch itself, which asks again and raises it
        where it belongs."""
        if self.engine is None or shared is None:
            return None
        from simseam.runner.warp_vector import benchmark_port

        port = benchmark_port(self.engine, self.backend)
        if not hasattr(port, "prefetch"):
            return None
        config, seeds = self._port_config(), [seed + i for i in indices]

        def work() -> None:
            try:
                port.prefetch(config, seeds, shared)
            except Exception:  # noqa: BLE001 - the batch asks again and reports it
                pass

        thread = threading.Thread(target=work, name=f"prefetch {self.describe()}", daemon=True)
        thread.start()
        return thread.join
