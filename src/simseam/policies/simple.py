"""Baseline policies: ``random`` and ``zero``."""

from __future__ import annotations

import numpy as np

from simseam.policies.base import BasePolicy
from simseam.seam import OBS_JOINT_POSITIONS, ControlMode, Observation, RolloutSpec


def _arm_index(spec: RolloutSpec) -> list[int]:
    """Positions of the JOINT_POSITION arm slots in the observation's joint order."""
    names = spec.robot.joint_names
    return [names.index(n) for n in spec.action.arm_names]


class ZeroPolicy(BasePolicy):
    """A true no-op: the robot holds still. Cartesian deltas and base twists are zero; under
    JOINT_POSITION the arm holds the joint positions measured at the episode's first step; the
    gripper holds the opening it had then (not command 0, which would half-close it)."""

    def reset(self, spec: RolloutSpec) -> None:
        super().reset(spec)
        self._hold: np.ndarray | None = None

    def act(self, observation: Observation) -> np.ndarray:
        if self._hold is None:
            spec = self.spec
            action = spec.action.pack()
            q = np.asarray(observation[OBS_JOINT_POSITIONS], dtype=np.float64)
            if spec.control_mode == ControlMode.JOINT_POSITION:
                action[spec.action.arm] = q[_arm_index(spec)]
            g = spec.robot.gripper
            if spec.action.has_gripper and g is not None:
                names = spec.robot.joint_names
                action[spec.action.grip] = g.command_of(q[[names.index(n) for n in g.joints]])
            self._hold = action
        return self._hold.copy()


class RandomPolicy(BasePolicy):
    """Uniform random actions in [-1, 1] (JOINT_POSITION: current joints +- 0.1 rad), seeded."""

    def __init__(self, seed: int = 0):
        self._rng = np.random.default_rng(seed)

    def act(self, observation: Observation) -> np.ndarray:
        spec = self.spec
        action = self._rng.uniform(-1.0, 1.0, spec.action.dim).astype(np.float32)
        if spec.control_mode == ControlMode.JOINT_POSITION:
            arm = spec.action.arm
            action[arm] = np.asarray(observation[OBS_JOINT_POSITIONS])[_arm_index(spec)] + 0.1 * action[arm]
        return action
