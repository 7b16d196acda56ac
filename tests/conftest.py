"""Shared fixtures. Tests run headless on the CPU (MUJOCO_GL=egl by default)."""

import os
import signal

os.environ.setdefault("MUJOCO_GL", "egl")

# A suite started as a background job (`cmd &` in a script, as a CI runner may) inherits SIGINT ignored, and so
# would every process a test starts: the Ctrl-C tests then see no Ctrl-C. Catching it here gives the children
# the default again (an exec resets a caught signal, not an ignored one).
if signal.getsignal(signal.SIGINT) is signal.SIG_IGN:
    signal.signal(signal.SIGINT, signal.default_int_handler)

import pytest  # noqa: E402

from simseam.robot.manifest import load_robot  # noqa: E402
from simseam.scene.manifest_scene import ManifestScene, SceneOptions  # noqa: E402


@pytest.fixture(scope="session")
def panda_spec():
    return load_robot("franka_panda")


@pytest.fixture(scope="session")
def so101_spec():
    return load_robot("so101")


@pytest.fixture(scope="session")
def mobile_spec():
    return load_robot("panda_mobile")


@pytest.fixture
def make_scene():
    """Factory for ManifestScenes that are closed at the end of the test."""
    scenes = []

    def _make(spec, task="lift_cube", **options):
        scene = ManifestScene(spec, task, "mujoco", SceneOptions(**options))
        scenes.append(scene)
        return scene

    yield _make
    for s in scenes:
        s.close()


@pytest.fixture
def lift(panda_spec, make_scene):
    """A state-only Franka lift scene (7-D cartesian_delta actions)."""
    return make_scene(panda_spec, render_images=False)


@pytest.fixture
def count_successes():
    """``count(scene, policy, seeds) -> int``: episodes (one per seed) that end in success."""

    def _count(scene, policy, seeds):
        wins = 0
        for seed in seeds:
            obs = scene.reset(seed)
            policy.reset(scene.spec)
            for _ in range(scene.spec.task.max_steps):
                step = scene.step(policy.act(obs))
                obs = step.observation
                if step.terminated or step.truncated:
                    break
            wins += bool(step.info["success"])
        return wins

    return _count


# ------------------------------------------------------------------ learned policies (marker: learning)
TINY_ACT = dict(dim_model=64, n_heads=2, dim_feedforward=128, n_encoder_layers=1, chunk_size=8, n_action_steps=4,
                batch_size=4, num_workers=0, log_every=1)

#: a tiny Diffusion Policy: a 2-level U-Net over 8 actions, 2 observations, 4 actions executed, 3 DDIM steps
TINY_DP = dict(policy_type="diffusion", down_dims=(16, 32), horizon=8, n_obs_steps=2, n_action_steps=4,
               diffusion_steps=10, inference_steps=3, batch_size=4, num_workers=0, log_every=1)


class RecordingPolicy:
    """Wraps a policy and keeps every (state, action) pair it produced, in order."""

    def __init__(self, inner):
        self.inner = inner
        self.requires_privileged = inner.requires_privileged
        self.uses_images = True
        self.log = []
        self.env_states = []  # environment_state per step, when the scene observes it

    def reset(self, spec):
        self.inner.reset(spec)

    def observe_next(self):
        return None  # it logs the images too

    def act(self, obs):
        action = self.inner.act(obs)
        self.log.append((obs["state"].copy(), {k: v.copy() for k, v in obs.get("images", {}).items()},
                         action.copy()))
        if "environment_state" in obs:
            self.env_states.append(obs["environment_state"].copy())
        return action


@pytest.fixture(scope="session")
def scripted_dataset(tmp_path_factory, panda_spec):
    """3 scripted lift_cube episodes (40x56 (HxW) cameras: non-square, so a height/width swap shows; AV1 video) recorded through ``collect_dataset``;
    returns (root, CollectResult, the RecordingPolicy's log)."""
    from simseam.policies.base import make_policy
    from simseam.runner.collect import collect_dataset

    root = tmp_path_factory.mktemp("lerobot") / "lift"
    scene = ManifestScene(panda_spec, "lift_cube", "mujoco", SceneOptions(image_size=(40, 56), privileged=True,
                                                                          max_steps=60))
    policy = RecordingPolicy(make_policy("scripted"))
    try:
        result = collect_dataset(scene, policy, root, episodes=3)
    finally:
        scene.close()
    return root, result, policy.log


