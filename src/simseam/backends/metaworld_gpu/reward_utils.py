"""Meta-World's reward shaping terms, batched: one row per world, arrays of the namespace ``xp`` handed in.

The rules are Meta-World v3's (``metaworld/utils/reward_utils.py``, itself from dm_control, and
``SawyerXYZEnv._gripper_caging_reward`` with the variants some tasks override); the code is written
here for N worlds with the NumPy API subset of ``simseam.scene.tasks.batch`` (NumPy on the CPU, CuPy
on a CUDA device): no per-world Python branching, no conversion to Python scalars. Every function
keeps its inputs' float dtype (float64 on the CPU, float32 on the device).

Where Meta-World raises (a negative margin, a Hamacher operand outside [0, 1]) the batched term
computes the formula on: a batch cannot stop for one world, and those inputs do not arise in the
benchmark's own episodes.
"""

from __future__ import annotations

from typing import Any

import numpy as np

#: ``tolerance``'s value at ``margin`` away from the bounds (dm_control's default)
VALUE_AT_MARGIN = 0.1
#: each sigmoid's scale so that it is ``VALUE_AT_MARGIN`` at 1 (computed as the reference computes it)
_LONG_TAIL_SCALE = float(np.sqrt(1 / VALUE_AT_MARGIN - 1))
_GAUSSIAN_SCALE = float(np.sqrt(-2 * np.log(VALUE_AT_MARGIN)))
SIGMOIDS = ("long_tail", "gaussian")


def vec(xp, like, values) -> Any:
    """A constant vector in ``like``'s dtype (so float32 arrays stay float32)."""
    return xp.asarray(values, dtype=like.dtype)


def norm(xp, v) -> Any:
    """float[N]: the Euclidean norm over the last axis."""
    return xp.sqrt(xp.sum(v * v, axis=-1))


def sigmoid(xp, d, kind: str) -> Any:
    """dm_control's sigmoid: 1 at 0, ``VALUE_AT_MARGIN`` at 1 (``long_tail`` or ``gaussian``)."""
    if kind == "long_tail":
        return 1 / ((d * _LONG_TAIL_SCALE) ** 2 + 1)
    if kind == "gaussian":
        return xp.exp(-0.5 * (d * _GAUSSIAN_SCALE) ** 2)
    raise ValueError(f"metaworld reward_utils: sigmoid {kind!r} is not one of {SIGMOIDS}")


def tolerance(xp, x, lower, upper, margin, kind: str = "long_tail") -> Any:
    """1 where ``lower <= x <= upper``; outside, the sigmoid of the distance to the nearer bound over
    ``margin``; with ``margin == 0``, 0 outside. ``lower`` / ``upper`` / ``margin`` are numbers or
    float[N] (a margin may differ per world)."""
    inside = (lower <= x) & (x <= upper)
    if isinstance(margin, (int, float)):  # one margin for every world: a constant of the rule, not a branch
        if margin == 0:
            return inside.astype(x.dtype)
        d = xp.where(x < lower, lower - x, x - upper) / margin
        return xp.where(inside, 1, sigmoid(xp, d, kind)).astype(x.dtype)
    zero = margin == 0
    d = xp.where(x < lower, lower - x, x - upper) / xp.where(zero, 1, margin)
    value = xp.where(inside, 1, sigmoid(xp, d, kind))
    return xp.where(zero, inside, value).astype(x.dtype)


def hamacher(xp, a, b) -> Any:
    """The Hamacher t-norm ``a b / (a + b - a b)``, 0 where the denominator is not positive."""
    den = a + b - a * b
    pos = den > 0
    return xp.where(pos, (a * b) / xp.where(pos, den, 1), 0)


def rect_prism(xp, curr, zero, one) -> Any:
    """float[N]: inside the box spanned by the corners ``zero`` and ``one`` (float[N, 3]), the product of
    ``curr``'s fractions of the way from ``zero`` to ``one`` per axis; outside it, 1."""
    lo_first = one >= zero
    within = xp.where(lo_first, (zero <= curr) & (curr <= one), (one <= curr) & (curr <= zero))
    inside = within[:, 0] & within[:, 1] & within[:, 2]
    diff = one - zero
    frac = (curr - zero) / xp.where(diff == 0, 1, diff)
    return xp.where(inside, frac[:, 0] * frac[:, 1] * frac[:, 2], 1)


def clamp_grip(xp, action, like, effort: float = 1.0) -> Any:
    """How closed the gripper command is, as a share of ``effort``: ``min(max(0, a[3]), effort) / effort``,
    in ``like``'s dtype. Computed in the action's own dtype first, as Meta-World does (a float32 action
    keeps that term float32 there)."""
    return (xp.minimum(xp.maximum(action[:, 3], 0), effort) / effort).astype(like.dtype)


def _xz(xp, p) -> Any:
    """``p`` with its y set to 0 (as ``p + [0, -p_y, 0]``)."""
    return xp.stack([p[:, 0], p[:, 1] - p[:, 1], p[:, 2]], axis=-1)


