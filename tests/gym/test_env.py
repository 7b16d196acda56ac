"""simseam.gym: gymnasium's env checker on three scenes, and measured behaviour through the env."""

import subprocess
import sys
import warnings

import numpy as np
import pytest

import gymnasium as gym  # noqa: E402  (a missing module fails, never skips)

from gymnasium.utils.env_checker import check_env  # noqa: E402

from simseam.gym import ENV_ID, SimseamEnv, make  # noqa: E402
from simseam.gym.spaces import pad_points  # noqa: E402
from simseam.policies.base import make_policy  # noqa: E402
from simseam.runner.scene_config import SceneConfig  # noqa: E402
from simseam.seam import ConfigError, InvalidActionError  # noqa: E402

#: check_env warnings the contract makes unavoidable: state, joint and pose observations are
#: unbounded Boxes (physics can overshoot any bound we would write down).
UNBOUNDED_OBS = ("observation space minimum value is -infinity", "observation space maximum value is infinity")
#: base twist slots are in m/s and rad/s (+-0.8, +-1.5 for panda_mobile), not normalised to [-1, 1].
PHYSICAL_ACTION_UNITS = ("we recommend using a symmetric and normalized space",)


@pytest.fixture
def envs():
    """``open(scene_fields, **env_kwargs)``: a simseam env from a scene file written to tmp_path,
    closed at the end of the test."""
    made = []

    def _open(tmp_path, fields, **kwargs):
        path = tmp_path / f"scene{len(made)}.yaml"
        path.write_text("".join(f"{k}: {v}\n" for k, v in fields.items()))
        env = make(str(path), **kwargs)
        made.append(env)
        return env

    yield _open
    for env in made:
        env.close()


LIFT = {"robot": "franka_panda", "layout": "lift_cube", "image_size": "[64, 64]", "max_steps": 150}
NAV = {"robot": "panda_mobile", "layout": "nav_obstacles"}


def checked(env, allowed=UNBOUNDED_OBS):
    """Run gymnasium's env checker; return the warnings it raised that ``allowed`` does not explain."""
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        check_env(env.unwrapped)
    return [str(w.message) for w in caught if not any(a in str(w.message) for a in allowed)]


def test_lift_with_cameras_passes_check_env(tmp_path, envs):
    env = envs(tmp_path, LIFT, render_mode="rgb_array")
    space = env.observation_space
    assert set(space.spaces) == {"images", "state", "joint_positions", "joint_velocities"}
    for key in ("camera1", "camera2"):
        assert space["images"][key] == gym.spaces.Box(0, 255, (64, 64, 3), np.uint8)
    assert space["state"].shape == (8,) and space["state"].dtype == np.float32
    assert space["joint_positions"].shape == (9,)
    assert env.action_space == gym.spaces.Box(-1, 1, (7,), np.float32)
    assert env.metadata["render_fps"] == 20.0 and env.spec.id == ENV_ID
    assert checked(env) == []
    with warnings.catch_warnings(record=True) as caught:  # plain use through make()'s wrappers
        warnings.simplefilter("always")
        obs, info = env.reset(seed=0)
        obs, reward, terminated, truncated, info = env.step(env.action_space.sample())
        frame = env.render()
    assert [str(w.message) for w in caught] == []
    assert obs in space and info["task"] == "lift the red cube" and info["sim_time_ns"] == 50_000_000
    assert (reward, terminated, truncated, info["is_success"]) == (0.0, False, False, False)
    assert frame.shape == (64, 64, 3) and frame.dtype == np.uint8


def test_state_only_with_privileged_passes_check_env(tmp_path, envs):
    env = envs(tmp_path, LIFT, render_images=False, privileged=True)
    space = env.observation_space
    assert "images" not in space.spaces
    assert set(space["privileged"].spaces) == {"eef_pose", "objects"}
    assert set(space["privileged"]["objects"].spaces) == {"cube"}
    assert checked(env) == []


