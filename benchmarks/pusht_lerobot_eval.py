"""The same number as LeRobot's own evaluator on PushT: one state-based ACT checkpoint, evaluated by the real
``lerobot-eval --env.type=pusht --env.obs_type=environment_state_agent_pos`` (offline, its gym-pusht env) and by
``simseam eval pusht`` on the same seeds, compared episode by episode.

    .venv/bin/python benchmarks/pusht_lerobot_eval.py [--demos 250] [--train-s 840] [--seed 1000]
        [--episodes 50] [--checkpoint DIR] [--work DIR] [--compare-only] [--json FILE]

What LeRobot's PushT env gives a policy (lerobot 0.4.4, ``PushtEnv`` config, obs_type
``environment_state_agent_pos``): ``observation.state``, the agent's position, and
``observation.environment_state``, the T's 8 keypoints flattened (16 floats), both float64 cast to float32;
300 steps (``TimeLimit``); the episode ends at ``is_success`` (coverage > 95 %). ``lerobot-eval --seed=S``
resets episode ``i`` with ``reset(seed=S + i)`` and gym-pusht draws the initial state from the env's own
seeded generator, so every episode is fixed by its seed. ``simseam eval pusht --seed S`` gives its episode
``i`` the same seed, and the pusht backend's ``environment_state`` is the same keypoints under the same
names (``observation.state``, ``observation.environment_state``): one checkpoint directory serves both, no
renaming. Both sides run batches of one (``--eval.batch_size=1``; ``--num-envs 1``) on the CPU.

The checkpoint is made through simseam (skipped with ``--checkpoint``):

1. ``simseam collect --policy scripted --no-cameras --action-noise 6`` from ``benchmark: {name: pusht}``,
   seeds ``0 .. demos-1``: simseam's PushT expert (``simseam.backends.pusht_expert``), its targets executed
   with 6 px of Gaussian noise (so the demonstrations show recoveries) and recorded clean, successes only;
2. ``simseam train``: ACT from scratch on the state (no VAE, chunks of ``--chunk`` 10 actions of which
   ``--n-action-steps`` 2 are executed, dim 64, one encoder and one decoder layer, 0.12 M parameters,
   batch 64, cosine from 5e-4 over ``--train-steps``), within ``--train-s`` seconds.

The baseline, measured in the same run (``--no-expert`` skips it): the demonstrations' expert, ``simseam eval pusht
--policy scripted``, on the same seeds. Compared per seed: success, and the return (LeRobot's ``sum_reward``, the sum of
``clip(coverage / 0.95, 0, 1)``) to 1e-9 (``RETURN_TOL``); LeRobot's ``max_reward`` is reported beside
simseam's last coverage. The returns differ only in summation order: LeRobot sums an episode's float64
rewards with torch (``einops.reduce``), simseam adds them one by one; summed one by one, LeRobot's own rewards
give simseam's return to the last bit (traced on seed 1000, docs/benchmarks.md). LeRobot's interpreter needs gym-pusht and its dependencies, which the main venv
does not have: they are linked from the pusht backend's venv into a temporary site directory first on its
path. Every process runs with ``OMP_NUM_THREADS=1``. Prints a table, writes JSON (default
``benchmarks/results/pusht_lerobot_eval.json``).
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

from metaworld_lerobot_eval import run_logged  # benchmarks/ is the script's directory

ROOT = Path(__file__).resolve().parents[1]
SIMSEAM = str(Path(sys.executable).with_name("simseam"))
#: gym-pusht 0.1.8 and what it imports that the main venv lacks (the pusht backend venv has them all)
PUSHT_PACKAGES = ("gym_pusht", "pymunk", "pygame", "pygame.libs", "shapely", "shapely.libs", "cffi", "pycparser")
#: sums of at most 300 rewards in [0, 1], float64 on both sides, in different orders (torch's sum, Python's +=)
RETURN_TOL = 1e-9


def make_checkpoint(args, work: Path, log: Path) -> dict:
    scene = work / "scene_demos.yaml"
    scene.write_text("# simseam's PushT expert (benchmarks/pusht_lerobot_eval.py)\nbenchmark: {name: pusht}\n")
    data, ckpt = work / "demos", work / "act"
    collect_s = run_logged([SIMSEAM, "collect", "--scene", str(scene), "--policy", "scripted", "--episodes",
                      str(args.demos), "--seed", "0", "--no-cameras", "--action-noise", str(args.action_noise),
                      "--out", str(data), "--overwrite"], log)
    train_s_wall = run_logged([SIMSEAM, "train", "--dataset", str(data), "--out", str(ckpt), "--overwrite", "--cache",
                         "--workers", "0", "--device", "cpu", "--no-vae", "--steps", str(args.train_steps),
                         "--time-budget-s", str(args.train_s), "--batch-size", "64", "--lr", "5e-4",
                         "--lr-schedule", "cosine", "--chunk-size", str(args.chunk), "--n-action-steps",
                         str(args.n_action_steps), "--dim-model", "64", "--ff-dim", "256", "--encoder-layers", "1"],
                        log)
    info = json.loads((data / "meta" / "info.json").read_text())
    return {"dir": str(ckpt), "demos": {"seeds": f"0:{args.demos}", "action_noise_px": args.action_noise,
                                        "episodes_kept": info["total_episodes"],
                                        "frames": info["total_frames"], "seconds": round(collect_s, 1)},
            "training": {**training_facts(ckpt), "wall_seconds": round(train_s_wall, 1)}}


def training_facts(ckpt: Path) -> dict:
    t = json.loads((ckpt / "training.json").read_text())
    return {"steps": t["steps"], "seconds": round(t["seconds"], 1), "n_params": t["n_params"],
            "episodes": t.get("episodes"), "frames": t.get("frames"), "config": t.get("config"),
            "final_loss": t["losses"][-1][1] if t["losses"] else None}


def pusht_site() -> Path:
    """gym-pusht and its dependencies from the pusht backend venv, for LeRobot's interpreter."""
    from simseam.backends.provision import venv_dir

    found = list((venv_dir("pusht") / "lib").glob("python*/site-packages"))
    if not found or not (found[0] / "gym_pusht").is_dir():
        raise SystemExit("the pusht backend is not provisioned: `simseam backends provision pusht`")
    site = Path(tempfile.mkdtemp(prefix="pusht-lerobot-site-"))
    for path in [found[0] / p for p in PUSHT_PACKAGES] + list(found[0].glob("_cffi_backend*.so")):
        (site / path.name).symlink_to(path)
    return site


