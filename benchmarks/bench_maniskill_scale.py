"""ManiSkill3 native vs through simseam at N environments: aggregate env-steps/s, same run, alternating.

For each ``--kinds`` (``state``; ``rgb``: ManiSkill's ``base_camera`` at ``--image-size``, 128x128 by
default, as simseam's maniskill backend requests it) and each N in ``--n``:

- **native**: N independent processes, each running ManiSkill's own gym env (``gym.make(task, num_envs=1,
  obs_mode="state" | "rgb", sim_backend="physx_cpu", control_mode="pd_ee_delta_pose",
  render_backend="none" | "gpu", sensor_configs=...)``, the kwargs simseam's backend uses; ``rgb`` is
  ManiSkill's own camera observation mode), ``torch.set_num_threads(1)`` as the backend sets it;
- **seam**: N worker processes, each owning one ``SidecarRollout`` of ``BackendTarget("maniskill", ...)``
  (one env per sidecar: the sidecar ``simseam eval --num-envs N`` starts per worker on physx_cpu), the
  sidecar's interpreter the backend's (``--backend-python``), busy-polling as that command's workers'
  sidecars do (``runner.vector.sidecar_spin_us``: not at all where 2N + 1 processes exceed the cores;
  ``--spin-us`` overrides it); ``rgb``: ``cameras: true`` and every step's observation carries ``camera1``.

Both sides step the same seeded uniform random actions (the seam's grip negated, so ManiSkill receives
identical actions), reset with ``env.reset(seed)`` every ``--episode-steps`` (ManiSkill's PickCube limit,
50), and run ``--steps`` steps per round. All processes of a case are started once (ManiSkill imported,
the env built, one warm-up round per side), then the rounds alternate native / seam (ABBA order). Each
worker times its own round with ``time.monotonic()`` (one clock for every process on Linux); a round's
rate is ``N * steps / (last end - first start)``. Reported per case: the median round rate per side and
``overhead = native_rate / seam_rate - 1`` (from the medians; ``overhead_paired``: the median of the
per-pair ratios). Each worker also reports the CPU time its round took, and the time it waited runnable on a
run queue (``/proc/PID/task/*/schedstat``, all threads): its own, and for the seam its sidecar's, per env-step
(``*_cpu_ms_per_step``, ``*_runq_wait_ms_per_step``: [worker] or [worker, sidecar]); on a shared or
oversubscribed machine the CPU time says what each side costs where the rates mostly say what else ran.
``--seam-variant NAME=SRC[@SPIN_US]`` adds seam sides that import simseam from another source tree (an older
commit's ``src``) and/or busy-poll differently, alternated with the others in the same run: before / after.
Prints a markdown table and writes JSON.

    .venv/bin/python benchmarks/bench_maniskill_scale.py --n 1 2 --steps 20 --rounds 2     # here, CPU
    git archive REV src | tar -x -C /tmp/before       # then, before / after in one run:
    .venv/bin/python benchmarks/bench_maniskill_scale.py --n 1 --kinds state --seam-variant before=/tmp/before/src
    # the GPU machine (benchmarks/device/maniskill_upload.sh run prints the exact command):
    python3 bench_maniskill_scale.py --n 1 16 --backend-python python3 --backend-env PYTHONPATH=/tmp/mssite

``--backend-python`` (default: the provisioned backend venv's python, else this interpreter) runs the
native workers and the sidecars; ``--backend-env KEY=VALUE`` adds to their environment (a
``PYTHONPATH`` there is appended through a small wrapper script, because the sidecar client replaces
PYTHONPATH with its own ``simseam`` path). Vulkan: where neither ``VK_ICD_FILENAMES`` nor a GPU's ICD
is set, both sides get simseam's software Vulkan (``simseam.backends.software_vulkan.sidecar_env()``,
Mesa lavapipe), as ``open_benchmark`` gives the sidecar.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import queue
import shutil
import statistics
import subprocess
import sys
import tempfile
import threading
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))
from bench_libero_scale import machine  # noqa: E402  (host, cores, CPU and GPU names)

HERE = Path(__file__).resolve()
PREFIX = "@@ "
DEFAULT_TASK = "PickCube-v1"
CONTROL_MODE = "pd_ee_delta_pose"
TARGETS = {"state": 0.05, "rgb": 0.10}  # issue 23: overhead at N = 16


# ---------------------------------------------------------------------------------------------- workers
def _send(msg: dict) -> None:
    sys.stdout.write(PREFIX + json.dumps(msg) + "\n")
    sys.stdout.flush()


def _actions(seed: int, index: int, rnd: int, steps: int):
    import numpy as np

    rng = np.random.default_rng([seed, index, rnd])
    return rng.uniform(-1.0, 1.0, size=(steps, 7)).astype(np.float32)


def schedstat(pid: int) -> tuple[int, int]:
    """Nanoseconds process ``pid`` (all its threads) has run on a CPU, and has waited runnable on a run
    queue (``/proc/PID/task/*/schedstat``; (0, 0) where unreadable). Threads that exited are not counted:
    the difference over a round is what the live ones did."""
    run = wait = 0
    try:
        tasks = os.listdir(f"/proc/{pid}/task")
    except OSError:
        return 0, 0
    for t in tasks:
        try:
            with open(f"/proc/{pid}/task/{t}/schedstat") as f:
                a, b, _ = f.read().split()
        except (OSError, ValueError):
            continue
        run += int(a)
        wait += int(b)
    return run, wait


def _worker_loop(reset, step, args, pids: tuple[int, ...] = ()) -> None:
    """Answer ``{"steps", "round"}`` requests on stdin: reset every ``episode_steps``, step, time it; and
    the CPU time (and run-queue wait) of this process and of ``pids`` (the sidecar) over the round."""
    procs = (os.getpid(), *pids)
    for line in sys.stdin:
        req = json.loads(line)
        if req.get("quit"):
            break
        steps, rnd = int(req["steps"]), int(req["round"])
        acts = _actions(args.seed, args.index, rnd, steps)
        episode = 0
        c0 = [schedstat(p) for p in procs]
        t0 = time.monotonic()
        for i in range(steps):
            if i % args.episode_steps == 0:
                reset(args.seed + 1000 * args.index + 100 * rnd + episode)
                episode += 1
            step(acts[i])
        t1 = time.monotonic()
        c1 = [schedstat(p) for p in procs]
        _send({"t0": t0, "t1": t1, "steps": steps, "resets": episode,
               "cpu_s": [(b[0] - a[0]) * 1e-9 for a, b in zip(c0, c1)],
               "wait_s": [(b[1] - a[1]) * 1e-9 for a, b in zip(c0, c1)]})


def native_worker(args) -> None:
    t = time.monotonic()
    try:  # where SAPIEN cannot render, the same physics-only stand-in the backend (and its tests) use
        from simseam.backends.maniskill import allow_physics_only

        allow_physics_only()
    except ImportError:
        pass
    import logging

    import gymnasium as gym
    import mani_skill.envs  # noqa: F401  (registers the tasks)
    import torch

    logging.getLogger("mani_skill").setLevel(logging.ERROR)
    torch.set_num_threads(1)  # as simseam's backend sets it
    h, w = args.image_size
    rgb = args.kind == "rgb"
    env = gym.make(args.task, num_envs=1, obs_mode="rgb" if rgb else "state", control_mode=CONTROL_MODE,
                   sim_backend="physx_cpu", render_mode=None, render_backend="gpu" if rgb else "none",
                   sensor_configs=dict(width=w, height=h))
    u = env.unwrapped
    import mani_skill
    import sapien

    def reset(seed: int):
        obs, _ = env.reset(seed=seed)
        return _native_obs(obs, rgb)

    def step(a):
        obs, reward, _term, _trunc, info = env.step(a)
        out = _native_obs(obs, rgb)
        return out, float(reward[0]), bool(info["success"][0])

    first = reset(0)
    _send({"ready": True, "build_s": time.monotonic() - t, "pid": os.getpid(),
           "versions": {"mani_skill": mani_skill.__version__, "sapien": sapien.__version__,
                        "torch": torch.__version__, "python": platform.python_version()},
           "render_device": str(getattr(u, "_render_device", "")),
           "image": list(first[1].shape) if rgb else None})
    _worker_loop(reset, step, args)
    env.close()


def _native_obs(obs, rgb: bool):
    if not rgb:
        return obs[0].cpu().numpy(), None
    image = obs["sensor_data"]["base_camera"]["rgb"][0].cpu().numpy()
    return obs["agent"]["qpos"][0].cpu().numpy(), image


def seam_worker(args) -> None:
    t = time.monotonic()
    import numpy as np

    from simseam.backends.maniskill import normalize_config
    from simseam.sidecar.client import SidecarRollout
    from simseam.sidecar.target import BackendTarget

    config = normalize_config({"task": args.task, "control_mode": CONTROL_MODE, "cameras": args.kind == "rgb",
                               "image_size": list(args.image_size), "sim_backend": "physx_cpu"})
    env = json.loads(args.backend_env_json)
    rollout = SidecarRollout(BackendTarget("maniskill", config), python=args.backend_python, env=env,
                             boot_timeout=600.0, request_timeout=300.0, spin_us=args.spin_us)

    def reset(seed: int):
        return rollout.reset(seed=seed)

    def step(a):
        a = a.copy()
        a[-1] = -a[-1]  # the seam's grip (+1 closed) is ManiSkill's negated: ManiSkill gets the native action
        return rollout.step(a)

    obs = reset(0)
    image = obs["images"].get("camera1")
    import simseam

    _send({"ready": True, "simseam": str(Path(simseam.__file__).resolve().parent), "build_s": time.monotonic() - t, "pid": os.getpid(), "sidecar_pid": rollout.pid,
           "engine": rollout.spec.engine, "fast": bool(rollout.fast), "compact": bool(rollout.compact),
           "spin_us": int(rollout._spin_us), "image": list(np.shape(image)) if image is not None else None})
    try:
        _worker_loop(reset, step, args, (rollout.pid,))
    finally:
        rollout.close()


# ---------------------------------------------------------------------------------------------- parent
class Worker:
    def __init__(self, argv: list[str], env: dict[str, str], log: Path):
        self.log = log
        self._err = open(log, "wb")
        self.proc = subprocess.Popen(argv, stdin=subprocess.PIPE, stdout=subprocess.PIPE, stderr=self._err,
                                     env=env, text=True, bufsize=1)
        self.q: queue.Queue = queue.Queue()
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self) -> None:
        for line in self.proc.stdout:
            if line.startswith(PREFIX):
                self.q.put(json.loads(line[len(PREFIX):]))
        self.q.put(None)

    def send(self, msg: dict) -> None:
        self.proc.stdin.write(json.dumps(msg) + "\n")
        self.proc.stdin.flush()

    def recv(self, deadline: float) -> dict:
        try:
            msg = self.q.get(timeout=max(0.1, deadline - time.monotonic()))
        except queue.Empty:
            raise RuntimeError(f"worker {self.proc.pid} timed out; log {self.log}:\n{self.tail()}") from None
        if msg is None:
            self.proc.wait()
            raise RuntimeError(f"worker {self.proc.pid} exited {self.proc.returncode}; log {self.log}:\n{self.tail()}")
        return msg

    def tail(self, n: int = 30) -> str:
        self._err.flush()
        try:
            return "\n".join(self.log.read_text(errors="replace").splitlines()[-n:])
        except OSError:
            return ""

    def close(self) -> None:
        try:
            self.send({"quit": True})
            self.proc.stdin.close()
        except (BrokenPipeError, OSError, ValueError):
            pass
        try:
            self.proc.wait(timeout=30)
        except subprocess.TimeoutExpired:
            self.proc.kill()
            self.proc.wait()
        self._err.close()


def default_backend_python() -> str:
    try:
        from simseam.backends.provision import python_of

        p = python_of("maniskill")
        if p.exists():
            return str(p)
    except Exception:  # noqa: BLE001  (no provisioned venv: this interpreter)
        pass
    return sys.executable


def vulkan_env() -> dict[str, str]:
    """The software Vulkan driver where no GPU driver / VK_ICD_FILENAMES is set (as open_benchmark does)."""
    try:
        from simseam.backends import software_vulkan

        return software_vulkan.sidecar_env()
    except ImportError:
        return {}


def backend_launch(python: str, extra: dict[str, str]) -> tuple[str, dict[str, str]]:
    """The backend interpreter (a wrapper appending ``extra['PYTHONPATH']`` when set) and its extra env."""
    extra = dict(extra)
    path = extra.pop("PYTHONPATH", "")
    if not path:
        return python, extra
    wrapper = Path(tempfile.mkdtemp(prefix="ms-backend-")) / "python"  # /tmp: not a noexec output folder
    real = shutil.which(python) or python
    wrapper.write_text("#!/bin/sh\n"
                       f'PYTHONPATH="${{PYTHONPATH:+$PYTHONPATH:}}{path}"\n'
                       "export PYTHONPATH\n"
                       f'exec "{real}" "$@"\n')
    wrapper.chmod(0o755)
    return str(wrapper), extra


def runner_spin_us(n: int) -> int | None:
    """The sidecar busy-poll the vector runner gives N workers here (``runner.vector.sidecar_spin_us``): 0
    when the N workers, their N sidecars and the parent outnumber the cores, else None (the sidecar's own
    default). A SidecarRollout left to its own default decides from the 1-minute load average, which cannot
    see N workers that all start at once: at N = cores they would all spin."""
    from simseam.runner.vector import sidecar_spin_us

    return sidecar_spin_us(n, len(os.sched_getaffinity(0)))


def start(side: str, kind: str, n: int, args, backend_python: str, backend_extra: dict[str, str], src: str,
          logs: Path) -> list[Worker]:
    """N workers of ``side``: "native", "seam", or a ``--seam-variant`` name (a seam side whose worker, and
    so its sidecar, imports simseam from that variant's source tree)."""
    mode = "native" if side == "native" else "seam"
    common = ["--worker", mode, "--kind", kind, "--task", args.task, "--seed", str(args.seed),
              "--episode-steps", str(args.episode_steps), "--image-size", *map(str, args.image_size)]
    base = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    variants = {name: (path, spin) for name, path, spin in args.seam_variant}
    runner_spin = runner_spin_us(n)
    workers = []
    for i in range(n):
        log = logs / f"{kind}_n{n}_{side}{i}.log"
        if side == "native":
            env = {**base, **backend_extra, "PYTHONPATH": src}
            argv = [backend_python, str(HERE), *common, "--index", str(i)]
        else:
            env = dict(os.environ)
            spin = runner_spin if args.spin_us is None else args.spin_us
            if side != "seam":  # the variant's simseam first, before this one's (and whatever else is on the path)
                path, spin = variants[side]
                spin = runner_spin if spin is None else spin
                env["PYTHONPATH"] = os.pathsep.join(p for p in (path, os.environ.get("PYTHONPATH")) if p)
            argv = [sys.executable, str(HERE), *common, "--index", str(i), "--backend-python", backend_python,
                    "--backend-env-json", json.dumps(backend_extra)]
            if spin is not None:
                argv += ["--spin-us", str(spin)]
        workers.append(Worker(argv, env, log))
    return workers


def run_round(workers: list[Worker], steps: int, rnd: int, timeout: float) -> dict:
    for w in workers:
        w.send({"steps": steps, "round": rnd})
    deadline = time.monotonic() + timeout
    replies = [w.recv(deadline) for w in workers]
    t0 = min(r["t0"] for r in replies)
    t1 = max(r["t1"] for r in replies)
    total = sum(r["steps"] for r in replies)
    per_env = [1000.0 * (r["t1"] - r["t0"]) / r["steps"] for r in replies]
    # CPU per env-step: [worker] (native) or [worker, sidecar] (seam), summed over the workers
    cpu = [1000.0 * sum(x) / total for x in zip(*(r["cpu_s"] for r in replies))]
    wait = [1000.0 * sum(x) / total for x in zip(*(r["wait_s"] for r in replies))]
    return {"rate": total / (t1 - t0), "wall_s": t1 - t0, "steps": total,
            "ms_per_step_env": statistics.median(per_env), "ms_per_step_env_max": max(per_env),
            "cpu_ms_per_step": cpu, "runq_wait_ms_per_step": wait}


def run_case(kind: str, n: int, args, backend_python: str, backend_extra: dict[str, str], src: str,
             logs: Path) -> dict:
    t = time.monotonic()
    names = ["native", "seam", *(v[0] for v in args.seam_variant)]
    sides = {}
    try:
        for side in names:
            sides[side] = start(side, kind, n, args, backend_python, backend_extra, src, logs)
        deadline = time.monotonic() + args.boot_timeout
        ready = {side: [w.recv(deadline) for w in ws] for side, ws in sides.items()}
        boot_s = time.monotonic() - t
        warm = {side: run_round(ws, args.warmup_steps, 99, args.round_timeout) for side, ws in sides.items()}
        rounds: dict[str, list[dict]] = {side: [] for side in names}
        for r in range(args.rounds):
            for side in (names if r % 2 == 0 else names[::-1]):  # ABBA (ABCCBA, ...)
                rounds[side].append(run_round(sides[side], args.steps, r, args.round_timeout))
    finally:
        for ws in sides.values():
            for w in ws:
                w.close()
    out = {"kind": kind, "n": n, "steps": args.steps, "rounds": args.rounds,
           "native_rate": statistics.median(x["rate"] for x in rounds["native"]),
           "native_ms_per_step_env": statistics.median(x["ms_per_step_env"] for x in rounds["native"]),
           "native_cpu_ms_per_step": _median_cols(x["cpu_ms_per_step"] for x in rounds["native"]),
           "native_runq_wait_ms_per_step": _median_cols(x["runq_wait_ms_per_step"] for x in rounds["native"])}
    for side in names[1:]:
        rate = statistics.median(x["rate"] for x in rounds[side])
        stats = {"rate": rate, "overhead": out["native_rate"] / rate - 1,
                 "overhead_paired": statistics.median(a["rate"] / b["rate"] - 1
                                                      for a, b in zip(rounds["native"], rounds[side])),
                 "ms_per_step_env": statistics.median(x["ms_per_step_env"] for x in rounds[side]),
                 "cpu_ms_per_step": _median_cols(x["cpu_ms_per_step"] for x in rounds[side]),
                 "runq_wait_ms_per_step": _median_cols(x["runq_wait_ms_per_step"] for x in rounds[side]),
                 "spin_us": [x.get("spin_us") for x in ready[side]]}
        if side == "seam":  # (overhead, overhead_paired: the keys earlier results used)
            out.update({"seam_rate": rate, "overhead": stats.pop("overhead"),
                        "overhead_paired": stats.pop("overhead_paired"), **{f"seam_{k}": v for k, v in stats.items()}})
        else:
            out.setdefault("variants", {})[side] = stats
    out.update({"boot_s": boot_s, "case_s": time.monotonic() - t, "warmup": warm, "rounds_detail": rounds,
                "ready": {side: ready[side][0] for side in names}})
    return out


def _median_cols(rows) -> list[float]:
    """Column-wise medians of per-round lists ([worker] or [worker, sidecar])."""
    return [statistics.median(col) for col in zip(*rows)]


def table(results: list[dict]) -> str:
    lines = ["| kind | N | native env-steps/s | seam env-steps/s | overhead (medians) | overhead (paired) | "
             "native ms/step/env | seam ms/step/env | native CPU ms/step | seam CPU ms/step (worker + sidecar) | "
             "target |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in results:
        target = TARGETS.get(r["kind"])
        seams = [("", {"overhead": r["overhead"], "overhead_paired": r["overhead_paired"],
                       **{k[5:]: v for k, v in r.items() if k.startswith("seam_")}}),
                 *((f" ({name})", v) for name, v in r.get("variants", {}).items())]
        for label, x in seams:
            mark = ""
            if target is not None and r["n"] == 16:
                mark = f"<= {100 * target:.0f} %: {'met' if x['overhead'] <= target else 'NOT met'}"
            lines.append(f"| {r['kind']}{label} | {r['n']} | {r['native_rate']:.1f} | {x['rate']:.1f} | "
                         f"{100 * x['overhead']:+.1f} % | {100 * x['overhead_paired']:+.1f} % | "
                         f"{r['native_ms_per_step_env']:.2f} | {x['ms_per_step_env']:.2f} | "
                         f"{sum(r['native_cpu_ms_per_step']):.2f} | {sum(x['cpu_ms_per_step']):.2f} "
                         f"({' + '.join(f'{c:.2f}' for c in x['cpu_ms_per_step'])}) | {mark} |")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1, 16], help="environments (processes) per side")
    ap.add_argument("--kinds", nargs="+", default=["state", "rgb"], choices=["state", "rgb"])
    ap.add_argument("--steps", type=int, default=300, help="steps per environment per round")
    ap.add_argument("--rounds", type=int, default=4, help="rounds per side, alternating (ABBA)")
    ap.add_argument("--warmup-steps", type=int, default=20)
    ap.add_argument("--episode-steps", type=int, default=50, help="reset every this many steps (PickCube: 50)")
    ap.add_argument("--task", default=DEFAULT_TASK)
    ap.add_argument("--image-size", type=int, nargs=2, default=[128, 128], metavar=("H", "W"))
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--backend-python", default=None, help="interpreter of the native workers and the sidecars")
    ap.add_argument("--backend-env", nargs="*", default=[], metavar="KEY=VALUE",
                    help="added to the backend side's environment (PYTHONPATH: appended via a wrapper)")
    ap.add_argument("--spin-us", type=int, default=None,
                    help="sidecar busy-poll (default: the vector runner's rule for N workers: 0 where 2N + 1 "
                         "exceed the cores, else the sidecar's own default)")
    ap.add_argument("--seam-variant", nargs="*", default=[], metavar="NAME=SRC",
                    help="extra seam sides, each importing simseam from SRC (e.g. an older commit's src: git "
                         "archive REV src | tar -x -C DIR; '.' for this one) and busy-polling SPIN_US (default: "
                         "--spin-us), alternated with the others: before/after in one run")
    ap.add_argument("--boot-timeout", type=float, default=600.0)
    ap.add_argument("--round-timeout", type=float, default=600.0)
    ap.add_argument("--out", default=None, help="JSON (default benchmarks/results/maniskill_scale.json)")
    ap.add_argument("--logs", default=None, help="worker stderr logs (default: a temp dir, kept on failure)")
    # worker mode (internal)
    ap.add_argument("--worker", choices=["native", "seam"], help=argparse.SUPPRESS)
    ap.add_argument("--kind", choices=["state", "rgb"], help=argparse.SUPPRESS)
    ap.add_argument("--index", type=int, default=0, help=argparse.SUPPRESS)
    ap.add_argument("--backend-env-json", default="{}", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.worker == "native":
        return native_worker(args)
    if args.worker == "seam":
        return seam_worker(args)

    import simseam

    src = str(Path(simseam.__file__).resolve().parents[1])
    logs = Path(args.logs) if args.logs else Path(tempfile.mkdtemp(prefix="ms-scale-logs-"))
    logs.mkdir(parents=True, exist_ok=True)
    extra = dict(vulkan_env())
    for kv in args.backend_env:
        key, sep, value = kv.partition("=")
        if not sep:
            ap.error(f"--backend-env: KEY=VALUE, got {kv!r}")
        extra[key] = value
    variants = []
    for kv in args.seam_variant:
        name, sep, rest = kv.partition("=")
        path, at, spin = rest.partition("@")
        path = str(Path(path).resolve()) if path not in ("", ".") else src
        if not sep or name in ("native", "seam") or not Path(path, "simseam").is_dir() or (at and not spin.isdigit()):
            ap.error(f"--seam-variant: NAME=SRC[@SPIN_US] with SRC/simseam a directory (. for this one), NAME not "
                     f"native/seam; got {kv!r}")
        variants.append((name, path, int(spin) if at else args.spin_us))
    args.seam_variant = variants
    backend_python, backend_extra = backend_launch(args.backend_python or default_backend_python(), extra)
    info = {"machine": machine(), "backend_python": args.backend_python or default_backend_python(),
            "backend_env": extra, "vk_icd_filenames": os.environ.get("VK_ICD_FILENAMES", ""),
            "argv": sys.argv, "simseam_src": src}
    print(f"# ManiSkill3 {args.task} native vs simseam: {info['machine']['cores']} cores, "
          f"{info['machine']['gpu'] or info['machine']['cpu']}; backend {info['backend_python']}; "
          f"logs {logs}", flush=True)
    results = []
    out = Path(args.out) if args.out else HERE.parent / "results" / "maniskill_scale.json"
    for kind in args.kinds:
        for n in args.n:
            r = run_case(kind, n, args, backend_python, backend_extra, src, logs)
            results.append(r)
            rn, rs = r["ready"]["native"], r["ready"]["seam"]
            print(f"{kind} N={n}: native {r['native_rate']:.1f}/s, seam {r['seam_rate']:.1f}/s, overhead "
                  f"{100 * r['overhead']:+.1f} % (paired {100 * r['overhead_paired']:+.1f} %); boot {r['boot_s']:.0f} s, "
                  f"case {r['case_s']:.0f} s; render {rn.get('render_device')}, seam fast={rs.get('fast')} "
                  f"compact={rs.get('compact')} spin_us={sorted(set(r['seam_spin_us']))}"
                  + "".join(f"; {name}: {v['rate']:.1f}/s, overhead {100 * v['overhead']:+.1f} % (paired "
                            f"{100 * v['overhead_paired']:+.1f} %)" for name, v in r.get("variants", {}).items()),
                  flush=True)
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(json.dumps({**info, "results": results}, indent=1))
    print()
    print(table(results))
    print(f"\nJSON: {out}")


if __name__ == "__main__":
    main()
