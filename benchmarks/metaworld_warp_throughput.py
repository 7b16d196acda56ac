"""Meta-World v3 on MuJoCo Warp: throughput against the CPU backend, in one call, with the same policy.

Sections (each printed as a table; all in one JSON, ``--out``, kept unless ``--overwrite``):

- ``cpu``: the CPU backend's own per-env code (``simseam.backends.metaworld.make_rollout``: what each
  sidecar env of ``simseam eval metaworld_*`` runs, here without the sidecar's transport, so an upper
  bound on the CPU backend's rate) in ``--cpu-procs`` processes of Meta-World's provisioned interpreter,
  each stepping its share of the tasks (every task in turn, ``--cpu-chunk`` steps at a time, resetting at
  ``max_path_length``) for ``--cpu-seconds`` after all are ready; env-steps/s summed over the processes.
- ``warp``: per ``--worlds`` N and task, ``MetaWorldBatch(task, N)`` on ``--device``; worlds reset to
  seeds ``i % 50``; two untimed steps (the first launches directly, the second captures the CUDA graph:
  ``cuda_graphs`` names those captured); then ``--steps`` timed control steps,
  each with Meta-World's observation, reward and success for every world copied to the host. Per task
  env-steps/s; over the tasks, all their steps over all their timed seconds.
- ``mt50``: the whole evaluation a user waits for: every task, ``--episodes`` episodes (seeds 0..E-1, one
  world each) of ``max_path_length`` steps, building, resetting and stepping timed together (wall), the
  tasks split over ``--mt50-procs`` processes sharing the device (``--mps``: as clients of a CUDA MPS server of
  the benchmark's own, so that their kernels run side by side). The processes claim tasks one at a time
  (``runner.claims``, as ``simseam eval --processes`` does), so one that finishes early takes the next;
  ``--mt50-order RUN.json`` offers them longest first by an earlier run's per-task seconds (else in the order
  given). Each task's stepping is split into ``physics.advance`` (the control step's launches and the wait for
  the device) and the host's own work (actions, observation, reward, success): per task ``advance_seconds`` of
  ``stepping_seconds``, over the tasks ``step_split``.
- ``--host-arrays``: the Warp sections' observation and reward code in NumPy on host copies of the poses and
  contacts (``MetaWorldBatch(host_arrays=True)``); without it the bench keeps them on the device
  (``host_arrays=False``, CuPy: each array call one GPU launch), whatever the product's default
  (``metaworld_gpu.env.host_arrays_for``: host copies on CUDA up to 64 worlds).
- with ``--cameras corner,gripperPOV --image 128``, the same with those cameras rendered every step, beside
  the state-only sections (``--no-state`` leaves those out): ``cpu_cameras``, the CPU backend's per-env code
  with ``camera: [corner, gripperPOV]`` at ``--image``² (each step observes both images: Meta-World's
  ``env.render()``, MuJoCo's OpenGL renderer, ``MUJOCO_GL`` default ``egl``) in ``--cpu-procs`` processes;
  ``warp_cameras``, per ``--camera-worlds`` N, ``MetaWorldBatch`` with both cameras, each timed step
  followed by ``render()`` of every world (MuJoCo Warp's ray tracer; the images stay on the device, where a
  GPU policy reads them).

The policy is uniform random actions in [-1, 1] (seeded), drawn where each env lives (the device for
Warp, NumPy for the CPU), so its cost is nil on both sides: the figures are the simulators' and
Meta-World's observation and reward code's. A section is skipped by giving it 0 (``--worlds ""``,
``--cpu-procs 0``, ``--episodes 0``).

    python benchmarks/metaworld_warp_throughput.py --device cuda:0 --worlds 1024,4096,8192 --cpu-procs 16
    python benchmarks/metaworld_warp_throughput.py --device cpu --tasks reach-v3 --worlds 8 --steps 5 \\
        --cpu-procs 2 --cpu-seconds 5 --episodes 2 --out /tmp/t.json
    python benchmarks/metaworld_warp_throughput.py --device cuda:0 --tasks reach-v3,push-v3,pick-place-v3 --no-state \\
        --cameras corner,gripperPOV --image 128 --camera-worlds 1024,4096 --cpu-procs 16
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
from typing import Any

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
from run_timings import per_process, stepping  # noqa: E402

OUT = Path(__file__).resolve().parent / "results" / "metaworld_warp_throughput.json"
SRC = Path(__file__).resolve().parents[1] / "src"


# ------------------------------------------------------------------------------------------------ cpu
def camera_config(cameras: list[str], image: int) -> dict[str, Any]:
    """The backend config of ``cameras`` at ``image``² (state-only when none)."""
    if not cameras:
        return {"cameras": False}
    return {"cameras": True, "camera": list(cameras), "image_size": [image, image]}


def cpu_worker(tasks: list[str], chunk: int, seconds: float, seed: int, cameras: list[str] = (),
               image: int = 128) -> None:
    """Run in Meta-World's interpreter: make every task's env, print ``ready``, wait for a line on stdin,
    then step for ``seconds`` (each step observing ``cameras``' images, if any); print one JSON line of counts."""
    from simseam.backends.metaworld import make_rollout, normalize_config

    rollouts = {t: make_rollout(normalize_config({"task": t, **camera_config(cameras, image)})) for t in tasks}
    for i, r in enumerate(rollouts.values()):
        r.reset(seed=seed + i)
    rng = np.random.default_rng(seed)
    steps = {t: 0 for t in tasks}
    print("ready", flush=True)
    sys.stdin.readline()
    t0 = time.perf_counter()
    while time.perf_counter() - t0 < seconds:
        for task, rollout in rollouts.items():
            for _ in range(chunk):
                result = rollout.step(rng.uniform(-1.0, 1.0, 4).astype(np.float32))
                steps[task] += 1
                if result.truncated or result.terminated:
                    rollout.reset(seed=seed + steps[task])
    print(json.dumps({"steps": steps, "seconds": time.perf_counter() - t0,
                      "gl_renderer": gl_renderer() if cameras else None}), flush=True)


def gl_renderer() -> str:
    """The OpenGL renderer the env's cameras drew with (its context is current after a render): the machine fact
    that decides the CPU backend's camera cost (a GPU's driver, or Mesa's llvmpipe on the CPU)."""
    try:
        from OpenGL import GL

        name = GL.glGetString(GL.GL_RENDERER)
        return name.decode() if name else "unknown (no current context)"
    except Exception as exc:  # noqa: BLE001 - reported, never fatal: the figure stands without it
        return f"unknown ({type(exc).__name__}: {exc})"


def cpu_section(tasks: list[str], procs: int, chunk: int, seconds: float, cameras: list[str] = (),
                image: int = 128) -> dict[str, Any]:
    from simseam.backends.provision import require

    python = str(require("metaworld"))
    env = {k: v for k, v in os.environ.items() if k not in ("PYTHONHOME", "VIRTUAL_ENV")}
    env["PYTHONPATH"] = str(SRC)
    workers = []
    for j in range(procs):
        share = tasks[j::procs] or [tasks[j % len(tasks)]]
        argv = [python, __file__, "--cpu-worker", ",".join(share), "--cpu-chunk", str(chunk),
                "--cpu-seconds", str(seconds), "--seed", str(1000 * j), "--cameras", ",".join(cameras),
                "--image", str(image)]
        workers.append(subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, text=True, env=env))
    t_setup = time.perf_counter()
    for w in workers:
        if w.stdout.readline().strip() != "ready":
            raise RuntimeError(f"cpu worker {w.args[3]} failed to start (rc {w.wait()})")
    setup = time.perf_counter() - t_setup
    for w in workers:
        w.stdin.write("go\n")
        w.stdin.flush()
    counts = [json.loads(w.stdout.readline()) for w in workers]
    for w in workers:
        w.wait()
    per_task: dict[str, int] = {}
    for c in counts:
        for task, n in c["steps"].items():
            per_task[task] = per_task.get(task, 0) + n
    rate = sum(sum(c["steps"].values()) / c["seconds"] for c in counts)
    return {"procs": procs, "seconds": seconds, "gl_renderers": sorted({c["gl_renderer"] for c in counts} - {None}),
            "cameras": list(cameras), "image": image if cameras else None, "setup_seconds": round(setup, 1), "env_steps_per_s": rate,
            "steps_per_task": per_task, "per_proc_env_steps_per_s": [sum(c["steps"].values()) / c["seconds"]
                                                                    for c in counts]}


