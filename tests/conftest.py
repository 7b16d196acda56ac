"""Shared fixtures. Tests run headless on the CPU (MUJOCO_GL=egl by default)."""

import os

os.environ.setdefault("MUJOCO_GL", "egl")

import pytest  # noqa: E402

from simseam.robot.manifest import load_robot  # noqa: E402
from simseam.scene.manifest_scene import ManifestScene, SceneOptions  # noqa: E402


@pytest.fixture(scope="session")
def panda_spec():
    return load_robot("franka_panda")


@pytest.fixture(scope="session")
def so101_spec():
    return load_robot("so101")


@pytest.fixture
def make_scene():
    """Factory for ManifestScenes that are closed at the end of the test."""
    scenes = []

    def _make(spec, layout="lift_cube", **options):
        scene = ManifestScene(spec, layout, "mujoco", SceneOptions(**options))
        scenes.append(scene)
        return scene

    yield _make
    for s in scenes:
        s.close()


@pytest.fixture
def count_successes():
    """``count(scene, policy, seeds) -> int``: episodes (one per seed) that end in success."""

    def _count(scene, policy, seeds):
        wins = 0
        for seed in seeds:
            obs = scene.reset(seed)
            policy.reset(scene.scene, scene.task)
            for _ in range(scene.task.max_steps):
                step = scene.step(policy.act(obs))
                obs = step.observation
                if step.terminated or step.truncated:
                    break
            wins += bool(step.info["success"])
        return wins

    return _count
