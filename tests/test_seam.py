"""The seam contract: action validation, control modes, error hierarchy."""

import numpy as np
import pytest

from simseam.seam import (
    BackendUnavailableError,
    ConfigError,
    ControlMode,
    InvalidActionError,
    SceneInfo,
    SidecarError,
    SimseamError,
    SimulationError,
    check_action,
)


def test_check_action_accepts_and_converts_to_float32():
    out = check_action([0.1, -1.0, 2.0], 3)
    assert out.dtype == np.float32 and out.tolist() == pytest.approx([0.1, -1.0, 2.0])


@pytest.mark.parametrize("bad, fragment", [
    (np.zeros(6), "shape (6,), expected (7,)"),
    (np.zeros((1, 7)), "shape (1, 7)"),
    (np.array([0, 0, np.nan, 0, 0, 0, 0]), "action[2] is nan"),
    (np.array([0, 0, 0, 0, 0, 0, np.inf]), "action[6] is inf"),
    (["a"] * 7, "not numeric"),
])
def test_check_action_rejects_with_culprit(bad, fragment):
    with pytest.raises(InvalidActionError) as exc:
        check_action(bad, 7)
    assert fragment in str(exc.value)


def test_control_mode_parse():
    assert ControlMode.parse("CARTESIAN_DELTA") is ControlMode.CARTESIAN_DELTA
    assert ControlMode.parse("joint_position") is ControlMode.JOINT_POSITION
    with pytest.raises(ConfigError, match="unknown control mode 'osc'"):
        ControlMode.parse("osc")


def test_error_hierarchy():
    for cls in (ConfigError, InvalidActionError, BackendUnavailableError, SimulationError, SidecarError):
        assert issubclass(cls, SimseamError)
    assert issubclass(ConfigError, ValueError) and issubclass(InvalidActionError, ValueError)


def test_scene_info_json_is_plain():
    info = SceneInfo("r", "mujoco", "lift_cube", ControlMode.CARTESIAN_DELTA, 7, 8, 20.0,
                     {"camera1": (256, 256)}, ("j1",), ("dx",))
    j = info.to_json()
    assert j["control_mode"] == "cartesian_delta" and j["cameras"] == {"camera1": [256, 256]}
