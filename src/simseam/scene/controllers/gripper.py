"""The gripper: one slot, -1 fully open .. +1 fully closed, linear in between."""

from __future__ import annotations

import numpy as np

from simseam.seam import ActionSlot, GripperFacts


class Gripper:
    group = "grip"

    def __init__(self, spec: GripperFacts):
        self.open = np.asarray(spec.open, dtype=np.float64)
        self.closed = np.asarray(spec.closed, dtype=np.float64)
        self._span = self.closed - self.open
        self.slots = (ActionSlot("grip", "grip", -1.0, 1.0, "-1 open .. +1 closed"),)

    def targets(self, command: float) -> np.ndarray:
        """Finger joint targets (manifest gripper-joint order) for a command already in [-1, 1]."""
        g = (command + 1.0) * 0.5
        return self.open + g * self._span
