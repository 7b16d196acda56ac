#!/usr/bin/env bash
# Out of GPU memory for LIBERO's port (issue: LIBERO on the GPU, "Bad input"), on the lent GPU machine after
# libero_warp_upload.sh's install (source /tmp/lww/env.sh first):
#   bash benchmarks/device/libero_oom.sh [WORLDS] [DEVICE]     (default 100000 worlds on cuda:0)
# 1. `simseam eval libero_spatial --engine mujoco_warp --num-envs WORLDS --episodes WORLDS` on one task: it must end
#    with a one-line error naming the largest number of worlds that fits, measured by allocating them (and before
#    any of LIBERO's resets are computed: 100,000 of them take minutes);
# 2. in a fresh process, the batch of that many worlds is built (what a user asks for next) and closed.
# Logs go to $OUT (oom.log, fit.log); the first lines of each are printed. OOM_LIMIT / FIT_LIMIT: each step's
# seconds (300, 200); FIT=0 skips step 2.
set -uo pipefail
WORLDS="${1:-100000}" DEVICE="${2:-cuda:0}" OUT="${OUT:-/tmp/out}"
mkdir -p "$OUT"
t0=$SECONDS
timeout "${OOM_LIMIT:-300}" python3 -m simseam.cli.main eval libero_spatial --engine mujoco_warp --sim-device "$DEVICE" \
  --tasks libero_spatial/0 --policy zero --episodes "$WORLDS" --num-envs "$WORLDS" --out /tmp/libero_oom_run --overwrite \
  > "$OUT/oom.log" 2>&1
echo "eval: rc $? after $((SECONDS - t0)) s"
grep -v '^Module ' "$OUT/oom.log" | grep -iv warning | tail -3
N="$(grep -o 'largest number that fits is [0-9]*' "$OUT/oom.log" | grep -o '[0-9]*$')"
[ -n "$N" ] || { echo "no largest number named"; exit 1; }
[ "${FIT:-1}" = 0 ] && exit 0  # FIT=0: the message only (building that many worlds' data takes minutes on the host)
t0=$SECONDS
timeout "${FIT_LIMIT:-200}" python3 - "$N" "$DEVICE" > "$OUT/fit.log" 2>&1 <<'PY'
import sys
import time

from simseam.backends.libero_gpu.rollout import LiberoBatchRollout
from simseam.backends.libero_gpu.worker import NativeWorker

n, device = int(sys.argv[1]), sys.argv[2]
t0 = time.perf_counter()
with NativeWorker() as worker:
    batch = LiberoBatchRollout({"suite": "libero_spatial", "task": 0}, n, worker, device=device)
    print(f"fresh process: {n} worlds built on {device} in {time.perf_counter() - t0:.1f} s", flush=True)
    batch.close()
PY
echo "fit check: rc $? after $((SECONDS - t0)) s"
grep -v '^Module ' "$OUT/fit.log" | tail -2