# ----------------------------------------------------------------------------------------------- warp
def warp_task(worker, task: str, worlds: int, steps: int, device: str | None, seed: int,
              cameras: list[str] = (), image: int = 128, host_arrays: bool = False) -> dict[str, Any]:
    from simseam.backends.metaworld_gpu.env import MetaWorldBatch

    t0 = time.perf_counter()
    plan = [(name, f"camera{i + 1}", (image, image)) for i, name in enumerate(cameras)]
    env = MetaWorldBatch(task, worlds, worker, device=device, cameras=plan, host_arrays=host_arrays)
    env.reset(np.arange(worlds), np.arange(worlds) % 50)
    xp = env.xp
    rng = xp.random.RandomState(seed)  # NumPy and CuPy alike

    def one_step() -> None:
        env.step(rng.uniform(-1.0, 1.0, (worlds, 4)).astype(xp.float32))
        if plan:
            env.render()  # every world's images, on the device

    for _ in range(2):  # the first launches run directly, the second are captured as a CUDA graph: untimed
        one_step()
    env.physics.synchronize()
    graphs = list(env.physics.graphs.captured)
    setup = time.perf_counter() - t0
    t1 = time.perf_counter()
    for _ in range(steps):
        one_step()
    env.physics.synchronize()
    seconds = time.perf_counter() - t1
    env.close()
    return {"worlds": worlds, "steps": steps, "seconds": seconds, "setup_seconds": setup,
            "env_steps_per_s": worlds * steps / seconds, "cuda_graphs": graphs}


