"""Evaluation throughput vs the number of environments: env-steps/s, episodes/hour, main-process cost.

    .venv/bin/python benchmarks/bench_vector.py [--n 1 2 4 8 16] [--steps 300] [--episodes-per-env 2]
        [--cases state overhead rgb128 rgb256 sidecar_state] [--modes vector local bare]
        [--renderers workers batched] [--rounds 1] [--profile] [--robot-json panda.json --urdf .../panda.urdf]
        [--out benchmarks/results/vector.json]

    # the GPU machine's sweep (docs/evaluation.md; no pydantic there: --robot-json + --urdf):
    python3 bench_vector.py --n 1 2 4 8 16 --cases state overhead rgb128 rgb256 --modes vector local \
        --renderers workers batched --robot-json panda.json --urdf franka_panda/panda.urdf --out $OUT/vector.json

Franka Panda, lift_cube, 20 Hz control, ``--steps`` control steps per episode (the episode never
succeeds: a trivial zero-action policy), ``episodes-per-env x N`` episodes per point. Cases:

- ``state``: in-process MuJoCo, state-only observations (no rendering);
- ``rgb128`` / ``rgb256``: in-process MuJoCo, both cameras (camera1 + wrist camera2) at 128x128 /
  256x256 in every observation (the policy reads them every step), drawn by each worker (``--renderers
  workers``: its own EGL context) or by the parent in one MuJoCo Warp batch for all workers
  (``batched``: the workers send their render states; ``VectorEnv(renderer="batched")``);
- ``sidecar_state``: the same scene behind the sidecar (each worker owns its own sidecar process),
  state-only (needs pydantic, msgpack, pyzmq);
- ``overhead``: no physics: each worker's rollout answers at once with a state-only observation of
  lift_cube's layout (the same keys, shapes, info and diagnostics), so the wall time per env-step is
  the vector runner's own cost (pipes, wake-ups, the parent's per-env work), not a simulator's.

Modes: ``vector`` is ``simseam.runner.vector.VectorEnv.run`` (lockstep: N worker processes stepped
together by one batched policy in this process; each side busy-polls its pipe when every process has
a core beyond the load, ``vector_spin_us``). Its variants are named ``vector[0][_xK][_gG|_readyM][_spin[US]]``
(``mode_rule``): ``0`` the busy-poll off (``SIMSEAM_VECTOR_SPIN_US=0``); ``_xK`` K environments on each
of the N worker processes (``VectorEnv(envs_per_worker=K)``: K x N environments; a worker steps one
while the policy's action for another is on its way); ``_gG`` pipelined lockstep with G policy groups
(``run(groups=G)``: the policy acts for one group while the others step); ``_readyM`` the ready rule
(``run(ready=M)``: the policy acts for the environments whose steps are in once M of them are);
``_spin`` the busy-poll forced on (``DEFAULT_VECTOR_SPIN_US``, or US microseconds). G and M are capped
at the environments. E.g. ``vector_g4_spin``, ``vector_x2_ready8`` (32 environments on 16 workers at
N = 16, the policy acting once 8 steps are in). ``vector_default`` is the rule a run that names none gets on
this machine (``runner.scheduler.default_lockstep``: ``vector_x2_ready4`` at N = 16 on 16 cores). ``local`` is
``runner.whole_episodes.run_local`` (the built-in ``zero``
policy inside each worker, whole episodes per command; state-only cases only); ``bare`` is N plain
independent processes, each running its share of the episodes with ``run_episodes`` (the baseline the
vector API must not fall behind). Timing starts once every worker has built its rollout (and the
batched renderer has compiled its kernels) and stops when the last episode ends. Efficiency =
throughput(N) / (N x throughput(first N)) of the same case, mode and renderer; ``vs bare`` =
throughput(N) / throughput of ``bare`` at the same N (with ``--modes ... bare``). Every mode of a case
runs at one N back to back, ``--rounds`` times, before the next N (a drift in the machine's speed hits
them alike); the median round is reported. ``main_us`` is this
process's own CPU time (user + system) per env-step in the vector modes: what bounds lockstep
efficiency at large N. ``step us`` is one rollout step as timed inside the process that runs it (a
lockstep worker or a bare process; ``StepTimer``): its mean wall and CPU time, so a lockstep loss
splits into steps that got slower (cold caches, a shared core) and time between the steps. ``run-queue wait``
(``sched`` in the JSON, Linux's ``/proc/PID/schedstat``): how long the parent and the workers sat runnable but
not running during the timed run, per env-step, with their involuntary context switches: a lockstep parent
that waits for a core holds up every environment, and this is where that shows. Prints a table and writes JSON.

Scenes are built without pydantic (``BenchRecipe``: a RobotSpec, the task, SceneOptions), so the GPU
machine needs only numpy, mujoco (+ PyOpenGL for EGL), and warp-lang + mujoco-warp for ``batched``.
"""

