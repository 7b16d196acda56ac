"""PushT through the seam as LeRobot runs it: simseam's scripted expert covers the target on fixed seeds, and
one checkpoint (a state-based ACT reading ``observation.state`` and ``observation.environment_state``) gives
the same episode in LeRobot's own PushT env (``lerobot-eval``'s ``rollout``, obs_type
``environment_state_agent_pos``, run in a subprocess of this interpreter with gym-pusht linked from the pusht
backend's venv, as benchmarks/pusht_lerobot_eval.py does) and in the pusht backend's sidecar."""

from __future__ import annotations

import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from backend_util import backend_python

from simseam.seam import ObsRequest

pytestmark = pytest.mark.backends

T_AT_1000 = [340.0, 280.0]  # about where seed 1000 puts the T: the random policy's targets centre there
PUSHT_PACKAGES = ("gym_pusht", "pymunk", "pygame", "pygame.libs", "shapely", "shapely.libs", "cffi", "pycparser")
LEROBOT_SIDE = """
import sys, numpy as np
from lerobot.configs.policies import PreTrainedConfig
from lerobot.envs.configs import PushtEnv
from lerobot.envs.factory import make_env, make_env_pre_post_processors
from lerobot.policies.factory import make_policy, make_pre_post_processors
from lerobot.scripts.lerobot_eval import rollout
ckpt, seed, steps, out = sys.argv[1], int(sys.argv[2]), int(sys.argv[3]), sys.argv[4]
env_cfg = PushtEnv(obs_type="environment_state_agent_pos", episode_length=steps)
cfg = PreTrainedConfig.from_pretrained(ckpt)
cfg.pretrained_path, cfg.device = ckpt, "cpu"
policy = make_policy(cfg=cfg, env_cfg=env_cfg)
policy.eval()
pre, post = make_pre_post_processors(policy_cfg=cfg, pretrained_path=ckpt,
                                     preprocessor_overrides={"device_processor": {"device": "cpu"}})
env_pre, env_post = make_env_pre_post_processors(env_cfg=env_cfg, policy_cfg=cfg)
env = next(iter(next(iter(make_env(env_cfg, n_envs=1).values())).values()))
r = rollout(env, policy, env_pre, env_post, pre, post, seeds=[seed], return_observations=True)
o = r["observation"]
np.savez(out, action=r["action"][0].numpy(), reward=r["reward"][0].numpy(),
         state=o["observation.state"][0].numpy(), env_state=o["observation.environment_state"][0].numpy())
"""


def _state_act(tmp_path: Path) -> Path:
    """A LeRobot ACT (random weights) on PushT's state: agent position and the T's 8 keypoints; its targets
    spread about where seed 1000 puts the T, so that it pushes the T."""
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors

    cfg = ACTConfig(input_features={"observation.state": PolicyFeature(FeatureType.STATE, (2,)),
                                    "observation.environment_state": PolicyFeature(FeatureType.ENV, (16,))},
                    output_features={"action": PolicyFeature(FeatureType.ACTION, (2,))},
                    chunk_size=5, n_action_steps=5, dim_model=32, dim_feedforward=64, n_encoder_layers=1,
                    n_decoder_layers=1, n_heads=2, use_vae=False, device="cpu")
    torch.manual_seed(0)
    policy = ACTPolicy(cfg)
    stats = {"observation.state": {"mean": torch.full((2,), 256.0), "std": torch.full((2,), 150.0)},
             "observation.environment_state": {"mean": torch.full((16,), 256.0), "std": torch.full((16,), 150.0)},
             "action": {"mean": torch.tensor(T_AT_1000), "std": torch.full((2,), 60.0)}}
    pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
    out = tmp_path / "pusht_state_act"
    for obj in (policy, pre, post):
        obj.save_pretrained(out)
    return out


def _lerobot_episode(tmp_path: Path, ckpt: Path, seed: int, steps: int) -> dict:
    site = tmp_path / "site"
    site.mkdir()
    found = next((Path(backend_python("pusht")).parents[1] / "lib").glob("python*/site-packages"))
    for path in [found / p for p in PUSHT_PACKAGES] + list(found.glob("_cffi_backend*.so")):
        (site / path.name).symlink_to(path)
    env = dict(os.environ, PYTHONPATH=str(site), OMP_NUM_THREADS="1", HF_HUB_OFFLINE="1")
    out = subprocess.run([sys.executable, "-c", LEROBOT_SIDE, str(ckpt), str(seed), str(steps),
                          str(tmp_path / "lerobot.npz")], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, f"LeRobot's PushT env failed:\n{out.stderr[-3000:]}"
    with np.load(tmp_path / "lerobot.npz") as z:
        return {k: z[k] for k in z.files}


def test_the_expert_covers_the_target(open_backend):
    sim = open_backend("pusht", {"cameras": False}, privileged=True)  # what collect --no-cameras opens
    assert sim.spec.env_state_dim == 16 and sim.spec.cameras == {} and sim.spec.can("privileged")
    for seed in (3, 11):
        obs = sim.reset(seed, ObsRequest.state_only())
        for _ in range(sim.spec.task.max_steps):
            step = sim.step(obs["expert_action"], ObsRequest.state_only())
            obs = step.observation
            if step.terminated or step.truncated:
                break
        assert step.terminated and step.info["success"], f"seed {seed}: {step.info}"
        assert step.info["diagnostics"]["coverage"] > 0.95


@pytest.mark.learning
def test_one_checkpoint_one_episode_in_lerobots_env_and_through_the_seam(open_backend, tmp_path):
    from simseam.policies.base import make_policy

    seed, steps = 1000, 40
    ckpt = _state_act(tmp_path)
    native = _lerobot_episode(tmp_path, ckpt, seed, steps)
    assert native["action"].shape == (steps, 2) and np.ptp(native["action"], axis=0).min() > 1.0  # it moves
    assert ((native["action"] > 0) & (native["action"] < 512)).all()  # nothing for the seam to clip
    sim = open_backend("pusht", {"max_steps": steps})
    policy = make_policy(f"lerobot:{ckpt}", device="cpu")
    policy.reset(sim.spec)
    obs = sim.reset(seed, ObsRequest.state_only())
    for t in range(steps):
        np.testing.assert_array_equal(obs["state"], native["state"][t])
        np.testing.assert_array_equal(obs["environment_state"], native["env_state"][t])
        action = policy.act(obs)
        np.testing.assert_array_equal(action, native["action"][t])
        step = sim.step(action, ObsRequest.state_only())
        assert step.reward == native["reward"][t]
        obs = step.observation
    assert step.truncated
    assert np.ptp(native["reward"]) > 0 and np.ptp(native["env_state"][:steps, 0]) > 1.0  # the T was pushed
