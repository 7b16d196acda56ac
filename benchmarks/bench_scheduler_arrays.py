"""The episode scheduler's own cost per step on the array path, before and after its bookkeeping on columns.

    .venv/bin/python benchmarks/bench_scheduler_arrays.py [--n 1024 8192] [--rounds 3] [--port-worlds 1024]
        [--out benchmarks/results/scheduler_arrays_cpu.json]

On the array path (a policy with ``act_arrays`` on a batch that offers arrays: MuJoCo Warp's worlds, the
Meta-World and LIBERO ports) every environment steps in every flight. Two ways of doing a step's bookkeeping,
in the same run, side by side:

- ``per_env``: the per-environment loop (each busy environment's steps, reward, latencies and success updated one
  by one, its info read as a dict), with infos handed out as a list of dicts, one per environment: what the
  scheduler and the ports did before;
- ``columns``: ``runner.scheduler._Tally`` (steps, rewards, success and latencies as arrays over the environments,
  written into an episode's result when it ends) with infos as ``seam.InfoColumns`` (read as one success column;
  a dict built only for an episode that ends).

Section ``scheduler``: a batch with no simulator (``FreeArrays``: one vectorised NumPy step; episodes of 40-89
steps by seed, so some end at every step and are reset), the policy answering one cached zero array: the wall
time per step is the scheduler's and the batch's bookkeeping alone. Section ``port`` (``--port-worlds N``, 0 skips
it): Meta-World's port (reach-v3) on Warp's CPU device, two episodes of ``--port-steps`` per world, the wall time
less the physics (``physics.advance``) and the resets (``reset``: every world's twice, each a model update on
Warp's CPU device), per step: the scheduler's bookkeeping, the port's observation, reward and success (on the CPU
device here, on the GPU there) and the policy's cached answer. Each point's median over ``--rounds``; every round is kept in the JSON.
"""

from __future__ import annotations

import argparse
import json
import statistics
import sys
import time
from contextlib import contextmanager
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "src"))
sys.path.insert(1, str(Path(__file__).resolve().parent))
from cpu_facts import CpuWindow, topology  # noqa: E402

from simseam.runner import scheduler  # noqa: E402
from simseam.seam import (  # noqa: E402
    INFO_DIAGNOSTICS, INFO_STEPS, STATE_ONLY, BatchStepResult, InfoColumns, SyncStepPair)

DIAGNOSTICS = ("near_object", "grasp_success", "grasp_reward", "in_place_reward", "obj_to_target", "unscaled_reward")


class FreeArrays(SyncStepPair):
    """``n`` environments with no simulator, stepped as one NumPy batch: episode ``seed`` lasts ``40 + seed % 50``
    steps and succeeds at its end when ``seed`` is odd; six diagnostics a step, as Meta-World's port hands out.
    ``columns``: its infos as ``InfoColumns``, else a list of dicts (one per environment)."""

    def __init__(self, n: int, columns: bool):
        sys.path.insert(0, str(REPO / "tests"))
        from spec_factory import make_spec

        self.spec, self.num_envs, self.columns = make_spec(action_dim=4, cameras={}, state_dim=39), n, columns
        self.t, self.length, self.odd = np.zeros(n, np.int64), np.zeros(n, np.int64), np.zeros(n, bool)
        self.obs = np.zeros((n, 39), np.float32)

    def reset(self, envs, seeds, observe=None):
        idx, seeds = np.asarray(envs), np.asarray(seeds)
        self.t[idx], self.length[idx], self.odd[idx] = 0, 40 + seeds % 50, seeds % 2 == 1
        return [{} for _ in envs]

    def observation_arrays(self, observe=None):
        return {"state": self.obs}

    def step_arrays(self, envs, actions, observe=None) -> BatchStepResult:
        idx = np.asarray(envs)
        self.t[idx] += 1
        end = self.t[idx] >= self.length[idx]
        success, steps = end & self.odd[idx], self.t[idx]
        diags = {k: (steps * (i + 1) * 0.37).astype(np.float64) for i, k in enumerate(DIAGNOSTICS)}
        if self.columns:
            infos = InfoColumns({"success": success, INFO_STEPS: steps}, diags)
        else:  # as the ports built them before: Python values, row by row
            rows = zip(*(diags[k].tolist() for k in DIAGNOSTICS))
            infos = [{"success": s, INFO_STEPS: n, INFO_DIAGNOSTICS: dict(zip(DIAGNOSTICS, values))}
                     for s, n, values in zip(success.tolist(), steps.tolist(), rows)]
        return BatchStepResult(idx, [{} for _ in envs], (0.01 * steps).astype(np.float64), success, end & ~success, infos)

    def step(self, envs, actions, observe=None):
        return self.step_arrays(envs, actions, observe)

    def failures(self):
        return {}

    def render(self, env):
        return None

    def close(self):
        pass


class ZeroArrays:
    """A policy of the array path that answers one cached zero array and asks for no image (``STATE_ONLY``, as a
    state policy does: the scheduler takes the union of every environment's request twice a step)."""

    def __init__(self, n: int, dim: int):
        self.n, self.zeros = n, np.zeros((n, dim), np.float32)
        self.calls = 0

    def reset(self, env, spec):
        pass

    def observe_next(self, env):
        return STATE_ONLY

    def act_batch(self, envs, observations):
        return self.zeros[:len(envs)]

    def act_arrays(self, arrays):
        self.calls += 1
        return self.zeros


@contextmanager
def bookkeeping(mode: str):
    """``per_env``: the scheduler's per-environment loop (its ``_Tally`` left out); ``columns``: as it is."""
    original = scheduler._BatchRun.__init__

    def per_env(self, *a, **k):
        original(self, *a, **k)
        self.tally = None

    if mode == "per_env":
        scheduler._BatchRun.__init__ = per_env
    try:
        yield
    finally:
        scheduler._BatchRun.__init__ = original


