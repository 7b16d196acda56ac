"""Train a LeRobot ACT or Diffusion Policy on a simseam-recorded LeRobot dataset.

The loop is LeRobot's own recipe, written out so it can run on a step and a
wall-clock budget: features from the dataset metadata, ``ACTConfig`` or ``DiffusionConfig``
(``TrainConfig.policy_type``; no pretrained backbone download: ``pretrained_backbone_weights=None``
unless asked), pre/post-processors built from the dataset statistics, action chunks (and, for
Diffusion, the ``n_obs_steps`` observation history) through ``delta_timestamps``, AdamW with the
policy's parameter groups, gradient clipping.

Diffusion from scratch: the ResNet is trained with group norm (LeRobot's default without
pretrained weights), a random crop of ``crop_fraction`` of each image while training (the center
crop at inference), a U-Net of ``down_dims`` over a ``horizon`` of actions, and a DDIM sampler of
``inference_steps`` steps at inference (DDPM is one option away; DDIM without added noise makes an
episode's actions a function of its observations and the initial noise alone).

The output directory is a complete ``lerobot:`` checkpoint: ``config.json`` +
``model.safetensors`` (``save_pretrained``), both processor pipelines, the
``simseam_skill.json`` contract of the scene the data came from, and
``training.json`` (steps, seconds, loss curve, dataset size, device).

Nothing is lost or silently replaced: an output directory that already holds a
training run is refused unless ``overwrite`` (removed once the dataset has loaded and training
starts; only a directory that holds a training run, never the dataset or other files) or ``resume``.
Every ``checkpoint_every`` steps, when the run is interrupted (Ctrl-C, SIGTERM), and (with
``checkpoint_every`` set) where ``time_budget_s`` ends it before ``steps``,
``out_dir/checkpoints/step_NNNNNNN/`` receives the weights, both
processors and ``training_state.pt`` (optimizer state, step, losses), written
under a temporary name and renamed when complete (the two newest are kept).
``resume`` continues from the newest checkpoint up to ``steps`` in total
(the data order of the resumed part differs from an uninterrupted run).
"""

from __future__ import annotations

import json
import math
import time
from dataclasses import asdict, dataclass, field
from pathlib import Path
from typing import Callable

from simseam.policies.contract import SkillContract
from simseam.seam import FEATURE_ACTION as ACTION_KEY
from simseam.seam import FEATURE_ENV_STATE as ENV_STATE_KEY
from simseam.seam import FEATURE_IMAGE_PREFIX as IMAGE_PREFIX
from simseam.seam import FEATURE_STATE as STATE_KEY
from simseam.seam import ConfigError


POLICY_TYPES = ("act", "diffusion")

#: what ``None`` means for the fields whose default depends on the policy type (LeRobot's own defaults)
KIND_DEFAULTS = {
    "act": {"lr": 1e-5, "lr_backbone": 1e-5, "weight_decay": 1e-4, "n_action_steps": 20},
    "diffusion": {"lr": 1e-4, "lr_backbone": 1e-4, "weight_decay": 1e-6, "n_action_steps": 8},
}


@dataclass
class TrainConfig:
    """Hyper-parameters. ``steps`` and ``time_budget_s`` (counted from the call, preparation
    included) both bound the run; the first one reached ends it. ``None`` in ``lr``, ``lr_backbone``,
    ``weight_decay``, ``n_action_steps``: the policy type's default (``KIND_DEFAULTS``)."""

    steps: int = 1000
    time_budget_s: float | None = None
    #: "act" or "diffusion" (LeRobot's ACTPolicy or DiffusionPolicy)
    policy_type: str = "act"
    batch_size: int = 8
    lr: float | None = None
    lr_backbone: float | None = None
    #: "constant" (LeRobot ACT's own) or "cosine": decays every learning rate to 0 at ``steps`` (half a cosine),
    #: so the last weights are not one noisy iterate of a constant-rate run; a ``time_budget_s`` that ends the
    #: run first leaves the rate where it was
    lr_schedule: str = "constant"
    #: linear warm-up of the learning rate over the first steps (LeRobot's Diffusion recipe uses 500)
    warmup_steps: int = 0
    weight_decay: float | None = None
    grad_clip_norm: float = 10.0
    chunk_size: int = 20
    n_action_steps: int | None = None
    #: ACT's temporal ensembling at inference (needs n_action_steps 1): every step averages the actions that the
    #: overlapping chunks predicted for it, weighted exp(-coeff * age); saved in the checkpoint's config
    temporal_ensemble_coeff: float | None = None
    dim_model: int = 512
    n_heads: int = 8
    dim_feedforward: int = 3200
    n_encoder_layers: int = 4
    n_decoder_layers: int = 1
    use_vae: bool = True
    kl_weight: float = 10.0
    pretrained_backbone_weights: str | None = None
    # Diffusion Policy (policy_type "diffusion")
    #: observations the policy reads per prediction (the current one and n_obs_steps - 1 before it)
    n_obs_steps: int = 2
    #: actions the U-Net denoises per prediction, from the oldest observation on (a multiple of 2**len(down_dims))
    horizon: int = 16
    down_dims: tuple[int, ...] = (256, 512, 1024)
    #: the training noise schedule's steps, and the sampler's steps at inference
    diffusion_steps: int = 100
    inference_steps: int = 10
    noise_scheduler: str = "DDIM"
    #: random crop of this fraction of each image side while training (center crop at inference); 1: none
    crop_fraction: float = 0.9
    num_workers: int = 0
    #: decode every frame once and keep the dataset on the training device (uint8 images):
    #: batches are then index gathers instead of per-sample PNG/video decoding
    cache_on_device: bool = False
    #: bfloat16 autocast for the forward pass on CUDA (weights and optimizer stay float32)
    use_amp: bool = False
    seed: int = 0
    device: str | None = None
    log_every: int = 50
    #: save a resumable checkpoint every this many steps (None: only at the end / on interrupt)
    checkpoint_every: int | None = None
    #: the smallest spread the normaliser gives each state input (``STATE_INPUTS``), in the input's own units
    #: (``state_spread``); None: the dataset's statistics as they are
    state_std_floor: float | None = None
    #: Gaussian noise of this standard deviation (the input's own units) added to every state input of every
    #: training sample (``noisy_states``); the normaliser's spread is the noisy data's (``state_spread``)
    state_noise: float | None = None


