"""lift_cube: a cube on a table; success when lifted 10 cm above its rest height.

Free-axis: any manifest robot with a gripper. The cube's position (within
the robot's reachable strip, scaled by its reach) and yaw (+-45 deg) are drawn
from the episode seed. Reward is sparse: 1.0 on success.
"""

from __future__ import annotations

import numpy as np

from simseam.engines.base import Engine, ObjectModel, Shape
from simseam.math3d import yaw_quat
from simseam.scene.tasks.base import TABLE_TOP, Task
from simseam.scene.tasks.batch import BatchEvaluation, Draw, TaskState, norm

CUBE_HALF = 0.02
LIFT_HEIGHT = 0.10
REST_Z = TABLE_TOP + CUBE_HALF  # world z of the cube's centre at rest


class LiftCube(Task):
    name = "lift_cube"
    instruction = "lift the red cube"
    max_steps = 150
    tracked_objects = ("cube",)
    diagnostics = ("cube_height", "eef_to_cube", "grasped")

    def build(self, engine: Engine) -> None:
        super().build(engine)
        engine.add_object(
            ObjectModel(
                "cube",
                [Shape("box", (CUBE_HALF,) * 3, rgba=(0.85, 0.12, 0.1, 1.0))],
                pos=(0.5, 0.0, TABLE_TOP + CUBE_HALF),
                mass=0.05,
                friction=1.2,
            )
        )

    def sample(self, rng: np.random.Generator) -> Draw:
        cx, half = self.workspace()
        x = cx + rng.uniform(-half, half) * 0.6
        y = rng.uniform(-half, half)
        yaw = rng.uniform(-np.pi / 4, np.pi / 4)
        base, _ = self.robot_base()
        return Draw(poses={"cube": (np.array([base[0] + x, base[1] + y, REST_Z]), yaw_quat(yaw))})

    def evaluate_batch(self, state: TaskState) -> BatchEvaluation:
        xp = state.xp
        pos = state.object_pos("cube")
        height = pos[:, 2] - REST_Z  # m above its resting height
        success = height > LIFT_HEIGHT
        lifted = height > 0.005
        return BatchEvaluation(success, success, {
            "cube_height": height,
            "eef_to_cube": norm(xp, state.eef_position_world() - pos),  # m, tool frame to cube
            "grasped": state.contacts("cube", "robot", where=lifted),  # asked only where lifted (False elsewhere)
        })
