"""Pipelined lockstep (``run_batch(groups=K)``): the policy acts for one group of workers while the others
step. Per-episode results equal plain lockstep's (K = 1) and one process's whatever K, through a worker
killed mid-run and with videos; the worker processes' step send / receive pair keeps the replies of the
other groups in flight for their own receive. Workers of two environments each give the same results,
and a killed one costs both its episodes once each."""

import os
import signal

import numpy as np
import pytest

from simseam.policies.batch import make_policy_batch
from simseam.runner.scene_config import load_scene_config
from simseam.runner.recipe import SceneRecipe
from simseam.runner.scheduler import BatchVectorEnv, run_batch
from simseam.runner.vector import VectorEnv
from simseam.runner.whole_episodes import run_local
from simseam.seam import STATE_ONLY, ConfigError, SyncBatchRollout

from test_vector import _outcome, _recipe, _scene, _sequential


def _run(scene, n: int, groups: int, indices, seed: int, **kwargs) -> dict[int, tuple]:
    pol = make_policy_batch("scripted", n)
    with VectorEnv(_recipe(scene, pol, seed), n) as vec:
        return {r.index: _outcome(r) for r in vec.run(pol, indices, seed=seed, groups=groups, **kwargs)}


class _Sizes:
    """A policy batch that records the size of every batch it acts for."""

    def __init__(self, inner):
        self.inner, self.n, self.sizes = inner, inner.n, []

    def act_batch(self, envs, observations):
        self.sizes.append(len(envs))
        return self.inner.act_batch(envs, observations)

    def __getattr__(self, name):
        return getattr(self.inner, name)


def test_groups_give_the_results_of_one_process(tmp_path):
    scene = _scene(tmp_path, steps=30)
    reference = _sequential(scene, "scripted", range(7), seed=4)
    assert sum(r[2] for r in reference.values()) >= 3  # the scripted expert mostly succeeds: a real signal
    for groups in (1, 2, 3):
        assert _run(scene, 3, groups, range(7), seed=4) == reference, groups


def test_the_ready_rule_gives_the_results_of_one_process_and_acts_on_partial_batches(tmp_path):
    """``ready`` M: the policy acts once M workers' steps are in, for every one in by then. The
    per-episode results equal one process's whatever M, the policy acts exactly once per step taken,
    and M = N acts on whole batches while N episodes are in flight (plain lockstep)."""
    scene = _scene(tmp_path, steps=30)
    reference = _sequential(scene, "scripted", range(7), seed=4)
    for ready in (1, 2, 3):
        pol = _Sizes(make_policy_batch("scripted", 3))
        with VectorEnv(_recipe(scene, pol.inner, 4), 3) as vec:
            results = vec.run(pol, range(7), seed=4, ready=ready)
        assert {r.index: _outcome(r) for r in results} == reference, ready
        assert sum(pol.sizes) == sum(r.steps for r in results), ready
        assert all(1 <= k <= 3 for k in pol.sizes)
        if ready == 3:
            assert pol.sizes[:20] == [3] * 20, pol.sizes[:20]


def test_a_receive_of_at_least_m_returns_those_in_and_keeps_the_rest_in_flight(tmp_path):
    cfg, base = load_scene_config(_scene(tmp_path, steps=20))
    recipe = SceneRecipe(cfg.model_dump(mode="json"), str(base), render_images=False)
    a = lambda vec, k: np.full((k, vec.spec.action_dim), 0.1, np.float32)  # noqa: E731
    with VectorEnv(recipe, 3) as vec:
        vec.reset([0, 1, 2], [5, 5, 5], STATE_ONLY)
        plain = vec.step([0, 1, 2], a(vec, 3), STATE_ONLY).observations
        vec.reset([0, 1, 2], [5, 5, 5], STATE_ONLY)
        vec.step_send([0, 1, 2], a(vec, 3), STATE_ONLY)
        first = vec.step_receive([0, 1, 2], at_least=1)
        got = dict(zip(first.envs.tolist(), first.observations))
        assert 1 <= len(got) <= 3 and first.envs.tolist() == sorted(got)
        rest = [e for e in (0, 1, 2) if e not in got]
        if rest:
            with pytest.raises(ConfigError, match="in flight"):
                vec.step_send(rest, a(vec, len(rest)), STATE_ONLY)
            more = vec.step_receive(rest)
            got.update(zip(more.envs.tolist(), more.observations))
        with pytest.raises(ConfigError, match="at_least"):
            vec.step_send([0], a(vec, 1), STATE_ONLY)
            vec.step_receive([0], at_least=2)
    for e in (0, 1, 2):
        assert np.array_equal(got[e]["state"], plain[e]["state"])