def test_mobile_nav_passes_check_env_and_twist_moves_the_base(tmp_path, envs):
    env = envs(tmp_path, NAV, render_images=False)
    space, act = env.observation_space, env.action_space
    assert set(space.spaces) == {"state", "joint_positions", "joint_velocities", "base_pose", "scan"}
    assert space["scan"] == gym.spaces.Box(0.0, 10.0, (360,), np.float32)
    assert space["joint_positions"].shape == (12,)
    np.testing.assert_allclose(act.low, [-1] * 7 + [-0.8, -0.8, -1.5])
    np.testing.assert_allclose(act.high, [1] * 7 + [0.8, 0.8, 1.5])
    assert checked(env, UNBOUNDED_OBS + PHYSICAL_ACTION_UNITS) == []

    obs, _ = env.reset(seed=0)
    start = obs["base_pose"].copy()
    action = np.zeros(10, np.float32)
    action[7] = 0.5  # vx = 0.5 m/s, base frame; starts facing +x
    for _ in range(10):
        obs, _, _, _, info = env.step(action)
    np.testing.assert_allclose(obs["base_pose"] - start, [0.25, 0.0, 0.0], atol=2e-3)  # 10 steps at 20 Hz
    assert info["sim_time_ns"] == 500_000_000 and not info["is_success"]


def test_depth_points_are_left_out_by_default_and_padded_on_request(tmp_path, envs):
    plain = envs(tmp_path, {**NAV, "image_size": "[16, 16]"})
    assert "depth_points" not in plain.observation_space.spaces
    assert "depth_points" in plain.unwrapped.rollout.reset(seed=0)  # the seam still has the cloud

    k = 160 * 120  # the depth camera's pixel count: no cloud can be larger
    env = envs(tmp_path, {**NAV, "image_size": "[16, 16]"}, depth_points=k)
    assert env.observation_space["depth_points"]["front_depth"].shape == (k, 3)
    obs, info = env.reset(seed=0)
    n = info["depth_points_count"]["front_depth"]
    raw = env.unwrapped.last_observation["depth_points"]["front_depth"]
    assert 0 < n == len(raw) < k
    np.testing.assert_array_equal(obs["depth_points"]["front_depth"][:n], raw)
    assert not obs["depth_points"]["front_depth"][n:].any() and obs in env.observation_space


def test_pad_points_subsamples_evenly_and_pads_with_zeros():
    pts = np.arange(30, dtype=np.float32).reshape(10, 3)
    out, n = pad_points(pts, 4)
    assert n == 4 and out.tolist() == pts[[0, 3, 6, 9]].tolist()
    out, n = pad_points(pts, 12)
    assert n == 10 and out.shape == (12, 3) and not out[10:].any() and (out[:10] == pts).all()


def test_plus_z_cartesian_delta_raises_the_end_effector(tmp_path, envs):
    env = envs(tmp_path, LIFT, render_images=False)
    obs, _ = env.reset(seed=0)
    start = obs["state"][:3].copy()  # state = [eef_pos(3), eef_axis_angle(3), finger qpos(2)], base frame
    up = np.array([0, 0, 0.4, 0, 0, 0, -1], np.float32)  # dz = 0.4 * 0.05 m per step, gripper open
    for _ in range(8):
        obs, *_ = env.step(up)
    moved = obs["state"][:3] - start
    assert moved[2] == pytest.approx(8 * 0.4 * 0.05, rel=0.10)
    assert np.abs(moved[:2]).max() < 0.016  # off-axis drift under 10 % of the commanded 16 cm


def test_joint_position_action_space_is_the_joint_limits(tmp_path, envs):
    env = envs(tmp_path, {**LIFT, "control_mode": "joint_position"}, render_images=False)
    arm = env.unwrapped.rollout.spec.robot.arm_joints
    act = env.action_space
    np.testing.assert_allclose(act.low, [j.lower for j in arm] + [-1.0], rtol=1e-6)
    np.testing.assert_allclose(act.high, [j.upper for j in arm] + [1.0], rtol=1e-6)
    obs, _ = env.reset(seed=0)
    target = np.append(obs["joint_positions"][:7], -1.0).astype(np.float32)
    target[0] += 0.3  # rad: joint 1 (limited by its speed, ~2.2 rad/s, over several steps)
    for _ in range(15):
        obs, *_ = env.step(target)
    assert obs["joint_positions"][0] == pytest.approx(target[0], abs=0.01)


