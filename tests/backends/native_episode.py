"""One episode on a benchmark's NATIVE environment, exactly as its own documentation drives it.

Run by the fidelity tests with the backend's provisioned interpreter; it never imports simseam
(the independent peer the seam is compared against):

    <venv>/bin/python native_episode.py BACKEND CONFIG_JSON SEED ACTIONS.npy OUT.npz

Writes, per step t (t = 0 is the reset): the native observation vector / agent position, the
image the native env gives a policy, and for t >= 1 the reward and success flag.
"""

import json
import sys

import numpy as np


def metaworld(cfg, seed, actions):
    import metaworld

    bench = metaworld.MT1(cfg["task"], seed=cfg.get("goal_seed", 0))
    h, w = cfg["image_size"]
    env = bench.train_classes[cfg["task"]](render_mode="rgb_array", camera_name=cfg["camera"], width=w, height=h)
    env.set_task(bench.train_tasks[seed % 50])
    env.seed(seed)
    obs, _ = env.reset()
    out = {"state": [obs], "image": [env.render()], "reward": [], "success": []}
    for a in actions:
        obs, r, _, _, info = env.step(a)
        out["state"].append(obs)
        out["image"].append(env.render())
        out["reward"].append(r)
        out["success"].append(bool(info["success"]))
    return out


def pusht(cfg, seed, actions):
    import gymnasium as gym
    import gym_pusht  # noqa: F401  (registers the env)

    h, w = cfg["image_size"]
    env = gym.make("gym_pusht/PushT-v0", obs_type="pixels_agent_pos", render_mode="rgb_array",
                   observation_width=w, observation_height=h).unwrapped
    obs, _ = env.reset(seed=seed)
    out = {"state": [obs["agent_pos"]], "image": [obs["pixels"]], "reward": [], "success": []}
    for a in actions:
        obs, r, _, _, info = env.step(a)
        out["state"].append(obs["agent_pos"])
        out["image"].append(obs["pixels"])
        out["reward"].append(r)
        out["success"].append(bool(info["is_success"]))
    return out


def aloha(cfg, seed, actions):
    import gymnasium as gym
    import gym_aloha  # noqa: F401  (registers the envs)

    env_id = {"insertion": "gym_aloha/AlohaInsertion-v0", "transfer_cube": "gym_aloha/AlohaTransferCube-v0"}
    env = gym.make(env_id[cfg["task"]], obs_type="pixels_agent_pos").unwrapped
    obs, _ = env.reset(seed=seed)
    out = {"state": [obs["agent_pos"]], "image": [obs["pixels"]["top"]], "reward": [], "success": []}
    for a in actions:
        obs, r, _, _, info = env.step(a)
        out["state"].append(obs["agent_pos"])
        out["image"].append(obs["pixels"]["top"])
        out["reward"].append(r)
        out["success"].append(bool(info["is_success"]))
    return out


if __name__ == "__main__":
    backend, cfg, seed, actions_path, out_path = sys.argv[1:6]
    result = globals()[backend](json.loads(cfg), int(seed), np.load(actions_path))
    assert "simseam" not in sys.modules
    np.savez(out_path, **{k: np.asarray(v) for k, v in result.items()})
