"""The same-machine transports before and after a change, alternating in one run (issue 40 item 2: the
vector runner's shared-memory transport made the sidecar's; "no slowdown").

    .venv/bin/python benchmarks/transport_before_after.py [--before origin/main] [--after HEAD]
        [--order before after before after] [--n 2] [--steps 300] [--rounds 3] [--out JSON]

Each revision's committed ``src/`` (``git archive``) goes to ``--work``; then, in the order given, each side
runs ``bench_vector.py`` (``--cases state overhead --modes vector bare``: lockstep over N worker
processes against N bare processes; ``overhead`` answers without physics, so its time per env-step is
the runner's own: pipes, the step block), then the step block alone (``--step-block-codec``: a
lift_cube state-only reply written and read back in one process, microseconds each, the least noisy
figure on a shared machine) and ``bench_sidecar.py`` (``--parts step,messages --ways
inproc,local,compact``: a sidecar step's added latency on the local path, msgpack through the ring and
compact templates; and each step message's encode / decode / framing in one process), both this checkout's scripts with
``PYTHONPATH`` at that side's sources (the workers and the sidecars import them too). Prints one table
(per metric: each side's median over its runs, and every run) and writes every run's figures, the
machine and the revisions as JSON.
"""

from __future__ import annotations

import argparse
import json
import os
import statistics
import subprocess
import sys
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[1]
HERE = ROOT / "benchmarks"


def archive(rev: str, dest: Path) -> str:
    """``rev``'s committed src/ in ``dest``/src; its full hash."""
    full = subprocess.run(["git", "rev-parse", rev], cwd=ROOT, capture_output=True, text=True, check=True).stdout.strip()
    dest.mkdir(parents=True, exist_ok=True)
    tar = subprocess.run(["git", "archive", full, "src"], cwd=ROOT, capture_output=True, check=True).stdout
    subprocess.run(["tar", "-x", "-C", str(dest)], input=tar, check=True)
    return full


def run_side(side: str, src: Path, i: int, work: Path, args) -> dict:
    """One run of both benchmarks on ``side``'s sources: their JSON, and the load around them."""
    env = {**os.environ, "PYTHONPATH": str(src), "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl")}
    vec, sc = work / f"vector_{i}_{side}.json", work / f"sidecar_{i}_{side}.json"
    load = os.getloadavg()
    t0 = time.monotonic()
    subprocess.run([sys.executable, str(HERE / "bench_vector.py"), "--n", str(args.n), "--steps", str(args.steps),
                    "--episodes-per-env", "2", "--rounds", str(args.rounds), "--cases", "state", "overhead",
                    "--modes", "vector", "bare", "--out", str(vec)], env=env, check=True, stdout=subprocess.DEVNULL)
    subprocess.run([sys.executable, str(HERE / "bench_sidecar.py"), "--steps", str(args.steps), "--rounds",
                    str(args.rounds), "--cases", "state,rgb2x256", "--parts", "step,messages", "--ways",
                    "inproc,local,compact", "--json", str(sc)], env=env, check=True, stdout=subprocess.DEVNULL)
    codec = subprocess.run([sys.executable, __file__, "--step-block-codec"], env=env, check=True, capture_output=True,
                           text=True).stdout
    return {"side": side, "run": i, "load_before": load, "load_after": os.getloadavg(),
            "wall_s": time.monotonic() - t0, "vector": json.loads(vec.read_text()), "sidecar": json.loads(sc.read_text()),
            "step_block": json.loads(codec.strip().splitlines()[-1])}


def step_block_codec(iterations: int = 2000, repeats: int = 7) -> dict:
    """In this process (the sources on ``sys.path``): one lift_cube state-only step reply (with a render
    state) written into a vector worker's step block and read back as the parent does, over and over;
    the best and the median of ``repeats`` rounds, microseconds per reply, for the write and the read."""
    import multiprocessing as mp
    from multiprocessing import reduction

    import mmap
    import numpy as np

    from simseam.robot.manifest import load_robot
    from simseam.runner import vector
    from simseam.scene.manifest_scene import ManifestScene, SceneOptions
    from simseam.seam import STATE_ONLY

    scene = ManifestScene(load_robot("franka_panda"), "lift_cube", "mujoco", SceneOptions())
    scene.reset(seed=0, observe=STATE_ONLY)
    result = scene.step(np.zeros(scene.spec.action_dim, np.float32), STATE_ONLY)
    pose = np.zeros(64, np.float32)
    parent, child = mp.Pipe()
    tx = vector._StepBlock(child, os.getpid(), scene.spec.action_dim)
    assert tx.write(result.observation, result, pose) and tx.announced
    _kind, size, layout = parent.recv()
    fd = reduction.recv_handle(parent)
    rx = vector._MainBlock(mmap.mmap(fd, size), layout)
    os.close(fd)
    assert rx.read()[1].keys() == result.observation.keys()
    out = {}
    for name, call in (("write", lambda: tx.write(result.observation, result, pose)), ("read", rx.read)):
        rounds = []
        for _ in range(repeats):
            t0 = time.perf_counter()
            for _ in range(iterations):
                call()
            rounds.append((time.perf_counter() - t0) / iterations * 1e6)
        out[name] = {"best_us": min(rounds), "median_us": statistics.median(rounds), "rounds_us": rounds}
    scene.close()
    return out


