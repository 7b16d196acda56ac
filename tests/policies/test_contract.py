"""Skill contracts: every mismatch between a policy and a scene, listed with its fix."""

import json

import pytest

from simseam.policies.contract import SKILL_FILE, SkillContract, check_contract, contract_mismatches
from simseam.seam import ConfigError, ControlMode
from spec_factory import make_spec


def _scene(**kw):
    return make_spec(**kw)


FITS = SkillContract(name="act", action_dim=7, control_mode=ControlMode.CARTESIAN_DELTA, state_dim=8,
                     images={"camera1": (96, 96), "camera2": (96, 96)}, control_hz=20.0)


def test_a_fitting_contract_passes():
    assert contract_mismatches(FITS, _scene()) == []
    check_contract(FITS, _scene())


def test_every_mismatch_is_listed_once_with_its_fix():
    scene = _scene(control_mode=ControlMode.JOINT_POSITION, action_dim=8, state_dim=9, control_hz=10.0,
                   cameras={"camera1": (256, 256)})
    with pytest.raises(ConfigError) as err:
        check_contract(FITS, scene)
    text = str(err.value)
    assert "6 mismatches" in text
    assert "image 'camera1'" in text and "expects 96x96, the scene renders 256x256" in text
    assert "`image_size: [96, 96]`" in text
    assert "scene camera 'camera2' but the scene has none" in text and "camera1 (256x256)" in text
    assert "state: the policy expects 8-D, the scene provides 9-D" in text
    assert "`control_mode: cartesian_delta`" in text
    assert "the policy emits 7-D actions, the scene takes 8-D" in text
    assert "`control_hz: 20`" in text


def test_image_map_feeds_policy_images_from_other_cameras():
    c = SkillContract(name="p", images={"top": (96, 96), "wrist": (96, 96)},
                      image_map={"top": "camera1", "wrist": "camera2"})
    assert contract_mismatches(c, _scene()) == []
    assert c.scene_key("top") == "camera1" and c.scene_key("other") == "other"


def test_unknown_fields_are_not_checked():
    assert contract_mismatches(SkillContract(name="any"), _scene()) == []


def test_json_round_trip_and_file(tmp_path):
    assert SkillContract.from_json(FITS.to_json()) == FITS
    FITS.save(tmp_path)
    assert SkillContract.load(tmp_path) == FITS
    assert SkillContract.load(tmp_path / "nowhere") is None


@pytest.mark.parametrize("doc, field", [
    ([], "expected a JSON object"),
    ({"action_dim": -1}, "action_dim"),
    ({"action_dim": True}, "action_dim"),
    ({"images": {"cam": [96]}}, "images.cam"),
    ({"images": [1, 2]}, "images must map"),
    ({"image_map": {"a": 3}}, "image_map"),
    ({"control_mode": "teleport"}, "unknown control mode"),
    ({"control_hz": 0}, "control_hz"),
    ({"env_state_dim": "7"}, "env_state_dim"),
    ({"surprise": 1}, "unknown field(s) surprise"),
])
def test_malformed_documents_name_the_field(doc, field):
    with pytest.raises(ConfigError, match="skill contract|control mode"):
        SkillContract.from_json(doc)
    with pytest.raises(ConfigError) as err:
        SkillContract.from_json(doc)
    assert field in str(err.value)


def test_unreadable_file_names_its_path(tmp_path):
    (tmp_path / SKILL_FILE).write_text("{not json")
    with pytest.raises(ConfigError, match=SKILL_FILE):
        SkillContract.load(tmp_path)
    (tmp_path / SKILL_FILE).write_text(json.dumps({"state_dim": "eight"}))
    with pytest.raises(ConfigError, match="state_dim"):
        SkillContract.load(tmp_path)


def test_a_policy_of_object_state_needs_a_scene_that_observes_it():
    reads = SkillContract(name="state", state_dim=8, action_dim=7, env_state_dim=7)
    assert contract_mismatches(reads, _scene(env_state_dim=7)) == []
    [missing] = contract_mismatches(reads, _scene())
    assert "environment_state: the policy reads 7-D object state, the scene provides none" in missing
    assert "`environment_state: true`" in missing
    [other] = contract_mismatches(reads, _scene(env_state_dim=14))
    assert "provides 14-D" in other and "the task the policy was trained on" in other
    # a policy that reads no object state fits a scene that offers it
    assert contract_mismatches(FITS, _scene(env_state_dim=7)) == []
    assert SkillContract.from_json(reads.to_json()) == reads