from __future__ import annotations

import argparse
import contextlib
import dataclasses
import json
import multiprocessing as mp
import os
import platform
import re
import resource
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import numpy as np  # noqa: E402

from cpu_facts import CpuWindow, topology  # noqa: E402
from simseam.policies.batch import PolicyBatch  # noqa: E402
from simseam.runner import whole_episodes  # noqa: E402
from simseam.runner.vector import VectorEnv  # noqa: E402

# case -> (image size or None, behind a sidecar)
CASES = {
    "state": (None, False),
    "rgb128": (128, False),
    "rgb256": (256, False),
    "sidecar_state": (None, True),
    "overhead": (None, False),
}

# the robot: a built-in name or a manifest path, or a RobotSpec JSON (machines without pydantic) with
# its URDF; spawned workers read them from the environment
ROBOT = os.environ.get("SIMSEAM_BENCH_ROBOT", "franka_panda")
ROBOT_JSON = os.environ.get("SIMSEAM_BENCH_ROBOT_JSON") or None
URDF = os.environ.get("SIMSEAM_BENCH_URDF") or None


def robot_spec():
    from simseam.robot.spec import RobotSpec

    if ROBOT_JSON:
        spec = RobotSpec.from_json(json.loads(Path(ROBOT_JSON).read_text()))
    else:
        from simseam.robot.manifest import load_robot

        spec = load_robot(ROBOT)
    if URDF:
        spec = dataclasses.replace(spec, urdf="file:" + str(Path(URDF).resolve()))
    return spec


@dataclasses.dataclass(frozen=True)
class BenchRecipe:
    """A worker's rollout without the scene-file layer (no pydantic): the vector runner only calls
    ``build()`` and ``rollout_for()`` and reads ``scene`` (the central renderer's support check),
    ``render_images`` and ``pose_states``."""

    image: int | None
    steps: int
    render_images: bool = False
    pose_states: bool = False
    privileged: bool = False
    seed: int = 0
    scene: dict = dataclasses.field(default_factory=lambda: {"engine": {"name": "mujoco"}})

    def build(self):
        from simseam.scene.manifest_scene import ManifestScene, SceneOptions

        size = (self.image, self.image) if self.image else None
        opts = SceneOptions(control_hz=20, image_size=size, max_steps=self.steps, render_images=self.render_images,
                            privileged=self.privileged, seed=self.seed)
        return timed(ManifestScene(robot_spec(), "lift_cube", "mujoco", opts))

    def rollout_for(self, rollout, index: int, seed: int):
        """Every episode on the worker's one scene (as ``SceneRecipe``): what the runner asks a recipe."""
        return rollout, seed


STEP_TIMES_ENV = "SIMSEAM_BENCH_STEP_TIMES"


