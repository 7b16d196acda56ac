"""Memory over a long run: the resident set of ``simseam run`` after 1,000 and after 100,000 episodes.

    .venv/bin/python benchmarks/bench_memory.py [--episodes 100000] [--modes sequential workers]
        [--json benchmarks/results/bench_memory.json]

Each mode is the command a user types, run as a subprocess on a small state-only scene (franka_panda
lift_cube, MuJoCo, ``max_steps: 2``, ``--policy zero``, console output to /dev/null), so that
100,000 episodes take minutes and what is measured is the per-episode bookkeeping of the run, not
the physics:

- ``sequential``: ``--num-envs 1`` (one process, ``runner.session.run_episodes``);
- ``workers``: ``--num-envs 2`` (the episode scheduler over two worker processes); the resident
  sets of the main process and of each worker are summed.

While a run goes, its ``episodes.jsonl`` is counted and ``/proc/PID/status`` (``VmRSS``) is sampled;
the row for a checkpoint is the first sample at or after that many finished episodes (the run goes on
2 % past the last one, so that it is sampled while the run is live). The baseline
is the same run's resident set at 1,000 episodes: the target is RSS(100,000) within 10 % of it.
Prints a table and writes JSON.
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
SIMSEAM = str(Path(sys.executable).with_name("simseam"))
SCENE = """robot: franka_panda
engine: mujoco
task: lift_cube
max_steps: 2
control_hz: 20
environment_state: true
"""
MODES = {"sequential": 1, "workers": 2}


def rss_kib(pid: int) -> int:
    """``VmRSS`` of ``pid`` plus that of its live descendants (worker processes, sidecars), in KiB."""
    total = 0
    for p in [pid, *descendants(pid)]:
        try:
            for line in Path(f"/proc/{p}/status").read_text().splitlines():
                if line.startswith("VmRSS:"):
                    total += int(line.split()[1])
        except (FileNotFoundError, ProcessLookupError):
            pass
    return total


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


def measure(mode: str, episodes: int, checkpoints: list[int], work: Path) -> dict:
    scene = work / "scene.yaml"
    scene.write_text(SCENE)
    out = work / f"run_{mode}"
    total = episodes + max(200, episodes // 50)  # run on past the last checkpoint, so it is sampled live
    cmd = [SIMSEAM, "run", "--scene", str(scene), "--policy", "zero", "--episodes", str(total),
           "--num-envs", str(MODES[mode]), "--out", str(out)]
    counter, samples, rows = LineCounter(out / "episodes.jsonl"), [], {}
    t0 = time.monotonic()
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        while proc.poll() is None:
            n, rss = counter.poll(), rss_kib(proc.pid)
            samples.append((round(time.monotonic() - t0, 2), n, rss))
            for c in checkpoints:
                if c not in rows and n >= c:
                    rows[c] = {"episodes": n, "rss_mib": round(rss / 1024, 1), "seconds": samples[-1][0]}
            time.sleep(0.2)
    finally:
        if proc.poll() is None:
            proc.kill()
        err = proc.communicate()[1]
    if proc.returncode != 0:
        raise SystemExit(f"{mode}: simseam run exited {proc.returncode}: {err.strip().splitlines()[-1:]}")
    done = counter.poll()
    base, last = rows.get(checkpoints[0]), rows.get(checkpoints[-1])
    growth = None if not (base and last) else round(last["rss_mib"] / base["rss_mib"] - 1, 4)
    return {"mode": mode, "num_envs": MODES[mode], "episodes": done, "checkpoints": {str(c): rows[c] for c in sorted(rows)},
            "growth_vs_first": growth, "seconds": round(time.monotonic() - t0, 1),
            "samples": samples[:: max(1, len(samples) // 200)]}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--episodes", type=int, default=100_000)
    ap.add_argument("--modes", nargs="+", default=list(MODES), choices=list(MODES))
    ap.add_argument("--json", type=Path, default=HERE / "results" / "bench_memory.json")
    args = ap.parse_args()
    checkpoints = [c for c in (1_000, 10_000, 30_000, 100_000) if c <= args.episodes]
    if args.episodes not in checkpoints:
        checkpoints.append(args.episodes)
    results = []
    with tempfile.TemporaryDirectory(prefix="simseam-memory-") as d:
        for mode in args.modes:
            results.append(measure(mode, args.episodes, checkpoints, Path(d)))
    print(f"\n{'mode':<11}" + "".join(f"{c:>12,}" for c in checkpoints) + f"{'growth':>9}{'time':>9}")
    for r in results:
        cells = []
        for c in checkpoints:
            hit = r["checkpoints"].get(str(c))
            cells.append(f"{hit['rss_mib']:>8.1f} MiB" if hit else f"{'-':>12}")
        g = "-" if r["growth_vs_first"] is None else f"{100 * r['growth_vs_first']:+.1f}%"
        print(f"{r['mode']:<11}" + "".join(cells) + f"{g:>9}{r['seconds']:>8.0f}s")
    print("(resident set of the run's processes after that many finished episodes; growth: last vs the first "
          "checkpoint; target: within 10 %)")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"machine": platform.node(), "cpus": os.cpu_count(), "python": sys.version.split()[0],
                                     "episodes": args.episodes, "scene": SCENE, "results": results}, indent=1))
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
