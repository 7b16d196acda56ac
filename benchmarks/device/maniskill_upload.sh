#!/usr/bin/env bash
# ManiSkill3 native vs through simseam (benchmarks/bench_maniskill_scale.py) on the lent GPU machine:
# no registry there, Python 3.12 + torch (CUDA) + numpy, at most 64 MiB carried per call.
#
#   here:   bash benchmarks/device/maniskill_upload.sh prepare [DIR]     (default DIR: .cache/mscarry_h200)
#           -> DIR/c1 ... DIR/cK, one per device call, each one piece (<= 60 MB) of ms.tar.xz, which holds:
#              site/: the cp312 manylinux wheels (pip download --only-binary --no-deps) of the maniskill backend
#                venv's `pip freeze` less what that machine has (torch, numpy) and less what this benchmark never
#                imports (mplib + toppra: the motion-planning expert; imageio-ffmpeg: videos), opencv-python
#                swapped for opencv-python-headless of the same version (no libGL / glib needed), installed
#                here with a Python 3.12 (pip install --no-deps --target) and pruned of the robot assets
#                PickCube never loads (ManiSkill's other robots, ReplicaCAD's sky map);
#              debs/: libvulkan1 and libX11's chain (apt-get download; unpacked there only where missing);
#              src/: simseam's committed src (git archive HEAD src); bench_maniskill_scale.py; this script.
#           DIR/c1 also holds ms.sha256 and ms.count. Wheels are cached in ~/.cache/simseam/maniskill-device-*.
#   there:  call k = 1 .. K, consecutive while the machine stays warm, carrying DIR/ck:
#             bash benchmarks/device/maniskill_upload.sh receive .cache/mscarry_h200/ck        (-> /tmp/ms)
#           the last call then:
#             bash benchmarks/device/maniskill_upload.sh install      (-> /tmp/mssite, /tmp/msroot, /tmp/ms/env.sh)
#             bash benchmarks/device/maniskill_upload.sh run "$OUT"   (prints and runs the benchmark)
#           (install copies this script to /tmp/ms too: later calls may run bash /tmp/ms/maniskill_upload.sh run)
# PYVER=3.11 prepare builds the same for a cp311 interpreter (a local rehearsal with the backend venv's
# python as "the machine's python3": PY=... install / run).
set -euo pipefail
cmd="${1:-}"
MS="${MS_ROOT:-/tmp/ms}"
SITE="${MS_SITE:-/tmp/mssite}"
SYSROOT="${MS_SYSROOT:-/tmp/msroot}"
PY="${PY:-python3}"
CHUNK_BYTES=55000000   # a call carries at most 64 MiB, the checkout (8.3 MB in December) included
# torch's own dependencies: installed there only when that python3 cannot import them already
TORCH_DEPS="filelock fsspec jinja2 markupsafe networkx sympy mpmath typing_extensions"
case "$cmd" in
  prepare)
    ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
    DIR="${2:-$ROOT/.cache/mscarry_h200}"
    PYVER="${PYVER:-3.12}"
    PIP_PY="${PIP_PYTHON:-$ROOT/.venv/bin/python}"   # any Python with pip: it only downloads
    BACKEND="$(ls -d "$HOME"/.cache/simseam/backends/maniskill-*/ | tail -1)"
    INSTALL_PY="${INSTALL_PY:-}"                       # a Python $PYVER: pip install --target
    if [ -z "$INSTALL_PY" ]; then
      for c in "$HOME"/.pyenv/versions/"$PYVER"*/bin/python"$PYVER" "$(command -v "python$PYVER" || true)"; do
        [ -x "$c" ] && INSTALL_PY="$c" && break
      done
    fi
    [ -n "$INSTALL_PY" ] || { echo "no Python $PYVER here (set INSTALL_PY)" >&2; exit 1; }
    # the backend venv less torch / numpy (there) and less the expert's planner and ffmpeg (never imported)
    REQ="$("$BACKEND/bin/python" -m pip freeze --disable-pip-version-check | sed 's/+cpu$//' \
           | grep -v -i -E '^(torch|numpy|mplib|toppra|imageio-ffmpeg|imageio_ffmpeg)==' \
           | sed -E 's/^opencv-python==/opencv-python-headless==/')"
    KEY="$(echo "$REQ" | sha256sum | cut -c1-12)"
    CACHE="$HOME/.cache/simseam/maniskill-device-$KEY-py$PYVER"
    if [ ! -f "$CACHE/complete" ]; then
      rm -rf "$CACHE"; mkdir -p "$CACHE/wheels" "$CACHE/debs"
      echo "$REQ" > "$CACHE/requirements.txt"
      "$PIP_PY" -m pip download -q --disable-pip-version-check --no-deps --only-binary=:all: \
        --python-version "$PYVER" --implementation cp --platform manylinux_2_28_x86_64 \
        --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 \
        -d "$CACHE/wheels" -r "$CACHE/requirements.txt" 2>&1 | grep -v "Location 'file" || true
      [ "$(ls "$CACHE"/wheels/*.whl | wc -l)" -eq "$(grep -c . "$CACHE/requirements.txt")" ] \
        || { echo "wheel count != requirement count" >&2; exit 1; }
      (cd "$CACHE/debs" && apt-get download libvulkan1 libx11-6 libx11-data libxcb1 libxau6 libxdmcp6 libbsd0 libmd0)
      touch "$CACHE/complete"
    fi
    rm -rf "$DIR"; mkdir -p "$DIR/stage"
    "$INSTALL_PY" -m pip install -q --disable-pip-version-check --no-index --no-deps --no-compile \
      --target "$DIR/stage/site" "$CACHE"/wheels/*.whl
    M="$DIR/stage/site/mani_skill"
    for r in g1_humanoid fetch trifinger dclaw ability_hand koch inspire_hand allegro xarm7 so100; do
      rm -rf "$M/assets/robots/$r"
    done
    rm -f "$M/utils/scene_builder/replicacad/autumn_field_puresky_4k.hdr"
    rm -rf "$DIR/stage/site/bin"; find "$DIR/stage/site" -name __pycache__ -prune -exec rm -rf {} +
    cp -r "$CACHE/debs" "$DIR/stage/debs"
    cp "$CACHE/requirements.txt" "$DIR/stage/"
    git -C "$ROOT" archive HEAD src | tar -x -C "$DIR/stage"
    if [ -n "${BEFORE:-}" ]; then   # an older commit's src too: run then adds it as the seam side "before"
      mkdir -p "$DIR/stage/before"; git -C "$ROOT" archive "$BEFORE" src | tar -x -C "$DIR/stage/before"
      git -C "$ROOT" rev-parse "$BEFORE" > "$DIR/stage/before/simseam.rev"
    fi
    cp "$ROOT/benchmarks/bench_maniskill_scale.py" "$ROOT/benchmarks/device/maniskill_upload.sh" "$DIR/stage/"
    git -C "$ROOT" rev-parse HEAD > "$DIR/stage/simseam.rev"
    tar -C "$DIR/stage" -cf - . | xz -T0 -6 > "$DIR/ms.tar.xz"
    rm -rf "$DIR/stage"
    bash "$0" split "$DIR"
    ;;
  split)   # DIR/ms.tar.xz -> DIR/c1 .. cK: K = ceil(size / 60 MiB) pieces of equal size
    DIR="$2"
    size=$(stat -c %s "$DIR/ms.tar.xz")
    n=$(( (size + CHUNK_BYTES - 1) / CHUNK_BYTES ))
    rm -rf "$DIR"/c[0-9]*
    split -n "$n" -d -a 1 "$DIR/ms.tar.xz" "$DIR/ms.part"
    mkdir -p "$DIR/c1"
    sha256sum "$DIR/ms.tar.xz" | awk '{print $1}' > "$DIR/c1/ms.sha256"
    echo "$n" > "$DIR/c1/ms.count"
    i=0
    for part in "$DIR"/ms.part*; do
      i=$((i + 1)); mkdir -p "$DIR/c$i"; mv "$part" "$DIR/c$i/"
    done
    rm -f "$DIR/ms.tar.xz"
    du -sb "$DIR"/c* | awk '{printf "%s %d bytes (%.1f MiB)\n", $2, $1, $1 / 1048576}'
    ;;
  receive)
    mkdir -p "$MS"; cp -r "$2"/. "$MS"/; ls -la "$MS"
    # what the machine has (cheap; for the report): its python, torch, the NVIDIA Vulkan ICD, libX11 / libvulkan
    env -u PYTHONPATH "$PY" -c "import sys, numpy, torch; print(sys.version.split()[0], 'numpy', numpy.__version__, \
'torch', torch.__version__)" 2>&1 | tail -1 || true
    ls /usr/share/vulkan/icd.d /etc/vulkan/icd.d 2>/dev/null | tr '\n' ' ' || true; echo
    ldconfig -p 2>/dev/null | grep -E "libX11.so.6 |libvulkan.so.1 |libGLX_nvidia.so.0 " || true
    ;;
  install)
    cd "$MS"
    n="$(cat ms.count)"
    for i in $(seq 0 $((n - 1))); do [ -f "ms.part$i" ] || { echo "missing ms.part$i (call $((i + 1)))" >&2; exit 1; }; done
    cat $(for i in $(seq 0 $((n - 1))); do echo "ms.part$i"; done) > ms.tar.xz
    echo "$(cat ms.sha256)  ms.tar.xz" | sha256sum -c -
    rm -rf x; mkdir x
    if command -v xz >/dev/null; then tar -xJf ms.tar.xz -C x
    else "$PY" -c "import sys, tarfile; tarfile.open(sys.argv[1], 'r:xz').extractall(sys.argv[2])" ms.tar.xz x; fi
    rm -f ms.tar.xz
    rm -rf "$SITE" src debs before; mv x/site "$SITE"; mv x/src x/debs x/bench_maniskill_scale.py x/maniskill_upload.sh \
      x/simseam.rev x/requirements.txt .; [ -d x/before ] && mv x/before .; rm -rf x
    for m in $TORCH_DEPS; do   # the machine's own, where it has them (torch needs them)
      if env -u PYTHONPATH "$PY" -c "import $m" 2>/dev/null; then
        rm -rf "${SITE:?}/$m" "$SITE"/"$m"-*.dist-info "$SITE"/"$(echo "$m" | sed 's/_/-/g')"-*.dist-info
        [ "$m" = typing_extensions ] && rm -f "$SITE/typing_extensions.py"
        [ "$m" = markupsafe ] && rm -rf "$SITE"/MarkupSafe-*.dist-info
        [ "$m" = jinja2 ] && rm -rf "$SITE"/Jinja2-*.dist-info
        echo "using the machine's $m"
      fi
    done
    # the driver's libraries may be linked into /lib after the machine's ld cache was built: without this,
    # SAPIEN's Vulkan instance failed with ErrorIncompatibleDriver on 2026-12-03 (the ICD's libGLX_nvidia.so.0
    # not in the cache) and worked once ldconfig had run
    if command -v ldconfig >/dev/null; then ldconfig || true; fi
    # system libraries: unpack a deb only where this machine lacks its library
    rm -rf "$SYSROOT"; mkdir -p "$SYSROOT"
    LIB="$SYSROOT/usr/lib/x86_64-linux-gnu"
    for pair in libvulkan1:libvulkan.so.1 libx11-6:libX11.so.6 libx11-data: libxcb1:libxcb.so.1 libxau6:libXau.so.6 \
                libxdmcp6:libXdmcp.so.6 libbsd0:libbsd.so.0 libmd0:libmd.so.0; do
      pkg="${pair%%:*}"; so="${pair#*:}"
      if [ -n "$so" ] && ldconfig -p 2>/dev/null | grep -qE "^[[:space:]]+$so "; then continue; fi
      [ -z "$so" ] && ! ls "$LIB"/libX11.so.6 >/dev/null 2>&1 && continue   # libx11-data: with libX11 only
      d="$(ls debs/"${pkg}"_*.deb)"
      if command -v dpkg >/dev/null; then dpkg -x "$d" "$SYSROOT"
      else (t="$(mktemp -d)"; cd "$t" && ar x "$MS/$d" && tar -xf data.tar.* -C "$SYSROOT"; rm -rf "$t"); fi
      echo "carried: $pkg ($so)"
    done
    ICD=""
    for d in /usr/share/vulkan/icd.d /etc/vulkan/icd.d /usr/local/nvidia/share/vulkan/icd.d /usr/local/share/vulkan/icd.d; do
      [ -f "$d/nvidia_icd.json" ] && ICD="$d/nvidia_icd.json" && break
    done
    [ -n "$ICD" ] || ICD="$(timeout 20 find / -xdev \( -path /proc -o -path /sys -o -path /tmp -o -path '*/sapien/vulkan_library' \) \
      -prune -o -name 'nvidia_icd*.json' -print 2>/dev/null | head -1 || true)"
    if [ -z "$ICD" ]; then   # the driver's Vulkan library without its ICD file: write one
      GLX="$(ldconfig -p 2>/dev/null | awk '/libGLX_nvidia.so.0 /{print $NF; exit}' || true)"
      if [ -n "$GLX" ]; then
        ICD="$SYSROOT/nvidia_icd.json"
        printf '{"file_format_version": "1.0.0", "ICD": {"library_path": "%s", "api_version": "1.3.0"}}\n' "$GLX" > "$ICD"
        echo "no nvidia_icd.json: wrote $ICD for $GLX"
      else
        echo "WARNING: no NVIDIA Vulkan ICD and no libGLX_nvidia.so.0: cameras will not render" >&2
      fi
    fi
    {
      echo "export LD_LIBRARY_PATH=$LIB\${LD_LIBRARY_PATH:+:\$LD_LIBRARY_PATH}"
      [ -n "$ICD" ] && echo "export VK_ICD_FILENAMES=$ICD"
      echo "export PYTHONPATH=$SITE:$MS/src"
    } > "$MS/env.sh"
    cat "$MS/env.sh"
    # shellcheck disable=SC1091
    . "$MS/env.sh"
    "$PY" - <<'PY'