@pytest.fixture(scope="session")
def tiny_act(scripted_dataset, tmp_path_factory):
    """A tiny ACT trained for 3 optimizer steps on ``scripted_dataset``; returns (checkpoint dir, TrainResult)."""
    from simseam.runner.training import ActTrainConfig, train_act

    out = tmp_path_factory.mktemp("act") / "ckpt"
    result = train_act(scripted_dataset[0], out, ActTrainConfig(steps=3, device="cpu", **TINY_ACT))
    return out, result


@pytest.fixture(scope="session")
def tiny_state_act(state_dataset, tmp_path_factory):
    """A tiny ACT trained for 3 optimizer steps on ``state_dataset`` (proprioception and the cube's pose, no
    camera); returns (checkpoint dir, TrainResult)."""
    from simseam.runner.training import ActTrainConfig, train_act

    out = tmp_path_factory.mktemp("state_act") / "ckpt"
    return out, train_act(state_dataset[0], out, ActTrainConfig(steps=3, device="cpu", use_vae=False, **TINY_ACT))


@pytest.fixture(scope="session")
def tiny_act_te(tiny_act, tmp_path_factory):
    """``tiny_act``'s weights with ACT's temporal ensembling (coefficient 0.01, one action a prediction, as
    LeRobot requires): the policy re-plans every step and averages the overlapping chunks; returns
    (checkpoint dir, None)."""
    import json
    import shutil

    out = tmp_path_factory.mktemp("act_te") / "ckpt"
    shutil.copytree(tiny_act[0], out)
    config = json.loads((out / "config.json").read_text())
    (out / "config.json").write_text(json.dumps({**config, "temporal_ensemble_coeff": 0.01, "n_action_steps": 1}))
    return out, None


@pytest.fixture(scope="session")
def tiny_dp(scripted_dataset, tmp_path_factory):
    """A tiny Diffusion Policy trained for 3 optimizer steps on ``scripted_dataset`` (through the device
    cache); returns (checkpoint dir, TrainResult)."""
    from simseam.runner.training import TrainConfig, train_act

    out = tmp_path_factory.mktemp("dp") / "ckpt"
    result = train_act(scripted_dataset[0], out, TrainConfig(steps=3, device="cpu", cache_on_device=True, **TINY_DP))
    return out, result


@pytest.fixture
def tiny_dp_config():
    """Keyword arguments for a tiny, fast Diffusion ``TrainConfig``."""
    return dict(TINY_DP)


@pytest.fixture(scope="session")
def state_dataset(tmp_path_factory, panda_spec):
    """3 scripted lift_cube episodes recorded from state alone (proprioception + the cube's pose as
    ``environment_state``, no camera); returns (root, CollectResult, the RecordingPolicy)."""
    from simseam.policies.base import make_policy
    from simseam.runner.collect import collect_dataset

    root = tmp_path_factory.mktemp("lerobot") / "lift_state"
    scene = ManifestScene(panda_spec, "lift_cube", "mujoco", SceneOptions(render_images=False, privileged=True,
                                                                          environment_state=True, max_steps=60))
    policy = RecordingPolicy(make_policy("scripted"))
    try:
        result = collect_dataset(scene, policy, root, episodes=3)
    finally:
        scene.close()
    return root, result, policy


@pytest.fixture(scope="session")
def state_act(state_dataset, tmp_path_factory):
    """A tiny ACT (no VAE) trained for 3 optimizer steps on ``state_dataset``; returns the checkpoint dir."""
    from simseam.runner.training import ActTrainConfig, train_act

    out = tmp_path_factory.mktemp("act") / "state_ckpt"
    train_act(state_dataset[0], out, ActTrainConfig(steps=3, device="cpu", use_vae=False, **TINY_ACT))
    return out


@pytest.fixture
def recording_policy():
    """The ``RecordingPolicy`` class (wraps a policy, logs (state, images, action) per step)."""
    return RecordingPolicy


@pytest.fixture
def tiny_act_config():
    """Keyword arguments for a tiny, fast ``ActTrainConfig``."""
    return dict(TINY_ACT)
