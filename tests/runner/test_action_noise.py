"""Noise-injected demonstrations: the rollout executes a perturbed action, the recorder keeps the clean one."""

import numpy as np
import pytest

from simseam.policies.base import make_policy
from simseam.runner.action_noise import ActionNoise
from simseam.runner.episodes import run_episode
from simseam.seam import ConfigError


class _Spy:
    """Passes a rollout through and keeps every action that reaches its ``step``."""

    def __init__(self, inner):
        self.inner, self.executed = inner, []
        self.spec, self.action_dim = inner.spec, inner.action_dim

    def reset(self, seed=None, observe=None):
        return self.inner.reset(seed, observe)

    def step(self, action, observe=None):
        self.executed.append(np.array(action, dtype=np.float64))
        return self.inner.step(action, observe)

    def render(self):
        return self.inner.render()

    def sim_time_ns(self):
        return self.inner.sim_time_ns()

    def close(self):
        self.inner.close()


class _Recorder:
    def __init__(self):
        self.actions = []

    def add(self, observation, action):
        self.actions.append(np.array(action, dtype=np.float64))


@pytest.fixture
def lift(panda_spec, make_scene):
    """A state-only Franka lift scene the scripted expert can drive (privileged observations)."""
    return make_scene(panda_spec, render_images=False, privileged=True)


def _episode(rollout, seed, recorder=None):
    return run_episode(rollout, make_policy("scripted"), index=0, seed=seed, recorder=recorder)


def test_the_recorder_keeps_the_policys_action_and_the_scene_executes_it_perturbed(lift):
    spy = _Spy(lift)
    rec = _Recorder()
    res = _episode(ActionNoise(spy, 0.1), seed=3, recorder=rec)
    assert res.steps == len(rec.actions) == len(spy.executed) > 10
    recorded, executed = np.stack(rec.actions), np.stack(spy.executed)
    grip = lift.spec.action.grip
    assert np.array_equal(executed[:, grip], recorded[:, grip])  # the gripper is never perturbed
    motion = [i for i in range(lift.spec.action.dim) if i != grip]
    diff = executed[:, motion] - recorded[:, motion]
    inside = np.all(np.abs(recorded[:, motion]) < 0.5, axis=1)  # steps whose noisy action no bound clips
    assert inside.sum() > 10
    assert np.std(diff[inside]) == pytest.approx(0.1, rel=0.25) and abs(np.mean(diff[inside])) < 0.03


def test_the_same_seed_gives_the_same_perturbations_and_another_seed_others(lift):
    runs = []
    for seed in (5, 5, 6):
        spy = _Spy(lift)
        _episode(ActionNoise(spy, 0.2), seed=seed)
        runs.append(np.stack(spy.executed))
    assert np.array_equal(runs[0], runs[1])
    n = min(len(runs[0]), len(runs[2]))
    assert not np.allclose(runs[0][:n], runs[2][:n])


def test_the_closed_loop_expert_still_succeeds_under_noise_and_its_path_changes(lift):
    clean, noisy = _Spy(lift), _Spy(lift)
    assert _episode(clean, seed=7).success
    assert _episode(ActionNoise(noisy, 0.1), seed=7).success
    n = min(len(clean.executed), len(noisy.executed))
    assert not np.allclose(clean.executed[:n], noisy.executed[:n])


@pytest.mark.parametrize("sigma", [0.0, -0.1, float("nan"), float("inf")])
def test_a_bad_sigma_is_refused(lift, sigma):
    with pytest.raises(ConfigError, match="sigma must be a positive number"):
        ActionNoise(lift, sigma)
