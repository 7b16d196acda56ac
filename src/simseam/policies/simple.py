"""Baseline policies: ``random`` and ``zero``."""

from __future__ import annotations

import numpy as np

from simseam.policies.base import BasePolicy, register_policy
from simseam.scene.actions import ActionLayout
from simseam.seam import ControlMode, Observation, SceneInfo, TaskInfo


@register_policy("zero")
class ZeroPolicy(BasePolicy):
    """All-zero actions. Under JOINT_POSITION the arm part holds the current joint
    positions instead (zero joint targets would swing the arm to q = 0)."""

    def reset(self, scene: SceneInfo, task: TaskInfo) -> None:
        super().reset(scene, task)
        self.layout = ActionLayout.from_scene(scene)
        self._hold = None

    def act(self, observation: Observation) -> np.ndarray:
        action = self.layout.pack()
        if self.layout.control_mode == ControlMode.JOINT_POSITION:
            if self._hold is None:
                idx = [self.scene_info.joint_names.index(n) for n in self.layout.arm_names]
                self._hold = np.asarray(observation["joint_positions"])[idx]
            action[self.layout.arm] = self._hold
        return action


@register_policy("random")
class RandomPolicy(BasePolicy):
    """Uniform random actions in [-1, 1] (JOINT_POSITION: current joints +- 0.1 rad), seeded."""

    def __init__(self, seed: int = 0):
        self._rng = np.random.default_rng(seed)

    def reset(self, scene: SceneInfo, task: TaskInfo) -> None:
        super().reset(scene, task)
        self.layout = ActionLayout.from_scene(scene)

    def act(self, observation: Observation) -> np.ndarray:
        action = self._rng.uniform(-1.0, 1.0, self.layout.dim).astype(np.float32)
        if self.layout.control_mode == ControlMode.JOINT_POSITION:
            idx = [self.scene_info.joint_names.index(n) for n in self.layout.arm_names]
            action[self.layout.arm] = np.asarray(observation["joint_positions"])[idx] + 0.1 * action[self.layout.arm]
        return action
