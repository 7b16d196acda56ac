#!/usr/bin/env bash
# Real peers for tests/ros2, cached OUTSIDE the repo and keyed by their pins:
#   ~/.cache/simseam/ros-jazzy-<hash>/        a Python 3.11 venv with rclpy + Fast DDS (ros-peer-pins.txt)
#   ~/.cache/simseam/foxglove-client-<hash>/  @foxglove/ws-protocol & decoders under node (foxglove-client-pins.json)
# Idempotent (a stamp file per cache dir). Prints the two paths as KEY=VALUE lines.
# Usage: bash scripts/setup_ros_peers.sh   (called from scripts/bootstrap.sh)
set -euo pipefail
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
CACHE="${SIMSEAM_CACHE:-$HOME/.cache/simseam}"
mkdir -p "$CACHE"

pin_hash() { sha256sum "$1" | cut -c1-12; }

# --- ROS 2 Jazzy (rclpy, rmw_fastrtps_cpp): cp311 wheels need Python 3.11
ROS_DIR="$CACHE/ros-jazzy-$(pin_hash "$HERE/ros-peer-pins.txt")"
if [ ! -f "$ROS_DIR/.ready" ]; then
  PY311=""
  for c in python3.11 python3 $(ls -d "$HOME"/.pyenv/versions/3.11*/bin/python3.11 2>/dev/null); do
    if command -v "$c" >/dev/null 2>&1 && "$c" -c 'import sys, venv; sys.exit(sys.version_info[:2] != (3, 11))' 2>/dev/null; then
      PY311="$c"; break
    fi
  done
  if [ -z "$PY311" ]; then
    echo "[simseam] no Python 3.11 for the ROS 2 Jazzy test peer (PyPI's ros-jazzy wheels are cp311)" >&2; exit 1
  fi
  echo "[simseam] creating the ROS 2 Jazzy test peer in $ROS_DIR"
  rm -rf "$ROS_DIR"
  "$PY311" -m venv "$ROS_DIR"
  "$ROS_DIR/bin/python" -m pip install -q --upgrade pip 2>&1 | grep -v '^WARNING: Location' || true
  "$ROS_DIR/bin/python" -m pip install -q -r "$HERE/ros-peer-pins.txt" 2>&1 | grep -v '^WARNING: Location' || true
  "$ROS_DIR/bin/python" -c 'import rclpy, rmw_dds_common.msg, sensor_msgs.msg, nav_msgs.msg, rosgraph_msgs.msg'
  touch "$ROS_DIR/.ready"
fi

# --- Foxglove WebSocket client (node + npm)
FG_DIR="$CACHE/foxglove-client-$(pin_hash "$HERE/foxglove-client-pins.json")"
if [ ! -f "$FG_DIR/.ready" ]; then
  if ! command -v npm >/dev/null 2>&1; then
    echo "[simseam] installing node/npm (Debian) for the Foxglove test client"
    SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq nodejs npm >/dev/null
  fi
  echo "[simseam] installing the Foxglove test client in $FG_DIR"
  rm -rf "$FG_DIR"; mkdir -p "$FG_DIR"
  cp "$HERE/foxglove-client-pins.json" "$FG_DIR/package.json"
  (cd "$FG_DIR" && npm install --silent --no-audit --no-fund >/dev/null)
  (cd "$FG_DIR" && node -e 'require("@foxglove/ws-protocol"); require("@foxglove/rosmsg"); require("@foxglove/rosmsg2-serialization"); require("ws")')
  touch "$FG_DIR/.ready"
fi
echo "SIMSEAM_ROS_PEER_VENV=$ROS_DIR"
echo "SIMSEAM_FOXGLOVE_CLIENT=$FG_DIR"