class StepTimer:
    """A rollout whose steps are timed where they run (wall, and this thread's CPU): what one physics step
    costs inside a lockstep worker against inside a bare process. Each process writes its times to
    ``$SIMSEAM_BENCH_STEP_TIMES/<pid>.json`` at every reset and at close."""

    def __init__(self, rollout, out_dir: str):
        self._rollout, self._out = rollout, Path(out_dir) / f"{os.getpid()}.json"
        self._wall: list[float] = []
        self._cpu: list[float] = []

    def __getattr__(self, name):
        return getattr(self._rollout, name)

    def step(self, action, observe=None):
        t, c = time.perf_counter(), time.thread_time()
        r = self._rollout.step(action, observe)
        self._cpu.append(time.thread_time() - c)
        self._wall.append(time.perf_counter() - t)
        return r

    def reset(self, seed, observe=None):
        self._write()
        return self._rollout.reset(seed, observe)

    def close(self):
        self._write()
        self._rollout.close()

    def _write(self):
        if self._wall:
            self._out.write_text(json.dumps({"wall": self._wall, "cpu": self._cpu}))


def timed(rollout):
    out = os.environ.get(STEP_TIMES_ENV)
    return StepTimer(rollout, out) if out else rollout


def step_times(out_dir: str) -> dict:
    """Every process's step times in ``out_dir``: the mean wall and CPU microseconds per step over all of them."""
    wall, cpu = [], []
    for f in Path(out_dir).glob("*.json"):
        d = json.loads(f.read_text())
        wall += d["wall"]
        cpu += d["cpu"]
    if not wall:
        return {}
    return {"step_wall_us": float(np.mean(wall)) * 1e6, "step_cpu_us": float(np.mean(cpu)) * 1e6}


@contextlib.contextmanager
def _step_times_dir():
    """``$SIMSEAM_BENCH_STEP_TIMES`` set to a fresh directory for the processes started inside (spawned
    workers read it when they build their rollouts); the dict it yields gets their ``step_times``."""
    times: dict = {}
    saved = os.environ.get(STEP_TIMES_ENV)
    with tempfile.TemporaryDirectory(prefix="bench-steps-") as out:
        os.environ[STEP_TIMES_ENV] = out
        try:
            yield times
        finally:
            if saved is None:
                os.environ.pop(STEP_TIMES_ENV, None)
            else:
                os.environ[STEP_TIMES_ENV] = saved
            times.update(step_times(out))


class InstantRollout:
    """``overhead`` case: lift_cube's spec and observation layout, no physics (answers at once)."""

    def __init__(self, spec):
        self.spec, self.k = spec, 0
        self.state = np.zeros(spec.observation.state_dim, np.float32)
        self.q = np.zeros(len(spec.robot.joints), np.float32)

    def _obs(self):
        return {"images": {}, "state": self.state.copy(), "task": self.spec.task.instruction,
                "joint_positions": self.q.copy(), "joint_velocities": self.q.copy(), "sim_time_ns": self.k * 50_000_000}

    def reset(self, seed, observe=None):
        self.k = 0
        return self._obs()

    def step(self, action, observe=None):
        from simseam.seam import StepResult

        self.k += 1
        info = {self.spec.task.success_key: False, "steps": self.k,
                "diagnostics": {"cube_height": 0.0, "eef_to_cube": 0.3, "grasped": False}}
        return StepResult(self._obs(), 0.0, False, self.k >= self.spec.task.max_steps, info)

    def render(self):
        return None

    def close(self):
        pass


@dataclasses.dataclass(frozen=True)
class InstantRecipe(BenchRecipe):
    def build(self):
        scene = BenchRecipe(None, self.steps).build()
        spec = scene.spec
        scene.close()
        return timed(InstantRollout(spec))


def recipe_for(case: str, steps: int):
    if case == "overhead":
        return InstantRecipe(None, steps)
    image, sidecar = CASES[case]
    if not sidecar:
        return BenchRecipe(image, steps, render_images=image is not None)
    from simseam.runner.scene_config import SceneConfig
    from simseam.runner.recipe import SceneRecipe

    cfg = SceneConfig.model_validate({"robot": ROBOT, "task": "lift_cube", "engine": {"name": "mujoco", "process": "sidecar"},
                                      "max_steps": steps, "control_hz": 20})
    return SceneRecipe(cfg.model_dump(mode="json"), str(Path.cwd()), render_images=False)


