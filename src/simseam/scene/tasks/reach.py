"""reach: bring the tool frame to a target pose drawn from the seed. Any arm, with or without a gripper.

The target is reachable by construction: the task draws arm joint positions around the home
posture (each joint within +-``SPREAD`` of its range, at most +-``MAX_DQ`` rad, inside its limits)
and takes the tool pose the scene's own kinematic chain gives for them (``SerialChain.forward``,
the same chain the Cartesian IK uses), keeping only poses at least ``MIN_HEIGHT`` above the table,
``MIN_TRAVEL`` away from the home pose and ``MIN_RADIUS`` of the robot's reach out from its base
(a tool tucked against the arm's own base column puts the fingers into the first link).
Success: the measured tool frame within ``POS_TOL`` (2 cm) and ``ROT_TOL`` (10 degrees) of the
target. The target pose is ground truth in ``privileged['objects']['target']`` (base frame);
diagnostics: ``position_error`` (m) and ``orientation_error`` (rad). Reward is sparse: 1.0 on
success. Either control mode.
"""

from __future__ import annotations

import math

import numpy as np

from simseam.math3d import matrix_to_quat, rotation_error
from simseam.scene.tasks.base import Evaluation, Task
from simseam.seam import ConfigError

POS_TOL = 0.02  # m
ROT_TOL = math.radians(10.0)
SPREAD = 0.3  # fraction of each joint's range around home
MAX_DQ = 0.8  # rad (m for prismatic joints: the range fraction alone bounds them)
MIN_HEIGHT = 0.05  # m above the table top (the base frame's z = 0 plane for tabletop tasks)
MIN_TRAVEL = 0.10  # m from the home tool position
MIN_RADIUS = 0.35  # of the robot's tabletop reach: the tool stays clear of the arm's own base column
DRAWS = 200


class Reach(Task):
    name = "reach"
    instruction = "move the tool to the target pose"
    max_steps = 150
    needs_gripper = False
    privileged_extras = ("target",)
    diagnostics = ("position_error", "orientation_error")

    def check_robot(self) -> None:
        super().check_robot()
        if self.chain is None:
            raise ConfigError(f"task {self.name!r} needs the robot's kinematic chain (a manifest scene)")

    def reset(self, engine, rng: np.random.Generator) -> None:
        chain = self.chain
        home = np.array([j.home for j in self.spec.arm_joints], dtype=np.float64)
        home = np.clip(home, chain.lower, chain.upper)
        lo, hi = np.maximum(chain.lower, home - 2 * np.pi), np.minimum(chain.upper, home + 2 * np.pi)
        half = np.minimum(SPREAD * (hi - lo), MAX_DQ)
        p_home = chain.forward(home)[0][:3, 3]
        tip = None
        for _ in range(DRAWS):
            q = np.clip(home + rng.uniform(-1.0, 1.0, chain.n) * half, chain.lower, chain.upper)
            t = chain.forward(q)[0]
            if (t[2, 3] >= MIN_HEIGHT and np.hypot(t[0, 3], t[1, 3]) >= MIN_RADIUS * self.reach
                    and np.linalg.norm(t[:3, 3] - p_home) >= MIN_TRAVEL):
                tip = t
                break
        if tip is None:
            raise ConfigError(f"task {self.name!r}: robot {self.spec.name!r} found no target pose "
                              f"{MIN_HEIGHT} m above the table within reach of its home posture")
        self.target_pos, self.target_rot = tip[:3, 3].copy(), tip[:3, :3].copy()

    def privileged(self, scene) -> dict[str, np.ndarray]:
        return {"target": np.concatenate([self.target_pos, matrix_to_quat(self.target_rot)])}

    def evaluate(self, scene) -> Evaluation:
        pos, rot = scene.eef_pose_base()
        e_pos = math.dist(np.asarray(pos).tolist(), np.asarray(self.target_pos).tolist())
        e_rot = math.hypot(*rotation_error(self.target_rot, rot).tolist())
        success = e_pos < POS_TOL and e_rot < ROT_TOL
        return Evaluation(float(success), success, {"position_error": e_pos, "orientation_error": e_rot})
