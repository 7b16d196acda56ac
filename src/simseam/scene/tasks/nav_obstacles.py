"""nav_obstacles: drive a mobile base to a goal pose between static obstacles.

The robot starts at the origin facing +x. Obstacles (boxes and cylinders, 4-6
of them) and the goal pose (2.5-3.5 m ahead, +-1.2 m sideways, any heading) are
drawn from the seed; obstacles keep 1 m clear of the start and of the goal and 1.6 m apart (centres).
Success: the base within 0.2 m and 0.3 rad of the goal, and no obstacle touched
during the episode (a touch is a failure that cannot be undone). The goal pose
is ground truth in ``privileged['objects']['goal']`` (base frame). Needs a robot
with a kinematic base; the scripted policy also needs its 2-D lidar.
"""

from __future__ import annotations

import math

import numpy as np

from simseam.engines.base import Engine, ObjectModel, Shape
from simseam.math3d import yaw_quat
from simseam.scene.tasks.base import Task
from simseam.scene.tasks.batch import BatchEvaluation, Draw, TaskState, norm, wrap_angle, yaw_quats
from simseam.seam import ConfigError

N_OBSTACLES = 6
GOAL_POS_TOL = 0.2
GOAL_YAW_TOL = 0.3
CLEARANCE = 1.0
PARKED_X = -8.0  # unused obstacles wait behind the start, out of the way, on the floor


class NavObstacles(Task):
    name = "nav_obstacles"
    instruction = "drive to the goal without touching anything"
    max_steps = 400
    needs_gripper = False
    diagnostics = ("distance_to_goal", "yaw_error", "touched")
    privileged_extras = ("goal",)

    def check_robot(self) -> None:
        super().check_robot()
        if self.spec.kinematic_base is None:
            raise ConfigError(f"task {self.name!r} needs robot {self.spec.name!r} to declare a kinematic_base")

    def robot_base(self) -> tuple[np.ndarray, float]:
        return np.array([0.0, 0.0, self.spec.kinematic_base.height]), 0.0

    def build(self, engine: Engine) -> None:
        engine.add_ground()
        # Obstacles are built once and moved per episode: static in physics, placed by reset.
        for k in range(N_OBSTACLES):
            shape = (Shape("box", (0.2, 0.3, 0.4), pos=(0, 0, 0.4), rgba=(0.75, 0.55, 0.2, 1)) if k % 2 == 0 else
                     Shape("cylinder", (0.22, 0.4), pos=(0, 0, 0.4), rgba=(0.3, 0.55, 0.75, 1)))
            engine.add_object(ObjectModel(f"obstacle{k}", [shape], pos=(PARKED_X - 1.5 * k, 0.0, 0.0), dynamic=True,
                                          mass=50.0))

    def sample(self, rng: np.random.Generator) -> Draw:
        """The goal, then 4-6 obstacles placed clear of the start, the goal and each other (the rest parked);
        params: ``goal`` [x, y, yaw], ``active`` (which obstacles take part), ``touched`` (False: a touch
        during the episode is carried over by ``evaluate_batch``)."""
        goal = np.array([rng.uniform(2.5, 3.5), rng.uniform(-1.2, 1.2), rng.uniform(-math.pi, math.pi)])
        n = int(rng.integers(4, N_OBSTACLES + 1))
        placed: list[np.ndarray] = []
        poses = {}
        for k in range(N_OBSTACLES):
            pos = np.array([PARKED_X - 1.5 * k, 0.0, 0.0])
            if k < n:
                for _ in range(100):
                    p = np.array([rng.uniform(0.6, goal[0] - 0.2), rng.uniform(-1.8, 1.8)])
                    if (np.linalg.norm(p) > CLEARANCE and np.linalg.norm(p - goal[:2]) > CLEARANCE
                            and all(np.linalg.norm(p - q) > 1.6 for q in placed)):
                        placed.append(p)
                        pos = np.array([p[0], p[1], 0.0])
                        break
            poses[f"obstacle{k}"] = (pos, yaw_quat(rng.uniform(-math.pi, math.pi)))
        active = np.arange(N_OBSTACLES) < len(placed)
        return Draw(poses=poses, params={"goal": goal, "active": active, "touched": np.array(False)})

    def extra_poses(self, state: TaskState) -> dict:
        xp, goal = state.xp, state.params["goal"]
        return {"goal": state.to_base(xp.stack([goal[:, 0], goal[:, 1], xp.zeros_like(goal[:, 0])], axis=-1),
                                      yaw_quats(xp, goal[:, 2]))}

    def evaluate_batch(self, state: TaskState) -> BatchEvaluation:
        xp, p = state.xp, state.params
        touched, active = p["touched"], p["active"]
        for k in range(N_OBSTACLES):  # a touch cannot be undone: once touched, no more contact checks
            touched = touched | state.contacts("robot", f"obstacle{k}", where=active[:, k] & ~touched)
        p["touched"] = touched
        base, goal = state.base_pose(), p["goal"]
        dyaw = xp.abs(wrap_angle(xp, goal[:, 2] - base[:, 2]))
        dist = norm(xp, goal[:, :2] - base[:, :2])
        success = ~touched & (dist < GOAL_POS_TOL) & (dyaw < GOAL_YAW_TOL)
        return BatchEvaluation(success, success,
                               {"distance_to_goal": dist, "yaw_error": dyaw, "touched": touched})
