"""Scripted navigation for a holonomic base: pick the free heading nearest the goal.

Works in the base frame on what a real robot has: the 2-D scan (``observation
['scan']``, beam 0 at -pi, counter-clockwise, measured from the base centre) and
the goal pose (here from ``privileged['objects']['goal']``, as a localization
stack would give it). Each step it sweeps the base's footprint (a disc) along 72
candidate headings through the scan points, keeps those with enough free room,
and drives along the one closest to the goal direction (with a little hysteresis
so it commits to one side of an obstacle), slowing down near obstacles and the
goal, while turning towards the goal heading. The arm holds; the gripper stays open.
"""

from __future__ import annotations

import math

import numpy as np

from simseam.math3d import quat_to_matrix
from simseam.seam import ActionSpec


class NavExpert:
    max_speed = 0.5  # m/s
    robot_radius = 0.42  # m: the chassis' half diagonal
    margin = 0.05  # m of extra clearance
    look_ahead = 0.6  # m of free room wanted along the chosen heading
    yaw_gain = 1.2

    def __init__(self, action: ActionSpec, _down_rot=None):
        self.action = action
        self.headings = np.linspace(-np.pi, np.pi, 72, endpoint=False)
        self._u = np.stack([np.cos(self.headings), np.sin(self.headings)], axis=1)
        self._angles = None
        self._last = None

    def free_distance(self, points: np.ndarray) -> np.ndarray:
        """Distance the footprint can travel along each candidate heading before touching a point."""
        r = self.robot_radius + self.margin
        along = self._u @ points.T  # (headings, points)
        cross = np.abs(self._u[:, :1] * points[:, 1] - self._u[:, 1:] * points[:, 0])
        hit = (along > 0) & (cross < r)
        stop = np.where(hit, along - np.sqrt(np.maximum(r * r - cross * cross, 0.0)), np.inf)
        return np.maximum(stop.min(axis=1), 0.0)

    def act(self, priv: dict, obs: dict) -> np.ndarray:
        goal = priv["objects"]["goal"]
        g = np.asarray(goal[:2], dtype=np.float64)
        dist = float(np.hypot(*g))
        rot = quat_to_matrix(goal[3:])
        yaw_err = math.atan2(rot[1, 0], rot[0, 0])
        scan = np.asarray(obs["scan"], dtype=np.float64)
        if self._angles is None or len(self._angles) != len(scan):
            self._angles = -np.pi + np.arange(len(scan)) * (2 * np.pi / len(scan))
        points = (scan[:, None] * np.stack([np.cos(self._angles), np.sin(self._angles)], axis=1))[scan < 9.0]
        free = self.free_distance(points) if len(points) else np.full(len(self.headings), np.inf)

        want = min(dist, self.look_ahead)
        score = self._u @ (g / max(dist, 1e-6))
        if self._last is not None:
            score = score + 0.15 * (self._u @ self._last)
        ok = free >= want
        j = int(np.argmax(np.where(ok, score, -np.inf))) if ok.any() else int(np.argmax(free))
        speed = min(self.max_speed, 1.5 * dist, max(0.0, 0.8 * (free[j] - 0.05)))
        v = self._u[j] * speed
        self._last = self._u[j]
        wz = float(np.clip(self.yaw_gain * yaw_err, -1.0, 1.0))
        if dist < 0.05:
            v[:] = g * 1.5  # final approach: straight in, slowly
        return self.action.pack(grip=-1.0 if self.action.has_gripper else None, base=[v[0], v[1], wz])
