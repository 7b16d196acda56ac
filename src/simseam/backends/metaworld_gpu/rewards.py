"""Meta-World v3's 50 reward and success rules as batched task code: ``TASK_REWARDS[env_name](state)``.

Each function judges N worlds of one task after a step, as that task's ``evaluate_state`` judges one:
``BatchEvaluation.reward`` float[N] (Meta-World's reward), ``.success`` bool[N] (``info["success"]``)
and ``.diagnostics`` with every key of Meta-World's info dict (``DIAGNOSTICS``) as float[N] (a flag is
1.0 / 0.0, as ``float(info[k])`` reads it). The rules are the benchmark's spec (read in Meta-World's
``envs/sawyer_*_v3.py``, reward version ``v2``, the default); the code is written here against the NumPy
API subset of ``simseam.scene.tasks.batch`` with ``state.xp`` (NumPy on the CPU, CuPy on a CUDA device),
one row per world, with no Python branching per world.

``state`` is a ``MetaWorldState`` (``state.py``): ``obs`` (the clipped observation ``evaluate_state``
receives), ``action`` (as passed to ``step``), ``tcp_center``, ``left_pad`` / ``right_pad``, name lookups
(``site_pos``, ``body_pos``, ``qpos``), ``touching_object`` and ``params``, the reset attributes each task
reads (``TASK_PARAMS``), stacked per world.

Where Meta-World's attribute is not what its name says, the batched rule reads what the native env
actually computes with:

- ``init_left_pad`` / ``init_right_pad`` are views of the pads' live positions (``get_body_com`` returns
  MuJoCo's ``xpos``, not a copy): every caging margin measured "from the initial pad" uses the pad's
  current position (``state.left_pad`` / ``state.right_pad``), and door-lock's reach margin equals its
  reach distance;
- basketball's ``_target_pos`` is a view of the ``goal`` site's position, bin-picking's of the
  ``bin_goal`` body's, door-lock's and door-unlock's ``obj_init_pos`` of the ``lock_link`` body's: they
  are read live (``site_pos`` / ``body_pos``), not from ``params``;
- bin-picking's in-place margin (``_target_to_obj_init``) is set by its first judgement after a reset
  (``None`` before): ``params["_target_to_obj_init"]`` is NaN at reset, and the function writes the
  first distance into it (the one entry a rule carries across steps).
"""

from __future__ import annotations

from math import pi
from typing import Any, Callable

from simseam.backends.metaworld_gpu.reward_utils import (
    caging,
    caging_gripping,
    caging_pick_place,
    clamp_grip,
    hamacher,
    norm,
    rect_prism,
    tolerance,
    vec,
)
from simseam.scene.tasks.batch import BatchEvaluation

DIAGNOSTICS = ("success", "near_object", "grasp_success", "grasp_reward", "in_place_reward", "obj_to_target",
               "unscaled_reward")
#: Meta-World's default ``TARGET_RADIUS`` (``SawyerXYZEnv``), which several tasks read through ``self``
BASE_TARGET_RADIUS = 0.05
#: the main object geoms whose contact with both finger pads ``grasp_success`` reads
OBJ_GEOM, MUG_GEOM = "objGeom", "mug"


def _judged(xp, reward, success, *, near_object, grasp_success, grasp_reward, in_place_reward,
            obj_to_target) -> BatchEvaluation:
    """One task's judgement: every diagnostic as float[N] of the reward's dtype."""
    zero = xp.zeros_like(reward)
    diag = {"success": zero + success, "near_object": zero + near_object, "grasp_success": zero + grasp_success,
            "grasp_reward": zero + grasp_reward, "in_place_reward": zero + in_place_reward,
            "obj_to_target": zero + obj_to_target, "unscaled_reward": reward}
    return BatchEvaluation(reward=reward, success=success, diagnostics=diag)


def _split(state) -> tuple[Any, Any, Any, Any]:
    """(xp, hand float[N, 3], gripper opening float[N], first object float[N, 3]) of the observation."""
    obs = state.obs
    return state.xp, obs[:, :3], obs[:, 3], obs[:, 4:7]


def _p(state, name: str) -> Any:
    return state.params[name]


def _action_term(xp, state, like, fn) -> Any:
    """A term of the action computed in the action's dtype (as Meta-World computes it), then cast."""
    return fn(state.action[:, 3]).astype(like.dtype)


def _log_floor(xp, radius, threshold: float, scale: float, offset: float) -> Any:
    """``scale * log(radius - threshold) + offset`` beyond ``threshold``, else 0 (a height to stay above)."""
    beyond = radius > threshold
    return xp.where(beyond, scale * xp.log(xp.where(beyond, radius - threshold, 1)) + offset, 0)


def _above_floor(xp, z, floor, margin) -> Any:
    """1 at or above ``floor``, else tolerance of how far below (Meta-World's ``above_floor``)."""
    return xp.where(z >= floor, 1, tolerance(xp, xp.maximum(floor - z, 0), 0.0, 0.01, margin))


def _threshed(xp, hand, obj, half_length: float) -> Any:
    """The object's position with x taken from the hand when they are within ``half_length`` in x."""
    close = xp.abs(obj[:, 0] - hand[:, 0]) < half_length
    return xp.stack([xp.where(close, hand[:, 0], obj[:, 0]), obj[:, 1], obj[:, 2]], axis=-1)


def _quat_reward(xp, obs, ideal, scale: float) -> Any:
    return xp.maximum(1.0 - norm(xp, obs[:, 7:11] - vec(xp, obs, ideal)) / scale, 0.0)


# ------------------------------------------------------------------------------------------ reach
def reach(state, wall: bool = False) -> BatchEvaluation:
    """reach-v3 / reach-wall-v3: the tool centre within 5 cm of the goal."""
    xp, _, _, _ = _split(state)
    target = _p(state, "_target_pos")
    dist = norm(xp, state.tcp_center - target)
    in_place = tolerance(xp, dist, 0, 0.05, norm(xp, _p(state, "hand_init_pos") - target))
    reward = 10 * in_place
    if wall:
        return _judged(xp, reward, dist <= 0.05, near_object=0.0, grasp_success=0.0, grasp_reward=0.0,
                       in_place_reward=in_place, obj_to_target=dist)
    return _judged(xp, reward, dist <= 0.05, near_object=dist, grasp_success=1.0, grasp_reward=dist,
                   in_place_reward=in_place, obj_to_target=dist)


