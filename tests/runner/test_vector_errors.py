"""A sidecar error inside a vector worker costs its episode, recorded under that episode's index and seed
(never the worker's slot), on both paths: the scheduler stepping the workers (``VectorEnv.run``) and the
policies inside the workers (``VectorEnv.run_local``)."""

import dataclasses

import pytest

from simseam.policies.batch import make_policy_batch
from simseam.runner.scene_config import load_scene_config
from simseam.runner.vector import VectorEnv
from simseam.runner.whole_episodes import run_local

SCENE = "robot: franka_panda\ntask: lift_cube\nmax_steps: 6\n"
SEED, CRASH = 10, 13  # episode 3 crashes: 3 is the slot index of neither of the 2 workers
CRASHED = "SidecarError: the sidecar process exited (signal 9)"


class _CrashAt:
    """A rollout whose sidecar crashes at the second step of one seed; the real scene otherwise."""

    def __init__(self, rollout, crash_seed: int):
        self.rollout, self.crash_seed, self.seed, self.t = rollout, crash_seed, None, 0
        self.spec = dataclasses.replace(rollout.spec, capabilities=(*rollout.spec.capabilities, "restart"))

    def reset(self, seed=None, observe=None):
        self.seed, self.t = seed, 0
        return self.rollout.reset(seed, observe)

    def step(self, action, observe=None):
        from simseam.seam import SidecarError

        self.t += 1
        if self.seed == self.crash_seed and self.t == 2:
            raise SidecarError("the sidecar process exited (signal 9)")
        return self.rollout.step(action, observe)

    def restart(self):
        pass

    def render(self):
        return self.rollout.render()

    def close(self):
        self.rollout.close()


@dataclasses.dataclass(frozen=True)
class _CrashingRecipe:
    """The scene file's rollout, crashing at ``crash_seed``: built in each worker process (picklable:
    this module is importable there)."""

    scene_file: str
    crash_seed: int

    def build(self):
        from pathlib import Path

        from simseam.runner.scene_config import build_rollout

        cfg, base = load_scene_config(Path(self.scene_file))
        return _CrashAt(build_rollout(cfg, base, render_images=False, seed=SEED), self.crash_seed)

    def rollout_for(self, rollout, index, seed):
        return rollout, seed


@pytest.fixture
def recipe(tmp_path) -> _CrashingRecipe:
    path = tmp_path / "scene.yaml"
    path.write_text(SCENE)
    return _CrashingRecipe(str(path), CRASH)


def _check(results, errors):
    assert sorted(r.index for r in results) == [0, 1, 2, 3]  # each episode once
    assert {r.index: r.seed for r in results} == {i: SEED + i for i in range(4)}
    (err,) = [r for r in results if r.error]
    assert (err.index, err.seed, err.success, err.steps, err.error) == (3, CRASH, False, 0, CRASHED)
    assert [(r.index, r.seed, what) for r, what in errors] == [(3, CRASH, "restarting the sidecar")]
    assert all(r.steps == 6 and not r.error for r in results if r.index != 3)  # the others ran to their limit


def test_run_records_a_workers_sidecar_error_under_the_episode(recipe):
    """Catches: a worker's sidecar error recorded under the worker slot's index and seed (scheduler path)."""
    errors = []
    with VectorEnv(recipe, 2) as vec:
        results = vec.run(make_policy_batch("zero", 2), range(4), seed=SEED,
                          on_error=lambda r, what: errors.append((r, what)))
    _check(results, errors)


def test_run_local_records_a_workers_sidecar_error_under_the_episode(recipe):
    """Catches: a worker's sidecar error recorded under the worker slot's index and seed (run_local path)."""
    errors = []
    with VectorEnv(recipe, 2) as vec:
        results = run_local(vec, "zero", {}, range(4), seed=SEED, on_error=lambda r, what: errors.append((r, what)))
    _check(results, errors)


@dataclasses.dataclass(frozen=True)
class _RolloutForFails(_CrashingRecipe):
    """A recipe whose ``rollout_for`` raises a sidecar error for one episode index (as a benchmark's does when
    the next task's sidecar cannot start): the error escapes the worker's episode loop."""

    fail_index: int = 3

    def rollout_for(self, rollout, index, seed):
        from simseam.seam import SidecarError

        if index == self.fail_index:
            raise SidecarError("the sidecar process exited (signal 9)")
        return rollout, seed


def test_run_local_records_an_error_escaping_the_episode_loop_under_the_episode(tmp_path):
    """An error that escapes a worker's episode loop (here the recipe's ``rollout_for``) reaches the parent as
    ``episode_error``; it is recorded with the episode's own index and seed, each index once (catches: the
    worker slot's index and seed, or the episode counted twice)."""
    path = tmp_path / "scene.yaml"
    path.write_text(SCENE)
    errors = []
    with VectorEnv(_RolloutForFails(str(path), crash_seed=-1, fail_index=3), 2) as vec:
        results = run_local(vec, "zero", {}, range(5), seed=SEED, on_error=lambda r, what: errors.append((r, what)))
    assert sorted(r.index for r in results) == [0, 1, 2, 3, 4]  # each episode once
    assert {r.index: r.seed for r in results} == {i: SEED + i for i in range(5)}
    (err,) = [r for r in results if r.error]
    assert (err.index, err.seed, err.success, err.steps, err.error) == (3, SEED + 3, False, 0, CRASHED)
    assert [(r.index, r.seed, what) for r, what in errors] == [(3, SEED + 3, "restarting the sidecar")]
    assert all(r.steps == 6 and not r.error for r in results if r.index != 3)
