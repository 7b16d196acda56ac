"""The LaserScan the bridge publishes, read back as a ROS consumer reads it: beam ``i`` looks along
``angle_min + i * angle_increment`` (counter-clockwise, in ``header.frame_id``), so an obstacle placed
to the robot's left shows up to its left."""

import dataclasses
import math

import numpy as np
import pytest

from simseam.math3d import yaw_quat
from simseam.ros2 import convert as cv

RADIUS = 0.22  # nav_obstacles' cylinder


@pytest.mark.parametrize("fov_deg, beams, yaw", [(360.0, 360, 0.0), (180.0, 181, 0.5)],
                         ids=["360 deg", "180 deg, mount turned 0.5 rad"])
def test_an_obstacle_to_the_left_is_at_the_angle_the_scan_message_gives(mobile_spec, make_scene, fov_deg, beams, yaw):
    """Catches: LaserScan ``angle_increment`` with its sign flipped (the left obstacle read on the right)."""
    lidar = mobile_spec.sensors_of("lidar_2d")[0]
    lidar = dataclasses.replace(lidar, fov_deg=fov_deg, beams=beams, rpy=(0.0, 0.0, yaw))
    spec = dataclasses.replace(mobile_spec, sensors=[lidar if s.kind == "lidar_2d" else s for s in mobile_spec.sensors])
    scene = make_scene(spec, task="nav_obstacles", render_images=False, control_mode="joint_position")
    scene.reset(0)
    for k in range(6):  # every obstacle out of range but one, 1.5 m to the left of the base (the lidar's centre)
        scene.engine.set_object_pose(f"obstacle{k}", np.array([60.0 + 3 * k, 60.0, 0.0]), yaw_quat(0.0))
    scene.engine.set_object_pose("obstacle1", np.array([0.0, 1.5, 0.0]), yaw_quat(0.0))
    home = np.array([j.home for j in spec.arm_joints])
    ranges = scene.step(scene.spec.action.pack(arm=home, grip=-1.0)).observation["scan"]
    facts = scene.spec.robot.sensors_of("lidar_2d")[0]
    msg = cv.scan_msg(ranges, facts, 0, cv.scan_frame(facts, scene.spec.robot.base_link))
    assert msg.header.frame_id == (facts.name if yaw == 0.0 else scene.spec.robot.base_link)
    assert len(msg.ranges) == beams
    r = np.asarray(msg.ranges)
    hits = np.flatnonzero(np.isfinite(r))
    assert 5 <= len(hits) <= 25, hits  # the cylinder spans about +-8.4 deg
    angles = msg.angle_min + hits * msg.angle_increment
    x, y = r[hits] * np.cos(angles), r[hits] * np.sin(angles)  # each return, as a ROS consumer places it
    assert math.atan2(y.mean(), x.mean()) == pytest.approx(math.pi / 2, abs=0.03)
    nearest = msg.angle_min + int(np.argmin(r)) * msg.angle_increment
    assert math.remainder(nearest - math.pi / 2, 2 * math.pi) == pytest.approx(0.0, abs=math.radians(1.5))
    assert r.min() == pytest.approx(1.5 - RADIUS, abs=0.02)
    assert msg.angle_max == pytest.approx(msg.angle_min + (beams - 1) * msg.angle_increment)
