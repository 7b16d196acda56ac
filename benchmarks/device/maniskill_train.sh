#!/usr/bin/env bash
# Trains benchmarks/maniskill_policy.py's ACT on a lent GPU machine (no network there, no ManiSkill needed:
# the dataset is collected here and travels), through the device tool:
#   run(command="bash benchmarks/device/maniskill_train.sh", carry=[".whl", ".mscarry"], timeout_s=600)
# Prepared here first (ignored through .git/info/exclude):
#   .whl/      the wheels benchmarks/device/act_lift.sh lists (lerobot 0.4.4 and what the image lacks);
#   .mscarry/  pickcube_data/ (the dataset `maniskill_policy.py --work W` collected: W/pickcube_data) and
#              src/ (git archive HEAD src | tar -x -C .mscarry; .mscarry/src/COMMIT: git rev-parse HEAD).
# Writes $OUT/pickcube_act (a lerobot: checkpoint + training.json), which comes back; then, here:
#   .venv/bin/python benchmarks/maniskill_policy.py --work W --checkpoint <that directory>
# The recipe is maniskill_policy.py's (Recipe); STEPS, LR, DIM_MODEL, FF_DIM, ENCODER_LAYERS override it;
# TIME_BUDGET_S caps the training (the checkpoint is saved at the cap, the cosine schedule then unfinished).
set -euo pipefail
SITE=${SITE:-/tmp/site}
if [ ! -f "$SITE/.installed" ]; then
  python3 -m pip install -q --no-index --no-deps --no-compile --no-cache-dir --upgrade --target "$SITE" .whl/*.whl
  touch "$SITE/.installed"
fi
if ! PYTHONPATH="$SITE" python3 -c 'import av' 2>/dev/null; then  # lerobot imports PyAV; a state dataset never uses it
  mkdir -p "$SITE/av"
  printf 'from . import logging\n' > "$SITE/av/__init__.py"
  printf 'WARNING = 24\n' > "$SITE/av/logging.py"
fi
export PYTHONPATH="$SITE:$PWD/.mscarry/src:$PWD/benchmarks" PYTHONUNBUFFERED=1 HF_DATASETS_DISABLE_PROGRESS_BARS=1
echo "simseam from .mscarry/src at $(cat .mscarry/src/COMMIT)"
nvidia-smi --query-gpu=name,memory.total --format=csv,noheader || true
python3 - <<PY
import os
from maniskill_policy import Recipe
from simseam.runner.training import ActTrainConfig, train_act
from dataclasses import replace
r = Recipe()
r = replace(r, **{k: type(getattr(r, k))(os.environ[k.upper()]) for k in ("steps", "lr", "dim_model", "ff_dim",
                                                                         "encoder_layers") if k.upper() in os.environ})
print(r)
steps = r.steps
cfg = ActTrainConfig(steps=steps, batch_size=r.batch_size, lr=r.lr, lr_backbone=r.lr, lr_schedule=r.lr_schedule,
                     chunk_size=r.chunk_size, n_action_steps=r.n_action_steps, temporal_ensemble_coeff=r.temporal_ensemble,
                     dim_model=r.dim_model, dim_feedforward=r.ff_dim, n_encoder_layers=r.encoder_layers, use_vae=False,
                     device="cuda", cache_on_device=True, num_workers=0, log_every=max(1, min(100, steps // 10)),
                     time_budget_s=float(os.environ["TIME_BUDGET_S"]) if "TIME_BUDGET_S" in os.environ else None)
res = train_act(".mscarry/pickcube_data", os.environ["OUT"] + "/" + os.environ.get("NAME", "pickcube_act"), cfg,
                on_log=lambda s, loss: print(f"step {s:7d}  loss {loss:.4f}"))
print("trained", res.steps, "steps in", round(res.seconds, 1), "s")
PY
