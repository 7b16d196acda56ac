"""check_rollout: every in-process scene keeps the seam's contract, and a rollout that breaks it is caught."""

import numpy as np
import pytest

from simseam.seam import (
    STATE_ONLY,
    ObsRequest,
    RolloutContractError,
    RolloutSpec,
    StepResult,
    check_rollout,
    observation_problems,
)


@pytest.mark.parametrize("robot, task, options", [
    ("panda_spec", "lift_cube", dict(privileged=True, image_size=(32, 32))),
    ("panda_spec", "bowl_plate", dict(image_size=(32, 32))),
    ("panda_spec", "lift_cube", dict(control_mode="joint_position", render_images=False)),
    ("mobile_spec", "nav_obstacles", dict(image_size=(24, 24), privileged=True)),
    ("so101_spec", "lift_cube", dict(image_size=(24, 24))),
])
def test_in_process_scenes_keep_the_contract(request, make_scene, robot, task, options):
    spec = check_rollout(make_scene(request.getfixturevalue(robot), task=task, **options))
    assert isinstance(spec, RolloutSpec) and spec.backend == "inprocess"
    assert spec.task.name == task and set(spec.task.diagnostics)


def test_observation_requests_narrow_what_is_rendered(panda_spec, make_scene):
    scene = make_scene(panda_spec, image_size=(32, 32))
    obs = scene.reset(0, STATE_ONLY)
    assert obs["images"] == {} and "link_poses" not in obs
    obs = scene.step(np.zeros(7, np.float32), ObsRequest(images=frozenset({"camera2"}), link_poses=True)).observation
    assert set(obs["images"]) == {"camera2"} and obs["images"]["camera2"].shape == (32, 32, 3)
    # link poses are the engine's own, in base_link: the hand sits where the tool frame's parent is
    hand = obs["link_poses"]["panda_hand"]
    assert hand.dtype == np.float32 and hand.shape == (7,)
    assert np.linalg.norm(hand[:3] - obs["state"][:3]) < 0.15  # the tool point is ~10 cm beyond the flange
    np.testing.assert_allclose(obs["link_poses"]["panda_link0"], [0, 0, 0, 1, 0, 0, 0], atol=1e-6)
    assert observation_problems(obs, scene.spec, ObsRequest(images=frozenset({"camera2"}), link_poses=True)) == []


class _Liar:
    """Wraps a rollout and breaks one promise."""

    def __init__(self, inner, how):
        self.inner, self.how = inner, how

    def __getattr__(self, name):
        return getattr(self.inner, name)

    def reset(self, seed=None, observe=None):
        if self.how == "ignores_requests":
            observe = None
        obs = self.inner.reset(seed, observe)
        if self.how == "wrong_dtype":
            obs["state"] = obs["state"].astype(np.float64)
        return obs

    def step(self, action, observe=None):
        if self.how == "no_clip":
            action = np.zeros_like(action) if np.abs(action).max() > 1 else action
        if self.how == "ignores_requests":
            observe = None
        r = self.inner.step(action, observe)
        if self.how == "no_diagnostics":
            r = StepResult(r.observation, r.reward, r.terminated, r.truncated,
                           {k: v for k, v in r.info.items() if k != "diagnostics"})
        return r


@pytest.mark.parametrize("how, fragment", [
    ("ignores_requests", "observation lacks ['link_poses']"),
    ("wrong_dtype", "state: dtype float64, the spec says float32"),
    ("no_clip", "did not act as spec.action.clip()"),
    ("no_diagnostics", "info['diagnostics'] is None"),
])
def test_a_rollout_that_breaks_a_promise_is_caught(panda_spec, make_scene, how, fragment):
    scene = make_scene(panda_spec, image_size=(24, 24))
    with pytest.raises(RolloutContractError) as err:
        check_rollout(_Liar(scene, how))
    assert fragment in str(err.value)
