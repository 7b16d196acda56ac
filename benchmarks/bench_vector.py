"""Evaluation throughput vs the number of environments: env-steps/s and episodes/hour.

    .venv/bin/python benchmarks/bench_vector.py [--n 1 2 4 8 16] [--steps 300] [--episodes-per-env 2]
        [--cases state rgb256 sidecar_state] [--modes vector async local bare] [--rounds 1]
        [--out benchmarks/results/vector.json]

Franka Panda, lift_cube, 20 Hz control, ``--steps`` control steps per episode (the episode never
succeeds: a trivial zero-action policy), ``episodes-per-env x N`` episodes per point. Cases:

- ``state``: in-process MuJoCo, state-only observations (no rendering);
- ``rgb256``: in-process MuJoCo, both cameras (camera1 + wrist camera2) at 256x256 rendered into
  every observation (EGL; the policy reads them every step);
- ``sidecar_state``: the same scene behind the sidecar (each worker owns its own sidecar process),
  state-only.

Modes: ``vector`` is ``simseam.runner.vector.VectorEnv`` (N worker processes stepped together by one
batched policy in this process); ``async`` the same with ``sync=False`` (the policy acts on whichever
workers have answered); ``local`` is ``VectorEnv.run_local`` (the built-in ``zero`` policy inside
each worker, whole episodes per command; state-only cases only); ``bare`` is N plain independent processes, each running its share
of the episodes with ``run_episodes`` (the baseline the vector API must not fall behind). Timing
starts once every worker has built its rollout and stops when the last episode ends. Efficiency =
throughput(N) / (N x throughput(1)) of the same case and mode. Prints a table and writes JSON.
"""

from __future__ import annotations

import argparse
import json
import multiprocessing as mp
import os
import platform
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from simseam.policies.batch import PolicyBatch  # noqa: E402
from simseam.runner.vector import RolloutRecipe, VectorEnv  # noqa: E402

CASES = {
    "state": ({"name": "mujoco"}, False),
    "rgb256": ({"name": "mujoco"}, True),
    "sidecar_state": ({"name": "mujoco", "process": "sidecar"}, False),
}


# --robot: a built-in name or a manifest path (e.g. one with a file: URDF on a GPU machine); spawned
# workers read it from the environment
ROBOT = os.environ.get("SIMSEAM_BENCH_ROBOT", "franka_panda")


def scene_dict(case: str, steps: int) -> dict:
    from simseam.runner.scene_config import SceneConfig

    engine, _ = CASES[case]
    cfg = SceneConfig.model_validate({"robot": ROBOT, "task": "lift_cube", "engine": engine,
                                      "image_size": [256, 256], "max_steps": steps, "control_hz": 20})
    return cfg.model_dump(mode="json")


class ZeroBatch(PolicyBatch):
    """Zero Cartesian deltas for every environment; reads images every step when ``images``."""

    def __init__(self, n: int, images: bool):
        self.n, self.uses_images = n, images

    def reset(self, env, spec):
        self.dim = spec.action_dim

    def observe_next(self, env):
        from simseam.seam import STATE_ONLY

        return None if self.uses_images else STATE_ONLY

    def act_batch(self, envs, observations):
        return np.zeros((len(envs), self.dim), np.float32)


class ZeroPolicy:
    requires_privileged = False

    def __init__(self, images: bool):
        self.uses_images = images

    def reset(self, spec):
        self.dim = spec.action_dim

    def observe_next(self):
        from simseam.seam import STATE_ONLY

        return None if self.uses_images else STATE_ONLY

    def act(self, obs):
        return np.zeros(self.dim, np.float32)


def run_vector(case: str, n: int, steps: int, episodes: int, sync: bool = True) -> dict:
    _, images = CASES[case]
    recipe = RolloutRecipe(scene_dict(case, steps), str(Path.cwd()), render_images=images)
    with VectorEnv(recipe, n) as vec:
        vec._wait_booted(vec.slots)  # every worker ready before the clock starts
        t0, c0 = time.perf_counter(), time.process_time()
        results = vec.run(ZeroBatch(n, images), range(episodes), sync=sync)
        wall, cpu = time.perf_counter() - t0, time.process_time() - c0
    steps = sum(r.steps for r in results)
    # the main process's own CPU time per env-step: what bounds lockstep efficiency at large N
    return {"wall_s": wall, "env_steps": steps, "episodes": len(results), "main_cpu_us_per_env_step": cpu / steps * 1e6}


