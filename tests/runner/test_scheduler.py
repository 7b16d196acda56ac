"""The episode scheduler (``runner.scheduler.run_batch``) over a ``BatchRollout``: each episode's result
is the sequential loop's, whatever the number of environments, the order episodes finish in, or who
else shares the batch."""

import numpy as np
import pytest

from simseam.policies.base import make_policy
from simseam.policies.batch import PerEnvPolicies
from simseam.runner.scheduler import run_batch
from simseam.runner.session import run_episodes
from simseam.scene.manifest_scene import ManifestScene, SceneOptions
from simseam.seam import SimulationError, SyncBatchRollout

OPTS = dict(render_images=False, privileged=True, max_steps=31)  # some episodes end by the step limit
INDICES = list(range(6))


def _batch(spec, n):
    return SyncBatchRollout([ManifestScene(spec, "lift_cube", "mujoco", SceneOptions(**OPTS)) for _ in range(n)])


def _outcome(results):
    return {r.index: (r.seed, r.success, r.steps, round(r.reward, 9), r.diagnostics) for r in results}


@pytest.fixture(scope="module")
def sequential(panda_spec):
    scene = ManifestScene(panda_spec, "lift_cube", "mujoco", SceneOptions(**OPTS))
    try:
        results = run_episodes(scene, make_policy("scripted"), INDICES, seed=40)
    finally:
        scene.close()
    out = _outcome(results)
    assert {s for _, s, *_ in out.values()} == {True, False}, out  # both endings, or the test proves little
    return out


@pytest.mark.parametrize("n", [1, 2, 4])
def test_each_episode_is_the_sequential_loops_whatever_the_number_of_environments(panda_spec, sequential, n):
    events = []
    with _batch(panda_spec, n) as batch:
        results = run_batch(batch, PerEnvPolicies(lambda: make_policy("scripted"), n), INDICES, seed=40,
                            on_start=lambda env, i: events.append(("start", env, i)),
                            on_done=lambda r: events.append(("done", r.index)))
    assert _outcome(results) == sequential
    assert sorted(i for what, *rest in events if what == "start" for i in rest[1:]) == INDICES
    assert [e[1] for e in events if e[0] == "done"] == [r.index for r in results]  # each handed over once
    assert all(len(r.step_ms) == len(r.policy_ms) == r.steps for r in results)


def test_a_policy_answering_the_wrong_shape_stops_the_run_by_name(panda_spec):
    class Short(PerEnvPolicies):
        def act_batch(self, envs, observations):
            return np.zeros((len(envs), 3), np.float32)

    with _batch(panda_spec, 2) as batch:
        with pytest.raises(SimulationError, match=r"act_batch returned shape \(2, 3\) for 2 environments"):
            run_batch(batch, Short(lambda: make_policy("zero"), 2), INDICES)


def test_a_lost_episode_goes_back_to_the_front_until_its_last_attempt():
    from simseam.runner.scheduler import EpisodeQueue

    q = EpisodeQueue([3, 4, 5], seed=100, max_attempts=2)
    assert q.next() == 3
    what, res = q.lost(3, lambda n: f"lost {n} times")
    assert (what, res) == ("episode 3 goes back to the queue (attempt 2 of 2)", None)
    assert q.next() == 3  # first again
    what, res = q.lost(3, lambda n: f"lost {n} times")
    assert what == "episode 3 failed 2 times; recorded as an error"
    assert (res.index, res.seed, res.success, res.steps, res.error) == (3, 103, False, 0, "lost 2 times")
    assert [q.next(), q.next()] == [4, 5] and not q