def lerobot_env(site: Path) -> dict:
    return dict(os.environ, HF_HUB_OFFLINE="1", PYTHONPATH=os.pathsep.join(
        filter(None, [str(site), os.environ.get("PYTHONPATH")])))


def lerobot_argv(ckpt: Path, seed: int, episodes: int, out: Path) -> list[str]:
    """The ``lerobot-eval`` command (its console script's module, this interpreter)."""
    return [sys.executable, "-m", "lerobot.scripts.lerobot_eval", f"--policy.path={ckpt}", "--env.type=pusht",
            "--env.obs_type=environment_state_agent_pos", f"--eval.n_episodes={episodes}", "--eval.batch_size=1",
            "--policy.device=cpu", f"--seed={seed}", f"--output_dir={out}"]


def read_lerobot(out: Path, seed: int) -> dict[int, dict]:
    m = json.loads((out / "eval_info.json").read_text())["per_task"][0]["metrics"]
    return {seed + i: {"success": bool(s), "reward": r, "max_reward": mr}
            for i, (s, r, mr) in enumerate(zip(m["successes"], m["sum_rewards"], m["max_rewards"]))}


def read_simseam(run: Path) -> dict[int, dict]:
    lines = (run / "episodes.jsonl").read_text().splitlines() if (run / "episodes.jsonl").exists() else []
    return {e["seed"]: e for e in map(json.loads, filter(str.strip, lines)) if not e.get("error")}


