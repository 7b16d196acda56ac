"""What an idle gap before each step costs the step itself: one process, lift_cube's state-only step.

    .venv/bin/python benchmarks/bench_idle_step.py [--gaps-us 200 1000] [--blocks 40] [--steps-per-block 25]
        [--robot-json panda.json --urdf .../panda.urdf] [--out benchmarks/results/idle_step.json]

A lockstep worker waits between its steps (for the parent's policy and the other workers) while a bare
process steps back to back. This times the same step, in one process, after no gap, after sleeping
``gap`` microseconds (the core idles, as a sleeping worker's does), and after busy-waiting the same time
(the core stays busy, as a busy-polling worker's does). The gaps alternate in blocks of
``--steps-per-block`` steps, ``--blocks`` times, so a drift in the machine's speed hits them alike; each
figure is the median over blocks of a block's median step, in the thread's CPU time (the step's own
work, not the wait). Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_vector  # noqa: E402  (its lift_cube recipe and robot options)


def wait(kind: str, gap_s: float) -> None:
    if kind == "sleep":
        time.sleep(gap_s)
    elif kind == "spin":
        end = time.perf_counter() + gap_s
        while time.perf_counter() < end:
            pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--gaps-us", type=int, nargs="+", default=[200, 1000])
    ap.add_argument("--blocks", type=int, default=40)
    ap.add_argument("--steps-per-block", type=int, default=25)
    ap.add_argument("--robot-json", default=None, help="a RobotSpec as JSON (machines without pydantic)")
    ap.add_argument("--urdf", default=None, help="override the robot's URDF path")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/idle_step.json"))
    args = ap.parse_args()
    for name, value in (("ROBOT_JSON", args.robot_json), ("URDF", args.urdf)):
        if value:
            setattr(bench_vector, name, str(Path(value).resolve()))
    from simseam.seam import STATE_ONLY

    os.environ.pop(bench_vector.STEP_TIMES_ENV, None)  # the bare scene: no StepTimer around it
    rollout = bench_vector.BenchRecipe(None, 10**9).build()
    action = np.zeros(rollout.spec.action_dim, np.float32)
    rollout.reset(0, STATE_ONLY)
    cases = [("none", 0)] + [(kind, g) for g in args.gaps_us for kind in ("sleep", "spin")]
    blocks: dict[str, list[float]] = {f"{k} {g}" if g else k: [] for k, g in cases}
    try:
        for _ in range(args.blocks):
            for kind, gap in cases:
                cpu = []
                for _ in range(args.steps_per_block):
                    wait(kind, gap * 1e-6)
                    c = time.thread_time()
                    rollout.step(action, STATE_ONLY)
                    cpu.append(time.thread_time() - c)
                blocks[f"{kind} {gap}" if gap else kind].append(float(np.median(cpu)) * 1e6)
    finally:
        rollout.close()
    base = float(np.median(blocks["none"]))
    rows = [{"gap": name, "step_cpu_us": float(np.median(v)), "vs_no_gap": float(np.median(v)) / base,
             "blocks_us": v} for name, v in blocks.items()]
    print("| gap before each step | step us (CPU, median) | vs no gap |")
    print("|---|---:|---:|")
    for r in rows:
        print(f"| {r['gap']} | {r['step_cpu_us']:.0f} | {r['vs_no_gap']:.2f} |")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"machine": bench_vector.machine_facts(), "blocks": args.blocks,
                                    "steps_per_block": args.steps_per_block, "rows": rows}, indent=2))
    print(f"\nwrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
