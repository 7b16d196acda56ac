"""N environments of a benchmark in one sidecar (``SidecarBatchRollout``): the batch contract through the
wire, each environment's episode the single rollout's, and the scheduler running on it (real sidecars on
the provisioned PushT venv)."""

from __future__ import annotations

import numpy as np
import pytest

from simseam.policies.base import make_policy
from simseam.policies.batch import PerEnvPolicies
from simseam.runner.scheduler import run_batch
from simseam.runner.session import run_episodes
from simseam.seam import ConfigError, ObsRequest, check_batch_rollout

pytestmark = pytest.mark.backends

CONFIG = {"task": "pusht", "max_steps": 12}


@pytest.fixture
def pusht(open_backend):
    return lambda num_envs=None: open_backend("pusht", CONFIG, num_envs=num_envs)


def test_a_batch_in_one_sidecar_keeps_the_batch_contract(pusht):
    batch = pusht(3)
    assert batch.num_envs == 3 and batch.spec.backend == "sidecar"
    check_batch_rollout(batch)  # closes it


def test_each_environment_plays_the_single_rollouts_episode(pusht):
    single, batch = pusht(), pusht(2)
    rng = np.random.default_rng(0)
    actions = rng.uniform(-1, 1, (8, 2, single.spec.action.dim)).astype(np.float32)
    want = []
    for env, seed in enumerate((5, 9)):
        obs = [single.reset(seed, ObsRequest.state_only())["state"]]
        for t in range(8):
            obs.append(single.step(actions[t, env], ObsRequest.state_only()).observation["state"])
        want.append(np.stack(obs))
    got = [[o["state"]] for o in batch.reset([1, 0], [9, 5], ObsRequest.state_only())][::-1]
    for t in range(8):
        r = batch.step([0, 1], actions[t], ObsRequest.state_only())
        for env in (0, 1):
            got[env].append(r.observations[env]["state"])
    assert batch.failures() == {}
    for env in (0, 1):
        np.testing.assert_array_equal(np.stack(got[env]), want[env])


def test_the_scheduler_on_a_sidecar_batch_gives_the_sequential_results(pusht):
    single = pusht()
    want = {r.index: (r.seed, r.success, r.steps, r.reward) for r in run_episodes(single, make_policy("zero"),
                                                                                  range(5), seed=3)}
    batch = pusht(2)
    got = run_batch(batch, PerEnvPolicies(lambda: make_policy("zero"), 2), range(5), seed=3)
    assert {r.index: (r.seed, r.success, r.steps, r.reward) for r in got} == want


def test_single_and_batch_ops_are_refused_across(pusht):
    single, batch = pusht(), pusht(2)
    with pytest.raises(Exception, match="serves a batch of 2 environments"):
        batch._request("reset", {"seed": 0})
    with pytest.raises(Exception, match="serves one rollout"):
        single._request("batch_reset", {"envs": [0], "seeds": [0]})
    with pytest.raises(ConfigError, match="num_envs >= 1"):
        pusht(0)
