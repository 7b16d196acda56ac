#!/usr/bin/env bash
# The Meta-World-on-Warp measurements on the lent GPU machine, after metaworld_upload.sh's install (one call):
#   bash benchmarks/device/metaworld_h200.sh throughput   (a CUDA smoke of the fidelity harness first; then MT50 x 50 in
#     MT50_PROCS processes (default 8), MT50_MPS=1: as clients of a CUDA MPS server; MT50_LIMIT=0 skips it)
#   bash benchmarks/device/metaworld_h200.sh mt50x50      (MT50 x 50 under MPS, MT50_PROCS processes (default 16), the
#     tasks claimed longest first: first cold with --host-arrays, then warm with and without it (MT50_RUNS
#     overrides: "host plain host24" = the two warm runs, then host arrays in 24 processes; "cli": the product's own
#     `simseam eval metaworld_mt50 --engine mujoco_warp --processes 16 --mps --policy random`; each run within
#     MT50_LIMIT s, default 180, a cold one MT50_COLD_LIMIT, default 330); then the Warp kernel cache, when it fits, comes back as
#     mw_kcache.txz.NN pieces, at most three (the next machine: put them in a directory, carry it and `metaworld_upload.sh receive` it
#     before the install call: install unpacks them)
#   bash benchmarks/device/metaworld_h200.sh cameras      (corner + gripperPOV at 128x128: Warp's ray tracer against
#     the CPU backend's OpenGL cameras in 16 processes; carry .gl as well; then SSIM against OpenGL on CUDA)
#   bash benchmarks/device/metaworld_h200.sh fidelity     (MT50 x 50 seeds x 500 steps, 15 processes (FID_JOBS); a CUDA smoke
#     first; FID_RESUME=1 in the next back-to-back call finishes the tasks a FID_LIMIT cut off; returns mwfid.tgz:
#     untar it into DIR, then: metaworld_warp_fidelity.py --tasks mt50 --seeds 0:50 --device cuda:0 --merge
#     --out DIR/metaworld_warp_fidelity.json; FID_FROM=JSON keeps that file's tasks and runs only the others)
#   bash benchmarks/device/metaworld_h200.sh kernels      (a fresh machine: every MT50 task's kernels compiled by KPROCS
#     processes at once at TP_WORLDS worlds, one step a task, so that the next call's `throughput` over MT50 compiles
#     nothing and fits one call)
# Logs and JSON go to $OUT (the device tool brings them back).
set -uo pipefail
# shellcheck source=pieces.sh
source "$(dirname "$0")/pieces.sh"  # cache_back
source /tmp/mw/env.sh
export PYTHONUNBUFFERED=1
OUT="${OUT:-/tmp/out}"; mkdir -p "$OUT"
nvidia-smi --query-gpu=name,driver_version,clocks.sm,clocks.max.sm,temperature.gpu --format=csv | tee "$OUT/gpu.txt"
quiet() { grep -v '^Module ' ; }
case "${1:-}" in
  throughput)
    [ -n "${SMOKE_AFTER:-}" ] || timeout 200 python3 benchmarks/metaworld_warp_fidelity.py --tasks reach-v3,drawer-close-v3 --seeds 0:4 \
      --steps 60 --device cuda:0 --out "$OUT/smoke_fidelity.json" --overwrite 2>&1 | quiet | tee "$OUT/smoke.log" | tail -4
    timeout "${TP_LIMIT:-330}" python3 benchmarks/metaworld_warp_throughput.py --device cuda:0 \
      --tasks "${TP_TASKS:-reach-v3,push-v3,pick-place-v3,door-open-v3,drawer-open-v3,drawer-close-v3,button-press-topdown-v3,peg-insert-side-v3,window-open-v3,window-close-v3}" \
      --worlds "${TP_WORLDS:-1024,4096,8192}" --steps 10 --cpu-procs 16 --cpu-seconds "${TP_CPU_S:-15}" --episodes 0 \
      --out "$OUT/throughput.json" --overwrite 2>&1 | quiet > "$OUT/throughput.log"; tail -12 "$OUT/throughput.log"
    if [ -n "${SMOKE_AFTER:-}" ]; then  # after the throughput, whose first steps compiled the kernels
      timeout "${SMOKE_LIMIT:-120}" python3 benchmarks/metaworld_warp_fidelity.py --tasks reach-v3 --seeds 0:2 --steps 30 \
        --device cuda:0 --out "$OUT/smoke_fidelity.json" --overwrite 2>&1 | quiet | tee "$OUT/smoke.log" | tail -3
    fi
    if [ "${MT50_LIMIT:-200}" != 0 ]; then  # MT50_LIMIT=0: no MT50 x 50 (and no log of it to show)
      timeout "${MT50_LIMIT:-200}" python3 benchmarks/metaworld_warp_throughput.py --device cuda:0 --tasks mt50 \
        --worlds "" --cpu-procs 0 --episodes 50 --mt50-procs "${MT50_PROCS:-8}" ${MT50_MPS:+--mps} \
        --out "$OUT/throughput_mt50x50.json" --overwrite 2>&1 | quiet > "$OUT/mt50.log"; tail -5 "$OUT/mt50.log"
    fi
    ;;
  mt50x50)
    order=benchmarks/results/metaworld_mt50x50_mps16_warm_h100.json
    for run in ${MT50_RUNS:-cold host plain}; do  # a run's name: cold, host, plain or cli, then its processes if not MT50_PROCS
      # cli: `simseam eval metaworld_mt50 --engine mujoco_warp --processes K --mps --policy random`, as a user runs it
      flag=--host-arrays; [ "${run//[0-9]/}" = plain ] && flag=; [ "${run//[0-9]/}" = cli ] && flag=--mt50-cli
      procs="${run//[!0-9]/}"
      limit="${MT50_LIMIT:-180}"; [ "${run//[0-9]/}" = cold ] && limit="${MT50_COLD_LIMIT:-330}"
      timeout "$limit" python3 benchmarks/metaworld_warp_throughput.py --device cuda:0 --tasks mt50 \
        --worlds "" --cpu-procs 0 --episodes 50 --mt50-procs "${procs:-${MT50_PROCS:-16}}" --mps --mt50-order "$order" $flag \
        --out "$OUT/mt50x50_$run.json" --overwrite 2>&1 | quiet > "/tmp/mt50_$run.log"; echo "== $run"; tail -2 "/tmp/mt50_$run.log"
      cat "/tmp/mt50_$run.log" >> "$OUT/mt50.log"  # one log: a call brings back at most 8 files
    done
    [ "${KCACHE:-1}" = 0 ] && exit 0  # KCACHE=0: no kernel cache back (an earlier call brought it)
    cache_back "$WARP_CACHE_PATH" "$OUT" mw_kcache 45000000
    ;;
  fidelity)  # resumable: a second call with FID_RESUME=1 (machine still warm) runs only the tasks not yet on disk
    mkdir -p /tmp/mwfid; FID=/tmp/mwfid/metaworld_warp_fidelity.json
    # FID_FROM: an earlier call's merged JSON (same seeds, steps, device): its tasks are kept, only the rest run
    # (e.g. FID_FROM=benchmarks/results/metaworld_warp_fidelity_mt50_cuda.json: the four tasks it lacks)
    [ -n "${FID_FROM:-}" ] && [ ! -f "$FID" ] && cp "$FID_FROM" "$FID"
    if [ -z "${FID_RESUME:-}" ]; then  # a CUDA smoke first (it compiles the kernels once for the 15 jobs); if it
      # hangs, a watchdog sends SIGABRT and faulthandler prints where every process of it waits
      # (300 s: on a fresh machine the first CUDA compile of the kernels alone took over 150 s, 6 December)
      ( sleep "${SMOKE_LIMIT:-300}"; pkill -ABRT -f 'metaworld_gpu.native|metaworld_warp_fidelity' ) & wd=$!
      PYTHONFAULTHANDLER=1 python3 benchmarks/metaworld_warp_fidelity.py --tasks reach-v3,drawer-close-v3 --seeds 0:4 \
        --steps 60 --device cuda:0 --out "$OUT/smoke_fidelity.json" --overwrite 2>&1 | quiet | tee "$OUT/smoke.log" | tail -40
      kill "$wd" 2>/dev/null
      [ -s "$OUT/smoke_fidelity.json" ] || { echo "smoke failed: no fidelity run"; exit 1; }
    fi
    timeout "${FID_LIMIT:-400}" python3 benchmarks/metaworld_warp_fidelity.py --tasks mt50 --seeds 0:50 --steps 500 \
      --device cuda:0 --jobs "${FID_JOBS:-15}" --out "$FID" --resume 2>&1 | quiet >> /tmp/mwfid/fidelity.log
    # one archive: the device tool brings back at most 8 files, and there is a part per job and call
    tar -C /tmp/mwfid -czf "$OUT/mwfid.tgz" . && cp /tmp/mwfid/fidelity.log "$OUT/"; tail -8 /tmp/mwfid/fidelity.log
    ls /tmp/mwfid/metaworld_warp_fidelity.parts | wc -l
    ;;
  cameras)  # carry .gl too: the CPU backend's cameras render through EGL (the GL loader debs, as vector_lockstep.sh)
    for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig; export MUJOCO_GL=egl
    # the driver's EGL where the loader does not find it (the device README's hint): the GPU's OpenGL, not llvmpipe
    V=/usr/local/nvidia/share/glvnd/egl_vendor.d/10_nvidia.json; [ -f "$V" ] && export __EGL_VENDOR_LIBRARY_FILENAMES=$V
    timeout "${TP_LIMIT:-540}" python3 benchmarks/metaworld_warp_throughput.py --device cuda:0 --no-state \
      --tasks "${TP_TASKS:-reach-v3,push-v3,pick-place-v3,door-open-v3,drawer-open-v3,drawer-close-v3,button-press-topdown-v3,peg-insert-side-v3,window-open-v3,window-close-v3}" \
      --cameras corner,gripperPOV --image 128 --camera-worlds "${TP_WORLDS:-1024,4096}" --steps 10 --cpu-procs 16 \
      --cpu-seconds "${TP_CPU_S:-15}" --episodes 0 --out "$OUT/throughput_cameras.json" --overwrite 2>&1 | quiet > "$OUT/cameras.log"
    tail -12 "$OUT/cameras.log"
    # then the SSIM / PSNR of the ray tracer against MuJoCo's OpenGL on the same states, here on CUDA (the CPU device's
    # figure is in docs/benchmarks.md); SSIM=0 skips it
    [ "${SSIM:-1}" = 0 ] || timeout "${SSIM_LIMIT:-240}" python3 benchmarks/metaworld_warp_cameras.py --device cuda:0 \
      --out "$OUT/cameras_ssim_cuda.json" --overwrite 2>&1 | quiet > "$OUT/ssim.log"; tail -12 "$OUT/ssim.log"
    ;;
  kernels)  # the call before one that measures MT50 (a fresh machine, no kernel cache carried): every task's kernels
    # compiled, and its model and reset states cached, by KPROCS processes at once (default 8), TP_WORLDS worlds
    # (default 8192) for one step a task, so that the measuring call compiles nothing. One process alone took
    # 252 s for the first task's kernels and 715 s of setups over the 50 tasks on 7 December; the three tasks whose
    # setups then compiled most kernels of their own (48-120 s) get a process each, the others share the rest.
    mapfile -t shares < <(python3 - "${KPROCS:-8}" <<'EOP'
import sys
from simseam.backends.metaworld_gpu.tasks import OBJECTS
alone = ["assembly-v3", "box-close-v3", "basketball-v3"]
rest = [t for t in sorted(OBJECTS) if t not in alone]
k = int(sys.argv[1]) - len(alone)
print("\n".join(alone + [",".join(rest[i::k]) for i in range(k)]))
EOP
)
    for i in "${!shares[@]}"; do
      timeout "${TP_LIMIT:-480}" python3 benchmarks/metaworld_warp_throughput.py --device cuda:0 --tasks "${shares[$i]}" \
        --worlds "${TP_WORLDS:-8192}" --steps 1 --cpu-procs 0 --episodes 0 --out "/tmp/mwk_$i.json" --overwrite \
        > "/tmp/mwk_$i.log" 2>&1 &
    done
    rc=0; for job in $(jobs -p); do wait "$job" || rc=$?; done
    for i in "${!shares[@]}"; do echo "== process $i"; quiet < "/tmp/mwk_$i.log"; done > "$OUT/kernels.log"
    grep -c "env-steps/s" "$OUT/kernels.log"; tail -4 "$OUT/kernels.log"; exit "$rc"
    ;;
  *) echo "usage: $0 throughput | mt50x50 | fidelity | cameras | kernels" >&2; exit 2 ;;
esac
