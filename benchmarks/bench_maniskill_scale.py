"""ManiSkill3 native vs through simseam at N environments: aggregate env-steps/s, same run, alternating.

For each ``--kinds`` (``state``; ``rgb``: ManiSkill's ``base_camera`` at ``--image-size``, 128x128 by
default, as simseam's maniskill backend requests it) and each N in ``--n``:

- **native**: N independent processes, each running ManiSkill's own gym env (``gym.make(task, num_envs=1,
  obs_mode="state" | "rgb", sim_backend="physx_cpu", control_mode="pd_ee_delta_pose",
  render_backend="none" | "gpu", sensor_configs=...)``, the kwargs simseam's backend uses; ``rgb`` is
  ManiSkill's own camera observation mode), ``torch.set_num_threads(1)`` as the backend sets it;
- **seam**: N worker processes, each owning one ``SidecarRollout`` of ``BackendTarget("maniskill", ...)``
  (one env per sidecar: the sidecar ``simseam eval --num-envs N`` starts per worker on physx_cpu), the
  sidecar's interpreter the backend's (``--backend-python``); ``rgb``: ``cameras: true`` and every step's
  observation carries ``camera1``.

Both sides step the same seeded uniform random actions (the seam's grip negated, so ManiSkill receives
identical actions), reset with ``env.reset(seed)`` every ``--episode-steps`` (ManiSkill's PickCube limit,
50), and run ``--steps`` steps per round. All processes of a case are started once (ManiSkill imported,
the env built, one warm-up round per side), then the rounds alternate native / seam (ABBA order). Each
worker times its own round with ``time.monotonic()`` (one clock for every process on Linux); a round's
rate is ``N * steps / (last end - first start)``. Reported per case: the median round rate per side and
``overhead = native_rate / seam_rate - 1`` (from the medians; ``overhead_paired``: the median of the
per-pair ratios). Prints a markdown table and writes JSON.

    .venv/bin/python benchmarks/bench_maniskill_scale.py --n 1 2 --steps 20 --rounds 2     # here, CPU
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


def _worker_loop(reset, step, args) -> None:
    """Answer ``{"steps", "round"}`` requests on stdin: reset every ``episode_steps``, step, time it."""
    for line in sys.stdin:
        req = json.loads(line)
        if req.get("quit"):
            break
        steps, rnd = int(req["steps"]), int(req["round"])
        acts = _actions(args.seed, args.index, rnd, steps)
        episode = 0
        t0 = time.monotonic()
        for i in range(steps):
            if i % args.episode_steps == 0:
                reset(args.seed + 1000 * args.index + 100 * rnd + episode)
                episode += 1
            step(acts[i])
        t1 = time.monotonic()
        _send({"t0": t0, "t1": t1, "steps": steps, "resets": episode})


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
    _send({"ready": True, "build_s": time.monotonic() - t, "pid": os.getpid(), "sidecar_pid": rollout.pid,
           "engine": rollout.spec.engine, "fast": bool(rollout.fast), "compact": bool(rollout.compact),
           "spin_us": int(rollout._spin_us), "image": list(np.shape(image)) if image is not None else None})
    try:
        _worker_loop(reset, step, args)
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


def start(side: str, kind: str, n: int, args, backend_python: str, backend_extra: dict[str, str], src: str,
          logs: Path) -> list[Worker]:
    common = ["--worker", side, "--kind", kind, "--task", args.task, "--seed", str(args.seed),
              "--episode-steps", str(args.episode_steps), "--image-size", *map(str, args.image_size)]
    base = {k: v for k, v in os.environ.items() if k != "PYTHONPATH"}
    workers = []
    for i in range(n):
        log = logs / f"{kind}_n{n}_{side}{i}.log"
        if side == "native":
            env = {**base, **backend_extra, "PYTHONPATH": src}
            argv = [backend_python, str(HERE), *common, "--index", str(i)]
        else:
            env = dict(os.environ)
            argv = [sys.executable, str(HERE), *common, "--index", str(i), "--backend-python", backend_python,
                    "--backend-env-json", json.dumps(backend_extra)]
            if args.spin_us is not None:
                argv += ["--spin-us", str(args.spin_us)]
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
    return {"rate": total / (t1 - t0), "wall_s": t1 - t0, "steps": total,
            "ms_per_step_env": statistics.median(per_env), "ms_per_step_env_max": max(per_env)}


def run_case(kind: str, n: int, args, backend_python: str, backend_extra: dict[str, str], src: str,
             logs: Path) -> dict:
    t = time.monotonic()
    sides = {}
    try:
        for side in ("native", "seam"):
            sides[side] = start(side, kind, n, args, backend_python, backend_extra, src, logs)
        deadline = time.monotonic() + args.boot_timeout
        ready = {side: [w.recv(deadline) for w in ws] for side, ws in sides.items()}
        boot_s = time.monotonic() - t
        warm = {side: run_round(ws, args.warmup_steps, 99, args.round_timeout) for side, ws in sides.items()}
        rounds: dict[str, list[dict]] = {"native": [], "seam": []}
        for r in range(args.rounds):
            order = ("native", "seam") if r % 2 == 0 else ("seam", "native")
            for side in order:
                rounds[side].append(run_round(sides[side], args.steps, r, args.round_timeout))
    finally:
        for ws in sides.values():
            for w in ws:
                w.close()
    native = statistics.median(x["rate"] for x in rounds["native"])
    seam = statistics.median(x["rate"] for x in rounds["seam"])
    paired = statistics.median(a["rate"] / b["rate"] - 1 for a, b in zip(rounds["native"], rounds["seam"]))
    return {"kind": kind, "n": n, "steps": args.steps, "rounds": args.rounds, "native_rate": native,
            "seam_rate": seam, "overhead": native / seam - 1, "overhead_paired": paired,
            "native_ms_per_step_env": statistics.median(x["ms_per_step_env"] for x in rounds["native"]),
            "seam_ms_per_step_env": statistics.median(x["ms_per_step_env"] for x in rounds["seam"]),
            "boot_s": boot_s, "case_s": time.monotonic() - t, "warmup": warm, "rounds_detail": rounds,
            "ready": {"native": ready["native"][0], "seam": ready["seam"][0]},
            "seam_spin_us": [x.get("spin_us") for x in ready["seam"]]}


def table(results: list[dict]) -> str:
    lines = ["| kind | N | native env-steps/s | seam env-steps/s | overhead (medians) | overhead (paired) | "
             "native ms/step/env | seam ms/step/env | target |",
             "|---|---:|---:|---:|---:|---:|---:|---:|---|"]
    for r in results:
        target = TARGETS.get(r["kind"])
        mark = ""
        if target is not None and r["n"] == 16:
            mark = f"<= {100 * target:.0f} %: {'met' if r['overhead'] <= target else 'NOT met'}"
        lines.append(f"| {r['kind']} | {r['n']} | {r['native_rate']:.1f} | {r['seam_rate']:.1f} | "
                     f"{100 * r['overhead']:+.1f} % | {100 * r['overhead_paired']:+.1f} % | "
                     f"{r['native_ms_per_step_env']:.2f} | {r['seam_ms_per_step_env']:.2f} | {mark} |")
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
    ap.add_argument("--spin-us", type=int, default=None, help="sidecar busy-poll (default: simseam's own)")
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
                  f"compact={rs.get('compact')} spin_us={sorted(set(r['seam_spin_us']))}", flush=True)
            out.parent.mkdir(parents=True, exist_ok=True)
            out.write_text(json.dumps({**info, "results": results}, indent=1))
    print()
    print(table(results))
    print(f"\nJSON: {out}")


if __name__ == "__main__":
    main()
