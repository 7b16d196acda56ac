"""The same number as LeRobot's own evaluator: one image ACT checkpoint on Meta-World, evaluated by LeRobot
(its Meta-World env, ``lerobot-eval --env.type=metaworld``, offline) and by ``simseam eval metaworld_lerobot``
on the same task and seeds, compared episode by episode.

    .venv/bin/python benchmarks/metaworld_lerobot_eval.py [--task drawer-close-v3] [--demos 30]
        [--train-s 720] [--seed 1000] [--episodes 50] [--lerobot-workers 2] [--cli-check 2] [--checkpoint DIR]
        [--work DIR] [--compare-only] [--json FILE]

What LeRobot's env gives a policy (lerobot 0.4.4, lerobot/envs/metaworld.py, obs_type ``pixels_agent_pos``):
``observation.image``, a 480x480 render of ``corner2`` moved to (0.75, 0.075, 0.7) and flipped on both
axes, and ``observation.state``, the 4-D ``agent_pos`` (hand xyz, gripper opening); 500 steps; the episode
ends at ``info['success']``. Its resets ignore the seed: Meta-World draws each initial state from NumPy's
*global* generator, which ``lerobot-eval --seed=S`` seeds once (``set_seed``) before its first episode; the
later episodes of a run continue that stream, one extra draw after each success (the env resets itself).
So only a run's first episode is fixed by its seed. The ``metaworld_lerobot`` preset is that env behind the
seam (``variation: lerobot``: ``np.random.seed(seed)`` then the reset), so LeRobot's side here runs one
episode per seed: for each seed, what ``lerobot-eval --seed=<seed> --eval.n_episodes=1
--eval.batch_size=1`` runs (LeRobot's ``set_seed``, ``make_env``, ``eval_policy_all``, in one process, the
policy loaded once, no videos), and ``--cli-check K`` runs the ``lerobot-eval`` command itself for the first
K seeds to show that it gives the same episodes.

The checkpoint is made through simseam (skipped with ``--checkpoint``):

1. ``simseam collect`` of Meta-World's scripted expert from a scene with LeRobot's camera, flip and
   ``agent_pos`` but 64x64 images (rendering is the cost on a CPU), ``variation: sampled``, seeds
   ``0 .. demos-1`` (not the evaluation's generator nor its seeds);
2. ``simseam train``: ACT from scratch (no VAE, chunk 10 executed whole, a small transformer);
3. the served copy reads what LeRobot's env gives: its config and skill file declare a 480x480
   ``camera1``, and its preprocessor starts with LeRobot's own ``image_crop_resize_processor`` (resize to
   the 64x64 it was trained on), so both evaluators hand the same 480x480 frame to the same pipeline.

The image travels as ``observation.images.camera1`` (simseam's name); ``lerobot-eval`` gets
``--rename_map='{"observation.image": "observation.images.camera1"}'``, its own way to feed a policy whose
image is named otherwise. Compared per seed: success, and the return (LeRobot's ``sum_reward``) within one float32
ulp of 10 per step (``REWARD_ULP``; docs/benchmarks.md says what differs and what is known of why).
``--compare-only`` compares what ``--work`` holds on the seeds both sides finished (LeRobot's workers append
one line per episode; a seed run by two workers must give the same episode). LeRobot's interpreter needs metaworld 3.0.0 and MuJoCo 3.3.0 (the main venv's
MuJoCo 4 breaks metaworld 3.0.0): the metaworld backend venv's two packages go first on its path. Every
process runs with ``OMP_NUM_THREADS=1``. Prints a table, writes JSON (default
``benchmarks/results/metaworld_lerobot_eval.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
SIMSEAM = str(Path(sys.executable).with_name("simseam"))
RENAME = {"observation.image": "observation.images.camera1"}
TRAIN_SIZE = 64


def scene_yaml(task: str, size: int) -> str:
    from simseam.runner.evaluate import METAWORLD_LEROBOT

    opts = {**METAWORLD_LEROBOT, "expert": True, "variation": "sampled", "image_size": [size, size]}
    fields = ", ".join(f"{k}: {json.dumps(v)}" for k, v in opts.items())
    return (f"# Meta-World's expert with LeRobot's camera, flip and agent_pos, {size}x{size} "
            f"(benchmarks/metaworld_lerobot_eval.py)\nbenchmark: {{name: metaworld, task: {task}, {fields}}}\n")


def run_logged(argv: list[str], log: Path, env: dict | None = None) -> float:
    """Run ``argv`` from the repository root, its output appended to ``log``; its wall seconds (a non-zero
    exit raises, naming the log)."""
    t0 = time.perf_counter()
    with log.open("a") as f:
        f.write(f"$ {' '.join(argv)}\n")
        f.flush()
        rc = subprocess.run(argv, stdout=f, stderr=subprocess.STDOUT, cwd=ROOT, env=env).returncode
    if rc != 0:
        raise RuntimeError(f"{Path(argv[0]).name} {argv[1]} exited {rc}; its output is in {log}")
    return time.perf_counter() - t0


def make_checkpoint(task: str, demos: int, train_s: float, steps: int, work: Path, log: Path) -> dict:
    scene = work / "scene_demos.yaml"
    scene.write_text(scene_yaml(task, TRAIN_SIZE))
    data, ckpt = work / "demos", work / "act"
    collect_s = run_logged([SIMSEAM, "collect", "--scene", str(scene), "--policy", "scripted", "--episodes", str(demos),
                      "--seed", "0", "--images", "--out", str(data), "--overwrite"], log)
    train_s_wall = run_logged([SIMSEAM, "train", "--dataset", str(data), "--out", str(ckpt), "--overwrite", "--cache",
                         "--workers", "0", "--device", "cpu", "--no-vae", "--steps", str(steps),
                         "--time-budget-s", str(train_s), "--batch-size", "32", "--lr", "3e-4",
                         "--lr-schedule", "cosine", "--chunk-size", "10", "--n-action-steps", "10",
                         "--dim-model", "128", "--ff-dim", "512", "--encoder-layers", "2"], log)
    info = json.loads((data / "meta" / "info.json").read_text())
    training = json.loads((ckpt / "training.json").read_text())
    return {"dir": str(ckpt), "scene": scene.read_text().splitlines()[-1],
            "demos": {"seeds": f"0:{demos}", "episodes_kept": info["total_episodes"],
                      "frames": info["total_frames"], "seconds": round(collect_s, 1)},
            "training": {"steps": training["steps"], "seconds": round(training["seconds"], 1),
                         "wall_seconds": round(train_s_wall, 1), "n_params": training["n_params"],
                         "final_loss": training["losses"][-1][1] if training["losses"] else None}}


def serve_480(ckpt: Path, out: Path) -> Path:
    """A copy of ``ckpt`` that reads LeRobot's 480x480 frame: LeRobot's image_crop_resize_processor (to the
    size it was trained on) before the normalizer."""
    if out.exists():
        shutil.rmtree(out)
    shutil.copytree(ckpt, out, ignore=shutil.ignore_patterns("checkpoints", "training_state*"))
    cfg = json.loads((out / "config.json").read_text())
    sizes = set()
    for key, feat in cfg["input_features"].items():
        if key.startswith("observation.image"):
            sizes.add(tuple(feat["shape"][1:]))
            feat["shape"] = [3, 480, 480]
    if len(sizes) != 1:
        raise SystemExit(f"{ckpt}: expected one image size among the inputs, got {sorted(sizes)}")
    size = list(sizes.pop())
    (out / "config.json").write_text(json.dumps(cfg, indent=4))
    skill = out / "simseam_skill.json"
    if skill.exists():
        s = json.loads(skill.read_text())
        s["images"] = {k: [480, 480] for k in s.get("images", {})}
        skill.write_text(json.dumps(s, indent=2))
    pre = json.loads((out / "policy_preprocessor.json").read_text())
    step = {"registry_name": "image_crop_resize_processor", "config": {"crop_params_dict": None,
                                                                     "resize_size": size}}
    names = [s.get("registry_name") for s in pre["steps"]]
    at = names.index("normalizer_processor") if "normalizer_processor" in names else len(names)
    pre["steps"].insert(at, step)
    (out / "policy_preprocessor.json").write_text(json.dumps(pre, indent=2))
    return out


def lerobot_site() -> Path:
    """metaworld 3.0.0 and MuJoCo 3.3.0 from the metaworld backend venv, for LeRobot's interpreter."""
    from simseam.backends.provision import venv_dir

    found = list((venv_dir("metaworld") / "lib").glob("python*/site-packages"))
    if not found or not (found[0] / "metaworld").is_dir():
        raise SystemExit("the metaworld backend is not provisioned: `simseam backends provision metaworld`")
    site = Path(tempfile.mkdtemp(prefix="mw-lerobot-site-"))
    for pkg in ("metaworld", "mujoco"):
        (site / pkg).symlink_to(found[0] / pkg)
    return site