@pytest.mark.parametrize("rule", [{"groups": 2}, {"ready": 1}], ids=["groups", "ready"])
def test_a_worker_killed_mid_run_reruns_its_episode_once(tmp_path, rule):
    scene = _scene(tmp_path, steps=30)
    reference = _sequential(scene, "scripted", range(5), seed=1)
    pol = make_policy_batch("scripted", 3)
    failures, done, killed = [], [], []
    with VectorEnv(_recipe(scene, pol, 1), 3) as vec:
        def on_step(env, index, steps):  # episode 2, mid-way: SIGKILL its worker (another group is in flight)
            if index == 2 and steps == 6 and not killed:
                killed.append(env)
                os.kill(vec.pids()[env], signal.SIGKILL)

        results = vec.run(pol, range(5), seed=1, **rule, on_step=on_step, on_done=done.append,
                          on_worker_failure=failures.append)
        assert vec.restarts == 1
    assert killed and len(failures) == 1 and failures[0].index == 2
    assert sorted(r.index for r in done) == list(range(5))
    assert {r.index: _outcome(r) for r in results} == reference


def test_videos_with_groups_are_one_per_episode(tmp_path):
    scene = _scene(tmp_path, steps=12)
    out = tmp_path / "videos"
    out.mkdir()
    pol = make_policy_batch("scripted", 2)
    with VectorEnv(_recipe(scene, pol, 0), 2) as vec:
        results = vec.run(pol, range(3), seed=0, groups=2, video_dir=out)
    assert sorted(p.name for p in out.iterdir()) == ["episode_000.mp4", "episode_001.mp4", "episode_002.mp4"]
    assert all(r.video for r in results)


def test_replies_of_other_groups_wait_for_their_receive_and_a_reset_meanwhile_works(tmp_path):
    """Group A = [0, 2] and group B = [1] in flight together; B's reply arrives while A's are awaited
    and is kept; B's env is reset while A is in flight; each result equals the plain step's."""
    cfg, base = load_scene_config(_scene(tmp_path, steps=20))
    recipe = SceneRecipe(cfg.model_dump(mode="json"), str(base), render_images=False)
    a = lambda vec, k: np.full((k, vec.spec.action_dim), 0.1, np.float32)  # noqa: E731
    with VectorEnv(recipe, 3) as vec:
        vec.reset([0, 1, 2], [5, 5, 5], STATE_ONLY)
        plain = vec.step([0, 1, 2], a(vec, 3), STATE_ONLY).observations
        vec.reset([0, 1, 2], [5, 5, 5], STATE_ONLY)
        vec.step_send([1], a(vec, 1), STATE_ONLY)
        vec.step_send([0, 2], a(vec, 2), STATE_ONLY)
        with pytest.raises(ConfigError, match="in flight"):
            vec.step_send([2], a(vec, 1), STATE_ONLY)
        got = vec.step_receive([0, 2]).observations
        late = vec.step_receive([1]).observations
        vec.step_send([0, 2], a(vec, 2), STATE_ONLY)
        vec.reset([1], [5], STATE_ONLY)  # B reset while A steps
        vec.step_send([1], a(vec, 1), STATE_ONLY)
        again = vec.step_receive([1]).observations
        vec.step_receive([0, 2])
        with pytest.raises(ConfigError, match="no step in flight"):
            vec.step_receive([0])
    for o, p in zip(got + late + again, [plain[0], plain[2], plain[1], plain[1]]):
        assert np.array_equal(o["state"], p["state"])


def test_groups_out_of_range_and_on_a_one_process_batch_are_refused(tmp_path):
    from simseam.runner.scene_config import build_rollout

    cfg, base = load_scene_config(_scene(tmp_path, steps=5))
    batch = SyncBatchRollout([build_rollout(cfg, base, privileged=True, render_images=False) for _ in range(2)])
    pol = make_policy_batch("scripted", 2)
    with batch:
        for bad in (0, 3):
            with pytest.raises(ConfigError, match=r"policy groups must be an integer in 1\.\.2"):
                run_batch(batch, pol, range(2), groups=bad)
            with pytest.raises(ConfigError, match=r"--policy-ready must be an integer in 1\.\.2"):
                run_batch(batch, pol, range(2), ready=bad)
        with pytest.raises(ConfigError, match="choose one"):
            run_batch(batch, pol, range(2), groups=2, ready=1)
        with pytest.raises(ConfigError, match="worker processes"):
            BatchVectorEnv(batch).run(pol, range(2), ready=1)
        assert len(run_batch(batch, pol, range(3), ready=1)) == 3  # a synchronous pair returns every env
        with pytest.raises(ConfigError, match="worker processes"):
            BatchVectorEnv(batch).run(pol, range(2), groups=2)
        assert len(run_batch(batch, pol, range(3), groups=2)) == 3  # the sync pair: any batch pipelines alike