#: the name the ACT-only trainer had
ActTrainConfig = TrainConfig


def resolve_config(cfg: TrainConfig) -> TrainConfig:
    """``cfg`` with the policy type's defaults filled in and checked (``ConfigError`` on bad input)."""
    import dataclasses

    if cfg.policy_type not in POLICY_TYPES:
        raise ConfigError(f"policy type {cfg.policy_type!r}: expected one of {', '.join(POLICY_TYPES)}")
    defaults = KIND_DEFAULTS[cfg.policy_type]
    cfg = dataclasses.replace(cfg, **{k: v for k, v in defaults.items() if getattr(cfg, k) is None})
    if cfg.lr_schedule not in LR_SCHEDULES:
        raise ConfigError(f"learning-rate schedule {cfg.lr_schedule!r}: expected one of {', '.join(LR_SCHEDULES)}")
    for name, value in (("lr", cfg.lr), ("lr_backbone", cfg.lr_backbone), ("time_budget_s", cfg.time_budget_s)):
        if value is not None and not (math.isfinite(value) and value > 0):
            raise ConfigError(f"--{name.replace('_', '-')} must be a positive number, got {value!r}")
    for name, value in (("state_std_floor", cfg.state_std_floor), ("state_noise", cfg.state_noise)):
        if value is not None and not (math.isfinite(value) and value >= 0):
            raise ConfigError(f"--{name.replace('_', '-')} must be a non-negative number, got {value!r}")
    if cfg.temporal_ensemble_coeff is not None and cfg.n_action_steps != 1:
        raise ConfigError(f"temporal ensembling queries the policy every step: it needs n_action_steps 1, "
                          f"not {cfg.n_action_steps}")
    if cfg.policy_type == "diffusion":
        _check_diffusion(cfg)
    return cfg


def _check_diffusion(cfg: TrainConfig) -> None:
    """The Diffusion-specific fields make a policy LeRobot can build and run."""
    if cfg.temporal_ensemble_coeff is not None:
        raise ConfigError("temporal ensembling is ACT's; Diffusion Policy executes n_action_steps of each prediction")
    if cfg.n_obs_steps < 1 or cfg.n_action_steps < 1 or not cfg.down_dims:
        raise ConfigError(f"n_obs_steps ({cfg.n_obs_steps}), n_action_steps ({cfg.n_action_steps}) and down_dims "
                          f"({cfg.down_dims}) must be at least 1 / non-empty")
    factor = 2 ** len(cfg.down_dims)
    if cfg.horizon < factor or cfg.horizon % factor:
        raise ConfigError(f"diffusion horizon {cfg.horizon}: the U-Net halves it {len(cfg.down_dims)} times "
                          f"(down_dims {list(cfg.down_dims)}): it must be a multiple of {factor}")
    if cfg.n_action_steps > cfg.horizon - cfg.n_obs_steps + 1:
        raise ConfigError(f"n_action_steps {cfg.n_action_steps} exceeds what one diffusion prediction covers from "
                          f"the current step: horizon - n_obs_steps + 1 = {cfg.horizon - cfg.n_obs_steps + 1}")
    if cfg.noise_scheduler not in ("DDPM", "DDIM"):
        raise ConfigError(f"noise scheduler {cfg.noise_scheduler!r}: expected DDPM or DDIM")
    if not 1 <= cfg.inference_steps <= cfg.diffusion_steps:
        raise ConfigError(f"inference_steps must be in [1, diffusion_steps={cfg.diffusion_steps}], "
                          f"got {cfg.inference_steps}")
    if not 0 < cfg.crop_fraction <= 1:
        raise ConfigError(f"crop_fraction must be in (0, 1], got {cfg.crop_fraction}")


