#!/usr/bin/env bash
# The sidecar's added step latency and the vector runner against bare processes, on the lent GPU
# machine (16 cores; no registry there). Here:
#   mkdir -p .cache/scarry && cp <the cp312 wheels of mujoco-core, mujoco, pyzmq, msgpack, PyOpenGL>,
#   panda.json (the Panda's RobotSpec JSON), franka_panda/ (URDF + meshes), src/, bench_sidecar.py and
#   bench_vector.py into it  (25 MB; benchmarks/device/warp_upload.sh prepare builds the same pieces)
# device tool: run(command="bash benchmarks/device/latency_run.sh", carry=[".cache/scarry", ".gl"])
set -euo pipefail
C=.cache/scarry
mkdir -p /tmp/glx /tmp/gllib
for d in .gl/*.deb; do dpkg -x "$d" /tmp/glx; done
for f in $(find /tmp/glx -name '*.so*' \( -type f -o -type l \)); do
  ldconfig -p | grep -q "$(basename "$f") " || cp -a "$f" /tmp/gllib/
done
export LD_LIBRARY_PATH=/tmp/gllib MUJOCO_GL=egl
python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site $C/*.whl
export PYTHONPATH=/tmp/site:$PWD/$C/src
nproc; python3 --version
python3 $C/bench_sidecar.py --parts step,profile --cases state,rgb2x256 --rounds 7 \
  --robot-json $C/panda.json --urdf $C/franka_panda/panda.urdf --json "$OUT/sidecar_h200.json" 2>&1 | tee "$OUT/sidecar_h200.txt"
python3 $C/bench_vector.py --n 1 2 4 8 16 --cases state --modes vector async local bare --rounds 3 \
  --robot-json $C/panda.json --urdf $C/franka_panda/panda.urdf --out "$OUT/vector_h200_bare.json" 2>&1 | tee "$OUT/vector_h200_bare.txt"
