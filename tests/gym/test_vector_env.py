"""simseam.gym's vector env against gymnasium's own ``SyncVectorEnv`` over ``SimseamEnv`` (the same seeds and
actions give the same observations, rewards, terminations and autoresets, in both autoreset modes), on CPU
MuJoCo (stacked dict observations) and MuJoCo Warp on Warp's CPU device (the batch's observation arrays)."""

import numpy as np
import pytest
import torch

import gymnasium as gym
from gymnasium.utils.env_checker import data_equivalence
from gymnasium.vector import AutoresetMode

from simseam.gym import ENV_ID, SimseamEnv, SimseamVectorEnv, make_vec
from simseam.runner.scene_config import SceneConfig
from simseam.seam import ConfigError, InvalidActionError

N, STEPS = 2, 11


def _cfg(engine: str) -> SceneConfig:
    return SceneConfig.model_validate({"robot": "franka_panda", "task": "reach", "max_steps": 4,
                                       "engine": {"name": engine}})


@pytest.mark.parametrize("engine", ["mujoco", "mujoco_warp"])
@pytest.mark.parametrize("mode", [AutoresetMode.NEXT_STEP, AutoresetMode.SAME_STEP])
def test_the_vector_env_steps_as_gymnasiums_sync_vector_env(engine, mode):
    kw = {"privileged": True, "render_images": False}
    ours = make_vec(_cfg(engine), N, autoreset_mode=mode, **kw)
    ref = gym.vector.SyncVectorEnv([lambda: SimseamEnv(_cfg(engine), **kw) for _ in range(N)], autoreset_mode=mode)
    try:
        assert isinstance(ours, SimseamVectorEnv) and ours.metadata["autoreset_mode"] == mode
        assert ours.observation_space == ref.observation_space and ours.action_space == ref.action_space
        assert ours.batch.__class__.__name__ == ("WarpBatchRollout" if engine == "mujoco_warp" else "SyncBatchRollout")
        obs, info = ours.reset(seed=5)
        ref_obs, _ = ref.reset(seed=5)
        assert data_equivalence(obs, ref_obs, exact=True) and info["episode_seed"].tolist() == [5, 6]
        ours.action_space.seed(3)
        resets = 0
        for _ in range(STEPS):
            a = ours.action_space.sample()
            got, want = ours.step(a), ref.step(a)
            assert ours.observation_space.contains(got[0])
            assert data_equivalence(got[0], want[0], exact=True)
            for i in (1, 2, 3):
                np.testing.assert_array_equal(got[i], want[i])
            if mode == AutoresetMode.SAME_STEP and got[4].get("_final_obs", np.zeros(N, bool)).any():
                resets += 1
                np.testing.assert_array_equal(got[4]["_final_obs"], want[4]["_final_obs"])
                for e in np.flatnonzero(got[4]["_final_obs"]):
                    assert data_equivalence(got[4]["final_obs"][e], want[4]["final_obs"][e], exact=True)
            resets += int(mode == AutoresetMode.NEXT_STEP and "_episode_seed" in got[4])
        assert resets >= 2  # max_steps 4 over 11 steps: every environment autoreset at least twice
    finally:
        ours.close()
        ref.close()


def test_device_arrays_are_the_worlds_memory_and_take_torch_actions():
    env = SimseamVectorEnv(_cfg("mujoco_warp"), N, privileged=True, render_images=False, device_arrays=True)
    try:
        obs, _ = env.reset(seed=1)
        scene = env.batch.batch
        state = torch.from_dlpack(obs["state"])
        assert state.data_ptr() == scene.state.ptr and state.shape == (N, env.batch.spec.state_dim)
        assert torch.from_dlpack(obs["privileged"]["eef_pose"]).dtype == torch.float64
        before = state.clone()
        obs, reward, term, trunc, info = env.step(torch.full((N, env.single_action_space.shape[0]), 0.5))
        assert not torch.equal(torch.from_dlpack(obs["state"]), before)  # the worlds moved, in place
        with pytest.raises(InvalidActionError, match=r"actions\[1\]"):
            env.step(np.stack([np.zeros(7, np.float32), np.full(7, np.nan, np.float32)]))
    finally:
        env.close()


def test_gymnasium_wrappers_and_errors():
    env = gym.wrappers.vector.RecordEpisodeStatistics(
        gym.make_vec(ENV_ID, num_envs=N, vectorization_mode="vector_entry_point", scene=_cfg("mujoco"),
                     privileged=True, render_images=False))
    try:
        env.reset(seed=0)
        episodes = []
        for _ in range(5):
            _, _, term, trunc, info = env.step(env.action_space.sample())
            if "episode" in info:
                episodes += info["episode"]["l"][info["_episode"]].tolist()
        assert episodes == [4, 4]  # both truncated at max_steps
        with pytest.raises(ConfigError, match="reset_mask"):
            env.reset(options={"other": 1})
    finally:
        env.close()
    with pytest.raises(ConfigError, match="num_envs must be a positive int"):
        SimseamVectorEnv(_cfg("mujoco"), 0)
