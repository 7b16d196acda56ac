"""Policies: scripted experts succeed (the proof that layouts, IK and gripper are right),
baselines produce valid actions, chunked policies replay their chunks."""

import numpy as np
import pytest

from simseam.policies.base import ChunkedPolicy, make_policy, policy_names
from simseam.seam import ConfigError


@pytest.mark.parametrize("layout", ["lift_cube", "bowl_plate"])
def test_scripted_expert_succeeds_in_at_least_8_of_10_seeds(panda_spec, make_scene, count_successes, layout):
    scene = make_scene(panda_spec, task=layout, render_images=False, privileged=True)
    assert count_successes(scene, make_policy("scripted"), range(10)) >= 8


def test_so101_scripted_lift_succeeds_in_at_least_8_of_10_seeds(so101_spec, make_scene, count_successes):
    """The SO-101's tool frame is its manifest tcp, between the jaws (its URDF's gripper_frame_link sits on
    the fixed jaw, which then landed on the cube: 0/10 before). benchmarks/bench_scripted.py: 40/40."""
    scene = make_scene(so101_spec, render_images=False, privileged=True)
    assert count_successes(scene, make_policy("scripted"), range(10)) >= 8


def test_lift_success_means_the_cube_is_10cm_up(panda_spec, make_scene):
    scene = make_scene(panda_spec, render_images=False, privileged=True)
    policy = make_policy("scripted")
    obs = scene.reset(4)
    rest_z = obs["privileged"]["objects"]["cube"][2]
    policy.reset(scene.spec)
    heights = []
    for _ in range(scene.spec.task.max_steps):
        step = scene.step(policy.act(obs))
        obs = step.observation
        heights.append(obs["privileged"]["objects"]["cube"][2] - rest_z)
        if step.terminated:
            break
    assert step.terminated and step.reward == 1.0
    assert heights[-1] > 0.10 and all(h <= 0.10 for h in heights[:-1])


def test_scripted_needs_privileged_and_a_known_layout(panda_spec, make_scene):
    scene = make_scene(panda_spec, render_images=False)
    policy = make_policy("scripted")
    obs = scene.reset(0)
    policy.reset(scene.spec)
    with pytest.raises(ConfigError, match="privileged"):
        policy.act(obs)
    js = make_scene(panda_spec, render_images=False, control_mode="joint_position", privileged=True)
    with pytest.raises(ConfigError, match="cartesian_delta"):
        policy.reset(js.spec)


@pytest.mark.parametrize("name", ["random", "zero"])
@pytest.mark.parametrize("mode", ["cartesian_delta", "joint_position"])
def test_baselines_produce_valid_actions(panda_spec, make_scene, name, mode):
    scene = make_scene(panda_spec, render_images=False, control_mode=mode)
    policy = make_policy(name)
    obs = scene.reset(0)
    policy.reset(scene.spec)
    q0 = obs["joint_positions"].copy()
    for _ in range(10):
        action = policy.act(obs)
        assert action.shape == (scene.action_dim,) and action.dtype == np.float32
        step = scene.step(action)
        obs = step.observation
    assert not step.info["success"]
    moved = np.abs(obs["joint_positions"][:7] - q0[:7]).max()
    if name == "zero":
        assert moved < 0.02  # the no-op holds the arm
    else:
        assert moved > 0.02  # random actions do move it


@pytest.mark.parametrize("mode", ["cartesian_delta", "joint_position"])
def test_random_is_seeded(panda_spec, make_scene, mode):
    """Same seed: the same actions; another seed: other actions (compared through act())."""
    scene = make_scene(panda_spec, render_images=False, control_mode=mode)
    obs = scene.reset(0)

    def actions(seed):
        policy = make_policy("random", seed=seed)
        policy.reset(scene.spec)
        return np.stack([policy.act(obs) for _ in range(5)])

    same, again, other = actions(3), actions(3), actions(4)
    assert np.array_equal(same, again)
    assert not np.allclose(same, other)
    assert not np.allclose(same[0], same[1])  # and it does vary step to step


def test_unknown_policy_lists_known():
    with pytest.raises(ConfigError, match="unknown policy 'act'.*random, scripted, zero"):
        make_policy("act")
    assert {"random", "scripted", "zero"} <= set(policy_names())


def test_chunked_policy_executes_n_action_steps_per_chunk(panda_spec, make_scene):
    class Counting(ChunkedPolicy):
        calls = 0

        def predict_chunk(self, observation):
            Counting.calls += 1
            chunk = np.zeros((5, 7), np.float32)
            chunk[:, 0] = np.arange(5)  # tag each action with its index in the chunk
            return chunk

    scene = make_scene(panda_spec, render_images=False)
    policy = Counting(n_action_steps=3)
    obs = scene.reset(0)
    policy.reset(scene.spec)
    tags = [policy.act(obs)[0] for _ in range(7)]
    assert tags == [0, 1, 2, 0, 1, 2, 0] and Counting.calls == 3
    policy.reset(scene.spec)  # reset drops the queued actions
    assert policy.act(obs)[0] == 0 and Counting.calls == 4


@pytest.mark.parametrize("robot", ["panda_spec", "so101_spec"])
@pytest.mark.parametrize("mode", ["cartesian_delta", "joint_position"])
def test_zero_holds_the_gripper_in_both_control_modes(request, make_scene, robot, mode):
    """``zero`` is a true no-op: the fingers keep their opening (grip command 0 would half-close them)."""
    spec = request.getfixturevalue(robot)
    scene = make_scene(spec, render_images=False, control_mode=mode)
    policy = make_policy("zero")
    obs = scene.reset(0)
    policy.reset(scene.spec)
    fingers = [spec.joint_names.index(n) for n in spec.gripper.joints]
    g0, q0 = obs["joint_positions"][fingers].copy(), obs["joint_positions"].copy()
    for _ in range(20):
        obs = scene.step(policy.act(obs)).observation
    span = np.abs(np.subtract(spec.gripper.closed, spec.gripper.open))
    assert np.all(np.abs(obs["joint_positions"][fingers] - g0) < 0.02 * span)
    assert np.abs(obs["joint_positions"] - q0).max() < 0.02


@pytest.mark.parametrize("robot", ["panda_spec", "so101_spec"])
@pytest.mark.parametrize("mode", ["cartesian_delta", "joint_position"])
def test_scripted_reach_succeeds_in_at_least_9_of_10_seeds(request, make_scene, count_successes, robot, mode):
    scene = make_scene(request.getfixturevalue(robot), task="reach", render_images=False, privileged=True,
                       control_mode=mode)
    assert count_successes(scene, make_policy("scripted"), range(10)) >= 9


@pytest.mark.parametrize("spec", ["scripted", "zero", "remote:ws://127.0.0.1:9"])
def test_an_option_a_policy_does_not_take_is_one_configerror_naming_it(spec):
    from simseam.seam import ConfigError

    with pytest.raises(ConfigError, match=r"does not take --device \(it takes: "):
        make_policy(spec, device="cpu")
