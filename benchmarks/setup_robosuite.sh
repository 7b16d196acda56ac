#!/usr/bin/env bash
# Create benchmarks/.venv-robosuite with the pinned robosuite baseline stack.
# Idempotent: if the pinned versions are already installed it exits 0 at once,
# without touching the network. Override the interpreter with PYTHON=...
set -euo pipefail

ROBOSUITE_VERSION=1.5.2
MUJOCO_VERSION=3.9.0
HERE="$(cd "$(dirname "${BASH_SOURCE[0]}")" && pwd)"
VENV="$HERE/.venv-robosuite"
PY="$VENV/bin/python"

installed() {
    [ -x "$PY" ] && "$PY" - "$ROBOSUITE_VERSION" "$MUJOCO_VERSION" <<'EOF' 2>/dev/null
import sys
from importlib.metadata import version
sys.exit(not (version("robosuite") == sys.argv[1] and version("mujoco") == sys.argv[2]))
EOF
}

if installed; then
    echo "robosuite $ROBOSUITE_VERSION / mujoco $MUJOCO_VERSION already in $VENV"
    exit 0
fi

[ -x "$PY" ] || "${PYTHON:-python3.11}" -m venv "$VENV"

# robosuite 1.5.2 pins mink==0.0.5, which needs numpy<2; opencv-python>=4.12
# needs numpy>=2, so cap it here to spare pip several ~70 MB backtracking downloads.
# pynput (a robosuite dependency) pulls evdev, an sdist: building it needs gcc.
"$PY" -m pip install --disable-pip-version-check \
    "robosuite==$ROBOSUITE_VERSION" "mujoco==$MUJOCO_VERSION" "numpy<2" "opencv-python<4.12"

installed || { echo "setup_robosuite.sh: install finished but versions do not match" >&2; exit 1; }
echo "installed robosuite $ROBOSUITE_VERSION / mujoco $MUJOCO_VERSION in $VENV"
