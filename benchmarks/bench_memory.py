"""Memory over a long run: the resident set of ``simseam run`` in every way it runs episodes, after a
first and a last checkpoint of finished episodes.

    .venv/bin/python benchmarks/bench_memory.py [--episodes 100000] [--first 1000]
        [--modes sequential workers lockstep groups envs_per_worker] [--json FILE]
        [--baseline-src WORKTREE/src [--baseline-modes sequential]]

Each mode is the command a user types, run as a subprocess (``python -m simseam.cli.main``: the source
this interpreter imports, so a checkout measures itself) on a small state-only scene (franka_panda
lift_cube, MuJoCo, ``max_steps: 2``, ``--policy zero``, console output to /dev/null), so that many
episodes take minutes and what is measured is the per-episode bookkeeping of the run, not the physics:

- ``sequential``: ``--num-envs 1`` (one process, ``runner.session.run_episodes`` with its progress bar);
- ``workers``: ``--num-envs 2`` (the policy inside each of two worker processes, ``runner.whole_episodes.run_local``);
- ``lockstep``: ``--num-envs 2 --policy-ready 1`` (the policy in the main process, the ready rule);
- ``groups``: ``--num-envs 2 --policy-groups 2`` (pipelined lockstep);
- ``envs_per_worker``: ``--num-envs 4 --envs-per-worker 2 --policy-ready 2`` (two environments per worker).

(``--ray`` and ``--renderer batched`` are not measured here: a Ray cluster, a CUDA device.)

While a run goes, its ``episodes.jsonl`` is counted and ``/proc/PID/status`` (``VmRSS``) is sampled, of
the main process and of all its processes together; the row for a checkpoint is the first sample at or
after that many finished episodes (the run goes on 2 % past the last one, so that it is sampled while
the run is live). The baseline is the same run's resident set at the first checkpoint: the target is
the last within 10 % of it, and the growth per episode (main process, last minus first over the
episodes between) near 0. Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
SIMSEAM = [sys.executable, "-m", "simseam.cli.main"]
SCENE = """robot: franka_panda
engine: mujoco
task: lift_cube
max_steps: 2
control_hz: 20
environment_state: true
"""
MODES = {"sequential": ["--num-envs", "1"], "workers": ["--num-envs", "2"],
         "lockstep": ["--num-envs", "2", "--policy-ready", "1"], "groups": ["--num-envs", "2", "--policy-groups", "2"],
         "envs_per_worker": ["--num-envs", "4", "--envs-per-worker", "2", "--policy-ready", "2"]}


def vm_rss_kib(pid: int) -> int:
    """``VmRSS`` of ``pid`` in KiB (0 once it is gone)."""
    try:
        for line in Path(f"/proc/{pid}/status").read_text().splitlines():
            if line.startswith("VmRSS:"):
                return int(line.split()[1])
    except (FileNotFoundError, ProcessLookupError):
        pass
    return 0


def rss_kib(pid: int) -> int:
    """``VmRSS`` of ``pid`` plus that of its live descendants (worker processes, sidecars), in KiB."""
    return sum(vm_rss_kib(p) for p in [pid, *descendants(pid)])


def descendants(pid: int) -> list[int]:
    out, frontier = [], [pid]
    while frontier:
        p = frontier.pop()
        try:
            kids = Path(f"/proc/{p}/task/{p}/children").read_text().split()
        except FileNotFoundError:
            continue
        out += [int(k) for k in kids]
        frontier += [int(k) for k in kids]
    return out


class LineCounter:
    """Finished episodes in a growing ``episodes.jsonl`` (reads only what was appended)."""

    def __init__(self, path: Path):
        self.path, self.offset, self.count = path, 0, 0

    def poll(self) -> int:
        try:
            with open(self.path, "rb") as f:
                f.seek(self.offset)
                chunk = f.read()
        except FileNotFoundError:
            return 0
        complete = chunk[: chunk.rfind(b"\n") + 1]
        self.offset += len(complete)
        self.count += complete.count(b"\n")
        return self.count


def measure(mode: str, episodes: int, checkpoints: list[int], work: Path, src: Path | None = None) -> dict:
    """One mode's run (``src``: run that source tree's simseam instead, e.g. a worktree of an earlier revision)."""
    scene = work / "scene.yaml"
    scene.write_text(SCENE)
    out = work / f"run_{mode}{'_baseline' if src else ''}"
    env = dict(os.environ, PYTHONPATH=str(src)) if src else None
    total = episodes + max(200, episodes // 50)  # run on past the last checkpoint, so it is sampled live
    cmd = [*SIMSEAM, "run", "--scene", str(scene), "--policy", "zero", "--episodes", str(total), *MODES[mode],
           "--out", str(out)]
    counter, samples, rows = LineCounter(out / "episodes.jsonl"), [], {}
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True, env=env)
    try:
        while proc.poll() is None:
            n, main, rss = counter.poll(), vm_rss_kib(proc.pid), rss_kib(proc.pid)
            samples.append((round(time.monotonic() - t0, 2), n, rss, main))
            for c in checkpoints:
                if c not in rows and n >= c:
                    rows[c] = {"episodes": n, "rss_mib": round(rss / 1024, 1), "main_rss_mib": round(main / 1024, 1),
                               "seconds": samples[-1][0]}
            time.sleep(0.2)
    finally:
        if proc.poll() is None:
            proc.kill()
        err = proc.communicate()[1]
    if proc.returncode != 0:
        raise SystemExit(f"{mode}: simseam run exited {proc.returncode}: {err.strip().splitlines()[-1:]}")
    done = counter.poll()
    base, last = rows.get(checkpoints[0]), rows.get(checkpoints[-1])
    growth = per_episode = None
    if base and last:
        growth = round(last["rss_mib"] / base["rss_mib"] - 1, 4)
        per_episode = round((last["main_rss_mib"] - base["main_rss_mib"]) * 1024 / (last["episodes"] - base["episodes"]),
                            3)
    return {"mode": mode + (" (baseline)" if src else ""), "src": str(src) if src else None, "args": MODES[mode],
            "episodes": done, "checkpoints": {str(c): rows[c] for c in sorted(rows)},
            "growth_vs_first": growth, "main_kib_per_episode": per_episode, "seconds": round(time.monotonic() - t0, 1),
            "samples": samples[:: max(1, len(samples) // 200)]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=100_000)
    ap.add_argument("--first", type=int, default=1_000, help="the first checkpoint (the baseline)")
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    ap.add_argument("--json", type=Path, default=HERE / "results" / "bench_memory.json")
    ap.add_argument("--label", default="", help="recorded in the JSON (e.g. the revision measured)")
    ap.add_argument("--baseline-src", type=Path, help="also run each mode, first, on this source tree (the src/ "
                    "of a worktree at an earlier revision: git worktree add DIR REV): its rows are the baseline's")
    ap.add_argument("--baseline-modes", nargs="+", choices=list(MODES), help="the modes run on --baseline-src "
                    "(default: all of --modes)")
    args = ap.parse_args()
    checkpoints = sorted({args.first, *[c for c in (10_000, 30_000, 100_000) if args.first < c <= args.episodes],
                          args.episodes})
    results = []
    with tempfile.TemporaryDirectory(prefix="simseam-memory-") as d:
        for mode in args.modes:
            if args.baseline_src and mode in (args.baseline_modes or args.modes):
                results.append(measure(mode, args.episodes, checkpoints, Path(d), src=args.baseline_src.resolve()))
            results.append(measure(mode, args.episodes, checkpoints, Path(d)))
            print(f"{mode}: {results[-1]['seconds']:.0f} s", file=sys.stderr)
    print(f"\n{'mode':<28}" + "".join(f"{c:>12,}" for c in checkpoints) + f"{'growth':>9}{'main B/ep':>11}{'time':>8}")
    for r in results:
        cells = []
        for c in checkpoints:
            hit = r["checkpoints"].get(str(c))
            cells.append(f"{hit['rss_mib']:>8.1f} MiB" if hit else f"{'-':>12}")
        g = "-" if r["growth_vs_first"] is None else f"{100 * r['growth_vs_first']:+.1f}%"
        b = "-" if r["main_kib_per_episode"] is None else f"{1024 * r['main_kib_per_episode']:+.0f}"
        print(f"{r['mode']:<28}" + "".join(cells) + f"{g:>9}{b:>11}{r['seconds']:>7.0f}s")
    print("(resident set of all the run's processes after that many finished episodes; growth: last vs the first "
          "checkpoint, target within 10 %; main B/ep: the main process's growth per episode between them)")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"machine": platform.node(), "cpus": os.cpu_count(), "python": sys.version.split()[0],
                                     "label": args.label, "baseline_src": str(args.baseline_src or ""),
                                     "episodes": args.episodes, "scene": SCENE,
                                     "results": results}, indent=1))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
