"""The vector runner's central renderer (``renderer="batched"``): workers step physics with images off
and send their MuJoCo render state; this process draws every worker's cameras in one MuJoCo Warp batch
(warp's CPU device here, a handful of environments).

The reference for every image is the worker's own renderer: MuJoCo's OpenGL rasterizer (EGL) on the
same state, replayed in-process from the same seed and actions. A ray tracer and a rasterizer are not
bit-exact, so the images are compared with stated, measured tolerances:

- geometry: the red cube's silhouette (IoU) and centroid in both cameras; measured on seeds 3-4 (96x96,
  30 scripted steps, every frame): IoU 0.93-1.0 where the cube is in view, centroid within 0.3 px;
- appearance: mean absolute difference per camera; measured: front camera1 <= 2.3, wrist camera2 <= 18.3
  (the ray tracer's spot light leaves a brighter patch on the table close to the wrist camera).

A wrong state (another seed's cube position) fails the geometry check (IoU 0, centroid 5.8 px off).
"""

from __future__ import annotations

import numpy as np
import pytest

from simseam.policies.base import make_policy
from simseam.policies.batch import PerEnvPolicies
from simseam.robot.manifest import load_robot
from simseam.runner.central_render import CentralRenderer, choose_renderer, cuda_available, unsupported
from simseam.runner.scene_config import SceneConfig
from simseam.runner.recipe import SceneRecipe
from simseam.runner.vector import VectorEnv
from simseam.runner.whole_episodes import run_local
from simseam.scene.manifest_scene import ManifestScene, SceneOptions
from simseam.seam import STATE_ONLY, ConfigError, ObsRequest

SIZE = (96, 96)
STEPS = 30
CUBE_IOU_MIN = 0.8
CUBE_CENTROID_PX = 1.5
MEAN_ABS_DIFF = {"camera1": 4.0, "camera2": 25.0}


def _cube(img):
    return (img[..., 0] > 150) & (img[..., 1] < 90) & (img[..., 2] < 90)


def _geometry_problems(got, want) -> list[str]:
    """Where the cube's silhouette differs beyond the stated tolerance (empty: it matches)."""
    problems = []
    for key in want:
        a, b = _cube(got[key]), _cube(want[key])
        if a.sum() + b.sum() < 8:  # out of view in both (or a few pixels at the border)
            continue
        iou = (a & b).sum() / (a | b).sum()
        shift = np.abs(np.argwhere(a).mean(0) - np.argwhere(b).mean(0)).max() if a.any() and b.any() else np.inf
        if iou < CUBE_IOU_MIN or shift > CUBE_CENTROID_PX:
            problems.append(f"{key}: cube IoU {iou:.2f}, centroid {shift:.2f} px")
    return problems


def _recipe(privileged=True) -> SceneRecipe:
    cfg = SceneConfig.model_validate({"robot": "franka_panda", "task": "lift_cube", "image_size": list(SIZE),
                                      "max_steps": STEPS})
    return SceneRecipe(cfg.model_dump(mode="json"), ".", privileged=privileged, render_images=True)


# the request the policy makes at each step (cycled): every camera, one camera, none
REQUESTS = (None, ObsRequest(images=frozenset({"camera1"})), STATE_ONLY)


class _Recorder(PerEnvPolicies):
    """The scripted expert for every environment, asking for images as ``REQUESTS`` cycles; records what
    each environment observed and did."""

    uses_images = True

    def __init__(self, n):
        super().__init__(lambda: make_policy("scripted"), n)
        self.log: dict[int, list] = {}
        self.k = [0] * n

    def reset(self, env, spec):
        super().reset(env, spec)
        self.k[env] = 0
        self.log[env] = []

    def observe_next(self, env):
        return REQUESTS[self.k[env] % len(REQUESTS)]

    def act_batch(self, envs, observations):
        actions = super().act_batch(envs, observations)
        for e, o, a in zip(envs, observations, actions):
            self.log[e].append((self.observe_next(e), o, a))
            self.k[e] += 1
        return actions


@pytest.fixture(scope="module")
def batched_run():
    """Two episodes (seeds 3, 4) on two workers, the cameras drawn centrally."""
    pol = _Recorder(2)
    with VectorEnv(_recipe(), 2, renderer="batched") as vec:
        results = vec.run(pol, [0, 1], seed=3)
        spec = vec.spec
    # which environment played which episode is not fixed: find each seed's log by its cube
    by_seed = {}
    for e in range(2):
        first_obs = pol.log[e][0][1]
        by_seed[_seed_of(first_obs)] = pol.log[e]
    assert set(by_seed) == {3, 4}
    return spec, by_seed, results


def _seed_of(obs) -> int:
    """Which of seeds 3/4 an episode started from (its cube position, privileged)."""
    cube = obs["privileged"]["objects"]["cube"][:3]
    for seed in (3, 4):
        scene = ManifestScene(load_robot("franka_panda"), "lift_cube", "mujoco",
                              SceneOptions(image_size=SIZE, max_steps=STEPS, privileged=True, render_images=False))
        try:
            ref = scene.reset(seed)["privileged"]["objects"]["cube"][:3]
        finally:
            scene.close()
        if np.allclose(ref, cube):
            return seed
    raise AssertionError(f"cube at {cube} matches neither seed")


def _egl_replay(seed, actions):
    """The worker's own renderer (MuJoCo OpenGL through EGL) on the same states: every camera, every step."""
    scene = ManifestScene(load_robot("franka_panda"), "lift_cube", "mujoco",
                          SceneOptions(image_size=SIZE, max_steps=STEPS, privileged=True))
    try:
        frames = [scene.reset(seed)["images"]]
        for a in actions[:-1]:
            frames.append(scene.step(a).observation["images"])
        return frames
    finally:
        scene.close()


