"""Meta-World: one trained policy per task on both engines (issue 37, fidelity (c)): the CPU backend (native
Meta-World on its pinned MuJoCo) against the MuJoCo Warp port, paired on the same held-out seeds.

    .venv/bin/python benchmarks/metaworld_warp_policy_agreement.py [--tasks reach-v3,...] [--seed 10000]
        [--episodes 20] [--sim-device cpu] [--work /tmp/mwp] [--json FILE] [--overwrite]

Per task:
1. the policy: ``benchmarks/metaworld_proof.py``'s recipe (Meta-World's expert, 200 ``variation: sampled``
   demonstrations on seeds 0-199 through ``simseam collect``, a state ACT from scratch through ``simseam
   train``); a checkpoint already in ``--work`` from that recipe (``<task>_act/training.json``) is reused;
2. ``simseam eval metaworld_mt50 --tasks <task> --policy lerobot:<ckpt> --seed S --episodes E`` on the CPU
   backend and with ``--engine mujoco_warp --sim-device D`` (MT1 variations ``seed % 50``, 500 steps);
3. the port on CPU MuJoCo of the port's version (``MetaWorldBatchRollout(engine="mujoco")``, one world, the
   same policy code, episode for episode as ``simseam eval`` runs them: 500 steps or success);
4. paired by seed (``simseam compare``'s statistics): success on both, the same success, the same step
   count, exact McNemar, the Newcombe interval of the difference; for three pairs: ``overall`` (the CPU
   backend vs Warp), ``version`` (the CPU backend, native Meta-World on its pinned MuJoCo 3.3, vs the port on
   CPU MuJoCo 4.0) and ``engine`` (the port on CPU MuJoCo 4.0 vs the port on Warp: the same MuJoCo version). Writes JSON after every task (one entry per task under ``tasks``); an existing file
is kept unless ``--overwrite``.
"""

from __future__ import annotations

import argparse
import json
import platform
from dataclasses import asdict
import sys
from pathlib import Path
from typing import Any

sys.path.insert(0, str(Path(__file__).resolve().parent))
import metaworld_proof as proof  # noqa: E402  (the recipe and its phases)

OUT = Path(__file__).resolve().parent / "results" / "metaworld_warp_policy_agreement_cpu.json"


def checkpoint(task: str, recipe: proof.Recipe, work: Path, train_s: float) -> tuple[Path, dict]:
    """The task's ACT checkpoint from the proof's recipe: reused when ``work`` has one, else collected and
    trained; returns it with its demonstrations' and training's facts."""
    ckpt, data = work / f"{task}_act", work / f"{task}_data"
    if not (ckpt / "training.json").exists():
        scene = work / f"{task}.yaml"
        scene.write_text(proof.scene_yaml(task))
        proof.collect_and_train(task, recipe, scene, data, ckpt, train_s, "cpu", work / f"{task}.log")
    training = json.loads((ckpt / "training.json").read_text())
    info = json.loads((data / "meta" / "info.json").read_text())
    return ckpt, {"demos": {"seeds": f"0:{recipe.demos}", "variation": "sampled", "episodes_kept": info["total_episodes"],
                            "frames": info["total_frames"]},
                  "training": {"steps": training["steps"], "seconds": round(training["seconds"], 1)}}


def evaluate(task: str, ckpt: Path, seed: int, episodes: int, out: Path, engine_args: list[str], log: Path,
             reuse: bool = False) -> dict:
    """One ``simseam eval`` of the checkpoint; its summary. ``reuse``: a finished run already in ``out`` of the
    same task and seeds is read instead of run again (``--reuse-cpu``: the CPU backend's runs, whose code the
    port's changes do not touch)."""
    done = out / "summary.json"
    if reuse and done.exists():
        summary = json.loads(done.read_text())
        if sorted(e["seed"] for e in summary["episodes"]) == list(range(seed, seed + episodes)) \
                and list(summary["per_task"]) == [task]:
            return summary
    proof._simseam("eval", "metaworld_mt50", "--tasks", task, "--policy", f"lerobot:{ckpt}", "--seed", str(seed),
                   "--episodes", str(episodes), "--out", str(out), "--overwrite", "--device", "cpu", *engine_args, log=log)
    return json.loads((out / "summary.json").read_text())


def port_cpu_episodes(task: str, ckpt: Path, seed: int, episodes: int, policy_spec: str | None = None) -> list[dict]:
    """The port on CPU MuJoCo (its version), one world, the policy as ``simseam eval`` builds it (``policy_spec``,
    default ``lerobot:<ckpt>``), its episodes run by ``simseam eval``'s scheduler (``run_batch``: 500 steps or
    success); per episode its seed, success (at any step) and steps (to success, else ``max_path_length``)."""
    from simseam.backends.metaworld_gpu.rollout import MetaWorldBatchRollout
    from simseam.backends.metaworld_gpu.worker import NativeWorker
    from simseam.policies.batch import make_policy_batch
    from simseam.runner.scheduler import run_batch

    config = {"task": task, "variation": "mt1", "max_steps": 500}
    spec = policy_spec or f"lerobot:{ckpt}"
    policy = make_policy_batch(spec, 1, **({"device": "cpu"} if spec.startswith("lerobot:") else {}))
    with NativeWorker() as worker, MetaWorldBatchRollout(config, 1, worker, engine="mujoco",
                                                         privileged=policy.requires_privileged) as batch:
        results = run_batch(batch, policy, range(episodes), seed=seed)
    policy.close()
    return [{"seed": r.seed, "success": r.success, "steps": r.steps} for r in sorted(results, key=lambda r: r.seed)]