class ZeroBatch(PolicyBatch):
    """Zero Cartesian deltas for every environment; reads images every step when ``images``."""

    def __init__(self, n: int, images: bool):
        from simseam.seam import STATE_ONLY

        self.n, self.uses_images = n, images
        self.request = None if images else STATE_ONLY
        self.seen = 0

    def reset(self, env, spec):
        self.dim = spec.action_dim

    def observe_next(self, env):
        return self.request

    def act_batch(self, envs, observations):
        if self.uses_images:  # the images are there, every camera, every step
            self.seen += sum(len(o["images"]) for o in observations)
        return np.zeros((len(envs), self.dim), np.float32)


class ZeroPolicy:
    requires_privileged = False

    def __init__(self, images: bool):
        self.uses_images = images

    def reset(self, spec):
        self.dim = spec.action_dim

    def observe_next(self):
        from simseam.seam import STATE_ONLY

        return None if self.uses_images else STATE_ONLY

    def act(self, obs):
        return np.zeros(self.dim, np.float32)


# a lockstep mode's name: vector[0][_xK][_gG | _readyM][_spin[US]]. vector0: the busy-poll off; _xK: K
# environments on each of the N worker processes (VectorEnv(envs_per_worker=K)); _gG: G policy groups
# (run(groups=G)); _readyM: the ready rule (run(ready=M)); _spin: the busy-poll forced on (2000 us, or US).
# Without _spin or 0 the default busy-poll rule holds (vector_spin_us). G and M are capped at the environments.
MODE_RE = re.compile(r"vector(?P<off>0)?(?:_x(?P<k>[1-9]\d*))?(?:_g(?P<g>[1-9]\d*)|_ready(?P<m>[1-9]\d*))?"
                     r"(?:_spin(?P<us>\d+)?(?P<on>))?")


def mode_rule(mode: str, n: int = 1, episodes: int = 1) -> dict | None:
    """A lockstep mode's keyword arguments for run_vector at ``n`` workers and ``episodes``, or None when ``mode``
    is not one. ``vector_default``: the rule a run naming none gets on this machine (``default_lockstep``; its
    environments are K x n here, as every _xK mode's, so give --episodes-per-env 2 or more to match a run's)."""
    if mode == "vector_default":
        from simseam.runner.scheduler import default_lockstep
        from simseam.runner.vector import usable_cores

        rule, _ = default_lockstep(n, episodes, usable_cores())
        return {"spin_us": None, "groups": 1, "ready": rule.ready, "envs_per_worker": rule.envs_per_worker}
    hit = MODE_RE.fullmatch(mode)
    if hit is None:
        return None
    spin = 0 if hit["off"] else int(hit["us"] or 2000) if hit["on"] is not None else None
    return {"spin_us": spin, "groups": int(hit["g"] or 1), "ready": int(hit["m"]) if hit["m"] else None,
            "envs_per_worker": int(hit["k"] or 1)}


def check_mode(mode: str) -> str:
    if mode in ("local", "bare") or mode_rule(mode) is not None:
        return mode
    raise argparse.ArgumentTypeError(f"{mode!r}: expected local, bare, vector_default or "
                                     "vector[0][_xK][_gG|_readyM][_spin[US]]")


def _cpu() -> float:
    r = resource.getrusage(resource.RUSAGE_SELF)
    return r.ru_utime + r.ru_stime


