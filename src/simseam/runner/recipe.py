"""Recipes: how a process that holds no rollout yet builds one. Plain data (picklable, JSON-able), the one
shape that the worker processes (``runner.vector``), the Ray actors (``runner.ray_eval``) and the
command line pass around.

- ``SceneRecipe``: a scene file's config (``SceneConfig.model_dump()``), its directory and the options
  ``build_rollout`` takes: an in-process scene, a sidecar, or a ``benchmark:`` scene's backend sidecar;
- ``BenchmarkRecipe``: an evaluation preset's backend, config and tasks: the backend's sidecar for the
  task of each episode index (``simseam eval``).

Both answer ``build()`` (the first rollout) and ``rollout_for(rollout, index, seed) -> (rollout,
seed_base)``: the rollout episode ``index`` runs on and the base its seed counts from (episode ``i``
runs with ``seed_base + i``). A scene's is always the same rollout; a benchmark's changes task at task
boundaries (``i = task_index * episodes + e`` runs with ``seed + e``).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from pathlib import Path


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

    def build(self):
        from simseam.runner.scene_config import SceneConfig, build_rollout

        cfg = SceneConfig.model_validate(self.scene)
        return build_rollout(cfg, Path(self.base_dir), privileged=self.privileged,
                             render_images=self.render_images, seed=self.seed)

    def rollout_for(self, rollout, index: int, seed: int):
        return rollout, seed


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

    def _open(self, ti: int):
        from simseam.sidecar.benchmark import open_benchmark

        task = self.tasks[ti]
        rollout = open_benchmark(self.backend, {**self.config, **self.per_task.get(task, {}), "task": task},
                                 privileged=self.privileged)
        self._task = ti
        return rollout

    def build(self):
        return self._open(self.first_task)

    def rollout_for(self, rollout, index: int, seed: int):
        ti = index // self.episodes
        if ti != getattr(self, "_task", None):
            self._task = None
            rollout.close()
            rollout = self._open(ti)
        return rollout, seed - ti * self.episodes
