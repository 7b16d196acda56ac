"""Train ACT or Diffusion Policy from camera images on scripted demonstrations and measure it through simseam.

    .venv/bin/python benchmarks/train_act_lift.py [--policy-type act|diffusion] [--task lift_cube|bowl_plate]
        [--episodes 300] [--train-s 420] [--eval-seeds 10000:10050] ...

``--policy-type diffusion`` trains LeRobot's Diffusion Policy instead (``simseam train --policy-type
diffusion``'s code: group-norm ResNet from scratch, its own random crop instead of the shift below, DDIM
sampling; the batch-norm and joint-camera patches below are ACT's and are not applied). ``--task
bowl_plate`` records the bowl-on-plate expert instead of lift_cube's (same cameras, state and actions).
``--smoke`` marks a run with tiny numbers (a few demos and steps) as such in its JSON.

Three phases, all through simseam's own code paths (the GPU machine runs it through
``benchmarks/device/act_lift.sh``):

1. collect: the scripted expert (privileged ground truth) runs ``--episodes`` episodes of
   franka_panda / lift_cube (MuJoCo, two RGB cameras -- third-person ``camera1`` and wrist
   ``camera2`` -- at ``--image-size``, 8-D proprioceptive state, 7-D CARTESIAN_DELTA, 20 Hz) on
   seeds 0..N-1 (``collect_dataset``; ``--collect-workers`` processes each record a block of seeds,
   merged with LeRobot's ``aggregate_datasets``); successful episodes become the LeRobot dataset,
   whose camera mean/std are then recomputed from every frame (``fix_image_stats``: LeRobot 0.4.4
   records an image std of about 0);
2. train: LeRobot ACT from scratch (no ImageNet weights: the GPU machine has no network) through
   ``train_act``, the code behind ``simseam train``, with the recipe the state-based proof found
   (docs/policies.md): no VAE, chunk 10, one action per model call with temporal ensembling,
   cosine learning rate, a small transformer; plus a random shift of each camera image
   (``--aug-shift`` pixels, DrQ-style) applied to the cached batches on the device, and the ResNet
   trained with batch norm (``batchnorm_backbone``: ACT's frozen batch norm is no normalization
   from scratch), both cameras through it in one call (``joint_camera_backbone``: the batch statistics
   training normalizes with are then the mixture that the saved running statistics hold), saved as a
   plain ACT checkpoint;
3. evaluate: the checkpoint is loaded through ``lerobot:<dir>`` (the spec a user gives
   ``simseam run``) and runs ``--eval-seeds`` held-out seeds from images and proprioception only
   (no privileged state, no environment_state); the scripted expert runs the same seeds.

The training length is a wall-clock plan, turned into a step count once the speed is known: after
``--calibrate-s`` seconds of training the cosine schedule's horizon (``ActTrainConfig.steps``) is
set to the steps that fit the remaining time, so the learning rate reaches 0 as the time runs out
and the checkpoint records the step count it ran (``simseam train --steps N --lr-schedule cosine``
replays it on any machine).

One run can span several commands on the same machine (a device command is limited to 10 minutes):
``--pause`` makes training stop at ``--deadline-s`` with a resumable checkpoint under ``--work``
(``train_act`` saves one when interrupted), planning ``--later-train-s`` more seconds of training;
the next invocation with the same ``--work`` skips the finished phases, resumes training,
re-plans the horizon to its own deadline, and evaluates. Writes JSON (``--json``) after every phase:
the loss curve (step, mean loss since the last point, wall seconds of training so far: each invocation's
preparation, i.e. decoding the dataset onto the device, included) is in ``train.curve``.

``--curve-every N`` also measures success against training steps, beside training: every N steps
``train_act`` saves a resumable checkpoint, a copy of which a child process evaluates on ``--curve-seeds``
(default 10000-10019, the first 20 of the held-out seeds) on the CPU, one at a time, while the GPU
trains on; the results are in ``curve_success``.
"""

from __future__ import annotations

import argparse
import contextlib
import json
import multiprocessing as mp
import os
import platform
import shutil
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from simseam.policies.base import make_policy  # noqa: E402
from simseam.robot.manifest import load_robot  # noqa: E402
from simseam.runner import training  # noqa: E402
from simseam.runner.collect import collect_dataset  # noqa: E402
from simseam.runner.episodes import run_episode  # noqa: E402
from simseam.runner.summary import wilson_interval  # noqa: E402
from simseam.runner.training import ActTrainConfig, latest_checkpoint, train_act  # noqa: E402
from simseam.scene.manifest_scene import ManifestScene, SceneOptions  # noqa: E402

T0 = time.perf_counter()


def _now() -> float:
    return time.perf_counter() - T0


TASKS = ("lift_cube", "bowl_plate")


