"""LIBERO at scale: ``simseam eval libero_spatial --num-envs N`` timed end to end, for several N.

Each case runs the real command line in a subprocess (``python -m simseam.cli.main eval PRESET
--policy zero --num-envs N ...`` into a fresh run directory) and measures its wall time: the workers'
sidecar boots, task changes, every episode (state + the preset's two 256x256 cameras each step) and
the summary. From the run's own episode log it reports episodes/hour and env-steps/s (the policy's
steps; the preset's 10 settle steps per episode are counted separately as ``settle_steps``), the mean step and
the policy's share of a step (``policy``: its mean time per step over that plus the environment's step); from the
port's ``timings.jsonl``, per process where the time went (``run_timings.per_process``: its start, its batches'
opening and running).

    python benchmarks/bench_libero_scale.py --n 1 2 --episodes 2 --tasks libero_spatial/0,libero_spatial/1
    python benchmarks/bench_libero_scale.py --n 8 16 --episodes 5 --full 16     # the GPU machine

``--full N`` adds the whole protocol (10 tasks x 50 episodes) at N. ``--warp DEVICE`` adds, after each CPU case,
the same episodes on the MuJoCo Warp port (``--engine mujoco_warp --sim-device DEVICE``; ``--warp-n K``: its
worlds per task, default the case's N; ``--warp-shards K``: ``--processes K``, K processes at once, each taking
whole tasks, merged by the command itself; ``--warp-runs R``: R times in a row, the later ones with the caches the
first filled; ``--mps``: the port's case once more with ``--mps``, the processes as clients of a CUDA MPS server
of the run's own): the GPU against the CPU backend in the same run, on the same machine. Without MPS the GPU runs one process's kernels at a time (it time-slices
between processes); under MPS the shards' kernels run side by side.
Each command's console is written to its log as it runs (``--logs``, else beside its run); ``--case-limit S`` gives
a case still running after S seconds a Ctrl-C, as a user's would (its finished episodes and summary kept, its row
marked cut, its rates over the episodes it finished), so that a call with a time limit still brings back a row.
Both draw only the cameras a policy reads at each step (the CPU backend's sidecars blank the others' sensors,
``robosuite_cameras.CameraSwitch``, and draw both cameras while resetting: robosuite's reset, the last settle
step); the rows say which (``images``). Prints a table and writes JSON
(default ``benchmarks/results/libero_scale.json``). Needs the LIBERO backend provisioned (``simseam
backends provision libero``, or ``benchmarks/device/libero_upload.sh install`` on the GPU machine).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(Path(__file__).resolve().parent))
sys.path.insert(1, str(REPO / "src"))  # this checkout's simseam (the commands it times run it too)
from run_timings import per_process  # noqa: E402

EXTRA: list[str] = []  # options every eval gets (--image-size)


def machine() -> dict:
    info = {"host": platform.node(), "python": platform.python_version(), "cores": len(os.sched_getaffinity(0)),
            "cpu": "", "gpu": "", "mujoco_gl": os.environ.get("MUJOCO_GL", "")}
    try:
        for line in Path("/proc/cpuinfo").read_text().splitlines():
            if line.startswith("model name"):
                info["cpu"] = line.split(":", 1)[1].strip()
                break
    except OSError:
        pass
    if shutil.which("nvidia-smi"):
        out = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                             text=True)
        info["gpu"] = out.stdout.strip()
    return info


def _env() -> dict:
    env = dict(os.environ)
    env.setdefault("MUJOCO_GL", "egl")
    env["PYTHONPATH"] = os.pathsep.join([str(REPO / "src"), *filter(None, [env.get("PYTHONPATH")])])
    return env


def _eval_argv(preset: str, policy: str, n: int, episodes: int | None, tasks: str | None, out: Path,
               warp: str | None) -> list[str]:
    argv = [sys.executable, "-m", "simseam.cli.main", "eval", preset, "--policy", policy, "--num-envs", str(n),
            "--out", str(out), "--overwrite", *EXTRA]
    if warp:
        argv += ["--engine", "mujoco_warp", "--sim-device", warp]
    if episodes:
        argv += ["--episodes", str(episodes)]
    if tasks:
        argv += ["--tasks", tasks]
    return argv


class _Cut(Exception):
    """A case's time limit has come."""


def _run(command: list[str], log: Path, limit: float | None = None) -> bool:
    """The command in its own process, its console written to ``log`` as it goes (a call cut short still has it);
    after ``limit`` seconds it gets a Ctrl-C (``runner.processes.run_processes``' own: SIGINT, the run ends as an
    interrupted one with its finished episodes and summary kept) and True is returned. Any other failure stops the
    benchmark."""
    from simseam.runner.processes import run_processes

    deadline = None if limit is None else time.monotonic() + limit

    def check() -> None:
        if deadline is not None and time.monotonic() > deadline:
            raise _Cut

    try:
        (code,) = run_processes([command], [log], _env(), on_poll=check)
    except _Cut:
        return True
    if code != 0:
        raise SystemExit(f"{' '.join(command)} failed (exit {code}):\n{log.read_text()[-4000:]}")
    return False


