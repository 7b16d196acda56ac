"""lift_cube: a cube on a table; success when lifted 10 cm above its rest height.

Free-axis: any manifest robot with a gripper. The cube's position (within
the robot's reachable strip, scaled by its reach) and yaw (+-45 deg) are drawn
from the episode seed. Reward is sparse: 1.0 on success.
"""

from __future__ import annotations

import math

import numpy as np

from simseam.engines.base import Engine, ObjectModel, Shape
from simseam.math3d import yaw_quat
from simseam.scene.tasks.base import TABLE_TOP, Evaluation, Task

CUBE_HALF = 0.02
LIFT_HEIGHT = 0.10


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

    def reset(self, engine: Engine, rng: np.random.Generator) -> None:
        cx, half = self.workspace()
        x = cx + rng.uniform(-half, half) * 0.6
        y = rng.uniform(-half, half)
        yaw = rng.uniform(-np.pi / 4, np.pi / 4)
        base, _ = self.robot_base()
        self.rest_z = TABLE_TOP + CUBE_HALF
        engine.set_object_pose("cube", np.array([base[0] + x, base[1] + y, self.rest_z]), yaw_quat(yaw))

    def evaluate(self, scene) -> Evaluation:
        eng = scene.engine
        pos = eng.object_pose("cube")[0].tolist()  # plain floats: the same numbers, fewer numpy calls
        height = pos[2] - self.rest_z
        success = height > LIFT_HEIGHT
        eef = scene.eef_position_world()
        return Evaluation(float(success), success, {
            "cube_height": height,  # m above its resting height
            "eef_to_cube": math.dist(eef.tolist(), pos),  # m, tool frame to cube centre
            "grasped": height > 0.005 and bool(eng.contacts_between("cube", "robot")),  # contacts: only when lifted
        })
