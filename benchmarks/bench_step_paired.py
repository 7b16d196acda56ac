"""The state-only step before / after a change, paired in ONE process (bench_step.py's state cases).

    .venv/bin/python benchmarks/bench_step_paired.py --baseline REV [--rounds 10] [--json PATH]

``bench_step.py --baseline`` runs each side in its own processes, minutes apart; on a shared machine
the two sides' ratios then scatter by more than a small change moves them. Here ``REV``'s ``src/``
is imported beside this checkout's, renamed ``simseam_base`` (its imports and "module:attribute"
strings rewritten), and the floor, both sides' Cartesian and joint cases are interleaved in one
process (``bench_step.interleaved``: blocks of 10 steps, the first case rotating), so every round
compares the sides under the same load. Reports per side the median over rounds of p50 / the floor's
p50 and, per round, after minus before.
"""

from __future__ import annotations

import argparse
import json
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

import bench_step as bs  # noqa: E402

HERE = Path(__file__).resolve().parent


def import_revision(rev: str, root: Path):
    """``rev``'s simseam as the package ``simseam_base`` (under ``root``): its ManifestScene, SceneOptions
    and load_robot."""
    archive = subprocess.run(["git", "-C", str(HERE.parent), "archive", rev, "src/simseam"],
                             capture_output=True, check=True)
    subprocess.run(["tar", "-x", "-C", str(root)], input=archive.stdout, check=True)
    pkg = root / "simseam_base"
    (root / "src" / "simseam").rename(pkg)
    for f in pkg.rglob("*.py"):
        text = f.read_text()
        text = re.sub(r"\bsimseam\.", "simseam_base.", text)
        text = re.sub(r"\bfrom simseam import\b", "from simseam_base import", text)
        text = re.sub(r"^import simseam$", "import simseam_base", text, flags=re.M)
        f.write_text(text)
    sys.path.insert(0, str(root))
    from simseam_base.robot.manifest import load_robot
    from simseam_base.scene.manifest_scene import ManifestScene, SceneOptions
    return ManifestScene, SceneOptions, load_robot


class BaseCase(bs.SeamCase):
    """``bench_step.SeamCase`` (state only) on the other revision's scene class."""

    def __init__(self, scene_cls, options_cls, spec, mode: str, steps: int):
        self.scene = scene_cls(spec, "lift_cube", "mujoco", options_cls(render_images=False, control_mode=mode))
        self.steps = steps
        acts = bs.smooth_actions(steps + bs.WARMUP, self.scene.action_dim, seed=1)
        if mode == "joint_position":
            home = np.array([j.home for j in spec.arm_joints], dtype=np.float32)
            acts[:, :7] = home + 0.5 * acts[:, :7]
        self.actions = acts


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--baseline", required=True, metavar="REV")
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--rounds", type=int, default=10)
    ap.add_argument("--json", default=str(HERE / "results" / "step_paired.json"))
    args = ap.parse_args()
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as tmp:
        scene_b, options_b, load_b = import_revision(args.baseline, Path(tmp))
        spec, spec_b, n = bs.load_robot("franka_panda"), load_b("franka_panda"), args.steps
        cases = {"floor": bs.FloorCase(bs.SeamCase(spec, "cartesian_delta", False, None, n)),
                 "before_cartesian": BaseCase(scene_b, options_b, spec_b, "cartesian_delta", n),
                 "after_cartesian": bs.SeamCase(spec, "cartesian_delta", False, None, n),
                 "before_joint": BaseCase(scene_b, options_b, spec_b, "joint_position", n),
                 "after_joint": bs.SeamCase(spec, "joint_position", False, None, n)}
        ratios: dict[str, list[float]] = {k: [] for k in cases}
        for r in range(args.rounds):
            times = bs.interleaved(cases, n)
            floor = float(np.median(times["floor"]))
            for k, t in times.items():
                ratios[k].append(float(np.median(t)) / floor)
            print(f"round {r + 1}/{args.rounds}: " + " ".join(f"{k} {v[-1]:.3f}" for k, v in ratios.items()))
    x = {k: float(np.median(v)) for k, v in ratios.items()}
    gain = {m: [b - a for b, a in zip(ratios[f"before_{m}"], ratios[f"after_{m}"])] for m in ("cartesian", "joint")}
    for m, g in gain.items():
        print(f"{m}: {x[f'before_{m}']:.3f}x -> {x[f'after_{m}']:.3f}x the floor; after faster in "
              f"{sum(d > 0 for d in g)}/{len(g)} rounds, by a median of {np.median(g):.3f}x")
    load1 = os.getloadavg()
    print(f"load average: start {load0[0]:.2f}, end {load1[0]:.2f}")
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({"baseline": args.baseline, "steps": args.steps, "rounds": args.rounds,
                               "loadavg": {"start": load0, "end": load1}, "x_floor": x, "x_floor_rounds": ratios,
                               "before_minus_after": gain}, indent=2))
    print(f"wrote {out}")
    for c in cases.values():
        c.scene.close()


if __name__ == "__main__":
    main()
