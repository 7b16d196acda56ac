"""The kinematic holonomic base: BODY_TWIST in, planar pose out (numpy only).

The pose ``[x, y, yaw]`` is the base link in the world (m, m, rad). A twist
``[vx, vy, wz]`` is in the base frame (m/s, rad/s), already within the bounds
of the rollout's action spec (``scene.controllers.TwistBase`` states them).
Integration is exact for a twist held constant over the interval (the base
follows the arc).
"""

from __future__ import annotations

import math

import numpy as np

from simseam.robot.spec import KinematicBaseSpec


class KinematicBase:
    def __init__(self, spec: KinematicBaseSpec):
        self.spec = spec
        self.pose = np.zeros(3)
        self.velocity = np.zeros(3)  # world-frame [xdot, ydot, yawdot] of the last interval

    def reset(self, x: float, y: float, yaw: float) -> None:
        self.pose[:] = (x, y, yaw)
        self.velocity[:] = 0.0

    def advance(self, twist: np.ndarray, dt: float) -> None:
        """Move along a clipped body twist held for ``dt`` seconds."""
        vx, vy, wz = twist
        x, y, yaw = self.pose
        yaw1 = yaw + wz * dt
        if abs(wz * dt) < 1e-9:
            c, s = math.cos(yaw), math.sin(yaw)
            dx, dy = (vx * c - vy * s) * dt, (vx * s + vy * c) * dt
        else:
            ds, dc = math.sin(yaw1) - math.sin(yaw), math.cos(yaw) - math.cos(yaw1)
            dx, dy = (vx * ds - vy * dc) / wz, (vx * dc + vy * ds) / wz
        self.pose[:] = (x + dx, y + dy, math.atan2(math.sin(yaw1), math.cos(yaw1)))
        if dt > 0:
            self.velocity[:] = (dx / dt, dy / dt, wz)
