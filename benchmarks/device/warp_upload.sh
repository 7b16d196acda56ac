#!/usr/bin/env bash
# Getting MuJoCo Warp onto the lent GPU machine (no registry there, 64 MiB per call).
#
#   here:   bash benchmarks/device/warp_upload.sh prepare [DIR]   (default DIR: .cache/warpcarry)
#           -> DIR/c1, DIR/c2, DIR/c3: what three consecutive calls carry (each < 62 MB):
#              the warp-lang wheel (149 MB) split in three chunks + SHA256, the cp312 wheels of
#              mujoco / mujoco-core / mujoco-warp, simseam's src/, this benchmark, the Panda
#              as a RobotSpec JSON and its URDF + meshes (no pydantic / pybullet needed there);
#              for bench_vector.py also the PyOpenGL and msgpack wheels (EGL cameras, built-in policies)
#   there:  call k (k = 1, 2, 3, while the machine stays warm), carrying DIR/ck:
#             bash benchmarks/device/warp_upload.sh receive DIR/ck      (copies to /tmp/ww)
#           the last call then:
#             bash benchmarks/device/warp_upload.sh install             (concatenate, sha256, pip --target)
#             export PYTHONPATH=/tmp/site:/tmp/ww/src
#             python3 /tmp/ww/bench_warp.py --robot-json /tmp/ww/panda.json --urdf /tmp/ww/franka_panda/panda.urdf
#             python3 /tmp/ww/warp_conformance.py --robot /tmp/ww/franka_panda.yaml --robot /tmp/ww/so101.yaml
#             python3 /tmp/ww/bench_vector.py --robot-json /tmp/ww/panda.json --urdf /tmp/ww/franka_panda/panda.urdf ...
# Paths carried in one call are removed in the next, hence the copy to /tmp/ww. warp's kernel cache
# (~/.cache/warp) lives on that machine only: compile and benchmark in as few calls as possible.
set -euo pipefail
cmd="${1:-}"
case "$cmd" in
  prepare)
    ROOT="$(cd "$(dirname "$0")/../.." && pwd)"
    DIR="${2:-$ROOT/.cache/warpcarry}"
    PY="${PYTHON:-$ROOT/.venv/bin/python}"
    rm -rf "$DIR"; mkdir -p "$DIR/c1" "$DIR/c2" "$DIR/c3" "$DIR/wheels"
    "$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
      --platform manylinux_2_28_x86_64 --platform manylinux_2_27_x86_64 --platform manylinux2014_x86_64 \
      -d "$DIR/wheels" warp-lang==1.19.0 mujoco==4.0.0 mujoco-core==4.0.0 mujoco-warp==4.0.0 \
      PyOpenGL==3.1.10 msgpack==1.1.2
    W="$(ls "$DIR"/wheels/warp_lang-*.whl)"
    split -n 3 -d "$W" "$DIR/warp.part"
    sha256sum "$W" | awk '{print $1}' > "$DIR/c1/warp.sha256"
    basename "$W" > "$DIR/c1/warp.name"
    mv "$DIR/warp.part00" "$DIR/c1/"; mv "$DIR/warp.part01" "$DIR/c2/"; mv "$DIR/warp.part02" "$DIR/c3/"
    mv "$DIR"/wheels/mujoco_core-*.whl "$DIR/c1/"
    mv "$DIR"/wheels/mujoco-*.whl "$DIR"/wheels/mujoco_warp-*.whl "$DIR/c2/"
    cp -r "$ROOT/src" "$DIR/c1/src"; find "$DIR/c1/src" -name __pycache__ -prune -exec rm -rf {} +
    mv "$DIR"/wheels/pyopengl-*.whl "$DIR"/wheels/msgpack-*.whl "$DIR/c3/"
    cp "$ROOT/benchmarks/bench_warp.py" "$ROOT/benchmarks/bench_vector.py" "$ROOT/benchmarks/warp_conformance.py" "$DIR/c3/"
    # warp_conformance.py loads manifests (pydantic) and needs the SO-101's URDF + meshes too
    "$PY" -m pip download -q --no-deps --only-binary=:all: --python-version 3.12 --implementation cp \
      --platform manylinux2014_x86_64 -d "$DIR/c3" pydantic==2.14.4 pydantic-core==2.50.5 \
      annotated-types==0.8.0 typing-inspection==0.4.5
    "$PY" - "$DIR" <<'PY'
import json, shutil, sys
from pathlib import Path
from simseam.robot.assets import resolve_asset
from simseam.robot.manifest import load_robot
d = Path(sys.argv[1])
r = load_robot("franka_panda")
(d / "c3" / "panda.json").write_text(json.dumps(r.to_json()))
shutil.copytree(Path(resolve_asset(r.urdf)).parent, d / "c2" / "franka_panda")
import re, tarfile
from simseam.robot.manifest import find_manifest
for name, folder in (("franka_panda", "franka_panda"), ("so101", "SO101")):
    urdf = Path(resolve_asset(load_robot(name).urdf))
    text = Path(find_manifest(name)).read_text()
    (d / "c3" / f"{name}.yaml").write_text(re.sub(r"(?m)^urdf: .*$", f"urdf: file:{folder}/{urdf.name}", text))
so = Path(resolve_asset(load_robot("so101").urdf))
with tarfile.open(d / "c3" / "so101.tar.xz", "w:xz") as tar:
    tar.add(so, f"SO101/{so.name}")
    tar.add(so.parent / "assets", "SO101/assets")
PY
    rm -rf "$DIR/wheels"
    du -sh "$DIR"/c*
    ;;
  receive)
    mkdir -p /tmp/ww; cp -r "$2"/. /tmp/ww/; ls /tmp/ww
    ;;
  install)
    cd /tmp/ww
    cat warp.part00 warp.part01 warp.part02 > "$(cat warp.name)"
    echo "$(cat warp.sha256)  $(cat warp.name)" | sha256sum -c -
    python3 -m pip install -q --no-index --no-deps --no-compile --target /tmp/site ./*.whl
    if [ -f so101.tar.xz ]; then tar xJf so101.tar.xz; fi
    PYTHONPATH=/tmp/site python3 -c "import warp, mujoco, mujoco_warp; print('warp', warp.config.version, 'mujoco', mujoco.__version__, 'mujoco_warp', mujoco_warp.__version__)"
    ;;
  *)
    echo "usage: $0 prepare [DIR] | receive DIR | install" >&2; exit 2
    ;;
esac
