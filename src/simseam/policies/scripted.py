"""Scripted experts: state machines over privileged ground truth.

They drive CARTESIAN_DELTA actions (``reach``'s expert also JOINT_POSITION) with a
saturated proportional controller towards waypoints in the robot base frame, keeping
the end effector's reset orientation (gripper down for a tabletop arm) and turning
only about the base z axis to line the fingers up. Their success rate is the proof that tasks,
IK and the gripper convention are right.
"""

from __future__ import annotations

from collections.abc import Callable
from typing import Any

import numpy as np

from simseam import registry
from simseam.math3d import quat_to_matrix, rotation_error
from simseam.policies.base import BasePolicy
from simseam.policies.navigation import NavExpert
from simseam.robot.kinematics import SerialChain
from simseam.seam import (OBS_EXPERT_ACTION, OBS_JOINT_POSITIONS, OBS_PRIVILEGED, ActionSpec, ConfigError, ControlMode,
                          Observation, RolloutSpec)

OPEN, CLOSE = -1.0, 1.0


def _rz(yaw: float) -> np.ndarray:
    c, s = np.cos(yaw), np.sin(yaw)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def _nearest_equivalent(angle: float, reference: float, period: float) -> float:
    """``angle + k * period`` closest to ``reference``."""
    return angle + period * np.round((reference - angle) / period)


class _CartesianExpert:
    """Waypoint following with a P-controller saturated at the action bounds.

    A saturated command is scaled as a whole, not clipped per axis, so the tool moves in a straight
    line to the waypoint: a lateral error shrinks in proportion over the whole approach instead of
    vanishing in the first step or two while the long axis is still saturated. Demonstrations then
    hold, at every step of the approach, the lateral correction that matches the lateral error, which
    is what a policy cloned from them must reproduce when its own approach drifts.
    """

    gain = 0.5  # per-step fraction of the position error to close
    rot_gain = 0.2  # same for orientation (the wrist lags more: keep it calm)

    def __init__(self, action: ActionSpec, down_rot: np.ndarray):
        self.action = action
        self.max_t = action.max_translation
        self.max_r = action.max_rotation
        self.down = down_rot  # reset orientation of the end effector (base frame)
        self.phase = 0
        self.timer = 0

    def yaw_of(self, rot: np.ndarray) -> float:
        """Yaw of an end-effector rotation relative to the reset orientation."""
        rel = rot @ self.down.T
        return float(np.arctan2(rel[1, 0], rel[0, 0]))

    def command(self, eef: np.ndarray, target_pos: np.ndarray, target_yaw: float, grip: float,
                speed: float = 1.0) -> np.ndarray:
        pos, rot = eef[:3], quat_to_matrix(eef[3:])
        dpos = self.gain * (target_pos - pos) / self.max_t
        dpos *= min(1.0, speed / max(float(np.abs(dpos).max()), 1e-12))  # a straight line to the target
        drot = np.clip(self.rot_gain * rotation_error(_rz(target_yaw) @ self.down, rot) / self.max_r, -0.5, 0.5)
        return self.action.pack(arm=np.concatenate([dpos, drot]), grip=grip)

    def advance(self) -> None:
        self.phase += 1
        self.timer = 0


class LiftExpert(_CartesianExpert):
    """Above the cube, yaw-aligned -> down -> close -> lift 20 cm."""

    def act(self, priv: dict, obs: dict | None = None) -> np.ndarray:
        eef = priv["eef_pose"]
        cube = priv["objects"]["cube"]
        cube_yaw = self.yaw_of(quat_to_matrix(cube[3:]))
        yaw = _nearest_equivalent(cube_yaw, self.yaw_of(quat_to_matrix(eef[3:])), np.pi / 2)
        self.timer += 1
        err = lambda p: float(np.linalg.norm(p - eef[:3]))  # noqa: E731
        above = cube[:3] + [0.0, 0.0, 0.08]
        if self.phase == 0:  # hover above the cube, aligned
            if (err(above) < 0.01 and abs(self.yaw_of(quat_to_matrix(eef[3:])) - yaw) < 0.05) or self.timer > 60:
                self.advance()
            return self.command(eef, above, yaw, OPEN)
        if self.phase == 1:  # descend around it
            grasp = cube[:3] + [0.0, 0.0, 0.005]
            if err(grasp) < 0.008 or self.timer > 40:
                self.advance()
            return self.command(eef, grasp, yaw, OPEN, speed=0.6)
        if self.phase == 2:  # close
            if self.timer > 6:
                self.advance()
                self.lift_to = eef[:3] + [0.0, 0.0, 0.2]
            return self.command(eef, eef[:3], yaw, CLOSE)
        return self.command(eef, self.lift_to, yaw, CLOSE, speed=0.6)


