#!/usr/bin/env bash
# Runs benchmarks/train_act_lift.py on a lent GPU machine (no network there), through the device tool:
#   run(command="bash benchmarks/device/act_lift.sh --pause --later-train-s 380 --episodes 1000 --collect-workers 15
#                --curve-every 2500", carry=[".whl", ".gl", ".devcarry"], timeout_s=600)
#   run(command="LIMIT=540 bash benchmarks/device/act_lift.sh --episodes 1000 --curve-every 2500",
#       carry=[".whl", ".gl", ".devcarry"], timeout_s=600)   # next call, same warm machine: resumes, evaluates
# (the next call must come within the machine's ~30 s idle release, or /tmp/act_lift is gone)
# Diffusion Policy and bowl_plate, each in ONE call (collect ~40-80 s with 15 workers, train what is left of
# LIMIT less --eval-reserve-s, about 5-6 min, then 50 held-out seeds 10000-10049; a success-vs-steps curve
# on 10 of them, evaluated on the CPU beside training); NAME names the work dir, JSON and log:
#   run(command="NAME=dp_lift bash benchmarks/device/act_lift.sh --policy-type diffusion --episodes 300
#                --collect-workers 15 --curve-every 500 --curve-seeds 10000:10010 --curve-threads 8
#                --curve-first-s 60 --eval-reserve-s 130", carry=[".whl", ".gl", ".devcarry"], timeout_s=600)
#   run(command="NAME=act_bowl_plate bash benchmarks/device/act_lift.sh --task bowl_plate --max-steps 200
#                --episodes 300 --collect-workers 15 --curve-every 1000 --curve-seeds 10000:10010
#                --curve-threads 8 --curve-first-s 40 --eval-reserve-s 150", carry=[...as above], timeout_s=600)
#   run(command="NAME=dp_bowl_plate bash benchmarks/device/act_lift.sh --policy-type diffusion --task bowl_plate
#                --max-steps 200 --episodes 300 --collect-workers 15 --curve-every 500 --curve-seeds 10000:10010
#                --curve-threads 8 --curve-first-s 60 --eval-reserve-s 150", carry=[...as above], timeout_s=600)
# Every argument goes to train_act_lift.py after these defaults (a later one wins): --work /tmp/$NAME
# (NAME defaults to act_lift; kept between back-to-back calls: the machine's /tmp lives while it stays warm),
# --json $OUT/$NAME.json (and the log $OUT/$NAME.log; no checkpoint comes back: over the transfer limit),
# --deadline-s (what is left of LIMIT seconds, default 570, counted from this script's start: the tool's
# command limit is 600 s), --amp, --collect-workers 12.
#
# Prepared here first, in the repository root (all three are ignored through .git/info/exclude):
#   .whl/      cp312 wheels the machine's image lacks, installed with --no-deps into /tmp/site (23 MB):
#                P="--no-deps --only-binary=:all: --python-version 3.12 --implementation cp
#                   --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64
#                   --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64 -d .whl"
#                python3 -m pip download $P lerobot==0.4.4 datasets==4.8.5 dill multiprocess draccus==0.10.0 \
#                  mergedeep pyyaml-include toml deepdiff==8.6.2 orderly-set gymnasium==1.4.0 farama-notifications \
#                  diffusers==0.35.2 importlib_metadata jsonlines termcolor mujoco==4.0.0 mujoco-core==4.0.0 glfw \
#                  pyopengl pydantic==2.14.4 pydantic-core==2.50.5 annotated-types typing-inspection \
#                  huggingface-hub==0.35.3 pyserial transformers==4.57.6 tokenizers==0.22.1
#              (transformers 4.x since 6 December: the image's transformers became 5.17.0, which breaks lerobot
#              0.4.4's import (its GR00T dataclasses; lerobot pins transformers < 5); 15 MB more)
#              (Diffusion Policy needs nothing more: diffusers and einops are already imported on ACT's path,
#              through lerobot's factory);
#              (huggingface-hub 0.35: lerobot 0.4.4 needs < 0.36, the image has 1.x; mujoco-studio is not
#              needed: the classic EGL renderer is in mujoco-core; torch, torchvision, numpy, pandas, pyarrow,
#              accelerate, opencv, safetensors ... are the image's own);
#   .gl/       the GL loader .debs, so MuJoCo renders through the NVIDIA EGL driver
#              (the GPU machine has the NVIDIA driver but not the GL loaders: apt-get download libvulkan1 libegl1 libglvnd0 libopengl0
#              libgl1 libglx0 libgles2, amd64);
#   .devcarry/ pybullet_franka.tar.xz: pybullet_data/franka_panda (the Panda URDF + meshes, 1.9 MB) from
#              an installed pybullet (tar -C <site-packages> -cJf .devcarry/pybullet_franka.tar.xz
#              pybullet_data/franka_panda). The pybullet wheel is over the 64 MiB transfer cap, so the
#              assets travel alone under a minimal pybullet dist-info, which is how `pkg:pybullet/...`
#              asset references find them;
#              src/: simseam's sources at a commit (rm -rf .devcarry/src; git archive HEAD src | tar -x -C
#              .devcarry), used instead of the checkout's src/ when present, so that edits in progress in
#              a shared checkout do not travel into the run (.devcarry/src/COMMIT: git rev-parse HEAD).
# PyAV (av, 40 MB) is also over the cap; lerobot imports it at module load but only calls it for
# video features, and this run stores frames as PNG images, so a module that raises on any use
# stands in for it (it defines only the one constant lerobot reads at import).
# SKIP_SETUP=1 skips the .deb and wheel installs (SITE already prepared: a rehearsal on another machine).
set -euo pipefail
LIMIT=${LIMIT:-570}
NAME=${NAME:-act_lift}
PY=${PY:-python3}
SITE=${SITE:-/tmp/site}
if [ -z "${SKIP_SETUP:-}" ]; then
  for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
  if [ ! -f "$SITE/.installed" ]; then
    "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" .whl/*.whl
    touch "$SITE/.installed"
  fi
fi
tar -C "$SITE" -xJf .devcarry/pybullet_franka.tar.xz
mkdir -p "$SITE/pybullet-3.2.7.dist-info"
printf 'Metadata-Version: 2.1\nName: pybullet\nVersion: 3.2.7\n' > "$SITE/pybullet-3.2.7.dist-info/METADATA"
if ! PYTHONPATH="$SITE" "$PY" -c 'import av' 2>/dev/null || grep -qs "PNG-only run" "$SITE/av/__init__.py"; then
  mkdir -p "$SITE/av"
  cat > "$SITE/av/__init__.py" <<'PY'
"""PyAV is not on this machine (its wheel is over the transfer cap); any use fails loudly."""
from . import logging  # lerobot reads av.logging.WARNING in a default argument at import
def __getattr__(name):
    raise ImportError(f"av.{name}: PyAV is not installed on this machine (PNG-only run)")
PY
  cat > "$SITE/av/logging.py" <<'PY'
WARNING = 24  # libav's AV_LOG_WARNING
ERROR = 16
def set_libav_level(level):  # simseam's recorder quiets libav's log; there is no libav here
    pass
def __getattr__(name):
    raise ImportError(f"av.logging.{name}: PyAV is not installed on this machine (PNG-only run)")
PY
fi
SRC="$PWD/src"
if [ -d .devcarry/src/simseam ]; then SRC="$PWD/.devcarry/src"; echo "simseam from .devcarry/src at $(cat .devcarry/src/COMMIT 2>/dev/null)"; fi
export PYTHONPATH="$SITE:$SRC" MUJOCO_GL=egl PYTHONUNBUFFERED=1 HF_DATASETS_DISABLE_PROGRESS_BARS=1 \
  TQDM_DISABLE=1
OUTDIR=${OUT:-benchmarks/results}
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader || true
"$PY" -c 'import torch, lerobot, mujoco; print("torch", torch.__version__, "cuda", torch.cuda.is_available(), "mujoco", mujoco.__version__)'
echo "setup: ${SECONDS} s"
set -o pipefail
"$PY" benchmarks/train_act_lift.py --work "/tmp/$NAME" --json "$OUTDIR/$NAME.json" --amp --collect-workers 12 \
  --deadline-s $((LIMIT - SECONDS)) "$@" 2>&1 | tee -a "$OUTDIR/$NAME.log"
