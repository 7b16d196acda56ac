#!/usr/bin/env bash
# Item 8's image figure (issue: LIBERO on the GPU) on the lent GPU machine, in one call: libero_spatial's 500
# episodes with a trained image policy on the port (MuJoCo Warp, 50 worlds a task, 10 processes under CUDA MPS)
# against the CPU backend on all 16 cores, both cameras at IMAGE x IMAGE, the same policy on both sides
# (bench_libero_scale.py: the real command lines timed from start to merged summary).
# Needs, on the same warm machine: libero_warp_upload.sh's install (/tmp/lww) and libero_image_act.sh's train
# (/tmp/limg: lerobot and its needs in /tmp/limg/site, the checkpoints in /tmp/limg/ckpt).
#   bash benchmarks/device/libero_image_figure.sh [NAME] [IMAGE]   (default libero_spatial_0_img, 128)
# The port's case runs once, under MPS (--warp-runs 0 --mps), after the CPU backend's. The JSON and each run's
# console (written as it runs) come back in $OUT. Each case gets a Ctrl-C after CASE_LIMIT s (default 270: both fit
# a 600 s call; a cut case's row counts the episodes it finished; on 7 December the two cases together ran past a
# call's 600 s and nothing came back). PORT_ONLY=1: the port's case alone; CPU_ONLY=1: the CPU backend's alone (two
# calls on one warm machine then give both, each with a call's whole time). A checkpoint trained on one task is a
# throughput figure on all ten: its successes count only on its own task. RESIZED=1 (the 2 x 256² case, with a
# checkpoint trained at 128): the run uses a copy of it that reads IMAGE x IMAGE (resized_checkpoint.py): the
# cameras' and the policy's time at that size, its successes count for nothing.
set -euo pipefail
NAME="${1:-libero_spatial_0_img}" IMAGE="${2:-128}" OUT="${OUT:-/tmp/out}"
[ -f /tmp/lww/env.sh ] || { echo "libero_image_figure: /tmp/lww/env.sh missing: run libero_warp_upload.sh install first" >&2; exit 2; }
[ -d "/tmp/limg/ckpt/$NAME" ] || { echo "libero_image_figure: /tmp/limg/ckpt/$NAME missing: run libero_image_act.sh train first" >&2; exit 2; }
# shellcheck disable=SC1091
source /tmp/lww/env.sh
export PYTHONPATH="$PYTHONPATH:/tmp/limg/site" HF_HUB_OFFLINE=1 TQDM_DISABLE=1
mkdir -p "$OUT/logs"
port=(--warp cuda:0 --warp-n 50 --warp-shards 10 --warp-runs 0 --mps)
[ -n "${CPU_ONLY:-}" ] && port=()
CKPT="/tmp/limg/ckpt/$NAME"
if [ -n "${RESIZED:-}" ]; then
  CKPT="/tmp/limg/ckpt/${NAME}_at$IMAGE"
  [ -d "$CKPT" ] || python3 benchmarks/device/resized_checkpoint.py "/tmp/limg/ckpt/$NAME" "$CKPT" "$IMAGE"
fi
python3 benchmarks/bench_libero_scale.py --policy "lerobot:$CKPT" --image-size "$IMAGE" --n --full 16 \
  "${port[@]}" --case-limit "${CASE_LIMIT:-270}" ${PORT_ONLY:+--port-only} \
  --out "$OUT/libero_scale_img${IMAGE}_$NAME${RESIZED:+_resized}${PORT_ONLY:+_port}${CPU_ONLY:+_cpu}.json" \
  --logs "$OUT/logs"