@dataclass
class TrainResult:
    out_dir: str
    steps: int
    seconds: float
    device: str
    episodes: int
    frames: int
    n_params: int
    #: seconds before the first step (model, processors, dataset; decoding when cached)
    prepare_seconds: float = 0.0
    losses: list[tuple[int, float]] = field(default_factory=list)
    #: the step a resumed run started from (0: a fresh run)
    resumed_from: int = 0
    interrupted: bool = False


LR_SCHEDULES = ("constant", "cosine")


def lr_factor(cfg: TrainConfig, step: int) -> float:
    """The learning rate of optimizer step ``step`` (0-based), as a fraction of ``cfg.lr``."""
    warm = min(1.0, (step + 1) / cfg.warmup_steps) if cfg.warmup_steps > 0 else 1.0
    if cfg.lr_schedule == "constant":
        return warm
    return warm * 0.5 * (1.0 + math.cos(math.pi * min(step, cfg.steps) / cfg.steps))


CHECKPOINTS = "checkpoints"
KEEP_CHECKPOINTS = 2


def latest_checkpoint(out_dir: str | Path) -> Path | None:
    """The newest complete checkpoint under ``out_dir/checkpoints`` (None when there is none)."""
    root = Path(out_dir) / CHECKPOINTS
    done = sorted(p for p in root.glob("step_*") if (p / "training_state.pt").is_file()) if root.is_dir() else []
    return done[-1] if done else None


def default_loader_workers() -> int:
    """Data-loading processes beside the training process: one per remaining core, at most 4."""
    import os

    return max(0, min(4, len(os.sched_getaffinity(0)) - 1))


#: what marks a directory as a training run (``--overwrite`` deletes nothing else)
TRAINING_MARKS = ("training.json", CHECKPOINTS, "model.safetensors")


def image_stats(meta, root: Path) -> dict:
    """The dataset's statistics, with each camera's per-channel mean/std recomputed from its frames when the
    recorded std is degenerate (< 0.01: LeRobot 0.4.4 squares uint8 frames in uint8, so datasets it recorded
    hold ~0; simseam's recorder writes the real values). The dataset on disk is left as it is."""
    import copy

    import numpy as np
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    bad = [k for k in meta.camera_keys if float(np.max(np.asarray(meta.stats[k]["std"]))) < 0.01]
    if not bad:
        return meta.stats
    stats = copy.deepcopy(meta.stats)
    sums = {k: [torch.zeros(3, dtype=torch.float64), torch.zeros(3, dtype=torch.float64), 0] for k in bad}
    for batch in torch.utils.data.DataLoader(LeRobotDataset("simseam/local", root=root), batch_size=64):
        for k in bad:
            x = batch[k].double()  # [B, 3, H, W] in [0, 1]
            sums[k][0] += x.sum(dim=(0, 2, 3))
            sums[k][1] += (x * x).sum(dim=(0, 2, 3))
            sums[k][2] += x.shape[0] * x.shape[2] * x.shape[3]
    for k, (total, squares, n) in sums.items():
        mean = total / n
        stats[k]["mean"] = mean.reshape(3, 1, 1).numpy()
        stats[k]["std"] = (squares / n - mean**2).clamp(min=0).sqrt().reshape(3, 1, 1).numpy()
    return stats


#: the non-image inputs the normaliser scales by the dataset's spread
STATE_INPUTS = ("observation.state", "observation.environment_state")


def state_spread(stats: dict, floor: float | None, noise: float | None = None) -> dict:
    """``stats`` as the normaliser should see the state inputs: with training noise of std ``noise``, each
    state input's spread is the noisy data's (std ``sqrt(std**2 + noise**2)``, min-max widened by ``3 * noise``
    each side); with a ``floor`` (its own units: m, rad, quaternion units), at least ``floor`` (std at least
    ``floor``, max - min at least ``2 * floor`` about the middle). An input that barely moves in the
    demonstrations (a resting object's pose recorded on deterministic float64 physics: std down to 1e-10) is
    otherwise divided by about LeRobot's 1e-8, so a jitter of 1e-6 (another engine's float32) reads as hundreds
    of deviations the policy never saw. The other features, and the dataset on disk, are left as they are."""
    import copy

    import numpy as np

    if floor is None and not noise:
        return stats
    floor, noise = floor or 0.0, noise or 0.0
    out = copy.deepcopy(stats)
    for key in STATE_INPUTS:
        if key not in out:
            continue
        entry = out[key]
        if "std" in entry:
            std = np.hypot(np.asarray(entry["std"], dtype=np.float64), noise)
            entry["std"] = np.maximum(std, floor).astype(np.float32)
        if "min" in entry and "max" in entry:
            lo, hi = np.asarray(entry["min"], dtype=np.float64), np.asarray(entry["max"], dtype=np.float64)
            mid, half = (lo + hi) / 2, np.maximum((hi - lo) / 2 + 3 * noise, floor)
            entry["min"], entry["max"] = (mid - half).astype(np.float32), (mid + half).astype(np.float32)
    return out


