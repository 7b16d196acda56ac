"""LIBERO's scripted expert (``--policy scripted``): its goal from LIBERO's parsed BDDL problem, its grasp
geometry on given poses, and whole episodes through ``simseam eval`` on init states it was not tuned on
(it was tuned on init states 0-9; benchmarks/libero_expert_cpu.py measured it on 10-29: 95.5 % and 100 %)."""

from __future__ import annotations

import json
import math

import numpy as np
import pytest
from backend_util import backend_python
from test_benchmark_cli import simseam

from simseam.backends.libero_expert import Facts, Goal, PickPlaceExpert, Poses, goal_of, rot_z
from simseam.seam import ConfigError

pytestmark = pytest.mark.backends

OBJECTS = {"akita_black_bowl_1", "plate_1", "alphabet_soup_1", "basket_1"}
REGIONS = {"basket_1_contain_region": "basket_1", "wooden_cabinet_1_top_region": "wooden_cabinet_1"}


def test_the_goal_comes_from_the_parsed_bddl_and_an_unhandled_one_names_task_and_predicate():
    assert goal_of("t", [["on", "akita_black_bowl_1", "plate_1"]], OBJECTS, REGIONS) == \
        Goal("on", "akita_black_bowl_1", "plate_1", "plate_1")
    assert goal_of("t", [["In", "alphabet_soup_1", "basket_1_contain_region"]], OBJECTS, REGIONS) == \
        Goal("in", "alphabet_soup_1", "basket_1_contain_region", "basket_1")
    cases = {
        "(open wooden_cabinet_1_middle_region)": [["open", "wooden_cabinet_1_middle_region"]],
        "(turnon flat_stove_1)": [["turnon", "flat_stove_1"]],
        "(in alphabet_soup_1 basket_1_contain_region) (in akita_black_bowl_1 basket_1_contain_region)": [
            ["in", "alphabet_soup_1", "basket_1_contain_region"],
            ["in", "akita_black_bowl_1", "basket_1_contain_region"]],
        "(in akita_black_bowl_1 wooden_cabinet_1_top_region)": [
            ["in", "akita_black_bowl_1", "wooden_cabinet_1_top_region"]],
    }
    for shown, goal in cases.items():
        with pytest.raises(ConfigError) as err:
            goal_of("libero_goal/0 (open the middle drawer)", goal, OBJECTS, REGIONS)
        msg = str(err.value)
        assert "\n" not in msg and msg.startswith("libero_goal/0 (open the middle drawer): ") and shown in msg, msg


def _expert(lo, hi) -> PickPlaceExpert:
    plate = (np.array([-0.07, -0.07, 0.0]), np.array([0.07, 0.07, 0.02]))
    facts = Facts(obj_box=(np.array(lo), np.array(hi)), holder_box=plate,
                  region_half=None, closing_axis=np.array([0.0, 1.0, 0.0]), max_translation=0.05, max_rotation=0.5)
    return PickPlaceExpert(Goal("on", "o", "p", "p"), facts)


def _poses(obj_pos, obj_rot=np.eye(3)) -> Poses:
    down = np.diag([1.0, -1.0, -1.0])  # gripper pointing down, fingers closing along world y
    return Poses(eef_pos=np.array([-0.2, 0.0, 1.2]), eef_rot=down, opening=0.08, obj_pos=np.array(obj_pos),
                 obj_rot=obj_rot, holder_pos=np.array([0.1, 0.2, 0.9]), holder_rot=np.eye(3), region_pos=None,
                 region_rot=None)


def test_the_grasp_crosses_a_narrow_object_and_takes_a_wide_ones_rim_facing_the_start():
    """No other objects around: a long box is held across its short side, nearer the robot; a bowl by its rim
    on the side facing the gripper's start."""
    box = _expert([-0.04, -0.02, -0.03], [0.04, 0.02, 0.03])  # 8 x 4 cm, turned 90 degrees about z
    p = _poses([0.0, 0.1, 0.93], rot_z(math.pi / 2))
    box.act(p)
    point, yaw = box._grasp_plan(p)
    # 3 cm below the 6 cm top, 2 cm off the centre along the long side, towards the gripper's start (-0.2, 0)
    np.testing.assert_allclose(point, [0.0, 0.08, 0.93], atol=1e-9)
    closing = rot_z(yaw) @ p.eef_rot @ box.facts.closing_axis
    assert abs(closing @ (rot_z(math.pi / 2) @ [0.0, 1.0, 0.0])) == pytest.approx(1.0)  # across the 4 cm side
    bowl = _expert([-0.055, -0.055, 0.0], [0.055, 0.055, 0.05])  # 11 cm wide: wider than the fingers open
    p = _poses([0.1, 0.0, 0.9])
    bowl.act(p)
    point, yaw = bowl._grasp_plan(p)
    np.testing.assert_allclose(point, [0.1 - 0.055 + 0.012, 0.0, 0.93], atol=1e-9)  # the rim facing the start
    closing = rot_z(yaw) @ p.eef_rot @ bowl.facts.closing_axis
    assert abs(closing @ [1.0, 0.0, 0.0]) == pytest.approx(1.0)  # across the rim, radially
    a = bowl.act(p)
    assert a.shape == (7,) and a[6] == -1.0 and a[0] > 0 and np.all(np.abs(a) <= 1.0)  # open, towards the hover


