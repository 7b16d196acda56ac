"""Batched policies act exactly as their unbatched selves, one environment at a time."""

import math

import numpy as np
import pytest

from simseam.policies.base import make_policy
from simseam.policies.batch import PerEnvPolicies, make_policy_batch
from simseam.policies.lerobot_policy import LeRobotBatch

SEEDS = (3, 8, 11)
#: the trained LeRobot policies batched: ACT, ACT with temporal ensembling (an ensembler per environment), and
#: Diffusion (an observation history per environment)
CHECKPOINTS = ["tiny_act", "tiny_act_te", "tiny_dp"]


def _unbatched(make, scenes, steps, seen=None):
    """Each environment driven alone by its own policy instance: the per-step actions (and, into
    ``seen``, the observations each action answered)."""
    out = []
    for scene, seed in zip(scenes, SEEDS):
        policy = make()
        policy.reset(scene.spec)
        obs = scene.reset(seed, policy.observe_next())
        actions, observations = [], []
        for _ in range(steps):
            observations.append(obs)
            a = policy.act(obs)
            actions.append(a)
            obs = scene.step(a, policy.observe_next()).observation
        out.append(np.stack(actions))
        if seen is not None:
            seen.append(observations)
    return out


def _batched(batch, scenes, steps, envs=(0, 1, 2), replay=None):
    """The batch's per-step actions; with ``replay`` (per environment, the observations of an unbatched run)
    it answers those observations instead of its own rollouts', so floats summed in another order cannot
    compound through the closed loop (a rendered pixel that flips) and only the batching is compared."""
    obs = []
    for env, scene, seed in zip(envs, scenes, SEEDS):
        batch.reset(env, scene.spec)
        obs.append(scene.reset(seed, batch.observe_next(env)))
    actions = [[] for _ in scenes]
    for t in range(steps):
        if replay is not None:
            obs = [r[t] for r in replay]
        acts = batch.act_batch(list(envs), obs)
        assert acts.shape == (len(scenes), scenes[0].spec.action_dim) and acts.dtype == np.float32
        for k, (env, scene) in enumerate(zip(envs, scenes)):
            actions[k].append(acts[k])
            obs[k] = scene.step(acts[k], batch.observe_next(env)).observation
    return [np.stack(a) for a in actions]


def test_per_env_policies_equal_one_instance_per_episode(panda_spec, make_scene):
    scenes = [make_scene(panda_spec, privileged=True, max_steps=30) for _ in SEEDS]
    reference = _unbatched(lambda: make_policy("scripted"), scenes, 25)
    batch = make_policy_batch("scripted", 3)
    assert isinstance(batch, PerEnvPolicies) and batch.requires_privileged
    got = _batched(batch, scenes, 25)
    for a, b in zip(reference, got):
        np.testing.assert_array_equal(a, b)
    assert not np.allclose(got[0], got[1])  # different episodes, different actions: a real comparison


@pytest.mark.learning
@pytest.mark.parametrize("checkpoint", CHECKPOINTS)
def test_lerobot_batch_is_one_forward_pass_and_equals_unbatched(request, checkpoint, panda_spec, make_scene):
    out, _ = request.getfixturevalue(checkpoint)
    steps = 10
    scenes = [make_scene(panda_spec, image_size=(40, 56), max_steps=steps) for _ in SEEDS]
    seen = []
    reference = _unbatched(lambda: make_policy(f"lerobot:{out}", device="cpu"), scenes, steps, seen)
    batch = make_policy_batch(f"lerobot:{out}", 3, device="cpu")
    assert isinstance(batch, LeRobotBatch)
    got = _batched(batch, scenes, steps, replay=seen)
    for a, b in zip(reference, got):
        np.testing.assert_allclose(a, b, rtol=1e-3, atol=2e-4)  # float32 sums in another order
    n = batch.policy.n_action_steps
    assert batch.forward_passes == math.ceil(steps / n)  # one model call per chunk boundary, for all 3 envs
    assert batch.chunks_predicted == 3 * math.ceil(steps / n)
    assert not np.allclose(got[0], got[1], atol=1e-2)


