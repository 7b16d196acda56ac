#!/usr/bin/env bash
# LIBERO image policies (issue: LIBERO on the GPU, item 6): ACT from the CPU benchmark's images, trained on the lent
# GPU machine (no network there, at most 64 MiB carried per call, 8 files of 16 MiB back), evaluated here.
#
# The demonstrations are recorded here, on the CPU benchmark (LIBERO in its venv behind the sidecar, MuJoCo's
# OpenGL cameras): `simseam collect --scene S.yaml --policy scripted --episodes 30 --seed 0 --videos` for each
# task, S.yaml the eval preset's task with both cameras at 128x128 (init states 0-29; 30-49 stay held out).
# The datasets travel as their MP4 videos (a task's 30 episodes: ~1.5 MB), so the machine needs PyAV to decode
# them: its wheel (40 MB) travels in a call of its own.
#
#   here:   bash benchmarks/device/libero_image_act.sh prepare DATASET_DIR...   (-> .cache/limg/c1, c2)
#             c1: the wheels lerobot needs beyond the machine's own (lerobot 0.4.4 and its pure-Python needs,
#                 10 MB: the list act_lift.sh documents, less MuJoCo) and the datasets without their PNG frames;
#             c2: the PyAV wheel and transformers 4.57 (below, at AV).
#   there:  call 1, carrying .cache/limg/c1:  bash benchmarks/device/libero_image_act.sh receive .cache/limg/c1
#           call 2, carrying .cache/limg/c2:  bash benchmarks/device/libero_image_act.sh receive .cache/limg/c2 \
#                                               && bash benchmarks/device/libero_image_act.sh train [NAME...]
#           (train installs the wheels into /tmp/limg/site once, unpacks the datasets, and trains each dataset
#           NAME (default: all) with the recipe below, one after another within LIMIT seconds (default 540,
#           counted from the script's start; TRAIN_S seconds each, default an equal share); a later call on the
#           same warm machine may name the ones left). Each checkpoint comes back in $OUT as NAME.ckpt.txz.NN
#           pieces (its weights rounded to float16 for the transfer: 18.7 M parameters, 3 pieces a policy) with
#           the training log (train.log); a call brings back 8 files, so the checkpoints that do not fit wait:
#           the next call on the same warm machine, `bash benchmarks/device/libero_image_act.sh send`, brings
#           them (whole checkpoints while 8 files and 60 MB hold them: two of ~27 MB a call).
#   here:   bash benchmarks/device/libero_image_act.sh unpack FILES_DIR DEST   (DEST/NAME: a checkpoint whose
#           weights are float32 again, their values the float16 ones; `simseam eval ... --policy lerobot:DEST/NAME`)
#   there, a policy trained by an earlier machine (its pieces kept here, e.g. .cache/limg_pack, 27 MB: carried
#           beside c1, whose call copies them to /tmp/limg/pack_in): after receive c2,
#           `bash benchmarks/device/libero_image_act.sh policy /tmp/limg/pack_in` (into /tmp/limg/ckpt/NAME, where
#           libero_image_figure.sh reads it)
#
# The recipe: the LIBERO state proofs' (benchmarks/libero_proof.py: ACT without VAE, chunk 10, one call per step
# with temporal ensembling 0.01, cosine lr 3e-4, batch 64, 3,000 steps) with the image lift proof's model
# (benchmarks/train_act_lift.py: a ResNet-18 from scratch, no ImageNet weights offline; a transformer 256 wide,
# feed-forward 1,024, 4 encoder layers); `--amp --cache` (the frames decoded onto the GPU once). The normalisers'
# statistics travel as they are (float32); only model.safetensors is rounded. The training runs through
# benchmarks/device/lerobot_pyav.py: the frames decoded by PyAV (that machine's torchvision has no VideoReader and
# it lacks torchcodec's FFmpeg libraries; the first training call of 6 December stopped there). LIMG_ROOT moves /tmp/limg; PY names the interpreter.
# Rehearsal on a machine without CUDA: DEVICE=cpu STEPS=4 SKIP_INSTALL=1 (the repo's venv as PY).
set -euo pipefail