def noisy_states(batch: dict, noise: float | None, generator) -> dict:
    """``batch`` with Gaussian noise of std ``noise`` added to its state inputs (``STATE_INPUTS``, every frame
    of an observation history too), drawn from ``generator`` (a CPU ``torch.Generator``: the same seed, the same
    noise on any device); images and actions untouched. Training a state policy so teaches it that changes of
    this size mean nothing (another engine's float32 jitter on a resting object's pose)."""
    import torch

    if not noise:
        return batch
    out = dict(batch)
    for key in STATE_INPUTS:
        if key in out:
            x = out[key]
            out[key] = x + noise * torch.randn(x.shape, generator=generator, dtype=x.dtype).to(x.device)
    return out


def _parquet_complete(path: Path) -> bool:
    """A parquet file ends with its footer and the magic bytes PAR1 (a killed writer leaves neither)."""
    with open(path, "rb") as f:
        size = f.seek(0, 2)
        if size < 8:
            return False
        f.seek(size - 4)
        return f.read(4) == b"PAR1"


def check_dataset(root: Path) -> None:
    """``ConfigError`` unless ``root`` is a LeRobot dataset holding episodes."""
    from simseam.runner.dataset_recorder import unfinished

    if not (root / "meta" / "info.json").is_file():
        raise ConfigError(f"{root}: not a LeRobot dataset (no meta/info.json); record one with `simseam collect`")
    if unfinished(root):
        raise ConfigError(unfinished(root))
    if not (root / "meta" / "tasks.parquet").is_file():
        raise ConfigError(f"{root}: the dataset holds no episodes (was every collected episode a failure? "
                          "`simseam collect --keep-failures` keeps them)")
    for part in sorted((root / "data").rglob("*.parquet")) + sorted((root / "meta" / "episodes").rglob("*.parquet")):
        if not _parquet_complete(part):
            raise ConfigError(f"{root}: {part.relative_to(root)} is incomplete: the recording was killed before it "
                              "finalized the dataset (Ctrl-C or SIGTERM finalize it; a SIGKILL cannot); record "
                              "it again")
    if not any((root / "meta" / "episodes").rglob("*.parquet")):
        raise ConfigError(f"{root}: meta/episodes holds no episode index: the recording was killed before it "
                          "finalized the dataset; record it again")


def _prepare_out(out: Path, dataset: Path, overwrite: bool, resume: bool) -> tuple[Path | None, bool]:
    """Check ``out`` before anything runs (nothing is deleted here); returns the checkpoint to resume from,
    and whether an earlier training run in ``out`` is to be replaced once training starts."""
    from simseam.runner.run_dir import check_writable

    if overwrite and resume:
        raise ConfigError("--overwrite and --resume exclude each other")
    o, d = out.resolve(), dataset.resolve()
    if o == d or o in d.parents or d in o.parents:
        raise ConfigError(f"--out {out} and the dataset {dataset} overlap: training would "
                          f"{'replace' if o == d or o in d.parents else 'write into'} the dataset; choose another --out")
    check_writable(out)
    held = sorted(p.name for p in out.iterdir()) if out.is_dir() else []
    if resume:
        ckpt = latest_checkpoint(out)
        if ckpt is None:
            raise ConfigError(f"--resume {out}: no complete checkpoint under {out / CHECKPOINTS}")
        return ckpt, False
    if held and not overwrite:
        raise ConfigError(f"--out {out} is not empty (an earlier training run?); pass --overwrite to replace it, "
                          "--resume to continue its newest checkpoint, or choose another --out")
    if held and not any(m in held for m in TRAINING_MARKS):
        raise ConfigError(f"--out {out} holds {', '.join(held[:5])}{' ...' if len(held) > 5 else ''}, not a training "
                          "run; --overwrite replaces only a training run (nothing was deleted): choose another --out")
    others = [name for name in held if not _training_output(name)]
    if others:
        raise ConfigError(f"--out {out} holds {', '.join(others[:5])}{' ...' if len(others) > 5 else ''} beside the "
                          "training run; --overwrite replaces only a training run's own files (nothing was deleted): "
                          "move them out or choose another --out")
    return None, bool(held)


def _training_output(name: str) -> bool:
    """Whether ``name`` in a training run's directory is one ``train_act`` writes (what ``--overwrite`` removes)."""
    return name in (*TRAINING_MARKS, "config.json", "simseam_skill.json") or name.startswith(
        ("policy_preprocessor", "policy_postprocessor"))


