#!/usr/bin/env bash
# One GPU-machine call, the third of warp_upload.sh's three (README.md here): where MuJoCo Warp's camera
# step spends its time and what each render option buys (bench_warp_render.py: the split, the state-only
# scene's step beside the camera scene's, six render variants, the image cadence), then the CPU step's
# cost against the physics floor on that machine's idle cores (bench_step.py: issue 22's 1.25x).
# Both scripts and simseam's sources are the sent checkout's; only the wheels and the Panda travel in the carry.
#   here:  bash benchmarks/device/warp_upload.sh prepare .cache/warpcarry
#          D=.cache/warpcarry; mkdir -p $D/c3r; cp $D/c3/warp.part02 $D/c3/*.whl $D/c3/panda.json $D/c3/franka_panda.yaml $D/c3r/
#          .venv/bin/python -m pip download --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
#            --platform manylinux2014_x86_64 -d $D/c3r pyyaml==6.0.2          # bench_step loads a manifest
#   there: calls 1 and 2: bash benchmarks/device/warp_upload.sh receive .cache/warpcarry/c1 (c2);
#          call 3:        bash benchmarks/device/warp_render_step.sh   (carry .cache/warpcarry/c3r and .gl)
# Returns $OUT/log.txt (every table), $OUT/warp_render.json and $OUT/step.json.
set -uo pipefail
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
bash benchmarks/device/warp_upload.sh receive .cache/warpcarry/c3r > /dev/null
bash benchmarks/device/warp_upload.sh install
W=/tmp/ww LOG=$OUT/log.txt
export MUJOCO_GL=egl PYTHONUNBUFFERED=1 PYTHONPATH=/tmp/site:$PWD/src
echo "== bench_warp_render ($SECONDS s)" | tee -a "$LOG"
timeout 330 python3 benchmarks/bench_warp_render.py --robot-json $W/panda.json --urdf $W/franka_panda/panda.urdf \
  --worlds 1024,4096 --image 128 --steps 20 --out "$OUT/warp_render.json" > "$OUT/warp_render.txt" 2>&1
grep -v '^Module\|^Warp\|^   [A-Z"]' "$OUT/warp_render.txt" | tee -a "$LOG"
echo "== bench_step on idle cores ($SECONDS s; load $(cut -d' ' -f1-3 /proc/loadavg))" | tee -a "$LOG"
T=$((570 - SECONDS)); [ $T -gt 30 ] && timeout $T python3 benchmarks/bench_step.py --robot $W/franka_panda.yaml \
  --steps 300 --rounds 8 --json "$OUT/step.json" 2>&1 | tail -12 | tee -a "$LOG"
echo "total $SECONDS s" | tee -a "$LOG"