import time
t = time.monotonic()
import mani_skill, sapien, torch, numpy, zmq, msgpack, gymnasium, cv2
import mani_skill.envs  # noqa: F401
from simseam.backends.maniskill import allow_physics_only
print(f"OK mani_skill {mani_skill.__version__} sapien {sapien.__version__} torch {torch.__version__} numpy "
      f"{numpy.__version__} gymnasium {gymnasium.__version__} cv2 {cv2.__version__}; cuda {torch.cuda.is_available()}; "
      f"SAPIEN can render: {allow_physics_only()}; imports {time.monotonic() - t:.1f} s")
PY
    ;;
  run)
    OUTDIR="${2:-${OUT:-$MS/out}}"; mkdir -p "$OUTDIR"
    # shellcheck disable=SC1091
    . "$MS/env.sh"
    B="$(cd "$(dirname "$0")" && pwd)/../bench_maniskill_scale.py"   # the sent checkout's, else the carried copy
    [ -f "$B" ] || B="$MS/bench_maniskill_scale.py"
    BENCH=("$PY" "$B" --backend-python "$PY" --backend-env "PYTHONPATH=$SITE")
    MAIN=(--n ${N:-1 16} --kinds ${KINDS:-state rgb} --steps "${STEPS:-400}" --rounds "${ROUNDS:-4}")
    VARIANTS=(${VARIANTS:-})   # e.g. VARIANTS="spin1000=.@1000": more seam sides, alternated in the same run
    [ -d "$MS/before/src" ] && VARIANTS+=("before=$MS/before/src")   # prepared with BEFORE=REV
    [ ${#VARIANTS[@]} -gt 0 ] && MAIN+=(--seam-variant "${VARIANTS[@]}")
    echo "+ ${BENCH[*]} ${MAIN[*]} --out $OUTDIR/maniskill_scale.json --logs $OUTDIR/logs"
    t0=$(date +%s)
    timeout "${RUN_TIMEOUT:-420}" "${BENCH[@]}" "${MAIN[@]}" --out "$OUTDIR/maniskill_scale.json" \
      --logs "$OUTDIR/logs" 2>&1 | tee "$OUTDIR/maniskill_scale.txt"
    left=$(( ${SPIN0_UNTIL:-360} - ($(date +%s) - t0) ))
    # time left: N = 16 again, the seam as it ran before 05f2162 (every sidecar busy-polling 1000 us) beside
    # the runner's rule (none at 2N + 1 > cores), alternated
    if [ "$left" -gt 60 ] && [ -z "${NO_SPIN0:-}" ]; then
      echo "+ ${BENCH[*]} --n 16 --kinds state rgb --steps ${STEPS:-400} --rounds 2 --seam-variant spin1000=.@1000 --out $OUTDIR/maniskill_scale_spin.json"
      timeout "$left" "${BENCH[@]}" --n 16 --kinds state rgb --steps "${STEPS:-400}" --rounds 2 \
        --seam-variant spin1000=.@1000 --out "$OUTDIR/maniskill_scale_spin.json" --logs "$OUTDIR/logs_spin" 2>&1 \
        | tee "$OUTDIR/maniskill_scale_spin.txt" || true
    fi
    ;;
  *)
    echo "usage: $0 prepare [DIR] | split DIR | receive DIR | install | run [OUTDIR]" >&2; exit 2
    ;;
esac
