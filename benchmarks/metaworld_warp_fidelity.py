"""Meta-World on MuJoCo Warp: fidelity against CPU MuJoCo of the same version (engine gap) and against the
native env on its pinned MuJoCo (version gap), per task, paired on the same seeds.

Per task and seed (MT1 variation ``seed % 50``, as ``simseam eval metaworld_*``):
- native: Meta-World's scripted expert (``metaworld.policies``) in the native env, ``--steps`` steps;
- Warp (all seeds as one batch of worlds) and CPU MuJoCo 4.0 (one world per seed): the same expert closed
  loop; the expert runs in Meta-World's venv, asked once per step for every world's action through one
  native worker (its policies are functions of the observation), so it is Meta-World's own code, unported;
- state divergence under the same actions: the native episode's actions replayed open loop on Warp and on
  CPU MuJoCo 4.0; per step, the largest gap of the 39-D observation: Warp vs CPU (engine) and CPU vs native
  (version); median and worst over steps and seeds.

Success on Warp and CPU is Meta-World's rule written once over the batched state
(``backends/metaworld_gpu/rewards.py``, called by ``MetaWorldBatch.step``), at any step, with the expert's
actions cast to float32 as ``simseam eval`` passes them. McNemar's exact test per task on the paired successes (Warp vs CPU; CPU vs native), Holm's correction
across tasks. Prints a table; writes ``benchmarks/results/metaworld_warp_fidelity.json`` (one entry per
task under ``tasks``); an existing file is kept unless ``--overwrite``.

    python benchmarks/metaworld_warp_fidelity.py --tasks reach-v3,pick-place-v3 --seeds 0:5 --steps 150 --device cpu
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path
from typing import Any

import numpy as np

OUT = Path(__file__).resolve().parent / "results" / "metaworld_warp_fidelity.json"


def mcnemar(a: list[bool], b: list[bool]) -> float:
    """Two-sided exact McNemar p on paired outcomes (``runner.compare``'s test, as ``simseam compare``)."""
    from simseam.runner.compare import mcnemar_exact

    return mcnemar_exact(sum(1 for x, y in zip(a, b) if x and not y), sum(1 for x, y in zip(a, b) if y and not x))


def closed_loop(worker, task: str, engine: str, seeds: list[int], steps: int, device: str | None) -> list[bool]:
    """The expert driving ``engine`` (Warp: all seeds as one batch of worlds; CPU MuJoCo: one world per
    seed, stepped in lockstep), its actions asked once per step for every world; per seed: success at any
    step (Meta-World's batched rule)."""
    envs = _batches(worker, task, engine, seeds, device)
    success = np.zeros(len(seeds), dtype=bool)
    for _ in range(steps):
        obs = np.concatenate([np.asarray(_host(env.obs), dtype=np.float64) for env in envs])
        actions = np.asarray(worker.call("expert", task=task, obs=obs), dtype=np.float32)
        success |= np.concatenate([env.step(actions[i:i + env.num_worlds])["success"]
                                   for i, env in zip(_offsets(envs), envs)])
    for env in envs:
        env.close()
    return success.tolist()


def _batches(worker, task: str, engine: str, seeds: list[int], device: str | None) -> list[Any]:
    """Warp: one batch of len(seeds) worlds; CPU MuJoCo: one single-world batch per seed; each reset."""
    from simseam.backends.metaworld_gpu.env import MetaWorldBatch

    groups = [seeds] if engine == "mujoco_warp" else [[s] for s in seeds]
    envs = []
    for group in groups:
        env = MetaWorldBatch(task, len(group), worker, engine=engine, device=device)
        env.reset(list(range(len(group))), group)
        envs.append(env)
    return envs


def _offsets(envs: list[Any]) -> list[int]:
    return list(np.cumsum([0] + [env.num_worlds for env in envs[:-1]]))


def open_loop(worker, task: str, engine: str, seeds: list[int], actions: np.ndarray, device: str | None) -> np.ndarray:
    """float[S, T, 39]: the observations under the native episodes' actions (float[S, T, 4])."""
    envs = _batches(worker, task, engine, seeds, device)
    out = []
    for t in range(actions.shape[1]):
        for i, env in zip(_offsets(envs), envs):
            env.step(actions[i:i + env.num_worlds, t])
        out.append(np.concatenate([np.asarray(_host(env.obs), dtype=np.float64) for env in envs]))
    for env in envs:
        env.close()
    return np.stack(out, axis=1)


def _host(a: Any) -> np.ndarray:
    return a.get() if hasattr(a, "get") else np.asarray(a)


def one_task(worker, task: str, seeds: list[int], steps: int, device: str | None) -> dict[str, Any]:
    t0 = time.perf_counter()
    native = [worker.call("replay", task=task, variation="mt1", goal_seed=0, seed=s, actions=None, steps=steps)
              for s in seeds]
    native_success = [bool(np.any(r["success"])) for r in native]
    actions = np.stack([r["action"] for r in native])
    warp_obs = open_loop(worker, task, "mujoco_warp", seeds, actions, device)
    cpu_obs = open_loop(worker, task, "mujoco", seeds, actions, None)
    engine_gap = np.abs(warp_obs - cpu_obs).max(axis=2)
    version_gap = np.abs(cpu_obs - np.stack([r["obs"] for r in native])).max(axis=2)
    warp_success = closed_loop(worker, task, "mujoco_warp", seeds, steps, device)
    cpu_success = closed_loop(worker, task, "mujoco", seeds, steps, None)
    judged = all(x is not None for x in warp_success + cpu_success)
    return {
        "seeds": seeds, "steps": steps, "native_success": native_success,
        "warp_success": warp_success, "cpu_success": cpu_success, "success_judged": judged,
        "engine_gap": {"median": float(np.median(engine_gap)), "worst": float(engine_gap.max())},
        "version_gap": {"median": float(np.median(version_gap)), "worst": float(version_gap.max())},
        "p_engine": mcnemar(warp_success, cpu_success) if judged else None,
        "p_version": mcnemar(cpu_success, native_success) if judged else None,
        "seconds": round(time.perf_counter() - t0, 1),
    }


def write(args, results: dict[str, Any], final: bool = True) -> None:
    """The JSON (atomically): Holm's correction across the tasks done so far; ``complete`` once every task
    asked for ran with success judged."""
    from simseam.runner.compare import holm

    for key in ("p_engine", "p_version"):
        tasks = [t for t, r in results.items() if r[key] is not None]
        for t, p in zip(tasks, holm([results[t][key] for t in tasks])):
            results[t][key + "_holm"] = p
    doc = {"benchmark": "metaworld_warp_fidelity", "device": args.device, "seeds": args.seeds, "steps": args.steps,
           "complete": final and all(r["success_judged"] for r in results.values()), "tasks": results}
    args.out.parent.mkdir(parents=True, exist_ok=True)
    tmp = args.out.with_suffix(".partial")
    tmp.write_text(json.dumps(doc, indent=1))
    tmp.replace(args.out)


def run_jobs(args, tasks: list[str]) -> dict[str, Any]:
    """``--jobs J``: J copies of this script, job j taking tasks j, j + J, ...; each writes its own part
    (every finished task on disk); their tasks merged in the order asked."""
    import subprocess

    parts = args.out.with_suffix(".parts")
    parts.mkdir(parents=True, exist_ok=True)
    if not args.resume:  # --overwrite: an earlier run's parts are not this run's
        for stale in parts.glob("part*.json"):
            stale.unlink()
    done = _finished(args)
    todo = [t for t in tasks if t not in done]
    first = next_part(parts)  # a resumed run's parts come after the kept ones
    procs = []
    for j in range(min(args.jobs, len(todo))):
        argv = [sys.executable, __file__, "--tasks", ",".join(todo[j::args.jobs]), "--seeds", args.seeds,
                "--steps", str(args.steps), "--out", str(parts / f"part{first + j}.json"), "--overwrite"]
        procs.append(subprocess.Popen(argv + (["--device", args.device] if args.device else [])))
    failed = [p.args[3] for p in procs if p.wait() != 0]
    merged = {**done, **_parts(parts)}
    if failed:
        print(f"jobs failed for tasks {failed}; their finished tasks are kept", file=sys.stderr)
    return {t: merged[t] for t in tasks if t in merged}


def next_part(parts: Path) -> int:
    """The first part number after every kept part's (not their count: a job cut off before its first task
    left no part, and a count would reuse, and overwrite, a kept part's number)."""
    numbers = [int(p.stem[4:]) for p in parts.glob("part*.json") if p.stem[4:].isdigit()]
    return max(numbers, default=-1) + 1


def _parts(parts: Path) -> dict[str, Any]:
    merged: dict[str, Any] = {}
    for part in sorted(parts.glob("part*.json")):
        merged.update(json.loads(part.read_text())["tasks"])
    return merged


def _finished(args) -> dict[str, Any]:
    """``--resume``: the tasks already on disk (the output and, with ``--jobs``, its parts) for the same
    seeds, steps and device; they are kept and not run again."""
    if not args.resume:
        return {}
    found = {}
    if args.out.exists():
        doc = json.loads(args.out.read_text())
        if (doc["seeds"], doc["steps"], doc["device"]) != (args.seeds, args.steps, args.device):
            raise SystemExit(f"{args.out}: made with seeds {doc['seeds']}, steps {doc['steps']}, device "
                             f"{doc['device']}; --resume needs the same")
        found.update(doc["tasks"])
    parts = args.out.with_suffix(".parts")
    if parts.is_dir():
        for part in sorted(parts.glob("part*.json")):
            doc = json.loads(part.read_text())
            if (doc["seeds"], doc["steps"], doc["device"]) == (args.seeds, args.steps, args.device):
                found.update(doc["tasks"])
    return found


def merge(args) -> int:
    """``--merge``: the tasks a run left in ``--out`` and its parts (another machine's, say), in the order asked,
    written as one document, ``complete`` only if every task asked for is there; nothing runs."""
    args.resume = True
    found = _finished(args)
    tasks = _tasks(args.tasks)
    results = {t: found[t] for t in tasks if t in found}
    write(args, results, final=len(results) == len(tasks))
    missing = [t for t in tasks if t not in results]
    print(f"wrote {args.out}: {len(results)} of {len(tasks)} tasks" + (f"; missing {', '.join(missing)}" if missing else ""))
    return 0


def _tasks(text: str) -> list[str]:
    """``--tasks``: comma-separated names, or ``mt50`` for every task of the port."""
    from simseam.backends.metaworld_gpu.tasks import OBJECTS

    return sorted(OBJECTS) if text == "mt50" else text.split(",")


def _seeds(text: str) -> list[int]:
    lo, hi = (int(x) for x in text.split(":"))
    return list(range(lo, hi))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", required=True, help="comma-separated Meta-World v3 tasks, or 'mt50'")
    ap.add_argument("--seeds", default="0:50", help="lo:hi (MT1 variations seed %% 50)")
    ap.add_argument("--steps", type=int, default=500)
    ap.add_argument("--device", default=None, help="a Warp device (cuda:0, cpu); default Warp's preferred one")
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--overwrite", action="store_true")
    ap.add_argument("--resume", action="store_true",
                    help="keep the tasks already in --out (and its .parts/) for the same seeds, steps and device; run the rest")
    ap.add_argument("--jobs", type=int, default=1,
                    help="processes, each taking every J-th task with its own native worker (merged at the end)")
    ap.add_argument("--merge", action="store_true",
                    help="run nothing: write --out from the tasks in it and its .parts/ (same seeds, steps and device)")
    args = ap.parse_args(argv)
    if args.merge:
        return merge(args)
    if args.out.exists() and not (args.overwrite or args.resume):
        print(f"{args.out} exists; pass --overwrite to replace it or --resume to finish it", file=sys.stderr)
        return 2
    from simseam.backends.metaworld_gpu.worker import NativeWorker

    tasks = _tasks(args.tasks)
    seeds = _seeds(args.seeds)
    results: dict[str, Any] = _finished(args) if args.jobs <= 1 else {}
    if args.jobs > 1:
        results = run_jobs(args, tasks)
        write(args, results, final=len(results) == len(tasks))
        print(f"wrote {args.out}")
        return 0 if len(results) == len(tasks) else 1
    with NativeWorker() as worker:
        for task in [t for t in tasks if t not in results]:
            results[task] = one_task(worker, task, seeds, args.steps, args.device)
            r = results[task]
            print(f"{task:28s} success native {sum(r['native_success'])} cpu {sum(r['cpu_success'])} "
                  f"warp {sum(r['warp_success'])} /{len(seeds)}  "
                  f"engine gap med {r['engine_gap']['median']:.1e} worst {r['engine_gap']['worst']:.1e}  "
                  f"version gap med {r['version_gap']['median']:.1e} worst {r['version_gap']['worst']:.1e}  "
                  f"({r['seconds']} s)", flush=True)
            write(args, results, final=False)  # every finished task is on disk
    write(args, results)
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