def metrics(run: dict) -> dict[str, float]:
    """The figures compared: higher is better for env-steps/s and vs bare, lower for the rest."""
    out: dict[str, float] = {}
    for row in run["vector"]["rows"]:
        key = f"vector {row['case']} {row['mode']}"
        out[f"{key} env-steps/s"] = row["env_steps_per_s"]
        if row.get("vs_bare") is not None:
            out[f"{key} vs bare"] = row["vs_bare"]
        if row.get("main_cpu_us_per_env_step") is not None:
            out[f"{key} main us/env-step"] = row["main_cpu_us_per_env_step"]
    for name, r in run["sidecar"]["results"].get("step", {}).items():
        if "added_p50_ms" in r:
            out[f"sidecar {name} added p50 ms"] = r["added_p50_ms"]
    for part, r in run.get("step_block", {}).items():
        out[f"vector step block {part} best us"] = r["best_us"]
        out[f"vector step block {part} median us"] = r["median_us"]
    for case, kinds in run["sidecar"]["results"].get("messages", {}).items():
        for kind, r in kinds.items():
            for part in ("server_encode_reply", "client_decode_reply", "total_ms"):
                out[f"messages {case} {kind} {part.removesuffix('_ms')} ms"] = r[part]
    return out


def table(runs: list[dict]) -> tuple[str, dict]:
    """The markdown table (per metric: each side's median and every run, in run order) and its data."""
    per = {side: [metrics(r) for r in runs if r["side"] == side] for side in ("before", "after")}
    names = [k for k in per["before"][0] if all(k in m for side in per.values() for m in side)] if per["before"] else []
    lines = ["| metric | before median | after median | after / before | before runs | after runs |",
             "|---|---:|---:|---:|---|---|"]
    data = {}
    for k in names:
        b, a = [m[k] for m in per["before"]], [m[k] for m in per["after"]]
        mb, ma = statistics.median(b), statistics.median(a)
        data[k] = {"before": b, "after": a, "before_median": mb, "after_median": ma, "ratio": ma / mb if mb else None}
        fmt = (lambda x: f"{x:.0f}") if "env-steps" in k else (lambda x: f"{x:.3f}")
        lines.append(f"| {k} | {fmt(mb)} | {fmt(ma)} | {ma / mb if mb else float('nan'):.3f} | "
                     f"{', '.join(fmt(x) for x in b)} | {', '.join(fmt(x) for x in a)} |")
    return "\n".join(lines), data


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--before", default="origin/main")
    ap.add_argument("--after", default="HEAD")
    ap.add_argument("--order", nargs="+", default=["before", "after", "before", "after"], choices=["before", "after"])
    ap.add_argument("--n", type=int, default=2)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--rounds", type=int, default=3)
    ap.add_argument("--work", type=Path, default=Path("/tmp/simseam-transport-before-after"))
    ap.add_argument("--out", type=Path, default=HERE / "results" / "transport_before_after_cpu.json")
    ap.add_argument("--step-block-codec", action="store_true", help=argparse.SUPPRESS)  # (one side's, as JSON)
    args = ap.parse_args()
    if args.step_block_codec:
        print(json.dumps(step_block_codec()))
        return
    if args.out.exists():
        ap.error(f"--out {args.out} exists: give another path (results are never overwritten)")
    revs = {side: archive(rev, args.work / side) for side, rev in (("before", args.before), ("after", args.after))}
    runs = []
    for i, side in enumerate(args.order, 1):
        print(f"== run {i}: {side} {revs[side][:10]} (load {os.getloadavg()[0]:.2f})", flush=True)
        runs.append(run_side(side, args.work / side / "src", i, args.work, args))
    text, data = table(runs)
    print(text)
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"revisions": revs, "order": args.order, "n": args.n, "steps": args.steps,
                                    "rounds": args.rounds, "machine": runs[0]["vector"].get("machine"),
                                    "compared": data, "runs": runs, "table": text}, indent=1, default=str))
    print(f"wrote {args.out}")


if __name__ == "__main__":
    main()