def _save_checkpoint(out: Path, step: int, policy, preprocessor, postprocessor, optimizer, losses) -> Path:
    import os
    import shutil

    import torch

    root = out / CHECKPOINTS
    root.mkdir(parents=True, exist_ok=True)
    final = root / f"step_{step:07d}"
    tmp = root / f".step_{step:07d}.partial"
    shutil.rmtree(tmp, ignore_errors=True)
    tmp.mkdir()
    policy.save_pretrained(tmp)
    preprocessor.save_pretrained(tmp)
    postprocessor.save_pretrained(tmp)
    torch.save({"step": step, "optimizer": optimizer.state_dict(), "losses": list(losses)},
               tmp / "training_state.pt")
    shutil.rmtree(final, ignore_errors=True)
    os.replace(tmp, final)
    for old in sorted(p for p in root.glob("step_*"))[:-KEEP_CHECKPOINTS]:
        shutil.rmtree(old, ignore_errors=True)
    return final


def _skill_from_dataset(meta, root: Path, name: str) -> SkillContract:
    """The contract of the scene the dataset was recorded in (``meta/simseam_skill.json``, written by the
    recorder); for datasets recorded elsewhere, the one their features imply (control mode unknown)."""
    saved = SkillContract.load(root / "meta")
    if saved is not None:
        return SkillContract(**{**saved.__dict__, "name": name})
    images = {k[len(IMAGE_PREFIX):]: (int(ft["shape"][0]), int(ft["shape"][1]))
              for k, ft in meta.features.items() if k.startswith(IMAGE_PREFIX)}
    state = meta.features.get(STATE_KEY)
    return SkillContract(name=name, action_dim=int(meta.features[ACTION_KEY]["shape"][0]),
                         state_dim=int(state["shape"][0]) if state else None, images=images,
                         control_hz=float(meta.fps))


def _gather_index(idx, starts, ends, offsets):
    """Frame indices ``idx + offsets`` clamped into each frame's episode, and which of them fell outside it
    (LeRobot's ``delta_timestamps``: the episode's first / last frame repeated, marked ``*_is_pad``)."""
    import torch

    raw = idx[:, None] + offsets[None, :]
    return torch.maximum(torch.minimum(raw, ends[:, None] - 1), starts[:, None]), (raw < starts[:, None]) | (
        raw >= ends[:, None])


class _DeviceCache:
    """The whole dataset decoded once and held on ``device``; ``batches()`` yields shuffled
    batches shaped like LeRobotDataset's with ``delta_timestamps``: action chunks of ``chunk_offsets``
    clamped to the episode (``action_is_pad`` marking steps past its end), and, with ``obs_offsets``
    (Diffusion's observation history), every observation as ``[B, len(obs_offsets), ...]`` with frames
    before the episode's start repeating its first frame (``<key>_is_pad`` marking them)."""

    def __init__(self, dataset, chunk_offsets: list[int], device: str, num_workers: int, batch_size: int,
                 seed: int, obs_offsets: list[int] | None = None):
        import torch

        loader = torch.utils.data.DataLoader(dataset, batch_size=256, num_workers=num_workers, shuffle=False)
        parts: dict[str, list] = {}
        self.image_keys = [k for k in dataset.meta.camera_keys]
        for batch in loader:
            for k in self.image_keys:
                parts.setdefault(k, []).append((batch[k] * 255).round().to(torch.uint8))
            for k in (STATE_KEY, ENV_STATE_KEY, ACTION_KEY, "episode_index"):
                if k in batch:
                    parts.setdefault(k, []).append(batch[k])
        data = {k: torch.cat(v).to(device) for k, v in parts.items()}
        ep = data.pop("episode_index")
        n = ep.shape[0]
        idx = torch.arange(n, device=device)
        starts = torch.zeros(n, dtype=torch.long, device=device)
        ends = torch.zeros(n, dtype=torch.long, device=device)
        for e in ep.unique():
            m = ep == e
            starts[m], ends[m] = idx[m].min(), idx[m].max() + 1
        self.chunk_idx, self.chunk_pad = _gather_index(idx, starts, ends, torch.as_tensor(chunk_offsets, device=device))
        self.obs_idx = self.obs_pad = None
        if obs_offsets is not None:
            self.obs_idx, self.obs_pad = _gather_index(idx, starts, ends, torch.as_tensor(obs_offsets, device=device))
        self.data, self.n, self.device, self.batch_size = data, n, device, batch_size
        self._gen = torch.Generator(device="cpu").manual_seed(seed)

    def batch(self, b) -> dict:
        """The batch of frame indices ``b`` (a long tensor on the device)."""
        rows = b if self.obs_idx is None else self.obs_idx[b]
        out = {k: self.data[k][rows].float() / 255.0 for k in self.image_keys}
        for k in (STATE_KEY, ENV_STATE_KEY):
            if k in self.data:
                out[k] = self.data[k][rows]
        if self.obs_idx is not None:
            for k in [*self.image_keys, STATE_KEY, ENV_STATE_KEY]:
                if k in out:
                    out[f"{k}_is_pad"] = self.obs_pad[b]
        out[ACTION_KEY] = self.data[ACTION_KEY][self.chunk_idx[b]]
        out["action_is_pad"] = self.chunk_pad[b]
        return out

    def batches(self):
        import torch

        while True:
            order = torch.randperm(self.n, generator=self._gen).to(self.device)
            for i in range(0, self.n - self.batch_size + 1 if self.n >= self.batch_size else 1, self.batch_size):
                yield self.batch(order[i:i + self.batch_size])


