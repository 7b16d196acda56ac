#!/usr/bin/env bash
# Meta-World on MuJoCo Warp on the lent GPU machine (no registry there, 64 MiB per call, the checkout included).
#
# Two interpreters' worth of packages travel: MuJoCo Warp's side (warp-lang, mujoco-warp and the CPU MuJoCo of
# this checkout's venv: site/) and Meta-World's native side (metaworld, gymnasium and Meta-World's pinned MuJoCo:
# mwsite/). numpy, scipy, imageio, cloudpickle, absl-py and etils are the machine's own. Both sides are unpacked
# wheels in one xz tar cut into pieces (pieces.sh): 3 device calls in December (the wheels themselves took 4).
# Warp's tests, examples and warp-clang.so (Warp's CPU device, which a run on cuda:K never uses) stay behind.
#
#   here:   bash benchmarks/device/metaworld_upload.sh prepare [DIR]   (default DIR: .cache/mwcarry)
#             -> DIR/c01 .. cNN, one per device call (the wheels cached in ~/.cache/simseam/metaworld-device-<key>)
#           bash benchmarks/device/metaworld_upload.sh recut [DIR]     (the checkout grew: the same package cut again)
#           bash benchmarks/device/metaworld_upload.sh side [DIR]      (default .cache/mwside: Meta-World's side alone,
#             ~46 MB of wheels, one call, for a machine where MuJoCo Warp's side is already there, e.g. after
#             libero_warp_upload.sh's install: there `receive .cache/mwside && ... install /tmp/lww/site`, with
#             MW_WARP_CACHE=/tmp/lww/cache/warp to share the kernels LIBERO compiled)
#   there:  call k = 1 .. N, back to back while the machine stays warm, carrying DIR/ck:
#             bash benchmarks/device/metaworld_upload.sh receive DIR/ck                  (-> /tmp/mw/in)
#           (optionally, kernel caches brought back by earlier machines, received the same way before install, which
#            unpacks them into WARP_CACHE_PATH, so that the first run loads those kernels instead of compiling them:
#            Meta-World's, from `metaworld_h200.sh mt50x50` (mw_kcache.txz.NN, in a directory of their own), and
#            LIBERO's, .cache/libero_warp_kcache (the kernels of MuJoCo Warp that no model specialises))
#           the last call then:
#             bash benchmarks/device/metaworld_upload.sh install [SITE]
#             source /tmp/mw/env.sh   (PYTHONPATH: MuJoCo Warp's side and the checkout's src; SIMSEAM_CACHE,
#                                      WARP_CACHE_PATH; MUJOCO_GL=disable: nothing there renders unless a run sets it)
#             bash benchmarks/device/metaworld_h200.sh mt50x50 | throughput | cameras | fidelity
# ``install`` makes Meta-World's interpreter the way ``simseam backends provision metaworld`` would leave it (a venv
# directory with its provisioning record, under $SIMSEAM_CACHE): its ``bin/python`` is the machine's python3 with
# mwsite first on its path, since nothing can be pip-installed from an index there. With SITE (MuJoCo Warp's side
# already installed there), only the Meta-World wheels received (`side`) are installed.
set -euo pipefail
# shellcheck source=pieces.sh
source "$(dirname "$0")/pieces.sh"  # mb, piece_bytes, pack, recut, receive_pieces, unpack_pieces
# shellcheck source=standin_backend.sh
source "$(dirname "$0")/standin_backend.sh"  # standin_backend
MW=/tmp/mw
PLAT=(--no-deps --only-binary=:all: --python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64
      --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64)
export PIP_CONSTRAINT="" PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_ROOT_USER_ACTION=ignore

wheels() {  # ROOT -> the cache directory holding main/ and mw/ wheels (downloaded once per set of versions)
  local root="$1" py mj warp pins key cache
  py="${PYTHON:-$root/.venv/bin/python}"
  mj="$("$py" -c 'import mujoco; print(mujoco.__version__)')"
  warp="$("$py" -c 'from importlib.metadata import version as v; print(v("warp-lang"), v("mujoco-warp"))')"
  pins="$root/src/simseam/backends/pins/metaworld.txt"
  key="$( (echo "$mj $warp"; cat "$pins") | sha256sum | cut -c1-12)"
  cache="$HOME/.cache/simseam/metaworld-device-$key"
  if [ ! -f "$cache/complete" ]; then
    pin() { grep -i "^$1==" "$pins"; }
    set -- $warp
    "$py" -m pip download -q "${PLAT[@]}" -d "$cache/main" "warp-lang==$1" "mujoco-warp==$2" "mujoco==$mj" \
      "mujoco-core==$mj" >&2
    "$py" -m pip download -q "${PLAT[@]}" -d "$cache/mw" "$(pin metaworld)" "$(pin mujoco)" "$(pin gymnasium)" \
      "$(pin Farama-Notifications)" "$(pin glfw)" "$(pin PyOpenGL)" >&2
    touch "$cache/complete"
  fi
  echo "$cache"
}