# ------------------------------------------------------------------------------- pick and place
def pick_place(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    to_target = norm(xp, obj - target)
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    in_place = tolerance(xp, to_target, 0, 0.05, norm(xp, init - target))
    grasped = caging_pick_place(xp, state, obj)
    reward = hamacher(xp, grasped, in_place)
    lifted = (tcp_to_obj < 0.02) & (opened > 0) & (obj[:, 2] - 0.01 > init[:, 2])
    reward = xp.where(lifted, reward + (1.0 + 5.0 * in_place), reward)
    reward = xp.where(to_target < 0.05, 10.0, reward)
    grasp = state.touching_object(OBJ_GEOM) & (opened > 0) & (obj[:, 2] - 0.02 > init[:, 2])
    return _judged(xp, reward, to_target <= 0.07, near_object=tcp_to_obj <= 0.03, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=in_place, obj_to_target=to_target)


def pick_place_wall(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    midpoint = xp.stack([target[:, 0], xp.zeros_like(opened) + 0.77, xp.zeros_like(opened) + 0.25], axis=-1)
    scale = vec(xp, obj, [1.0, 1.0, 3.0])
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    to_mid = norm(xp, (obj - midpoint) * scale)
    to_mid_init = norm(xp, (init - midpoint) * scale)
    to_target = norm(xp, obj - target)
    part1 = tolerance(xp, to_mid, 0, 0.05, to_mid_init)
    part2 = tolerance(xp, to_target, 0, 0.05, norm(xp, init - target))
    grasped = caging(xp, state, obj, init, obj_radius=0.015, pad_thresh=0.05, reach_radius=0.01, xz_thresh=0.005)
    both = hamacher(xp, grasped, part1)
    lifted = (tcp_to_obj < 0.02) & (opened > 0) & (obj[:, 2] - 0.015 > init[:, 2])
    over = xp.where(obj[:, 1] > 0.75, both + 1.0 + 4.0 + 3.0 * part2, both + 1.0 + 4.0 * part1)
    reward = xp.where(lifted, over, both)
    reward = xp.where(to_target < 0.05, 10.0, reward)
    grasp = state.touching_object(OBJ_GEOM) & (opened > 0) & (obj[:, 2] - 0.02 > init[:, 2])
    return _judged(xp, reward, to_target <= 0.07, near_object=tcp_to_obj <= 0.03, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=part2, obj_to_target=to_target)


def shelf_place(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    to_target = norm(xp, obj - target)
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    in_place = tolerance(xp, to_target, 0, 0.05, norm(xp, init - target))
    grasped = caging(xp, state, obj, init, obj_radius=0.02, pad_thresh=0.05, reach_radius=0.01, xz_thresh=0.01)
    reward = hamacher(xp, grasped, in_place)
    x, y, z = obj[:, 0], obj[:, 1], obj[:, 2]
    tx, ty = target[:, 0], target[:, 1]
    below = (0.0 < z) & (z < 0.24) & (tx - 0.15 < x) & (x < tx + 0.15)
    front = below & (ty - 3 * 0.05 < y) & (y < ty)
    z_scaling = (0.24 - z) / 0.24
    y_scaling = (y - (ty - 3 * 0.05)) / (3 * 0.05)
    loss = hamacher(xp, y_scaling, z_scaling)
    in_place = xp.where(front, xp.clip(in_place - loss, 0.0, 1.0), in_place)
    in_place = xp.where(below & (y > ty), 0.0, in_place)
    lifted = (tcp_to_obj < 0.025) & (opened > 0) & (z - 0.01 > init[:, 2])
    reward = xp.where(lifted, reward + (1.0 + 5.0 * in_place), reward)
    reward = xp.where(to_target < 0.05, 10.0, reward)
    grasp = state.touching_object(OBJ_GEOM) & (opened > 0) & (z - 0.02 > init[:, 2])
    return _judged(xp, reward, to_target <= 0.07, near_object=tcp_to_obj <= 0.03, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=in_place, obj_to_target=to_target)


def basketball(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    init = _p(state, "obj_init_pos")
    goal = state.site_pos("goal")  # Meta-World's _target_pos is a view of this site's position
    target = xp.stack([goal[:, 0], goal[:, 1], xp.zeros_like(opened) + 0.3], axis=-1)
    scale = vec(xp, obj, [1.0, 1.0, 2.0])
    to_target = norm(xp, (obj - target) * scale)
    in_place = tolerance(xp, to_target, 0, 0.08, norm(xp, (init - target) * scale))
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    grasped = caging(xp, state, obj, init, obj_radius=0.025, pad_thresh=0.06, reach_radius=0.01,
                     xz_thresh=0.005, density="high")
    lifted = (tcp_to_obj < 0.035) & (opened > 0) & (obj[:, 2] - 0.01 > init[:, 2])
    grasped = xp.where(lifted, 1.0, grasped)
    reward = hamacher(xp, grasped, in_place)
    reward = xp.where(lifted, reward + (1.0 + 5.0 * in_place), reward)
    reward = xp.where(to_target < 0.08, 10.0, reward)
    grasp = (opened > 0) & (obj[:, 2] - 0.03 > init[:, 2])
    return _judged(xp, reward, to_target <= 0.08, near_object=tcp_to_obj <= 0.05, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=in_place, obj_to_target=to_target)


def bin_picking(state) -> BatchEvaluation:
    xp, hand, opened, obj = _split(state)
    init = _p(state, "obj_init_pos")
    target = state.body_pos("bin_goal")  # Meta-World's _target_pos is a view of this body's position
    to_target = norm(xp, obj - target)
    first = _p(state, "_target_to_obj_init")
    first = xp.where(xp.isnan(first), to_target, first)
    state.params["_target_to_obj_init"] = first
    in_place = tolerance(xp, to_target, 0, BASE_TARGET_RADIUS, first)
    floor = xp.minimum(_log_floor(xp, norm(xp, hand[:, :2] - init[:, :2]), 0.03, 0.02, 0.2),
                       _log_floor(xp, norm(xp, hand[:, :2] - target[:, :2]), 0.03, 0.02, 0.2))
    above = _above_floor(xp, hand[:, 2], floor, 0.05)
    grasped = caging(xp, state, obj, init, obj_radius=0.015, pad_thresh=0.05, reach_radius=0.01,
                     xz_thresh=0.01, effort=0.7, density="high")
    reward = hamacher(xp, grasped, in_place)
    near = norm(xp, obj - hand) < 0.04
    grasp = near & (obj[:, 2] - 0.02 > init[:, 2]) & ~(opened < 0.43)
    reward = xp.where(grasp, reward + (1.0 + 5.0 * hamacher(xp, above, in_place)), reward)
    reward = xp.where(to_target < BASE_TARGET_RADIUS, 10.0, reward)
    return _judged(xp, reward, to_target <= 0.05, near_object=near, grasp_success=grasp, grasp_reward=grasped,
                   in_place_reward=in_place, obj_to_target=to_target)


def pick_out_of_hole(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    tcp = state.tcp_center
    to_target = norm(xp, obj - target)
    tcp_to_obj = norm(xp, obj - tcp)
    floor = _log_floor(xp, norm(xp, tcp[:, :2] - init[:, :2]), 0.03, 0.015, 0.15)
    above = _above_floor(xp, tcp[:, 2], floor, 0.02)
    grasped = caging(xp, state, obj, init, obj_radius=0.015, pad_thresh=0.02, reach_radius=0.01,
                     xz_thresh=0.03, effort=0.1, density="high")
    in_place = tolerance(xp, to_target, 0, 0.02, norm(xp, init - target))
    reward = hamacher(xp, grasped, in_place)
    grasp = (tcp_to_obj < 0.04) & (obj[:, 2] - 0.02 > init[:, 2]) & ~(opened < 0.33)
    reward = xp.where(grasp, reward + (1.0 + 5.0 * hamacher(xp, in_place, above)), reward)
    reward = xp.where(to_target < BASE_TARGET_RADIUS, 10.0, reward)
    return _judged(xp, reward, to_target <= 0.07, near_object=tcp_to_obj <= 0.03, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=in_place, obj_to_target=to_target)


def hand_insert(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    to_target = norm(xp, obj - target)
    in_place = tolerance(xp, to_target, 0, 0.05, norm(xp, init - target))
    grasped = caging(xp, state, obj, init, obj_radius=0.015, pad_thresh=0.05, reach_radius=0.01,
                     xz_thresh=0.005, density="high")
    reward = hamacher(xp, grasped, in_place)
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    reward = xp.where((tcp_to_obj < 0.02) & (opened > 0), reward + (1.0 + 7.0 * in_place), reward)
    reward = xp.where(to_target < 0.05, 10.0, reward)
    grasp = state.touching_object(OBJ_GEOM) & (opened > 0) & (obj[:, 2] - 0.02 > init[:, 2])
    return _judged(xp, reward, to_target <= 0.05, near_object=tcp_to_obj <= 0.03, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=in_place, obj_to_target=to_target)


def peg_insert_side(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    head = state.site_pos("pegHead")
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    scale = vec(xp, obj, [1.0, 2.0, 2.0])
    to_target = norm(xp, (head - target) * scale)
    in_place = tolerance(xp, to_target, 0, 0.07, norm(xp, (_p(state, "peg_head_pos_init") - target) * scale))
    box1 = rect_prism(xp, head, state.site_pos("bottom_right_corner_collision_box_1"),
                      state.site_pos("top_left_corner_collision_box_1"))
    box2 = rect_prism(xp, head, state.site_pos("bottom_right_corner_collision_box_2"),
                      state.site_pos("top_left_corner_collision_box_2"))
    in_place = hamacher(xp, in_place, hamacher(xp, box2, box1))
    grasped = caging(xp, state, obj, init, obj_radius=0.0075, pad_thresh=0.03, reach_radius=0.01,
                     xz_thresh=0.005, density="high")
    lifted = (tcp_to_obj < 0.08) & (opened > 0) & (obj[:, 2] - 0.01 > init[:, 2])
    grasped = xp.where(lifted, 1.0, grasped)
    reward = hamacher(xp, grasped, in_place)
    reward = xp.where(lifted, reward + (1.0 + 5 * in_place), reward)
    reward = xp.where(to_target <= 0.07, 10.0, reward)
    grasp = (tcp_to_obj < 0.02) & (opened > 0) & (obj[:, 2] - 0.01 > init[:, 2])
    return _judged(xp, reward, to_target <= 0.07, near_object=tcp_to_obj <= 0.03, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=in_place, obj_to_target=to_target)


def peg_unplug_side(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    to_target = norm(xp, obj - target)
    grasped = caging(xp, state, obj, init, obj_radius=0.025, pad_thresh=0.05, reach_radius=0.01,
                     xz_thresh=0.005, effort=0.8, density="high")
    in_place = tolerance(xp, to_target, 0, 0.05, norm(xp, init - target))
    grasp = (opened > 0.5) & (obj[:, 0] - init[:, 0] > 0.015)
    reward = xp.where(grasp & (tcp_to_obj < 0.035), 1 + 2 * grasped + 5 * in_place, 2 * grasped)
    reward = xp.where(to_target <= 0.05, 10.0, reward)
    return _judged(xp, reward, to_target <= 0.07, near_object=tcp_to_obj <= 0.03, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=in_place, obj_to_target=to_target)


# ------------------------------------------------------------------------------------------ push
def push(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    to_target = norm(xp, obj - target)
    in_place = tolerance(xp, to_target, 0, 0.05, norm(xp, init - target))
    grasped = caging(xp, state, obj, init, obj_radius=0.015, pad_thresh=0.05, reach_radius=0.01,
                     xz_thresh=0.005, density="high")
    reward = 2 * grasped
    reward = xp.where((tcp_to_obj < 0.02) & (opened > 0), reward + (1.0 + reward + 5.0 * in_place), reward)
    reward = xp.where(to_target < 0.05, 10.0, reward)
    grasp = state.touching_object(OBJ_GEOM) & (opened > 0) & (obj[:, 2] - 0.02 > init[:, 2])
    return _judged(xp, reward, to_target <= 0.05, near_object=tcp_to_obj <= 0.03, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=in_place, obj_to_target=to_target)


def push_back(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    to_target = norm(xp, obj - target)
    to_target_init = norm(xp, init - target)
    in_place = tolerance(xp, to_target, 0, 0.05, to_target_init)
    grasped = caging_gripping(xp, state, obj, 0.007, 0.003, 0.01)
    reward = hamacher(xp, grasped, in_place)
    pushing = (tcp_to_obj < 0.01) & (0 < opened) & (opened < 0.55) & (to_target_init - to_target > 0.01)
    reward = xp.where(pushing, reward + (1.0 + 5.0 * in_place), reward)
    reward = xp.where(to_target < 0.05, 10.0, reward)
    grasp = state.touching_object(OBJ_GEOM) & (opened > 0) & (obj[:, 2] - 0.02 > init[:, 2])
    return _judged(xp, reward, to_target <= 0.07, near_object=tcp_to_obj <= 0.03, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=in_place, obj_to_target=to_target)


def push_wall(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    zero = xp.zeros_like(opened)
    midpoint = xp.stack([zero - 0.05, zero + 0.77, obj[:, 2]], axis=-1)
    scale = vec(xp, obj, [3.0, 1.0, 1.0])
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    to_target = norm(xp, obj - target)
    part1 = tolerance(xp, norm(xp, (obj - midpoint) * scale), 0, 0.05, norm(xp, (init - midpoint) * scale))
    part2 = tolerance(xp, to_target, 0, 0.05, norm(xp, init - target))
    grasped = caging(xp, state, obj, init, obj_radius=0.015, pad_thresh=0.05, reach_radius=0.01,
                     xz_thresh=0.005, density="high")
    over = xp.where(obj[:, 1] > 0.75, 2 * grasped + 1.0 + 4.0 + 3.0 * part2, 2.0 * grasped + 1.0 + 4.0 * part1)
    reward = xp.where((tcp_to_obj < 0.02) & (opened > 0), over, 2 * grasped)
    reward = xp.where(to_target < 0.05, 10.0, reward)
    grasp = state.touching_object(OBJ_GEOM) & (opened > 0) & (obj[:, 2] - 0.02 > init[:, 2])
    return _judged(xp, reward, to_target <= 0.07, near_object=tcp_to_obj <= 0.03, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=part2, obj_to_target=to_target)


def soccer(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    scale = vec(xp, obj, [3.0, 1.0, 1.0])
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    to_target = norm(xp, (obj - target) * scale)
    in_place = tolerance(xp, to_target, 0, 0.07, norm(xp, (obj - init) * scale))
    goal_line = target[:, 1] - 0.1
    wide = (obj[:, 1] > goal_line) & (xp.abs(obj[:, 0] - target[:, 0]) > 0.1)
    in_place = xp.where(wide, xp.clip(in_place - 2 * ((obj[:, 1] - goal_line) / (1 - goal_line)), 0.0, 1.0),
                        in_place)
    grasped = caging_gripping(xp, state, obj, 0.013, 0.01, 0.005)
    reward = 3 * grasped + 6.5 * in_place
    reward = xp.where(to_target < 0.07, 10.0, reward)
    dist = norm(xp, obj - target)
    grasp = state.touching_object(OBJ_GEOM) & (opened > 0) & (obj[:, 2] - 0.02 > init[:, 2])
    return _judged(xp, reward, dist <= 0.07, near_object=tcp_to_obj <= 0.03, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=in_place, obj_to_target=dist)


def sweep(state, into: bool = False) -> BatchEvaluation:
    """sweep-v3 and sweep-into-v3 (the goal at the object's height; a looser grip band)."""
    xp, _, opened, obj = _split(state)
    goal, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    target = xp.stack([goal[:, 0], goal[:, 1], obj[:, 2]], axis=-1) if into else goal
    to_target = norm(xp, obj - target)
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    in_place = tolerance(xp, to_target, 0, 0.05, norm(xp, init - target))
    grasped = caging_gripping(xp, state, obj, 0.02, 0.005 if into else 0.01, 0.01 if into else 0.005)
    reward = 2 * grasped + 6 * hamacher(xp, grasped, in_place)
    reward = xp.where(to_target < 0.05, 10.0, reward)
    grasp = state.touching_object(OBJ_GEOM) & (opened > 0)
    return _judged(xp, reward, to_target <= 0.05, near_object=tcp_to_obj <= 0.03, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=in_place, obj_to_target=to_target)


def plate_slide(state, variant: bool = True) -> BatchEvaluation:
    """plate-slide-v3 (``variant=False``) and its side / back / back-side variants: the puck into a goal."""
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    tcp = state.tcp_center
    to_target = norm(xp, obj - target)
    shrink = 0.05 if variant else 0.0
    in_place = tolerance(xp, to_target, 0, 0.05, norm(xp, init - target) - shrink)
    tcp_to_obj = norm(xp, tcp - obj)
    grasped = tolerance(xp, tcp_to_obj, 0, 0.05, norm(xp, _p(state, "init_tcp") - init) - shrink)
    if variant:
        reward = xp.where((tcp[:, 2] <= 0.03) & (tcp_to_obj < 0.07), 2.0 + 7.0 * in_place, 1.5 * grasped)
    else:
        reward = 8 * hamacher(xp, grasped, in_place)
    reward = xp.where(to_target < 0.05, 10.0, reward)
    return _judged(xp, reward, to_target <= 0.07, near_object=tcp_to_obj <= 0.03, grasp_success=0.0,
                   grasp_reward=grasped, in_place_reward=in_place, obj_to_target=to_target)


# --------------------------------------------------------------------------------------- buttons
def _button(state, axis: int, near_bound: float):
    """(xp, tcp_to_obj, obj_to_target, near, pressed) of the button tasks (pressed along ``axis``)."""
    xp, _, _, obj = _split(state)
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    near = tolerance(xp, tcp_to_obj, 0, near_bound, norm(xp, obj - _p(state, "init_tcp")))
    to_target = xp.abs(_p(state, "_target_pos")[:, axis] - obj[:, axis])
    pressed = tolerance(xp, to_target, 0, 0.005, _p(state, "_obj_to_target_init"))
    return xp, tcp_to_obj, to_target, near, pressed


def button_press_topdown(state) -> BatchEvaluation:
    """button-press-topdown-v3 and its wall variant (the same rule)."""
    xp, tcp_to_obj, to_target, near, pressed = _button(state, 2, 0.01)
    opened = state.obs[:, 3]
    reward = 5 * hamacher(xp, 1 - opened, near)
    reward = xp.where(tcp_to_obj <= 0.03, reward + 5 * pressed, reward)
    return _judged(xp, reward, to_target <= 0.024, near_object=tcp_to_obj <= 0.05, grasp_success=opened > 0,
                   grasp_reward=near, in_place_reward=pressed, obj_to_target=to_target)


def button_press(state) -> BatchEvaluation:
    xp, tcp_to_obj, to_target, near, pressed = _button(state, 1, 0.05)
    opened = state.obs[:, 3]
    reward = 2 * hamacher(xp, xp.maximum(opened, 0.0), near)
    reward = xp.where(tcp_to_obj <= 0.05, reward + 8 * pressed, reward)
    return _judged(xp, reward, to_target <= 0.02, near_object=tcp_to_obj <= 0.05, grasp_success=opened > 0,
                   grasp_reward=near, in_place_reward=pressed, obj_to_target=to_target)


def button_press_wall(state) -> BatchEvaluation:
    xp, tcp_to_obj, to_target, near, pressed = _button(state, 1, 0.01)
    opened = state.obs[:, 3]
    far = 2 * hamacher(xp, (1 - opened) / 2.0, near)
    reward = xp.where(tcp_to_obj > 0.07, far, 2 + 2 * (1 + opened) + 4 * pressed**2)
    return _judged(xp, reward, to_target <= 0.03, near_object=tcp_to_obj <= 0.05, grasp_success=opened > 0,
                   grasp_reward=near, in_place_reward=pressed, obj_to_target=to_target)


def coffee_button(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    to_target = xp.abs(_p(state, "_target_pos")[:, 1] - obj[:, 1])
    near = tolerance(xp, tcp_to_obj, 0, 0.05, norm(xp, obj - _p(state, "init_tcp")))
    pressed = tolerance(xp, to_target, 0, 0.005, 0.03)
    reward = 2 * hamacher(xp, xp.maximum(opened, 0.0), near)
    reward = xp.where(tcp_to_obj <= 0.05, reward + 8 * pressed, reward)
    return _judged(xp, reward, to_target <= 0.02, near_object=tcp_to_obj <= 0.05, grasp_success=opened > 0,
                   grasp_reward=near, in_place_reward=pressed, obj_to_target=to_target)


def coffee_mug(state) -> BatchEvaluation:
    """coffee-pull-v3 and coffee-push-v3 (the same rule): the mug to its goal."""
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    scale = vec(xp, obj, [2.0, 2.0, 1.0])
    to_target = norm(xp, (obj - target) * scale)
    in_place = tolerance(xp, to_target, 0, 0.05, norm(xp, (init - target) * scale))
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    grasped = caging(xp, state, obj, init, obj_radius=0.02, pad_thresh=0.05, reach_radius=0.04, xz_thresh=0.05,
                     effort=0.7, density="medium")
    reward = hamacher(xp, grasped, in_place)
    reward = xp.where((tcp_to_obj < 0.04) & (opened > 0), reward + (1.0 + 5.0 * in_place), reward)
    reward = xp.where(to_target < 0.05, 10.0, reward)
    dist = norm(xp, obj - target)
    grasp = state.touching_object(MUG_GEOM) & (opened > 0)
    return _judged(xp, reward, dist <= 0.07, near_object=tcp_to_obj <= 0.03, grasp_success=grasp,
                   grasp_reward=grasped, in_place_reward=in_place, obj_to_target=dist)


# ----------------------------------------------------------------------- doors, drawers, windows
def door_open(state) -> BatchEvaluation:
    xp, hand, _, obj = _split(state)
    theta = state.qpos("doorjoint")[:, 0]
    grab = _action_term(xp, state, obj, lambda a: (xp.clip(a, -1, 1) + 1.0) / 2.0)
    door = obj + vec(xp, obj, [-0.05, 0.0, 0.0])
    radius = norm(xp, hand[:, :2] - door[:, :2])
    floor = _log_floor(xp, radius, 0.12, 0.04, 0.4)
    above = xp.where(hand[:, 2] >= floor, 1, tolerance(xp, floor - hand[:, 2], 0.0, 0.01, floor / 2.0))
    handle = norm(xp, hand - door - vec(xp, obj, [0.05, 0.03, -0.01]))
    ready = hamacher(xp, above, tolerance(xp, handle, 0, 0.12 / 2.0, 0.5))
    swung = (theta < -pi / 90.0).astype(obj.dtype)
    opened = 0.2 * swung + 0.8 * tolerance(xp, pi / 2.0 + pi / 6 - (-theta), 0, 0.5, pi / 3.0)
    reward = 2.0 * hamacher(xp, ready, grab) + 8.0 * opened
    success = xp.abs(obj[:, 0] - _p(state, "_target_pos")[:, 0]) <= 0.08
    reward = xp.where(success, 10.0, reward)
    return _judged(xp, reward, success, near_object=ready, grasp_success=grab >= 0.5, grasp_reward=grab,
                   in_place_reward=opened, obj_to_target=0.0)


def door_close(state) -> BatchEvaluation:
    xp, _, _, obj = _split(state)
    target = _p(state, "_target_pos")
    tcp_to_target = norm(xp, state.tcp_center - target)
    to_target = norm(xp, obj - target)
    in_place = tolerance(xp, to_target, 0, 0.05, norm(xp, _p(state, "obj_init_pos") - target), "gaussian")
    hand_margin = norm(xp, _p(state, "hand_init_pos") - obj) + 0.1
    hand_in_place = tolerance(xp, tcp_to_target, 0, 0.25 * 0.05, hand_margin, "gaussian")
    reward = xp.where(to_target < 0.05, 10.0, 3 * hand_in_place + 6 * in_place)
    return _judged(xp, reward, to_target <= 0.08, near_object=0.0, grasp_success=1.0, grasp_reward=1.0,
                   in_place_reward=hand_in_place, obj_to_target=to_target)


def door_lock(state) -> BatchEvaluation:
    xp, _, opened, obj = _split(state)
    scale = vec(xp, obj, [0.25, 1.0, 0.5])
    tcp_to_obj = norm(xp, (obj - state.left_pad) * scale)
    # the margin is measured from init_left_pad, a view of the left pad's live position: the same distance
    near = tolerance(xp, tcp_to_obj, 0, 0.01, norm(xp, (obj - state.left_pad) * scale))
    to_target = xp.abs(_p(state, "_target_pos")[:, 2] - obj[:, 2])
    pressed = tolerance(xp, to_target, 0, 0.005, 0.1)
    reward = 2 * hamacher(xp, xp.maximum(opened, 0.0), near) + 8 * pressed
    return _judged(xp, reward, to_target <= 0.02, near_object=tcp_to_obj <= 0.05, grasp_success=opened > 0,
                   grasp_reward=near, in_place_reward=pressed, obj_to_target=to_target)


def door_unlock(state) -> BatchEvaluation:
    xp, hand, opened, lock = _split(state)
    offset, scale = vec(xp, lock, [0.0, 0.055, 0.07]), vec(xp, lock, [0.25, 1.0, 0.5])
    shoulder = norm(xp, (hand + offset - lock) * scale)
    # obj_init_pos is a view of the lock_link body's live position
    shoulder_init = norm(xp, (_p(state, "init_tcp") + offset - state.body_pos("lock_link")) * scale)
    ready = tolerance(xp, shoulder, 0, 0.02, shoulder_init)
    to_target = xp.abs(_p(state, "_target_pos")[:, 0] - lock[:, 0])
    pushed = tolerance(xp, to_target, 0, 0.005, 0.1)
    reward = 2 * ready + 8 * pushed
    return _judged(xp, reward, to_target <= 0.02, near_object=shoulder <= 0.05, grasp_success=opened > 0,
                   grasp_reward=ready, in_place_reward=pushed, obj_to_target=to_target)


def drawer_open(state) -> BatchEvaluation:
    xp, hand, opened, handle = _split(state)
    target = _p(state, "_target_pos")
    error = norm(xp, handle - target)
    opening = tolerance(xp, error, 0, 0.02, 0.2)
    handle_init = target + vec(xp, handle, [0.0, 0.2, 0.0])
    scale = vec(xp, handle, [3.0, 3.0, 1.0])
    cage_margin = norm(xp, (handle_init - _p(state, "init_tcp")) * scale)
    cage = tolerance(xp, norm(xp, (handle - hand) * scale), 0, 0.01, cage_margin)
    reward = (cage + opening) * 5.0
    return _judged(xp, reward, error <= 0.03, near_object=norm(xp, handle - hand) <= 0.03,
                   grasp_success=opened > 0, grasp_reward=cage, in_place_reward=opening, obj_to_target=error)


def _reach_and_place(state, obj, target_radius: float, reach_radius: float, kind: str):
    """(xp, tcp_to_obj, obj_to_target, reach, in_place) of drawer-close and the faucets."""
    xp = state.xp
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    to_target = norm(xp, obj - target)
    in_place = tolerance(xp, to_target, 0, target_radius, xp.abs(norm(xp, init - target) - target_radius))
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    reach_margin = xp.abs(norm(xp, init - _p(state, "init_tcp")) - reach_radius)
    reach = tolerance(xp, tcp_to_obj, 0, reach_radius, reach_margin, kind)
    return xp, tcp_to_obj, to_target, reach, in_place


def drawer_close(state) -> BatchEvaluation:
    xp, tcp_to_obj, to_target, reach, in_place = _reach_and_place(state, state.obs[:, 4:7], BASE_TARGET_RADIUS,
                                                                  0.005, "gaussian")
    reach = hamacher(xp, reach, clamp_grip(xp, state.action, to_target))
    done = to_target <= BASE_TARGET_RADIUS + 0.015
    reward = xp.where(done, 1.0, hamacher(xp, reach, in_place)) * 10
    return _judged(xp, reward, done, near_object=tcp_to_obj <= 0.01, grasp_success=1.0, grasp_reward=reach,
                   in_place_reward=in_place, obj_to_target=to_target)


def faucet(state, opening: bool) -> BatchEvaluation:
    """faucet-open-v3 (the handle read 4 cm in and 3 cm up) and faucet-close-v3."""
    obj = state.obs[:, 4:7] + vec(state.xp, state.obs, [-0.04, 0.0, 0.03] if opening else [0.0, 0.0, 0.0])
    xp, tcp_to_obj, to_target, reach, in_place = _reach_and_place(state, obj, 0.07, 0.01, "gaussian")
    reward = xp.where(to_target <= 0.07, 10.0, (2 * reach + 3 * in_place) * 2)
    return _judged(xp, reward, to_target <= 0.07, near_object=tcp_to_obj <= 0.01, grasp_success=1.0,
                   grasp_reward=reach, in_place_reward=in_place, obj_to_target=to_target)


def window(state, opening: bool) -> BatchEvaluation:
    """window-open-v3 and window-close-v3: the handle slid to the goal's x."""
    xp = state.xp
    obj = state.site_pos("handleOpenStart" if opening else "handleCloseStart")
    target, handle_init = _p(state, "_target_pos"), _p(state, "window_handle_pos_init")
    to_target = xp.abs(obj[:, 0] - target[:, 0])
    start = (_p(state, "obj_init_pos") if opening else handle_init)[:, 0]
    in_place = tolerance(xp, to_target, 0, 0.05, xp.abs(xp.abs(start - target[:, 0]) - 0.05))
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    reach_margin = xp.abs(norm(xp, handle_init - _p(state, "init_tcp")) - 0.02)
    reach = tolerance(xp, tcp_to_obj, 0, 0.02, reach_margin, "long_tail" if opening else "gaussian")
    reward = 10 * hamacher(xp, reach, in_place)
    return _judged(xp, reward, to_target <= 0.05, near_object=tcp_to_obj <= 0.05, grasp_success=1.0,
                   grasp_reward=reach, in_place_reward=in_place, obj_to_target=to_target)


def handle_press(state) -> BatchEvaluation:
    """handle-press-v3 and handle-press-side-v3 (the same rule): the handle down to its goal height."""
    xp = state.xp
    obj = state.site_pos("handleStart")
    target, handle_init = _p(state, "_target_pos"), _p(state, "_handle_init_pos")
    to_target = xp.abs(obj[:, 2] - target[:, 2])
    in_place = tolerance(xp, to_target, 0, 0.02, xp.abs(xp.abs(handle_init[:, 2] - target[:, 2]) - 0.02))
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    reach_margin = xp.abs(norm(xp, handle_init - _p(state, "init_tcp")) - 0.02)
    reach = tolerance(xp, tcp_to_obj, 0, 0.02, reach_margin)
    reward = xp.where(to_target <= 0.02, 1.0, hamacher(xp, reach, in_place)) * 10
    return _judged(xp, reward, to_target <= 0.02, near_object=tcp_to_obj <= 0.05, grasp_success=1.0,
                   grasp_reward=reach, in_place_reward=in_place, obj_to_target=to_target)


def handle_pull(state, side: bool) -> BatchEvaluation:
    """handle-pull-v3 (height only; its lift test reads the object's y, as Meta-World's does) and
    handle-pull-side-v3 (the whole distance)."""
    xp, _, opened, obj = _split(state)
    target, init = _p(state, "_target_pos"), _p(state, "obj_init_pos")
    if side:
        to_target, to_target_init = norm(xp, obj - target), norm(xp, init - target)
    else:
        to_target, to_target_init = xp.abs(target[:, 2] - obj[:, 2]), xp.abs(target[:, 2] - init[:, 2])
    in_place = tolerance(xp, to_target, 0, BASE_TARGET_RADIUS, to_target_init)
    grasped = caging(xp, state, obj, init, obj_radius=0.032 if side else 0.022, pad_thresh=0.06 if side else 0.05,
                     reach_radius=0.01, xz_thresh=0.01, density="high")
    reward = hamacher(xp, grasped, in_place)
    tcp_to_obj = norm(xp, obj - state.tcp_center)
    lifted = obj[:, 2 if side else 1] - 0.01 > init[:, 2]
    reward = xp.where((tcp_to_obj < 0.035) & (opened > 0) & lifted, reward + (1.0 + 5.0 * in_place), reward)
    reward = xp.where(to_target < BASE_TARGET_RADIUS, 10.0, reward)
    grasp = (opened > 0) & (obj[:, 2] - 0.03 > init[:, 2])
    return _judged(xp, reward, to_target <= (0.08 if side else BASE_TARGET_RADIUS), near_object=tcp_to_obj <= 0.05,
                   grasp_success=grasp, grasp_reward=grasped, in_place_reward=in_place, obj_to_target=to_target)


def lever_pull(state) -> BatchEvaluation:
    xp, hand, _, lever = _split(state)
    lever_init, target = _p(state, "_lever_pos_init"), _p(state, "_target_pos")
    scale, offset = vec(xp, lever, [4.0, 1.0, 4.0]), vec(xp, lever, [0.0, 0.055, 0.07])
    shoulder = norm(xp, (hand + offset - lever) * scale)
    ready = tolerance(xp, shoulder, 0, 0.02, norm(xp, (_p(state, "init_tcp") + offset - lever_init) * scale))
    error = xp.abs(-state.qpos("LeverAxis")[:, 0] - pi / 2.0)
    engagement = tolerance(xp, error, 0, pi / 48.0, pi / 2.0 - pi / 12.0)
    in_place = tolerance(xp, norm(xp, lever - target), 0, 0.04, norm(xp, lever_init - target))
    reward = 10.0 * hamacher(xp, ready, in_place)
    return _judged(xp, reward, error <= pi / 24, near_object=shoulder < 0.03, grasp_success=ready > 0.9,
                   grasp_reward=ready, in_place_reward=engagement, obj_to_target=shoulder)


def dial_turn(state) -> BatchEvaluation:
    xp = state.xp
    angle = state.qpos("knob_Joint_1")[:, 0]
    zero = xp.zeros_like(angle)
    obj = state.body_pos("dial") + xp.stack([xp.sin(angle), -xp.cos(angle), zero], axis=-1) * 0.05
    push_pos = obj + vec(xp, obj, [0.05, 0.02, 0.09])
    target, push_init = _p(state, "_target_pos"), _p(state, "dial_push_position")
    to_target = norm(xp, obj - target)
    in_place = tolerance(xp, to_target, 0, 0.07, xp.abs(norm(xp, push_init - target) - 0.07))
    tcp_to_obj = norm(xp, push_pos - state.tcp_center)
    reach_margin = xp.abs(norm(xp, push_init - _p(state, "init_tcp")) - 0.005)
    reach = tolerance(xp, tcp_to_obj, 0, 0.005, reach_margin, "gaussian")
    reach = hamacher(xp, reach, clamp_grip(xp, state.action, obj))
    reward = 10 * hamacher(xp, reach, in_place)
    return _judged(xp, reward, to_target <= 0.07, near_object=tcp_to_obj <= 0.01, grasp_success=1.0,
                   grasp_reward=reach, in_place_reward=in_place, obj_to_target=to_target)


# ---------------------------------------------------------------------------- tools and lids
def _nut(state, disassemble: bool) -> BatchEvaluation:
    """assembly-v3 (the nut onto the peg) and disassemble-v3 (the nut off it)."""
    xp, hand, _, wrench = _split(state)
    target = _p(state, "_target_pos")
    center = state.site_pos("RoundNut")
    quat = _quat_reward(xp, state.obs, [0.707, 0, 0, 0.707], 0.4)
    grab = caging(xp, state, _threshed(xp, hand, wrench, 0.02 / 2.0), _p(state, "obj_init_pos"),
                  obj_radius=0.015, pad_thresh=0.02, reach_radius=0.01, xz_thresh=0.01,
                  density="high" if disassemble else "medium")
    if disassemble:
        lifted = (center[:, 2] > 0.02).astype(hand.dtype)
        error = norm(xp, target + vec(xp, hand, [0.0, 0.0, 0.1]) - center)
        in_place = 0.1 * lifted + 0.9 * tolerance(xp, error, 0, 0.02, 0.2)
        success = state.obs[:, 6] > target[:, 2]
    else:
        in_place, success = _assembly_place(xp, center, target)
    reward = xp.where(success, 10.0, (2.0 * grab + 6.0 * in_place) * quat)
    return _judged(xp, reward, success, near_object=quat, grasp_success=grab >= 0.5, grasp_reward=grab,
                   in_place_reward=in_place, obj_to_target=0.0)


def _assembly_place(xp, center, target) -> tuple[Any, Any]:
    """assembly's in-place term and success: the nut centred over the peg (2 cm) and below its top."""
    error = target - center
    radius = norm(xp, error[:, :2])
    success = (radius < 0.02) & (error[:, 2] > 0.0)
    threshold = xp.where(success, 0.02, 0.01).astype(center.dtype)
    beyond = radius > threshold
    height = xp.where(beyond, 0.02 * xp.log(xp.where(beyond, radius - threshold, 1)) + 0.2, 0.0)
    error = xp.stack([error[:, 0], error[:, 1], height - center[:, 2]], axis=-1)
    lifted = ((center[:, 2] > 0.02) | (radius < threshold)).astype(center.dtype)
    scaled = norm(xp, error * vec(xp, center, [1.0, 1.0, 3.0]))
    return 0.1 * lifted + 0.9 * tolerance(xp, scaled, 0, 0.02, 0.4), success


def assembly(state) -> BatchEvaluation:
    return _nut(state, disassemble=False)


def disassemble(state) -> BatchEvaluation:
    return _nut(state, disassemble=True)


def hammer(state) -> BatchEvaluation:
    xp, hand, _, hammer_pos = _split(state)
    head = hammer_pos + vec(xp, hand, [0.16, 0.06, 0.0])
    quat = _quat_reward(xp, state.obs, [1.0, 0.0, 0.0, 0.0], 0.4)
    grab = caging(xp, state, _threshed(xp, hand, hammer_pos, 0.14 / 2.0), _p(state, "obj_init_pos"),
                  obj_radius=0.015, pad_thresh=0.02, reach_radius=0.01, xz_thresh=0.01, density="high")
    lifted = (head[:, 2] > 0.02).astype(hand.dtype)
    in_place = 0.1 * lifted + 0.9 * tolerance(xp, norm(xp, _p(state, "_target_pos") - head), 0, 0.02, 0.2)
    reward = (2.0 * grab + 6.0 * in_place) * quat
    success = state.qpos("NailSlideJoint")[:, 0] > 0.09
    reward = xp.where(success & (reward > 5.0), 10.0, reward)
    return _judged(xp, reward, success, near_object=quat, grasp_success=grab >= 0.5, grasp_reward=grab,
                   in_place_reward=in_place, obj_to_target=0.0)


def box_close(state) -> BatchEvaluation:
    xp, hand, _, obj = _split(state)
    target = _p(state, "_target_pos")
    grab = _action_term(xp, state, obj, lambda a: xp.clip((xp.clip(a, -1, 1) + 1.0) / 2.0, 0.0, 1.0))
    quat = _quat_reward(xp, state.obs, [0.707, 0, 0, 0.707], 0.2)
    lid = obj + vec(xp, obj, [0.0, 0.0, 0.02])
    floor = _log_floor(xp, norm(xp, hand[:, :2] - lid[:, :2]), 0.02, 0.04, 0.4)
    above = xp.where(hand[:, 2] >= floor, 1, tolerance(xp, floor - hand[:, 2], 0.0, 0.01, floor / 2.0))
    ready = hamacher(xp, above, tolerance(xp, norm(xp, hand - lid), 0, 0.02, 0.5))
    error = norm(xp, (target - lid) * vec(xp, obj, [1.0, 1.0, 3.0]))
    lifted = 0.2 * (lid[:, 2] > 0.04).astype(obj.dtype) + 0.8 * tolerance(xp, error, 0, 0.05, 0.25)
    reward = 2.0 * hamacher(xp, grab, ready) + 8.0 * lifted
    success = norm(xp, obj - target) < 0.08
    reward = xp.where(success, 10.0, reward) * quat
    return _judged(xp, reward, success, near_object=ready, grasp_success=grab >= 0.5, grasp_reward=grab,
                   in_place_reward=lifted, obj_to_target=0.0)


def stick_push(state) -> BatchEvaluation:
    xp, _, opened, stick_obs = _split(state)
    target, stick_init = _p(state, "_target_pos"), _p(state, "stick_init_pos")
    stick = stick_obs + vec(xp, stick_obs, [0.015, 0.0, 0.0])
    container = state.obs[:, 11:14]
    tcp_to_stick = norm(xp, stick - state.tcp_center)
    stick_in_place = tolerance(xp, norm(xp, stick - target), 0, 0.12, norm(xp, stick_init - target) - 0.12)
    to_target = norm(xp, container - target)
    container_margin = norm(xp, _p(state, "obj_init_pos") - target) - 0.12
    container_in_place = tolerance(xp, to_target, 0, 0.12, container_margin)
    grasped = caging(xp, state, stick, stick_init, obj_radius=0.04, pad_thresh=0.05, reach_radius=0.01,
                     xz_thresh=0.01, density="high")
    holding = (tcp_to_stick < 0.02) & (opened > 0) & (stick[:, 2] - 0.01 > stick_init[:, 2])
    pushed = xp.where(to_target <= 0.12, 10.0, 2.0 + 5.0 * stick_in_place + 3.0 * container_in_place)
    reward = xp.where(holding, pushed, grasped)
    grasped = xp.where(holding, 1.0, grasped)
    grasp = state.touching_object(OBJ_GEOM) & (opened > 0) & (stick_obs[:, 2] - 0.01 > stick_init[:, 2])
    return _judged(xp, reward, grasp & (to_target <= 0.12), near_object=tcp_to_stick <= 0.03,
                   grasp_success=grasp, grasp_reward=grasped, in_place_reward=stick_in_place,
                   obj_to_target=to_target)


def stick_pull(state) -> BatchEvaluation:
    xp, _, opened, stick = _split(state)
    target, stick_init, init = _p(state, "_target_pos"), _p(state, "stick_init_pos"), _p(state, "obj_init_pos")
    end = state.site_pos("stick_end")
    handle = state.obs[:, 11:14]
    shift, yz = vec(xp, stick, [0.05, 0.0, 0.0]), vec(xp, stick, [1.0, 1.0, 2.0])
    container = handle + shift
    tcp_to_stick = norm(xp, stick - state.tcp_center)
    handle_to_target = norm(xp, handle - target)
    stick_margin = norm(xp, (stick_init - (init + shift)) * yz)
    stick_in_place = tolerance(xp, norm(xp, (stick - container) * yz), 0, 0.05, stick_margin)
    stick_in_place_2 = tolerance(xp, norm(xp, stick - target), 0, 0.05, norm(xp, stick_init - target))
    container_in_place = tolerance(xp, norm(xp, container - target), 0, 0.05, norm(xp, init - target))
    grasped = caging(xp, state, stick, init, obj_radius=0.014, pad_thresh=0.05, reach_radius=0.01,
                     xz_thresh=0.01, density="high")
    holding = (tcp_to_stick < 0.02) & (opened > 0) & (stick[:, 2] - 0.01 > stick_init[:, 2])
    grasped = xp.where(holding, 1.0, grasped)
    both = hamacher(xp, grasped, stick_in_place)
    inserted = ((end[:, 0] >= handle[:, 0]) & (xp.abs(end[:, 1] - handle[:, 1]) <= 0.04)
                & (xp.abs(end[:, 2] - handle[:, 2]) <= 0.06))
    hooked = 1.0 + both + 5.0 + 2.0 * stick_in_place_2 + 1.0 * container_in_place
    hooked = xp.where(handle_to_target <= 0.12, 10.0, hooked)
    reward = xp.where(holding, xp.where(inserted, hooked, 1.0 + both + 5.0 * stick_in_place), both)
    grasp = state.touching_object(OBJ_GEOM) & (opened > 0) & (stick[:, 2] - 0.02 > init[:, 2])
    return _judged(xp, reward, (handle_to_target <= 0.12) & inserted, near_object=tcp_to_stick <= 0.03,
                   grasp_success=grasp, grasp_reward=grasped, in_place_reward=stick_in_place,
                   obj_to_target=handle_to_target)


# ------------------------------------------------------------------------------------ the table
_PLACE = ("_target_pos", "obj_init_pos", "init_tcp")

#: env name -> (batched rule, the reset attributes it reads from ``state.params``)
TASKS: dict[str, tuple[Callable[[Any], BatchEvaluation], tuple[str, ...]]] = {
    "assembly-v3": (assembly, _PLACE),
    "basketball-v3": (basketball, ("obj_init_pos", "init_tcp")),
    "bin-picking-v3": (bin_picking, ("obj_init_pos", "init_tcp", "_target_to_obj_init")),
    "box-close-v3": (box_close, ("_target_pos",)),
    "button-press-topdown-v3": (button_press_topdown, ("_target_pos", "init_tcp", "_obj_to_target_init")),
    "button-press-topdown-wall-v3": (button_press_topdown, ("_target_pos", "init_tcp", "_obj_to_target_init")),
    "button-press-v3": (button_press, ("_target_pos", "init_tcp", "_obj_to_target_init")),
    "button-press-wall-v3": (button_press_wall, ("_target_pos", "init_tcp", "_obj_to_target_init")),
    "coffee-button-v3": (coffee_button, ("_target_pos", "init_tcp")),
    "coffee-pull-v3": (coffee_mug, _PLACE),
    "coffee-push-v3": (coffee_mug, _PLACE),
    "dial-turn-v3": (dial_turn, ("_target_pos", "dial_push_position", "init_tcp")),
    "disassemble-v3": (disassemble, _PLACE),
    "door-close-v3": (door_close, ("_target_pos", "obj_init_pos", "hand_init_pos")),
    "door-lock-v3": (door_lock, ("_target_pos",)),
    "door-open-v3": (door_open, ("_target_pos",)),
    "door-unlock-v3": (door_unlock, ("_target_pos", "init_tcp")),
    "drawer-close-v3": (drawer_close, _PLACE),
    "drawer-open-v3": (drawer_open, ("_target_pos", "init_tcp")),
    "faucet-close-v3": (lambda s: faucet(s, opening=False), _PLACE),
    "faucet-open-v3": (lambda s: faucet(s, opening=True), _PLACE),
    "hammer-v3": (hammer, _PLACE),
    "hand-insert-v3": (hand_insert, _PLACE),
    "handle-press-side-v3": (handle_press, ("_target_pos", "_handle_init_pos", "init_tcp")),
    "handle-press-v3": (handle_press, ("_target_pos", "_handle_init_pos", "init_tcp")),
    "handle-pull-side-v3": (lambda s: handle_pull(s, side=True), _PLACE),
    "handle-pull-v3": (lambda s: handle_pull(s, side=False), _PLACE),
    "lever-pull-v3": (lever_pull, ("_target_pos", "_lever_pos_init", "init_tcp")),
    "peg-insert-side-v3": (peg_insert_side, (*_PLACE, "peg_head_pos_init")),
    "peg-unplug-side-v3": (peg_unplug_side, _PLACE),
    "pick-out-of-hole-v3": (pick_out_of_hole, _PLACE),
    "pick-place-v3": (pick_place, _PLACE),
    "pick-place-wall-v3": (pick_place_wall, _PLACE),
    "plate-slide-back-side-v3": (plate_slide, _PLACE),
    "plate-slide-back-v3": (plate_slide, _PLACE),
    "plate-slide-side-v3": (plate_slide, _PLACE),
    "plate-slide-v3": (lambda s: plate_slide(s, variant=False), _PLACE),
    "push-back-v3": (push_back, _PLACE),
    "push-v3": (push, _PLACE),
    "push-wall-v3": (push_wall, _PLACE),
    "reach-v3": (reach, ("_target_pos", "hand_init_pos")),
    "reach-wall-v3": (lambda s: reach(s, wall=True), ("_target_pos", "hand_init_pos")),
    "shelf-place-v3": (shelf_place, _PLACE),
    "soccer-v3": (soccer, _PLACE),
    "stick-pull-v3": (stick_pull, (*_PLACE, "stick_init_pos")),
    "stick-push-v3": (stick_push, (*_PLACE, "stick_init_pos")),
    "sweep-into-v3": (lambda s: sweep(s, into=True), _PLACE),
    "sweep-v3": (sweep, _PLACE),
    "window-close-v3": (lambda s: window(s, opening=False), ("_target_pos", "window_handle_pos_init", "init_tcp")),
    "window-open-v3": (lambda s: window(s, opening=True), (*_PLACE, "window_handle_pos_init")),
}
#: env name -> the geom both pads must touch for its ``grasp_success`` (Meta-World's ``touching_main_object``)
GRASPED_GEOM: dict[str, str] = {
    **{name: OBJ_GEOM for name in ("hand-insert-v3", "pick-place-v3", "pick-place-wall-v3", "push-back-v3",
                                   "push-v3", "push-wall-v3", "shelf-place-v3", "soccer-v3", "stick-pull-v3",
                                   "stick-push-v3", "sweep-into-v3", "sweep-v3")},
    "coffee-pull-v3": MUG_GEOM, "coffee-push-v3": MUG_GEOM,
}
#: env name -> its batched rule: ``TASK_REWARDS[name](state) -> BatchEvaluation``
TASK_REWARDS: dict[str, Callable[[Any], BatchEvaluation]] = {k: fn for k, (fn, _) in TASKS.items()}
#: env name -> the reset attributes its rule reads (``state.params`` keys, stacked per world)
TASK_PARAMS: dict[str, tuple[str, ...]] = {k: params for k, (_, params) in TASKS.items()}


def evaluate(task: str, state) -> BatchEvaluation:
    """``TASK_REWARDS[task](state)``, with a one-line error naming an unknown task or a missing attribute."""
    if task not in TASKS:
        raise KeyError(f"Meta-World reward: no batched rule for task {task!r}; known: {', '.join(sorted(TASKS))}")
    fn, needed = TASKS[task]
    missing = [k for k in needed if k not in state.params]
    if missing:
        raise KeyError(f"Meta-World reward for {task!r}: state.params lacks {missing} (it reads {list(needed)})")
    return fn(state)
