"""Per-control-step cost of the seam vs the raw physics floor, and vs robosuite's Lift.

    .venv/bin/python benchmarks/bench_step.py [--steps 300] [--rounds 3] [--robosuite]
    .venv/bin/python benchmarks/bench_step.py --baseline HEAD~3 [--rounds 6]   # before / after in one run

Cases (Franka Panda, lift_cube layout, MuJoCo, 20 Hz control, 2 ms physics step):

- ``floor``: bare ``mj_step`` x 25 substeps per control step on the very model the scene
  compiled, replaying the controls a seam run sent (same trajectory, same physics work):
  what physics alone costs per control step.
- ``seam_state_cartesian`` / ``seam_state_joint``: ``ManifestScene.step`` with no images
  (CARTESIAN_DELTA through the scene's IK / JOINT_POSITION targets).
- ``seam_rgb128`` / ``seam_rgb256``: CARTESIAN_DELTA with both cameras (camera1 + wrist
  camera2) rendered into every observation at 128x128 / 256x256, lean render settings.
- ``robosuite_*`` (with ``--robosuite``): robosuite 1.5.2 Lift, Panda, OSC_POSE, the same two
  camera counts and sizes, run by benchmarks/robosuite_lift.py in its own venv
  (benchmarks/setup_robosuite.sh), one case after the other, never concurrently.

The state-only cases are interleaved every 10 steps within a round (the first of them rotating), so
the slow and fast phases of a shared machine hit all of them alike; the table reports the median
over rounds of each case's per-step p50 / p90. The action stream
is a smooth, seeded sweep (like a policy's), not white noise. ``x floor`` is the median over rounds
of each round's p50 / the floor's p50 of the same round (the same process, interleaved): steadier on
a shared machine than the times themselves. Prints a table and writes JSON, with the load average.

``--baseline REV``: before / after in one run. Each round runs this script (one round, its own
process) on ``REV``'s code and on this checkout's, alternately (``revisions.py``: the order swaps every
round); the table puts both sides' medians side by side.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import mujoco  # noqa: E402
import numpy as np  # noqa: E402

from simseam.robot.manifest import load_robot  # noqa: E402
from simseam.scene.manifest_scene import ManifestScene, SceneOptions  # noqa: E402

HERE = Path(__file__).resolve().parent
WARMUP = 20


def smooth_actions(n: int, dim: int, seed: int, scale: float = 0.4) -> np.ndarray:
    """A seeded sum of slow sinusoids per action dimension, in [-scale, scale]."""
    rng = np.random.default_rng(seed)
    t = np.arange(n)[:, None]
    freq = rng.uniform(0.02, 0.08, (1, dim))
    phase = rng.uniform(0, 2 * np.pi, (1, dim))
    return (scale * np.sin(2 * np.pi * freq * t + phase)).astype(np.float32)


def time_steps(fn, n: int) -> np.ndarray:
    out = np.empty(n)
    for i in range(n):
        t0 = time.perf_counter()
        fn(i)
        out[i] = time.perf_counter() - t0
    return out * 1e3


class SeamCase:
    def __init__(self, spec, mode: str, images: bool, size: int | None, steps: int):
        opts = SceneOptions(render_images=images, image_size=(size, size) if size else None, control_mode=mode)
        self.scene = ManifestScene(spec, "lift_cube", "mujoco", opts)
        self.steps = steps
        dim = self.scene.action_dim
        acts = smooth_actions(steps + WARMUP, dim, seed=1)
        if mode == "joint_position":
            home = np.array([j.home for j in spec.arm_joints], dtype=np.float32)
            acts[:, :7] = home + 0.5 * acts[:, :7]
        self.actions = acts

    def start(self) -> None:
        self.scene.reset(0)
        for i in range(WARMUP):
            self.scene.step(self.actions[i])

    def step(self, i: int) -> None:
        self.scene.step(self.actions[WARMUP + i])

    def run(self) -> np.ndarray:
        self.start()
        return time_steps(self.step, self.steps)


class FloorCase:
    """Raw physics: the scene's own compiled model stepped through the very same trajectory.

    A seam run (the cartesian case's actions) records every control the scene sends (its
    setpoint ramp included); the floor replays them with bare ``mj_step`` calls, so both do
    identical physics work (contacts, solver iterations) and differ only by the seam itself.
    """

    def __init__(self, seam: "SeamCase"):
        self.scene = seam.scene
        eng = self.scene.engine
        self.model, self.data = eng.model, eng.data
        self.steps = seam.steps
        record: list[list[tuple[np.ndarray, int]]] = []
        orig_targets, orig_step = eng.set_joint_targets, eng.step
        pending: list[np.ndarray] = []

        def set_targets(q):
            orig_targets(q)
            pending.append(self.data.ctrl.copy())

        def step(n):
            orig_step(n)
            record[-1].append((pending[-1], int(n)))

        self.scene.reset(0)
        eng.set_joint_targets, eng.step = set_targets, step
        for a in seam.actions:
            record.append([])
            self.scene.step(a)
        eng.set_joint_targets, eng.step = orig_targets, orig_step
        self.record = record

    def _control_step(self, i: int) -> None:
        m, d = self.model, self.data
        for ctrl, n in self.record[i]:
            d.ctrl[:] = ctrl
            mujoco.mj_step(m, d, n)

    def start(self) -> None:
        self.scene.reset(0)
        for i in range(WARMUP):
            self._control_step(i)

    def step(self, i: int) -> None:
        self._control_step(WARMUP + i)


def run_robosuite(steps: int) -> dict | None:
    py = HERE / ".venv-robosuite" / "bin" / "python"
    if not py.exists():
        print("robosuite venv missing: run benchmarks/setup_robosuite.sh first (skipping the baseline)")
        return None
    out = HERE / "results" / "robosuite_lift.json"
    out.parent.mkdir(exist_ok=True)
    proc = subprocess.run([str(py), str(HERE / "robosuite_lift.py"), "--steps", str(steps),
                           "--cases", "state,rgb128,rgb256", "--json", str(out)],
                          env=dict(os.environ, MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl")),
                          capture_output=True, text=True)
    if proc.returncode != 0:
        print("robosuite baseline failed:\n" + proc.stderr[-2000:])
        return None
    return json.loads(out.read_text())


def interleaved(cases: dict, steps: int, block: int = 10) -> dict[str, np.ndarray]:
    """Time ``steps`` steps of each case, alternating between cases every ``block`` steps,
    so that a shared machine's slow and fast phases fall on every case alike. The case that goes
    first rotates every block: the one right after the floor ran measurably slower than an identical
    copy of it two places later (1.43x vs 1.33x the floor, one run), a cache effect of the switch."""
    for c in cases.values():
        c.start()
    times = {k: np.empty(steps) for k in cases}
    names = list(cases)
    for k, b0 in enumerate(range(0, steps, block)):
        for name in names[k % len(names):] + names[:k % len(names)]:
            c = cases[name]
            for i in range(b0, min(steps, b0 + block)):
                t0 = time.perf_counter()
                c.step(i)
                times[name][i] = (time.perf_counter() - t0) * 1e3
    return times


def stats(ms: np.ndarray) -> dict:
    return {"p50_ms": float(np.percentile(ms, 50)), "p90_ms": float(np.percentile(ms, 90)),
            "mean_ms": float(ms.mean()), "n": int(ms.size)}


def ratio_medians(rounds: dict[str, list[dict]]) -> dict[str, float]:
    """Per case: the median over rounds of its p50 / the floor's p50 in the same round."""
    floor = [r["p50_ms"] for r in rounds["floor"]]
    return {k: float(np.median([r["p50_ms"] / f for r, f in zip(v, floor)])) for k, v in rounds.items()}