def run_local(case: str, n: int, steps: int, episodes: int) -> dict:
    """The policy inside each worker (``VectorEnv.run_local``): the built-in ``zero`` policy, state only."""
    recipe = RolloutRecipe(scene_dict(case, steps), str(Path.cwd()), render_images=False)
    with VectorEnv(recipe, n) as vec:
        vec._wait_booted(vec.slots)
        t0 = time.perf_counter()
        results = vec.run_local("zero", {}, range(episodes))
        wall = time.perf_counter() - t0
    return {"wall_s": wall, "env_steps": sum(r.steps for r in results), "episodes": len(results)}


def _bare_worker(case, steps, indices, ready, go, out):
    from simseam.runner.scene_config import SceneConfig, build_rollout
    from simseam.runner.session import run_episodes

    _, images = CASES[case]
    rollout = build_rollout(SceneConfig.model_validate(scene_dict(case, steps)), Path.cwd(), render_images=images)
    try:
        ready.put(os.getpid())
        go.wait()
        res = run_episodes(rollout, ZeroPolicy(images), indices)
        out.put(sum(r.steps for r in res))
    finally:
        rollout.close()


def run_bare(case: str, n: int, steps: int, episodes: int) -> dict:
    ctx = mp.get_context("spawn")
    ready, out, go = ctx.Queue(), ctx.Queue(), ctx.Event()
    procs = [ctx.Process(target=_bare_worker, args=(case, steps, list(range(k, episodes, n)), ready, go, out))
             for k in range(n)]
    for p in procs:
        p.start()
    try:
        for _ in procs:
            ready.get(timeout=600)
        t0 = time.perf_counter()
        go.set()
        total = sum(out.get(timeout=3600) for _ in procs)
        wall = time.perf_counter() - t0
    finally:
        for p in procs:
            p.join(30)
            if p.is_alive():
                p.kill()
    return {"wall_s": wall, "env_steps": total, "episodes": episodes}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--episodes-per-env", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=1, help="repeat each point; the median round is reported")
    ap.add_argument("--cases", nargs="+", default=list(CASES), choices=list(CASES))
    ap.add_argument("--modes", nargs="+", default=["vector", "async", "local", "bare"],
                    choices=["vector", "async", "local", "bare"])
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/vector.json"))
    ap.add_argument("--robot", default=ROBOT, help="built-in robot name or manifest path (absolute)")
    args = ap.parse_args()
    globals()["ROBOT"] = os.environ["SIMSEAM_BENCH_ROBOT"] = args.robot
    rows = []
    for case in args.cases:
        for mode in args.modes:
            base = None
            for n in args.n:
                episodes = args.episodes_per_env * n
                if mode == "local" and CASES[case][1]:
                    continue  # the built-in zero policy reads no images
                rounds = []
                for _ in range(args.rounds):
                    if mode == "bare":
                        rounds.append(run_bare(case, n, args.steps, episodes))
                    elif mode == "local":
                        rounds.append(run_local(case, n, args.steps, episodes))
                    else:
                        rounds.append(run_vector(case, n, args.steps, episodes, sync=mode == "vector"))
                r = sorted(rounds, key=lambda x: x["env_steps"] / x["wall_s"])[len(rounds) // 2]  # the median round
                r["rounds_env_steps_per_s"] = [x["env_steps"] / x["wall_s"] for x in rounds]
                sps = r["env_steps"] / r["wall_s"]
                base = sps if n == args.n[0] and base is None else base
                eff = sps / (n / args.n[0] * base) if base else None
                row = {"case": case, "mode": mode, "n": n, **r, "env_steps_per_s": sps,
                       "episodes_per_hour": r["episodes"] / r["wall_s"] * 3600, "efficiency": eff}
                rows.append(row)
                print(f"{case:14s} {mode:7s} N={n:3d}  {sps:9.1f} env-steps/s  {row['episodes_per_hour']:9.0f} "
                      f"episodes/h  efficiency {eff:.2f}", flush=True)
    print()
    print(f"| case | mode | N | env-steps/s | episodes/h ({args.steps} steps) | efficiency |")
    print("|---|---|---:|---:|---:|---:|")
    for r in rows:
        print(f"| {r['case']} | {r['mode']} | {r['n']} | {r['env_steps_per_s']:.0f} | {r['episodes_per_hour']:.0f} | "
              f"{r['efficiency']:.2f} |")
    machine = {"cpus": os.cpu_count(), "affinity": len(os.sched_getaffinity(0)), "platform": platform.platform(),
               "python": platform.python_version(), "mujoco_gl": os.environ.get("MUJOCO_GL")}
    try:
        import subprocess

        gpu = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                             text=True, timeout=10)
        machine["gpu"] = gpu.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        machine["gpu"] = None
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"machine": machine, "steps_per_episode": args.steps,
                                    "episodes_per_env": args.episodes_per_env, "rows": rows}, indent=2))
    print(f"\nwrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
