"""How long a ``simseam`` command takes to end once its run is done: from the run's last timing line (``ran``: its
episodes written) to the process's exit, with the heap frozen at exit (``simseam.cli.main``: ``atexit.register(
gc.freeze)``, as shipped) and without (the same command with that handler unregistered), alternating in one run.

The default command is a LIBERO task on MuJoCo Warp's CPU device (needs the LIBERO backend: ``simseam backends
provision libero``), 5 steps, the zero policy: a command whose heap holds MuJoCo Warp's kernels and a LIBERO
model. The last of ``simseam eval --processes K``'s processes delays the whole run by its end.

    python benchmarks/bench_exit.py --rounds 3            # a table + benchmarks/results/exit_cpu.json
"""

from __future__ import annotations

import argparse
import json
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "benchmarks"))
from cpu_facts import CpuWindow, topology  # noqa: E402

SCENE = """benchmark: {name: libero, suite: libero_spatial, task: 0, max_steps: 5}
engine: {name: mujoco_warp, num_envs: 1, device: cpu}
"""
WAYS = {
    "frozen": "import sys, simseam.cli.main as m; sys.argv = ['simseam', *sys.argv[1:]]; m.main()",
    "collected": ("import atexit, gc, sys, simseam.cli.main as m; atexit.unregister(gc.freeze); "
                  "sys.argv = ['simseam', *sys.argv[1:]]; m.main()"),
}


def one(way: str, scene: Path, out: Path) -> dict:
    """One command run ``way``: its wall time and the seconds from its run's ``ran`` to the process's exit."""
    t0 = time.time()
    proc = subprocess.run([sys.executable, "-c", WAYS[way], "run", "--scene", str(scene), "--policy", "zero",
                           "--episodes", "1", "--out", str(out), "--overwrite"], capture_output=True, text=True)
    ended = time.time()
    if proc.returncode != 0:
        raise SystemExit(f"{way}: exit {proc.returncode}\n{proc.stdout[-2000:]}{proc.stderr[-2000:]}")
    ran = json.loads((out / "timings.jsonl").read_text().splitlines()[0])["ran"]
    return {"wall_s": ended - t0, "exit_after_ran_s": ended - ran}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--scene", type=Path, default=None, help="another scene file (default: LIBERO on Warp's CPU)")
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "exit_cpu.json")
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args()
    if args.out.exists() and not args.overwrite:
        ap.error(f"{args.out} exists; pass --overwrite to replace it")
    doc: dict = {"benchmark": "exit", "argv": sys.argv[1:], "machine": topology(), "ways": {w: [] for w in WAYS}}
    with tempfile.TemporaryDirectory() as tmp, CpuWindow() as window:
        scene = args.scene or Path(tmp) / "scene.yaml"
        if args.scene is None:
            scene.write_text(SCENE)
        doc["scene"] = scene.read_text()
        one("frozen", scene, Path(tmp) / "warm")  # untimed: kernels and the task's caches
        for _ in range(args.rounds):
            for way in WAYS:
                doc["ways"][way].append(one(way, scene, Path(tmp) / way))
    doc["cpu_window"] = window.facts()
    print(f"\n{'at exit':<12} {'exit after the run, s (median)':>32} {'rounds':>24} {'wall s (median)':>16}")
    for way, rows in doc["ways"].items():
        ends = [r["exit_after_ran_s"] for r in rows]
        print(f"{way:<12} {statistics.median(ends):32.3f} {' '.join(f'{e:.3f}' for e in ends):>24} "
              f"{statistics.median(r['wall_s'] for r in rows):16.2f}")
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1))
    print(f"wrote {args.out}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