def test_seeds_reproduce_observations(tmp_path, envs):
    a = envs(tmp_path, LIFT, render_images=False, privileged=True)
    b = envs(tmp_path, LIFT, render_images=False, privileged=True)

    def cube(env):
        return env.unwrapped.last_observation["privileged"]["objects"]["cube"]

    def episode_starts(env):
        first, _ = env.reset(seed=11)
        rest = [env.reset()[0] for _ in range(2)]
        return [first, *rest], cube(env)

    obs_a, cube_a = episode_starts(a)
    obs_b, cube_b = episode_starts(b)
    for x, y in zip(obs_a, obs_b):
        assert gym.utils.env_checker.data_equivalence(x, y, exact=True)
    np.testing.assert_array_equal(cube_a, cube_b)
    a.reset(seed=11)
    first = cube(a).copy()
    a.reset(seed=12)
    assert np.abs(cube(a)[:2] - first[:2]).max() > 1e-3  # another seed, another cube placement


def test_scripted_expert_lifts_the_cube_through_the_env(tmp_path, envs):
    env = envs(tmp_path, LIFT, render_images=False, privileged=True)
    policy = make_policy("scripted")
    rollout = env.unwrapped.rollout
    for seed in (0, 1):
        _, info = env.reset(seed=seed)
        policy.reset(rollout.spec)
        assert not info["is_success"]
        for _ in range(rollout.spec.task.max_steps):
            _, reward, terminated, truncated, info = env.step(policy.act(env.unwrapped.last_observation))
            if terminated or truncated:
                break
        assert terminated and info["is_success"] and info["success"] and reward == 1.0, seed


def test_bad_actions_raise_clear_errors(tmp_path, envs):
    env = envs(tmp_path, LIFT, render_images=False)
    env.reset(seed=0)
    before = env.unwrapped.last_observation["joint_positions"].copy()
    with pytest.raises(InvalidActionError, match=r"shape \(3,\), expected \(7,\).*dx, dy, dz, dax, day, daz, grip"):
        env.step(np.zeros(3, np.float32))
    with pytest.raises(InvalidActionError, match=r"action\[2\] is nan"):
        env.step(np.array([0, 0, np.nan, 0, 0, 0, 0], np.float32))
    assert env.unwrapped.rollout.sim_time_ns() == 0  # nothing was applied
    np.testing.assert_array_equal(env.unwrapped.last_observation["joint_positions"], before)


def test_scene_config_overrides_and_close_twice(tmp_path):
    env = SimseamEnv(SceneConfig(robot="franka_panda", layout="lift_cube"), image_size=(32, 48), max_steps=5)
    try:
        assert env.observation_space["images"]["camera1"].shape == (32, 48, 3)
        assert env.rollout.spec.task.max_steps == 5
    finally:
        env.close()
        env.close()
    with pytest.raises(ConfigError, match="image_sise"):
        SimseamEnv(SceneConfig(robot="franka_panda", layout="lift_cube"), image_sise=(32, 32))
    with pytest.raises(ConfigError, match="render_mode 'human'"):
        SimseamEnv(SceneConfig(robot="franka_panda", layout="lift_cube"), render_mode="human")


def test_core_never_imports_gymnasium_and_missing_gymnasium_is_explained():
    core = ("import sys, simseam, simseam.seam, simseam.runner.scene_config, simseam.runner.episodes, "
            "simseam.scene.manifest_scene\nprint('gymnasium' in sys.modules)")
    out = subprocess.run([sys.executable, "-c", core], capture_output=True, text=True, check=True)
    assert out.stdout.strip() == "False"
    blocked = "import sys\nsys.modules['gymnasium'] = None\nimport simseam.gym"
    out = subprocess.run([sys.executable, "-c", blocked], capture_output=True, text=True, check=False)
    assert out.returncode != 0 and "pip install gymnasium" in out.stderr and "simseam[gym]" in out.stderr
