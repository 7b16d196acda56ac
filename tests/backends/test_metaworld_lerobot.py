"""The ``metaworld_lerobot`` preset is LeRobot's own Meta-World env behind the seam: LeRobot's
``MetaworldEnv`` (lerobot/envs/metaworld.py, run in a subprocess of this interpreter with the metaworld
backend's metaworld 3.0.0 and MuJoCo 3.3.0 first on its path, as benchmarks/metaworld_lerobot_eval.py
does) and the seam's sidecar give the same 480x480 image, ``agent_pos`` and rewards, seeded the way
``lerobot-eval --seed`` seeds its first episode; and the options one by one, on small images."""

from __future__ import annotations

import json
import os
import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest
from backend_util import backend_python

from simseam.runner.evaluate import METAWORLD_LEROBOT
from simseam.seam import ObsRequest

pytestmark = pytest.mark.backends

TASK = "drawer-close-v3"
LEROBOT_SIDE = """
import json, sys, numpy as np
from lerobot.envs.metaworld import MetaworldEnv
from lerobot.utils.random_utils import set_seed
task, seeds, actions, out = sys.argv[1], json.loads(sys.argv[2]), np.load(sys.argv[3]), sys.argv[4]
res = {}
for s in seeds:
    set_seed(s)  # lerobot-eval: set_seed(cfg.seed), then make_env, then the first episode's reset(seed)
    env = MetaworldEnv(task=task, obs_type="pixels_agent_pos")
    o, _ = env.reset(seed=s)
    res[f"image{s}"], res[f"state{s}"] = o["pixels"], [o["agent_pos"]]
    res[f"reward{s}"] = []
    for a in actions if s == seeds[0] else []:
        o, r, term, trunc, info = env.step(a)
        res[f"state{s}"].append(o["agent_pos"])
        res[f"reward{s}"].append(r)
        if term:
            break
    env.close()
np.savez(out, **res)
"""


def _lerobot_episodes(tmp_path: Path, seeds: list[int], actions: np.ndarray) -> dict:
    site = tmp_path / "site"
    site.mkdir()
    lib = Path(backend_python("metaworld")).parents[1] / "lib"
    found = next(lib.glob("python*/site-packages"))
    for pkg in ("metaworld", "mujoco"):
        (site / pkg).symlink_to(found / pkg)
    np.save(tmp_path / "actions.npy", actions)
    env = dict(os.environ, PYTHONPATH=str(site), MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"),
               OMP_NUM_THREADS="1", HF_HUB_OFFLINE="1")
    out = subprocess.run([sys.executable, "-c", LEROBOT_SIDE, TASK, json.dumps(seeds), str(tmp_path / "actions.npy"),
                          str(tmp_path / "lerobot.npz")], capture_output=True, text=True, env=env, timeout=600)
    assert out.returncode == 0, f"LeRobot's env failed:\n{out.stderr[-3000:]}"
    with np.load(tmp_path / "lerobot.npz") as z:
        return {k: z[k] for k in z.files}


@pytest.mark.learning
def test_the_preset_gives_what_lerobots_env_gives(open_backend, tmp_path):
    seeds = [1000, 1003]
    actions = np.random.default_rng(0).uniform(-1, 1, (4, 4)).astype(np.float32)
    native = _lerobot_episodes(tmp_path, seeds, actions)
    sim = open_backend("metaworld", {"task": TASK, **METAWORLD_LEROBOT})
    assert sim.spec.state_dim == 4 and sim.spec.cameras == {"camera1": (480, 480)}
    for s in seeds:
        obs = sim.reset(s)
        np.testing.assert_array_equal(obs["images"]["camera1"], native[f"image{s}"])
        np.testing.assert_array_equal(obs["state"], native[f"state{s}"][0].astype(np.float32))
        for t, a in enumerate(actions[: len(native[f"reward{s}"])]):  # LeRobot's episode ends at success
            step = sim.step(a, ObsRequest.state_only())
            np.testing.assert_array_equal(step.observation["state"], native[f"state{s}"][t + 1].astype(np.float32))
            np.testing.assert_allclose(step.reward, native[f"reward{s}"][t], rtol=1e-6)
    assert len(native[f"reward{seeds[0]}"]) > 0
    # the seed matters (the drawer's place differs), and a repeated seed is the same episode
    assert not np.array_equal(native[f"image{seeds[0]}"], native[f"image{seeds[1]}"])
    np.testing.assert_array_equal(sim.reset(seeds[0])["images"]["camera1"], native[f"image{seeds[0]}"])


def test_flip_camera_position_and_agent_pos_one_by_one(open_backend):
    base = {"task": TASK, "image_size": [32, 32], "goal_seed": 42, "variation": "lerobot"}
    plain = open_backend("metaworld", base)
    flipped = open_backend("metaworld", {**base, "image_flip": True, "state": "agent_pos"})
    moved = open_backend("metaworld", {**base, "camera_pos": [0.75, 0.075, 0.7]})
    a, b, c = plain.reset(5), flipped.reset(5), moved.reset(5)
    np.testing.assert_array_equal(b["images"]["camera1"], a["images"]["camera1"][::-1, ::-1])
    assert a["state"].shape == (39,) and b["state"].shape == (4,)
    np.testing.assert_array_equal(b["state"], a["state"][:4])
    assert not np.array_equal(c["images"]["camera1"], a["images"]["camera1"])
    np.testing.assert_allclose(moved.spec.robot.sensors[0].xyz, (0.75, 0.075, 0.7), atol=1e-9)
    # the flipped camera's mount is the plain one rolled half a turn
    roll_a, roll_b = plain.spec.robot.sensors[0].rpy[0], flipped.spec.robot.sensors[0].rpy[0]
    assert abs(abs(((roll_b - roll_a) + np.pi) % (2 * np.pi) - np.pi) - np.pi) < 1e-6
