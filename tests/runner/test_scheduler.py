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
    return {r.index: (r.seed, r.success, r.steps, r.reward, r.diagnostics) for r in results}  # rewards exactly


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


class _Crashing:
    """A rollout whose sidecar crashes at one step of one seed (the rest of the time the real scene)."""

    def __init__(self, scene, crash_seed: int, at_step: int):
        import dataclasses

        self.scene, self.crash_seed, self.at_step = scene, crash_seed, at_step
        self.spec = dataclasses.replace(scene.spec, capabilities=(*scene.spec.capabilities, "restart"))
        self.restarts, self.t, self.seed = 0, 0, None

    def reset(self, seed=None, observe=None):
        self.seed, self.t = seed, 0
        return self.scene.reset(seed, observe)

    def step(self, action, observe=None):
        from simseam.seam import SidecarError

        self.t += 1
        if self.seed == self.crash_seed and self.t == self.at_step:
            raise SidecarError("the sidecar process exited (signal 9)")
        return self.scene.step(action, observe)

    def restart(self):
        self.restarts += 1

    def render(self):
        return self.scene.render()

    def close(self):
        self.scene.close()


def test_a_sidecar_crash_costs_its_episode_only_recorded_with_its_error(panda_spec, sequential):
    """As in the sequential loop: the crashed episode is recorded with the error (no retry), the
    environment goes on with the next episode, and every other episode is unchanged."""
    errors, starts = [], []
    rollouts = [_Crashing(ManifestScene(panda_spec, "lift_cube", "mujoco", SceneOptions(**OPTS)), 42, 7)
                for _ in range(2)]
    with SyncBatchRollout(rollouts) as batch:
        results = run_batch(batch, PerEnvPolicies(lambda: make_policy("scripted"), 2), INDICES, seed=40,
                            on_start=lambda env, i: starts.append((env, i)),
                            on_error=lambda r, what: errors.append((r.index, what)))
    crashed_env = next(env for env, i in starts if i == 2)
    assert any(env == crashed_env and i > 2 for env, i in starts), starts  # the environment plays on
    got = _outcome(results)
    assert sorted(got) == INDICES and got[2] == (42, False, 0, 0.0, {})
    assert [r.error for r in results if r.index == 2] == ["SidecarError: the sidecar process exited (signal 9)"]
    assert {i: o for i, o in got.items() if i != 2} == {i: o for i, o in sequential.items() if i != 2}
    assert errors == [(2, "restarting the sidecar")] and sum(r.restarts for r in rollouts) == 1


class _Counting:
    """A rollout without a simulator: every episode ends (success) after ``length`` steps; its sidecar
    crashes at the first step of ``crash_seed``. Records the seeds it was reset with."""

    def __init__(self, length: int, crash_seed: int | None = None):
        import dataclasses

        from spec_factory import make_spec

        self.spec = dataclasses.replace(make_spec(action_dim=2, cameras={}), capabilities=("restart",))
        self.length, self.crash_seed = length, crash_seed
        self.seeds, self.restarts, self.t = [], 0, 0

    def reset(self, seed=None, observe=None):
        self.seeds.append(seed)
        self.t = 0
        return {}

    def step(self, action, observe=None):
        from simseam.seam import SidecarError, StepResult

        self.t += 1
        if self.seeds[-1] == self.crash_seed:
            raise SidecarError("the sidecar process exited (signal 9)")
        done = self.t >= self.length
        return StepResult({}, 0.0, done, False, {"success": done})

    def restart(self):
        self.restarts += 1

    def close(self):
        pass


class _Still:
    """A policy batch that sends zero actions."""

    n = 2

    def reset(self, env, spec):
        pass

    def observe_next(self, env):
        return None

    def act_batch(self, envs, observations):
        return np.zeros((len(envs), 2), np.float32)


def test_a_sidecar_error_is_recorded_under_the_episodes_index_and_seed_not_the_environments():
    """Catches: a sidecar error result made from the environment's slot (1, seed 41), not its episode (3, 43)."""
    env0, env1 = _Counting(length=20), _Counting(length=2, crash_seed=43)
    errors = []
    with SyncBatchRollout([env0, env1]) as batch:
        results = run_batch(batch, _Still(), range(5), seed=40, on_error=lambda r, what: errors.append((r, what)))
    assert env1.seeds[:3] == [41, 42, 43] and sorted(env0.seeds + env1.seeds) == [40, 41, 42, 43, 44]  # 3 on env 1
    assert sorted(r.index for r in results) == [0, 1, 2, 3, 4]  # each episode once
    (err,) = [r for r in results if r.error]
    assert (err.index, err.seed, err.success, err.steps) == (3, 43, False, 0)
    assert err.error == "SidecarError: the sidecar process exited (signal 9)"
    assert [(r.index, r.seed, what) for r, what in errors] == [(3, 43, "restarting the sidecar")]
    assert {r.index: r.seed for r in results} == {i: 40 + i for i in range(5)} and env1.restarts == 1


