"""ManiSkill3's motion-planning experts: success through the seam vs on ManiSkill's own env.

    .venv/bin/python benchmarks/bench_maniskill_experts.py [--episodes 10] [--tasks PickCube-v1,...] [--json PATH]

``native``: ManiSkill's solution (``mani_skill.examples.motionplanning.panda.solutions``, mplib) on
``gym.make(task, control_mode="pd_joint_pos", sim_backend="physx_cpu")`` in the backend's venv (a
subprocess that imports no simseam), seeds 0..N-1, driven as its ``run.py`` does: the solver steps
the env itself, past the registered step limit. Reported: its own verdict at the end of its plan
and whether it succeeded at some step within the limit ManiSkill registers.

``seam``: the ``maniskill`` backend with ``--policy scripted``'s contract (``expert_action``: the plan
made on a twin env at each reset, replayed), the episode ending at success or at ``max_steps``:
once with the registered limit (what ``simseam eval maniskill_tabletop`` runs), once with 300 steps
(longer than every plan: past its end the seam holds the plan's last action). ``same``: episodes
that succeed through the seam at exactly the step where the native solver first succeeds, or fail
where it does not (within the limit / within its plan).

Prints a table and writes JSON (default benchmarks/results/maniskill_experts.json). Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
TASKS = ("PickCube-v1", "PushCube-v1", "StackCube-v1", "PegInsertionSide-v1", "PullCube-v1")

NATIVE = r'''
import json, sys
import gymnasium as gym
import sapien
import sapien.wrapper.urdf_loader
try:
    sapien.render.RenderMaterial()
except RuntimeError:  # no Vulkan device SAPIEN can render with: physics only (as simseam's backend does)
    class Inert:
        def __init__(self, *a, **k): pass
    sapien.render.RenderMaterial = sapien.pysapien.render.RenderMaterial = Inert
    sapien.wrapper.urdf_loader.RenderMaterial = Inert
import mani_skill.envs
from mani_skill.examples.motionplanning.panda import solutions
from mani_skill.utils.registration import REGISTERED_ENVS
task, solver, n = sys.argv[1], sys.argv[2], int(sys.argv[3])
env = gym.make(task, obs_mode="state", control_mode="pd_joint_pos", sim_backend="physx_cpu", num_envs=1,
               render_mode=None, render_backend="none")
limit = REGISTERED_ENVS[task].max_episode_steps
out = []
for seed in range(n):
    flags = []
    step = env.step
    def watch(a, step=step, flags=flags):
        r = step(a)
        flags.append(bool(r[4]["success"][0]))
        return r
    env.step = watch
    res = getattr(solutions, solver)(env, seed=seed)
    del env.step
    first = flags.index(True) + 1 if True in flags else 0
    out.append({"seed": seed, "solver_success": res != -1 and bool(res[-1]["success"].item()),
                "success_within_limit": 0 < first <= limit, "first_success_step": first, "plan_steps": len(flags)})
assert "simseam" not in sys.modules
print(json.dumps({"limit": limit, "episodes": out}))
'''


def native(task: str, solver: str, n: int) -> dict:
    from simseam.backends.provision import require

    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
    out = subprocess.run([str(require("maniskill")), "-c", NATIVE, task, solver, str(n)], capture_output=True,
                         text=True, env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def seam(task: str, n: int, max_steps: int) -> list[dict]:
    from simseam.sidecar.benchmark import open_benchmark

    r = open_benchmark("maniskill", {"task": task, "max_steps": max_steps}, privileged=True)
    out = []
    try:
        for seed in range(n):
            obs = r.reset(seed)
            steps = 0
            while True:
                res = r.step(obs["expert_action"])
                obs, steps = res.observation, steps + 1
                if res.terminated or res.truncated:
                    break
            out.append({"seed": seed, "success": bool(res.info["success"]), "steps": steps})
    finally:
        r.close()
    return out


def main() -> None:
    from simseam.backends.maniskill import EXPERT_TASKS

    ap = argparse.ArgumentParser()
    ap.add_argument("--episodes", type=int, default=10)
    ap.add_argument("--tasks", default=",".join(TASKS))
    ap.add_argument("--json", type=Path, default=HERE / "results" / "maniskill_experts.json")
    args = ap.parse_args()
    rows = []
    for task in args.tasks.split(","):
        t0 = time.monotonic()
        nat = native(task, EXPERT_TASKS[task], args.episodes)
        t_native = time.monotonic() - t0
        t0 = time.monotonic()
        limited = seam(task, args.episodes, nat["limit"])
        t_seam = time.monotonic() - t0
        long = seam(task, args.episodes, 300)
        eps = nat["episodes"]
        def same(seam_eps, within):  # succeeded at exactly the native first-success step, or failed with it
            return sum(s["success"] == within(e) and (not s["success"] or s["steps"] == e["first_success_step"])
                       for s, e in zip(seam_eps, eps))
        rows.append({"task": task, "episodes": args.episodes, "limit": nat["limit"],
                     "native_solver_success": sum(e["solver_success"] for e in eps) / len(eps),
                     "native_success_within_limit": sum(e["success_within_limit"] for e in eps) / len(eps),
                     "seam_success_at_limit": sum(s["success"] for s in limited) / len(limited),
                     "seam_success_300_steps": sum(s["success"] for s in long) / len(long),
                     "episodes_identical_at_limit": same(limited, lambda e: e["success_within_limit"]),
                     "episodes_identical_300": same(long, lambda e: e["first_success_step"] > 0),
                     "native_seconds": round(t_native, 1),
                     "seam_seconds": round(t_seam, 1), "native": eps, "seam_at_limit": limited, "seam_300": long})
    print(f"{'task':22} {'limit':>5} {'native solver':>13} {'native<=limit':>13} {'seam@limit':>10} "
          f"{'seam@300':>8} {'same@limit':>10} {'same@300':>8}")
    for r in rows:
        n = r["episodes"]
        print(f"{r['task']:22} {r['limit']:5d} {r['native_solver_success']:13.0%} "
              f"{r['native_success_within_limit']:13.0%} {r['seam_success_at_limit']:10.0%} "
              f"{r['seam_success_300_steps']:8.0%} {r['episodes_identical_at_limit']:7d}/{n} "
              f"{r['episodes_identical_300']:5d}/{n}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"rows": rows, "python": sys.version.split()[0], "cpus": os.cpu_count()},
                                    indent=2))
    print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
