#!/usr/bin/env bash
# One GPU-machine call, the third of warp_upload.sh's three (README.md here): the batched engine and the
# lockstep runner before and after the seam redesign, alternating in the same call, then where the camera
# step's time goes (bench_warp_render.py) and the batched engine's throughput table with cameras.
#   here:  bash benchmarks/device/warp_upload.sh prepare .cache/warpcarry
#          D=.cache/warpcarry; rm -rf $D/c1/src; git archive HEAD src | tar -x -C $D/c1   # committed sources only
#          B=bd54bc2^    # the last revision before the redesign moved the batched scene (issue 22)
#          git archive $B src | tar -x -C $D/c3 --transform 's,^src,src-base,'
#          git show $B:benchmarks/bench_vector.py > $D/c3/bench_vector_base.py
#          git show $B:benchmarks/bench_warp.py > $D/c3/bench_warp_base.py; git rev-parse --short $B > $D/c3/BASE_REV
#          cp benchmarks/bench_warp_render.py $D/c3/
#   there: calls 1 and 2: bash benchmarks/device/warp_upload.sh receive .cache/warpcarry/c1 (c2);
#          call 3:        bash benchmarks/device/warp_before_after.sh      (carry .cache/warpcarry/c3 and .gl:
#                         the GL loader debs MuJoCo's EGL import needs, act_lift.sh's header says how)
# Returns $OUT/log.txt (every table) and $OUT/results.tgz (each run's JSON).
set -uo pipefail
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
bash benchmarks/device/warp_upload.sh receive .cache/warpcarry/c3 > /dev/null
bash benchmarks/device/warp_upload.sh install
W=/tmp/ww R=$OUT/res LOG=$OUT/log.txt
mkdir -p "$R"
export MUJOCO_GL=egl PYTHONUNBUFFERED=1
robot=(--robot-json $W/panda.json --urdf $W/franka_panda/panda.urdf)
echo "base $(cat $W/BASE_REV), head: the carried src" | tee -a "$LOG"
side() {  # side NAME: the sources and scripts of one side
  if [ "$1" = base ]; then src=$W/src-base bw=$W/bench_warp_base.py bv=$W/bench_vector_base.py
  else src=$W/src bw=$W/bench_warp.py bv=$W/bench_vector.py; fi
}
i=0
for s in head base head base; do  # bench_warp, state only (issue 22: no regression)
  i=$((i + 1)); side $s
  echo "== bench_warp $i $s ($SECONDS s)" | tee -a "$LOG"
  PYTHONPATH=/tmp/site:$src timeout 150 python3 $bw "${robot[@]}" --worlds 1024,4096 --collision primitives \
    --observations state --steps 20 --out $R/warp_${i}_$s.json > $R/warp_${i}_$s.txt 2>&1; tail -3 $R/warp_${i}_$s.txt | tee -a "$LOG"
done
i=0
for s in base head base head; do  # lockstep (vector) against N bare processes at N = 16 cores
  i=$((i + 1)); side $s
  echo "== bench_vector $i $s ($SECONDS s)" | tee -a "$LOG"
  PYTHONPATH=/tmp/site:$src timeout 90 python3 $bv "${robot[@]}" --n 1 16 --steps 300 --episodes-per-env 2 \
    --cases state --modes vector bare --out $R/vector_${i}_$s.json 2>&1 | grep '^|' | tee -a "$LOG"
done
echo "== bench_warp_render ($SECONDS s)" | tee -a "$LOG"
PYTHONPATH=/tmp/site:$W/src timeout 200 python3 $W/bench_warp_render.py "${robot[@]}" --worlds 1024,4096 \
  --image 128 --steps 20 --out $R/warp_render.json > $R/warp_render.txt 2>&1
grep -v '^Module\|^Warp\|^   [A-Z"]' $R/warp_render.txt | tee -a "$LOG"
echo "== bench_warp head, state and 2x128^2 RGB ($SECONDS s)" | tee -a "$LOG"
T=$((575 - SECONDS)); [ $T -gt 30 ] && PYTHONPATH=/tmp/site:$W/src timeout $T python3 $W/bench_warp.py "${robot[@]}" --worlds 1024,4096 \
  --collision primitives --observations state,rgb --steps 20 --out $R/warp_table.json > $R/warp_table.txt 2>&1
tail -6 $R/warp_table.txt | tee -a "$LOG"
tar -C "$OUT" -czf "$OUT/results.tgz" res && rm -rf "$R"
echo "total $SECONDS s" | tee -a "$LOG"