def caging(xp, state, obj, obj_init, *, obj_radius: float, pad_thresh: float, reach_radius: float,
           xz_thresh: float, effort: float = 1.0, density: str | None = None) -> Any:
    """``SawyerXYZEnv._gripper_caging_reward``: the pads bracketing ``obj`` in y (relative to where the
    object started, ``obj_init`` float[N, 3]), the tool centre over it in x-z, the gripper closing once
    caged; ``density``: ``"high"`` averages in the caging alone, ``"medium"`` a reach term."""
    init_tcp = state.params["init_tcp"]
    tcp = state.tcp_center
    pad_y = xp.stack([state.left_pad[:, 1], state.right_pad[:, 1]], axis=-1)
    pad_to_obj = xp.abs(pad_y - obj[:, 1:2])
    margin = xp.abs(xp.abs(pad_y - obj_init[:, 1:2]) - pad_thresh)
    lr = tolerance(xp, pad_to_obj, obj_radius, pad_thresh, margin)
    caging_y = hamacher(xp, lr[:, 0], lr[:, 1])
    xz_margin = norm(xp, obj_init[:, ::2] - init_tcp[:, ::2]) - xz_thresh
    caging_xz = tolerance(xp, norm(xp, tcp[:, ::2] - obj[:, ::2]), 0, xz_thresh, xz_margin)
    closed = clamp_grip(xp, state.action, obj, effort)
    cage = hamacher(xp, caging_y, caging_xz)
    gripping = xp.where(cage > 0.97, closed, 0)
    out = hamacher(xp, cage, gripping)
    if density == "high":
        out = (out + cage) / 2
    elif density == "medium":
        reach_margin = xp.abs(norm(xp, obj_init - init_tcp) - reach_radius)
        reach = tolerance(xp, norm(xp, obj - tcp), 0, reach_radius, reach_margin)
        out = (out + reach) / 2
    return out


def _pad_margins(xp, state, obj, pad: float) -> tuple[Any, Any, Any, Any]:
    """Each pad's y offset from the object and its caging margin (the ``y_caging`` variants). Meta-World
    measures the margin from ``init_left_pad`` / ``init_right_pad``, which are views of the pads' live
    positions (``get_body_com`` returns MuJoCo's array, not a copy): the pads' current y."""
    left_y, right_y, obj_y = state.left_pad[:, 1], state.right_pad[:, 1], obj[:, 1]
    d_left, d_right = left_y - obj_y, obj_y - right_y
    m_right = xp.abs(xp.abs(obj_y - right_y) - pad)
    m_left = xp.abs(xp.abs(obj_y - left_y) - pad)
    return d_left, d_right, m_left, m_right


def _xz_caging(xp, state, obj, xz_margin: float) -> Any:
    init_tcp, obj_init = state.params["init_tcp"], state.params["obj_init_pos"]
    dist = norm(xp, _xz(xp, state.tcp_center) - _xz(xp, obj))
    margin = norm(xp, _xz(xp, obj_init) - _xz(xp, init_tcp)) - xz_margin
    return tolerance(xp, dist, 0, xz_margin, margin)


def caging_pick_place(xp, state, obj) -> Any:
    """``SawyerPickPlaceEnvV3._gripper_caging_reward`` (pads 5 cm, x-z 5 mm, object radius 15 mm)."""
    d_left, d_right, m_left, m_right = _pad_margins(xp, state, obj, 0.05)
    right = tolerance(xp, d_right, 0.015, 0.05, m_right)
    left = tolerance(xp, d_left, 0.015, 0.05, m_left)
    y_caging = hamacher(xp, left, right)
    x_z = _xz_caging(xp, state, obj, 0.005)
    closed = clamp_grip(xp, state.action, obj)
    cage = hamacher(xp, y_caging, x_z)
    gripping = xp.where(cage > 0.97, closed, 0)
    return (hamacher(xp, cage, gripping) + cage) / 2


def caging_gripping(xp, state, obj, obj_radius: float, grip_extra: float, xz_margin: float) -> Any:
    """The caging variant of push-back, soccer, sweep and sweep-into: caged pads (5 cm) and, once caged
    past 0.95, pads gripping within ``obj_radius + grip_extra``, averaged."""
    grip = obj_radius + grip_extra
    d_left, d_right, m_left, m_right = _pad_margins(xp, state, obj, 0.05)
    right_cage = tolerance(xp, d_right, obj_radius, 0.05, m_right)
    left_cage = tolerance(xp, d_left, obj_radius, 0.05, m_left)
    right_grip = tolerance(xp, d_right, obj_radius, grip, m_right)
    left_grip = tolerance(xp, d_left, obj_radius, grip, m_left)
    y_caging = hamacher(xp, right_cage, left_cage)
    y_gripping = hamacher(xp, right_grip, left_grip)
    cage = hamacher(xp, y_caging, _xz_caging(xp, state, obj, xz_margin))
    gripping = xp.where(cage > 0.95, y_gripping, 0)
    return (cage + gripping) / 2