@pytest.mark.learning
def test_a_state_policy_batched_reads_each_environments_state(tiny_state_act, panda_spec, make_scene):
    """An ACT of proprioception and environment state (no camera): batched equals unbatched, one forward pass
    per chunk boundary for all environments."""
    out, _ = tiny_state_act
    steps = 9
    scenes = [make_scene(panda_spec, render_images=False, environment_state=True, privileged=True,
                         max_steps=steps) for _ in SEEDS]
    reference = _unbatched(lambda: make_policy(f"lerobot:{out}", device="cpu"), scenes, steps)
    batch = make_policy_batch(f"lerobot:{out}", 3, device="cpu")
    assert not batch.uses_images and batch.reads_environment_state
    got = _batched(batch, scenes, steps)
    for a, b in zip(reference, got):
        np.testing.assert_allclose(a, b, rtol=1e-3, atol=2e-4)
    assert batch.forward_passes == math.ceil(steps / batch.policy.n_action_steps)
    assert not np.allclose(got[0], got[1], atol=1e-3)


@pytest.mark.learning
@pytest.mark.parametrize("checkpoint", CHECKPOINTS)
def test_lerobot_batch_envs_out_of_step_keep_their_own_queues(request, checkpoint, panda_spec, make_scene):
    """Environments that start at different times (a vector env refilling a slot) each replay their own chunk."""
    out, _ = request.getfixturevalue(checkpoint)
    scenes = [make_scene(panda_spec, image_size=(40, 56), max_steps=12) for _ in SEEDS[:2]]
    reference = _unbatched(lambda: make_policy(f"lerobot:{out}", device="cpu"), scenes, 7)
    batch = make_policy_batch(f"lerobot:{out}", 2, device="cpu")
    obs = {}
    for env in (0, 1):
        batch.reset(env, scenes[env].spec)
        obs[env] = scenes[env].reset(SEEDS[env], batch.observe_next(env))
    got = {0: [], 1: []}
    for t in range(9):
        envs = [0] if t < 2 else ([0, 1] if t < 7 else [1])  # env 1 starts two steps late
        acts = batch.act_batch(envs, [obs[e] for e in envs])
        for e, a in zip(envs, acts):
            got[e].append(a)
            obs[e] = scenes[e].step(a, batch.observe_next(e)).observation
    for e in (0, 1):
        np.testing.assert_allclose(np.stack(got[e]), reference[e], rtol=1e-3, atol=2e-4)


@pytest.mark.learning
@pytest.mark.parametrize("checkpoint", CHECKPOINTS)
def test_lerobot_through_the_vector_env_equals_one_process(request, checkpoint, tmp_path):
    """`simseam run --num-envs 2 --policy lerobot:...`'s loop: worker processes render, the parent batches."""
    from simseam.runner.scene_config import build_rollout, load_scene_config
    from simseam.runner.session import run_episodes
    from simseam.runner.recipe import SceneRecipe
    from simseam.runner.vector import VectorEnv

    out, _ = request.getfixturevalue(checkpoint)
    scene = tmp_path / "scene.yaml"
    scene.write_text("robot: franka_panda\ntask: lift_cube\nimage_size: [40, 56]\nmax_steps: 12\n")
    cfg, base = load_scene_config(scene)
    rollout = build_rollout(cfg, base, render_images=True)
    try:
        reference = run_episodes(rollout, make_policy(f"lerobot:{out}", device="cpu"), range(3), seed=4)
    finally:
        rollout.close()
    batch = make_policy_batch(f"lerobot:{out}", 2, device="cpu")
    with VectorEnv(SceneRecipe(cfg.model_dump(mode="json"), str(base), render_images=True), 2) as vec:
        got = {r.index: r for r in vec.run(batch, range(3), seed=4)}
    assert batch.forward_passes < batch.chunks_predicted  # the two environments shared forward passes
    for ref in reference:
        r = got[ref.index]
        assert (r.seed, r.steps, r.success) == (ref.seed, ref.steps, ref.success)
        for k, v in ref.diagnostics.items():
            assert float(r.diagnostics[k]) == pytest.approx(float(v), abs=1e-3)


