"""ROS 2 test fixtures: a private DDS domain per test run, loopback-only Cyclone, small scenes."""

import os
import random

import pytest

import cyclonedds  # noqa: F401  (a missing module fails, never skips: bootstrap installs simseam[dev])
import rosbags  # noqa: F401

from simseam.ros2.dds import loopback_config

# one domain per test run (pid-derived, so parallel runs on one machine do not cross-talk)
DOMAIN_ID = 100 + (os.getpid() + random.randrange(1000)) % 120



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


# ------------------------------------------------------------------ real peers (scripts/setup_ros_peers.sh)
import shutil  # noqa: E402
import sys  # noqa: E402
from pathlib import Path  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent / "peers"))
from harness import MOBILE_SCENE, SETUP_HINT, NetNS, netns_possible, pinned_dir  # noqa: E402


@pytest.fixture(scope="session")
def ros_peer_python() -> Path:
    """The ROS 2 Jazzy venv's python (rclpy + rmw_fastrtps_cpp). Missing is a failure, not a skip."""
    d = pinned_dir("ros-jazzy", "ros-peer-pins.txt")
    if not (d / ".ready").exists():
        pytest.fail(f"the ROS 2 Jazzy test peer is not installed at {d}: {SETUP_HINT}")
    return d / "bin" / "python"


@pytest.fixture(scope="session")
def foxglove_client_dir() -> Path:
    d = pinned_dir("foxglove-client", "foxglove-client-pins.json")
    if not (d / ".ready").exists():
        pytest.fail(f"the Foxglove test client is not installed at {d}: {SETUP_HINT}")
    if shutil.which("node") is None:
        pytest.fail("node is not on PATH (the Foxglove test client runs under node)")
    return d


@pytest.fixture
def netns():
    why = netns_possible()
    if why:
        pytest.skip(why)
    ns = NetNS()
    yield ns
    ns.close()