def _scene(size: int, privileged: bool, max_steps: int, task: str = "lift_cube") -> ManifestScene:
    return ManifestScene(load_robot("franka_panda"), task, "mujoco",
                         SceneOptions(image_size=(size, size), privileged=privileged, max_steps=max_steps))


def _collect_block(job: tuple[str, int, int, int, int, bool, str]) -> tuple[int, int, int]:
    """One worker: the scripted expert on seeds ``seed .. seed+n-1``, recorded at ``root``."""
    root, seed, n, size, max_steps, videos, task = job
    scene = _scene(size, privileged=True, max_steps=max_steps, task=task)
    try:
        col = collect_dataset(scene, make_policy("scripted"), root, episodes=n, seed=seed, use_videos=videos,
                              overwrite=True)
    finally:
        scene.close()
    return col.episodes_run, col.episodes_written, col.frames_written


def collect(root: Path, episodes: int, workers: int, size: int, max_steps: int, videos: bool,
            task: str = "lift_cube") -> dict:
    """Seeds 0..episodes-1 in ``workers`` contiguous blocks, merged into one dataset at ``root``."""
    t = time.perf_counter()
    workers = max(1, min(workers, episodes))
    if root.exists():
        shutil.rmtree(root)
    if workers == 1:
        runs = [_collect_block((str(root), 0, episodes, size, max_steps, videos, task))]
    else:
        bounds = np.linspace(0, episodes, workers + 1).astype(int)
        shards = root.parent / (root.name + "_shards")
        shutil.rmtree(shards, ignore_errors=True)
        jobs = [(str(shards / f"s{k:02d}"), int(bounds[k]), int(bounds[k + 1] - bounds[k]), size, max_steps, videos,
                 task) for k in range(workers)]
        with mp.get_context("spawn").Pool(workers) as pool:
            runs = pool.map(_collect_block, jobs)
        from lerobot.datasets.aggregate import aggregate_datasets

        kept = [Path(j[0]) for j, r in zip(jobs, runs) if r[1] > 0]
        if not kept:
            raise RuntimeError(f"the scripted expert succeeded in none of {episodes} episodes: no demonstrations")
        aggregate_datasets([f"simseam/shard{k}" for k in range(len(kept))], "simseam/local", roots=kept,
                           aggr_root=root)
        # the scene's contract (control mode, image sizes) that `train_act` copies into the checkpoint
        shutil.copy(kept[0] / "meta" / "simseam_skill.json", root / "meta" / "simseam_skill.json")
        shutil.rmtree(shards, ignore_errors=True)
    info = json.loads((root / "meta" / "info.json").read_text())
    out = {"seeds": f"0:{episodes}", "episodes_run": sum(r[0] for r in runs),
           "episodes_written": sum(r[1] for r in runs), "frames": sum(r[2] for r in runs),
           "dataset_episodes": info["total_episodes"], "dataset_frames": info["total_frames"],
           "workers": workers, "seconds": time.perf_counter() - t}
    if (out["dataset_episodes"], out["dataset_frames"]) != (out["episodes_written"], out["frames"]):
        raise RuntimeError(f"merged dataset holds {info['total_episodes']} episodes / {info['total_frames']} "
                           f"frames, the workers wrote {out['episodes_written']} / {out['frames']}")
    return out


def fix_image_stats(root: Path, workers: int) -> dict:
    """Rewrite the per-channel ``mean`` / ``std`` of every camera in ``root/meta/stats.json`` from all frames.

    LeRobot 0.4.4 computes an episode's image statistics from uint8 frames and squares them in uint8
    (``RunningQuantileStats.update``: ``batch**2`` wraps modulo 256), so every episode's image std is 0 and
    the dataset's is only the spread of the episodes' means (0.001-0.015 here, against 0.1-0.2). ACT
    normalizes images with these statistics, so its inputs were scaled up 10-200x, differently per camera.
    Returns the statistics before and after."""
    import torch
    from lerobot.datasets.lerobot_dataset import LeRobotDataset

    path = root / "meta" / "stats.json"
    stats = json.loads(path.read_text())
    ds = LeRobotDataset("simseam/local", root=root)
    keys = list(ds.meta.camera_keys)
    total = {k: torch.zeros(3, dtype=torch.float64) for k in keys}
    squares = {k: torch.zeros(3, dtype=torch.float64) for k in keys}
    n = 0
    for batch in torch.utils.data.DataLoader(ds, batch_size=256, num_workers=workers):
        for k in keys:
            x = batch[k].double()  # [B, 3, H, W] in [0, 1]
            total[k] += x.sum(dim=(0, 2, 3))
            squares[k] += (x * x).sum(dim=(0, 2, 3))
        n += batch[keys[0]].shape[0] * batch[keys[0]].shape[2] * batch[keys[0]].shape[3]
    report = {}
    for k in keys:
        mean = total[k] / n
        std = (squares[k] / n - mean**2).clamp(min=0).sqrt()
        report[k] = {"std_before": np.ravel(stats[k]["std"]).tolist(), "mean": mean.tolist(), "std": std.tolist()}
        stats[k]["mean"] = mean.reshape(3, 1, 1).tolist()
        stats[k]["std"] = std.reshape(3, 1, 1).tolist()
    path.write_text(json.dumps(stats, indent=4))
    return report


