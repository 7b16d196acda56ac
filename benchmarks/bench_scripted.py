"""Scripted-expert success rates per (robot, task, control mode), on this machine.

    .venv/bin/python benchmarks/bench_scripted.py [--case so101:lift_cube] [--seeds 0-9] [--json out.json]

A case is ``ROBOT:TASK[:MODE]`` (robot: a built-in name or a manifest path; MODE: cartesian_delta
(default) or joint_position). Each case runs one state-only, privileged episode per seed with the
``scripted`` policy and reports successes / episodes, mean steps and the final diagnostics of each
failed seed. The table goes to stdout, the numbers to JSON (``--json``).
"""

from __future__ import annotations

import argparse
import json
import os
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

from simseam.policies.base import make_policy  # noqa: E402
from simseam.robot.manifest import load_robot  # noqa: E402
from simseam.scene.manifest_scene import ManifestScene, SceneOptions  # noqa: E402

HERE = Path(__file__).resolve().parent
DEFAULT_CASES = ["so101:lift_cube", "franka_panda:lift_cube", "panda_mobile:nav_obstacles",
                 "franka_panda:reach", "franka_panda:reach:joint_position"]


def seeds_of(text: str) -> list[int]:
    out: list[int] = []
    for part in text.split(","):
        lo, _, hi = part.partition("-")
        out.extend(range(int(lo), int(hi or lo) + 1))
    return out


def run_case(case: str, seeds: list[int]) -> dict:
    robot, task, *mode = case.split(":")
    scene = ManifestScene(load_robot(robot), task, "mujoco",
                          SceneOptions(render_images=False, privileged=True, control_mode=mode[0] if mode else None))
    policy = make_policy("scripted")
    wins, steps, failed = 0, [], {}
    t0 = time.perf_counter()
    try:
        for seed in seeds:
            obs = scene.reset(seed)
            policy.reset(scene.spec)
            for _ in range(scene.spec.task.max_steps):
                res = scene.step(policy.act(obs))
                obs = res.observation
                if res.terminated or res.truncated:
                    break
            ok = bool(res.info[scene.spec.task.success_key])
            wins += ok
            steps.append(res.info["steps"])
            if not ok:
                failed[seed] = {k: (round(v, 4) if isinstance(v, float) else v)
                                for k, v in res.info["diagnostics"].items()}
    finally:
        scene.close()
    return {"case": case, "successes": wins, "episodes": len(seeds), "seeds": seeds,
            "mean_steps": sum(steps) / len(steps), "failed": failed, "wall_s": time.perf_counter() - t0}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("--case", action="append", help="ROBOT:TASK[:MODE] (repeatable); default: a standard set")
    ap.add_argument("--seeds", default="0-9", help="e.g. 0-9 or 0,3,5-7")
    ap.add_argument("--json", type=Path, default=HERE / "results" / "scripted.json")
    args = ap.parse_args()
    seeds = seeds_of(args.seeds)
    rows = []
    print(f"{'case':44s} {'success':>9s} {'mean steps':>10s} {'wall s':>7s}  failed seeds")
    for case in args.case or DEFAULT_CASES:
        r = run_case(case, seeds)
        rows.append(r)
        print(f"{case:44s} {r['successes']:>4d}/{r['episodes']:<4d} {r['mean_steps']:>10.1f} {r['wall_s']:>7.1f}  "
              f"{r['failed'] or '-'}", flush=True)
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"seeds": seeds, "cases": rows}, indent=2) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
