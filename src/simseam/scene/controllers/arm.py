"""Arm controllers: turn the arm slots of an action into arm joint targets.

Both keep targets inside the joint limits and move them at most
``max_velocity / control_hz`` per control step (the URDF's joint speed limits).

- ``JointPositionArm``: one slot per arm joint (manifest order), absolute targets
  in rad (m for prismatic joints), bounded by the joint limits.
- ``CartesianDeltaArm``: ``[dx, dy, dz, dax, day, daz]`` in [-1, 1] times the
  robot's max step (m, rad), in the robot base frame; the rotation delta applies
  on the left (robosuite OSC_POSE / LIBERO). The delta adds to the previous
  end-effector target while the arm tracks its last command (within 1.5 cm /
  0.1 rad), else to the measured pose (blocked or disturbed: no wind-up). Damped
  least squares IK on the arm joints (``ik_iters`` Newton steps per control step,
  warm-started from the last target), null-space pull to the home posture.
"""

from __future__ import annotations

import math

import numpy as np

from simseam.math3d import axis_angle_times_rows, rotation_angle_rows
from simseam.robot.kinematics import IKResult, SerialChain
from simseam.seam import ActionSlot, ControlMode

CARTESIAN_NAMES = ("dx", "dy", "dz", "dax", "day", "daz")
REANCHOR_POS = 0.015  # m: tracking error beyond which a Cartesian delta restarts from the measured pose
REANCHOR_ROT = 0.1  # rad
ROT_WEIGHT = 0.5  # m/rad: orientation error weight in the IK


class ArmController:
    """Common part: joint limits and the per-step rate limit of arm targets."""

    group = "arm"
    control_mode: ControlMode

    def __init__(self, names: list[str], lower: np.ndarray, upper: np.ndarray, max_step: np.ndarray):
        self.names = tuple(names)
        self.lower, self.upper = np.asarray(lower, float), np.asarray(upper, float)
        self.max_step = np.asarray(max_step, float)  # rad (m) per control step

    def reset(self) -> None:
        """A new episode begins."""

    def rate_limit(self, q_new: np.ndarray, q_prev: np.ndarray) -> np.ndarray:
        return np.minimum(np.maximum(q_new, q_prev - self.max_step), q_prev + self.max_step)  # np.clip, cheaper


class JointPositionArm(ArmController):
    control_mode = ControlMode.JOINT_POSITION

    def __init__(self, names, lower, upper, max_step, units: list[str]):
        super().__init__(names, lower, upper, max_step)
        self.slots = tuple(ActionSlot(n, "arm", float(lo), float(hi), u)
                           for n, lo, hi, u in zip(self.names, self.lower, self.upper, units))

    def targets(self, values: np.ndarray, q_prev: np.ndarray, eef=None) -> np.ndarray:
        """Arm targets for slot values already within the joint limits."""
        return self.rate_limit(np.asarray(values, dtype=np.float64), q_prev)


class CartesianDeltaArm(ArmController):
    control_mode = ControlMode.CARTESIAN_DELTA

    def __init__(self, names, lower, upper, max_step, *, chain: SerialChain, q_home: np.ndarray,
                 max_translation: float, max_rotation: float, ik_iters: int = 1):
        super().__init__(names, lower, upper, max_step)
        self.chain = chain
        self.q_home = np.asarray(q_home, float)
        self.max_translation, self.max_rotation = float(max_translation), float(max_rotation)
        self.ik_iters = int(ik_iters)
        self._scale = np.array([self.max_translation] * 3 + [self.max_rotation] * 3)
        unit_t, unit_r = f"x {max_translation:g} m", f"x {max_rotation:g} rad"
        self.slots = tuple(ActionSlot(n, "arm", -1.0, 1.0, unit_t if i < 3 else unit_r)
                           for i, n in enumerate(CARTESIAN_NAMES))
        self.last_ik: IKResult | None = None
        #: the pose the next delta adds to: (position[3], rotation rows 3x3), Python floats
        self._ref: tuple[list[float], list[list[float]]] | None = None

    def reset(self) -> None:
        self._ref = None
        self.last_ik = None

    def targets(self, values: np.ndarray, q_prev: np.ndarray, eef: tuple[list, list]) -> np.ndarray:
        """Arm targets for a delta already in [-1, 1]; ``q_prev``: the last arm targets;
        ``eef``: the measured tool pose in the base frame, in Python floats (position, rotation rows):
        3-vectors and 3x3s cost less there than as numpy calls."""
        pos, rot = eef
        fk = self.chain.forward_rows(q_prev)  # the pose the last command asked for (reachable by construction)
        asked_pos, asked_rot, _ = fk
        if self._ref is None or (math.dist(asked_pos, pos) > REANCHOR_POS
                                 or rotation_angle_rows(asked_rot, rot) > REANCHOR_ROT):
            self._ref = (pos, rot)  # first step, blocked or disturbed: restart from the measured pose
        (x, y, z), ref_rot = self._ref
        dx, dy, dz, ax, ay, az = (values * self._scale).tolist()  # [m, m, m, rad, rad, rad]
        tgt_pos = [x + dx, y + dy, z + dz]
        tgt_rot = axis_angle_times_rows(ax, ay, az, ref_rot)
        ik = self.chain.solve(q_prev, tgt_pos, tgt_rot, max_iters=self.ik_iters, rot_weight=ROT_WEIGHT,
                              q_rest=self.q_home, start=fk)
        self.last_ik = ik
        self._ref = (tgt_pos, tgt_rot)
        return self.rate_limit(ik.q, q_prev)