def test_a_rim_grasp_avoids_a_neighbour_where_the_outer_finger_would_land_and_a_side_that_failed():
    import dataclasses

    bowl = _expert([-0.055, -0.055, 0.0], [0.055, 0.055, 0.05])
    ramekin = (np.array([0.0, -0.05, 0.9]), np.array([0.03, 0.05, 0.945]))  # against the bowl's side facing the start
    p = dataclasses.replace(_poses([0.1, 0.0, 0.9]), obstacles=[ramekin])
    bowl.act(p)
    point, _ = bowl._grasp_plan(p)
    side = (point[:2] - [0.1, 0.0]) / np.linalg.norm(point[:2] - [0.1, 0.0])
    finger = point[:2] + 0.04 * side
    assert not (ramekin[0][0] - 0.01 < finger[0] < ramekin[1][0] + 0.01 and abs(finger[1]) < 0.06), (point, side)
    low = (np.array([0.0, -0.05, 0.88]), np.array([0.03, 0.05, 0.895]))  # below the fingertips: no obstacle
    p = dataclasses.replace(p, obstacles=[low])
    np.testing.assert_allclose(bowl._grasp_plan(p)[0][:2], [0.1 - 0.043, 0.0], atol=1e-9)
    bowl._failed.append(np.array([1.0, 0.0, 0.0]))  # a grasp closing along x failed: that side is avoided now
    point, _ = bowl._grasp_plan(p)
    side = (point[:2] - [0.1, 0.0]) / np.linalg.norm(point[:2] - [0.1, 0.0])
    assert abs(side[0]) <= 0.8, (point, side)  # at least ~37 degrees off the failed closing axis


@pytest.mark.parametrize("task, seeds", [("libero_spatial/0", (10, 11)), ("libero_object/3", (10, 11))])
def test_the_expert_succeeds_on_held_out_init_states_through_eval(tmp_path, task, seeds):
    backend_python("libero")
    out = tmp_path / "eval"
    proc = simseam("eval", task.split("/")[0], "--policy", "scripted", "--tasks", task, "--seed", str(seeds[0]),
                   "--episodes", str(len(seeds)), "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    episodes = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
    assert sorted((e["task"], e["seed"]) for e in episodes) == [(task, s) for s in seeds]  # in the order they end
    limit = {"libero_spatial": 220, "libero_object": 280}[task.split("/")[0]]
    assert all(e["success"] and e["steps"] < limit for e in episodes), episodes
    spec = json.loads((out / "spec.json").read_text())
    assert "privileged" in spec["capabilities"] and "expert_action" in spec["observation"]


def test_a_goal_the_expert_does_not_handle_is_a_one_line_error_naming_task_and_predicate(tmp_path):
    backend_python("libero")
    out = tmp_path / "eval"
    proc = simseam("eval", "libero_goal", "--policy", "scripted", "--tasks", "libero_goal/0", "--episodes", "1",
                   "--out", str(out))
    assert proc.returncode == 2, proc.stderr[-3000:]
    lines = [ln for ln in proc.stderr.splitlines() if ln.strip()]
    assert len(lines) == 1, proc.stderr
    assert "libero_goal/0" in lines[0] and "(open wooden_cabinet_1_middle_region)" in lines[0], lines[0]
    assert not out.exists() or not any(out.iterdir())


def test_collect_records_the_experts_demonstration_from_a_libero_scene(tmp_path):
    """``simseam collect --policy scripted`` on scenes/libero_spatial.yaml (libero_spatial/3), held-out init state 10."""
    backend_python("libero")
    out = tmp_path / "demos"
    proc = simseam("collect", "--scene", "scenes/libero_spatial.yaml", "--policy", "scripted", "--episodes", "1",
                   "--seed", "10", "--no-cameras", "--out", str(out))
    assert proc.returncode == 0, proc.stderr[-3000:]
    assert "(1/1 episodes succeeded)" in proc.stdout, proc.stdout[-2000:]
    info = json.loads((out / "meta" / "info.json").read_text())
    assert info["total_episodes"] == 1 and 50 < info["total_frames"] < 220
    assert info["features"]["action"]["names"] == ["dx", "dy", "dz", "dax", "day", "daz", "grip"]