def test_central_images_match_the_workers_own_cameras(batched_run):
    spec, by_seed, results = batched_run
    assert len(results) == 2 and all(r.error is None and r.steps > 0 for r in results)
    worst = {"camera1": 0.0, "camera2": 0.0}
    checked = 0
    for seed, log in by_seed.items():
        reference = _egl_replay(seed, [a for _, _, a in log])
        for (request, obs, _), want in zip(log, reference):
            asked = {k for k in want if request is None or request.wants_image(k)}
            assert set(obs["images"]) == asked  # exactly the cameras the policy asked for
            for key, img in obs["images"].items():
                assert img.dtype == np.uint8 and img.shape == want[key].shape == (*spec.observation.images[key], 3)
                worst[key] = max(worst[key], float(np.abs(img.astype(int) - want[key].astype(int)).mean()))
            assert _geometry_problems(obs["images"], {k: want[k] for k in obs["images"]}) == []
            checked += len(obs["images"])
    assert checked >= 2 * STEPS  # most steps carried images
    for key, tol in MEAN_ABS_DIFF.items():
        assert worst[key] <= tol, (key, worst[key])


def test_a_wrong_state_fails_the_fidelity_check(batched_run):
    """The check has teeth: seed 3's central frame against seed 4's EGL frame (the cube elsewhere)."""
    _, by_seed, _ = batched_run
    got = by_seed[3][0][1]["images"]
    other = _egl_replay(4, [by_seed[4][0][2]])[0]
    assert _geometry_problems(got, other)
    same = _egl_replay(3, [by_seed[3][0][2]])[0]
    assert _geometry_problems(got, same) == []


def test_frames_are_the_policys_own_copies(batched_run):
    _, by_seed, _ = batched_run
    frames = [obs["images"]["camera1"] for _, obs, _ in by_seed[3] if "camera1" in obs["images"]]
    assert len(frames) > 2 and not np.array_equal(frames[0], frames[-1])  # kept frames never overwritten


def test_what_the_central_renderer_cannot_serve_is_a_clear_error(tmp_path):
    sidecar = {"robot": "franka_panda", "task": "lift_cube", "engine": {"name": "mujoco", "process": "sidecar"}}
    assert "sidecar" in unsupported(sidecar)
    assert "benchmark 'metaworld'" in unsupported({"benchmark": {"name": "metaworld", "task": "reach-v3"}})
    assert "mujoco_warp" in unsupported({"engine": {"name": "mujoco_warp"}})
    with pytest.raises(ConfigError, match="--renderer batched: engine.process: sidecar"):
        choose_renderer("batched", sidecar, True)
    assert choose_renderer("auto", sidecar, True) == "workers"
    assert choose_renderer("batched", {"robot": "franka_panda"}, False) == "workers"  # nothing to draw
    assert choose_renderer("batched", {"robot": "franka_panda"}, True) == "batched"
    assert choose_renderer("auto", {"robot": "franka_panda"}, True) == ("batched" if cuda_available() else "workers")
    assert choose_renderer("auto", {"robot": "franka_panda"}, False) == "workers"
    with pytest.raises(ConfigError, match="--renderer must be one of"):
        choose_renderer("gpu", {}, True)
    cfg = SceneConfig.model_validate({"robot": "panda_mobile", "task": "nav_obstacles"})
    mobile = SceneRecipe(cfg.model_dump(mode="json"), ".", render_images=True)
    with pytest.raises(ConfigError, match="renderer 'batched': robot 'panda_mobile' has (depth cameras|a lidar)"):
        CentralRenderer(mobile, 2)


def test_run_local_is_refused_with_the_central_renderer():
    with VectorEnv(_recipe(privileged=False), 1, renderer="batched") as vec:
        with pytest.raises(ConfigError, match="run_local"):
            run_local(vec, "zero", {}, [0])


def test_a_worker_killed_mid_episode_with_the_central_renderer(tmp_path):
    """A worker dying mid-episode costs nothing with the central renderer either: the episode re-runs
    (counted once, same result), its partial video is dropped and the re-run's video is complete."""
    import os
    import signal

    import imageio.v2 as imageio

    from simseam.policies.batch import make_policy_batch
    from simseam.runner.session import run_episodes

    scene = ManifestScene(load_robot("franka_panda"), "lift_cube", "mujoco",
                          SceneOptions(image_size=SIZE, max_steps=STEPS, privileged=True, render_images=False))
    try:
        reference = {r.index: (r.success, r.steps, round(r.reward, 9))
                     for r in run_episodes(scene, make_policy("scripted"), range(3), seed=0)}
    finally:
        scene.close()
    pol = make_policy_batch("scripted", 2)
    killed, failures = [], []
    with VectorEnv(_recipe(), 2, renderer="batched") as vec:
        def on_step(env, index, steps):
            if index == 1 and steps == 5 and not killed:
                killed.append(index)
                os.kill(vec.pids()[env], signal.SIGKILL)

        results = vec.run(pol, range(3), seed=0, video_dir=tmp_path, on_step=on_step,
                          on_worker_failure=failures.append)
    assert killed and [f.index for f in failures] == [1]
    assert sorted(r.index for r in results) == [0, 1, 2]
    assert {r.index: (r.success, r.steps, round(r.reward, 9)) for r in results} == reference
    for r in results:
        with imageio.get_reader(r.video) as video:
            assert sum(1 for _ in video) == r.steps + 1
    assert sorted(p.name for p in tmp_path.iterdir()) == [f"episode_{i:03d}.mp4" for i in range(3)]