def compare(le: dict[int, dict], ss: dict[int, dict], seeds: list[int]) -> dict:
    from simseam.runner.summary import wilson_interval

    rows = []
    for s in seeds:
        a, b = le[s], ss[s]
        dr = abs(a["reward"] - b["reward"])
        rows.append({"seed": s, "lerobot_success": a["success"], "simseam_success": b["success"],
                     "lerobot_return": a["reward"], "simseam_return": b["reward"], "simseam_steps": b["steps"],
                     "lerobot_max_reward": a["max_reward"],
                     "simseam_last_coverage": b["diagnostics"].get("coverage"), "return_abs_diff": dr,
                     "same_success": a["success"] == b["success"], "same_return": dr <= RETURN_TOL})
    n = len(seeds)
    out = {"episodes": n, "success_agree": sum(r["same_success"] for r in rows),
           "return_agree": sum(r["same_return"] for r in rows),
           "return_equal": sum(r["return_abs_diff"] == 0.0 for r in rows),
           "return_max_abs_diff": max(r["return_abs_diff"] for r in rows), "per_seed": rows}
    for name, res in (("lerobot", le), ("simseam", ss)):
        k = sum(res[s]["success"] for s in seeds)
        lo, hi = wilson_interval(k, n)
        out[name] = {"successes": k, "success_rate": k / n, "wilson95": [round(lo, 4), round(hi, 4)]}
    a, b = out["lerobot"], out["simseam"]
    out["rates_inside_each_others_interval"] = bool(
        a["wilson95"][0] <= b["success_rate"] <= a["wilson95"][1]
        and b["wilson95"][0] <= a["success_rate"] <= b["wilson95"][1])
    return out


