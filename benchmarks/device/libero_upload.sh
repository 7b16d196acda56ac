#!/usr/bin/env bash
# LIBERO at scale on the lent GPU machine: no registry there, Python 3.12, at most 64 MiB carried per call.
#
#   here:   bash benchmarks/device/libero_upload.sh prepare [DIR]     (default DIR: .cache/liberocarry)
#           -> DIR/c01 ... DIR/cNN, one per device call, each one piece (<= 60 MB) of one tar holding:
#              the cp312 manylinux wheels of every pin in src/simseam/backends/pins/libero.txt (pip download
#              --only-binary; a pin without a wheel is built here with a Python 3.12 from pyenv), the wheels
#              of the client side (typer, rich and what they pull in, numpy, msgpack, pyzmq), simseam's src/,
#              benchmarks/bench_libero_scale.py and this script; DIR/c01 also holds the tar's SHA256.
#           Downloads are cached outside the checkout: ~/.cache/simseam/libero-device-<pins hash>/.
#   there:  call k = 1 .. N, consecutive while the machine stays warm, carrying DIR/ck (paths carried in one
#           call are removed by the next, so each call copies its piece out):
#             bash benchmarks/device/libero_upload.sh receive .cache/liberocarry/ck       (-> /tmp/lw)
#           the last call then (or any later one while the machine is warm):
#             bash benchmarks/device/libero_upload.sh install
#           which checks that every piece is there, reassembles the tar, checks its SHA256, unpacks it, makes
#           the client venv (python3 -m venv; pip install --no-index --find-links) and provisions the LIBERO
#           backend venv with simseam's own provisioning (the pins, --no-deps, the import check) offline
#           (PIP_NO_INDEX / PIP_FIND_LINKS), then prints one line starting with OK, and the commands to run:
#             export SIMSEAM_BACKENDS_DIR=/tmp/lw/backends PYTHONPATH=/tmp/lw/pkg/src MUJOCO_GL=egl
#             /tmp/lw/client/bin/python /tmp/lw/pkg/benchmarks/bench_libero_scale.py --n 8 16 --episodes 5 \
#               --full 16 --out $OUT/libero_scale.json --logs $OUT/logs
# LW_ROOT moves /tmp/lw; PYTHON names the interpreter the venvs are made from (default python3; it must be
# CPython 3.12: the wheels are cp312).
set -euo pipefail
cmd="${1:-}"
LW="${LW_ROOT:-/tmp/lw}"
CHUNK_BYTES=55000000  # with the checkout (8.3 MB in December) a call stays under its 64 MiB
case "$cmd" in
  prepare)
    ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
    DIR="${2:-$ROOT/.cache/liberocarry}"
    PIP_PY="${PIP_PYTHON:-$ROOT/.venv/bin/python}"   # any Python with pip: it only downloads
    PY312="${PY312:-}"
    if [ -z "$PY312" ]; then
      for c in "$(pyenv root 2>/dev/null || echo "$HOME/.pyenv")"/versions/3.12*/bin/python3.12 "$(command -v python3.12 || true)"; do
        [ -x "$c" ] && PY312="$c" && break
      done
    fi
    PINS="$ROOT/src/simseam/backends/pins/libero.txt"
    # the client side: what `python -m simseam.cli.main eval` imports (pip resolves their dependencies)
    CLIENT="typer==0.29.2 rich==15.0.0 numpy==2.4.6 msgpack==1.2.4 pyzmq==27.3.0"
    KEY="$( (cat "$PINS"; echo "$CLIENT") | sha256sum | cut -c1-12)"
    CACHE="$HOME/.cache/simseam/libero-device-$KEY"
    PLAT=(--only-binary=:all: --python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64
          --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64)
    if [ ! -f "$CACHE/complete" ]; then
      rm -rf "$CACHE"; mkdir -p "$CACHE/wheels"
      grep -v '^#' "$PINS" | grep . | while read -r req; do
        if ! "$PIP_PY" -m pip download -q --disable-pip-version-check --no-deps "${PLAT[@]}" -d "$CACHE/wheels" "$req" \
             >/dev/null 2>&1; then
          [ -n "$PY312" ] || { echo "no cp312 wheel for $req and no Python 3.12 here to build one (set PY312)" >&2; exit 1; }
          echo "building a wheel of $req with $PY312"
          "$PY312" -m pip wheel -q --disable-pip-version-check --no-deps -w "$CACHE/wheels" "$req"
          ls "$CACHE"/wheels/*.whl | xargs -n1 basename | grep -qi "^$(echo "${req%%==*}" | tr '-' '_')-" \
            || { echo "building $req gave no wheel" >&2; exit 1; }
        fi
      done
      # shellcheck disable=SC2086
      "$PIP_PY" -m pip download -q --disable-pip-version-check "${PLAT[@]}" -d "$CACHE/wheels" $CLIENT
      echo "$CLIENT" | tr ' ' '\n' > "$CACHE/client.txt"
      touch "$CACHE/complete"
    fi
    rm -rf "$DIR"; mkdir -p "$DIR/stage/benchmarks/device"
    cp -r "$CACHE/wheels" "$DIR/stage/wheels"
    cp "$CACHE/client.txt" "$DIR/stage/client.txt"
    cp -r "$ROOT/src" "$DIR/stage/src"; find "$DIR/stage/src" -name __pycache__ -prune -exec rm -rf {} +
    rm -rf "$DIR"/stage/src/*.egg-info
    cp "$ROOT/benchmarks/bench_libero_scale.py" "$DIR/stage/benchmarks/"
    cp "$ROOT/benchmarks/device/libero_upload.sh" "$DIR/stage/benchmarks/device/"
    tar -cf "$DIR/pkg.tar" -C "$DIR/stage" .
    rm -rf "$DIR/stage"
    split -b "$CHUNK_BYTES" -d -a 2 "$DIR/pkg.tar" "$DIR/pkg.part"
    n=$(ls "$DIR"/pkg.part* | wc -l)
    mkdir -p "$DIR/c01"
    sha256sum "$DIR/pkg.tar" | awk '{print $1}' > "$DIR/c01/pkg.sha256"
    echo "$n" > "$DIR/c01/pkg.count"
    i=0
    for part in "$DIR"/pkg.part*; do
      i=$((i + 1)); c="$DIR/c$(printf %02d "$i")"; mkdir -p "$c"; mv "$part" "$c/"
    done
    total=$(stat -c %s "$DIR/pkg.tar"); rm -f "$DIR/pkg.tar"
    du -b "$DIR"/c* | awk '{printf "%s %.1f MB\n", $2, $1 / 1e6}'
    echo "prepared $n chunk(s), $(awk -v b="$total" 'BEGIN{printf "%.1f", b / 1e6}') MB in all (wheels $(du -sb "$CACHE/wheels" | awk '{printf "%.1f", $1 / 1e6}') MB from $CACHE)"
    ;;
  receive)
    [ -d "${2:-}" ] || { echo "receive: no chunk directory ${2:-}" >&2; exit 2; }
    mkdir -p "$LW/in"; cp -r "$2"/. "$LW/in/"
    echo "received $(ls "$LW"/in/pkg.part* | wc -l) piece(s) of $(cat "$LW/in/pkg.count" 2>/dev/null || echo '?') in $LW/in"
    ;;
  install)
    PY="${PYTHON:-python3}"
    "$PY" -c 'import sys; assert sys.version_info[:2] == (3, 12), sys.version' 2>/dev/null \
      || { echo "install: $PY is not CPython 3.12 (the wheels are cp312); set PYTHON" >&2; exit 2; }
    cd "$LW/in"
    [ -f pkg.count ] && [ -f pkg.sha256 ] || { echo "install: the first piece (c01: count and SHA256) was not received" >&2; exit 2; }
    have=$(ls pkg.part* 2>/dev/null | wc -l); want=$(cat pkg.count)
    [ "$have" = "$want" ] || { echo "install: $have of $want pieces received ($(ls pkg.part* | tr '\n' ' '))" >&2; exit 2; }
    cat pkg.part* > "$LW/pkg.tar"
    echo "$(cat pkg.sha256)  $LW/pkg.tar" | sha256sum -c --quiet - || { echo "install: SHA256 mismatch" >&2; exit 2; }
    rm -rf "$LW/pkg" "$LW/client"; mkdir -p "$LW/pkg"; tar -xf "$LW/pkg.tar" -C "$LW/pkg"; rm -f "$LW/pkg.tar"
    "$PY" -m venv "$LW/client"
    "$LW/client/bin/python" -m pip install -q --disable-pip-version-check --no-index --find-links "$LW/pkg/wheels" \
      -r "$LW/pkg/client.txt"
    export SIMSEAM_BACKENDS_DIR="$LW/backends" PYTHONPATH="$LW/pkg/src"
    PIP_NO_INDEX=1 PIP_FIND_LINKS="$LW/pkg/wheels" "$LW/client/bin/python" -m simseam.backends.provision libero
    "$LW/client/bin/python" -m simseam.cli.main eval --help >/dev/null
    "$LW/client/bin/python" - <<'PY'
from simseam.backends.provision import marker, python_of
m = marker("libero")
assert m is not None, "the libero venv is not provisioned"
print(f"OK libero backend venv {python_of('libero').parent.parent} ({m['bytes'] / 2**20:.0f} MiB, provisioned offline "
      f"in {m['seconds']:.0f} s); client venv ready")
PY
    echo "export SIMSEAM_BACKENDS_DIR=$LW/backends PYTHONPATH=$LW/pkg/src MUJOCO_GL=egl"
    echo "$LW/client/bin/python $LW/pkg/benchmarks/bench_libero_scale.py --n 8 16 --episodes 5 --full 16 --out \$OUT/libero_scale.json --logs \$OUT/logs"
    ;;
  *)
    echo "usage: $0 prepare [DIR] | receive DIR | install" >&2; exit 2
    ;;
esac