def sched_facts(pid: int | str = "self") -> tuple[int, int, int] | None:
    """(run-queue wait ns, CPU ns, involuntary context switches) of a process so far (Linux ``/proc``:
    ``schedstat``, ``status``); None where the kernel does not keep them or the process is gone."""
    try:
        cpu_ns, wait_ns, _ = (int(x) for x in Path(f"/proc/{pid}/schedstat").read_text().split())
        status = Path(f"/proc/{pid}/status").read_text()
    except (OSError, ValueError):
        return None
    forced = next((int(line.split()[1]) for line in status.splitlines() if line.startswith("nonvoluntary_ctxt")), 0)
    return wait_ns, cpu_ns, forced


def sched_delta(before: dict, after: dict, env_steps: int) -> dict:
    """How long the parent and the workers sat runnable but not running during the timed run, per env-step:
    where lockstep's parent waits for a core (every environment then waits), this is where it shows."""
    def per(key: str) -> dict | None:
        pairs = [(before[p], after[p]) for p in before if p in after and before[p] and after[p]
                 and (p == "self") == (key == "parent")]
        if not pairs:
            return None
        wait = [(a[0] - b[0]) / env_steps / 1e3 for b, a in pairs]
        return {"runqueue_wait_us_per_env_step": sum(wait), "worst_process_us_per_env_step": max(wait),
                "involuntary_switches": sum(a[2] - b[2] for b, a in pairs)}

    return {"parent": per("parent"), "workers": per("workers")}


def _waits(sched: dict | None) -> str:
    if not sched:
        return ""
    part = lambda side: "-" if not sched.get(side) else f"{sched[side]['runqueue_wait_us_per_env_step']:.1f}"
    return f"{part('parent')} / {part('workers')}"


def run_vector(case: str, n: int, steps: int, episodes: int, renderer: str = "workers",
               spin_us: int | None = None, groups: int = 1, ready: int | None = None, envs_per_worker: int = 1) -> dict:
    with _step_times_dir() as times:  # the workers time their steps (StepTimer)
        r = _run_vector(case, n, steps, episodes, renderer, spin_us, groups, ready, envs_per_worker)
    return {**r, **times}


def _run_vector(case: str, n: int, steps: int, episodes: int, renderer: str, spin_us: int | None,
                groups: int, ready: int | None = None, envs_per_worker: int = 1) -> dict:
    """N worker processes (``envs_per_worker`` K > 1: K x N environments, K on each) run ``episodes``."""
    images = CASES[case][0] is not None
    procs, n = n, n * envs_per_worker  # from here on n counts environments
    per_worker = {"envs_per_worker": envs_per_worker} if envs_per_worker > 1 else {}  # (sources before it)
    saved = os.environ.get("SIMSEAM_VECTOR_SPIN_US")
    if spin_us is not None:
        os.environ["SIMSEAM_VECTOR_SPIN_US"] = str(spin_us)
    try:
        vec = VectorEnv(recipe_for(case, steps), n, **per_worker,
                        **({"renderer": renderer} if renderer != "workers" else {}))
    finally:
        if saved is None:
            os.environ.pop("SIMSEAM_VECTOR_SPIN_US", None)
        else:
            os.environ["SIMSEAM_VECTOR_SPIN_US"] = saved
    with vec:
        spin = vec.spin_us
        vec._wait_booted(vec.slots)  # every worker ready before the clock starts
        if getattr(vec, "central", None) is not None:  # compile the renderer's kernels before the clock starts
            state = vec.central.scene.engine.render_state()
            vec.central.render([state] * n)
        pol = ZeroBatch(n, images)
        pids = ["self", *dict.fromkeys(vec.pids())]
        sched0 = {p: sched_facts(p) for p in pids}
        t0, c0 = time.perf_counter(), _cpu()
        # groups / ready passed only when used: the plain modes also run on sources before run(groups=)
        rule = {"groups": min(groups, n)} if groups > 1 else {"ready": min(ready, n)} if ready else {}
        results = vec.run(pol, range(episodes), **rule)
        wall, cpu = time.perf_counter() - t0, _cpu() - c0
        sched1 = {p: sched_facts(p) for p in pids}
    steps_done = sum(r.steps for r in results)
    if images:
        assert pol.seen >= 2 * steps_done, "the policy did not get both cameras every step"
    return {"wall_s": wall, "env_steps": steps_done, "episodes": len(results),
            "main_cpu_us_per_env_step": cpu / steps_done * 1e6, "spin_us": spin, "groups": min(groups, n),
            "ready": min(ready, n) if ready else None, "processes": procs, "envs_per_worker": envs_per_worker,
            "sched": sched_delta(sched0, sched1, steps_done)}