def warp_section(tasks: list[str], sizes: list[int], steps: int, device: str | None, cameras: list[str] = (),
                 image: int = 128, host_arrays: bool = False, on_task=None) -> dict[str, Any]:
    """Each world count over ``tasks``; ``on_task(out)`` after every task with the rows so far (a run cut off by a
    time limit keeps the tasks it measured)."""
    from simseam.backends.metaworld_gpu.worker import NativeWorker

    out: dict[str, Any] = {}
    what = f"{len(cameras)} x {image}^2 cameras" if cameras else "state-only"
    with NativeWorker() as worker:
        for n in sizes:
            rows = out.setdefault(str(n), {"tasks": {}})["tasks"]
            for i, task in enumerate(tasks):
                rows[task] = warp_task(worker, task, n, steps, device, seed=i, cameras=cameras, image=image,
                                       host_arrays=host_arrays)
                print(f"  warp {n:6d} worlds  {task:28s} {rows[task]['env_steps_per_s']:12,.0f} env-steps/s "
                      f"({what}; setup {rows[task]['setup_seconds']:.1f} s)", flush=True)
                if on_task is not None:
                    on_task(out)
            total = sum(r["worlds"] * r["steps"] for r in rows.values())
            secs = sum(r["seconds"] for r in rows.values())
            rates = [r["env_steps_per_s"] for r in rows.values()]
            out[str(n)].update({"env_steps_per_s": total / secs, "slowest_task_env_steps_per_s": min(rates),
                                  "fastest_task_env_steps_per_s": max(rates)})
    return out


# ----------------------------------------------------------------------------------------------- mt50
def mt50_worker(tasks: list[str], episodes: int, device: str | None, claims: Path | None = None,
                host_arrays: bool = False) -> dict[str, Any]:
    """Every task's ``episodes`` episodes to their end, as one batch per task; per task the wall seconds.
    ``claims``: a directory shared with the other processes; a task runs here only if this process claims it first
    (``runner.claims``, as ``simseam eval --processes`` deals tasks)."""
    from simseam.backends.metaworld_gpu.env import MetaWorldBatch
    from simseam.backends.metaworld_gpu.worker import NativeWorker
    from simseam.runner.claims import TaskClaims

    out = {}
    held = TaskClaims(claims, os.getpid()) if claims is not None else None
    with NativeWorker() as worker:
        for i, task in enumerate(tasks):
            if held is not None and not held.take(i):
                continue
            t0 = time.perf_counter()
            env = MetaWorldBatch(task, episodes, worker, device=device, host_arrays=host_arrays)
            built = time.perf_counter()
            env.reset(np.arange(episodes), np.arange(episodes))
            reset = time.perf_counter()
            timer = _AdvanceTimer(env.physics)
            xp = env.xp
            rng = xp.random.RandomState(i)
            success = np.zeros(episodes, dtype=bool)
            t1 = time.perf_counter()
            for k in range(env.max_steps):
                success |= env.step(rng.uniform(-1.0, 1.0, (episodes, 4)).astype(xp.float32))["success"]
                if k == 0:
                    first = time.perf_counter() - t1  # on CUDA: the step's graphs captured, the kernels loaded
            stepping = time.perf_counter() - t1
            env.close()
            out[task] = {"seconds": time.perf_counter() - t0, "episodes": episodes, "steps": env.max_steps,
                         "successes": int(success.sum()), "process": os.getpid(), "stepping_seconds": stepping,
                         "advance_seconds": timer.seconds, "build_seconds": built - t0, "reset_seconds": reset - built,
                         "first_step_seconds": first}
    return out


