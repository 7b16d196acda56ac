"""LIBERO's scripted expert (or another policy) on MuJoCo Warp (Warp's CPU device here) against the CPU benchmark,
paired per init state.

    .venv/bin/python benchmarks/libero_warp_expert.py [--tasks libero_spatial/0,libero_spatial/1]
        [--init-states 10:15] [--num-envs 5] [--sim-device cpu] [--work DIR] [--json PATH]
        [--policy 'lerobot:CKPTS/{suite}_{index}_act']   # one checkpoint per task: {suite}, {index} filled in
        [--port-cpu]   # a third side: the port's code on CPU MuJoCo (engine gap vs version gap)
    .venv/bin/python benchmarks/libero_warp_expert.py --merge A.json B.json --json PATH   # runs of other tasks
    .venv/bin/python benchmarks/libero_warp_expert.py --from-runs --cpu-runs DIR ... --warp-runs DIR ... \
        --init-states 10:30 --sim-device cuda:0 --json PATH   # pairs runs made elsewhere (a GPU machine); runs nothing

For each task runs the command a user runs twice on the same episodes (episode ``e`` starts from LIBERO's init
state ``A + e``, the same fixture placement):

- ``simseam eval SUITE --policy P --tasks T --seed A --episodes B-A`` (``P``: ``scripted`` by default) (the ``libero`` backend: LIBERO
  itself in its venv behind the sidecar, LIBERO's success check);
- the same with ``--engine mujoco_warp --sim-device DEV --num-envs N`` (``backends/libero_gpu``: the episodes as
  the worlds of one batch, robosuite's controller and LIBERO's goal predicates batched, one expert per world).

With ``--port-cpu``, a third side: the port's own code on CPU MuJoCo of the port's version (``engine="mujoco"``:
one world, float64, in this process, the policy as ``simseam eval`` builds it, episode for episode as ``simseam
eval`` runs them: the step limit or success), and two more pairings per task: ``version`` (the CPU benchmark,
LIBERO on its own MuJoCo, against the port on CPU MuJoCo: what the port's code and the MuJoCo version change) and
``engine`` (the port on CPU MuJoCo against the port on MuJoCo Warp: the same MuJoCo version, what the engine
changes). Its episodes go to ``WORK/port-cpu-TASK/episodes.jsonl`` as they finish (a run cut off resumes).

``--from-runs`` pairs the episodes of run directories made elsewhere (``simseam eval`` of whole suites, say the
CPU benchmark here and ``--engine mujoco_warp --sim-device cuda:0`` on a GPU machine, or ``simseam run --scene``
of one task, e.g. an image policy on a scene of its cameras' size): every task whose episodes for init states
A..B-1 are all in both sides, by seed; a task one side has not finished is listed as left out.

Prints one row per task (successes on each engine, the init states where they disagree, the mean steps of the
episodes both engines solved, exact McNemar p over the discordant pairs) and writes JSON (default
benchmarks/results/libero_warp_expert.json). ``--work DIR`` keeps the run directories; a run already there is
resumed. The JSON records each task's revisions (both sides) and wall seconds (summed over the calls that ran
it; null for a run finished before this script recorded them). Nothing is asserted. Slow on Warp's CPU device (about 1 s per control step of a 5-world batch on the
2-core machine): run it niced, in the background.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

from simseam.runner.compare import mcnemar_exact

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
STEPS = {"libero_spatial": 220, "libero_object": 280}  # the eval presets' step limits (openpi's)


def run_eval(task: str, first: int, count: int, out: Path, warp: dict | None, policy: str = "scripted") -> float | None:
    """Run (or resume) one eval; its wall seconds, summed over the calls that ran it (``out/wall_seconds``), or
    None for a run an earlier version of this script finished without recording them."""
    suite, _, index = task.partition("/")
    cmd = [sys.executable, "-m", "simseam.cli.main", "eval", suite, "--policy", policy.format(suite=suite, index=index),
           "--tasks", task,
           "--seed", str(first), "--episodes", str(count), "--out", str(out)]
    if warp is not None:
        cmd += ["--engine", "mujoco_warp", "--sim-device", warp["device"], "--num-envs", str(warp["num_envs"])]
    if (out / "run.json").exists():
        cmd.append("--resume")
    resumed = (out / "run.json").exists()
    record = out / "wall_seconds"
    before = float(record.read_text()) if record.exists() else (None if resumed else 0.0)
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=REPO, check=True, env=dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl")))
    if before is None:
        return None
    total = before + time.perf_counter() - t0
    record.write_text(f"{total:.1f}\n")
    return total


def port_cpu_run(task: str, first: int, count: int, out: Path, policy_spec: str) -> float:
    """The port on CPU MuJoCo (one world) for episodes ``first`` .. ``first + count - 1`` of ``task``, run by the
    scheduler ``simseam eval`` uses (``run_batch``: episode ``i`` gets seed ``first + i``); each finished episode
    appended to ``out/episodes.jsonl`` (seed, success, steps), those already there skipped;
    returns this call's wall seconds."""
    from simseam.backends.libero_gpu.rollout import LiberoBatchRollout
    from simseam.backends.libero_gpu.worker import NativeWorker
    from simseam.policies.batch import make_policy_batch
    from simseam.runner.job import reads_environment_state
    from simseam.runner.scheduler import run_batch

    suite, _, index = task.partition("/")
    out.mkdir(parents=True, exist_ok=True)
    done = episodes(out) if (out / "episodes.jsonl").exists() else {}
    todo = [s for s in range(first, first + count) if s not in done]
    t0 = time.perf_counter()
    if not todo:
        return 0.0
    spec = policy_spec.format(suite=suite, index=index)
    policy = make_policy_batch(spec, 1, **({"device": "cpu"} if spec.startswith("lerobot:") else {}))
    config = {"suite": suite, "task": int(index), "max_steps": STEPS[suite], "settle_steps": 10,
              "environment_state": reads_environment_state(policy)}

    def write(result) -> None:  # each finished episode kept at once (a run cut off resumes)
        with (out / "episodes.jsonl").open("a") as f:
            f.write(json.dumps({"seed": result.seed, "success": result.success, "steps": result.steps,
                                **({"error": result.error} if result.error else {})}) + "\n")

    with NativeWorker() as worker, \
            LiberoBatchRollout(config, 1, worker, privileged=policy.requires_privileged, engine="mujoco") as batch:
        run_batch(batch, policy, [s - first for s in todo], seed=first, on_done=write, keep=False)
    policy.close()
    return time.perf_counter() - t0