def profile_vector(case: str, n: int, steps: int, episodes: int, top: int = 15, **kw) -> list[dict]:
    """One more run of a vector mode under cProfile, not in the timed rounds: this process's ``top``
    functions by their own wall time (a blocking poll counts its wait), in microseconds per env-step.
    cProfile slows the Python calls, not the system calls: compare shares, not sums."""
    import cProfile
    import pstats

    prof = cProfile.Profile()
    prof.enable()
    r = run_vector(case, n, steps, episodes, **kw)
    prof.disable()
    stats = pstats.Stats(prof).stats  # (file, line, name) -> (calls, primitive calls, own s, cumulative s, callers)
    rows = sorted(stats.items(), key=lambda kv: kv[1][2], reverse=True)[:top]
    return [{"function": f"{Path(f).name}:{line}({name})", "calls_per_env_step": v[0] / r["env_steps"],
             "own_us_per_env_step": v[2] / r["env_steps"] * 1e6} for (f, line, name), v in rows]


def run_local(case: str, n: int, steps: int, episodes: int) -> dict:
    """The policy inside each worker (``runner.whole_episodes.run_local``): the built-in ``zero`` policy, state only."""
    with VectorEnv(recipe_for(case, steps), n) as vec:
        vec._wait_booted(vec.slots)
        t0 = time.perf_counter()
        results = whole_episodes.run_local(vec, "zero", {}, range(episodes))
        wall = time.perf_counter() - t0
    return {"wall_s": wall, "env_steps": sum(r.steps for r in results), "episodes": len(results)}


def _bare_worker(case, steps, indices, ready, go, out):
    from simseam.runner.session import run_episodes

    images = CASES[case][0] is not None
    rollout = recipe_for(case, steps).build()
    try:
        ready.put(os.getpid())
        go.wait()
        before = sched_facts()
        res = run_episodes(rollout, ZeroPolicy(images), indices)
        out.put((sum(r.steps for r in res), before, sched_facts()))
    finally:
        rollout.close()


def run_bare(case: str, n: int, steps: int, episodes: int) -> dict:
    ctx = mp.get_context("spawn")
    ready, out, go = ctx.Queue(), ctx.Queue(), ctx.Event()
    procs = [ctx.Process(target=_bare_worker, args=(case, steps, list(range(k, episodes, n)), ready, go, out))
             for k in range(n)]
    with _step_times_dir() as times:
        wall, counts = _bare_run(procs, ready, go, out)
    total = sum(c[0] for c in counts)
    sched = sched_delta({k: c[1] for k, c in enumerate(counts)}, {k: c[2] for k, c in enumerate(counts)}, total)
    return {"wall_s": wall, "env_steps": total, "episodes": episodes, "sched": sched, **times}


def _bare_run(procs, ready, go, out) -> tuple[float, list]:
    for p in procs:
        p.start()
    try:
        for _ in procs:
            ready.get(timeout=600)
        t0 = time.perf_counter()
        go.set()
        counts = [out.get(timeout=3600) for _ in procs]  # (env-steps, sched_facts before, after) per process
        wall = time.perf_counter() - t0
    finally:
        for p in procs:
            p.join(30)
            if p.is_alive():
                p.kill()
    return wall, counts