ROOT="${LIMG_ROOT:-/tmp/limg}"
PY="${PY:-python3}"
STEPS="${STEPS:-3000}"
LR="${LR:-3e-4}"
# RESUME=1: continue each named policy from its newest checkpoint in $ROOT/ckpt up to STEPS (`simseam train --resume`;
# a checkpoint every 500 steps and where the time share ends a run), so a longer training spans back-to-back calls on
# one warm machine, each call's pack sent again (7 December: 3,000 steps left the image
# policies at a loss of 0.43-0.50 and failing; the image lift proof took 20,000)
RESUME="${RESUME:-0}"
DEVICE="${DEVICE:-cuda}"
CARRY=.cache/limg
# lerobot 0.4.4's pure-Python needs the machine lacks (torch, torchvision, numpy, pandas, pyarrow, accelerate,
# opencv, safetensors... are its own); huggingface-hub 0.35: lerobot needs < 0.36, the machine has 1.x
WHEELS="lerobot==0.4.4 datasets==4.8.5 dill multiprocess draccus==0.10.0 mergedeep pyyaml-include toml
deepdiff==8.6.2 orderly-set gymnasium==1.4.0 farama-notifications diffusers==0.35.2 importlib_metadata jsonlines
termcolor pydantic==2.14.4 pydantic-core==2.50.5 annotated-types typing-inspection huggingface-hub==0.35.3 pyserial
tokenizers==0.22.1"
# c2: PyAV, and transformers 4.x: lerobot 0.4.4 needs transformers < 5 (its policies package imports GR00T's, whose
# dataclasses fail to build on transformers 5: "non-default argument 'backbone_cfg' follows default argument"), and
# transformers 5 needs huggingface-hub 1.x ("cannot import name 'is_offline_mode'"); the machine's own was 5.17.0
# on 6 December (fifth session: found there, the training did not start)
AV="av==15.1.0 transformers==4.57.6"
PLAT=(--no-deps --only-binary=:all: --python-version 3.12 --implementation cp --platform manylinux_2_28_x86_64
      --platform manylinux_2_27_x86_64 --platform manylinux_2_17_x86_64 --platform manylinux2014_x86_64)
export PIP_CONSTRAINT="" PIP_DISABLE_PIP_VERSION_CHECK=1 PIP_ROOT_USER_ACTION=ignore

