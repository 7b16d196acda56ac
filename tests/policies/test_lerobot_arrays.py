"""ACT on a batch's observation arrays (``LeRobotArrayBatch.act_arrays``, docs/seam.md "Observations as
arrays"): MuJoCo Warp's worlds on Warp's CPU device, the images and state read through DLPack, one forward
pass for the environments that need a chunk; the per-episode results equal the per-environment dict path's
(``LeRobotBatch.act_batch``) on the same seeds."""

from __future__ import annotations

import pytest

from simseam.policies.base import make_policy
from simseam.policies.lerobot_policy import LeRobotArrayBatch, LeRobotBatch
from simseam.robot.manifest import load_robot
from simseam.runner.scheduler import run_batch
from simseam.scene.manifest_scene import SceneOptions
from simseam.seam import offers_arrays

pytestmark = pytest.mark.learning


@pytest.fixture(scope="module")
def lift3():
    from simseam.scene.warp import BatchedScene, WarpBatchRollout

    scene = BatchedScene(load_robot("franka_panda"), "lift_cube", 3, SceneOptions(image_size=(40, 56), max_steps=9),
                         None)
    yield WarpBatchRollout(scene)
    scene.close()


def _outcomes(results):
    return {r.index: (r.seed, r.steps, r.success, r.error) for r in results}


@pytest.mark.parametrize("checkpoint", ["tiny_act", "tiny_act_te"])
def test_act_on_arrays_equals_the_dict_path(request, checkpoint, lift3):
    out, _ = request.getfixturevalue(checkpoint)
    batch = lift3
    assert offers_arrays(batch)
    arrays = make_policy(f"lerobot:{out}", device="cpu").make_batch(3)
    assert isinstance(arrays, LeRobotArrayBatch) and callable(arrays.act_arrays)
    seen = []  # what the model read: the observation arrays' images, sliced on their device
    inner = arrays._array_frames
    arrays._array_frames = lambda a, rows: seen.append(rows) or inner(a, rows)
    on_arrays = run_batch(batch, arrays, range(5), seed=40)
    dicts = LeRobotBatch(make_policy(f"lerobot:{out}", device="cpu"), 3)
    on_dicts = run_batch(batch, dicts, range(5), seed=40)
    assert seen and sorted(_outcomes(on_arrays)) == list(range(5))
    assert _outcomes(on_arrays) == _outcomes(on_dicts)
    by_index = {r.index: r for r in on_dicts}
    for r in on_arrays:
        assert r.reward == pytest.approx(by_index[r.index].reward, abs=1e-4)
        for k, v in by_index[r.index].diagnostics.items():
            assert float(r.diagnostics[k]) == pytest.approx(float(v), abs=1e-3)
    n = arrays.policy.n_action_steps
    if checkpoint == "tiny_act_te":  # every environment predicts at every step, in one forward pass
        assert n == 1 and all(rows == [0, 1, 2] for rows in seen)
    else:  # only the environments whose queue ran out, together
        assert n > 1 and arrays.forward_passes < arrays.chunks_predicted
    assert arrays.forward_passes == len(seen)


@pytest.mark.parametrize("checkpoint", ["tiny_act", "tiny_act_te"])
def test_act_arrays_acts_as_act_batch_on_the_same_states(request, checkpoint, lift3):
    """Step by step on the same worlds: the actions from the arrays equal those from the dicts of the same
    states (the worlds then step with the dict path's), and they differ between worlds."""
    import numpy as np

    out, _ = request.getfixturevalue(checkpoint)
    batch, envs = lift3, [0, 1, 2]
    arrays = make_policy(f"lerobot:{out}", device="cpu").make_batch(3)
    dicts = LeRobotBatch(make_policy(f"lerobot:{out}", device="cpu"), 3)
    for e in envs:
        arrays.reset(e, batch.spec)
        dicts.reset(e, batch.spec)
    obs = batch.reset(envs, [7, 8, 9])
    for _ in range(4):
        got = arrays.act_arrays(batch.observation_arrays(None)).numpy()
        want = dicts.act_batch(envs, obs)
        np.testing.assert_allclose(got, want, rtol=1e-5, atol=1e-6)
        assert np.abs(want[0] - want[1]).max() > 1e-4  # the worlds' own observations: a real comparison
        obs = batch.step(envs, want).observations
    assert arrays.forward_passes == dicts.forward_passes