def run_case(preset: str, policy: str, n: int, episodes: int | None, tasks: str | None, workdir: Path,
             log_dir: Path | None, warp: str | None = None, shards: int = 1, mps: bool = False,
             limit: float | None = None) -> dict:
    """One ``simseam eval`` (the backend's CPU processes, or with ``warp`` the MuJoCo Warp port on that device)
    timed end to end, and what its run directory says it did. ``shards`` K > 1: ``--processes K`` (K processes of
    whole tasks at once, merged by the command itself); ``mps``: with ``--mps``; ``limit``: a Ctrl-C after that
    many seconds (``cut``: the rates then count the episodes finished by then)."""
    out = workdir / (f"{preset}_n{n}_{episodes or 'full'}{'_warp' if warp else ''}{f'_k{shards}' if shards > 1 else ''}"
                     + ("_mps" if mps else ""))
    workdir.mkdir(parents=True, exist_ok=True)
    log = (log_dir or workdir) / f"{workdir.name}_{out.name}.log"
    argv = _eval_argv(preset, policy, n, episodes, tasks, out, warp)
    argv += (["--processes", str(shards)] if shards > 1 else []) + (["--mps"] if mps else [])
    t0, launched = time.perf_counter(), time.time()
    cut = _run(argv, log, limit)
    wall = time.perf_counter() - t0
    if not (out / "summary.json").exists():
        raise SystemExit(f"{' '.join(argv)}: no summary after {wall:.0f} s{' (cut)' if cut else ''}:\n"
                         f"{log.read_text()[-4000:]}")
    summary = json.loads((out / "summary.json").read_text())
    rows = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines() if line.strip()]
    steps = sum(e["steps"] for e in rows)
    settle = int(summary["config"]["task_config"].get("settle_steps", 0)) * len(rows)
    step_ms = [e["step_latency_ms"]["mean"] for e in rows if e["step_latency_ms"]["mean"] is not None]
    # the policy's share: its time per step (a batch's, shared by the episodes it acted for) over the step's and its
    policy_ms = [e["policy_latency_ms"]["mean"] for e in rows if (e.get("policy_latency_ms") or {}).get("mean") is not None]
    return {"preset": preset, "policy": policy, "engine": f"mujoco_warp ({warp})" if warp else "backend (CPU)",
            "images": ("policy's; both at resets" if not warp else "policy's only") + (f" at {EXTRA[1]}" if EXTRA else ""), "num_envs": n, "processes": shards, "mps": mps,
            "tasks": len(summary["config"]["tasks"]),
            "episodes": len(rows), "errors": sum(1 for e in rows if e["error"]), "successes": summary["n_success"],
            "env_steps": steps, "settle_steps": settle, "wall_s": round(wall, 2),
            "episodes_per_hour": round(len(rows) / wall * 3600.0, 1), "env_steps_per_s": round(steps / wall, 1),
            "mean_step_ms": round(sum(step_ms) / len(step_ms), 2) if step_ms else None,
            "mean_policy_ms": round(sum(policy_ms) / len(policy_ms), 3) if policy_ms else None,
            "policy_share": (round(sum(policy_ms) / (sum(policy_ms) + sum(step_ms)), 4)
                             if policy_ms and len(policy_ms) == len(step_ms) else None),
            # a Ctrl-C that came after the run had finished its episodes and merge (its summary complete) cut nothing
            "complete": summary["complete"], "cut_at_s": limit if cut and not summary["complete"] else None,
            "per_process": per_process(out, launched)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--preset", default="libero_spatial")
    ap.add_argument("--policy", default="zero")
    ap.add_argument("--n", type=int, nargs="*", default=[1, 2],
                    help="--num-envs values for the subset cases (none: `--n` alone, with --full)")
    ap.add_argument("--episodes", type=int, default=2, help="episodes per task in the subset cases")
    ap.add_argument("--tasks", default=None, help="comma-separated task subset for the subset cases (default: all)")
    ap.add_argument("--full", type=int, nargs="*", default=[], help="also run the whole protocol at these N")
    ap.add_argument("--warp", default=None, metavar="DEVICE",
                    help="also run each case on the MuJoCo Warp port on this Warp device (cuda:0, cpu)")
    ap.add_argument("--warp-n", type=int, default=None, help="the port's worlds per task (default: the case's N)")
    ap.add_argument("--warp-shards", type=int, default=1, metavar="K",
                    help="the port's case as --processes K (K processes of whole tasks at once, merged)")
    ap.add_argument("--warp-runs", type=int, default=1, metavar="R",
                    help="the port's case R times in a row: the first with whatever caches there are (on a fresh "
                         "machine none: LIBERO's resets, compiled kernels), the later ones warm")
    ap.add_argument("--port-only", action="store_true",
                    help="the port's cases alone, no CPU baseline (e.g. to fill the caches on a fresh machine)")
    ap.add_argument("--mps", action="store_true",
                    help="the port's case once more with --mps (its processes as clients of a CUDA MPS server)")
    ap.add_argument("--image-size", type=int, default=None, metavar="N",
                    help="every case's cameras at N x N (simseam eval --image-size; e.g. a policy trained at 128)")
    ap.add_argument("--out", type=Path, default=REPO / "benchmarks" / "results" / "libero_scale.json")
    ap.add_argument("--logs", type=Path, default=None, help="keep each run's console output here")
    ap.add_argument("--keep-runs", type=Path, default=None, help="keep the run directories here")
    ap.add_argument("--case-limit", type=float, default=None, metavar="S",
                    help="a case still running after S seconds gets a Ctrl-C, as a user's would: its finished "
                         "episodes count (its row says cut), and the next case runs (a device call's time limit)")
    args = ap.parse_args()
    EXTRA.extend(["--image-size", str(args.image_size)] if args.image_size else [])

    info = machine()
    results = []
    work = args.keep_runs or Path(tempfile.mkdtemp(prefix="simseam-libero-scale-"))
    work.mkdir(parents=True, exist_ok=True)
    if args.logs:
        args.logs.mkdir(parents=True, exist_ok=True)
    cases = [(n, args.episodes, args.tasks) for n in args.n] + [(n, None, None) for n in args.full]
    try:
        for n, episodes, tasks in cases:
            runs = ([] if args.port_only else [(None, 1, False)]) + [(args.warp, a, False) for a in range(1, args.warp_runs + 1) if args.warp]
            runs += [(args.warp, args.warp_runs + 1, True)] if args.warp and args.mps else []
            for warp, attempt, mps in runs:
                k = (args.warp_n or n) if warp else n
                r = run_case(args.preset, args.policy, k, episodes, tasks, work / f"run{attempt}", args.logs, warp,
                             args.warp_shards if warp else 1, mps, args.case_limit)
                r["attempt"] = attempt  # 2, 3...: the port's same run again, its caches warm (resets, kernels)
                results.append(r)
                print(f"  {r['engine']:<22} N={k:3d} x{r['processes']}{' MPS' if mps else ''}  {r['episodes']} episodes in {r['wall_s']:.1f} s"
                      f"{' (cut)' if r['cut_at_s'] else ''}: "
                      f"{r['episodes_per_hour']:,.0f} episodes/h, {r['env_steps_per_s']:,.0f} env-steps/s", flush=True)
                for row in r["per_process"]:  # where the port's time went (its timings.jsonl)
                    print("    a process: " + ", ".join(f"{key} {v}" for key, v in row.items()), flush=True)
                args.out.parent.mkdir(parents=True, exist_ok=True)  # written after every case: a long run keeps its rows
                args.out.write_text(json.dumps({"machine": info, "results": results}, indent=2))
    finally:
        if args.keep_runs is None:
            shutil.rmtree(work, ignore_errors=True)

    print(f"\n{args.preset}, policy {args.policy}, {info['cores']} cores, {info['cpu']}"
          + (f", {info['gpu']}" if info["gpu"] else "") + f", MUJOCO_GL={info['mujoco_gl']}")
    head = (f"| {'engine':<22} | {'run':>3} | {'images':<14} | {'N':>3} | {'procs':>5} | {'tasks':>5} | {'episodes':>8} | {'wall s':>8} | {'episodes/h':>10} | {'env-steps/s':>11} "
            f"| {'step ms':>7} | {'policy':>6} | {'success':>7} | {'errors':>6} | {'MPS':>3} |")
    print(head)
    print("|" + "|".join("-" * (len(c)) for c in head.split("|")[1:-1]) + "|")
    for r in results:
        print(f"| {r['engine']:<22} | {r['attempt']:>3} | {r['images']:<14} | {r['num_envs']:>3} | {r['processes']:>5} | {r['tasks']:>5} | {r['episodes']:>8} | {_wall(r):>8} | "
              f"{r['episodes_per_hour']:>10,.0f} | {r['env_steps_per_s']:>11,.0f} | "
              f"{(r['mean_step_ms'] or 0):>7.1f} | {_share(r):>6} | {r['successes']:>7} | {r['errors']:>6} | {'yes' if r['mps'] else 'no':>3} |")
    print(f"\nJSON: {args.out}")


def _wall(r: dict) -> str:
    return f"{r['wall_s']:.1f}" + (" cut" if r.get("cut_at_s") else "")


def _share(r: dict) -> str:
    return "-" if r.get("policy_share") is None else f"{100 * r['policy_share']:.1f}%"


if __name__ == "__main__":
    main()