def _import_lerobot_training():
    import importlib

    try:
        for module in ("torch", "lerobot.datasets.lerobot_dataset", "lerobot.policies.factory"):
            importlib.import_module(module)
    except ImportError as exc:
        raise ConfigError(f"training needs the lerobot extra ({exc}); `pip install 'simseam[lerobot]'`") from None


def _policy_features(meta, root: Path, policy_type: str):
    """(inputs, outputs): the dataset's features as LeRobot policy features; ``ConfigError`` when the
    policy type cannot learn from them."""
    from lerobot.configs.types import FeatureType
    from lerobot.datasets.utils import dataset_to_policy_features

    features = dataset_to_policy_features(meta.features)
    outputs = {k: f for k, f in features.items() if f.type is FeatureType.ACTION}
    inputs = {k: f for k, f in features.items() if k not in outputs}
    if not any(f.type in (FeatureType.VISUAL, FeatureType.ENV) for f in inputs.values()):
        raise ConfigError(f"{root}: {policy_type} needs a camera or the object state (observation.environment_state); "
                          "the dataset has neither: collect with cameras, or from a scene with `environment_state: "
                          "true`")
    if policy_type == "diffusion":
        if STATE_KEY not in inputs:
            raise ConfigError(f"{root}: Diffusion Policy needs observation.state (proprioception); the dataset has none")
        shapes = {tuple(f.shape) for f in inputs.values() if f.type is FeatureType.VISUAL}
        if len(shapes) > 1:
            raise ConfigError(f"{root}: Diffusion Policy needs every camera at one size; the dataset has "
                              f"{sorted(shapes)}")
    return inputs, outputs


def _act_config(cfg: TrainConfig, inputs, outputs, device: str):
    from lerobot.configs.types import FeatureType, NormalizationMode
    from lerobot.policies.act.configuration_act import ACTConfig

    act_cfg = ACTConfig(
        input_features=inputs, output_features=outputs, device=device,
        chunk_size=cfg.chunk_size, n_action_steps=cfg.n_action_steps, dim_model=cfg.dim_model,
        temporal_ensemble_coeff=cfg.temporal_ensemble_coeff,
        n_heads=cfg.n_heads, dim_feedforward=cfg.dim_feedforward, n_encoder_layers=cfg.n_encoder_layers,
        n_decoder_layers=cfg.n_decoder_layers, use_vae=cfg.use_vae, kl_weight=cfg.kl_weight,
        pretrained_backbone_weights=cfg.pretrained_backbone_weights,
        optimizer_lr=cfg.lr, optimizer_lr_backbone=cfg.lr_backbone, optimizer_weight_decay=cfg.weight_decay,
    )
    # ACT's default mapping names VISUAL, STATE and ACTION only: without this, LeRobot's normalizer passes
    # environment_state through raw (a cube's y spans +-0.1 m beside inputs of unit spread)
    act_cfg.normalization_mapping = {**act_cfg.normalization_mapping, FeatureType.ENV.value: NormalizationMode.MEAN_STD}
    return act_cfg


def _diffusion_config(cfg: TrainConfig, inputs, outputs, device: str):
    from lerobot.configs.types import FeatureType, NormalizationMode
    from lerobot.policies.diffusion.configuration_diffusion import DiffusionConfig

    visual = [f for f in inputs.values() if f.type is FeatureType.VISUAL]
    crop = None
    if visual and cfg.crop_fraction < 1:
        _, h, w = visual[0].shape
        crop = (max(1, int(h * cfg.crop_fraction)), max(1, int(w * cfg.crop_fraction)))
    try:
        dp_cfg = DiffusionConfig(
            input_features=inputs, output_features=outputs, device=device, n_obs_steps=cfg.n_obs_steps,
            horizon=cfg.horizon, n_action_steps=cfg.n_action_steps,
            crop_shape=crop, crop_is_random=True, pretrained_backbone_weights=cfg.pretrained_backbone_weights,
            use_group_norm=cfg.pretrained_backbone_weights is None, down_dims=tuple(cfg.down_dims),
            noise_scheduler_type=cfg.noise_scheduler, num_train_timesteps=cfg.diffusion_steps,
            num_inference_steps=cfg.inference_steps, optimizer_lr=cfg.lr,
            optimizer_weight_decay=cfg.weight_decay)
        dp_cfg.validate_features()
    except ValueError as exc:
        raise ConfigError(f"diffusion policy: {str(exc).splitlines()[0]}") from None
    # LeRobot's mapping leaves environment_state raw; min-max like the state (the cube's pose spans centimetres)
    dp_cfg.normalization_mapping = {**dp_cfg.normalization_mapping, FeatureType.ENV.value: NormalizationMode.MIN_MAX}
    return dp_cfg


