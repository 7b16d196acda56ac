"""What a sidecar serves (sidecar/target.py): plain data that survives the boot file unchanged."""

import json

import pytest

from simseam.seam import ConfigError
from simseam.sidecar.target import BackendTarget, SceneTarget, target_from_json


def test_targets_cross_the_boot_file_unchanged_and_identity_tells_them_apart(panda_json):
    panda_json = json.loads(json.dumps(panda_json))  # as JSON has it (lists, not tuples)
    scene = SceneTarget(panda_json, "lift_cube", "mujoco", {"image_size": [64, 48], "render_images": True})
    backend = BackendTarget("metaworld", {"task": "reach-v3", "max_steps": 150})
    for t in (scene, backend):
        assert target_from_json(json.loads(json.dumps(t.to_json()))) == t
    assert (backend.task, backend.engine) == ("reach-v3", "metaworld")
    other = SceneTarget(panda_json, "lift_cube", "mujoco", {"image_size": [48, 64], "render_images": True})
    assert len({scene.identity(), other.identity(), backend.identity()}) == 3
    assert scene.identity() == SceneTarget(panda_json, "lift_cube", "mujoco", dict(scene.options)).identity()


@pytest.mark.parametrize("bad, says", [
    (None, "kind 'scene' or 'backend'"),
    ({"kind": "robot"}, "kind 'scene' or 'backend'"),
    ({"kind": "scene", "task": "lift_cube"}, "target 'scene' is missing or mistypes 'spec'"),
    ({"kind": "backend"}, "target 'backend' is missing or mistypes 'backend'"),
])
def test_a_malformed_boot_target_is_one_config_error(bad, says):
    with pytest.raises(ConfigError, match=says) as err:
        target_from_json(bad)
    assert "\n" not in str(err.value)