prepare() {  # DIR
  local root dir cache w
  root="$(cd "$(dirname "$0")/../.." && pwd)"
  dir="${1:-$root/.cache/mwcarry}"
  cache="$(wheels "$root")"
  rm -rf "$dir"; mkdir -p "$dir/stage/site" "$dir/stage/mwsite"
  for w in "$cache"/main/*.whl; do unzip -q -o "$w" -d "$dir/stage/site"; done  # a wheel is a zip of its files
  for w in "$cache"/mw/*.whl; do unzip -q -o "$w" -d "$dir/stage/mwsite"; done
  rm -rf "$dir"/stage/site/warp/tests "$dir"/stage/site/warp/examples "$dir"/stage/site/warp/bin/warp-clang.so \
    "$dir"/stage/site/mujoco/doc "$dir"/stage/mwsite/mujoco/doc
  echo "site: $(mb "$dir/stage/site"), mwsite: $(mb "$dir/stage/mwsite")"
  CHUNK_BYTES=$(piece_bytes "$root")
  pack "$dir"
  du -b "$dir"/c* | awk '{printf "%s %.1f MB\n", $2, $1 / 1e6}'
}

side() {  # DIR: Meta-World's wheels alone
  local root dir cache
  root="$(cd "$(dirname "$0")/../.." && pwd)"
  dir="${1:-$root/.cache/mwside}"
  cache="$(wheels "$root")"
  rm -rf "$dir"; mkdir -p "$dir/mw"; cp "$cache"/mw/*.whl "$dir/mw/"; echo "$(mb "$dir") in $dir"
}

# kernel caches an earlier machine brought back, received into $MW/in: Meta-World's (mw_kcache.txz.NN pieces) and
# LIBERO's (warp_kernel_cache*.txz: MuJoCo Warp's kernels that do not depend on the model load from it too)
kernel_caches() {
  local k
  mkdir -p "$WARP_CACHE_PATH"
  for k in "$MW"/in/warp_kernel_cache*.txz; do
    # its paths start at warp/ (the tar of LIBERO's cache directory): unpacked beside WARP_CACHE_PATH, named warp
    [ -f "$k" ] && [ "$(basename "$WARP_CACHE_PATH")" = warp ] && tar -C "$(dirname "$WARP_CACHE_PATH")" -xJf "$k" \
      && echo "kernel cache: $(basename "$k")"
  done
  cache_in "$MW/in" mw_kcache "$WARP_CACHE_PATH"
  return 0  # a cache that does not unpack costs its kernels' compile, not the install
}

install() {  # [SITE]
  local repo="$PWD" site mwsite venv
  if [ -n "${1:-}" ]; then  # MuJoCo Warp's side is there already: Meta-World's wheels (`side`) only
    site="$1"; mwsite="$MW/mwsite"
    python3 -m pip install -q --no-index --no-deps --no-compile --target "$mwsite" "$MW"/in/mw/*.whl
  else
    rm -rf "$MW/pkg"; unpack_pieces "$MW/in" "$MW/pkg"
    site="$MW/pkg/site"; mwsite="$MW/pkg/mwsite"
  fi
  cat > "$MW/env.sh" <<EOS
export PYTHONPATH=$site:$repo/src SIMSEAM_CACHE=$MW/cache WARP_CACHE_PATH=${MW_WARP_CACHE:-$MW/cache/warp} MUJOCO_GL=disable
EOS
  # shellcheck disable=SC1091
  source "$MW/env.sh"
  kernel_caches
  venv="$(standin_backend metaworld "$(command -v python3)" "$mwsite")"
  python3 -c "import warp, mujoco, mujoco_warp; print('warp', warp.config.version, 'mujoco', mujoco.__version__, 'mujoco_warp', mujoco_warp.__version__)"
  "$venv/bin/python" -c "import metaworld, mujoco; print('metaworld side: mujoco', mujoco.__version__)"
}

case "${1:-}" in
  prepare) prepare "${2:-}" ;;
  recut) recut "${2:-.cache/mwcarry}" ;;
  side) side "${2:-}" ;;
  receive) receive_pieces "${2:-}" "$MW/in" ;;
  install) install "${2:-}" ;;
  *) echo "usage: $0 prepare [DIR] | recut [DIR] | side [DIR] | receive DIR/ck | install [SITE]" >&2; exit 2 ;;
esac