def finish(report: dict, work: Path, seed: int, seeds: list[int], out_json: Path) -> None:
    le = read_lerobot(work / "lerobot_eval", seed)
    ss = read_simseam(work / "simseam_eval")
    both = [s for s in seeds if s in le and s in ss]
    if not both:
        raise SystemExit("no seed was run by both evaluators")
    report["lerobot_side"] = " ".join(lerobot_argv(Path("<checkpoint>"), seed, len(seeds), Path("<out>"))[1:])
    report["simseam_side"] = (f"simseam eval pusht --policy lerobot:<checkpoint> --seed {seed} --episodes "
                              f"{len(seeds)} --device cpu --num-envs 1")
    report["seeds_compared"] = [both[0], both[-1] + 1] if both == list(range(both[0], both[-1] + 1)) else both
    report["comparison"] = c = compare(le, ss, both)
    expert = read_simseam(work / "expert_eval")
    if expert:
        from simseam.runner.summary import wilson_interval

        k, n = sum(e["success"] for e in expert.values()), len(expert)
        report["expert_baseline"] = {"policy": "simseam eval pusht --policy scripted (the demonstrations' expert)",
                                     "episodes": n, "successes": k,
                                     "wilson95": [round(x, 4) for x in wilson_interval(k, n)],
                                     "mean_steps": round(sum(e["steps"] for e in expert.values()) / n, 1)}
    out_json.parent.mkdir(parents=True, exist_ok=True)
    out_json.write_text(json.dumps(report, indent=2) + "\n")

    print(f"PushT, seeds {both[0]}..{both[-1]} ({c['episodes']} episodes run by both)")
    print("| evaluator | successes | rate | Wilson 95 % |")
    print("|---|---:|---:|---|")
    for name, label in (("lerobot", "lerobot-eval --env.type=pusht"), ("simseam", "simseam eval pusht")):
        r = c[name]
        print(f"| {label} | {r['successes']}/{c['episodes']} | {r['success_rate']:.2f} | "
              f"[{r['wilson95'][0]:.2f}, {r['wilson95'][1]:.2f}] |")
    if "expert_baseline" in report:
        e = report["expert_baseline"]
        print(f"| simseam's expert (baseline) | {e['successes']}/{e['episodes']} | {e['successes'] / e['episodes']:.2f} "
              f"| [{e['wilson95'][0]:.2f}, {e['wilson95'][1]:.2f}] |")
    print(f"same success on {c['success_agree']}/{c['episodes']} seeds; return within {RETURN_TOL:g} on "
          f"{c['return_agree']} (bit-equal on {c['return_equal']}, largest difference "
          f"{c['return_max_abs_diff']:.3g}); rates inside each other's interval: "
          f"{c['rates_inside_each_others_interval']}")
    print("| seed | LeRobot success | simseam success | LeRobot return | simseam return | steps | "
          "LeRobot max reward | simseam last coverage |")
    print("|---:|---|---|---:|---:|---:|---:|---:|")
    for r in c["per_seed"]:
        print(f"| {r['seed']} | {r['lerobot_success']} | {r['simseam_success']} | {r['lerobot_return']:.6f} | "
              f"{r['simseam_return']:.6f} | {r['simseam_steps']} | {r['lerobot_max_reward']:.4f} | "
              f"{r['simseam_last_coverage']:.4f} |")
    print(f"json: {out_json}")


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--demos", type=int, default=250)
    ap.add_argument("--action-noise", type=float, default=6.0,
                    help="px of Gaussian noise on the executed actions while collecting (the expert's own recorded)")
    ap.add_argument("--train-s", type=float, default=840.0, help="training wall-clock cap, seconds")
    ap.add_argument("--train-steps", type=int, default=22000)
    ap.add_argument("--chunk", type=int, default=10)
    ap.add_argument("--n-action-steps", type=int, default=2)
    ap.add_argument("--seed", type=int, default=1000, help="first evaluation seed (lerobot-eval's default)")
    ap.add_argument("--episodes", type=int, default=50)
    ap.add_argument("--no-expert", dest="expert", action="store_false",
                    help="skip the baseline: simseam's PushT expert on the same seeds")
    ap.add_argument("--checkpoint", type=Path, default=None, help="a simseam-trained ACT (skips collect and train)")
    ap.add_argument("--work", type=Path, default=None)
    ap.add_argument("--compare-only", action="store_true", help="compare what --work holds without running")
    ap.add_argument("--json", type=Path, default=ROOT / "benchmarks" / "results" / "pusht_lerobot_eval.json")
    args = ap.parse_args()
    os.environ.setdefault("OMP_NUM_THREADS", "1")
    os.environ["HF_HUB_OFFLINE"] = "1"
    work = args.work or Path(tempfile.mkdtemp(prefix="pusht_lerobot_"))
    work.mkdir(parents=True, exist_ok=True)
    log = work / "log.txt"
    seeds = list(range(args.seed, args.seed + args.episodes))
    report: dict = {"machine": {"cpus": os.cpu_count(), "platform": platform.platform(),
                                "python": platform.python_version()},
                    "seeds": f"{seeds[0]}:{seeds[-1] + 1}", "work": str(work)}
    ckpt = args.checkpoint.resolve() if args.checkpoint else None
    if ckpt is None and not args.compare_only:
        report["checkpoint"] = make_checkpoint(args, work, log)
        ckpt = Path(report["checkpoint"]["dir"])
    elif ckpt is not None:
        report["checkpoint"] = {"dir": str(ckpt)}
        if (ckpt / "training.json").is_file():
            report["checkpoint"]["training"] = training_facts(ckpt)
    if not args.compare_only:
        site = pusht_site()
        out = work / "lerobot_eval"
        shutil.rmtree(out, ignore_errors=True)
        t0 = time.perf_counter()
        with log.open("a") as f:  # LeRobot's evaluator in the background, simseam's meanwhile
            argv = lerobot_argv(ckpt, args.seed, args.episodes, out)
            f.write(f"$ {' '.join(argv)}\n")
            f.flush()
            lerobot = subprocess.Popen(argv, stdout=f, stderr=subprocess.STDOUT, cwd=ROOT, env=lerobot_env(site))
        try:
            run_logged([SIMSEAM, "eval", "pusht", "--policy", f"lerobot:{ckpt}", "--seed", str(args.seed), "--episodes",
                  str(args.episodes), "--device", "cpu", "--num-envs", "1", "--out", str(work / "simseam_eval"),
                  "--overwrite"], log)
            report["seconds"] = {"simseam_eval": round(time.perf_counter() - t0, 1)}
        finally:
            rc = lerobot.wait()
            shutil.rmtree(site, ignore_errors=True)
        if rc != 0:
            raise SystemExit(f"lerobot-eval exited {rc}; its output is in {log}")
        report["seconds"]["lerobot_eval"] = round(time.perf_counter() - t0, 1)
        if args.expert:
            report["seconds"]["expert_eval"] = round(run_logged(
                [SIMSEAM, "eval", "pusht", "--policy", "scripted", "--seed", str(args.seed), "--episodes",
                 str(args.episodes), "--out", str(work / "expert_eval"), "--overwrite"], log), 1)
    finish(report, work, args.seed, seeds, args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
