"""LIBERO's scripted expert (``--policy scripted``) on the CPU benchmark: success per task and per suite.

    .venv/bin/python benchmarks/libero_expert_cpu.py [--suites libero_spatial,libero_object]
        [--init-states 10:30] [--num-envs 1] [--work DIR] [--json PATH]

Runs ``simseam eval SUITE --policy scripted --seed A --episodes B-A`` (the command a user runs: the
``libero`` backend in its venv behind the sidecar, LIBERO's own success check, openpi's step limits)
for every task of each suite, so episode ``e`` of a task starts from LIBERO's init state ``A + e``.
The expert was tuned on init states 0-9 of every task (the tuning set); the default reports init
states 10-29, held out. ``--work DIR`` keeps each suite's run directory (``DIR/SUITE``); a run
already there is resumed (``--resume``: its recorded episodes are kept), so an interrupted
measurement continues where it stopped (``seconds`` then counts this invocation only). ``--merge A.json
B.json`` combines the JSON of per-suite invocations run side by side (same init states and revision).

Prints one row per task (successes / episodes, rate, Wilson 95 % interval, mean steps of the
successful episodes) and one per suite (all its episodes pooled), and writes JSON (default
benchmarks/results/libero_expert_cpu.json). Nothing is asserted.
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

HERE = Path(__file__).resolve().parent
REPO = HERE.parent
TUNING = "init states 0-9 of every task"


def run_suite(suite: str, first: int, count: int, num_envs: int, out: Path) -> float:
    cmd = [sys.executable, "-m", "simseam.cli.main", "eval", suite, "--policy", "scripted", "--seed", str(first),
           "--episodes", str(count), "--out", str(out)]
    if num_envs > 1:
        cmd += ["--num-envs", str(num_envs)]
    if (out / "run.json").exists():
        cmd.append("--resume")
    t0 = time.perf_counter()
    subprocess.run(cmd, cwd=REPO, check=True, env=dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl")))
    return time.perf_counter() - t0


def rows_of(suite: str, outs: list[Path]) -> dict:
    """Per-task and pooled success over the episodes of ``outs`` (eval run directories of ``suite``, all run
    by the same simseam revision; an init state measured twice is an error)."""
    from simseam.runner.summary import wilson_interval

    revisions = {json.dumps(json.loads((o / "run.json").read_text())["provenance"]["simseam"]["revision"],
                            sort_keys=True) for o in outs}
    if len(revisions) != 1:
        raise SystemExit(f"{suite}: the runs {[str(o) for o in outs]} ran different simseam revisions {revisions}")
    episodes = [json.loads(line) for o in outs for line in (o / "episodes.jsonl").read_text().splitlines()
                if line.strip()]
    tasks: dict[str, list[dict]] = {}
    for e in episodes:
        tasks.setdefault(e["task"], []).append(e)
    rows = {}
    for task in sorted(tasks, key=lambda t: int(t.rsplit("/", 1)[1])):
        eps = sorted(tasks[task], key=lambda e: e["seed"])
        seeds = [e["seed"] for e in eps]
        if len(set(seeds)) != len(seeds):
            raise SystemExit(f"{task}: an init state was measured twice ({seeds})")
        wins = [e for e in eps if e["success"]]
        lo, hi = wilson_interval(len(wins), len(eps))
        rows[task] = {"successes": len(wins), "episodes": len(eps), "success_rate": len(wins) / len(eps),
                      "wilson95": [lo, hi], "init_states": [s % 50 for s in seeds],
                      "failed_init_states": [e["seed"] % 50 for e in eps if not e["success"]],
                      "mean_steps_successful": (sum(e["steps"] for e in wins) / len(wins)) if wins else None}
    n = sum(r["episodes"] for r in rows.values())
    k = sum(r["successes"] for r in rows.values())
    lo, hi = wilson_interval(k, n)
    return {"revision": json.loads(revisions.pop()), "tasks": rows, "suite": {
        "successes": k, "episodes": n, "success_rate": k / n if n else None, "wilson95": [lo, hi],
        "worst_task": min(rows, key=lambda t: rows[t]["success_rate"]) if rows else None}}


def print_table(results: dict) -> None:
    print(f"\n{'task':<20} {'success':>9} {'rate':>7} {'Wilson 95 %':>16} {'steps (ok)':>11}  failed init states")
    for suite, res in results.items():
        for task, r in res["tasks"].items():
            steps = "-" if r["mean_steps_successful"] is None else f"{r['mean_steps_successful']:.0f}"
            print(f"{task:<20} {r['successes']:>4}/{r['episodes']:<4} {r['success_rate']:>7.1%} "
                  f"[{r['wilson95'][0]:.3f}, {r['wilson95'][1]:.3f}] {steps:>11}  {r['failed_init_states'] or ''}")
        s = res["suite"]
        print(f"{suite + ' (all)':<20} {s['successes']:>4}/{s['episodes']:<4} {s['success_rate']:>7.1%} "
              f"[{s['wilson95'][0]:.3f}, {s['wilson95'][1]:.3f}]   worst task: {s['worst_task']}\n")


def merge(paths: list[Path]) -> dict:
    """One document from earlier runs of this script: suites measured side by side, or more init states of
    the same suites (their run directories are read again, their episodes pooled)."""
    docs = [json.loads(p.read_text()) for p in paths]
    if len({d["policy"] for d in docs}) != 1:
        raise SystemExit("--merge: the runs measured different policies")
    outs: dict[str, list[Path]] = {}
    seconds: dict[str, float] = {}
    for d in docs:
        for suite in d["results"]:
            outs.setdefault(suite, []).append(Path(d["work"]) / suite)
            seconds[suite] = seconds.get(suite, 0.0) + d["seconds"][suite]
    windows = sorted({tuple(w) for d in docs
                      for w in (d["init_states"] if isinstance(d["init_states"][0], list) else [d["init_states"]])})
    return {**docs[0], "init_states": [list(w) for w in windows], "held_out": all(w[0] >= 10 for w in windows),
            "seconds": seconds, "work": sorted({d["work"] for d in docs}),
            "results": {suite: rows_of(suite, o) for suite, o in outs.items()}}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--suites", default="libero_spatial,libero_object")
    ap.add_argument("--init-states", default="10:30", help="A:B: init states A..B-1 of every task (held out: A >= 10)")
    ap.add_argument("--num-envs", type=int, default=1)
    ap.add_argument("--work", type=Path, default=None, help="keep (and resume) the eval run directories here")
    ap.add_argument("--json", type=Path, default=HERE / "results" / "libero_expert_cpu.json")
    ap.add_argument("--overwrite", action="store_true", help="replace an existing --json file")
    ap.add_argument("--merge", type=Path, nargs="+", help="combine the JSON of earlier per-suite runs; runs nothing")
    args = ap.parse_args()
    if args.json.exists() and not args.overwrite:
        ap.error(f"--json: {args.json} exists; pass --overwrite to replace it")
    if args.merge:
        doc = merge(args.merge)
        print_table(doc["results"])
        args.json.write_text(json.dumps(doc, indent=1) + "\n")
        print(f"wrote {args.json}")
        return
    first, _, end = args.init_states.partition(":")
    first, end = int(first), int(end)
    if not 0 <= first < end <= 50:
        ap.error(f"--init-states: expected A:B with 0 <= A < B <= 50 (LIBERO has 50 per task), got {args.init_states}")
    work = args.work or Path(f"runs/libero_expert_cpu_{time.strftime('%Y%m%d_%H%M%S')}")
    results, seconds = {}, {}
    for suite in args.suites.split(","):
        seconds[suite] = run_suite(suite, first, end - first, args.num_envs, work / suite)
        results[suite] = rows_of(suite, [work / suite])
    print_table(results)
    overlap = first < 10
    doc = {"benchmark": "libero_expert_cpu", "policy": "scripted (simseam.backends.libero_expert)",
           "tuning_set": TUNING, "init_states": [[first, end - 1]], "held_out": not overlap,
           "num_envs": args.num_envs, "seconds": seconds, "machine": {"cpus": os.cpu_count(),
                                                                       "python": platform.python_version()},
           "work": str(work), "results": results}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.json}" + ("  (NOT held out: these init states overlap the tuning set)" if overlap else ""))


if __name__ == "__main__":
    main()