def random_shift(images, pad: int):
    """DrQ's augmentation: pad each image by ``pad`` pixels (edge replicated), crop back at a random offset
    (one per image). ``images``: float [..., C, H, W] (an observation history's frames each shifted alone)."""
    import torch
    import torch.nn.functional as F

    if images.ndim > 4:
        return random_shift(images.flatten(0, images.ndim - 4), pad).view(images.shape)
    b, c, h, w = images.shape
    padded = F.pad(images, (pad, pad, pad, pad), mode="replicate")
    dy = torch.randint(0, 2 * pad + 1, (b,), device=images.device)
    dx = torch.randint(0, 2 * pad + 1, (b,), device=images.device)
    rows = (dy[:, None] + torch.arange(h, device=images.device))[:, None, :, None].expand(b, c, h, w + 2 * pad)
    cols = (dx[:, None] + torch.arange(w, device=images.device))[:, None, None, :].expand(b, c, h, w)
    return padded.gather(2, rows).gather(3, cols)


def use_random_shift(pad: int) -> None:
    """Shift the camera images of every batch the device cache yields (training only: the cache is built
    by ``train_act`` for its loop; evaluation never sees it)."""
    cache = training._DeviceCache
    if getattr(cache, "_simseam_shift", None) is not None:
        cache._simseam_shift = pad
        return
    plain = cache.batches

    def batches(self):
        for batch in plain(self):
            if cache._simseam_shift:
                for k in self.image_keys:
                    batch[k] = random_shift(batch[k], cache._simseam_shift)
            yield batch

    cache.batches = batches
    cache._simseam_shift = pad


@contextlib.contextmanager
def batchnorm_backbone(on: bool):
    """Train the ResNet backbone with real batch normalization (``nn.BatchNorm2d``) instead of ACT's
    ``FrozenBatchNorm2d``.

    ACT freezes its backbone's batch norm because it expects ImageNet weights; from scratch that
    leaves a ResNet with no normalization at all, whose activations Adam blows up (on CPU, batch 32,
    lr 3e-4, correct image statistics: layer4's standard deviation about 1.7 at initialization, 359
    after 20 steps, 2e5 after 180; on the H200 the loss stalled at 0.39-0.49 for 12,600 steps).
    Trained with ``BatchNorm2d``, the weights and running statistics fill exactly the
    tensors ``FrozenBatchNorm2d`` holds (which drops ``num_batches_tracked`` when loading), so the saved
    checkpoint is a plain ACT checkpoint: ``lerobot:`` loads it with frozen batch norm and computes what
    the trained network computes in eval mode, as with ImageNet weights. Only construction is
    patched, for the duration of training."""
    from lerobot.policies.act import modeling_act

    frozen = modeling_act.FrozenBatchNorm2d
    if on:
        import torch.nn as nn

        modeling_act.FrozenBatchNorm2d = nn.BatchNorm2d
    try:
        yield
    finally:
        modeling_act.FrozenBatchNorm2d = frozen


@contextlib.contextmanager
def joint_camera_backbone(on: bool):
    """In training, pass every camera's batch through the ResNet in one call (``torch.cat`` of the cameras)
    instead of ACT's one call per camera.

    With batch norm in the backbone (``batchnorm_backbone``), ACT's per-camera calls normalize each camera by
    its own batch statistics while training, but the running statistics that inference uses (saved into the
    frozen batch norm) are one average over both cameras, whose features differ (a third-person and a wrist
    view): the deployed network would see other normalization than the trained one. One call over all
    cameras normalizes training batches with the same mixture the running statistics hold. Also fewer,
    larger kernels. Inference is untouched (eval mode: running statistics, so per-camera calls compute the
    same). Only ``ACT.forward`` is patched, for the duration of training."""
    from lerobot.policies.act import modeling_act

    plain = modeling_act.ACT.forward
    if on:
        import torch
        import torch.nn as nn

        class _Replay(nn.Module):
            """Stands in for the backbone during one forward: returns the precomputed features, camera by camera."""

            def __init__(self, feats):
                super().__init__()
                self.feats = list(feats)

            def forward(self, img):
                return {"feature_map": self.feats.pop(0)}

        def forward(self, batch):
            imgs = batch.get(modeling_act.OBS_IMAGES) if self.config.image_features else None
            if not self.training or not imgs or len(imgs) < 2:
                return plain(self, batch)
            real = self.backbone
            feats = real(torch.cat(list(imgs)))["feature_map"].split([int(i.shape[0]) for i in imgs])
            self.backbone = _Replay(feats)
            try:
                return plain(self, batch)
            finally:
                self.backbone = real

        modeling_act.ACT.forward = forward
    try:
        yield
    finally:
        modeling_act.ACT.forward = plain