def revision(out: Path) -> dict:
    return json.loads((out / "run.json").read_text())["provenance"]["simseam"]["revision"]


def revisions_now() -> dict:
    """This checkout's commit and whether it has changes (the in-process side's revision)."""
    head = subprocess.run(["git", "rev-parse", "HEAD"], cwd=REPO, capture_output=True, text=True).stdout.strip()
    dirty = bool(subprocess.run(["git", "status", "--porcelain", "--", "src"], cwd=REPO, capture_output=True,
                                text=True).stdout.strip())
    return {"commit": head, "dirty": dirty}


def episodes(out: Path) -> dict[int, dict]:
    lines = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines() if line.strip()]
    return {e["seed"]: e for e in lines}


def paired(cpu: dict[int, dict], warp: dict[int, dict]) -> dict:
    seeds = sorted(cpu)
    if sorted(warp) != seeds:
        raise SystemExit(f"the engines ran different episodes: CPU {seeds}, Warp {sorted(warp)}")
    both = [s for s in seeds if cpu[s]["success"] and warp[s]["success"]]
    only_cpu = [s for s in seeds if cpu[s]["success"] and not warp[s]["success"]]
    only_warp = [s for s in seeds if warp[s]["success"] and not cpu[s]["success"]]
    mean = (lambda side: sum(side[s]["steps"] for s in both) / len(both)) if both else (lambda side: None)
    return {"init_states": [s % 50 for s in seeds], "episodes": len(seeds),
            "cpu_successes": sum(cpu[s]["success"] for s in seeds),
            "warp_successes": sum(warp[s]["success"] for s in seeds),
            "only_cpu": [s % 50 for s in only_cpu], "only_warp": [s % 50 for s in only_warp],
            "mcnemar_p": mcnemar_exact(len(only_cpu), len(only_warp)),
            "mean_steps_both_solved": {"cpu": mean(cpu), "warp": mean(warp)},
            "steps": {str(s % 50): [cpu[s]["steps"], warp[s]["steps"]] for s in seeds},
            "errors": {str(s % 50): warp[s]["error"] for s in seeds if warp[s].get("error")}}


def two_sided(a: dict[int, dict], b: dict[int, dict], names: tuple[str, str]) -> dict:
    """Two sides' episodes paired by seed: each side's successes, the init states only one solved, McNemar."""
    seeds = sorted(a)
    if sorted(b) != seeds:
        raise SystemExit(f"the sides ran different episodes: {seeds} vs {sorted(b)}")
    x, y = names
    only_x = [s % 50 for s in seeds if a[s]["success"] and not b[s]["success"]]
    only_y = [s % 50 for s in seeds if b[s]["success"] and not a[s]["success"]]
    return {f"{x}_successes": sum(a[s]["success"] for s in seeds), f"{y}_successes": sum(b[s]["success"] for s in seeds),
            f"only_{x}": only_x, f"only_{y}": only_y, "mcnemar_p": mcnemar_exact(len(only_x), len(only_y)),
            "same_steps": sum(a[s]["steps"] == b[s]["steps"] for s in seeds)}


