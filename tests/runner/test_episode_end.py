"""How an episode ends and what it counts as: success terminates it and counts; the step limit (or a
rollout's own time limit) truncates it and counts as a failure, on every path that runs episodes."""

import dataclasses

import numpy as np
import pytest
from spec_factory import make_spec

from simseam.backends.base import BenchmarkRollout
from simseam.policies.base import make_policy
from simseam.policies.batch import PerEnvPolicies
from simseam.runner.episodes import run_episode
from simseam.runner.scheduler import run_batch
from simseam.scene.manifest_scene import ManifestScene, SceneOptions
from simseam.seam import StepResult, SyncBatchRollout

OPTS = SceneOptions(render_images=False, privileged=True, max_steps=5)


class _Last:
    """A rollout that remembers its last step's result."""

    def __init__(self, rollout):
        self.rollout, self.spec, self.last = rollout, rollout.spec, None

    def reset(self, seed=None, observe=None):
        return self.rollout.reset(seed, observe)

    def step(self, action, observe=None):
        self.last = self.rollout.step(action, observe)
        return self.last

    def close(self):
        self.rollout.close()


def test_an_episode_truncated_by_the_step_limit_is_a_failure(panda_spec):
    """Catches: a truncated episode counted as a success (the zero policy never lifts the cube)."""
    scene = _Last(ManifestScene(panda_spec, "lift_cube", "mujoco", OPTS))
    try:
        res = run_episode(scene, make_policy("zero"), index=0, seed=3)
        last = scene.last
    finally:
        scene.close()
    assert (last.terminated, last.truncated, last.info["success"]) == (False, True, False)
    assert (res.steps, res.success) == (5, False)
    with SyncBatchRollout([ManifestScene(panda_spec, "lift_cube", "mujoco", OPTS) for _ in range(2)]) as batch:
        results = run_batch(batch, PerEnvPolicies(lambda: make_policy("zero"), 2), range(3), seed=3)
    assert sorted((r.index, r.steps, r.success) for r in results) == [(0, 5, False), (1, 5, False), (2, 5, False)]


class _TimeLimit:
    """A rollout without a simulator that truncates every episode at its own time limit (step 3 of
    ``max_steps`` 10), never succeeding."""

    spec = make_spec(action_dim=2, cameras={})
    spec = dataclasses.replace(spec, task=dataclasses.replace(spec.task, max_steps=10))

    def reset(self, seed=None, observe=None):
        self.t = 0
        return {}

    def step(self, action, observe=None):
        self.t += 1
        return StepResult({}, 1.0, False, self.t >= 3, {"success": False})


class _Still:
    def reset(self, spec):
        pass

    def observe_next(self):
        return None

    def act(self, observation):
        return np.zeros(2, np.float32)


def test_an_episode_truncated_by_the_rollouts_own_limit_is_a_failure():
    """Catches: a truncated episode counted as a success (the rollout ends it before the step limit)."""
    res = run_episode(_TimeLimit(), _Still(), index=4, seed=9)
    assert (res.index, res.seed, res.steps, res.reward, res.success) == (4, 9, 3, 3.0, False)


class _Counter(BenchmarkRollout):
    """A benchmark backend whose native task succeeds at step ``succeed_at`` (never: 0)."""

    def __init__(self, succeed_at: int = 0):
        spec = make_spec(action_dim=2, cameras={})
        super().__init__(dataclasses.replace(spec, task=dataclasses.replace(spec.task, max_steps=4)))
        self.succeed_at, self.t = succeed_at, 0

    def _native_reset(self, seed):
        self.t = 0

    def _native_step(self, action):
        self.t += 1
        return 0.0, self.t == self.succeed_at, {}

    def _observe_native(self, request):
        return {}

    def _sim_time_s(self):
        return 0.05 * self.t


@pytest.mark.parametrize("succeed_at, want", [(0, (False, True, False)), (4, (True, False, True))],
                         ids=["never", "at the last step"])
def test_a_benchmark_backends_last_step_is_truncated_only_without_success(succeed_at, want):
    """Catches: a truncated episode counted as a success (the base class's step limit)."""
    rollout = _Counter(succeed_at)
    rollout.reset(0)
    steps = [rollout.step(np.zeros(2, np.float32)) for _ in range(4)]
    assert [(s.terminated, s.truncated) for s in steps[:3]] == [(False, False)] * 3
    assert (steps[-1].terminated, steps[-1].truncated, steps[-1].info["success"]) == want
    res = run_episode(_Counter(succeed_at), _Still(), index=0, seed=0)
    assert (res.steps, res.success) == (4, want[2])
