"""The reach task: a seeded, reachable target pose for the tool frame; success within 2 cm and 10 degrees."""

import math

import numpy as np
import pytest

from simseam.math3d import quat_to_matrix, rotation_error
from simseam.scene.tasks.reach import MIN_HEIGHT, MIN_TRAVEL, POS_TOL, ROT_TOL


def test_target_is_seeded_reachable_and_away_from_home(panda_spec, make_scene):
    scene = make_scene(panda_spec, task="reach", render_images=False, privileged=True, control_mode="joint_position")
    targets = []
    for seed in (0, 1, 0):
        obs = scene.reset(seed)
        targets.append(obs["privileged"]["objects"]["target"].copy())
        home = obs["privileged"]["eef_pose"]
        t = targets[-1]
        assert t[2] >= MIN_HEIGHT and np.linalg.norm(t[:3] - home[:3]) >= MIN_TRAVEL - 0.005
    np.testing.assert_array_equal(targets[0], targets[2])
    assert np.linalg.norm(targets[0][:3] - targets[1][:3]) > 1e-3
    assert scene.spec.task.diagnostics == ("position_error", "orientation_error")
    assert "target" in scene.spec.observation.fields["privileged"].entries["objects"].entries


def test_success_means_within_2cm_and_10_degrees(panda_spec, make_scene):
    """Drive with the IK's own solution; success exactly when both measured errors are inside the tolerances."""
    scene = make_scene(panda_spec, task="reach", render_images=False, privileged=True, control_mode="joint_position")
    obs = scene.reset(3)
    target = obs["privileged"]["objects"]["target"]
    q = obs["joint_positions"][:7].astype(np.float64)
    sol = scene.chain.solve(q, target[:3], quat_to_matrix(target[3:]), max_iters=300)
    assert sol.pos_error < 1e-3
    step = None
    for _ in range(60):
        step = scene.step(scene.spec.action.pack(arm=sol.q, grip=-1.0))
        eef = step.observation["privileged"]["eef_pose"]
        pos, rot = eef[:3], quat_to_matrix(eef[3:])
        e_pos = float(np.linalg.norm(pos - target[:3]))
        e_rot = float(np.linalg.norm(rotation_error(quat_to_matrix(target[3:]), rot)))
        d = step.info["diagnostics"]
        assert d["position_error"] == pytest.approx(e_pos, abs=1e-4)
        assert d["orientation_error"] == pytest.approx(e_rot, abs=1e-3)
        assert step.info["success"] == (e_pos < POS_TOL and e_rot < ROT_TOL)
        if step.terminated:
            break
    assert step.terminated and step.reward == 1.0
    assert ROT_TOL == pytest.approx(math.radians(10)) and POS_TOL == 0.02