def paired(first: list[dict], second: list[dict], names: tuple[str, str]) -> dict[str, Any]:
    """Two runs' episodes (seed, success, steps) paired by seed."""
    from simseam.runner.compare import mcnemar_exact, paired_difference_ci
    from simseam.runner.summary import wilson_interval as wilson

    a, b = {e["seed"]: e for e in first}, {e["seed"]: e for e in second}
    seeds = sorted(a)
    if seeds != sorted(b):
        raise SystemExit(f"the two runs hold different seeds: {seeds} vs {sorted(b)}")
    sa, sb = [bool(a[s]["success"]) for s in seeds], [bool(b[s]["success"]) for s in seeds]
    only_a = sum(x and not y for x, y in zip(sa, sb))
    only_b = sum(y and not x for x, y in zip(sa, sb))
    both = sum(x and y for x, y in zip(sa, sb))
    x, y = names
    return {x + "_success": sa, y + "_success": sb,
            x + "_steps": [a[s]["steps"] for s in seeds], y + "_steps": [b[s]["steps"] for s in seeds],
            x + "_rate_wilson95": wilson(sum(sa), len(seeds)), y + "_rate_wilson95": wilson(sum(sb), len(seeds)),
            "same_success": sum(p == q for p, q in zip(sa, sb)),
            "same_steps": sum(a[s]["steps"] == b[s]["steps"] for s in seeds),
            "mcnemar_p": mcnemar_exact(only_a, only_b),
            "difference_ci95": paired_difference_ci(both, only_a, only_b, len(seeds) - both - only_a - only_b)}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", default=",".join(proof.DEFAULT_TASKS))
    ap.add_argument("--seed", type=int, default=10000, help="first held-out evaluation seed")
    ap.add_argument("--episodes", type=int, default=20)
    ap.add_argument("--sim-device", default="cpu", help="the Warp device of the port (cpu here, cuda:0 on a GPU)")
    ap.add_argument("--train-s", type=float, default=240.0)
    ap.add_argument("--work", type=Path, default=Path("/tmp/mwp"))
    ap.add_argument("--json", type=Path, default=OUT)
    ap.add_argument("--overwrite", action="store_true")
    ap.add_argument("--reuse-cpu", action="store_true", help="read the CPU backend's finished eval runs in --work "
                    "(same task and seeds) instead of running them again")
    args = ap.parse_args()
    if args.json.exists() and not args.overwrite:
        print(f"{args.json} exists; pass --overwrite to replace it", file=sys.stderr)
        return 2
    recipe = proof.Recipe()
    if args.seed < recipe.demos:
        raise SystemExit(f"--seed {args.seed} overlaps the demonstration seeds 0:{recipe.demos}")
    args.work.mkdir(parents=True, exist_ok=True)
    doc: dict[str, Any] = {"benchmark": "metaworld_warp_policy_agreement", "recipe": asdict(recipe),
                           "sim_device": args.sim_device, "machine": {"python": platform.python_version(),
                                                                     "platform": platform.platform()}, "tasks": {}}
    for task in args.tasks.split(","):
        ckpt, facts = checkpoint(task, recipe, args.work, args.train_s)
        log = args.work / f"{task}.log"
        cpu = evaluate(task, ckpt, args.seed, args.episodes, args.work / f"{task}_eval", [], log, args.reuse_cpu)
        warp = evaluate(task, ckpt, args.seed, args.episodes, args.work / f"{task}_eval_warp",
                        ["--engine", "mujoco_warp", "--sim-device", args.sim_device], log)
        port = port_cpu_episodes(task, ckpt, args.seed, args.episodes)
        cpu, warp = cpu["episodes"], warp["episodes"]
        doc["tasks"][task] = row = {**facts, "seeds": sorted(e["seed"] for e in cpu),
                                    "overall": paired(cpu, warp, ("cpu_backend", "warp")),
                                    "version": paired(cpu, port, ("cpu_backend", "port_cpu")),
                                    "engine": paired(port, warp, ("port_cpu", "warp"))}
        o, v, e = row["overall"], row["version"], row["engine"]
        print(f"{task:24s} cpu backend {sum(o['cpu_backend_success'])}  port on CPU MuJoCo {sum(v['port_cpu_success'])}"
              f"  warp {sum(o['warp_success'])} /{args.episodes}   same success: version {v['same_success']} "
              f"engine {e['same_success']}   same steps: version {v['same_steps']} engine {e['same_steps']}  "
              f"McNemar p: version {v['mcnemar_p']:.3g} engine {e['mcnemar_p']:.3g}", flush=True)
        tmp = args.json.with_suffix(".partial")
        tmp.write_text(json.dumps(doc, indent=1))
        tmp.replace(args.json)
    return 0


if __name__ == "__main__":
    sys.exit(main())