prepare() {  # DATASET_DIR...
  [ $# -ge 1 ] || { echo "prepare: name the datasets (simseam collect --videos output directories)" >&2; exit 2; }
  local d pip_py=.venv/bin/python
  rm -rf "$CARRY" && mkdir -p "$CARRY/c1/whl" "$CARRY/c1/data" "$CARRY/c2/whl"
  # shellcheck disable=SC2086
  "$pip_py" -m pip download -q "${PLAT[@]}" -d "$CARRY/c1/whl" $WHEELS
  # shellcheck disable=SC2086
  "$pip_py" -m pip download -q "${PLAT[@]}" -d "$CARRY/c2/whl" $AV
  for d in "$@"; do
    [ -f "$d/meta/info.json" ] && [ -d "$d/videos" ] \
      || { echo "prepare: $d is not a dataset recorded with --videos (no meta/info.json or videos/)" >&2; exit 2; }
    tar -C "$(dirname "$d")" --exclude=images -cf "$CARRY/c1/data/$(basename "$d").tar" "$(basename "$d")"
  done
  du -sh "$CARRY"/c1 "$CARRY"/c2
}

receive() {  # DIR
  [ -d "${1:-}" ] || { echo "receive: no directory ${1:-}" >&2; exit 2; }
  mkdir -p "$ROOT/in"
  cp -r "$1"/. "$ROOT/in/"
  echo "received $(ls "$ROOT"/in/whl | wc -l) wheel(s), $(ls "$ROOT"/in/data 2>/dev/null | wc -l) dataset(s) in $ROOT/in"
}

install_site() {
  [ -f "$ROOT/site/.installed" ] && return
  ls "$ROOT"/in/whl/av-*.whl >/dev/null 2>&1 || { echo "train: the PyAV wheel (c2) was not received" >&2; exit 2; }
  "$PY" -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$ROOT/site" \
    "$ROOT"/in/whl/*.whl
  touch "$ROOT/site/.installed"
}

pack() {  # CKPT NAME: the checkpoint's weights as float16, xz, cut into 15 MiB pieces in $OUT
  local ckpt="$1" name="$2" tmp="$ROOT/pack/$2"
  rm -rf "$tmp" && mkdir -p "$tmp" && tar -C "$ckpt" --exclude=./checkpoints -cf - . | tar -C "$tmp" -xf -
  rm -f "$ROOT/out/$name".ckpt.txz.* "$ROOT/sent/$name"  # a new pack of it: not sent yet
  "$PY" - "$tmp" <<'PY'
import sys, pathlib, torch
from safetensors.torch import load_file, save_file
for f in pathlib.Path(sys.argv[1]).rglob("model.safetensors"):  # the weights; normalisers' stats stay float32
    tensors = load_file(str(f))
    save_file({k: v.half() if v.dtype == torch.float32 else v for k, v in tensors.items()}, str(f))
PY
  mkdir -p "$ROOT/out"
  tar -C "$ROOT/pack" -cf - "$name" | xz -T0 -6 | split -b 15M -d -a 2 - "$ROOT/out/$name.ckpt.txz."
}

send() {  # into $OUT: the training log and the checkpoints not sent yet, whole ones while 8 files and 60 MB hold them
  local name n bytes used=1 used_bytes=0
  mkdir -p "$ROOT/sent"
  cp "$ROOT/out/train.log" "${OUT:?}/" 2>/dev/null || true
  for first in "$ROOT"/out/*.ckpt.txz.00; do
    [ -f "$first" ] || continue
    name="$(basename "$first" .ckpt.txz.00)"
    [ -f "$ROOT/sent/$name" ] && continue
    n=$(ls "$ROOT/out/$name".ckpt.txz.* | wc -l)
    bytes=$(cat "$ROOT/out/$name".ckpt.txz.* | wc -c)
    # the device tool brings back at most 8 files and 64 MiB a call (7 December: a third 27 MB checkpoint was
    # marked sent and left out as over the total)
    if [ $((used + n)) -gt 8 ] || [ $((used_bytes + bytes)) -gt 60000000 ]; then
      echo "send: $name waits for the next call (8 files, 60 MB a call)"; continue
    fi
    cp "$ROOT/out/$name".ckpt.txz.* "$OUT/" && touch "$ROOT/sent/$name" && used=$((used + n)) \
      && used_bytes=$((used_bytes + bytes))
  done
  ls -la "$OUT"
}

train() {  # [NAME...]
  local names=("$@") left share name t0 gpu=() again
  [ "$DEVICE" = cpu ] || { install_site; gpu=(--amp --cache); }
  mkdir -p "$ROOT/data" "$ROOT/ckpt" "$ROOT/out"
  for t in "$ROOT"/in/data/*.tar; do tar -C "$ROOT/data" -xf "$t"; done
  [ ${#names[@]} -gt 0 ] || mapfile -t names < <(ls "$ROOT/data")
  export PYTHONPATH="$ROOT/site:$PWD/src${PYTHONPATH:+:$PYTHONPATH}" PYTHONUNBUFFERED=1 TQDM_DISABLE=1 \
    HF_DATASETS_DISABLE_PROGRESS_BARS=1 HF_HUB_OFFLINE=1
  "$PY" -c 'import torch, lerobot, av; print("torch", torch.__version__, "cuda", torch.cuda.is_available(), "av", av.__version__)'
  for i in "${!names[@]}"; do
    name="${names[$i]}"
    left=$(( ${LIMIT:-540} - SECONDS - 30 ))
    share=${TRAIN_S:-$(( left / (${#names[@]} - i) ))}
    [ "$share" -ge 30 ] || { echo "train: $name: no time left ($left s)"; break; }
    t0=$SECONDS
    again=(--overwrite)  # checkpoints every 500 steps and where the time share ends the run: RESUME=1 goes on
    [ "$RESUME" = 1 ] && compgen -G "$ROOT/ckpt/$name/checkpoints/step_*" > /dev/null && again=(--resume)
    "$PY" benchmarks/device/lerobot_pyav.py train --dataset "$ROOT/data/$name" --out "$ROOT/ckpt/$name" "${again[@]}" \
      --checkpoint-every 500 --policy-type act --steps "$STEPS" --time-budget-s "$share" --batch-size 64 --lr "$LR" --lr-schedule cosine \
      --no-vae --chunk-size 10 --n-action-steps 1 --temporal-ensemble 0.01 --dim-model 256 --ff-dim 1024 --encoder-layers 4 \
      --device "$DEVICE" "${gpu[@]}" 2>&1 | tee -a "$ROOT/out/train.log"
    echo "$name: trained in $(( SECONDS - t0 )) s" | tee -a "$ROOT/out/train.log"
    pack "$ROOT/ckpt/$name" "$name"
  done
  send
}

unpack() {  # FILES_DIR DEST (UNPACK_PY: the interpreter with torch and safetensors; here the repo's venv)
  local files="$1" dest="$2" first name
  mkdir -p "$dest"
  for first in "$files"/*.ckpt.txz.00; do
    name="$(basename "$first" .ckpt.txz.00)"
    rm -rf "${dest:?}/$name"
    cat "$files/$name".ckpt.txz.* | xz -dc | tar -x -C "$dest"
    "${UNPACK_PY:-.venv/bin/python}" - "$dest/$name" <<'PY'
import sys, pathlib, torch
from safetensors.torch import load_file, save_file
for f in pathlib.Path(sys.argv[1]).rglob("model.safetensors"):
    tensors = load_file(str(f))
    save_file({k: v.float() if v.dtype == torch.float16 else v for k, v in tensors.items()}, str(f))
PY
    echo "unpacked $dest/$name"
  done
}

policy() {  # FILES_DIR: there, a checkpoint brought back by an earlier machine (its NAME.ckpt.txz.NN pieces,
  # carried in) unpacked into $ROOT/ckpt, where libero_image_figure.sh reads it (after receive c1 and c2)
  install_site
  PYTHONPATH="$ROOT/site${PYTHONPATH:+:$PYTHONPATH}" UNPACK_PY="$PY" unpack "$1" "$ROOT/ckpt"
}

case "${1:-}" in
  prepare) shift; prepare "$@" ;;
  policy) policy "${2:?FILES_DIR}" ;;
  receive) receive "${2:-}" ;;
  train) shift; train "$@" ;;
  send) send ;;
  unpack) unpack "${2:?FILES_DIR}" "${3:?DEST}" ;;
  *) echo "usage: $0 prepare DATASET... | receive DIR | train [NAME...] | send | unpack FILES_DIR DEST" >&2; exit 2 ;;
esac