def lerobot_env(site: Path) -> dict:
    return dict(os.environ, HF_HUB_OFFLINE="1", PYTHONPATH=os.pathsep.join(
        filter(None, [str(site), str(ROOT / "src"), os.environ.get("PYTHONPATH")])))


def lerobot_worker(ckpt: Path, task: str, seeds: list[int], out: Path) -> None:
    """LeRobot's evaluator, one episode per seed (what ``lerobot-eval --seed=<s> --eval.n_episodes=1`` runs)."""
    import torch
    from lerobot.configs.policies import PreTrainedConfig
    from lerobot.envs.configs import MetaworldEnv as MetaworldEnvConfig
    from lerobot.envs.factory import make_env, make_env_pre_post_processors
    from lerobot.envs.utils import close_envs
    from lerobot.policies.factory import make_policy, make_pre_post_processors
    from lerobot.scripts.lerobot_eval import eval_policy_all
    from lerobot.utils.random_utils import set_seed

    env_cfg = MetaworldEnvConfig(task=task)
    pcfg = PreTrainedConfig.from_pretrained(ckpt)
    pcfg.pretrained_path = ckpt
    pcfg.device = "cpu"
    policy = make_policy(cfg=pcfg, env_cfg=env_cfg, rename_map=RENAME)
    policy.eval()
    pre, post = make_pre_post_processors(policy_cfg=pcfg, pretrained_path=str(ckpt), preprocessor_overrides={
        "device_processor": {"device": "cpu"}, "rename_observations_processor": {"rename_map": RENAME}})
    env_pre, env_post = make_env_pre_post_processors(env_cfg=env_cfg, policy_cfg=pcfg)
    with out.open("a") as f:
        for seed in seeds:
            t0 = time.perf_counter()
            set_seed(seed)  # eval_main's order: set_seed, make_env, then the episodes
            envs = make_env(env_cfg, n_envs=1)
            with torch.no_grad():
                info = eval_policy_all(envs=envs, policy=policy, env_preprocessor=env_pre, env_postprocessor=env_post,
                                       preprocessor=pre, postprocessor=post, n_episodes=1, max_episodes_rendered=0,
                                       start_seed=seed)
            close_envs(envs)
            m = info["per_task"][0]["metrics"]
            f.write(json.dumps({"seed": seed, "success": bool(m["successes"][0]), "reward": m["sum_rewards"][0],
                                "max_reward": m["max_rewards"][0], "seconds": round(time.perf_counter() - t0, 1)})
                    + "\n")
            f.flush()


