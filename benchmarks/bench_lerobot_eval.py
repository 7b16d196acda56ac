"""``lerobot-eval`` vs ``simseam eval pusht``: the same PushT policy, episodes and seeds, N environments.

The policy is a small ACT (random initialisation, ``torch.manual_seed(0)``, no hub: a ResNet-18
backbone without pretrained weights, one encoder and one decoder layer, chunks of 10 actions) saved
twice with ``save_pretrained`` from the same weights and normalisation statistics. The two copies
differ only in the name of the image input: LeRobot's PushT env hands the policy
``observation.image``; simseam's ``lerobot:`` adapter feeds ``observation.images.<camera>`` (the
PushT backend's camera is ``top``). Both run gym-pusht 0.1.8 (96 x 96 pixels + agent position,
300 steps) on CPU:

- ``lerobot-eval --env.type=pusht --eval.batch_size=N`` (a gymnasium ``SyncVectorEnv`` of N envs in
  one process; ``--async`` adds ``--eval.use_async_envs=true``: an ``AsyncVectorEnv``, one process each),
  episodes seeded ``seed, seed + 1, ...``; it always writes videos of up to 10 episodes;
- ``simseam eval pusht --num-envs N --policy lerobot:...`` (N worker processes, each owning a PushT
  sidecar; one batched forward pass for the environments that need a chunk), ``--seed`` the same,
  ``--video`` for parity (one MP4 per episode).

Each case is timed end to end as a subprocess (start-up, env construction, episodes, results).
lerobot-eval's interpreter needs gym-pusht, which the main venv does not have: ``--pusht-site DIR``
(default ``~/.cache/simseam/lerobot-eval-pusht-<hash>/site``, installed there with ``pip --target``
when missing: the only step that needs the network). Prints a table, writes JSON
(default ``benchmarks/results/lerobot_eval.json``).

    python benchmarks/bench_lerobot_eval.py --n 1 2 --episodes 4
"""

from __future__ import annotations

import argparse
import hashlib
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
PUSHT_PINS = ["gym-pusht==0.1.8", "pymunk==6.11.1", "pygame==2.6.1", "shapely==2.2.0", "cffi==2.1.1", "pycparser==3.12"]


def pusht_site(path: Path | None) -> Path:
    if path is None:
        key = hashlib.sha256(" ".join(PUSHT_PINS).encode()).hexdigest()[:12]
        path = Path.home() / ".cache" / "simseam" / f"lerobot-eval-pusht-{key}" / "site"
    if not (path / "gym_pusht").is_dir():
        subprocess.run([sys.executable, "-m", "pip", "install", "-q", "--disable-pip-version-check", "--no-deps",
                        "--target", str(path), *PUSHT_PINS], check=True)
    return path


def make_policies(work: Path) -> tuple[Path, Path]:
    """The same ACT weights and statistics saved for each evaluator's image name."""
    import torch
    from lerobot.configs.types import FeatureType, PolicyFeature
    from lerobot.policies.act.configuration_act import ACTConfig
    from lerobot.policies.act.modeling_act import ACTPolicy
    from lerobot.policies.factory import make_pre_post_processors

    def config(image_key: str) -> ACTConfig:
        return ACTConfig(input_features={image_key: PolicyFeature(FeatureType.VISUAL, (3, 96, 96)),
                                         "observation.state": PolicyFeature(FeatureType.STATE, (2,))},
                         output_features={"action": PolicyFeature(FeatureType.ACTION, (2,))},
                         chunk_size=10, n_action_steps=10, dim_model=64, dim_feedforward=128, n_encoder_layers=1,
                         n_decoder_layers=1, n_heads=2, use_vae=False, pretrained_backbone_weights=None, device="cpu")

    torch.manual_seed(0)
    weights = None
    dirs = []
    for key, name in (("observation.image", "act_lerobot_names"), ("observation.images.top", "act_simseam_names")):
        cfg = config(key)
        policy = ACTPolicy(cfg)
        if weights is None:
            weights = policy.state_dict()
        else:
            policy.load_state_dict(weights)  # parameter names do not depend on the image's name
        stats = {key: {"mean": torch.full((3, 1, 1), 0.5), "std": torch.full((3, 1, 1), 0.25)},
                 "observation.state": {"mean": torch.full((2,), 256.0), "std": torch.full((2,), 150.0)},
                 "action": {"mean": torch.full((2,), 256.0), "std": torch.full((2,), 150.0)}}
        pre, post = make_pre_post_processors(cfg, dataset_stats=stats)
        d = work / name
        for obj in (policy, pre, post):
            obj.save_pretrained(d)
        dirs.append(d)
    return dirs[0], dirs[1]


