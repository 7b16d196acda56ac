"""The HAL's added cost per control step, on this machine.

    .venv/bin/python benchmarks/bench_hal.py [--reps 200] [--blocks 5] [--rounds 5]

One state-only panda_mobile scene in nav_obstacles (MuJoCo, no images: the
lidar scan is in every observation), so the HAL's own cost is not hidden under
rendering. Cases, timed on the SAME scene:

- ``rollout_step``: ``scene.step(action)`` with a pre-packed action (zero
  Cartesian delta, gripper open, base twist ``[0.2, 0, 0.1]``).
- ``hal_send_tick``: ``hal.send_action([0.2, 0, 0.1], BODY_TWIST)`` then
  ``hal.tick()``, which packs the same action through the layout and steps.
- ``hal_send_only``: ``hal.send_action`` alone (validation + storing), for scale.
- ``hal_send_tick_null``: send + tick over a null rollout (same RolloutSpec, ``step`` returns a
  stored result at once): the HAL's own cost without the simulator's step noise, which at
  ~1-2 ms per step is larger than the difference being measured.

Blocks of ``--reps`` calls of each case alternate (A B A B ...) so drift in the
machine's speed hits both alike; per round, each case's per-call p50 / mean
over all its blocks; the table reports medians over rounds, plus the
difference ``hal_send_tick - rollout_step`` (the HAL's added cost per step).
Writes JSON (``--json``, default ``benchmarks/results/hal.json``).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from simseam.hal import SimAttachedHAL  # noqa: E402
from simseam.robot.manifest import load_robot  # noqa: E402
from simseam.scene.manifest_scene import ManifestScene, SceneOptions  # noqa: E402
from simseam.seam import ControlMode, StepResult  # noqa: E402

HERE = Path(__file__).resolve().parent
TWIST = [0.2, 0.0, 0.1]


def timed(fn, n: int) -> np.ndarray:
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        fn()
        out[i] = time.perf_counter() - t0
    return out * 1e3


class NullRollout:
    """A SimRollout that advertises a real scene's spec and steps in no time."""

    def __init__(self, scene: ManifestScene):
        self.spec, self.action_dim = scene.spec, scene.action_dim
        self._obs = scene.reset(0)
        self._result = StepResult(self._obs, 0.0, False, False, {"success": False})

    def reset(self, seed=None, observe=None):
        return self._obs

    def step(self, action, observe=None):
        return self._result

    def render(self):
        return None

    def sim_time_ns(self):
        return 0

    def close(self):
        pass


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--reps", type=int, default=200, help="calls per block")
    ap.add_argument("--blocks", type=int, default=5, help="blocks of each case per round (interleaved)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--json", default=str(HERE / "results" / "hal.json"))
    args = ap.parse_args()

    scene = ManifestScene(load_robot("panda_mobile"), "nav_obstacles", "mujoco", SceneOptions(render_images=False))
    hal = SimAttachedHAL(scene, hold_time_s=0.5)
    hal.connect()
    action = hal.action.pack(arm=np.zeros(hal.action.arm_dim), grip=-1.0, base=TWIST)

    def hal_step():
        hal.send_action(TWIST, ControlMode.BODY_TWIST)
        hal.tick()

    null_hal = SimAttachedHAL(NullRollout(scene), hold_time_s=0.5)
    null_hal.connect()

    def null_step():
        null_hal.send_action(TWIST, ControlMode.BODY_TWIST)
        null_hal.tick()

    cases = {
        "rollout_step": lambda: scene.step(action),
        "hal_send_tick": hal_step,
        "hal_send_only": lambda: hal.send_action(TWIST, ControlMode.BODY_TWIST),
        "hal_send_tick_null": null_step,
    }
    for fn in cases.values():  # warm-up
        timed(fn, 20)
    # the HAL packs exactly the pre-packed action
    hal_step()
    assert np.array_equal(hal.last_action, action), (hal.last_action, action)

    rounds: dict[str, list[dict]] = {k: [] for k in cases}
    for _ in range(args.rounds):
        hal.connect()  # resets the scene: every round starts from the same state
        samples: dict[str, list[np.ndarray]] = {k: [] for k in cases}
        for b in range(args.blocks):
            order = list(cases) if b % 2 == 0 else list(reversed(cases))  # A B C D, D C B A, ...
            for name in order:
                samples[name].append(timed(cases[name], args.reps))
        for name, blocks in samples.items():
            ms = np.concatenate(blocks)
            rounds[name].append({"p50_ms": float(np.percentile(ms, 50)), "p90_ms": float(np.percentile(ms, 90)),
                                 "mean_ms": float(ms.mean())})
    results = {k: {m: float(np.median([r[m] for r in v])) for m in ("p50_ms", "p90_ms", "mean_ms")} | {"rounds": v}
               for k, v in rounds.items()}
    added = {m: float(np.median([h[m] - s[m] for h, s in zip(rounds["hal_send_tick"], rounds["rollout_step"])]))
             for m in ("p50_ms", "mean_ms")}
    added["p50_percent"] = 100.0 * added["p50_ms"] / results["rollout_step"]["p50_ms"]

    print(f"\npanda_mobile nav_obstacles, state-only; {args.rounds} rounds x {args.blocks} interleaved blocks "
          f"x {args.reps} calls; medians over rounds")
    print(f"{'case':18s} {'p50 ms':>9s} {'p90 ms':>9s} {'mean ms':>9s}")
    for k, r in results.items():
        print(f"{k:18s} {r['p50_ms']:9.4f} {r['p90_ms']:9.4f} {r['mean_ms']:9.4f}")
    print(f"\nHAL added cost per step (hal_send_tick - rollout_step): p50 {added['p50_ms'] * 1e3:.1f} us "
          f"({added['p50_percent']:.1f} %), mean {added['mean_ms'] * 1e3:.1f} us (within the step's noise)")
    print(f"HAL's own cost (send + tick over a null rollout): p50 "
          f"{results['hal_send_tick_null']['p50_ms'] * 1e3:.1f} us, "
          f"{100 * results['hal_send_tick_null']['p50_ms'] / results['rollout_step']['p50_ms']:.1f} % of a step")
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "scene": {"robot": "panda_mobile", "layout": "nav_obstacles", "render_images": False, "engine": "mujoco"},
        "method": {"reps_per_block": args.reps, "blocks_per_round": args.blocks, "rounds": args.rounds,
                   "interleaved": True, "statistic": "median over rounds of per-call p50/p90/mean"},
        "machine": {"platform": platform.platform(), "processor": platform.processor(), "cpus": os.cpu_count()},
        "results": results,
        "hal_added_per_step": added,
    }, indent=2))
    print(f"wrote {out}")
    hal.close()


if __name__ == "__main__":
    main()