def lerobot_cli(ckpt: Path, task: str, seed: int, work: Path, site: Path, log: Path) -> None:
    """The ``lerobot-eval`` command itself (its module's main), one episode at ``seed``: writes
    ``lerobot_cli_<seed>/eval_info.json``."""
    out = work / f"lerobot_cli_{seed}"
    shutil.rmtree(out, ignore_errors=True)
    run_logged([sys.executable, "-m", "lerobot.scripts.lerobot_eval", f"--policy.path={ckpt}",
          "--env.type=metaworld", f"--env.task={task}", "--eval.n_episodes=1", "--eval.batch_size=1",
          "--policy.device=cpu", f"--seed={seed}", f"--output_dir={out}",
          f"--rename_map={json.dumps(RENAME)}"], log, env=lerobot_env(site))


def read_lerobot(work: Path) -> tuple[dict[int, dict], list[int]]:
    """LeRobot's episodes from every worker file; a seed run twice must give the same episode (returned: the
    seeds that were run twice, each checked)."""
    le: dict[int, dict] = {}
    repeated = []
    for out in sorted(work.glob("lerobot_episodes_*.jsonl")):
        for r in map(json.loads, out.read_text().splitlines()):
            if r["seed"] in le:
                first = le[r["seed"]]
                if (first["success"], first["reward"]) != (r["success"], r["reward"]):
                    raise SystemExit(f"LeRobot's seed {r['seed']} ran twice with different episodes: {first} {r}")
                repeated.append(r["seed"])
            le[r["seed"]] = r
    return le, sorted(repeated)


