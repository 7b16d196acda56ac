#!/usr/bin/env bash
# One GPU-machine call (its 16 idle CPU cores; no GPU work but EGL for the camera rows): bench_step.py's
# cost of a control step against the physics floor (issue 22: the state-only Cartesian step within 1.25x),
# on two revisions' sources, one round per process, alternating before / after ROUNDS times.
#   here:  bash benchmarks/device/step_before_after.sh prepare BEFORE [AFTER] [DIR]
#            (committed sources by git archive; DIR default .cache/stepcarry, ~20 MB: the cp312 wheels of
#            mujoco, PyOpenGL, pydantic, PyYAML, the Panda's manifest with its URDF and meshes)
#   there: bash benchmarks/device/step_before_after.sh run [DIR]     (carry DIR and .gl)
#            -> $OUT/log.txt, $OUT/step_before_after.json (medians per side) and $OUT/rounds.tgz (each round's JSON:
#               a call returns at most 8 files)
set -euo pipefail
cmd="${1:-}"
case "$cmd" in
  prepare)
    ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
    BEFORE="${2:?prepare BEFORE [AFTER] [DIR]}" AFTER="${3:-HEAD}" DIR="${4:-$ROOT/.cache/stepcarry}"
    PY="${PYTHON:-$ROOT/.venv/bin/python}"
    rm -rf "$DIR"; mkdir -p "$DIR"
    "$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
      --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux2014_x86_64 \
      -d "$DIR" mujoco==4.0.0 mujoco-core==4.0.0 PyOpenGL==3.1.10 pydantic==2.14.4 pydantic-core==2.50.5 \
      annotated-types==0.8.0 typing-inspection==0.4.5 pyyaml==6.0.2 2>&1 | grep -v "Location 'file" || true
    . "$ROOT/benchmarks/device/sides.sh"; archive_sides "$ROOT" "$BEFORE" "$AFTER" "$DIR" bench_step.py
    "$PY" - "$DIR" <<'PY'
import re, shutil, sys
from pathlib import Path
from simseam.robot.assets import resolve_asset
from simseam.robot.manifest import find_manifest, load_robot
d = Path(sys.argv[1])
urdf = Path(resolve_asset(load_robot("franka_panda").urdf))
shutil.copytree(urdf.parent, d / "franka_panda")
text = Path(find_manifest("franka_panda")).read_text()
(d / "franka_panda.yaml").write_text(re.sub(r"(?m)^urdf: .*$", f"urdf: file:franka_panda/{urdf.name}", text))
PY
    du -sh "$DIR"; cat "$DIR/REVS"
    ;;
  run)
    DIR="${2:-.cache/stepcarry}" ROUNDS="${ROUNDS:-8}"
    for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
    rm -rf /tmp/sc; mkdir -p /tmp/sc; cp -r "$DIR"/. /tmp/sc/
    python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/sc/site /tmp/sc/*.whl
    LOG=$OUT/log.txt
    export MUJOCO_GL=egl PYTHONUNBUFFERED=1
    echo "$(cat /tmp/sc/REVS); $(nproc) cores; load $(cut -d' ' -f1-3 /proc/loadavg)" | tee -a "$LOG"
    for i in $(seq 1 "$ROUNDS"); do
      if [ $((i % 2)) = 1 ]; then order="before after"; else order="after before"; fi
      for s in $order; do
        PYTHONPATH=/tmp/sc/site:/tmp/sc/src-$s timeout 120 python3 /tmp/sc/bench_step.py --robot /tmp/sc/franka_panda.yaml \
          --steps 300 --rounds 1 --json "$OUT/step_${i}_$s.json" > /dev/null 2>&1 || echo "round $i $s failed" | tee -a "$LOG"
      done
      echo "round $i done ($SECONDS s)" | tee -a "$LOG"
    done
    python3 - "$OUT" <<'PY' | tee -a "$LOG"
import glob, json, statistics, sys
out = sys.argv[1]
sides = {}
for side in ("before", "after"):
    runs = [json.load(open(f)) for f in sorted(glob.glob(f"{out}/step_*_{side}.json"))]
    cases = runs[0]["results"].keys()
    sides[side] = {k: {"x_floor_median": statistics.median(r["results"][k]["x_floor"] for r in runs),
                       "x_floor_rounds": [r["results"][k]["x_floor"] for r in runs],
                       "p50_ms_median": statistics.median(r["results"][k]["p50_ms"] for r in runs)} for k in cases}
print(f"{'case':24s} {'before p50':>10s} {'after p50':>10s} {'before x':>9s} {'after x':>9s}  (x floor, medians of rounds)")
for k in sides["after"]:
    b, a = sides["before"][k], sides["after"][k]
    print(f"{k:24s} {b['p50_ms_median']:10.3f} {a['p50_ms_median']:10.3f} {b['x_floor_median']:9.3f} {a['x_floor_median']:9.3f}")
json.dump({"revs": open("/tmp/sc/REVS").read().strip(), "sides": sides}, open(f"{out}/step_before_after.json", "w"), indent=2)
PY
    tar -C "$OUT" -czf "$OUT/rounds.tgz" $(cd "$OUT" && ls step_*_*.json) && rm -f "$OUT"/step_*_before.json "$OUT"/step_*_after.json
    echo "total $SECONDS s" | tee -a "$LOG"
    ;;
  *)
    echo "usage: $0 prepare BEFORE [AFTER] [DIR] | run [DIR]" >&2; exit 2
    ;;
esac