def compare(args) -> None:
    """``--baseline``: this script's rounds on REV's code and on this checkout's, alternately."""
    from revisions import alternate, resolve

    load0 = os.getloadavg()
    argv = [str(Path(__file__).resolve()), "--steps", str(args.steps), "--rounds", "1", "--json", "{json}",
            "--robot", args.robot]
    runs = alternate(args.baseline, argv, args.rounds)
    sides = {}
    for side, results in runs.items():
        rounds = {k: [r["results"][k]["rounds"][0] for r in results] for k in results[0]["results"]}
        ratio = ratio_medians(rounds)
        sides[side] = {k: {"p50_ms": float(np.median([x["p50_ms"] for x in v])),
                           "p90_ms": float(np.median([x["p90_ms"] for x in v])), "x_floor": ratio[k], "rounds": v}
                       for k, v in rounds.items()}
    print(f"\n{'case':24s} {'before p50':>10s} {'after p50':>10s} {'before x':>9s} {'after x':>9s}  (x floor)")
    for k in sides["head"]:
        b, a = sides["base"][k], sides["head"][k]
        print(f"{k:24s} {b['p50_ms']:10.3f} {a['p50_ms']:10.3f} {b['x_floor']:9.2f} {a['x_floor']:9.2f}")
    load1 = os.getloadavg()
    print(f"load average (1, 5, 15 min): start {load0[0]:.2f} {load0[1]:.2f} {load0[2]:.2f}, "
          f"end {load1[0]:.2f} {load1[1]:.2f} {load1[2]:.2f}")
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "machine": {"python": platform.python_version(), "mujoco": mujoco.__version__, "cpus": os.cpu_count()},
        "baseline": args.baseline, "baseline_commit": resolve(args.baseline), "steps": args.steps,
        "rounds": args.rounds, "loadavg": {"start": load0, "end": load1},
        "before": sides["base"], "after": sides["head"],
        "goal_state_cartesian_within_1.25x_floor": {s: sides[s]["seam_state_cartesian"]["x_floor"] <= 1.25
                                                    for s in ("base", "head")},
    }, indent=2))
    print(f"wrote {out}")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--robosuite", action="store_true", help="also run the robosuite Lift baseline (same run)")
    ap.add_argument("--baseline", metavar="REV", help="also run REV's code, alternating rounds (before / after)")
    ap.add_argument("--json", default=str(HERE / "results" / "step.json"))
    ap.add_argument("--robot", default="franka_panda",
                    help="the Panda's manifest: a built-in name or a path (a machine without the asset cache)")
    args = ap.parse_args()
    if args.baseline:
        if args.robosuite:
            raise SystemExit("--baseline and --robosuite: run them separately")
        return compare(args)
    load0 = os.getloadavg()

    spec = load_robot(args.robot)
    cartesian = SeamCase(spec, "cartesian_delta", False, None, args.steps)
    cases = {
        "floor": FloorCase(SeamCase(spec, "cartesian_delta", False, None, args.steps)),
        "seam_state_cartesian": cartesian,
        "seam_state_joint": SeamCase(spec, "joint_position", False, None, args.steps),
        "seam_rgb128": SeamCase(spec, "cartesian_delta", True, 128, max(60, args.steps // 5)),
        "seam_rgb256": SeamCase(spec, "cartesian_delta", True, 256, max(60, args.steps // 5)),
    }
    rounds: dict[str, list[dict]] = {k: [] for k in cases}
    robosuite_rounds: list[dict] = []
    state_cases = {k: cases[k] for k in ("floor", "seam_state_cartesian", "seam_state_joint")}
    for r in range(args.rounds):
        for name, ms in interleaved(state_cases, args.steps).items():
            rounds[name].append(stats(ms))
        for name in ("seam_rgb128", "seam_rgb256"):
            rounds[name].append(stats(cases[name].run()))
        if args.robosuite:
            res = run_robosuite(max(60, args.steps // 5))
            if res:
                robosuite_rounds.append(res)
        print(f"round {r + 1}/{args.rounds} done")

    def median(rs: list[dict], key: str) -> float:
        return float(np.median([x[key] for x in rs]))

    results = {k: {"p50_ms": median(v, "p50_ms"), "p90_ms": median(v, "p90_ms"), "rounds": v}
               for k, v in rounds.items()}
    for case in ("state", "rgb128", "rgb256"):
        rs = [r["cases"][case] for r in robosuite_rounds if case in r.get("cases", {})]
        if rs:
            results[f"robosuite_{case}"] = {"p50_ms": median(rs, "p50_ms"), "p90_ms": median(rs, "p90_ms"),
                                            "rounds": rs}
    floor = results["floor"]["p50_ms"]
    ratios = ratio_medians(rounds)
    rows = []
    for name, r in results.items():
        ratio = ratios.get(name, r["p50_ms"] / floor)
        r["x_floor"] = ratio
        rows.append((name, r["p50_ms"], r["p90_ms"], ratio))
    print(f"\n{'case':24s} {'p50 ms':>9s} {'p90 ms':>9s} {'x floor':>8s}")
    for name, p50, p90, ratio in rows:
        print(f"{name:24s} {p50:9.3f} {p90:9.3f} {ratio:8.2f}")
    goals = {
        "state_cartesian_within_1.25x_floor": ratios["seam_state_cartesian"] <= 1.25,
        "state_joint_within_1.25x_floor": ratios["seam_state_joint"] <= 1.25,
    }
    for size in ("128", "256"):
        if f"robosuite_rgb{size}" in results:
            goals[f"rgb{size}_faster_than_robosuite"] = (
                results[f"seam_rgb{size}"]["p50_ms"] < results[f"robosuite_rgb{size}"]["p50_ms"])
    print("\ngoals: " + ", ".join(f"{k}={'met' if v else 'NOT met'}" for k, v in goals.items()))
    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "machine": {"python": platform.python_version(), "mujoco": mujoco.__version__, "cpus": os.cpu_count(),
                    "MUJOCO_GL": os.environ.get("MUJOCO_GL")},
        "steps": args.steps, "rounds": args.rounds, "loadavg": {"start": load0, "end": os.getloadavg()},
        "results": results, "goals": goals,
    }, indent=2))
    print(f"wrote {out}")
    for c in cases.values():
        c.scene.close()
    sys.exit(0)


if __name__ == "__main__":
    main()
