"""Tasks written once: the same task code judges the CPU engine's one world and MuJoCo Warp's N worlds.

Each task's draws (``Task.sample``) and judgement (``Task.evaluate_batch``) are one definition
(``simseam.scene.tasks.batch``). Here, on Warp's CPU device: the two engines start each seed's episode
from the same reset, and on the same physics states (the CPU engine's, along its scripted expert's
episodes, loaded into the worlds) give the same reward and success, and the same diagnostics to float32
rounding. A task written for one world only is refused by the batched engine with what to write.
"""

from __future__ import annotations

import numpy as np
import pytest

from simseam.policies.base import make_policy
from simseam.robot.manifest import load_robot
from simseam.scene.manifest_scene import ManifestScene, SceneOptions
from simseam.scene.tasks.base import TASKS, Evaluation, Task
from simseam.scene.warp import BatchedScene, world_observations
from simseam.seam import INFO_DIAGNOSTICS, STATE_ONLY, ConfigError

POSE_TOL = 1e-5  # m / quaternion units: float32 device state against the float64 CPU state
DIAG_TOL = 1e-5  # m and rad: the diagnostics of one state on both engines
SEEDS = (3, 8)


@pytest.fixture(scope="module")
def panda():
    return load_robot("franka_panda")


def _expert_states(robot, task, opts, seed, every=10):
    """The CPU engine's scripted episode: (qpos, qvel, reward, success, diagnostics) every ``every`` steps
    and at the last step, and the reset observation."""
    scene = ManifestScene(robot, task, "mujoco", opts)
    pol = make_policy("scripted")
    pol.reset(scene.spec)
    obs = first = scene.reset(seed, STATE_ONLY)
    out = []
    for k in range(scene.spec.task.max_steps):
        r = scene.step(pol.act(obs), STATE_ONLY)
        obs = r.observation
        last = r.terminated or r.truncated
        if k % every == every - 1 or last:
            d = scene.engine.data
            out.append((d.qpos.copy(), d.qvel.copy(), r.reward, bool(r.info[scene.spec.task.success_key]),
                        dict(r.info[INFO_DIAGNOSTICS])))
        if last:
            break
    scene.close()
    return first, out


def _same_judgement(got: dict, w: int, reward: float, success: bool, diags: dict) -> None:
    assert bool(got["success"][w]) == success and float(got["reward"][w]) == reward
    assert set(got["diagnostics"]) == set(diags)
    for name, want in diags.items():
        value = got["diagnostics"][name][w].item()
        if isinstance(want, bool):
            assert value == want, name
        else:
            assert abs(value - want) < DIAG_TOL, (name, value, want)


@pytest.mark.parametrize("task", ["lift_cube", "reach", "bowl_plate"])
def test_both_engines_give_the_same_reset_reward_and_success_on_the_same_states(panda, task):
    opts = SceneOptions(render_images=False, privileged=True)
    b = BatchedScene(panda, task, len(SEEDS), opts)
    try:
        b.reset(range(len(SEEDS)), SEEDS)
        reset_obs = world_observations(b, range(len(SEEDS)), [STATE_ONLY] * len(SEEDS))
        succeeded = 0
        for w, seed in enumerate(SEEDS):
            first, states = _expert_states(panda, task, opts, seed)
            objects = first["privileged"]["objects"]
            assert set(reset_obs[w]["privileged"]["objects"]) == set(objects)
            for name, pose in objects.items():  # the same draws placed the same props (and targets)
                np.testing.assert_allclose(reset_obs[w]["privileged"]["objects"][name], pose, atol=POSE_TOL)
            np.testing.assert_allclose(reset_obs[w]["state"], first["state"], atol=POSE_TOL)
            for qpos, qvel, reward, success, diags in states:
                b.set_state([w], qpos[None], qvel[None])
                _same_judgement(b.evaluate(), w, reward, success, diags)
            succeeded += states[-1][3]
        assert succeeded == len(SEEDS), "the expert's episodes end in success: both outcomes were compared"
    finally:
        b.close()


class _OneWorldTask(Task):
    """A task in the one-world style only (its own reset and evaluate)."""

    name = "one_world_only"
    needs_gripper = False

    def reset(self, engine, rng):
        self.flag = bool(rng.integers(2))

    def evaluate(self, scene):
        return Evaluation(0.0, False, {})


def test_a_task_written_for_one_world_runs_on_the_cpu_and_is_refused_by_the_batch(panda):
    TASKS["one_world_only"] = _OneWorldTask
    try:
        scene = ManifestScene(panda, "one_world_only", "mujoco", SceneOptions(render_images=False))
        scene.reset(0, STATE_ONLY)
        assert not scene.step(scene.spec.action.pack(grip=-1.0), STATE_ONLY).terminated
        scene.close()
        with pytest.raises(ConfigError, match="'one_world_only' is written for one world only; write its "
                                              "evaluate_batch and sample"):
            BatchedScene(panda, "one_world_only", 2, SceneOptions(render_images=False))
    finally:
        del TASKS["one_world_only"]