def scheduler_point(n: int, mode: str, episodes_per_env: int) -> dict:
    batch, policy = FreeArrays(n, columns=mode == "columns"), ZeroArrays(n, 4)
    with bookkeeping(mode):
        t0 = time.perf_counter()
        results = scheduler.run_batch(batch, policy, range(n * episodes_per_env), keep=True)
        wall = time.perf_counter() - t0
    steps = sum(r.steps for r in results)
    return {"wall_s": wall, "flights": policy.calls, "env_steps": steps, "ms_per_step": wall / policy.calls * 1e3,
            "us_per_env_step": wall / steps * 1e6, "successes": sum(r.success for r in results)}


def port_point(n: int, mode: str, steps: int, device: str = "cpu") -> dict:
    from simseam.backends.metaworld_gpu.rollout import MetaWorldBatchRollout
    from simseam.backends.metaworld_gpu.worker import NativeWorker

    with NativeWorker() as worker:
        batch = MetaWorldBatchRollout({"task": "reach-v3", "max_steps": steps}, n, worker, device=device)
        policy = ZeroArrays(n, 4)
        scheduler.run_batch(batch, policy, range(n))  # untimed: kernels loaded, reset states cached
        spent = {"physics": 0.0, "resets": 0.0}

        def timed(call, key: str):
            def run(*a, **k):
                t = time.perf_counter()
                out = call(*a, **k)
                spent[key] += time.perf_counter() - t
                return out
            return run

        physics = batch.world.physics
        physics.advance, batch.reset = timed(physics.advance, "physics"), timed(batch.reset, "resets")
        policy.calls = 0
        with bookkeeping(mode):
            t0 = time.perf_counter()
            scheduler.run_batch(batch, policy, range(n, 3 * n))
            wall = time.perf_counter() - t0
        batch.close()
    rest = wall - spent["physics"] - spent["resets"]
    return {"wall_s": wall, "physics_s": spent["physics"], "resets_s": spent["resets"], "flights": policy.calls,
            "ms_per_step_without_physics_and_resets": rest / policy.calls * 1e3,
            "ms_per_step_without_resets": (wall - spent["resets"]) / policy.calls * 1e3}


def main() -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="*", default=[1024, 8192])
    ap.add_argument("--episodes-per-env", type=int, default=3)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--port-worlds", type=int, default=1024, help="Meta-World's port on Warp's CPU device (0 skips)")
    ap.add_argument("--port-steps", type=int, default=6, help="the port's episode length (its max_steps)")
    ap.add_argument("--port-device", default="cpu", help="the port's Warp device (cuda:0: physics.advance then "
                    "times only its launches; read ms_per_step_without_resets there)")
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "scheduler_arrays_cpu.json")
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args()
    if args.out.exists() and not args.overwrite:
        print(f"{args.out} exists; pass --overwrite to replace it", file=sys.stderr)
        return 2
    doc: dict = {"benchmark": "scheduler_arrays", "argv": sys.argv[1:], "machine": topology(), "scheduler": {},
                 "port": {}, "port_device": args.port_device}
    with CpuWindow() as window:
        for n in args.n:
            for r in range(args.rounds):  # the modes alternate within a round
                for mode in ("per_env", "columns"):
                    doc["scheduler"].setdefault(f"{n}", {}).setdefault(mode, []).append(
                        scheduler_point(n, mode, args.episodes_per_env))
        if args.port_worlds:
            for r in range(args.rounds):
                for mode in ("per_env", "columns"):
                    doc["port"].setdefault(mode, []).append(port_point(args.port_worlds, mode, args.port_steps,
                                                                         args.port_device))
    doc["cpu_window"] = window.facts()
    print_table(doc, args.port_worlds, args.port_device)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps(doc, indent=1))
    print(f"wrote {args.out}")
    return 0


def print_table(doc: dict, port_worlds: int, device: str) -> None:
    def med(rows: list, key: str) -> float:
        return statistics.median(r[key] for r in rows)

    print(f"\n{'section':<34} {'per_env ms/step':>16} {'columns ms/step':>16} {'ratio':>7}   rounds (per_env | columns)")
    for n, modes in doc["scheduler"].items():
        a, b = med(modes["per_env"], "ms_per_step"), med(modes["columns"], "ms_per_step")
        rounds = " ".join(f"{r['ms_per_step']:.2f}" for r in modes["per_env"]) + " | " + \
            " ".join(f"{r['ms_per_step']:.2f}" for r in modes["columns"])
        print(f"{'scheduler, ' + n + ' environments':<34} {a:16.2f} {b:16.2f} {a / b:6.1f}x   {rounds}")
    if doc["port"]:
        key = "ms_per_step_without_physics_and_resets"
        a, b = med(doc["port"]["per_env"], key), med(doc["port"]["columns"], key)
        rounds = " ".join(f"{r[key]:.1f}" for r in doc["port"]["per_env"]) + " | " + \
            " ".join(f"{r[key]:.1f}" for r in doc["port"]["columns"])
        print(f"{f'Meta-World port, {port_worlds} worlds*':<34} {a:16.2f} {b:16.2f} {a / b:6.1f}x   {rounds}")
        print(f"* the seam's step on Warp's device {device}, less physics.advance and the resets (its policy: one "
              "cached zero array); on CUDA advance returns once its kernels are launched, so the wait for them is "
              "in the rest")
        whole = {m: [round(r["ms_per_step_without_resets"], 2) for r in rows] for m, rows in doc["port"].items()}
        print(f"the port's whole step (physics included, resets not), ms: {whole}")


if __name__ == "__main__":
    sys.exit(main())
