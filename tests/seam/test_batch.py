"""The batched seam: ``BatchRollout``, ``check_batch_rollout`` and ``SyncBatchRollout`` (N separate
rollouts behind it). ``check_batch_rollout`` is proved on real scenes, and proved to catch batches that
break the contract (otherwise passing it would prove little)."""

import numpy as np
import pytest

from simseam.scene.manifest_scene import ManifestScene, SceneOptions
from simseam.seam import (
    BatchRollout,
    BatchStepResult,
    ConfigError,
    InvalidActionError,
    ObsRequest,
    RolloutContractError,
    StepResult,
    SyncBatchRollout,
    check_batch_rollout,
)

CAMERA = dict(image_size=(48, 64))  # non-square: H and W must not be swapped anywhere


def _scenes(spec, n, task="lift_cube", **options):
    return [ManifestScene(spec, task, "mujoco", SceneOptions(**options)) for _ in range(n)]


def test_separate_scenes_as_a_batch_keep_the_contract(panda_spec):
    batch = SyncBatchRollout(_scenes(panda_spec, 3, **CAMERA))
    assert isinstance(batch, BatchRollout) and batch.num_envs == 3
    spec = check_batch_rollout(batch)
    assert spec.task.name == "lift_cube" and spec.observation.images


def test_a_joint_position_reach_batch_keeps_the_contract(so101_spec):
    check_batch_rollout(SyncBatchRollout(_scenes(so101_spec, 2, "reach", render_images=False)))


def test_a_batch_step_is_each_scene_stepped_alone(panda_spec):
    """Row i of a step is env i's StepResult: the same as the single scene given the same seed and action."""
    alone = ManifestScene(panda_spec, "lift_cube", "mujoco", SceneOptions(render_images=False))
    with SyncBatchRollout(_scenes(panda_spec, 2, render_images=False)) as batch:
        try:
            a = np.full(batch.spec.action.dim, 0.3, np.float32)
            batch.reset([1, 0], [5, 6])
            r = batch.step([1, 0], np.stack([a, -a]))
            alone.reset(5)
            ref = alone.step(a)
        finally:
            alone.close()
        assert isinstance(r, BatchStepResult) and len(r) == 2 and r.envs.tolist() == [1, 0]
        assert isinstance(r[0], StepResult) and np.array_equal(r[0].observation["state"], ref.observation["state"])
        assert r[0].info == ref.info and r[0].reward == ref.reward


def test_a_batch_refuses_bad_input_by_name(panda_spec):
    with SyncBatchRollout(_scenes(panda_spec, 2, render_images=False)) as batch:
        batch.reset([0, 1], [0, 1])
        with pytest.raises(ConfigError, match=r"step: environment indices must be distinct, got \[1, 1\]"):
            batch.step([1, 1], np.zeros((2, 7), np.float32))
        with pytest.raises(ConfigError, match=r"reset: environment indices must be in \[0, 2\), got \[2\]"):
            batch.reset([2], [0])
        with pytest.raises(ConfigError, match="reset: 2 environments but 1 seeds"):
            batch.reset([0, 1], [0])
        with pytest.raises(ConfigError, match="step: 1 observation requests for 2 environments"):
            batch.step([0, 1], np.zeros((2, 7), np.float32), [ObsRequest.state_only()])
        bad = np.zeros((2, 7), np.float32)
        bad[1, 3] = np.inf
        with pytest.raises(InvalidActionError, match=r"actions\[1\]: action\[3\] is inf"):
            batch.step([0, 1], bad)
        with pytest.raises(InvalidActionError, match=r"actions must have shape \(2, 7\), got \(7,\)"):
            batch.step([0, 1], np.zeros(7, np.float32))


def test_a_batch_of_rollouts_with_different_specs_is_refused(panda_spec):
    scenes = _scenes(panda_spec, 1, render_images=False) + _scenes(panda_spec, 1, "reach", render_images=False)
    try:
        with pytest.raises(ConfigError, match="rollout 1 of the batch has another spec than rollout 0"):
            SyncBatchRollout(scenes)
    finally:
        for s in scenes:
            s.close()


class _SortsItsResults(SyncBatchRollout):
    """Broken: returns the stepped envs in index order, not in the order asked."""

    def step(self, envs, actions, observe=None):
        order = np.argsort(envs)
        requests = observe if observe is None or isinstance(observe, ObsRequest) else [observe[i] for i in order]
        return super().step([envs[i] for i in order], np.asarray(actions)[order], requests)


class _ResetsEveryone(SyncBatchRollout):
    """Broken: a reset of some envs resets all of them (a shared simulator reset)."""

    def reset(self, envs, seeds, observe=None):
        others = [e for e in range(self.num_envs) if e not in list(envs)]
        if others:
            super().reset(others, [123] * len(others))
        return super().reset(envs, seeds, observe)


