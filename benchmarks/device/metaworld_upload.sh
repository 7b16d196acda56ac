#!/usr/bin/env bash
# Meta-World on MuJoCo Warp on the lent GPU machine (no registry there, 64 MiB per call).
#
# Two interpreters' worth of packages travel: MuJoCo Warp's side (warp-lang, mujoco-warp and the CPU
# MuJoCo of this checkout's venv, into /tmp/site) and Meta-World's native side (metaworld, gymnasium and
# Meta-World's pinned MuJoCo, into /tmp/mwsite). numpy, scipy, imageio, cloudpickle, absl-py and etils
# are the machine's own.
#
#   here:   bash benchmarks/device/metaworld_upload.sh prepare [DIR]   (default DIR: .cache/mwcarry)
#           -> DIR/c1 .. DIR/c4, each < 57 MiB: the warp-lang wheel (149 MB) in three chunks + SHA256,
#              and the other cp312 wheels (simseam's src/ and the benchmarks travel with the checkout)
#   there:  call k (k = 1..4, while the machine stays warm), carrying DIR/ck:
#             bash benchmarks/device/metaworld_upload.sh receive DIR/ck      (copies to /tmp/mw)
#           (where MuJoCo Warp's side is already there, e.g. after libero_warp_upload.sh's install: `side` here
#            -> .cache/mwside, ~46 MB, one call: `receive .cache/mwside && ... install /tmp/lww/site`; MW_WARP_CACHE=/tmp/lww/cache/warp shares
#            the kernels LIBERO compiled)
#           (optionally, a kernel cache brought back by `metaworld_h200.sh mt50x50` (mw_kcache.txz.NN): put the
#            pieces in a DIR/ck before its call; install unpacks them into WARP_CACHE_PATH, so the first run loads
#            the kernels instead of compiling them)
#           the last call then:
#             bash benchmarks/device/metaworld_upload.sh install
#             source /tmp/mw/env.sh   (PYTHONPATH: the wheels and the checkout's src; SIMSEAM_CACHE, WARP_CACHE_PATH)
#             (MUJOCO_GL=disable: that machine has PyOpenGL but no EGL library, and nothing here renders)
#             python3 benchmarks/metaworld_warp_throughput.py --device cuda:0 ...
#             python3 benchmarks/metaworld_warp_fidelity.py --device cuda:0 --jobs 15 ...
# ``install`` makes Meta-World's interpreter the way ``simseam backends provision metaworld`` would leave
# it (a venv directory with its provisioning record, under $SIMSEAM_CACHE): here its ``bin/python`` is
# the machine's python3 with /tmp/mwsite first on its path, since nothing can be pip-installed from an
# index there.
set -euo pipefail
cmd="${1:-}"
case "$cmd" in
  prepare)
    ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
    DIR="${2:-$ROOT/.cache/mwcarry}"
    PY="${PYTHON:-$ROOT/.venv/bin/python}"
    MJ="$("$PY" -c 'import mujoco; print(mujoco.__version__)')"
    WARP="$("$PY" -c 'from importlib.metadata import version as v; print(v("warp-lang"), v("mujoco-warp"))')"
    MWPINS="$ROOT/src/simseam/backends/pins/metaworld.txt"
    pin() { grep -i "^$1==" "$MWPINS"; }
    rm -rf "$DIR"; mkdir -p "$DIR/c1" "$DIR/c2" "$DIR/c3" "$DIR/c4" "$DIR/main" "$DIR/mw"
    dl() { "$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
      --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 \
      --platform manylinux2014_x86_64 -d "$@"; }
    set -- $WARP
    dl "$DIR/main" "warp-lang==$1" "mujoco-warp==$2" "mujoco==$MJ" "mujoco-core==$MJ"
    dl "$DIR/mw" "$(pin metaworld)" "$(pin mujoco)" "$(pin gymnasium)" "$(pin Farama-Notifications)" \
      "$(pin glfw)" "$(pin PyOpenGL)"
    W="$(ls "$DIR"/main/warp_lang-*.whl)"
    split -n 3 -d "$W" "$DIR/warp.part"
    sha256sum "$W" | awk '{print $1}' > "$DIR/c1/warp.sha256"
    basename "$W" > "$DIR/c1/warp.name"
    rm "$W"
    mv "$DIR/warp.part00" "$DIR/c1/"; mv "$DIR/warp.part01" "$DIR/c2/"; mv "$DIR/warp.part02" "$DIR/c3/"
    # each chunk plus the sent checkout (~11 MB in December) must stay under the 64 MiB a call carries: PyOpenGL
    # (3.2 MB) rides with the small wheels in c3, since c4 with it and an 11 MB checkout came to 67.11 MB
    mkdir -p "$DIR/c2/main" "$DIR/c3/mw" "$DIR/c4/main" "$DIR/c4/mw"
    mv "$DIR"/main/mujoco_core-*.whl "$DIR/c4/main/"
    mv "$DIR"/main/*.whl "$DIR/c2/main/"
    mv "$DIR"/mw/metaworld-*.whl "$DIR"/mw/mujoco-*.whl "$DIR/c4/mw/"
    mv "$DIR"/mw/*.whl "$DIR/c3/mw/"
    rmdir "$DIR/main" "$DIR/mw"
    du -sh "$DIR"/c*
    ;;
  receive)
    mkdir -p /tmp/mw; cp -r "$2"/. /tmp/mw/; ls /tmp/mw
    ;;
  side)  # here: only Meta-World's side (~46 MB, one call) into DIR/mw, from prepare's SRC
    ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
    SRC="${2:-$ROOT/.cache/mwcarry}" DIR="${3:-$ROOT/.cache/mwside}"
    rm -rf "$DIR"; mkdir -p "$DIR/mw"; cp "$SRC"/c3/mw/*.whl "$SRC"/c4/mw/*.whl "$DIR/mw/"; du -sh "$DIR"
    ;;
  install)  # install SITE: MuJoCo Warp's side is already in SITE (e.g. /tmp/lww/site): only Meta-World's is installed
    REPO="$PWD"   # the sent checkout (its src/ is what runs)
    SITE="${2:-/tmp/site}"
    cd /tmp/mw
    if [ -z "${2:-}" ]; then
      cat warp.part00 warp.part01 warp.part02 > "main/$(cat warp.name)"
      echo "$(cat warp.sha256)  main/$(cat warp.name)" | sha256sum -c -
      python3 -m pip install -q --no-index --no-deps --no-compile --target "$SITE" main/*.whl
    fi
    python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/mwsite mw/*.whl
    cat > /tmp/mw/env.sh <<EOF
export PYTHONPATH=$SITE:$REPO/src SIMSEAM_CACHE=/tmp/mwcache WARP_CACHE_PATH=${MW_WARP_CACHE:-/tmp/mwcache/warp} MUJOCO_GL=disable
EOF
    source /tmp/mw/env.sh
    if compgen -G "/tmp/mw/mw_kcache.txz.*" > /dev/null; then  # a kernel cache an earlier machine brought back
      mkdir -p "$WARP_CACHE_PATH"; cat /tmp/mw/mw_kcache.txz.* | tar -C "$WARP_CACHE_PATH" -xJf -
    fi
    venv="$(python3 -c 'from simseam.backends.provision import venv_dir; print(venv_dir("metaworld"))')"
    mkdir -p "$venv/bin"
    printf '#!/bin/sh\nexport PYTHONPATH="/tmp/mwsite${PYTHONPATH:+:$PYTHONPATH}"\nexec %s "$@"\n' "$(command -v python3)" \
      > "$venv/bin/python"
    chmod +x "$venv/bin/python"
    python3 -c 'import json, sys; json.dump({"name": "metaworld", "python": "python3 + /tmp/mwsite (device)"}, open(sys.argv[1], "w"))' \
      "$venv/simseam-backend.json"
    python3 -c "import warp, mujoco, mujoco_warp; print('warp', warp.config.version, 'mujoco', mujoco.__version__, 'mujoco_warp', mujoco_warp.__version__)"
    "$venv/bin/python" -c "import metaworld, mujoco; print('metaworld side: mujoco', mujoco.__version__)"
    ;;
  *)
    echo "usage: $0 prepare [DIR] | side [SRC] [DIR] | receive DIR | install [SITE]" >&2; exit 2
    ;;
esac