class CurveEval:
    """Success against training steps, measured beside training: each resumable checkpoint that ``train_act``
    saves (every ``--curve-every`` steps) is copied under ``work/curve/`` and evaluated on ``--curve-seeds`` by a
    child process (this script with ``--curve-eval``), on ``--curve-device`` (cpu by default, so that the
    GPU keeps training alone), one at a time; polled from the training log callback (no threads)."""

    def __init__(self, args, ckpt: Path, data: Path, report: dict, save):
        self.args, self.ckpt, self.data, self.report, self.save = args, ckpt, data, report, save
        self.dir = args.work / "curve"
        self.dir.mkdir(parents=True, exist_ok=True)
        self.rows = report.setdefault("curve_success", [])
        self.proc = None
        self.running: tuple[int, Path, float] | None = None
        self.last_seconds = args.curve_first_s  # an evaluation's duration before the first is measured

    def _copy_new(self) -> None:
        root = self.ckpt / "checkpoints"
        for src in sorted(root.glob("step_*")) if root.is_dir() else []:
            dst = self.dir / src.name
            if dst.exists() or not (src / "training_state.pt").is_file():
                continue
            tmp = self.dir / f".{src.name}.partial"
            shutil.rmtree(tmp, ignore_errors=True)
            try:
                shutil.copytree(src, tmp, ignore=shutil.ignore_patterns("training_state.pt"))
                shutil.copy(self.data / "meta" / "simseam_skill.json", tmp / "simseam_skill.json")
                os.replace(tmp, dst)
            except OSError:  # pruned by train_act while copying: the next one will do
                shutil.rmtree(tmp, ignore_errors=True)

    def _collect(self) -> None:
        if self.proc is None or self.proc.poll() is None:
            return
        step, path, t0 = self.running
        out = path / "eval.json"
        row = {"step": step, "seconds": round(time.perf_counter() - t0, 1), "returncode": self.proc.returncode,
               "device": self.args.curve_device}
        if self.proc.returncode == 0 and out.is_file():
            row.update(json.loads(out.read_text()))
            self.last_seconds = row["seconds"]
        else:
            row["log_tail"] = (path / "eval.log").read_text()[-1500:] if (path / "eval.log").is_file() else ""
        self.rows.append(row)
        self.save()
        print(f"  curve: step {step}: {row.get('success', '?')}/{row.get('episodes', '?')} on "
              f"{self.args.curve_seeds.start}:{self.args.curve_seeds.stop} ({row['seconds']:.0f} s, "
              f"{self.args.curve_device})", flush=True)
        self.proc = self.running = None

    def poll(self, seconds_left: float, train_wall: float) -> None:
        """Collect a finished evaluation, copy new checkpoints, start the next if it can end in ``seconds_left``."""
        import subprocess
        import sys

        self._collect()
        self._copy_new()
        if self.proc is not None or seconds_left < 1.3 * self.last_seconds + 10:
            return
        done = {r["step"] for r in self.rows}
        todo = [p for p in sorted(self.dir.glob("step_*")) if int(p.name.split("_")[1]) not in done]
        if not todo:
            return
        path = todo[0]
        step = int(path.name.split("_")[1])
        a = self.args
        cmd = [sys.executable, str(Path(__file__).resolve()), "--curve-eval", str(path),
               "--eval-seeds", f"{a.curve_seeds.start}:{a.curve_seeds.stop}", "--episodes", str(a.episodes),
               "--image-size", str(a.image_size), "--max-steps", str(a.max_steps), "--task", a.task,
               "--policy-type", a.policy_type,
               "--curve-device", a.curve_device, "--curve-threads", str(a.curve_threads),
               "--json", str(path / "eval.json"), "--work", str(path)]
        env = {**os.environ, "OMP_NUM_THREADS": str(a.curve_threads)}
        log = open(path / "eval.log", "w")
        self.proc = subprocess.Popen(cmd, stdout=log, stderr=subprocess.STDOUT, env=env)
        log.close()
        self.running = (step, path, time.perf_counter())
        print(f"  curve: evaluating step {step} at {train_wall:.0f} s of training", flush=True)

    def finish(self, wait_s: float) -> None:
        """Wait up to ``wait_s`` for the evaluation in progress, then stop it (recorded as stopped)."""
        if self.proc is None:
            return
        try:
            self.proc.wait(timeout=max(0.0, wait_s))
        except Exception:  # noqa: BLE001 - subprocess.TimeoutExpired
            self.proc.kill()
            self.proc.wait()
            step, path, t0 = self.running
            self.rows.append({"step": step, "stopped": True, "seconds": round(time.perf_counter() - t0, 1)})
            self.save()
            print(f"  curve: step {step} stopped unfinished ({wait_s:.0f} s left)", flush=True)
            self.proc = self.running = None
            return
        self._collect()