class BowlPlateExpert(_CartesianExpert):
    """Grip the bowl's wall on the side facing the robot, carry it over the plate, set it down, let go.
    The props' sizes come from the task's spec (``spec.task.geometry``)."""

    def __init__(self, spec: RolloutSpec, down_rot: np.ndarray):
        super().__init__(spec.action, down_rot)
        task = spec.task
        self.wall_r, self.bowl_h, self.plate_h = (task.size(k) for k in ("bowl_wall_radius", "bowl_height",
                                                                          "plate_height"))

    def act(self, priv: dict, obs: dict | None = None) -> np.ndarray:
        eef = priv["eef_pose"]
        bowl, plate = priv["objects"]["bowl"], priv["objects"]["plate"]
        self.timer += 1
        err = lambda p: float(np.linalg.norm(p - eef[:3]))  # noqa: E731
        cur_yaw = self.yaw_of(quat_to_matrix(eef[3:]))
        if self.phase <= 2:
            u = -bowl[:2] / np.linalg.norm(bowl[:2])  # towards the robot base
            # Fingers close along the hand's y axis: point it along u (radially).
            y_axis = self.down @ np.array([0.0, 1.0, 0.0])
            base_yaw = np.arctan2(u[1], u[0]) - np.arctan2(y_axis[1], y_axis[0])
            self.yaw = _nearest_equivalent(base_yaw, cur_yaw, np.pi)
            self.grasp = np.array([*(bowl[:2] + self.wall_r * u), bowl[2] + self.bowl_h - 0.017])
        if self.phase == 0:  # above the wall
            above = self.grasp + [0.0, 0.0, 0.08]
            if (err(above) < 0.01 and abs(cur_yaw - self.yaw) < 0.05) or self.timer > 60:
                self.advance()
            return self.command(eef, above, self.yaw, OPEN)
        if self.phase == 1:  # straddle the wall
            if err(self.grasp) < 0.006 or self.timer > 40:
                self.advance()
            return self.command(eef, self.grasp, self.yaw, OPEN, speed=0.6)
        if self.phase == 2:  # close
            if self.timer > 6:
                self.advance()
                self.hold = eef[:3] - bowl[:3]  # bowl -> hand offset while carried
            return self.command(eef, eef[:3], self.yaw, CLOSE)
        plate_top = plate[2] + self.plate_h
        over = np.array([*(plate[:2] + self.hold[:2]), plate_top + self.hold[2] + 0.12])
        if self.phase == 3:  # lift
            lift = np.array([*eef[:2], over[2]])
            if err(lift) < 0.02 or self.timer > 30:
                self.advance()
            return self.command(eef, lift, self.yaw, CLOSE)
        if self.phase == 4:  # carry over the plate
            if err(over) < 0.01 or self.timer > 80:
                self.advance()
            return self.command(eef, over, self.yaw, CLOSE)
        if self.phase == 5:  # lower onto the plate
            down = over - [0.0, 0.0, 0.11]
            if err(down) < 0.008 or self.timer > 40:
                self.advance()
            return self.command(eef, down, self.yaw, CLOSE, speed=0.5)
        if self.phase == 6:  # release
            if self.timer > 6:
                self.advance()
            return self.command(eef, eef[:3], self.yaw, OPEN)
        return self.command(eef, eef[:3] + [0.0, 0.0, 0.1], self.yaw, OPEN, speed=0.5)  # back off