class _ClipsNothing(SyncBatchRollout):
    """Broken: lets a NaN action through (and into the physics)."""

    def step(self, envs, actions, observe=None):
        a = np.asarray(actions, np.float32)
        if a.ndim == 2 and a.shape[0] == len(envs) and np.isnan(a).any():
            return BatchStepResult.of(envs, [self.rollouts[e].step(np.nan_to_num(a[i]), None)
                                             for i, e in enumerate(envs)])
        return super().step(envs, actions, observe)


@pytest.mark.parametrize("broken, problem", [
    (_SortsItsResults, "did not return env 1's result first and env 0's second"),
    (_ResetsEveryone, "resetting one environment changed another's episode"),
    (_ClipsNothing, "a NaN action was accepted; expected InvalidActionError"),
])
def test_the_check_catches_a_broken_batch(panda_spec, broken, problem):
    with pytest.raises(RolloutContractError, match=problem):
        check_batch_rollout(broken(_scenes(panda_spec, 2, render_images=False)))


def test_batched_rewards_are_the_single_rollouts_floats_exactly():
    """A reward summed over an episode must not depend on the path: float64, as a single rollout's."""
    from simseam.seam import BatchStepResult, StepResult

    r = BatchStepResult.of([0, 1], [StepResult({}, 0.1, False, False, {}), StepResult({}, 1 / 3, True, False, {})])
    assert r.reward.tolist() == [0.1, 1 / 3] and r[1].reward == 1 / 3


class _DLPackArray:
    """A DLPack producer that is not a NumPy array (as a torch tensor or a CuPy array is to NumPy)."""

    def __init__(self, array: np.ndarray):
        self.array = array

    def __dlpack__(self, **kwargs):
        return self.array.__dlpack__(**kwargs)

    def __dlpack_device__(self):
        return self.array.__dlpack_device__()


def test_array_actions_takes_dlpack_arrays_and_names_what_is_wrong():
    """``array_actions`` (the benchmark ports' ``step_arrays``): NumPy and sequences cast, a float32 DLPack array in
    host memory read without a copy; a wrong dtype, shape or a non-array is one ``InvalidActionError`` naming
    ``step_arrays``."""
    from simseam.seam.batch import array_actions

    a = np.arange(8, dtype=np.float32).reshape(2, 4)
    got = array_actions(np, _DLPackArray(a), (2, 4))
    assert got.dtype == np.float32 and got.ctypes.data == a.ctypes.data  # the producer's own memory
    np.testing.assert_array_equal(array_actions(np, [[0.5] * 4] * 2, (2, 4)), np.full((2, 4), 0.5, np.float32))
    for bad, message in ((_DLPackArray(a.astype(np.float64)), "must be float32, got float64"),
                         (_DLPackArray(a[:1]), r"shape \(2, 4\), got \(1, 4\)"),
                         ("nope", "a str is not a DLPack array"), ([["a"] * 4] * 2, "not numeric")):
        with pytest.raises(InvalidActionError, match=f"step_arrays: .*{message}"):
            array_actions(np, bad, (2, 4))


def test_info_columns_are_the_list_of_dicts_they_stand_for():
    """``InfoColumns``: each environment's dict built when read, with the Python values ``tolist`` gives (a numpy
    scalar left in would change what an episode's diagnostics serialise to), one column at once, the usual
    sequence behaviour (iteration ends, negative and out-of-range indices), and columns of one length only."""
    from simseam.seam import INFO_DIAGNOSTICS, InfoColumns, info_column

    success, steps = np.array([True, False, True]), np.array([3, 4, 5], dtype=np.int64)
    dist = np.array([0.25, 0.5, 1.5], dtype=np.float32)
    ic = InfoColumns({"success": success, "steps": steps}, {"dist": dist})
    listed = [{"success": s, "steps": n, INFO_DIAGNOSTICS: {"dist": d}}
              for s, n, d in zip(success.tolist(), steps.tolist(), dist.tolist())]
    assert len(ic) == 3 and list(ic) == listed and ic == listed and ic[-1] == listed[2] and ic[1:] == listed[1:]
    assert {type(v) for v in ic[0].values()} == {bool, int, dict} and type(ic[0][INFO_DIAGNOSTICS]["dist"]) is float
    assert ic.column("steps") is steps
    assert info_column(ic, "success").tolist() == [True, False, True]
    assert info_column(listed, "success").tolist() == [True, False, True]
    assert info_column([{}, {"success": 1.0}], "success").tolist() == [False, True]  # .get, truthiness
    with pytest.raises(IndexError, match="index 3 out of range for 3 environments"):
        ic[3]
    assert list(InfoColumns({})) == [] and INFO_DIAGNOSTICS not in InfoColumns({"success": [True]})[0]
    with pytest.raises(ValueError, match=r"columns of different lengths \[2, 3\]"):
        InfoColumns({"success": success}, {"dist": dist[:2]})
