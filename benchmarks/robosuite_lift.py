"""Baseline step benchmark: robosuite 1.5.2 ``Lift`` with a Panda under OSC_POSE.

Run with the interpreter of ``benchmarks/.venv-robosuite`` (see setup_robosuite.sh):

    MUJOCO_GL=egl benchmarks/.venv-robosuite/bin/python benchmarks/robosuite_lift.py \
        --steps 200 --cases state,rgb128,rgb256 --json out.json

Cases: ``state`` (no rendering), ``rgb128`` / ``rgb256`` (RGB from ``agentview`` and
``robot0_eye_in_hand`` at that size, no depth). Each case builds the env, resets, runs
10 warm-up steps, then times ``env.step`` alone (time.perf_counter) for N steps with one
fixed action in [-1, 1]^7; a reset on ``done`` is not timed. control_freq=20. ``--seed``
seeds both the action and robosuite's own randomness (cube pose, joint init noise).
"""

import argparse
import json
import os
import sys
import time

import numpy as np

try:
    import mujoco
    import robosuite
    from robosuite import load_composite_controller_config
    from robosuite.utils.log_utils import ROBOSUITE_DEFAULT_LOGGER
except ImportError as exc:
    sys.exit(
        f"robosuite_lift.py: cannot import robosuite/mujoco ({exc}).\n"
        "Run benchmarks/setup_robosuite.sh and use benchmarks/.venv-robosuite/bin/python."
    )

CASES = ("state", "rgb128", "rgb256")
CAMERAS = ["agentview", "robot0_eye_in_hand"]
WARMUP = 10


def make_env(case, seed):
    """Build Lift for one case; camera cases render both CAMERAS at the case's size."""
    # Panda's default composite config is BASIC with the arm on OSC_POSE; unlike
    # controller="BASIC" it has no torso/head/base/legs parts to warn about.
    config = load_composite_controller_config(robot="Panda")
    assert config["type"] == "BASIC" and config["body_parts"]["right"]["type"] == "OSC_POSE", config
    kwargs = dict(
        robots="Panda",
        controller_configs=config,
        control_freq=20,
        has_renderer=False,
        has_offscreen_renderer=False,
        use_camera_obs=False,
        seed=seed,  # unseeded, robosuite randomizes cube pose and joint init noise
    )
    if case != "state":
        size = int(case.removeprefix("rgb"))
        kwargs.update(
            has_offscreen_renderer=True,
            use_camera_obs=True,
            camera_names=CAMERAS,
            camera_heights=size,
            camera_widths=size,
            camera_depths=False,
        )
    return robosuite.make("Lift", **kwargs)


def run_case(case, steps, seed):
    """Return per-step wall times (seconds) of ``steps`` timed env.step calls."""
    env = make_env(case, seed)
    try:
        low, high = env.action_spec
        action = np.random.default_rng(seed).uniform(-1.0, 1.0, size=low.shape)
        obs = env.reset()
        if case != "state":
            size = int(case.removeprefix("rgb"))
            for cam in CAMERAS:
                assert obs[f"{cam}_image"].shape == (size, size, 3), obs[f"{cam}_image"].shape
        times = []
        for i in range(WARMUP + steps):
            t0 = time.perf_counter()
            _, _, done, _ = env.step(action)
            dt = time.perf_counter() - t0
            if i >= WARMUP:
                times.append(dt)
            if done:
                env.reset()
        return np.asarray(times)
    finally:
        env.close()


def main():
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=200, help="timed steps per case (default 200)")
    parser.add_argument("--cases", default=",".join(CASES), help="comma-separated subset of " + ",".join(CASES))
    parser.add_argument("--seed", type=int, default=0, help="seed of the env and the fixed action (default 0)")
    parser.add_argument("--json", metavar="PATH", help="also write results as JSON to PATH")
    args = parser.parse_args()

    if args.steps < 1:
        parser.error("--steps must be >= 1")
    cases = [c.strip() for c in args.cases.split(",") if c.strip()]
    unknown = sorted(set(cases) - set(CASES))
    if unknown or not cases:
        parser.error(f"unknown cases {unknown}; choose from {','.join(CASES)}")
    ROBOSUITE_DEFAULT_LOGGER.setLevel("WARNING")  # silence per-env INFO lines

    results = {}
    for case in cases:
        ms = run_case(case, args.steps, args.seed) * 1e3
        results[case] = {
            "p50_ms": float(np.percentile(ms, 50)),
            "p90_ms": float(np.percentile(ms, 90)),
            "mean_ms": float(ms.mean()),
            "n": int(ms.size),
        }

    print(f"{'case':<8} {'p50 ms':>8} {'p90 ms':>8} {'mean ms':>8} {'steps':>6}")
    for case, r in results.items():
        print(f"{case:<8} {r['p50_ms']:8.2f} {r['p90_ms']:8.2f} {r['mean_ms']:8.2f} {r['n']:6d}")

    if args.json:
        out = {
            "tool": "robosuite",
            "robosuite_version": robosuite.__version__,
            "mujoco_version": mujoco.__version__,
            "mujoco_gl": os.environ.get("MUJOCO_GL"),  # as robosuite left it after import
            "env": "Lift",
            "robot": "Panda",
            "controller": "OSC_POSE",
            "control_freq": 20,
            "warmup_steps": WARMUP,
            "seed": args.seed,
            "cpu_count": os.cpu_count(),
            "loadavg_1m_at_end": os.getloadavg()[0],
            "cases": results,
        }
        with open(args.json, "w") as f:
            json.dump(out, f, indent=2)
            f.write("\n")


if __name__ == "__main__":
    main()
