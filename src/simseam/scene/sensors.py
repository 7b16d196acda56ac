"""Range sensors computed by the scene from engine primitives (numpy only).

- ``DepthCloud``: an engine depth image (metres along the optical axis) and the
  sensor's intrinsics (vertical field of view, square pixels) -> a point cloud in
  the robot's ``base_link`` frame, float32 (N, 3), clipped to [range_min, range_max].
- ``Lidar2D``: ``beams`` rays in the base_link xy plane from the mount position,
  one batched engine ray cast (never a Python loop per beam), the robot's own
  bodies never hit. Beam ``i`` points at ``-pi + i * 2pi / beams`` (360 deg) or
  spans ``fov_deg`` centred on the mount's heading, counter-clockwise. Each ray
  starts at ``range_min``; no hit reads ``range_max``.

Mount frames follow REP-103 (+x forward, +y left, +z up) relative to the
sensor's parent link.
"""

from __future__ import annotations

import math

import numpy as np

from simseam.math3d import rpy_to_matrix
from simseam.seam import SensorFacts


def intrinsics(width: int, height: int, fovy_deg: float) -> tuple[float, float, float, float]:
    """(fx, fy, cx, cy) in pixels for a pinhole camera with square pixels."""
    fy = (height / 2.0) / math.tan(math.radians(fovy_deg) / 2.0)
    return fy, fy, width / 2.0, height / 2.0


class DepthCloud:
    """Depth image -> base_link point cloud for one depth sensor."""

    def __init__(self, sensor: SensorFacts, width: int, height: int):
        self.sensor = sensor
        fx, fy, cx, cy = intrinsics(width, height, sensor.fovy_deg)
        v, u = np.mgrid[0:height, 0:width].astype(np.float64)
        # Mount frame: x along the optical axis (depth), y left, z up; pixel centres.
        rays = np.stack([np.ones_like(u), -(u + 0.5 - cx) / fx, -(v + 0.5 - cy) / fy], axis=-1)
        self._rays = rays.reshape(-1, 3).astype(np.float32)
        self._mount_rot = rpy_to_matrix(sensor.rpy)
        self._mount_pos = np.asarray(sensor.xyz, dtype=np.float64)
        self._cache_key: bytes | None = None
        self._rays_base: np.ndarray | None = None

    def points(self, depth: np.ndarray, parent_rot: np.ndarray, parent_pos: np.ndarray) -> np.ndarray:
        """``depth`` (H, W) metres; ``parent_rot``/``parent_pos``: the parent link in base_link."""
        rot = parent_rot @ self._mount_rot
        pos = (parent_rot @ self._mount_pos + parent_pos).astype(np.float32)
        key = rot.tobytes()
        if key != self._cache_key:  # rays in base_link: recomputed only when the camera turned
            self._rays_base = self._rays @ rot.T.astype(np.float32)
            self._cache_key = key
        d = depth.reshape(-1).astype(np.float32, copy=False)
        keep = (d >= self.sensor.range_min) & (d <= self.sensor.range_max)
        pts = self._rays_base.compress(keep, axis=0)  # compress: ~4x faster than boolean indexing
        pts *= d.compress(keep)[:, None]
        pts += pos
        return pts


class Lidar2D:
    """A planar scanner: ranges (float32, ``beams``) in the base_link xy plane."""

    def __init__(self, sensor: SensorFacts):
        self.sensor = sensor
        n = sensor.beams
        if sensor.fov_deg >= 360.0:
            angles = -np.pi + np.arange(n) * (2 * np.pi / n)
        else:
            heading = float(sensor.rpy[2])
            fov = math.radians(sensor.fov_deg)
            angles = heading - fov / 2 + np.arange(n) * (fov / max(n - 1, 1))
        self.angles = angles
        self._dirs = np.stack([np.cos(angles), np.sin(angles), np.zeros(n)], axis=1)
        self._mount_pos = np.asarray(sensor.xyz, dtype=np.float64)

    def scan(self, engine, base_rot: np.ndarray, base_pos: np.ndarray, parent_rot: np.ndarray,
             parent_pos: np.ndarray) -> np.ndarray:
        """Cast the fan. ``base_rot``/``base_pos``: base_link in the world; ``parent_*``: the
        parent link in base_link."""
        s = self.sensor
        origin = base_rot @ (parent_rot @ self._mount_pos + parent_pos) + base_pos
        dirs = self._dirs @ base_rot.T
        dist = engine.cast_rays(origin, dirs, s.range_max)
        near = np.flatnonzero(dist < s.range_min)
        for i in near:  # rare: something inside range_min; the beam really starts at range_min
            start = origin + dirs[i] * s.range_min
            dist[i] = s.range_min + engine.cast_rays(start, dirs[i:i + 1], s.range_max - s.range_min)[0]
        return np.minimum(dist, s.range_max).astype(np.float32)
