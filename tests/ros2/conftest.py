"""ROS 2 test fixtures: a private DDS domain per test run, loopback-only Cyclone, small scenes."""

import os
import random

import pytest

import cyclonedds  # noqa: F401  (a missing module fails, never skips: bootstrap installs simseam[dev])
import rosbags  # noqa: F401

from simseam.ros2.dds import loopback_config

# one domain per test run (pid-derived, so parallel runs on one machine do not cross-talk)
DOMAIN_ID = 100 + (os.getpid() + random.randrange(1000)) % 120

MOBILE_SCENE = """\
robot: panda_mobile
layout: nav_obstacles
image_size: [32, 32]
control_hz: 50
control_mode: joint_position
"""


@pytest.fixture
def ros_env(monkeypatch):
    """ROS_DOMAIN_ID and CYCLONEDDS_URI for this process and its children (loopback only)."""
    monkeypatch.setenv("ROS_DOMAIN_ID", str(DOMAIN_ID))
    monkeypatch.setenv("CYCLONEDDS_URI", loopback_config())
    return DOMAIN_ID


@pytest.fixture
def mobile_scene(tmp_path):
    path = tmp_path / "mobile.yaml"
    path.write_text(MOBILE_SCENE)
    return path