def scene_task(run_dir: Path) -> str | None:
    """The LIBERO task of a ``simseam run --scene`` directory (its ``run.json``'s scene: ``benchmark: {suite,
    task}``), whose episodes name none; None for a run of anything else."""
    bench = (json.loads((run_dir / "run.json").read_text()).get("scene") or {}).get("benchmark") or {}
    return f"{bench['suite']}/{bench['task']}" if bench.get("name") == "libero" and "suite" in bench else None


def run_episodes(dirs: list[Path]) -> dict[str, dict[int, dict]]:
    """The episodes of ``dirs``' runs (``episodes.jsonl``: ``simseam eval``'s name their task, ``simseam run
    --scene``'s take it from the scene), per task and seed; a seed run twice is an error."""
    out: dict[str, dict[int, dict]] = {}
    for d in dirs:
        lines = (d / "episodes.jsonl").read_text().splitlines()
        of_scene = None
        for e in (json.loads(line) for line in lines if line.strip()):
            if "task" not in e:
                of_scene = of_scene or scene_task(d)
                if of_scene is None:
                    raise SystemExit(f"--from-runs: {d}: its episodes name no task and it is no run of a LIBERO scene")
                e = {**e, "task": of_scene}
            task = out.setdefault(e["task"], {})
            if e["seed"] in task:
                raise SystemExit(f"--from-runs: {e['task']} seed {e['seed']} is in two runs ({d})")
            task[e["seed"]] = e
    return out


def from_runs(cpu_dirs: list[Path], warp_dirs: list[Path], seeds: range) -> tuple[dict, dict, list[str]]:
    """Each task's pairing (``paired``) where both sides hold every seed of ``seeds``; each task's revisions
    (both sides' run.json); the tasks left out, with what each side holds."""
    cpu, warp = run_episodes(cpu_dirs), run_episodes(warp_dirs)
    rows, revisions, left = {}, {}, []
    for task in sorted(set(cpu) | set(warp), key=lambda t: (t.split("/")[0], int(t.split("/")[1]))):
        a, b = cpu.get(task, {}), warp.get(task, {})
        if not all(s in a and s in b for s in seeds):
            left.append(f"{task} (CPU {sum(s in a for s in seeds)}, Warp {sum(s in b for s in seeds)} of {len(seeds)})")
            continue
        rows[task] = paired({s: a[s] for s in seeds}, {s: b[s] for s in seeds})
    revisions = {"cpu": sorted({json.dumps(revision(d)) for d in cpu_dirs}),
                 "warp": sorted({json.dumps(revision(d)) for d in warp_dirs})}
    return rows, {k: [json.loads(v) for v in vs] for k, vs in revisions.items()}, left


def print_table(rows: dict) -> None:
    print(f"\n{'task':<20} {'CPU':>7} {'Warp':>7}  {'only CPU':<12} {'only Warp':<12} {'McNemar p':>9}  steps (both ok)")
    for task, r in rows.items():
        m = r["mean_steps_both_solved"]
        steps = "-" if m["cpu"] is None else f"{m['cpu']:.0f} / {m['warp']:.0f}"
        print(f"{task:<20} {r['cpu_successes']:>3}/{r['episodes']:<3} {r['warp_successes']:>3}/{r['episodes']:<3}  "
              f"{str(r['only_cpu'] or ''):<12} {str(r['only_warp'] or ''):<12} {r['mcnemar_p']:>9.3f}  {steps}")
        for key in ("version", "engine"):
            if key in r:
                v = r[key]
                print(f"  {key:<8} {json.dumps({k: x for k, x in v.items()})}")