def run_lerobot(policy: Path, n: int, episodes: int, seed: int, site: Path, work: Path, use_async: bool) -> dict:
    out = work / f"lerobot_n{n}_{'async' if use_async else 'sync'}"
    # what the lerobot-eval console script runs (its module's main), with this interpreter
    argv = [sys.executable, "-m", "lerobot.scripts.lerobot_eval", f"--policy.path={policy}", "--env.type=pusht",
            f"--eval.batch_size={n}",
            f"--eval.n_episodes={episodes}", "--policy.device=cpu", f"--seed={seed}", f"--output_dir={out}"]
    if use_async:
        argv.append("--eval.use_async_envs=true")
    env = dict(os.environ, HF_HUB_OFFLINE="1", PYTHONPATH=os.pathsep.join(filter(None, [str(site),
                                                                                        os.environ.get("PYTHONPATH")])))
    t0 = time.perf_counter()
    proc = subprocess.run(argv, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    tool = "lerobot-eval" + (" async" if use_async else " sync")
    if proc.returncode != 0:
        if not use_async:
            raise SystemExit(f"lerobot-eval failed:\n{(proc.stdout + proc.stderr)[-4000:]}")
        errors = [ln for ln in (proc.stdout + proc.stderr).splitlines() if re.match(r"\w+(Error|Exception)\b", ln)]
        last = errors[-1] if errors else f"exit code {proc.returncode}"
        return {"tool": tool, "num_envs": n, "episodes": 0, "wall_s": round(wall, 2), "episodes_per_hour": 0.0,
                "success_rate": float("nan"), "error": last.strip()}
    m = re.search(r"Overall Aggregated Metrics:\n(\{.*?\})\n", proc.stdout + proc.stderr)
    metrics = eval(m.group(1), {}) if m else {}  # noqa: S307 - lerobot prints a dict literal of its own numbers
    return {"tool": tool, "num_envs": n, "episodes": episodes,
            "wall_s": round(wall, 2), "episodes_per_hour": round(episodes / wall * 3600, 1),
            "success_rate": metrics.get("pc_success", float("nan")) / 100.0,
            "eval_s_reported": round(metrics.get("eval_s", float("nan")), 2)}


def run_simseam(policy: Path, n: int, episodes: int, seed: int, work: Path) -> dict:
    out = work / f"simseam_n{n}"
    argv = [sys.executable, "-m", "simseam.cli.main", "eval", "pusht", "--policy", f"lerobot:{policy}", "--device",
            "cpu", "--num-envs", str(n), "--episodes", str(episodes), "--seed", str(seed), "--video", "--out",
            str(out), "--overwrite"]
    env = dict(os.environ)
    env.setdefault("MUJOCO_GL", "egl")
    env["PYTHONPATH"] = os.pathsep.join(filter(None, [str(REPO / "src"), env.get("PYTHONPATH")]))
    t0 = time.perf_counter()
    proc = subprocess.run(argv, env=env, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if proc.returncode != 0:
        raise SystemExit(f"simseam eval failed:\n{(proc.stdout + proc.stderr)[-4000:]}")
    rows = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines() if line.strip()]
    steps = sum(e["steps"] for e in rows)
    return {"tool": "simseam eval", "num_envs": n, "episodes": len(rows), "wall_s": round(wall, 2),
            "episodes_per_hour": round(len(rows) / wall * 3600, 1), "env_steps": steps,
            "env_steps_per_s": round(steps / wall, 1), "errors": sum(1 for e in rows if e["error"]),
            "success_rate": sum(e["success"] for e in rows) / len(rows)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--episodes", type=int, default=4)
    ap.add_argument("--seed", type=int, default=1000, help="lerobot-eval's default")
    ap.add_argument("--async", dest="use_async", action="store_true", help="also lerobot-eval's AsyncVectorEnv")
    ap.add_argument("--pusht-site", type=Path, default=None)
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "lerobot_eval.json")
    args = ap.parse_args()

    site = pusht_site(args.pusht_site)
    work = Path(tempfile.mkdtemp(prefix="simseam-lerobot-eval-"))
    results = []
    try:
        le_policy, sim_policy = make_policies(work)
        for n in args.n:
            cases = [lambda: run_lerobot(le_policy, n, args.episodes, args.seed, site, work, False)]
            if args.use_async and n > 1:
                cases.append(lambda: run_lerobot(le_policy, n, args.episodes, args.seed, site, work, True))
            cases.append(lambda: run_simseam(sim_policy, n, args.episodes, args.seed, work))
            for case in cases:
                r = case()
                results.append(r)
                print(f"  {r['tool']:20s} N={n}: {r['episodes']} episodes in {r['wall_s']:.1f} s"
                      + (f" (failed: {r['error']})" if r.get("error") else ""), flush=True)
    finally:
        shutil.rmtree(work, ignore_errors=True)
    info = {"cores": len(os.sched_getaffinity(0)), "python": sys.version.split()[0], "policy": "ACT, random init, "
            "chunk 10, dim 64, 1+1 layers, ResNet-18 without pretrained weights", "seed": args.seed}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"machine": info, "results": results}, indent=2))
    print(f"\nPushT, {args.episodes} episodes x 300 steps, {info['policy']}, {info['cores']} cores, CPU")
    print("| tool | N | wall s | episodes/h | success |")
    print("|---|---:|---:|---:|---:|")
    for r in results:
        if r.get("error"):
            print(f"| {r['tool']} | {r['num_envs']} | failed: {r['error']} | | |")
            continue
        print(f"| {r['tool']} | {r['num_envs']} | {r['wall_s']:.1f} | {r['episodes_per_hour']:,.0f} | "
              f"{r['success_rate']:.0%} |")
    print(f"\nJSON: {args.out}")


if __name__ == "__main__":
    main()