class _AdvanceTimer:
    """Times a batch's ``physics.advance`` (the control step's launches and the wait for the GPU to finish them),
    so that a step splits into that and the host's own work (actions, observation, reward, success): two clock
    reads a step, nothing else changed."""

    def __init__(self, physics) -> None:
        self.seconds = 0.0
        self._advance = physics.advance
        physics.advance = self

    def __call__(self, substeps: int) -> None:
        t0 = time.perf_counter()
        self._advance(substeps)
        self.seconds += time.perf_counter() - t0


def longest_first(tasks: list[str], earlier: Path | None) -> list[str]:
    """``tasks`` by an earlier run's per-task seconds (its ``mt50.per_task``), longest first; the tasks it lacks
    last, in their order."""
    if earlier is None:
        return list(tasks)
    seconds = {t: r["seconds"] for t, r in json.loads(earlier.read_text())["mt50"]["per_task"].items()}
    return sorted(tasks, key=lambda t: -seconds.get(t, -1.0))


def mt50_section(tasks: list[str], episodes: int, procs: int, device: str | None, mps: bool = False,
                 order: Path | None = None, host_arrays: bool = False) -> dict[str, Any]:
    """``mps``: the processes as clients of a CUDA MPS server of the section's own (``runner.processes``);
    ``order``: an earlier run's JSON, whose per-task seconds order the tasks longest first."""
    import contextlib

    from simseam.runner.processes import MpsServer

    tasks = longest_first(tasks, order)
    with MpsServer() if mps else contextlib.nullcontext() as env:
        out = _mt50_timed(tasks, episodes, procs, device, env, host_arrays)
    offered = f"longest first by {order}" if order else "in the order given"
    return dict(out, mps=mps, host_arrays=host_arrays, dealing=f"claimed one at a time, {offered}")


