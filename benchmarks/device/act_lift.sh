#!/usr/bin/env bash
# Runs benchmarks/train_act_lift.py on a lent GPU machine (no network there), through the
# device tool: run(command="bash benchmarks/device/act_lift.sh", carry=[".whl", ".gl", ".devcarry"]).
# Prepared here first (README, "Training ACT on a GPU"):
#   .whl/      cp312 wheels the machine lacks (lerobot 0.4.4 and its datasets/draccus/diffusers/
#              deepdiff/gymnasium deps, huggingface-hub 0.35 with the transformers 4.57 / tokenizers 0.22
#              that match it, mujoco 4, pydantic), installed with --no-deps;
#   .gl/       the GL loader .debs (libegl1, libglvnd0, ...) so MuJoCo renders through the NVIDIA EGL driver;
#   .devcarry/ pybullet_data/franka_panda (the Panda URDF + meshes, 1.9 MB as .tar.xz): the pybullet wheel
#              itself is over the 64 MiB transfer cap, so the assets travel alone under a minimal
#              pybullet dist-info, which is how `pkg:pybullet/...` asset references find them.
# PyAV (av, 40 MB) is also over the cap; lerobot imports it at module load but only calls it for
# video features, and this run stores frames as PNG images, so a module that raises on any use
# stands in for it (it defines only the one constant lerobot reads at import).
set -euo pipefail
for f in .gl/*.deb; do dpkg -x "$f" /; done; ldconfig
SITE=/tmp/site
python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" .whl/*.whl
tar -C "$SITE" -xJf .devcarry/pybullet_franka.tar.xz
mkdir -p "$SITE/pybullet-3.2.7.dist-info"
printf 'Metadata-Version: 2.1\nName: pybullet\nVersion: 3.2.7\n' > "$SITE/pybullet-3.2.7.dist-info/METADATA"
if ! python3 -c 'import av' 2>/dev/null; then
  mkdir -p "$SITE/av"
  cat > "$SITE/av/__init__.py" <<'PY'
"""PyAV is not on this machine (its wheel is over the transfer cap); any use fails loudly."""
from . import logging  # lerobot reads av.logging.WARNING in a default argument at import
def __getattr__(name):
    raise ImportError(f"av.{name}: PyAV is not installed on this machine (PNG-only run)")
PY
  cat > "$SITE/av/logging.py" <<'PY'
WARNING = 24  # libav's AV_LOG_WARNING
def __getattr__(name):
    raise ImportError(f"av.logging.{name}: PyAV is not installed on this machine (PNG-only run)")
PY
fi
export PYTHONPATH="$SITE:$PWD/src" MUJOCO_GL=egl PYTHONUNBUFFERED=1
nvidia-smi --query-gpu=name,memory.total,driver_version --format=csv,noheader
python3 -c 'import torch, lerobot, mujoco; print("torch", torch.__version__, "cuda", torch.cuda.is_available(), "mujoco", mujoco.__version__)'
python3 benchmarks/train_act_lift.py --json "${OUT:-benchmarks/results}/act_lift.json" --work /tmp/act_lift "$@"