def _build_policy(cfg: TrainConfig, inputs, outputs, device: str):
    """(LeRobot config, policy) of ``cfg.policy_type``, and the optimizer's parameter groups."""
    if cfg.policy_type == "diffusion":
        from lerobot.policies.diffusion.modeling_diffusion import DiffusionPolicy

        pcfg = _diffusion_config(cfg, inputs, outputs, device)
        policy = DiffusionPolicy(pcfg)
        return pcfg, policy, [{"params": list(policy.get_optim_params())}], dict(betas=pcfg.optimizer_betas,
                                                                                 eps=pcfg.optimizer_eps)
    from lerobot.policies.act.modeling_act import ACTPolicy

    pcfg = _act_config(cfg, inputs, outputs, device)
    policy = ACTPolicy(pcfg)
    return pcfg, policy, policy.get_optim_params(), {}


def _delta_indices(pcfg) -> tuple[list[int], list[int] | None]:
    """(action offsets, observation offsets or None): the frames one training sample reads around its own."""
    obs = getattr(pcfg, "observation_delta_indices", None)
    return list(pcfg.action_delta_indices), (list(obs) if obs is not None else None)


def delta_timestamps(pcfg, meta) -> dict[str, list[float]]:
    """LeRobotDataset's ``delta_timestamps`` for the policy config ``pcfg`` (as LeRobot's ``make_dataset``)."""
    actions, obs = _delta_indices(pcfg)
    delta = {ACTION_KEY: [i / meta.fps for i in actions]}
    if obs is not None:
        delta.update({k: [i / meta.fps for i in obs] for k in meta.features if k.startswith("observation.")})
    return delta


def _batch_source(cfg: TrainConfig, pcfg, meta, root: Path, device: str):
    """An endless iterator of training batches: from the device cache, or LeRobotDataset's loader."""
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    if cfg.cache_on_device:
        actions, obs = _delta_indices(pcfg)
        return _DeviceCache(LeRobotDataset("simseam/local", root=root), actions, device, cfg.num_workers,
                            cfg.batch_size, cfg.seed, obs_offsets=obs).batches()
    dataset = LeRobotDataset("simseam/local", root=root, delta_timestamps=delta_timestamps(pcfg, meta))
    loader = torch.utils.data.DataLoader(
        dataset, batch_size=cfg.batch_size, shuffle=True, drop_last=len(dataset) >= cfg.batch_size,
        num_workers=cfg.num_workers, pin_memory=device.startswith("cuda"),
        persistent_workers=cfg.num_workers > 0, generator=torch.Generator().manual_seed(cfg.seed))

    def _epochs():
        while True:
            yield from loader

    return _epochs()


def train_act(dataset_root: str | Path, out_dir: str | Path, cfg: TrainConfig | None = None,
              on_log: Callable[[int, float], None] | None = None, *, overwrite: bool = False,
              resume: bool = False) -> TrainResult:
    """Train ``cfg.policy_type`` (ACT by default, or Diffusion) on the dataset at ``dataset_root`` and save
    a ``lerobot:`` checkpoint in ``out_dir``. A KeyboardInterrupt (Ctrl-C, or SIGTERM turned into one)
    saves a checkpoint of the steps done, then propagates."""
    cfg = resolve_config(cfg or TrainConfig())
    t_start = time.perf_counter()
    out, root = Path(out_dir), Path(dataset_root)
    check_dataset(root)
    resume_from, replace = _prepare_out(out, root, overwrite, resume)
    _import_lerobot_training()
    import torch

    run = _Training.build(cfg, root, out_dir, resume_from)
    if replace:  # the dataset loaded and the model was built: now the earlier training run goes
        import shutil

        shutil.rmtree(out)
    if run.device.startswith("cuda"):
        torch.backends.cuda.matmul.allow_tf32 = True
        torch.backends.cudnn.allow_tf32 = True
    t0 = time.perf_counter()
    run.train(cfg, out, t_start, on_log)
    if run.device.startswith("cuda"):
        torch.cuda.synchronize()
    result = run.result
    result.seconds = time.perf_counter() - t0
    result.prepare_seconds = t0 - t_start
    run.save(cfg, Path(out_dir), root)
    return result