@pytest.mark.learning
def test_diffusion_history_does_not_leak_across_resets(tiny_dp, panda_spec, make_scene):
    """After a reset, a Diffusion Policy's observation history holds the new episode's first frame only: an
    episode started after another (sequentially, and in one environment of a batch while the other runs on)
    acts exactly as the same episode on a fresh policy."""
    out, _ = tiny_dp
    first, second = (make_scene(panda_spec, image_size=(40, 56), max_steps=12) for _ in range(2))
    fresh = _unbatched(lambda: make_policy(f"lerobot:{out}", device="cpu"), [second], 6)[0]  # seed 3 alone
    policy = make_policy(f"lerobot:{out}", device="cpu")
    policy.reset(first.spec)
    obs = first.reset(11, policy.observe_next())
    for _ in range(5):  # mid-chunk: history and queue hold episode 11's frames and actions
        obs = first.step(policy.act(obs), policy.observe_next()).observation
    policy.reset(second.spec)
    obs, after = second.reset(SEEDS[0], policy.observe_next()), []
    for _ in range(6):
        after.append(policy.act(obs))
        obs = second.step(after[-1], policy.observe_next()).observation
    np.testing.assert_array_equal(np.stack(after), fresh)

    batch = make_policy_batch(f"lerobot:{out}", 2, device="cpu")
    obs = {}
    for env, scene, seed in ((0, first, 11), (1, second, 8)):
        batch.reset(env, scene.spec)
        obs[env] = scene.reset(seed, batch.observe_next(env))
    for _ in range(5):
        acts = batch.act_batch([0, 1], [obs[0], obs[1]])
        for env, scene in ((0, first), (1, second)):
            obs[env] = scene.step(acts[env], batch.observe_next(env)).observation
    assert len(batch.history[0]) == 2 and batch.queues[0]
    batch.reset(0, first.spec)  # env 0 starts seed 3 while env 1 is mid-episode
    obs[0], got = first.reset(SEEDS[0], batch.observe_next(0)), []
    for _ in range(6):
        acts = batch.act_batch([0, 1], [obs[0], obs[1]])
        got.append(acts[0])
        for env, scene in ((0, first), (1, second)):
            obs[env] = scene.step(acts[env], batch.observe_next(env)).observation
    np.testing.assert_allclose(np.stack(got), fresh, rtol=1e-3, atol=2e-4)  # batched: float sums in another order


@pytest.mark.learning
def test_temporal_ensembles_equal_lerobots_ensembler_per_environment():
    """Four environments reset at different steps, any subset acting each step: each row's actions equal
    LeRobot's own ``ACTTemporalEnsembler`` fed that environment's chunks alone, from its reset on."""
    import torch
    from lerobot.policies.act.modeling_act import ACTTemporalEnsembler

    from simseam.policies.lerobot_policy import TemporalEnsembles

    coeff, chunk, dim, n = 0.05, 6, 3, 4
    ours = TemporalEnsembles(torch, coeff, chunk, n)
    theirs = [ACTTemporalEnsembler(coeff, chunk) for _ in range(n)]
    gen = torch.Generator().manual_seed(5)
    resets = {0: [0, 1, 2, 3], 3: [1], 5: [2, 0], 9: [3]}  # step -> the environments that start an episode
    acting = [[0, 1, 2, 3], [0, 2], [1, 2, 3], [0, 1, 2, 3], [3, 1], [0, 1, 2, 3]]
    compared = 0
    for t in range(14):
        for e in resets.get(t, []):
            ours.reset(e)
            theirs[e].reset()
        rows = acting[t % len(acting)]
        chunks = torch.randn((len(rows), chunk, dim), generator=gen)
        got = ours.update(rows, chunks)
        for k, e in enumerate(rows):
            want = theirs[e].update(chunks[k:k + 1])[0]
            assert torch.equal(got[k], want), (t, e, got[k], want)
            compared += 1
    assert compared > 40
