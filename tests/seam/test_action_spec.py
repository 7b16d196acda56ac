"""``ActionSpec.clip``: any finite action into the slot bounds (each slot's own, inclusive, asymmetric
ones too), then into the norm bounds (direction kept); a copy, the caller's array untouched."""

import numpy as np
import pytest

from simseam.seam import ActionSlot, ActionSpec, ControlMode
from simseam.seam.spec import NormBound

SPEC = ActionSpec(ControlMode.JOINT_POSITION, (
    ActionSlot("j1", "arm", -1.0, 1.0), ActionSlot("j2", "arm", -0.5, 2.0), ActionSlot("grip", "grip", -1.0, 1.0),
    ActionSlot("vx", "base", -0.6, 0.6), ActionSlot("vy", "base", -0.6, 0.6), ActionSlot("wz", "base", -1.5, 1.5)),
    norm_bounds=(NormBound(("vx", "vy"), 0.5),))


@pytest.mark.parametrize("action, want", [
    ([0.3, 1.7, -0.2, 0.1, -0.2, 1.0], [0.3, 1.7, -0.2, 0.1, -0.2, 1.0]),  # inside: unchanged
    ([1.0, -0.5, 1.0, 0.3, 0.4, -1.5], [1.0, -0.5, 1.0, 0.3, 0.4, -1.5]),  # on the bounds (inclusive; |v| = 0.5)
    ([3.0, -3.0, 9.0, 0.0, 0.0, -9.0], [1.0, -0.5, 1.0, 0.0, 0.0, -1.5]),  # each slot to its own bound
    ([-3.0, 3.0, -9.0, 0.0, 0.0, 9.0], [-1.0, 2.0, -1.0, 0.0, 0.0, 1.5]),  # j2's asymmetric upper bound
    ([0.0, 0.0, 0.0, 0.4, 0.4, 0.0], [0.0, 0.0, 0.0, 0.5 / 2 ** 0.5, 0.5 / 2 ** 0.5, 0.0]),  # |v| 0.57 -> 0.5
    ([0.0, 0.0, 0.0, -2.0, 0.1, 0.0], [0.0, 0.0, 0.0, -0.6 * 0.5 / 0.37 ** 0.5, 0.1 * 0.5 / 0.37 ** 0.5, 0.0]),
], ids=["inside", "on the bounds", "each to its own bound", "asymmetric", "norm bound", "box, then norm"])
def test_clip_maps_an_action_into_the_slot_and_norm_bounds(action, want):
    """Catches: ActionSpec.clip with bounds swapped or symmetric, norm mis-scaled or applied first, or in place."""
    a = np.array(action, dtype=np.float64)
    got = SPEC.clip(a)
    np.testing.assert_allclose(got, want, rtol=0, atol=1e-12)
    assert a.tolist() == action and got is not a  # a copy: what the caller holds is unchanged
    np.testing.assert_allclose(SPEC.clip(got), got, rtol=0, atol=1e-12)  # what clip returns is already legal
    assert np.all(got >= SPEC.low) and np.all(got <= SPEC.high)
    assert np.hypot(got[3], got[4]) <= 0.5 + 1e-12