@dataclass
class _Training:
    """One training run's policy, its processors, batches and optimizer, and its ``TrainResult`` so far."""

    device: str
    meta: object
    policy: object
    preprocessor: object
    postprocessor: object
    batches: object
    optimizer: object
    base_lrs: list[float]  # each parameter group's learning rate before a resumed optimizer state is loaded
    result: TrainResult

    @classmethod
    def build(cls, cfg: TrainConfig, root: Path, out_dir: str | Path, resume_from: Path | None) -> "_Training":
        """The policy of ``cfg`` for the dataset at ``root`` (its weights, optimizer state and losses from
        ``resume_from``'s checkpoint when resuming), on the device ``cfg`` picks."""
        import torch
        from lerobot.datasets.lerobot_dataset import LeRobotDatasetMetadata
        from lerobot.policies.factory import make_pre_post_processors

        from simseam.policies.lerobot_policy import pick_device

        device = pick_device(cfg.device)
        torch.manual_seed(cfg.seed)
        meta = LeRobotDatasetMetadata("simseam/local", root=root)
        inputs, outputs = _policy_features(meta, root, cfg.policy_type)
        pcfg, policy, param_groups, adam = _build_policy(cfg, inputs, outputs, device)
        state = None
        if resume_from is not None:
            from safetensors.torch import load_file

            policy.load_state_dict(load_file(str(resume_from / "model.safetensors")))
            state = torch.load(resume_from / "training_state.pt", map_location="cpu", weights_only=False)
        policy.to(device)
        policy.train()
        preprocessor, postprocessor = make_pre_post_processors(
            pcfg, dataset_stats=state_spread(image_stats(meta, root), cfg.state_std_floor, cfg.state_noise))
        batches = _batch_source(cfg, pcfg, meta, root, device)
        optimizer = torch.optim.AdamW(param_groups, lr=cfg.lr, weight_decay=cfg.weight_decay, **adam)
        base_lrs = [g["lr"] for g in optimizer.param_groups]
        result = TrainResult(out_dir=str(out_dir), steps=0, seconds=0.0, device=device, episodes=meta.total_episodes,
                             frames=meta.total_frames, n_params=sum(p.numel() for p in policy.parameters()))
        if state is not None:
            optimizer.load_state_dict(state["optimizer"])
            result.steps = result.resumed_from = int(state["step"])
            result.losses = [tuple(x) for x in state["losses"]]
        return cls(device, meta, policy, preprocessor, postprocessor, batches, optimizer, base_lrs, result)

    def train(self, cfg: TrainConfig, out: Path, t_start: float, on_log: Callable[[int, float], None] | None) -> None:
        """Step until ``cfg.steps`` (or ``cfg.time_budget_s`` since ``t_start``): the mean loss every
        ``cfg.log_every`` steps, a checkpoint every ``cfg.checkpoint_every``; on KeyboardInterrupt a
        checkpoint of the steps done, then it propagates."""
        import torch

        policy, optimizer, result, base_lrs = self.policy, self.optimizer, self.result, self.base_lrs
        amp = cfg.use_amp and self.device.startswith("cuda")
        running = 0.0
        # a resumed run draws a new stream (not the first steps' noise again); a fresh one: seed + 1
        noise_source = torch.Generator(device="cpu").manual_seed(cfg.seed + 1 + result.steps)
        done = result.steps >= cfg.steps
        since_log = 0
        try:
            while not done:
                batch = self.preprocessor(noisy_states(next(self.batches), cfg.state_noise, noise_source))
                with torch.autocast(device_type="cuda", dtype=torch.bfloat16, enabled=amp):
                    loss, _ = policy.forward(batch)
                optimizer.zero_grad(set_to_none=True)
                loss.backward()
                torch.nn.utils.clip_grad_norm_(policy.parameters(), cfg.grad_clip_norm)
                for group, base in zip(optimizer.param_groups, base_lrs):
                    group["lr"] = base * lr_factor(cfg, result.steps)
                optimizer.step()
                result.steps += 1
                since_log += 1
                running += loss.detach()
                over_time = cfg.time_budget_s is not None and time.perf_counter() - t_start >= cfg.time_budget_s
                done = result.steps >= cfg.steps or over_time
                if result.steps % cfg.log_every == 0 or done:
                    mean = float(running) / since_log
                    result.losses.append((result.steps, mean))
                    if on_log:
                        on_log(result.steps, mean)
                    running, since_log = 0.0, 0
                if cfg.checkpoint_every and (result.steps % cfg.checkpoint_every == 0 and not done
                                             or over_time and result.steps < cfg.steps):
                    self.checkpoint(out)  # and where the time budget cuts the run: --resume goes on from there
        except KeyboardInterrupt:
            result.interrupted = True
            if result.steps > result.resumed_from:
                self.checkpoint(out)
            raise

    def checkpoint(self, out: Path) -> Path:
        return _save_checkpoint(out, self.result.steps, self.policy, self.preprocessor, self.postprocessor,
                                self.optimizer, self.result.losses)

    def save(self, cfg: TrainConfig, out: Path, root: Path) -> None:
        """The trained policy as a ``lerobot:`` checkpoint in ``out``: weights, processors, the skill contract
        of the dataset, ``training.json``."""
        out.mkdir(parents=True, exist_ok=True)
        self.policy.save_pretrained(out)
        self.preprocessor.save_pretrained(out)
        self.postprocessor.save_pretrained(out)
        _skill_from_dataset(self.meta, root, name=f"{cfg.policy_type} trained on {root.name}").save(out)
        (out / "training.json").write_text(json.dumps({"config": asdict(cfg), **asdict(self.result)}, indent=2)
                                           + "\n")