def mt50_cli_section(tasks: list[str], episodes: int, procs: int, device: str | None, mps: bool) -> dict[str, Any]:
    """The same evaluation as a user runs it: ``simseam eval metaworld_mt50 --engine mujoco_warp --processes K
    [--mps] --policy random`` (the policy drawn on the host, per environment, by simseam's scheduler; the
    processes claim the tasks one at a time; the run written to disk and merged), timed from the command's start
    to its exit."""
    import tempfile

    from simseam.backends.metaworld_gpu.tasks import OBJECTS

    with tempfile.TemporaryDirectory(prefix="mt50-cli-") as tmp:
        out = Path(tmp) / "run"
        argv = ["eval", "metaworld_mt50", "--engine", "mujoco_warp", "--policy", "random", "--episodes",
                str(episodes), "--processes", str(procs), *(["--mps"] if mps else []),
                *(["--sim-device", device] if device else []),
                *([] if sorted(tasks) == sorted(OBJECTS) else ["--tasks", ",".join(tasks)])]
        t0, t0_epoch = time.perf_counter(), time.time()
        done = subprocess.run([sys.executable, "-m", "simseam.cli.main", *argv, "--out", str(out)],
                              capture_output=True, text=True)
        wall = time.perf_counter() - t0
        if done.returncode != 0:
            raise RuntimeError(f"simseam {' '.join(argv)}: exit {done.returncode}\n{done.stdout[-2000:]}")
        summary = json.loads((out / "summary.json").read_text())
        lines = [json.loads(line) for line in (out / "episodes.jsonl").read_text().splitlines()]
        processes = per_process(out, t0_epoch)  # before the run's folder goes
        by_task = stepping(out)
    step_ms = sorted(r["step_latency_ms"]["mean"] for r in lines)
    return {"command": "simseam " + " ".join(argv), "wall_seconds": wall,
            "episodes": summary["n_episodes"], "episodes_per_task": episodes, "tasks": len(tasks), "procs": procs,
            "mps": mps, "complete": summary["complete"], "env_steps_per_s": sum(r["steps"] for r in lines) / wall,
            "tasks_per_process": sorted(row["tasks"] for row in processes),
            "stepping_seconds": round(sum(by_task.values()), 2), "step_ms_median": step_ms[len(step_ms) // 2],
            "per_process": processes}


def _mt50_timed(tasks: list[str], episodes: int, procs: int, device: str | None, env: dict | None,
                host_arrays: bool = False) -> dict[str, Any]:
    t0 = time.perf_counter()
    if procs <= 1:
        per_task = mt50_worker(tasks, episodes, device, host_arrays=host_arrays)
    else:
        per_task = _mt50_processes(tasks, episodes, procs, device, dict(env or os.environ), host_arrays)
    wall = time.perf_counter() - t0
    n = sum(r["episodes"] for r in per_task.values())
    return {"episodes_per_task": episodes, "tasks": len(per_task), "episodes": n, "procs": procs,
            "wall_seconds": wall, "env_steps_per_s": sum(r["episodes"] * r["steps"] for r in per_task.values()) / wall,
            "step_split": step_split(per_task), "per_task": per_task}


def step_split(per_task: dict[str, Any]) -> dict[str, float]:
    """Over the tasks: a step's milliseconds (the median task's), of which ``physics.advance`` (the launches and
    the wait for the GPU) and the host's own work (the rest); and advance's share of all the stepping."""
    rows = list(per_task.values())
    step = np.array([1e3 * r["stepping_seconds"] / r["steps"] for r in rows])
    advance = np.array([1e3 * r["advance_seconds"] / r["steps"] for r in rows])
    out = {"step_ms_median": float(np.median(step)), "advance_ms_median": float(np.median(advance)),
           "host_ms_median": float(np.median(step - advance)),
           "advance_share": float(sum(r["advance_seconds"] for r in rows) / sum(r["stepping_seconds"] for r in rows))}
    if all("build_seconds" in r for r in rows):  # a task's seconds summed over the tasks: where the rest go
        out["task_seconds"] = {k: float(sum(r[f"{k}_seconds"] for r in rows))
                               for k in ("build", "reset", "first_step", "stepping")}
        out["task_seconds"]["total"] = float(sum(r["seconds"] for r in rows))
    return out


def _mt50_processes(tasks: list[str], episodes: int, procs: int, device: str | None, env: dict,
                    host_arrays: bool) -> dict[str, Any]:
    import tempfile

    with tempfile.TemporaryDirectory(prefix="mt50-claims-") as claims:
        workers = [subprocess.Popen([sys.executable, __file__, "--mt50-worker", ",".join(tasks), "--claims", claims,
                                     "--episodes", str(episodes), *(["--device", device] if device else []),
                                     *(["--host-arrays"] if host_arrays else [])],
                                    stdout=subprocess.PIPE, text=True, env=env) for _ in range(min(procs, len(tasks)))]
        per_task = {}
        for j, w in enumerate(workers):
            lines = w.stdout.read().strip().splitlines()
            if w.wait() != 0 or not lines:
                raise RuntimeError(f"mt50 worker {j} failed (rc {w.returncode})")
            per_task.update(json.loads(lines[-1]))
    missing = set(tasks) - set(per_task)
    if missing:
        raise RuntimeError(f"mt50: no process ran {sorted(missing)}")
    return per_task


# ----------------------------------------------------------------------------------------------- main
def machine(device: str | None) -> dict[str, Any]:
    facts: dict[str, Any] = {"cpu": platform.processor() or platform.machine(), "cores": os.cpu_count(),
                             "python": platform.python_version()}
    try:
        import mujoco
        import warp as wp

        wp.config.quiet = True
        wp.init()
        dev = wp.get_device(device) if device else wp.get_preferred_device()
        facts.update(mujoco=mujoco.__version__, warp=wp.config.version, device=str(dev), device_name=dev.name)
        from importlib.metadata import version

        facts["mujoco_warp"] = version("mujoco-warp")
    except Exception as exc:  # noqa: BLE001 - facts are best effort
        facts["error"] = repr(exc)
    try:
        with open("/proc/cpuinfo") as f:
            facts["cpu_model"] = next(line.split(":", 1)[1].strip() for line in f if line.startswith("model name"))
    except (OSError, StopIteration):
        pass
    return facts


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--tasks", default="mt50", help="comma-separated Meta-World v3 tasks, or 'mt50'")
    ap.add_argument("--worlds", default="1024,4096,8192", help="comma-separated world counts ('' to skip)")
    ap.add_argument("--steps", type=int, default=20, help="timed control steps per task and world count")
    ap.add_argument("--device", default=None, help="a Warp device (cuda:0, cpu); default Warp's preferred one")
    ap.add_argument("--cpu-procs", type=int, default=16)
    ap.add_argument("--cpu-seconds", type=float, default=30.0)
    ap.add_argument("--cpu-chunk", type=int, default=50)
    ap.add_argument("--episodes", type=int, default=50, help="per task, for the whole-MT50 wall time (0 skips)")
    ap.add_argument("--mt50-procs", type=int, default=1)
    ap.add_argument("--mps", action="store_true", help="the mt50 section's processes as clients of a CUDA MPS server")
    ap.add_argument("--host-arrays", action="store_true",
                    help="the Warp sections' observation and reward code in NumPy on host copies (MetaWorldBatch)")
    ap.add_argument("--mt50-order", type=Path, help="an earlier run's JSON: the mt50 tasks offered longest first")
    ap.add_argument("--mt50-cli", action="store_true", help="the mt50 section as a user runs it: simseam eval "
                    "metaworld_mt50 --engine mujoco_warp --processes K [--mps] --policy random (mt50_cli)")
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--out", type=Path, default=OUT)
    ap.add_argument("--overwrite", action="store_true")
    ap.add_argument("--cameras", default="", help="e.g. corner,gripperPOV: add the camera sections")
    ap.add_argument("--image", type=int, default=128, help="the cameras' image size (square)")
    ap.add_argument("--camera-worlds", default="1024,4096", help="world counts of the Warp camera section")
    ap.add_argument("--no-state", action="store_true", help="only the camera sections")
    ap.add_argument("--cpu-worker", help=argparse.SUPPRESS)
    ap.add_argument("--mt50-worker", help=argparse.SUPPRESS)
    ap.add_argument("--claims", type=Path, help=argparse.SUPPRESS)
    args = ap.parse_args(argv)
    if args.cpu_worker:
        cpu_worker(args.cpu_worker.split(","), args.cpu_chunk, args.cpu_seconds, args.seed, _names(args.cameras),
                   args.image)
        return 0
    if args.mt50_worker:
        print(json.dumps(mt50_worker(args.mt50_worker.split(","), args.episodes, args.device, args.claims,
                                     args.host_arrays)))
        return 0
    if args.out.exists() and not args.overwrite:
        print(f"{args.out} exists; pass --overwrite to replace it", file=sys.stderr)
        return 2
    from simseam.backends.metaworld_gpu.tasks import OBJECTS
    from simseam.files import write_atomic

    tasks = sorted(OBJECTS) if args.tasks == "mt50" else args.tasks.split(",")
    sizes = [] if args.no_state else [int(x) for x in args.worlds.split(",") if x]
    cameras = _names(args.cameras)
    camera_sizes = [int(x) for x in args.camera_worlds.split(",") if x] if cameras else []
    doc: dict[str, Any] = {"benchmark": "metaworld_warp_throughput", "policy": "uniform random actions",
                           "tasks": tasks, "machine": machine(args.device), "argv": sys.argv[1:]}

    def save() -> None:
        args.out.parent.mkdir(parents=True, exist_ok=True)
        write_atomic(args.out, json.dumps(doc, indent=1))

    if args.cpu_procs and not args.no_state:
        doc["cpu"] = cpu_section(tasks, args.cpu_procs, args.cpu_chunk, args.cpu_seconds)
        print(f"cpu backend, {args.cpu_procs} processes: {doc['cpu']['env_steps_per_s']:,.0f} env-steps/s", flush=True)
        save()
    def keeper(key: str):  # on disk after every task: {world count: ...} under doc[key], earlier counts kept
        def keep(rows: dict[str, Any]) -> None:
            doc.setdefault(key, {}).update(rows)
            save()
        return keep

    for n in sizes:
        keeper("warp")(warp_section(tasks, [n], args.steps, args.device, host_arrays=args.host_arrays,
                                    on_task=keeper("warp")))
    if cameras and args.cpu_procs:
        doc["cpu_cameras"] = cpu_section(tasks, args.cpu_procs, args.cpu_chunk, args.cpu_seconds, cameras, args.image)
        print(f"cpu backend with {','.join(cameras)} at {args.image}^2, {args.cpu_procs} processes: "
              f"{doc['cpu_cameras']['env_steps_per_s']:,.0f} env-steps/s", flush=True)
        save()
    for n in camera_sizes:
        keeper("warp_cameras")(warp_section(tasks, [n], args.steps, args.device, cameras, args.image,
                                            on_task=keeper("warp_cameras")))
    if args.episodes and args.mt50_cli:
        doc["mt50_cli"] = mt50_cli_section(tasks, args.episodes, args.mt50_procs, args.device, args.mps)
        print(f"{doc['mt50_cli']['command']}: {doc['mt50_cli']['wall_seconds']:.1f} s wall, "
              f"{doc['mt50_cli']['episodes']} episodes, tasks per process {doc['mt50_cli']['tasks_per_process']}; "
              f"stepping {doc['mt50_cli']['stepping_seconds']:.1f} s summed (a step's median "
              f"{doc['mt50_cli']['step_ms_median']:.2f} ms)")
        for row in doc["mt50_cli"]["per_process"]:
            print("  a process: " + ", ".join(f"{k} {v}" for k, v in row.items()))
        save()
    elif args.episodes and not args.no_state:
        doc["mt50"] = mt50_section(tasks, args.episodes, args.mt50_procs, args.device, args.mps, args.mt50_order,
                                   args.host_arrays)
        save()
    print_table(doc)
    print(f"wrote {args.out}")
    return 0


def print_table(doc: dict[str, Any]) -> None:
    print(f"\n{'path':44s} {'env-steps/s':>14s} {'slowest task':>14s} {'vs CPU':>8s}")
    for cpu_key, warp_key, what in (("cpu", "warp", ""), ("cpu_cameras", "warp_cameras", ", cameras")):
        cpu = doc.get(cpu_key, {}).get("env_steps_per_s")
        if cpu:
            name = f"CPU backend, {doc[cpu_key]['procs']} processes{what}"
            print(f"{name:44s} {cpu:14,.0f} {'':>14s} {'1.0x':>8s}")
        for n, row in doc.get(warp_key, {}).items():
            ratio = f"{row['env_steps_per_s'] / cpu:.1f}x" if cpu else "-"
            print(f"{'MuJoCo Warp, ' + n + ' worlds' + what:44s} {row['env_steps_per_s']:14,.0f} "
                  f"{row['slowest_task_env_steps_per_s']:14,.0f} {ratio:>8s}")
    if "mt50" in doc:
        m = doc["mt50"]
        print(f"\nwhole run: {m['tasks']} tasks x {m['episodes_per_task']} episodes ({m['episodes']}) "
              f"in {m['wall_seconds']:.1f} s wall ({m['procs']} process(es); builds and resets included)")
        sp = m["step_split"]
        print(f"a step (median task): {sp['step_ms_median']:.2f} ms, of which physics.advance (launches and the GPU "
              f"wait) {sp['advance_ms_median']:.2f} ms, the host {sp['host_ms_median']:.2f} ms; advance "
              f"{100 * sp['advance_share']:.0f} % of all stepping")
        if "task_seconds" in sp:
            t = sp["task_seconds"]
            print(f"the tasks' seconds summed: {t['total']:.1f}, of which builds {t['build']:.1f}, resets "
                  f"{t['reset']:.1f}, stepping {t['stepping']:.1f} (its first steps {t['first_step']:.1f}; the rest: "
                  f"closing)")


def _names(text: str | None) -> list[str]:
    return [x for x in (text or "").split(",") if x]


if __name__ == "__main__":
    sys.exit(main())
