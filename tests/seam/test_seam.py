"""The seam contract: action validation, control modes, error hierarchy."""

import numpy as np
import pytest

from simseam.seam import (
    BackendUnavailableError,
    ConfigError,
    ControlMode,
    InvalidActionError,
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


def test_rollout_spec_json_is_plain_and_round_trips(lift):
    import json

    from simseam.seam import RolloutSpec

    spec = lift.spec
    j = json.loads(json.dumps(spec.to_json()))  # plain JSON types only
    assert j["action"]["control_mode"] == "cartesian_delta" and j["observation"]["images"]["entries"] == {}
    assert [s["name"] for s in j["action"]["slots"]] == ["dx", "dy", "dz", "dax", "day", "daz", "grip"]
    assert RolloutSpec.from_json(j) == spec
    with pytest.raises(ConfigError, match="rollout spec: missing field 'task'"):
        RolloutSpec.from_json({k: v for k, v in j.items() if k != "task"})