@pytest.mark.parametrize("rule", [{}, {"groups": 2}, {"ready": 1}, {"ready": 2}],
                         ids=["lockstep", "groups2", "ready1", "ready2"])
def test_two_environments_per_worker_give_the_results_of_one_process(tmp_path, rule):
    """``envs_per_worker`` 2: four environments on two worker processes, each worker serving its two in
    turn (one steps while the other's action is on its way). Per-episode results equal one process's."""
    scene = _scene(tmp_path, steps=30)
    reference = _sequential(scene, "scripted", range(7), seed=4)
    pol = make_policy_batch("scripted", 4)
    with VectorEnv(_recipe(scene, pol, 4), 4, envs_per_worker=2) as vec:
        assert vec.num_workers == 2 and len(set(vec.pids())) == 2
        assert vec.pids()[0] == vec.pids()[2] != vec.pids()[1] == vec.pids()[3]  # environment j in worker j % 2
        results = vec.run(pol, range(7), seed=4, **rule)
    assert {r.index: _outcome(r) for r in results} == reference


def test_fewer_episodes_than_environments_still_use_every_worker(tmp_path):
    """Two episodes on four environments of two workers (two each): the environments the scheduler fills first
    lie on both workers, so neither worker idles while the other steps both episodes (where environment j
    lived in worker j // 2, both episodes went to the first worker: half the machine idle, the lockstep
    figure of 0.45-0.51 of bare processes measured with 32 episodes on 64 environments)."""
    scene = _scene(tmp_path, steps=10)
    pol = make_policy_batch("scripted", 4)
    played = []
    with VectorEnv(_recipe(scene, pol, 4), 4, envs_per_worker=2) as vec:
        results = vec.run(pol, range(2), seed=0, on_start=lambda env, index: played.append(env))
        pids = vec.pids()
    assert len(results) == 2 and len({pids[env] for env in played}) == 2, (played, pids)


@pytest.mark.parametrize("rule", [{}, {"ready": 1}], ids=["lockstep", "ready"])
def test_a_killed_worker_of_two_environments_reruns_both_episodes_once(tmp_path, rule):
    """Both environments of a killed worker lose their episodes; each goes back to the queue once, a
    fresh worker takes both environments, and the results still equal one process's."""
    scene = _scene(tmp_path, steps=30)
    reference = _sequential(scene, "scripted", range(6), seed=1)
    pol = make_policy_batch("scripted", 4)
    failures, done, killed = [], [], []
    with VectorEnv(_recipe(scene, pol, 1), 4, envs_per_worker=2) as vec:
        playing, at_kill = {}, {}

        def on_start(env, index):
            playing[env] = index

        def on_step(env, index, steps):  # episode 2, mid-way: SIGKILL its worker (its sibling is mid-episode)
            if index == 2 and steps == 6 and not killed:
                killed.append(env)
                at_kill.update(playing)
                os.kill(vec.pids()[env], signal.SIGKILL)

        results = vec.run(pol, range(6), seed=1, **rule, on_start=on_start, on_step=on_step, on_done=done.append,
                          on_worker_failure=failures.append)
        assert vec.restarts == 1
    sibling = killed[0] ^ 2  # the other environment of that worker (j % 2), mid-episode too (6 episodes, 4 environments)
    assert sorted((f.env, f.index) for f in failures) == sorted([(killed[0], 2), (sibling, at_kill[sibling])])
    assert all(f.exitcode == -signal.SIGKILL for f in failures)
    assert sorted(r.index for r in done) == list(range(6))
    assert {r.index: _outcome(r) for r in results} == reference


def test_envs_per_worker_out_of_range_and_with_policies_inside_the_workers_are_refused(tmp_path):
    cfg, base = load_scene_config(_scene(tmp_path, steps=20))
    recipe = SceneRecipe(cfg.model_dump(mode="json"), str(base), render_images=False)
    for k in (0, 3, True, 1.5):
        with pytest.raises(ConfigError, match="envs per worker"):
            VectorEnv(recipe, 2, envs_per_worker=k)
    with VectorEnv(recipe, 2, envs_per_worker=2) as vec:
        with pytest.raises(ConfigError, match="run_local"):
            run_local(vec, "zero", {}, range(2))