def read_simseam(run: Path) -> dict[int, dict]:
    lines = (run / "episodes.jsonl").read_text().splitlines() if (run / "episodes.jsonl").exists() else []
    return {e["seed"]: e for e in map(json.loads, filter(str.strip, lines)) if not e.get("error")}


#: the return tolerance per step: one float32 ulp of Meta-World's largest per-step reward (10). Known sources of
#: such differences: ``simseam eval``'s environments share batched forward passes (ACT's output for a row of a batch
#: of 2 differs from a batch of 1 in the last bits; LeRobot's side runs batches of 1), and LeRobot hands Meta-World the policy's raw action, the seam clips it to [-1, 1] first; the
#: physics is the same (Meta-World clips the move, MuJoCo the grip control), but drawer-close's reward reads the grip
#: (``min(max(0, grip), 1)``), float64 after a raw 1.3, float32 after a clipped float32 1.0 (docs/benchmarks.md)
REWARD_ULP = 9.5367431640625e-07


def compare(le: dict[int, dict], ss: dict[int, dict], seeds: list[int]) -> dict:
    from simseam.runner.summary import wilson_interval

    rows, agree, reward_agree = [], 0, 0
    for s in seeds:
        a, b = le[s], ss[s]
        same = a["success"] == b["success"]
        dr = abs(a["reward"] - b["reward"])
        close = dr <= b["steps"] * REWARD_ULP  # within one float32 ulp of 10 per step
        agree += same
        reward_agree += close
        rows.append({"seed": s, "lerobot_success": a["success"], "simseam_success": b["success"],
                     "lerobot_return": a["reward"], "simseam_return": b["reward"], "simseam_steps": b["steps"],
                     "return_abs_diff": dr, "same_success": same, "same_return": close})
    n = len(seeds)
    out = {"episodes": n, "success_agree": agree, "return_agree": reward_agree,
           "return_max_abs_diff": max(r["return_abs_diff"] for r in rows),
           "return_equal_1e-12": sum(r["return_abs_diff"] <= 1e-12 for r in rows), "per_seed": rows}
    for name, res in (("lerobot", le), ("simseam", ss)):
        k = sum(res[s]["success"] for s in seeds)
        lo, hi = wilson_interval(k, n)
        out[name] = {"successes": k, "success_rate": k / n, "wilson95": [round(lo, 4), round(hi, 4)]}
    a, b = out["lerobot"], out["simseam"]
    out["rates_inside_each_others_interval"] = bool(
        a["wilson95"][0] <= b["success_rate"] <= a["wilson95"][1]
        and b["wilson95"][0] <= a["success_rate"] <= b["wilson95"][1])
    return out