def curve_eval(args) -> int:
    """``--curve-eval DIR``: evaluate the checkpoint copy at DIR on ``--eval-seeds``; write ``--json``."""
    import torch

    torch.set_num_threads(args.curve_threads)
    t = time.perf_counter()
    pol = make_policy(f"lerobot:{args.curve_eval}", device=args.curve_device)
    row = _row(args.policy_type, evaluate(pol, list(args.eval_seeds), args.image_size, False, args.max_steps,
                                          args.task))
    row["eval_seconds"] = time.perf_counter() - t
    _write(args.json, row)
    return 0


def evaluate(policy, seeds, size, privileged, max_steps, task="lift_cube"):
    scene = _scene(size, privileged, max_steps, task)
    try:
        return [run_episode(scene, policy, index=i, seed=s) for i, s in enumerate(seeds)]
    finally:
        scene.close()


def _row(name: str, results) -> dict:
    k = sum(r.success for r in results)
    lo, hi = wilson_interval(k, len(results))
    return {"policy": name, "success": k, "episodes": len(results), "rate": k / len(results), "wilson95": [lo, hi],
            "mean_steps": sum(r.steps for r in results) / len(results),
            "policy_ms_p50": float(np.median([x for r in results for x in r.policy_ms])),
            "failed_seeds": [r.seed for r in results if not r.success]}


def _write(path: Path, report: dict) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    path.write_text(json.dumps(report, indent=2) + "\n")


def parse_seeds(text: str) -> range:
    start, end = (int(x) for x in text.split(":"))
    if not 0 <= start < end:
        raise argparse.ArgumentTypeError(f"--eval-seeds {text!r}: expected START:END with 0 <= START < END")
    return range(start, end)


#: the defaults that differ by policy type (argparse default None): ACT's are the recipe of the GPU proof
KIND_DEFAULTS = {"act": {"n_action_steps": 1, "temporal_ensemble": 0.01, "aug_shift": 4, "warmup_steps": 0},
                 "diffusion": {"n_action_steps": 8, "temporal_ensemble": 0.0, "aug_shift": 0, "warmup_steps": 200}}


