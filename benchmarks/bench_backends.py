"""What the seam costs on each benchmark backend, and what provisioning a backend costs.

    .venv/bin/python benchmarks/bench_backends.py [--steps 200] [--rounds 3] [--provision] [--json PATH]
        [--backends pusht,metaworld] [--kinds state] [--paths local,zmq]

Per backend (Meta-World reach-v3 with a 224x224 corner2 camera, PushT at 96x96, ALOHA
insertion with its 480x640 top camera, ManiSkill PickCube-v1 state-only) and per observation kind:

- ``state``: native ``env.step`` alone vs the seam's ``step(a, STATE_ONLY)``;
- ``pixels``: what a pixel policy needs each step: native ``env.step`` + ``env.render()``
  (Meta-World), native ``step`` with ``obs_type="pixels_agent_pos"`` (PushT, ALOHA; ALOHA's
  native task renders three 480x640 cameras per step whether read or not) vs the seam's
  ``step(a)`` with its one camera. LIBERO (libero_spatial task 3, 256x256, as openpi's client)
  renders both cameras on every native step in both kinds (it has no state-only mode); the seam's
  ``state`` step renders none.

``native`` runs in the backend's own venv (a subprocess that imports no simseam), ``seam``
is a ``SidecarRollout`` on that venv driven from this process; the same seeded action
stream in both. Rounds alternate native / seam; reported: the median over rounds of each
side's per-step p50 and the seam's overhead = seam p50 / native p50 - 1 (goal: <= 5 %).

``--provision``: also provisions every backend from scratch into a temporary directory with
pip's cache disabled (a cold CI run) and reports time and size; without it, the numbers of
the existing venvs' own provisioning records are reported (pip's cache may have been warm).

Prints a table and writes JSON (default benchmarks/results/backends.json). Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
CASES = {
    "metaworld": {"task": "reach-v3", "camera": "corner2", "image_size": [224, 224]},
    "pusht": {"image_size": [96, 96]},
    "aloha": {"task": "insertion", "cameras": ["top"]},
    "libero": {"suite": "libero_spatial", "task": 3, "image_size": [256, 256], "settle_steps": 10},
    "robosuite": {"task": "Lift", "robot": "Panda", "image_size": [128, 128]},
    "maniskill": {"task": "PickCube-v1"},
}
#: observation kinds per backend (ManiSkill: state only, SAPIEN cannot render on a CPU)
KINDS = {"maniskill": ("state",)}

NATIVE = r'''
import json, sys, time
import numpy as np
backend, cfg, kind, seed, path = sys.argv[1], json.loads(sys.argv[2]), sys.argv[3], int(sys.argv[4]), sys.argv[5]
actions = np.load(path)
if backend == "metaworld":
    import metaworld
    b = metaworld.MT1(cfg["task"], seed=0)
    h, w = cfg["image_size"]
    env = b.train_classes[cfg["task"]](render_mode="rgb_array", camera_name=cfg["camera"], width=w, height=h)
    env.max_path_length = 10**9
    env.set_task(b.train_tasks[seed % 50]); env.seed(seed); env.reset()
    def step(a):
        env.step(a)
        if kind == "pixels":
            env.render()
elif backend == "pusht":
    from gym_pusht.envs import PushTEnv
    h, w = cfg["image_size"]
    env = PushTEnv(obs_type="state" if kind == "state" else "pixels_agent_pos", observation_width=w,
                   observation_height=h)
    env.reset(seed=seed)
    step = env.step
elif backend == "libero":  # as openpi's LIBERO client: both 256x256 cameras on every step (it has no other mode)
    import os
    from libero.libero import benchmark, get_libero_path
    from libero.libero.envs import OffScreenRenderEnv
    suite = benchmark.get_benchmark_dict()[cfg["suite"]]()
    task = suite.get_task(cfg["task"])
    h, w = cfg["image_size"]
    env = OffScreenRenderEnv(bddl_file_name=os.path.join(get_libero_path("bddl_files"), task.problem_folder,
                             task.bddl_file), camera_heights=h, camera_widths=w)
    env.seed(seed); env.reset(); env.set_init_state(suite.get_task_init_states(cfg["task"])[seed % 50])
    step = env.step
elif backend == "robosuite":  # state: use_camera_obs=False (robosuite's own state-only mode)
    import robosuite as suite
    h, w = cfg["image_size"]
    env = suite.make(cfg["task"], robots=cfg["robot"], has_renderer=False, has_offscreen_renderer=kind != "state",
                     use_camera_obs=kind != "state", camera_names=["agentview", "robot0_eye_in_hand"],
                     camera_heights=h, camera_widths=w, horizon=10**9)
    env.reset()
    step = env.step
elif backend == "maniskill":  # obs_mode="state", PhysX CPU; physics-only where SAPIEN cannot render
    import gymnasium as gym
    import sapien
    import sapien.wrapper.urdf_loader
    try:
        sapien.render.RenderMaterial()
    except RuntimeError:
        class Inert:
            def __init__(self, *a, **k): pass
        sapien.render.RenderMaterial = sapien.pysapien.render.RenderMaterial = Inert
        sapien.wrapper.urdf_loader.RenderMaterial = Inert
    import mani_skill.envs
    import torch
    torch.set_num_threads(1)  # as the backend does
    env = gym.make(cfg["task"], obs_mode="state", control_mode="pd_ee_delta_pose", sim_backend="physx_cpu",
                   num_envs=1, render_mode=None, render_backend="none")
    env.reset(seed=seed)
    step = env.step
else:
    from gym_aloha.env import AlohaEnv
    env = AlohaEnv(task=cfg["task"], obs_type="pixels_agent_pos")
    env.reset(seed=seed)
    if kind == "state":  # the native task renders three cameras per step; "state" drives dm_control alone
        task = env._env.task
        task.get_observation = lambda p: {"qpos": task.get_qpos(p), "images": {"top": np.zeros((0, 0, 3), np.uint8)}}
    step = env.step
times = []
for a in actions:
    t0 = time.perf_counter(); step(a); times.append(time.perf_counter() - t0)
assert "simseam" not in sys.modules
print(json.dumps(times))
'''


def actions_for(backend: str, n: int, rng: np.random.Generator, start: np.ndarray | None) -> np.ndarray:
    if backend == "metaworld":
        return rng.uniform(-1, 1, (n, 4)).astype(np.float32)
    if backend == "pusht":
        return rng.uniform(60, 450, (n, 2)).astype(np.float32)
    if backend in ("libero", "robosuite"):
        return rng.uniform(-0.3, 0.3, (n, 7)).astype(np.float32)
    if backend == "maniskill":
        return rng.uniform(-1, 1, (n, 7)).astype(np.float32)
    return (start + np.cumsum(rng.normal(0, 0.005, (n, 14)), axis=0)).astype(np.float32)


def native_times(backend: str, cfg: dict, kind: str, seed: int, actions: np.ndarray) -> list[float]:
    from simseam.backends.provision import require

    with tempfile.TemporaryDirectory() as tmp:
        np.save(Path(tmp) / "a.npy", actions)
        env = {k: v for k, v in os.environ.items() if k not in ("PYTHONPATH", "VIRTUAL_ENV")}
        env.update(MUJOCO_GL=env.get("MUJOCO_GL", "egl"), PYGAME_HIDE_SUPPORT_PROMPT="1")
        out = subprocess.run([str(require(backend)), "-c", NATIVE, backend, json.dumps(cfg), kind, str(seed),
                              str(Path(tmp) / "a.npy")], capture_output=True, text=True, env=env, check=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def seam_times(rollout, kind: str, seed: int, actions: np.ndarray) -> list[float]:
    from simseam.seam import STATE_ONLY

    req = STATE_ONLY if kind == "state" else None
    rollout.reset(seed, req)
    times = []
    for a in actions:
        t0 = time.perf_counter()
        rollout.step(a, req)
        times.append(time.perf_counter() - t0)
    return times


def provision_cold(names: list[str]) -> dict:
    from simseam.backends.provision import provision

    out = {}
    with tempfile.TemporaryDirectory(prefix="simseam-backends-cold-") as tmp:
        old = os.environ.get("SIMSEAM_BACKENDS_DIR"), os.environ.get("PIP_NO_CACHE_DIR")
        os.environ["SIMSEAM_BACKENDS_DIR"], os.environ["PIP_NO_CACHE_DIR"] = tmp, "1"
        try:
            for n in names:
                rec = provision(n)
                out[n] = {"seconds": rec["seconds"], "bytes": rec["bytes"], "pip_cache": "disabled"}
        finally:
            for k, v in zip(("SIMSEAM_BACKENDS_DIR", "PIP_NO_CACHE_DIR"), old):
                if v is None:
                    os.environ.pop(k, None)
                else:
                    os.environ[k] = v
    return out


def main() -> None:
    from simseam.sidecar.benchmark import open_benchmark
    from simseam.backends.provision import marker

    ap = argparse.ArgumentParser()
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--backends", default=",".join(CASES))
    ap.add_argument("--provision", action="store_true", help="also provision each backend cold (minutes)")
    ap.add_argument("--json", type=Path, default=HERE / "results" / "backends.json")
    ap.add_argument("--kinds", default="state,pixels", help="observation kinds (comma list)")
    ap.add_argument("--paths", default="local", help="sidecar paths (comma list): local (the fast path: Unix socket "
                    "+ shared-memory slots), zmq (ZeroMQ over ipc, the path before it); rounds alternate native / each")
    args = ap.parse_args()
    names = [n for n in args.backends.split(",") if n]
    paths = [p for p in args.paths.split(",") if p]
    rows = []
    for name in names:
        cfg = CASES[name]
        rollouts = {p: open_benchmark(name, cfg, local=p == "local") for p in paths}
        for p, ro in rollouts.items():
            assert ro.fast == (p == "local"), f"{name}: path {p} not taken"
        start = np.asarray(next(iter(rollouts.values())).reset(0)["state"], dtype=np.float64)
        for kind in [k for k in args.kinds.split(",") if k and k in KINDS.get(name, ("state", "pixels"))]:
            steps = args.steps if kind == "state" or name == "pusht" else max(20, args.steps // 4)
            if name == "libero":  # ~0.1-0.5 s per step on this CPU
                steps = max(10, args.steps // 10)
            if name == "robosuite":
                steps = max(20, args.steps // 4)
            nat, sea = [], {p: [] for p in paths}
            for r in range(args.rounds):
                acts = actions_for(name, steps, np.random.default_rng(r), start)
                nat.append(statistics.median(native_times(name, cfg, kind, r, acts)))
                for p in (paths if r % 2 == 0 else paths[::-1]):
                    sea[p].append(statistics.median(seam_times(rollouts[p], kind, r, acts)))
            n_ms = statistics.median(nat) * 1e3
            for p in paths:
                s_ms = statistics.median(sea[p]) * 1e3
                rows.append({"backend": name, "obs": kind, "path": p, "steps": steps, "rounds": args.rounds,
                             "native_p50_ms": n_ms, "seam_p50_ms": s_ms, "overhead_pct": (s_ms / n_ms - 1) * 100,
                             "added_ms": s_ms - n_ms})
        for ro in rollouts.values():
            ro.close()
    prov = {n: {"seconds": m["seconds"], "bytes": m["bytes"], "pip_cache": "as it was"}
            for n in names if (m := marker(n))}
    if args.provision:
        prov = provision_cold(names)
    print(f"{'backend':10} {'obs':7} {'path':6} {'native p50':>11} {'seam p50':>10} {'added':>9} {'overhead':>9}")
    for r in rows:
        print(f"{r['backend']:10} {r['obs']:7} {r['path']:6} {r['native_p50_ms']:9.2f}ms {r['seam_p50_ms']:8.2f}ms "
              f"{r['added_ms']:7.2f}ms {r['overhead_pct']:8.1f}%")
    print(f"\n{'backend':10} {'provisioning':>13} {'venv size':>10}  pip cache")
    for n, p in prov.items():
        print(f"{n:10} {p['seconds']:11.0f} s {p['bytes'] / 2**20:7.0f} MiB  {p['pip_cache']}")
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps({"step": rows, "provisioning": prov, "python": sys.version.split()[0],
                                     "cpus": os.cpu_count()}, indent=2))
    print(f"\nwrote {args.json}")


if __name__ == "__main__":
    main()