def machine_facts() -> dict:
    """Where a benchmark ran: the CPU topology (``cpu_facts.topology``: model, usable CPUs, physical cores,
    SMT siblings, hypervisor, governor), the GL backend, the load, the GPU (if any)."""
    import subprocess

    machine = {"cpus": os.cpu_count(), "affinity": len(os.sched_getaffinity(0)), **topology(),
               "mujoco_gl": os.environ.get("MUJOCO_GL"), "load": os.getloadavg()}
    try:
        gpu = subprocess.run(["nvidia-smi", "--query-gpu=name", "--format=csv,noheader"], capture_output=True,
                             text=True, timeout=10)
        machine["gpu"] = gpu.stdout.strip() or None
    except (OSError, subprocess.SubprocessError):
        machine["gpu"] = None
    return machine


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n")[0])
    ap.add_argument("--n", type=int, nargs="+", default=[1, 2])
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--episodes-per-env", type=int, default=2)
    ap.add_argument("--rounds", type=int, default=1, help="repeat each point; the median round is reported")
    ap.add_argument("--cases", nargs="+", default=["state", "rgb128"], choices=list(CASES))
    ap.add_argument("--modes", nargs="+", default=["vector", "local"], type=check_mode)
    ap.add_argument("--renderers", nargs="+", default=["workers"], choices=["workers", "batched"],
                    help="camera cases in the vector modes: who draws the cameras")
    ap.add_argument("--profile", action="store_true",
                    help="after the rounds at the largest N, one more run of each vector mode under cProfile: "
                         "this process's functions by own time per env-step (printed, and in the JSON)")
    ap.add_argument("--out", type=Path, default=Path("benchmarks/results/vector.json"))
    ap.add_argument("--robot", default=ROBOT, help="built-in robot name or manifest path (absolute)")
    ap.add_argument("--robot-json", default=None, help="a RobotSpec as JSON (machines without pydantic)")
    ap.add_argument("--urdf", default=None, help="override the robot's URDF path")
    args = ap.parse_args()
    globals()["ROBOT"] = os.environ["SIMSEAM_BENCH_ROBOT"] = args.robot
    for name, value in (("ROBOT_JSON", args.robot_json), ("URDF", args.urdf)):
        if value:
            value = str(Path(value).resolve())
            globals()[name] = os.environ[f"SIMSEAM_BENCH_{name}"] = value
    # every (mode, renderer) of a case at one N runs back to back, round after round, so a drift in
    # this machine's speed (a shared VM, turbo with few cores busy) hits every mode alike
    points = []
    for case in args.cases:
        images = CASES[case][0] is not None
        for mode in args.modes:
            if mode == "local" and images:
                continue  # the built-in zero policy reads no images
            for renderer in (args.renderers if images and mode_rule(mode) is not None else ["workers"]):
                points.append((case, mode, renderer))
    measured: dict[tuple, list] = {}
    profiles: dict[tuple, list] = {}
    for case in args.cases:
        for n in args.n:
            episodes = args.episodes_per_env * n
            for _ in range(args.rounds):
                for (c, mode, renderer) in points:
                    if c != case:
                        continue
                    with CpuWindow() as window:
                        if mode == "bare":
                            r = run_bare(case, n, args.steps, episodes)
                        elif mode == "local":
                            r = run_local(case, n, args.steps, episodes)
                        else:
                            r = run_vector(case, n, args.steps, episodes, renderer=renderer,
                                           **mode_rule(mode, n, episodes))
                    r["cpu"] = window.facts()
                    measured.setdefault((case, mode, renderer, n), []).append(r)
                    c = r["cpu"]
                    print(f"  {case} {mode} {renderer} N={n}: {r['env_steps'] / r['wall_s']:.0f} env-steps/s  "
                          f"(cpus busy {c['busy_share']:.2f}, stolen {c['steal_share']:.3f}, others "
                          f"{c['others_cpu_share']:.2f}, {c['mhz_end']} MHz, parent on {c['parent_cpus']})",
                          file=sys.stderr, flush=True)
            if args.profile and n == max(args.n):
                for (c, mode, renderer) in points:
                    if c == case and mode_rule(mode) is not None:
                        profiles[(case, mode, renderer)] = prof = profile_vector(
                            case, n, args.steps, episodes, renderer=renderer, **mode_rule(mode, n, episodes))
                        print(f"\nprofile: {case} {mode} {renderer} N={n} (us per env-step, own time)")
                        for p in prof:
                            print(f"  {p['own_us_per_env_step']:7.2f}  {p['calls_per_env_step']:5.2f} calls  {p['function']}")
    rows = []
    for (case, mode, renderer) in points:
        base = None
        for n in args.n:
            rounds = measured[(case, mode, renderer, n)]
            r = dict(sorted(rounds, key=lambda x: x["env_steps"] / x["wall_s"])[len(rounds) // 2])  # the median
            r["rounds_env_steps_per_s"] = [x["env_steps"] / x["wall_s"] for x in rounds]
            if "main_cpu_us_per_env_step" in r:
                r["rounds_main_cpu_us_per_env_step"] = [x["main_cpu_us_per_env_step"] for x in rounds]
            sps = r["env_steps"] / r["wall_s"]
            base = sps if base is None else base
            eff = sps / (n / args.n[0] * base)
            row = {"case": case, "mode": mode, "renderer": renderer, "n": n, **r, "env_steps_per_s": sps,
                   "episodes_per_hour": r["episodes"] / r["wall_s"] * 3600, "efficiency": eff}
            if n == max(args.n) and (case, mode, renderer) in profiles:
                row["profile"] = profiles[(case, mode, renderer)]
            bare = measured.get((case, "bare", "workers", n))
            if bare and mode != "bare":  # this mode's throughput over N bare processes' at the same N
                bare_sps = sorted(x["env_steps"] / x["wall_s"] for x in bare)[len(bare) // 2]
                row["vs_bare"] = sps / bare_sps
            rows.append(row)
            main_us = r.get("main_cpu_us_per_env_step")
            print(f"{case:14s} {mode:11s} {renderer:8s} N={n:3d}  {sps:9.1f} env-steps/s  "
                  f"{row['episodes_per_hour']:9.0f} episodes/h  efficiency {eff:.2f}"
                  + (f"  vs bare {row['vs_bare']:.2f}" if "vs_bare" in row else "")
                  + (f"  main {main_us:6.1f} us/env-step" if main_us is not None else "")
                  + (f"  step {r['step_cpu_us']:6.1f} us cpu" if "step_cpu_us" in r else ""), flush=True)
    print()
    print(f"| case | mode | renderer | N | env-steps/s | episodes/h ({args.steps} steps) | efficiency | vs bare | "
          "main us/env-step | step us (wall / cpu) | run-queue wait us/env-step (parent / workers) |")
    print("|---|---|---|---:|---:|---:|---:|---:|---:|---:|---:|")
    for r in rows:
        main_us = r.get("main_cpu_us_per_env_step")
        vs = r.get("vs_bare")
        step = f"{r['step_wall_us']:.0f} / {r['step_cpu_us']:.0f}" if "step_cpu_us" in r else ""
        print(f"| {r['case']} | {r['mode']} | {r['renderer']} | {r['n']} | {r['env_steps_per_s']:.0f} | "
              f"{r['episodes_per_hour']:.0f} | {r['efficiency']:.2f} | {'' if vs is None else f'{vs:.2f}'} | "
              f"{'' if main_us is None else f'{main_us:.1f}'} | {step} | {_waits(r.get('sched'))} |")
    machine = machine_facts()
    args.out.parent.mkdir(parents=True, exist_ok=True)
    args.out.write_text(json.dumps({"machine": machine, "steps_per_episode": args.steps,
                                    "episodes_per_env": args.episodes_per_env, "rows": rows}, indent=2))
    print(f"\nwrote {args.out}", file=sys.stderr)


if __name__ == "__main__":
    main()
