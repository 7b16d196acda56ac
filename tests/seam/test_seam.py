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


def test_a_task_publishes_its_props_sizes_in_the_spec_for_privileged_experts(panda_spec):
    """The bowl-and-plate expert reads the bowl's and plate's sizes from ``spec.task.geometry`` (policies
    know only the seam); the sizes are the scene's own and cross the JSON boundary."""
    import dataclasses
    import json

    from simseam.policies.scripted import BowlPlateExpert
    from simseam.scene.manifest_scene import ManifestScene
    from simseam.scene.tasks.bowl_plate import BOWL_HEIGHT, BOWL_WALL_R, PLATE_HALF_H
    from simseam.seam import RolloutSpec

    scene = ManifestScene(panda_spec, "bowl_plate", "mujoco")
    try:
        spec = RolloutSpec.from_json(json.loads(json.dumps(scene.spec.to_json())))
    finally:
        scene.close()
    assert dict(spec.task.geometry) == {"bowl_wall_radius": BOWL_WALL_R, "bowl_height": BOWL_HEIGHT,
                                        "plate_height": 2 * PLATE_HALF_H}
    expert = BowlPlateExpert(spec, np.eye(3))
    assert (expert.wall_r, expert.bowl_h, expert.plate_h) == (BOWL_WALL_R, BOWL_HEIGHT, 2 * PLATE_HALF_H)
    bare = dataclasses.replace(spec, task=dataclasses.replace(spec.task, geometry=()))
    with pytest.raises(ConfigError, match="task 'bowl_plate' publishes no size 'bowl_wall_radius'"):
        BowlPlateExpert(bare, np.eye(3))


def test_matrix_to_rpy_inverts_rpy_to_matrix():
    from simseam.math3d import matrix_to_rpy, rpy_to_matrix

    rng = np.random.default_rng(0)
    for rpy in [*rng.uniform([-np.pi, -1.5, -np.pi], [np.pi, 1.5, np.pi], (50, 3)), (0.3, np.pi / 2, 0.2)]:
        np.testing.assert_allclose(rpy_to_matrix(matrix_to_rpy(rpy_to_matrix(rpy))), rpy_to_matrix(rpy), atol=1e-9)


def test_the_union_of_requests_asks_for_what_any_asks_for():
    from simseam.seam import STATE_ONLY, ObsRequest

    assert ObsRequest.union([STATE_ONLY, STATE_ONLY]) == STATE_ONLY
    assert ObsRequest.union([STATE_ONLY, None]) is None  # None: everything
    both = ObsRequest.union([ObsRequest(images=frozenset({"a"}), depth=False),
                             ObsRequest(images=frozenset({"b"}), depth=False, link_poses=True)])
    assert both == ObsRequest(images=frozenset({"a", "b"}), depth=False, link_poses=True)
    assert ObsRequest.union([STATE_ONLY, ObsRequest.full()]).images is None
