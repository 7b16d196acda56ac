"""How chaotic a trained LIBERO policy's episodes are in its object-state input: the CPU benchmark, the same
seeds, ``environment_state`` perturbed by Gaussian noise of a few sizes (0: the unperturbed control).

    .venv/bin/python benchmarks/libero_policy_input_noise.py --policy lerobot:CKPT --task libero_spatial/0 \
        [--seeds 30:50] [--sigmas 0,3e-7] [--json PATH] [--overwrite]

Each sigma runs the episodes in this process (``session.run_episodes``) on LIBERO itself behind the sidecar
(``open_benchmark``, the preset's step limit and settle steps), the policy reading ``environment_state`` plus the
noise, drawn from one seeded generator per sigma. MuJoCo Warp's float32 state differs from LIBERO's by about
2e-7 in that input at a reset and up to 2e-5 later (docs/benchmarks.md), so sigma = 3e-7 asks: would any
difference of that size change which episodes this policy solves? Prints each sigma's successes and the episodes
whose outcome differs from the control's; writes JSON. Nothing is asserted.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
from pathlib import Path
from typing import Any

import numpy as np

HERE = Path(__file__).resolve().parent


class NoisyObjects:
    """A rollout whose observations' ``environment_state`` gets N(0, sigma) noise (its dtype kept)."""

    def __init__(self, inner: Any, sigma: float, seed: int = 0):
        self.inner, self.sigma, self.rng = inner, float(sigma), np.random.default_rng(seed)

    def __getattr__(self, name: str) -> Any:
        return getattr(self.inner, name)

    def _perturb(self, obs: dict) -> dict:
        if self.sigma and "environment_state" in obs:
            e = np.asarray(obs["environment_state"])
            obs["environment_state"] = (e + self.rng.normal(0.0, self.sigma, e.shape)).astype(e.dtype)
        return obs

    def reset(self, *args: Any, **kwargs: Any) -> dict:
        return self._perturb(self.inner.reset(*args, **kwargs))

    def step(self, *args: Any, **kwargs: Any) -> Any:
        result = self.inner.step(*args, **kwargs)
        self._perturb(result.observation)
        return result


def run(policy_spec: str, task: str, first: int, count: int, sigma: float) -> dict[int, list]:
    from simseam.policies.base import make_policy
    from simseam.runner.evaluate import preset
    from simseam.runner.session import run_episodes
    from simseam.sidecar.benchmark import open_benchmark

    suite, _, index = task.partition("/")
    config = {**preset(suite).backend_config(False, task), "suite": suite, "task": int(index), "environment_state": True}
    rollout = open_benchmark("libero", config)
    try:
        results = run_episodes(NoisyObjects(rollout, sigma), make_policy(policy_spec, device="cpu"), range(count),
                               seed=first)
    finally:
        rollout.close()
    return {r.seed: [bool(r.success), int(r.steps)] for r in results}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--policy", required=True)
    ap.add_argument("--task", default="libero_spatial/0")
    ap.add_argument("--seeds", default="30:50", help="A:B: episode seeds A..B-1 (init state seed % 50)")
    ap.add_argument("--sigmas", default="0,3e-7")
    ap.add_argument("--json", type=Path, default=HERE / "results" / "libero_policy_input_noise.json")
    ap.add_argument("--overwrite", action="store_true")
    args = ap.parse_args()
    if args.json.exists() and not args.overwrite:
        ap.error(f"--json: {args.json} exists; pass --overwrite to replace it")
    first, _, end = args.seeds.partition(":")
    first, end = int(first), int(end)
    runs = {}
    for sigma in (float(s) for s in args.sigmas.split(",")):
        runs[str(sigma)] = run(args.policy, args.task, first, end - first, sigma)
        ok = sum(v[0] for v in runs[str(sigma)].values())
        control = runs[next(iter(runs))]
        flipped = sorted(s for s, v in runs[str(sigma)].items() if v[0] != control[s][0])
        print(f"sigma {sigma:g}: {ok}/{end - first} solved; outcome differs from the first sigma's on {flipped}",
              flush=True)
    doc = {"benchmark": "libero_policy_input_noise", "policy": args.policy, "task": args.task,
           "seeds": [first, end - 1], "runs": runs,
           "machine": {"cpus": os.cpu_count(), "python": platform.python_version()}}
    args.json.parent.mkdir(parents=True, exist_ok=True)
    args.json.write_text(json.dumps(doc, indent=1) + "\n")
    print(f"wrote {args.json}")


if __name__ == "__main__":
    main()