def test_videos_of_a_batch_that_renders_are_written_by_the_scheduler(panda_spec, tmp_path):
    """One MP4 per finished episode (reset frame + one per step), none left under a partial name."""
    import imageio.v2 as imageio

    opts = dict(OPTS, render_images=True)
    scenes = [ManifestScene(panda_spec, "lift_cube", "mujoco", SceneOptions(**opts)) for _ in range(2)]
    with SyncBatchRollout(scenes) as batch:
        results = run_batch(batch, PerEnvPolicies(lambda: make_policy("scripted"), 2), [0, 1, 2], seed=40,
                            video_dir=tmp_path)
    assert sorted(p.name for p in tmp_path.iterdir()) == ["episode_000.mp4", "episode_001.mp4", "episode_002.mp4"]
    for r in results:
        assert r.video == str(tmp_path / f"episode_{r.index:03d}.mp4")
        with imageio.get_reader(r.video) as video:
            assert sum(1 for _ in video) == r.steps + 1


class _Ragged:
    """A rollout without a simulator whose episodes differ by seed: seed s succeeds after ``5 + 37 * s % 2900``
    steps when s is odd, and otherwise runs into the step limit; rewards are sums of uneven floats; ``crash_seed``'s
    sidecar crashes at its third step."""

    def __init__(self, spec, crash_seed: int):
        self.spec, self.crash_seed, self.t, self.seed = spec, crash_seed, 0, None

    def reset(self, seed=None, observe=None):
        self.seed, self.t = seed, 0
        return {"state": np.full(2, seed, np.float32)}

    def step(self, action, observe=None):
        from simseam.seam import INFO_DIAGNOSTICS, SidecarError, StepResult

        self.t += 1
        if self.seed == self.crash_seed and self.t == 3:
            raise SidecarError("the sidecar process exited (signal 9)")
        done = self.seed % 2 == 1 and self.t >= 5 + 37 * self.seed % 2900
        info = {"success": done, INFO_DIAGNOSTICS: {"t": float(self.t), "seed": self.seed}}
        return StepResult({"state": np.full(2, self.t, np.float32)}, 0.1 * self.t + 1e-3 / (self.seed + 1), done,
                          False, info)

    def restart(self):
        pass

    def close(self):
        pass


class _RaggedArrays(SyncBatchRollout):
    """``_Ragged`` rollouts as a batch that offers arrays, its infos as ``InfoColumns`` (a port's)."""

    def observation_arrays(self, observe=None):
        return {"state": np.zeros((self.num_envs, 2), np.float32)}

    def step_arrays(self, envs, actions, observe=None):
        from simseam.seam import BatchStepResult, InfoColumns

        r = self.step(envs, np.asarray(actions)[np.asarray(envs)])
        infos = InfoColumns({"success": np.array([i.get("success", False) for i in r.infos])},
                            {"t": [i.get("diagnostics", {}).get("t") for i in r.infos],
                             "seed": [i.get("diagnostics", {}).get("seed") for i in r.infos]})
        return BatchStepResult(r.envs, [{} for _ in r.envs], r.reward, r.terminated, r.truncated, infos)


class _StillArrays(_Still):
    """``_Still`` on the array path (``act_arrays``)."""

    n = 3

    def act_arrays(self, arrays):
        return np.zeros((3, 2), np.float32)


def test_the_array_paths_bookkeeping_on_columns_gives_the_per_environment_loops_results():
    """The array path keeps its bookkeeping on arrays (``_Tally``, ``InfoColumns``): the same steps, success,
    rewards (summed exactly alike), diagnostics and errors as the per-environment loop, one latency per step, over
    ragged episodes (some ended by success, some by the step limit, one by a crashed sidecar), and over more steps
    than the latency timeline keeps at once (4,096 flights)."""
    import dataclasses

    from spec_factory import make_spec

    from simseam.runner.scheduler import _BatchRun

    spec = make_spec(action_dim=2, cameras={}, state_dim=2)
    spec = dataclasses.replace(spec, task=dataclasses.replace(spec.task, max_steps=3000),
                               capabilities=("restart",))
    out, tallied, original = {}, [], _BatchRun.__init__

    def spy(self, *a, **k):
        original(self, *a, **k)
        tallied.append(self.tally is not None)

    _BatchRun.__init__ = spy
    try:
        for name, policy in (("dicts", _Still()), ("arrays", _StillArrays())):
            policy.n = 3
            with _RaggedArrays([_Ragged(spec, crash_seed=6) for _ in range(3)]) as batch:
                out[name] = run_batch(batch, policy, range(15), seed=0)
    finally:
        _BatchRun.__init__ = original
    assert tallied == [False, True]
    dicts, arrays = ({r.index: (r.seed, r.success, r.steps, r.reward, r.diagnostics, r.error) for r in out[k]}
                     for k in ("dicts", "arrays"))
    assert arrays == dicts
    assert dicts[6][-1] == "SidecarError: the sidecar process exited (signal 9)" and dicts[6][2] == 0
    assert {i for i, o in dicts.items() if o[1]} == {1, 3, 5, 7, 9, 11, 13} and dicts[8][2] == 3000  # both endings
    assert sum(o[2] for o in dicts.values()) > 5 * 4096  # over 7,000 flights of 3: the timeline was let go of in part
    assert all(len(r.step_ms) == len(r.policy_ms) == r.steps for r in out["arrays"])
    assert all(x >= 0.0 for r in out["arrays"] for x in r.step_ms + r.policy_ms)
