"""One episode on a benchmark's NATIVE environment, exactly as its own documentation drives it.

Run by the fidelity tests with the backend's provisioned interpreter; it never imports simseam
(the independent peer the seam is compared against):

    <venv>/bin/python native_episode.py BACKEND CONFIG_JSON SEED ACTIONS.npy OUT.npz

Writes, per step t (t = 0 is the reset): the native observation vector / agent position, the
image the native env gives a policy, and for t >= 1 the reward and success flag.
"""

import gc
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


def libero(cfg, seed, actions):
    """As openpi's LIBERO example client: reset, fixed initial state, 10 dummy settle steps, upright images,
    state = eef pos + axis-angle of the eef quaternion + gripper qpos."""
    import math
    import os

    from libero.libero import benchmark, get_libero_path
    from libero.libero.envs import OffScreenRenderEnv

    suite = benchmark.get_benchmark_dict()[cfg["suite"]]()
    task = suite.get_task(cfg["task"])
    init = suite.get_task_init_states(cfg["task"])
    h, w = cfg["image_size"]
    env = OffScreenRenderEnv(bddl_file_name=os.path.join(get_libero_path("bddl_files"), task.problem_folder,
                                                         task.bddl_file), camera_heights=h, camera_widths=w)
    env.seed(seed)
    env.reset()
    obs = env.set_init_state(init[seed % 50])
    for _ in range(cfg["settle_steps"]):
        obs, _, _, _ = env.step([0.0] * 6 + [-1.0])

    def axis_angle(q):
        qw = min(1.0, max(-1.0, q[3]))
        den = math.sqrt(1.0 - qw * qw)
        return np.zeros(3) if math.isclose(den, 0.0) else q[:3] * 2.0 * math.acos(qw) / den

    def record(o):
        out["state"].append(np.concatenate([o["robot0_eef_pos"], axis_angle(o["robot0_eef_quat"]),
                                            o["robot0_gripper_qpos"]]))
        out["image"].append(o["agentview_image"][::-1, ::-1])
        out["wrist"].append(o["robot0_eye_in_hand_image"][::-1, ::-1])
        # the BDDL problem's objects as LIBERO observes them: {obj}_pos, {obj}_quat (x, y, z, w)
        out["objects"].append([np.concatenate([o[f"{n}_pos"], o[f"{n}_quat"]]) for n in names])

    names = list(env.env.objects_dict)
    out = {"state": [], "image": [], "wrist": [], "objects": [], "object_names": names, "reward": [], "success": []}
    record(obs)
    for a in actions:
        obs, r, done, _ = env.step(a)
        record(obs)
        out["reward"].append(r)
        out["success"].append(bool(done))
    return out


def robosuite(cfg, seed, actions):
    """robosuite 1.5, seeded per episode through its generator (the env's and its placement sampler's)."""
    import math

    import robosuite as suite

    h, w = cfg["image_size"]
    env = suite.make(cfg["task"], robots=cfg["robot"], has_renderer=False, has_offscreen_renderer=True,
                     use_camera_obs=True, camera_names=["agentview", "robot0_eye_in_hand"], camera_heights=h,
                     camera_widths=w, control_freq=20)
    rng = np.random.default_rng(seed)
    env.rng = rng
    env.placement_initializer.rng = rng
    obs = env.reset()

    def record(o):
        q = o["robot0_eef_quat"]
        qw = min(1.0, max(-1.0, q[3]))
        den = math.sqrt(1.0 - qw * qw)
        aa = np.zeros(3) if math.isclose(den, 0.0) else q[:3] * 2.0 * math.acos(qw) / den
        out["state"].append(np.concatenate([o["robot0_eef_pos"], aa, o["robot0_gripper_qpos"]]))
        out["image"].append(o["agentview_image"][::-1])
        out["wrist"].append(o["robot0_eye_in_hand_image"][::-1])
        out["cube"].append(o["cube_pos"])

    out = {"state": [], "image": [], "wrist": [], "cube": [], "reward": [], "success": []}
    record(obs)
    for a in actions:
        obs, r, _, _ = env.step(a)
        record(obs)
        out["reward"].append(r)
        out["success"].append(bool(env._check_success()))
    return out


