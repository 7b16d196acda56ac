"""bowl_plate: the LIBERO-shaped contract: "put the bowl on the plate".

Contract (LIBERO's): RGB ``camera1`` (third-person) and ``camera2`` (wrist),
256x256 by default; state 8-D ``[eef_pos(3), eef_axis_angle(3),
gripper_qpos(2)]`` for a two-finger gripper; action 7-D CARTESIAN_DELTA.
Bowl and plate positions are drawn from the seed on opposite sides of the
workspace. Success: the bowl rests on the plate: its centre within 6 cm of the
plate's, its bottom on the plate's top (+-1.5 cm), nearly still, and released
by the robot. Reward is sparse: 1.0 on success.
"""

from __future__ import annotations

import numpy as np

from simseam.engines.base import Engine, ObjectModel, Shape
from simseam.math3d import yaw_quat
from simseam.scene.tasks.base import TABLE_TOP, Task
from simseam.scene.tasks.batch import BatchEvaluation, Draw, TaskState, norm

BOWL_BASE_R = 0.045
BOWL_WALL_R = 0.052  # centre radius of the wall segments
BOWL_WALL_HALF = (0.004, 0.015, 0.02)  # radial, tangential, vertical half extents
BOWL_HEIGHT = 0.045
PLATE_R = 0.08
PLATE_HALF_H = 0.006
N_WALL = 12


def bowl_shapes() -> list[Shape]:
    """A bowl from primitives: a disc and a ring of wall segments (origin at the bottom centre)."""
    color = (0.15, 0.35, 0.8, 1.0)
    shapes = [Shape("cylinder", (BOWL_BASE_R + 0.004, 0.005), pos=(0.0, 0.0, 0.005), rgba=color)]
    for k in range(N_WALL):
        a = 2 * np.pi * k / N_WALL
        shapes.append(
            Shape(
                "box",
                BOWL_WALL_HALF,
                pos=(BOWL_WALL_R * np.cos(a), BOWL_WALL_R * np.sin(a), 0.005 + BOWL_WALL_HALF[2]),
                quat=tuple(yaw_quat(a)),
                rgba=color,
            )
        )
    return shapes


class BowlPlate(Task):
    name = "bowl_plate"
    instruction = "put the bowl on the plate"
    max_steps = 250
    image_size = (256, 256)
    required_rgb = ("camera1", "camera2")
    control_mode = "cartesian_delta"
    tracked_objects = ("bowl", "plate")
    diagnostics = ("bowl_to_plate", "bowl_on_plate", "released")
    geometry = {"bowl_wall_radius": BOWL_WALL_R, "bowl_height": BOWL_HEIGHT, "plate_height": 2 * PLATE_HALF_H}

    def build(self, engine: Engine) -> None:
        super().build(engine)
        engine.add_object(ObjectModel("bowl", bowl_shapes(), pos=(0.5, 0.15, TABLE_TOP), mass=0.12, friction=1.0))
        engine.add_object(
            ObjectModel(
                "plate",
                [Shape("cylinder", (PLATE_R, PLATE_HALF_H), pos=(0.0, 0.0, PLATE_HALF_H), rgba=(0.92, 0.92, 0.88, 1.0))],
                pos=(0.5, -0.15, TABLE_TOP),
                mass=0.4,
                friction=1.0,
            )
        )

    def sample(self, rng: np.random.Generator) -> Draw:
        cx, half = self.workspace()
        base, _ = self.robot_base()
        side = rng.choice([-1.0, 1.0])
        bowl = np.array([cx + rng.uniform(-0.4, 0.4) * half, side * rng.uniform(0.09, 0.14) * self.reach / 0.85])
        plate = np.array([cx + rng.uniform(-0.4, 0.4) * half, -side * rng.uniform(0.09, 0.14) * self.reach / 0.85])
        bowl_quat = yaw_quat(rng.uniform(-np.pi, np.pi))
        return Draw(poses={"bowl": (np.array([*(base[:2] + bowl), TABLE_TOP]), bowl_quat),
                           "plate": (np.array([*(base[:2] + plate), TABLE_TOP]), yaw_quat(0.0))})

    def evaluate_batch(self, state: TaskState) -> BatchEvaluation:
        xp = state.xp
        bowl, plate = state.object_pos("bowl"), state.object_pos("plate")
        offset = norm(xp, bowl[:, :2] - plate[:, :2])  # m, horizontal distance of the centres
        centred = offset < PLATE_R - 0.02
        on_top = xp.abs(bowl[:, 2] - (plate[:, 2] + 2 * PLATE_HALF_H)) < 0.015
        still = norm(xp, state.object_velocity("bowl")[:, :3]) < 0.05
        placed = centred & on_top & still
        released = ~state.contacts("bowl", "robot")
        success = placed & released
        return BatchEvaluation(success, success, {
            "bowl_to_plate": offset, "bowl_on_plate": centred & on_top, "released": released})