class ReachExpert:
    """Bring the tool frame to ``privileged['objects']['target']``; the gripper holds its opening.

    CARTESIAN_DELTA: a saturated P-controller on position and orientation. JOINT_POSITION: inverse
    kinematics once, from the measured joints, on the chain built from ``spec.robot`` alone (the
    policy's own ``SerialChain.of_robot``), then that joint target every step.
    """

    gain = 0.5
    rot_gain = 0.3

    def __init__(self, spec: RolloutSpec):
        self.spec = spec
        self.layout = spec.action
        self.grip: float | None = None
        self.q_goal: np.ndarray | None = None

    def act(self, priv: dict, obs: dict) -> np.ndarray:
        spec, layout = self.spec, self.layout
        target = priv["objects"]["target"]
        t_pos, t_rot = np.asarray(target[:3], dtype=np.float64), quat_to_matrix(target[3:])
        names = spec.robot.joint_names
        q = np.asarray(obs[OBS_JOINT_POSITIONS], dtype=np.float64)
        if self.grip is None and layout.has_gripper:
            g = spec.robot.gripper
            self.grip = g.command_of(q[[names.index(n) for n in g.joints]])
        if spec.control_mode == ControlMode.JOINT_POSITION:
            if self.q_goal is None:
                chain = SerialChain.of_robot(spec.robot)
                q_arm = q[[names.index(n) for n in layout.arm_names]]
                self.q_goal = chain.solve(q_arm, t_pos, t_rot, max_iters=300, q_rest=q_arm).q
            arm = self.q_goal
        else:
            eef = priv["eef_pose"]
            pos, rot = eef[:3], quat_to_matrix(eef[3:])
            arm = np.concatenate([np.clip(self.gain * (t_pos - pos) / layout.max_translation, -1.0, 1.0),
                                  np.clip(self.rot_gain * rotation_error(t_rot, rot) / layout.max_rotation, -1, 1)])
        return layout.pack(arm=arm, grip=self.grip)


def lift_expert(spec: RolloutSpec, down_rot: np.ndarray) -> LiftExpert:
    return LiftExpert(spec.action, down_rot)


def nav_expert(spec: RolloutSpec, down_rot: np.ndarray) -> NavExpert:
    return NavExpert(spec.action, down_rot)


def reach_expert(spec: RolloutSpec, down_rot: np.ndarray) -> ReachExpert:
    return ReachExpert(spec)


#: the scripted expert of each task (simseam.registry: "module:factory", imported when asked for), where
#: ``factory(spec, down_rot)`` gives an expert whose ``act(privileged, observation)`` returns the action
EXPERTS: dict[str, str | Callable[[RolloutSpec, np.ndarray], Any]] = {
    "lift_cube": "simseam.policies.scripted:lift_expert",
    "bowl_plate": "simseam.policies.scripted:BowlPlateExpert",
    "nav_obstacles": "simseam.policies.scripted:nav_expert",
    "reach": "simseam.policies.scripted:reach_expert",
}
_ANY_MODE = {"reach"}  # experts that drive joint_position too


class ScriptedPolicy(BasePolicy):
    """Dispatches to the expert of the rollout's task. Needs privileged observations.
    On a benchmark that ships its own experts (Meta-World) the rollout declares
    ``expert_action``: the benchmark's expert, run beside the simulator, is replayed as is."""

    requires_privileged = True

    def reset(self, spec: RolloutSpec) -> None:
        super().reset(spec)
        self._benchmark_expert = spec.observation.has(OBS_EXPERT_ACTION)
        if self._benchmark_expert:
            return
        self._make_expert = registry.load(EXPERTS, spec.task.name, "scripted expert for task")
        if spec.control_mode != ControlMode.CARTESIAN_DELTA and spec.task.name not in _ANY_MODE:
            raise ConfigError(f"the scripted expert for {spec.task.name!r} drives cartesian_delta; "
                              "set control_mode: cartesian_delta")
        self._expert = None

    def act(self, observation: Observation) -> np.ndarray:
        if self._benchmark_expert:
            return np.asarray(observation[OBS_EXPERT_ACTION], dtype=np.float32).copy()
        priv = observation.get(OBS_PRIVILEGED)
        if priv is None:
            raise ConfigError("the scripted expert needs privileged observations (build the scene with privileged=True)")
        if self._expert is None:
            down = quat_to_matrix(priv["eef_pose"][3:])
            self._expert = self._make_expert(self.spec, down)
        return self._expert.act(priv, observation)
