#!/usr/bin/env bash
# One GPU-machine call (16 cores): lockstep (one batched policy in the parent over N worker processes)
# against N bare processes at N = 1 and 16, the vector runner before and after a change, alternating
# in the same call (issue 22 item 8: lockstep >= 0.8 of bare at N = cores). State-only lift_cube, no GPU
# use; only mujoco, PyOpenGL and the GL loader debs are installed there.
#
#   here:  bash benchmarks/device/vector_lockstep.sh prepare BEFORE [AFTER] [DIR]
#            BEFORE / AFTER: revisions (AFTER default HEAD; committed sources only, git archive);
#            DIR default .cache/vectorcarry (~25 MB: the cp312 mujoco and PyOpenGL wheels, the Panda as a
#            RobotSpec JSON with its URDF and meshes, src-before/, src-after/, bench_vector.py and
#            bench_idle_step.py of AFTER)
#   there: bash benchmarks/device/vector_lockstep.sh run [DIR]      (carry DIR and .gl)
#            -> $OUT/log.txt (every table), $OUT/vector_<i>_<side>.json; ~8 of the 10 minutes
#   there: TAG=k bash benchmarks/device/vector_lockstep.sh holds [DIR] [MODE ...]   (AFTER only, N = 16, ~3 minutes,
#            no profile; unpacks DIR only when /tmp/vl is not there yet) -> $OUT/vector_holds_k.json, $OUT/log.txt
#   there: bash benchmarks/device/vector_lockstep.sh grid [DIR] [MODE ...]   (AFTER only, N = 16, ~4 minutes)
#            lockstep variants against bare (default: plain, 4 and 8 policy groups, each with the default
#            busy-poll rule and with it forced on, plain and 8 groups also with a 200 us one; or the bench_vector
#            modes given); then each under cProfile (bench_vector --profile); then bench_idle_step.py (a step
#            after an idle gap) -> $OUT/log.txt, $OUT/vector_grid.json, $OUT/idle_step.json
#
# Each side runs bench_vector.py --n 1 16 --steps 600 --rounds 3 --cases state --modes vector vector_spin
# bare (vector: the default busy-poll rule, which is off at N = cores; vector_spin: forced on), in the
# order before after before after; AFTER also runs vector_g2 vector_g4 (pipelined lockstep, 2 / 4 policy
# groups: run(groups=K), which BEFORE's sources may not have) and gets a longer time limit.
set -uo pipefail
cmd="${1:-}"