def merge(docs: list[dict]) -> dict:
    """One document from runs of other tasks on the same init states and Warp settings (their revisions listed)."""
    for key in ("init_states", "warp", "policy"):
        if len({json.dumps(d[key], sort_keys=True) for d in docs}) != 1:
            raise SystemExit(f"--merge: the runs differ in {key}")
    tasks = [t for d in docs for t in d["results"]]
    if len(set(tasks)) != len(tasks):
        raise SystemExit(f"--merge: a task was measured twice ({tasks})")
    return {**docs[0], "revision": {t: r for d in docs for t, r in d["revision"].items()}, "work": [d["work"] for d in docs],
            "seconds": {t: v for d in docs for t, v in d["seconds"].items()},
            "results": {t: r for d in docs for t, r in d["results"].items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--tasks", default="libero_spatial/0,libero_spatial/1")
    ap.add_argument("--init-states", default="10:15", help="A:B: init states A..B-1 of every task")
    ap.add_argument("--num-envs", type=int, default=5, help="worlds of the Warp batch")
    ap.add_argument("--sim-device", default="cpu", help="the Warp device (cpu, cuda:0, ...)")
    ap.add_argument("--work", type=Path, default=None, help="keep (and resume) the eval run directories here")
    ap.add_argument("--json", type=Path, default=HERE / "results" / "libero_warp_expert.json")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing --json file")
    ap.add_argument("--merge", type=Path, nargs="+", help="combine earlier runs' JSON (other tasks); runs nothing")
    ap.add_argument("--policy", default="scripted", help="the policy spec; {suite} and {index} are the task's")
    ap.add_argument("--port-cpu", action="store_true", help="a third side: the port's code on CPU MuJoCo (one world)")
    ap.add_argument("--from-runs", action="store_true", help="pair --cpu-runs with --warp-runs; runs nothing")
    ap.add_argument("--cpu-runs", type=Path, nargs="+", default=[], help="--from-runs: the CPU benchmark's run dirs")
    ap.add_argument("--warp-runs", type=Path, nargs="+", default=[], help="--from-runs: the port's run dirs")
    args = ap.parse_args()
    if args.json.exists() and not args.overwrite:
        ap.error(f"--json: {args.json} exists; pass --overwrite to replace it")
    if args.merge:
        doc = merge([json.loads(m.read_text()) for m in args.merge])
        print_table(doc["results"])
        args.json.write_text(json.dumps(doc, indent=1) + "\n")
        print(f"wrote {args.json}")
        return
    first, _, end = args.init_states.partition(":")
    first, end = int(first), int(end)
    if args.from_runs:
        write_from_runs(args, first, end)
        return
    work = args.work or Path(f"runs/libero_warp_expert_{time.strftime('%Y%m%d_%H%M%S')}")
    warp = {"device": args.sim_device, "num_envs": args.num_envs}
    rows, seconds, revisions = {}, {}, {}
    for task in args.tasks.split(","):
        name = task.replace("/", "-")
        seconds[task] = {"cpu": run_eval(task, first, end - first, work / f"cpu-{name}", None, args.policy),
                         "warp": run_eval(task, first, end - first, work / f"warp-{name}", warp, args.policy)}
        cpu, gpu = episodes(work / f"cpu-{name}"), episodes(work / f"warp-{name}")
        rows[task] = paired(cpu, gpu)
        revisions[task] = {"cpu": revision(work / f"cpu-{name}"), "warp": revision(work / f"warp-{name}")}
        if args.port_cpu:
            side = work / f"port-cpu-{name}"
            spent = port_cpu_run(task, first, end - first, side, args.policy)
            record = side / "wall_seconds"
            total = spent + (float(record.read_text()) if record.exists() else 0.0)
            record.write_text(f"{total:.1f}\n")
            seconds[task]["port_cpu"] = total
            port = episodes(side)
            revisions[task]["port_cpu"] = revisions_now()
            rows[task]["version"] = two_sided(cpu, port, ("cpu", "port_cpu"))
            rows[task]["engine"] = two_sided(port, gpu, ("port_cpu", "warp"))
        print_table({task: rows[task]})
    print_table(rows)
    policy = "scripted (simseam.backends.libero_expert)" if args.policy == "scripted" else args.policy
    doc = {"benchmark": "libero_warp_expert", "policy": policy,
           "init_states": [first, end - 1], "warp": warp, "seconds": seconds, "revision": revisions,
           "machine": {"cpus": os.cpu_count(), "python": platform.python_version()}, "work": str(work),
           "results": rows}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.json}")


def write_from_runs(args, first: int, end: int) -> None:
    """``--from-runs``: the pairing of runs made elsewhere, printed and written to ``--json``."""
    if not args.cpu_runs or not args.warp_runs:
        raise SystemExit("--from-runs needs --cpu-runs and --warp-runs")
    rows, revisions, left = from_runs(args.cpu_runs, args.warp_runs, range(first, end))
    if not rows:
        raise SystemExit(f"--from-runs: no task has init states {first}..{end - 1} on both sides ({'; '.join(left)})")
    print_table(rows)
    if left:
        print("left out (not finished on both sides): " + "; ".join(left))
    doc = {"benchmark": "libero_warp_expert", "policy": "runs", "init_states": [first, end - 1],
           "warp": {"device": args.sim_device, "runs": [str(d) for d in args.warp_runs]},
           "cpu": {"runs": [str(d) for d in args.cpu_runs]}, "revision": revisions, "left_out": left,
           "policies": sorted({json.loads((d / "run.json").read_text())["policy"] for d in args.cpu_runs + args.warp_runs}),
           "results": rows}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
