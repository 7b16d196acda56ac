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

from simseam.scene.tasks.base import Task
from simseam.scene.tasks.batch import BatchEvaluation, Draw, TaskState, matrix_to_quat, norm, rotation_angle
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

    def sample(self, rng: np.random.Generator) -> Draw:
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
        return Draw(params={"target_pos": tip[:3, 3].copy(), "target_rot": tip[:3, :3].copy()})

    def extra_poses(self, state: TaskState) -> dict:
        p = state.params
        return {"target": state.xp.concatenate([p["target_pos"], matrix_to_quat(state.xp, p["target_rot"])], axis=-1)}

    def evaluate_batch(self, state: TaskState) -> BatchEvaluation:
        xp, p = state.xp, state.params
        pos, rot = state.eef_pose_base()
        e_pos = norm(xp, pos - p["target_pos"])
        e_rot = rotation_angle(xp, p["target_rot"], rot)
        success = (e_pos < POS_TOL) & (e_rot < ROT_TOL)
        return BatchEvaluation(success, success,
                               {"position_error": e_pos, "orientation_error": e_rot})