unpack() {  # there: the GL loader debs, the carry DIR in /tmp/vl, its wheels in /tmp/vl/site; LOG and the env
  for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
  rm -rf /tmp/vl; mkdir -p /tmp/vl; cp -r "$1"/. /tmp/vl/
  python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/vl/site /tmp/vl/*.whl
  LOG=$OUT/log.txt
  export MUJOCO_GL=egl PYTHONUNBUFFERED=1
}
case "$cmd" in
  prepare)
    ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
    BEFORE="${2:?prepare BEFORE [AFTER] [DIR]}" AFTER="${3:-HEAD}" DIR="${4:-$ROOT/.cache/vectorcarry}"
    PY="${PYTHON:-$ROOT/.venv/bin/python}"
    rm -rf "$DIR"; mkdir -p "$DIR"
    W="$ROOT/.cache/warpcarry"  # warp_upload.sh's wheels, when there
    if ls "$W"/c1/mujoco_core-*.whl "$W"/c2/mujoco-*.whl "$W"/c3/pyopengl-*.whl > /dev/null 2>&1; then
      cp "$W"/c1/mujoco_core-*.whl "$W"/c2/mujoco-*.whl "$W"/c3/pyopengl-*.whl "$DIR/"
    else
      "$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
        --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux2014_x86_64 \
        -d "$DIR" mujoco==4.0.0 mujoco-core==4.0.0 PyOpenGL==3.1.10
    fi
    . "$ROOT/benchmarks/device/sides.sh"; archive_sides "$ROOT" "$BEFORE" "$AFTER" "$DIR" bench_vector.py
    (cd "$ROOT" && git show "$AFTER:benchmarks/bench_idle_step.py" > "$DIR/bench_idle_step.py" 2>/dev/null) \
      || rm -f "$DIR/bench_idle_step.py"  # (grid's last part; older revisions have none)
    (cd "$ROOT" && git show "$AFTER:benchmarks/cpu_facts.py" > "$DIR/cpu_facts.py" 2>/dev/null) \
      || rm -f "$DIR/cpu_facts.py"  # (bench_vector's machine facts; older revisions have none)
    "$PY" - "$DIR" <<'PY'
import json, shutil, sys
from pathlib import Path
from simseam.robot.assets import resolve_asset
from simseam.robot.manifest import load_robot
d = Path(sys.argv[1])
r = load_robot("franka_panda")
(d / "panda.json").write_text(json.dumps(r.to_json()))
shutil.copytree(Path(resolve_asset(r.urdf)).parent, d / "franka_panda")
PY
    du -sh "$DIR"; cat "$DIR/REVS"
    ;;
  run)
    DIR="${2:-.cache/vectorcarry}"
    unpack "$DIR"
    echo "$(cat /tmp/vl/REVS); $(nproc) cores; load $(cut -d' ' -f1-3 /proc/loadavg)" | tee -a "$LOG"
    i=0
    for s in before after before after; do
      i=$((i + 1))
      modes="vector vector_spin bare" limit=130
      if [ $s = after ]; then modes="$modes vector_g2 vector_g4" limit=200; fi
      if [ $((SECONDS + limit)) -gt 590 ]; then echo "== stopped before run $i: $SECONDS s used" | tee -a "$LOG"; break; fi
      echo "== bench_vector $i $s ($SECONDS s, load $(cut -d' ' -f1-3 /proc/loadavg))" | tee -a "$LOG"
      PYTHONPATH=/tmp/vl/site:/tmp/vl/src-$s timeout $limit python3 /tmp/vl/bench_vector.py \
        --robot-json /tmp/vl/panda.json --urdf /tmp/vl/franka_panda/panda.urdf \
        --n 1 16 --steps 600 --episodes-per-env 2 --rounds 3 --cases state --modes $modes \
        --out "$OUT/vector_${i}_$s.json" 2>&1 | grep '^|' | tee -a "$LOG"
    done
    echo "total $SECONDS s" | tee -a "$LOG"
    ;;
  grid)
    DIR="${2:-.cache/vectorcarry}"
    shift $(($# < 2 ? $# : 2))
    MODES="${*:-vector vector_spin vector_spin200 vector_g4 vector_g4_spin vector_g8 vector_g8_spin vector_g8_spin200}"
    unpack "$DIR"
    echo "$(cat /tmp/vl/REVS) (grid: after only); $(nproc) cores; load $(cut -d' ' -f1-3 /proc/loadavg)" | tee -a "$LOG"
    PYTHONPATH=/tmp/vl/site:/tmp/vl/src-after timeout 500 python3 /tmp/vl/bench_vector.py \
      --robot-json /tmp/vl/panda.json --urdf /tmp/vl/franka_panda/panda.urdf \
      --n 16 --steps 600 --episodes-per-env 2 --rounds 3 --cases state --profile \
      --modes $MODES bare \
      --out "$OUT/vector_grid.json" 2>&1 | grep -v '^  state' | tee -a "$LOG"
    PYTHONPATH=/tmp/vl/site:/tmp/vl/src-after timeout 60 python3 /tmp/vl/bench_idle_step.py \
      --robot-json /tmp/vl/panda.json --urdf /tmp/vl/franka_panda/panda.urdf --out "$OUT/idle_step.json" 2>&1 | tee -a "$LOG"
    echo "total $SECONDS s" | tee -a "$LOG"
    ;;
  holds)  # AFTER only, N = 16, no profile (~2-3 minutes): which lockstep rules hold >= 0.8 of bare, call after call.
    # The carry is unpacked only when /tmp/vl is not there yet, so back-to-back calls on a warm machine need not
    # carry it again (they may carry other work's files instead). TAG names the output: $OUT/vector_holds_TAG.json
    DIR="${2:-.cache/vectorcarry}"
    shift $(($# < 2 ? $# : 2))
    MODES="${*:-vector vector_default vector_x2_ready4 vector_x4_ready8}"  # vector_default: what a run naming no rule gets
    if [ -f /tmp/vl/REVS ] && [ -d /tmp/vl/site ]; then
      LOG=$OUT/log.txt; export MUJOCO_GL=egl PYTHONUNBUFFERED=1; for f in .gl/*.deb; do [ -f "$f" ] && dpkg -x "$f" /; done; ldconfig
    else
      unpack "$DIR"
    fi
    echo "$(cat /tmp/vl/REVS) (holds); $(nproc) cores; load $(cut -d' ' -f1-3 /proc/loadavg)" | tee -a "$LOG"
    PYTHONPATH=/tmp/vl/site:/tmp/vl/src-after timeout "${HOLDS_LIMIT:-400}" python3 /tmp/vl/bench_vector.py \
      --robot-json /tmp/vl/panda.json --urdf /tmp/vl/franka_panda/panda.urdf \
      --n 16 --steps 600 --episodes-per-env "${EPISODES_PER_ENV:-2}" --rounds "${ROUNDS:-3}" --cases state \
      --modes $MODES bare --out "$OUT/vector_holds_${TAG:-0}.json" 2>&1 | grep -v '^  state' | tee -a "$LOG"
    echo "total $SECONDS s" | tee -a "$LOG"
    ;;
  *)
    echo "usage: $0 prepare BEFORE [AFTER] [DIR] | run [DIR] | grid [DIR] [MODE ...] | holds [DIR] [MODE ...]" >&2; exit 2
    ;;
esac
