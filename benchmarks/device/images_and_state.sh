#!/usr/bin/env bash
# One device call, three trainings sharing the H200 (none fills it alone): Diffusion Policy from images on
# lift_cube and ACT from images on bowl_plate (benchmarks/device/act_lift.sh, each with 8 collection workers
# and 4 curve threads of the machine's 16 cores), and the ManiSkill3 PickCube state ACT at dim 256 / 4 encoder
# layers (benchmarks/device/maniskill_train.sh). Carry: .whl .gl .devcarry .mscarry (their headers say how
# each is prepared). Returns $OUT/{dp_lift,act_bowl_plate}.{json,log}, ms_b.log and ms_b.tgz.part* (the
# checkpoint, split under the tool's 16 MiB per file).
set -uo pipefail
SITE=${SITE:-/tmp/site}
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" .whl/*.whl
touch "$SITE/.installed"
echo "setup: $SECONDS s"
L=$((560 - SECONDS))
(STEPS=${MS_STEPS:-16000} DIM_MODEL=256 FF_DIM=1024 ENCODER_LAYERS=4 NAME=ms_b TIME_BUDGET_S=$((L - 60)) \
  timeout $L bash benchmarks/device/maniskill_train.sh > "$OUT/ms_b.log" 2>&1
 echo "rc=$?" >> "$OUT/ms_b.log"; tar -C "$OUT" -czf - ms_b | split -b 15M - "$OUT/ms_b.tgz.part"; rm -rf "$OUT/ms_b") &
SKIP_SETUP=1 LIMIT=$L NAME=dp_lift bash benchmarks/device/act_lift.sh --policy-type diffusion --episodes 300 \
  --collect-workers 8 --curve-every 500 --curve-seeds 10000:10010 --curve-threads 4 --curve-first-s 60 \
  --eval-reserve-s 130 > /dev/null 2>&1 &
sleep 15  # the two act_lift.sh unpack the same assets into $SITE: not at the same moment
SKIP_SETUP=1 LIMIT=$((L - 15)) NAME=act_bowl_plate bash benchmarks/device/act_lift.sh --task bowl_plate --max-steps 200 \
  --episodes 300 --collect-workers 8 --curve-every 1000 --curve-seeds 10000:10010 --curve-threads 4 \
  --curve-first-s 40 --eval-reserve-s 150 > /dev/null 2>&1 &
wait
tail -n 3 "$OUT"/*.log
echo "total: $SECONDS s"