def _maniskill_env(task, control_mode, cameras=None):
    """ManiSkill 3's own env, CPU physics, state observations. Where SAPIEN finds no Vulkan device to render
    with (a CPU), ManiSkill builds no visuals but its task builders still construct RenderMaterial objects:
    those become inert (the workaround simseam's backend applies too, in simseam/backends/maniskill.py)."""
    import gymnasium as gym
    import sapien
    import sapien.wrapper.urdf_loader

    try:
        sapien.render.RenderMaterial()
    except RuntimeError:
        class Inert:
            def __init__(self, *a, **k):
                pass

        sapien.render.RenderMaterial = sapien.pysapien.render.RenderMaterial = Inert
        sapien.wrapper.urdf_loader.RenderMaterial = Inert
    import mani_skill.envs  # noqa: F401  (registers the tasks)
    if cameras:  # (H, W): ManiSkill's own sensor images, rendered by SAPIEN
        return gym.make(task, obs_mode="state", control_mode=control_mode, sim_backend="physx_cpu", num_envs=1,
                        render_mode=None, render_backend="gpu", sensor_configs=dict(height=cameras[0],
                                                                                     width=cameras[1]))
    return gym.make(task, obs_mode="state", control_mode=control_mode, sim_backend="physx_cpu", num_envs=1,
                    render_mode=None, render_backend="none")


def maniskill(cfg, seed, actions):
    """Actions in ManiSkill's own convention (gripper -1 closed, +1 open); with cfg["solver"]: its expert."""
    if "solver" in cfg:
        return _maniskill_expert(cfg, seed)
    cameras = cfg.get("image_size")
    env = _maniskill_env(cfg["task"], cfg.get("control_mode", "pd_ee_delta_pose"), cameras)
    obs, _ = env.reset(seed=seed)
    out = {"state": [obs[0].numpy()], "reward": [], "success": [], "rgb": []}

    def frame():
        if cameras:
            out["rgb"].append(env.unwrapped.get_sensor_images()["base_camera"]["rgb"][0].cpu().numpy())

    frame()
    for a in actions:
        obs, r, _, _, info = env.step(a)
        out["state"].append(obs[0].numpy())
        out["reward"].append(float(r[0]))
        out["success"].append(bool(info["success"][0]))
        frame()
    return out


def _maniskill_expert(cfg, seed):
    """ManiSkill's motion-planning solution (mani_skill.examples.motionplanning) for seeds seed..seed+n-1, as its
    run.py drives it (the solver steps the env itself, past the registered step limit): per episode, the step of
    the first success (0: none), the solver's own verdict at its end, and how many actions it took."""
    from mani_skill.examples.motionplanning.panda import solutions

    env = _maniskill_env(cfg["task"], "pd_joint_pos")
    solve = getattr(solutions, cfg["solver"])
    out = {"first_success": [], "success": [], "n_actions": []}
    for s in range(seed, seed + cfg["episodes"]):
        flags = []
        step = env.step

        def watch(a, step=step, flags=flags):
            result = step(a)
            flags.append(bool(result[4]["success"][0]))
            return result

        env.step = watch
        res = solve(env, seed=s)
        del env.step
        out["first_success"].append(flags.index(True) + 1 if True in flags else 0)
        out["success"].append(res != -1 and bool(res[-1]["success"].item()))
        out["n_actions"].append(len(flags))
    return out


if __name__ == "__main__":
    backend, cfg, seed, actions_path, out_path = sys.argv[1:6]
    # robosuite's own loop (robosuite 1.5 and LIBERO's 1.4): a hard reset drops the MjSim that rendered so
    # far; if the cyclic garbage collector frees its render context after that, with the new context
    # current, every later frame is garbage (frame 0 intact, states untouched). When the collector runs
    # depends on allocations, e.g. on a fresh venv compiling its .pyc files; with it off, the native frames
    # do not depend on it (simseam's backends free the old context themselves: robosuite_cameras).
    gc.disable()
    result = globals()[backend](json.loads(cfg), int(seed), np.load(actions_path))
    assert "simseam" not in sys.modules
    np.savez(out_path, **{k: np.asarray(v) for k, v in result.items()})