def _kind_defaults(args) -> None:
    for key, value in KIND_DEFAULTS[args.policy_type].items():
        if getattr(args, key) is None:
            setattr(args, key, value)
    name = "act_lift" if (args.policy_type, args.task) == ("act", "lift_cube") else \
        f"{'dp' if args.policy_type == 'diffusion' else 'act'}_{args.task}"
    if args.work is None:
        args.work = Path("runs") / name
    if args.json is None:
        args.json = Path("benchmarks/results") / f"{name}_image.json"


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    g = ap.add_argument_group("data")
    g.add_argument("--task", choices=TASKS, default="lift_cube", help="franka_panda's task (scripted expert)")
    g.add_argument("--episodes", type=int, default=300, help="scripted demonstrations, seeds 0..N-1")
    g.add_argument("--collect-workers", type=int, default=1, help="processes recording the demonstrations")
    g.add_argument("--image-size", type=int, default=96)
    g.add_argument("--max-steps", type=int, default=150)
    g.add_argument("--videos", action="store_true", help="store frames as AV1 video (default: PNG images)")
    g = ap.add_argument_group("training (train_act, the code behind `simseam train`)")
    g.add_argument("--policy-type", choices=training.POLICY_TYPES, default="act")
    g.add_argument("--steps", type=int, default=None,
                   help="fixed step count (cosine horizon); default: planned from --train-s after calibration")
    g.add_argument("--train-s", type=float, default=None, help="training seconds for this invocation (default: "
                   "up to --deadline-s less --eval-reserve-s, or 420 without a deadline)")
    g.add_argument("--later-train-s", type=float, default=0.0,
                   help="with --pause: training seconds the next invocation will add (part of the cosine horizon)")
    g.add_argument("--calibrate-s", type=float, default=20.0,
                   help="seconds of training measured before the horizon is planned")
    g.add_argument("--batch-size", type=int, default=256)
    g.add_argument("--lr", type=float, default=3e-4, help="learning rate (backbone included: it starts from scratch)")
    g.add_argument("--warmup-steps", type=int, default=None, help="linear warm-up steps (default: act 0, diffusion "
                   "200)")
    g.add_argument("--lr-schedule", default="cosine", choices=training.LR_SCHEDULES)
    g.add_argument("--chunk-size", type=int, default=10)
    g.add_argument("--n-action-steps", type=int, default=None, help="actions executed per prediction (default: "
                   "act 1, diffusion 8)")
    g.add_argument("--temporal-ensemble", type=float, default=None,
                   help="ACT's temporal ensembling coefficient (needs --n-action-steps 1); 0: off (default: act "
                        "0.01, diffusion off)")
    g.add_argument("--horizon", type=int, default=16, help="diffusion: actions denoised per prediction")
    g.add_argument("--n-obs-steps", type=int, default=2, help="diffusion: observations per prediction")
    g.add_argument("--down-dims", default="256,512,1024", help="diffusion: the U-Net's widths")
    g.add_argument("--inference-steps", type=int, default=10, help="diffusion: DDIM steps per prediction")
    g.add_argument("--crop-fraction", type=float, default=0.9, help="diffusion: random crop while training")
    g.add_argument("--vae", action="store_true", help="ACT's VAE (off: the expert has one mode)")
    g.add_argument("--dim-model", type=int, default=256)
    g.add_argument("--ff-dim", type=int, default=1024)
    g.add_argument("--encoder-layers", type=int, default=4)
    g.add_argument("--aug-shift", type=int, default=None, help="random shift of each image, pixels (0: off; "
                   "default: act 4, diffusion 0: its random crop augments)")
    g.add_argument("--image-stats", choices=("recompute", "lerobot"), default="recompute",
                   help="recompute the cameras' mean/std from every frame before training (LeRobot 0.4.4 records "
                        "an image std of ~0: fix_image_stats), or keep what LeRobot recorded")
    g.add_argument("--backbone-norm", choices=("batch", "frozen"), default="batch",
                   help="train the ResNet with batch norm (saved into ACT's frozen batch norm) or as ACT builds it "
                        "(frozen: no normalization from scratch)")
    g.add_argument("--backbone-calls", choices=("joint", "per-camera"), default="joint",
                   help="in training, one backbone call over all cameras (batch statistics = the mixture the "
                        "running statistics hold: joint_camera_backbone) or one per camera as ACT does")
    g.add_argument("--amp", action="store_true", help="bfloat16 autocast for training on CUDA")
    g.add_argument("--no-cache", action="store_true",
                   help="stream batches through LeRobotDataset's loader instead of caching frames on the device "
                        "(no --aug-shift then)")
    g.add_argument("--workers", type=int, default=8, help="data-loader workers (decoding the cache)")
    g.add_argument("--log-every", type=int, default=100)
    g.add_argument("--seed", type=int, default=0)
    g = ap.add_argument_group("time and evaluation")
    g.add_argument("--deadline-s", type=float, default=None,
                   help="this invocation's limit in seconds: training ends (or pauses) early enough to leave "
                        "--eval-reserve-s for evaluation")
    g.add_argument("--eval-reserve-s", type=float, default=120.0)
    g.add_argument("--pause", action="store_true",
                   help="stop training at the deadline with a resumable checkpoint and do not evaluate")
    g.add_argument("--eval-seeds", type=parse_seeds, default=parse_seeds("10000:10050"),
                   help="held-out seeds START:END (default 10000:10050)")
    g.add_argument("--eval-variants", default="",
                   help="more evaluations of the same checkpoint, comma-separated n_action_steps values "
                        "(executed open loop from each chunk, no temporal ensembling), run if time is left")
    g.add_argument("--curve-every", type=int, default=0,
                   help="save a checkpoint every N steps and evaluate it on --curve-seeds beside training (0: off)")
    g.add_argument("--curve-seeds", type=parse_seeds, default=parse_seeds("10000:10020"),
                   help="held-out seeds for the success curve (default: the first 20 of --eval-seeds)")
    g.add_argument("--curve-device", default="cpu",
                   help="device of the curve's evaluations (cpu: the GPU trains alone)")
    g.add_argument("--curve-threads", type=int, default=4, help="torch threads of a curve evaluation")
    g.add_argument("--curve-first-s", type=float, default=90.0,
                   help="expected seconds of a curve evaluation until one is measured (none starts unless it can "
                        "end inside the training window)")
    g.add_argument("--curve-eval", type=Path, default=None, help=argparse.SUPPRESS)  # the child's mode
    g.add_argument("--work", type=Path, default=None, help="default runs/<policy>_<task>")
    g.add_argument("--json", type=Path, default=None,
                   help="default benchmarks/results/<policy>_<task>_image.json (act, lift_cube: act_lift_image.json)")
    g.add_argument("--smoke", action="store_true", help="a rehearsal with tiny numbers: marked so in the JSON")
    args = ap.parse_args()
    _kind_defaults(args)
    if args.curve_eval is not None:
        return curve_eval(args)
    if min(args.eval_seeds.start, args.curve_seeds.start) < args.episodes:
        ap.error(f"--eval-seeds {args.eval_seeds.start}:{args.eval_seeds.stop} or --curve-seeds overlaps the "
                 f"demonstration seeds 0:{args.episodes}")
    if args.aug_shift and args.no_cache:
        ap.error("--aug-shift shifts the device cache's batches: it needs the cache (drop --no-cache)")

    import torch

    if torch.cuda.is_available():
        torch.backends.cudnn.benchmark = True  # fixed shapes: let cuDNN pick its fastest convolutions
    args.work.mkdir(parents=True, exist_ok=True)
    state_path = args.work / "report.json"
    report: dict = json.loads(state_path.read_text()) if state_path.is_file() else {}
    report["policy_type"], report["task"] = args.policy_type, args.task
    if args.smoke:
        report["smoke"] = True
    report.setdefault("invocations", []).append({
        "host": platform.node(), "torch": torch.__version__,
        "gpu": torch.cuda.get_device_name(0) if torch.cuda.is_available() else None,
        "args": {k: (f"{v.start}:{v.stop}" if isinstance(v, range) else str(v) if isinstance(v, Path) else v)
                 for k, v in vars(args).items()}})
    calls = report["invocations"]

    def save() -> None:
        _write(state_path, report)
        _write(args.json, report)

    size = args.image_size
    data, ckpt = args.work / "dataset", args.work / args.policy_type

    # 1. demonstrations
    if "collect" not in report:
        report["collect"] = collect(data, args.episodes, args.collect_workers, size, args.max_steps, args.videos,
                                    args.task)
        save()
        c = report["collect"]
        print(f"collect: {c['episodes_written']}/{c['episodes_run']} episodes, {c['frames']} frames, "
              f"{c['seconds']:.0f} s ({c['workers']} workers)", flush=True)

    if args.image_stats == "recompute" and "image_stats" not in report:
        report["image_stats"] = fix_image_stats(data, args.workers)
        save()
        print("image stats recomputed: std " + ", ".join(
            f"{k.split('.')[-1]} {np.round(v['std_before'], 4).tolist()} -> {np.round(v['std'], 3).tolist()}"
            for k, v in report["image_stats"].items()), flush=True)

    # 2. training
    train = report.setdefault("train", {"curve": [], "segments": [], "done": False})
    if not train["done"]:
        resume = latest_checkpoint(ckpt) is not None
        prior_s = sum(s["seconds"] for s in train["segments"])
        window = args.train_s if args.train_s is not None else float("inf") if args.deadline_s else 420.0
        if args.deadline_s is not None:
            window = max(5.0, min(window, args.deadline_s - (0 if args.pause else args.eval_reserve_s) - _now()))
        cfg = ActTrainConfig(
            policy_type=args.policy_type, warmup_steps=args.warmup_steps, horizon=args.horizon,
            n_obs_steps=args.n_obs_steps, down_dims=tuple(int(d) for d in args.down_dims.split(",")),
            inference_steps=args.inference_steps, crop_fraction=args.crop_fraction,
            steps=args.steps or train.get("planned_steps") or 10**9, batch_size=args.batch_size,
            lr=args.lr, lr_backbone=args.lr, lr_schedule=args.lr_schedule, chunk_size=args.chunk_size,
            n_action_steps=args.n_action_steps, temporal_ensemble_coeff=args.temporal_ensemble or None,
            dim_model=args.dim_model, dim_feedforward=args.ff_dim, n_encoder_layers=args.encoder_layers,
            use_vae=args.vae, num_workers=args.workers, cache_on_device=not args.no_cache, use_amp=args.amp,
            seed=args.seed + len(calls) - 1, log_every=args.log_every, checkpoint_every=args.curve_every or None,
            # a final invocation ends by time at the latest; a pausing one is interrupted below instead
            time_budget_s=None if args.pause else window)
        if args.aug_shift:
            use_random_shift(args.aug_shift)
        seg = {"invocation": len(calls) - 1, "resumed": resume, "window_s": window}
        curve = CurveEval(args, ckpt, data, report, save) if args.curve_every else None
        first: list[float] = []  # (step, time) of this segment's first log: speed is measured from there

        def on_log(step: int, loss: float) -> None:
            now = time.perf_counter()
            if not first:
                first[:] = [step, now]
            wall = prior_s + _now() - seg["t_start"]
            train["curve"].append([step, loss, round(wall, 2)])
            print(f"  step {step:6d}  loss {loss:.4f}  lr x{training.lr_factor(cfg, step):.3f}  {wall:6.0f} s",
                  flush=True)
            if args.steps is None and "rate" not in seg and now - first[1] >= args.calibrate_s:
                # plan the cosine horizon: the steps that fit this window (+ the next invocation's)
                seg["rate"] = (step - first[0]) / (now - first[1])
                left = 0.97 * (window - (_now() - seg["t_start"]))  # a margin: the rate may sag
                left += args.later_train_s if args.pause else 0.0
                cfg.steps = train["planned_steps"] = step + max(1, int(seg["rate"] * left))
                print(f"  {seg['rate']:.1f} steps/s: horizon {cfg.steps} steps", flush=True)
            if curve is not None:
                curve.poll(window - (_now() - seg["t_start"]), wall)
            if args.pause and _now() - seg["t_start"] >= window:
                raise KeyboardInterrupt  # train_act saves a resumable checkpoint of the steps done

        seg["t_start"] = _now()
        print(f"train: {'resuming' if resume else 'from scratch'}, window {window:.0f} s, "
              f"batch {args.batch_size}, lr {args.lr} ({args.lr_schedule})", flush=True)
        try:
            act = args.policy_type == "act"  # the backbone patches are ACT's (Diffusion from scratch: group norm)
            with batchnorm_backbone(act and args.backbone_norm == "batch"), \
                    joint_camera_backbone(act and args.backbone_calls == "joint"):
                res = train_act(data, ckpt, cfg, on_log=on_log, resume=resume, overwrite=not resume)
        except KeyboardInterrupt:
            if not args.pause:
                if curve is not None:
                    curve.finish(0)
                raise
            if curve is not None:
                curve.finish((args.deadline_s - _now() - 10) if args.deadline_s is not None else 600)
            seg.update(paused_at=int(latest_checkpoint(ckpt).name.split("_")[1]), seconds=_now() - seg["t_start"])
            train["segments"].append(seg)
            save()
            print(f"paused at step {seg['paused_at']} (checkpoint {latest_checkpoint(ckpt)}); "
                  f"run again with --work {args.work} to continue", flush=True)
            return 0
        seg.update(steps=res.steps, seconds=_now() - seg["t_start"], train_seconds=res.seconds,
                   prepare_seconds=res.prepare_seconds)
        if curve is not None:  # the final evaluation runs alone; its first --curve-seeds give the last point
            curve.finish(0)
        train["segments"].append(seg)
        train.update(done=True, steps=res.steps, planned_steps=cfg.steps, seconds=prior_s + seg["seconds"],
                     device=res.device, n_params=res.n_params, batch_size=args.batch_size,
                     frames=res.frames, episodes=res.episodes, samples_seen=res.steps * args.batch_size,
                     epochs=res.steps * args.batch_size / max(res.frames, 1),
                     losses=res.losses, config=json.loads((ckpt / "training.json").read_text())["config"])
        save()
        print(f"train: {res.steps} steps (horizon {cfg.steps}) in {train['seconds']:.0f} s of training on "
              f"{res.device} ({res.n_params / 1e6:.1f} M params)", flush=True)

    # 3. held-out evaluation through `lerobot:`
    seeds = list(args.eval_seeds)
    spec = f"lerobot:{ckpt}"
    t = time.perf_counter()
    name = (f"act, temporal ensembling {args.temporal_ensemble}" if args.temporal_ensemble
            else f"{args.policy_type}, n_action_steps={args.n_action_steps}")
    rows = [_row(name, evaluate(make_policy(spec), seeds, size, False, args.max_steps, args.task))]
    ev = {"seeds": f"{seeds[0]}:{seeds[-1] + 1}", "policies": rows, "seconds": time.perf_counter() - t}
    report["eval"] = ev
    save()
    rows.append(_row("scripted expert (privileged)", evaluate(make_policy("scripted"), seeds, size, True,
                                                               args.max_steps, args.task)))
    save()
    for variant in filter(None, args.eval_variants.split(",")):
        # each variant runs as long as the first evaluation, at most
        if args.deadline_s is not None and _now() + ev["seconds"] + 15 > args.deadline_s:
            ev.setdefault("skipped_variants", []).append(variant)
            continue
        overrides = {"temporal_ensemble_coeff": None} if args.policy_type == "act" else None
        pol = make_policy(spec, n_action_steps=int(variant), config_overrides=overrides)
        rows.append(_row(f"{args.policy_type}, n_action_steps={int(variant)}",
                         evaluate(pol, seeds, size, False, args.max_steps, args.task)))
        save()
    ev["seconds_all"] = time.perf_counter() - t
    report["total_seconds_last_invocation"] = _now()
    save()

    print(f"\n{'policy':34s} {'success':>9s} {'rate':>6s} {'Wilson 95%':>14s} {'mean steps':>11s}")
    for r in rows:
        print(f"{r['policy']:34s} {r['success']:>4d}/{r['episodes']:<4d} {r['rate']:6.0%} "
              f"[{r['wilson95'][0]:.2f}, {r['wilson95'][1]:.2f}] {r['mean_steps']:11.1f}")
    c = report["collect"]
    print(f"{args.task}, {args.policy_type}{' (SMOKE: tiny numbers, not a result)' if args.smoke else ''}; "
          f"held-out seeds {ev['seeds']}; training: {train['steps']} steps x batch {args.batch_size} in "
          f"{train['seconds']:.0f} s on {calls[-1]['gpu'] or train['device']}; data: {c['episodes_written']} demos / "
          f"{c['frames']} frames (seeds {c['seeds']})")
    print(f"wrote {args.json}")
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
