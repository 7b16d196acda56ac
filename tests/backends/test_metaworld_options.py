"""Meta-World's options for learning from its experts (benchmarks/metaworld_proof.py): sampled variations
(held-out initial states), the object state a state policy reads, and a state-only rollout that declares
no camera (real sidecars on the provisioned venv)."""

from __future__ import annotations

import numpy as np
import pytest
from backend_util import backend_python

from simseam.seam import ObsRequest

pytestmark = pytest.mark.backends

TASK_SLOTS = [*range(4, 18), 36, 37, 38]  # obj1 pose, obj2 pose, goal


def _start(rollout, seed: int) -> np.ndarray:
    return np.asarray(rollout.reset(seed, ObsRequest.state_only())["state"])


def test_mt1_repeats_every_50_seeds_and_sampled_variations_do_not(open_backend):
    mt1 = open_backend("metaworld", {"task": "pick-place-v3", "cameras": False})
    sampled = open_backend("metaworld", {"task": "pick-place-v3", "cameras": False, "variation": "sampled"})
    # the preset's episodes: seed s and s + 50 (and 10000 + s) start from the same MT1 variation
    np.testing.assert_array_equal(_start(mt1, 7), _start(mt1, 57))
    np.testing.assert_array_equal(_start(mt1, 3), _start(mt1, 10003))
    mt1_starts = np.stack([_start(mt1, s)[TASK_SLOTS] for s in range(50)])
    # sampled: deterministic per seed, every seed its own start, none of them one of MT1's 50
    a, b = _start(sampled, 7), _start(sampled, 57)
    np.testing.assert_array_equal(a, _start(sampled, 7))
    assert np.abs(a[TASK_SLOTS] - b[TASK_SLOTS]).max() > 1e-3
    starts = np.stack([_start(sampled, s)[TASK_SLOTS] for s in range(20)])
    assert len(np.unique(starts.round(6), axis=0)) == 20
    nearest = np.abs(starts[:, None, :] - mt1_starts[None, :, :]).max(axis=2).min(axis=1)
    assert nearest.min() > 1e-3, "a sampled start coincides with an MT1 variation"
    # ... drawn from the same reset distribution: object and goal inside the range MT1's 50 span, widened 2 cm
    lo, hi = mt1_starts.min(axis=0) - 0.02, mt1_starts.max(axis=0) + 0.02
    assert ((starts >= lo) & (starts <= hi)).all()
    # the hand starts where MT1's does
    np.testing.assert_allclose(a[:4], _start(mt1, 0)[:4], atol=1e-6)


def test_environment_state_is_the_task_part_of_the_observation_and_cameras_can_be_off(open_backend):
    r = open_backend("metaworld", {"task": "push-v3", "cameras": False, "variation": "sampled"}, privileged=True)
    assert r.spec.cameras == {} or not r.spec.cameras
    assert r.spec.observation.env_state_dim == 17
    assert r.spec.observation.fields["environment_state"].names[-3:] == ("goal_x", "goal_y", "goal_z")
    obs = r.reset(5)
    assert not obs.get("images")
    for _ in range(3):
        np.testing.assert_array_equal(obs["environment_state"], obs["state"][TASK_SLOTS])
        obs = r.step(obs["expert_action"]).observation
    off = open_backend("metaworld", {"task": "push-v3", "environment_state": False, "image_size": [32, 32]})
    assert off.spec.observation.env_state_dim is None and list(off.spec.cameras) == ["camera1"]
    assert "environment_state" not in off.reset(5)


def test_a_benchmark_scene_declares_no_camera_when_nothing_reads_images(tmp_path):
    """``simseam collect --no-cameras`` (and a state policy's run) build the rollout with render_images=False:
    the backend's camera option is turned off, so the recorder records state alone and nothing is rendered."""
    from simseam.runner.scene_config import build_rollout, load_scene_config

    backend_python("metaworld")
    scene = tmp_path / "mw.yaml"
    scene.write_text("benchmark: {name: metaworld, task: reach-v3, image_size: [32, 32], variation: sampled}\n")
    cfg, base = load_scene_config(scene)
    for render, cameras in ((False, []), (True, ["camera1"])):
        r = build_rollout(cfg, base, render_images=render)
        try:
            assert list(r.spec.cameras) == cameras
        finally:
            r.close()


NATIVE_ML1 = """
import json, sys
import metaworld
task, seeds = sys.argv[1], json.loads(sys.argv[2])
ml1 = metaworld.ML1(task, seed=0)
env = ml1.test_classes[task]()
out = []
for s in seeds:
    env.set_task(ml1.test_tasks[s % 50])
    env.seed(s)
    obs, _ = env.reset()
    out.append(obs.tolist())
print(json.dumps(out))
"""


def test_ml1_is_metaworlds_own_held_out_test_goals(open_backend):
    """``variation: ml1`` (the ``metaworld_ml1`` preset): the reset Meta-World's ML1 test set gives, written by
    Meta-World itself in its venv (ML1's own env class, not simseam's); held out from MT1's 50, goal hidden."""
    import json
    import subprocess

    seeds = [3, 53, 11]
    out = subprocess.run([str(backend_python("metaworld")), "-c", NATIVE_ML1, "pick-place-v3", json.dumps(seeds)],
                         capture_output=True, text=True, check=True, env={"MUJOCO_GL": "egl", "PATH": "/usr/bin:/bin"})
    native = np.asarray(json.loads(out.stdout.strip().splitlines()[-1]), dtype=np.float32)
    ml1 = open_backend("metaworld", {"task": "pick-place-v3", "cameras": False, "variation": "ml1"})
    mt1 = open_backend("metaworld", {"task": "pick-place-v3", "cameras": False})
    ours = np.stack([_start(ml1, s) for s in seeds])
    np.testing.assert_array_equal(ours, native)
    np.testing.assert_array_equal(ours[0], ours[1])  # seed s and s + 50: one test variation
    assert np.abs(ours[0][TASK_SLOTS[:-3]] - ours[2][TASK_SLOTS[:-3]]).max() > 1e-3
    assert not ours[:, -3:].any(), "ML1 hides the goal"
    mt1_starts = np.stack([_start(mt1, s)[4:18] for s in range(50)])
    nearest = np.abs(ours[:, None, 4:18] - mt1_starts[None]).max(axis=2).min(axis=1)
    assert nearest.min() > 1e-3, "an ML1 test start is one of MT1's 50"