def finish(report: dict, work: Path, seeds: list[int], out_json: Path) -> None:
    """Compare on the seeds both evaluators finished; write the JSON and print the table."""
    le, repeated = read_lerobot(work)
    ss = read_simseam(work / "simseam_eval")
    both = [s for s in seeds if s in le and s in ss]
    if not both:
        raise SystemExit("no seed was run by both evaluators")
    report["lerobot_side"] = ("lerobot 0.4.4: per seed set_seed(seed), make_env(MetaworldEnv config, n_envs=1), "
                              "eval_policy_all(n_episodes=1, start_seed=seed, no videos): lerobot-eval --seed=<seed> "
                              "--eval.n_episodes=1 --eval.batch_size=1; rename_map " + json.dumps(RENAME))
    report["simseam_side"] = "simseam eval metaworld_lerobot --tasks <task> --seed <first> --episodes <n> --device cpu"
    report["seeds_compared"] = both
    report["seeds_not_run_by_lerobot"] = [s for s in seeds if s not in le]
    report["lerobot_seeds_run_twice"] = repeated
    report["comparison"] = compare(le, ss, both)
    simseam_all = [ss[s] for s in seeds if s in ss]
    if simseam_all:
        from simseam.runner.summary import wilson_interval

        k = sum(e["success"] for e in simseam_all)
        report["simseam_all_seeds"] = {"episodes": len(simseam_all), "successes": k,
                                       "wilson95": [round(x, 4) for x in wilson_interval(k, len(simseam_all))]}
    report["cli_check"] = []
    for d in sorted(work.glob("lerobot_cli_*")):
        info = d / "eval_info.json"
        if not info.exists():
            continue
        seed = int(d.name.rsplit("_", 1)[1])
        m = json.loads(info.read_text())["per_task"][0]["metrics"]
        r = {"seed": seed, "success": bool(m["successes"][0]), "return": m["sum_rewards"][0]}
        if seed in le:
            r["same_as_driver"] = r["success"] == le[seed]["success"] and r["return"] == le[seed]["reward"]
        if seed in ss:
            r["simseam_return"] = ss[seed]["reward"]
        report["cli_check"].append(r)
    out_json.parent.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps(report, indent=2) + "\n")

    c = report["comparison"]
    print(f"{report['task']}, seeds {both[0]}..{both[-1]} ({c['episodes']} episodes run by both)")
    print("| evaluator | successes | rate | Wilson 95 % |")
    print("|---|---:|---:|---|")
    for name, label in (("lerobot", "LeRobot (its env, set_seed, eval_policy_all)"), ("simseam", "simseam eval")):
        r = c[name]
        print(f"| {label} | {r['successes']}/{c['episodes']} | {r['success_rate']:.2f} | "
              f"[{r['wilson95'][0]:.2f}, {r['wilson95'][1]:.2f}] |")
    print(f"same success on {c['success_agree']}/{c['episodes']} seeds; return within one float32 ulp of 10 per "
          f"step on {c['return_agree']} (equal to 1e-12 on {c['return_equal_1e-12']}, largest difference "
          f"{c['return_max_abs_diff']:.2g}); "
          f"rates inside each other's interval: {c['rates_inside_each_others_interval']}")
    if repeated:
        print(f"LeRobot seeds run twice, same episode both times: {repeated}")
    for r in report["cli_check"]:
        print(f"lerobot-eval --seed={r['seed']}: success {r['success']}, return {r['return']!r} "
              f"(the driver's: {r.get('same_as_driver')}; simseam's return {r.get('simseam_return')!r})")
    print(f"json: {out_json}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="drawer-close-v3")
    ap.add_argument("--demos", type=int, default=30)
    ap.add_argument("--train-s", type=float, default=720.0, help="training wall-clock cap, seconds")
    ap.add_argument("--train-steps", type=int, default=3000)
    ap.add_argument("--seed", type=int, default=1000, help="first evaluation seed (lerobot-eval's default)")
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--lerobot-workers", type=int, default=2, help="processes for LeRobot's side (default 2)")
    ap.add_argument("--cli-check", type=int, default=2, help="run the lerobot-eval command for the first K seeds")
    ap.add_argument("--checkpoint", type=Path, default=None, help="a simseam-trained ACT (skips collect and train)")
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--compare-only", action="store_true",
                    help="compare what --work holds (the seeds both sides finished) without running anything")
    ap.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "metaworld_lerobot_eval.json")
    ap.add_argument("--lerobot-worker", nargs=2, metavar=("SEEDS", "OUT"), help=argparse.SUPPRESS)
    args = ap.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ.setdefault("MUJOCO_GL", "egl")
    os.environ["HF_HUB_OFFLINE"] = "1"
    if args.lerobot_worker:
        seeds = [int(s) for s in args.lerobot_worker[0].split(",")]
        lerobot_worker(args.checkpoint, args.task, seeds, Path(args.lerobot_worker[1]))
        return 0
    work = args.work or Path(tempfile.mkdtemp(prefix="metaworld_lerobot_"))
    work.mkdir(parents=True, exist_ok=True)
    log = work / "log.txt"
    seeds = list(range(args.seed, args.seed + args.episodes))
    report: dict = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                                "python": platform.python_version()},
                    "task": args.task, "seeds": f"{seeds[0]}:{seeds[-1] + 1}", "work": str(work)}
    ckpt = args.checkpoint.resolve() if args.checkpoint else None
    if ckpt is None and not args.compare_only:
        report["checkpoint"] = make_checkpoint(args.task, args.demos, args.train_s, args.train_steps, work, log)
        ckpt = Path(report["checkpoint"]["dir"])
    elif ckpt is not None:
        report["checkpoint"] = {"dir": str(ckpt)}
        if (ckpt / "training.json").is_file():  # made by simseam train: its data and budget
            t = json.loads((ckpt / "training.json").read_text())
            report["checkpoint"]["training"] = {
                "steps": t["steps"], "seconds": round(t["seconds"], 1), "n_params": t["n_params"],
                "episodes": t["episodes"], "frames": t["frames"], "config": t["config"],
                "final_loss": t["losses"][-1][1] if t["losses"] else None}
    if args.compare_only:
        finish(report, work, seeds, args.json)
        return 0
    serve = serve_480(ckpt, work / "act_480")
    site = lerobot_site()

    # LeRobot's side in the background (--lerobot-workers processes, the seeds dealt round-robin), simseam's
    # meanwhile
    workers = []
    with log.open("a") as f:
        for i in range(args.lerobot_workers):
            out = work / f"lerobot_episodes_{i}.jsonl"
            out.unlink(missing_ok=True)
            part = seeds[i:: args.lerobot_workers]
            workers.append(subprocess.Popen([sys.executable, __file__, "--lerobot-worker", ",".join(map(str, part)),
                                             str(out), "--task", args.task, "--checkpoint", str(serve)],
                                            stdout=f, stderr=subprocess.STDOUT, cwd=ROOT, env=lerobot_env(site)))
    t0 = time.perf_counter()
    run_logged([SIMSEAM, "eval", "metaworld_lerobot", "--tasks", args.task, "--policy", f"lerobot:{serve}", "--seed",
          str(args.seed), "--episodes", str(args.episodes), "--device", "cpu", "--out", str(work / "simseam_eval"),
          "--overwrite"], log)
    report["seconds"] = {"simseam_eval": round(time.perf_counter() - t0, 1)}
    for w in workers:
        if w.wait() != 0:
            raise SystemExit(f"LeRobot's evaluator exited {w.returncode}; its output is in {log}")
    report["seconds"]["lerobot"] = round(time.perf_counter() - t0, 1)
    for s in seeds[: args.cli_check]:
        lerobot_cli(serve, args.task, s, work, site, log)
    shutil.rmtree(site, ignore_errors=True)
    finish(report, work, seeds, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
