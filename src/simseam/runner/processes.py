"""A batched port's evaluation as K processes at once on one device (``simseam eval --engine mujoco_warp
--processes K``), and the CUDA MPS server that lets their kernels run side by side (``--mps``).

Process ``i`` is ``simseam eval ... --shard i/K``: on a port a shard takes whole tasks (``runner.sharding``), each
task one batch, into its own run directory ``OUT/shards/i`` (its console in ``OUT/shards/i.log``). When every
process has ended, ``merge_runs`` combines the shards into ``OUT``: the run one process would have written (its
episodes, seeds and summary; ``merged_from`` names the shards). A process that fails, or a Ctrl-C, costs no
finished episode: what the shards hold is merged (``missing`` names the rest), and ``--resume`` continues each shard.

Why processes: a task's batch at a protocol's 50 worlds fills a sliver of a GPU, and a control step is a chain of
small kernels, so one process stepping its tasks one after another leaves the GPU mostly idle. K processes each
step their own tasks' batches. On CUDA their kernels run side by side only when the processes are clients of one
MPS server; otherwise the GPU time-slices between them and runs one process's kernels at a time (measured on an
H100: libero_spatial's 500 episodes took 110 s in 4 processes without MPS, 61 s with it; docs/benchmarks.md).
``MpsServer`` starts a control daemon of the run's own (its pipe and log folders in a temporary folder, so it
neither meets nor stops another) and quits it when the run ends; the card's settings are left as they are.
"""

from __future__ import annotations

import contextlib
import os
import shutil
import signal
import subprocess
import tempfile
from pathlib import Path
from typing import Callable, Sequence

from simseam.seam import ConfigError

MPS_CONTROL = "nvidia-cuda-mps-control"
SHARDS = "shards"


def shard_dir(out: Path, i: int) -> Path:
    return Path(out) / SHARDS / str(i)


def shard_log(out: Path, i: int) -> Path:
    return Path(out) / SHARDS / f"{i}.log"


def claims_dir(out: Path) -> Path:
    """Where the K processes claim whole tasks (``runner.claims``); kept for a resumed run."""
    return Path(out) / SHARDS / "claims"


def child_env(k: int, base: dict | None = None) -> dict:
    """The processes' environment: ``base`` (default this one's), and the cores shared among the K processes,
    each unless set: among the benchmark's native workers (``SIMSEAM_NATIVE_WORKERS``: LIBERO's reset processes)
    and among their thread pools (``OMP_NUM_THREADS``: PyTorch's and OpenMP's, sized to every core by default, so
    that K processes of a policy would run K times the cores' threads, each pool spinning between its calls, beside
    the native workers that compute resets on the CPU)."""
    env = dict(os.environ if base is None else base)
    cores = len(os.sched_getaffinity(0))
    env.setdefault("SIMSEAM_NATIVE_WORKERS", str(max(1, (cores - 1) // max(1, k))))
    env.setdefault("OMP_NUM_THREADS", str(max(1, cores // max(1, k))))
    return env


class MpsServer:
    """A CUDA MPS control daemon of one run's own: ``with MpsServer() as env:`` gives the environment whose
    processes are its clients (``CUDA_MPS_PIPE_DIRECTORY`` and ``CUDA_MPS_LOG_DIRECTORY`` in a temporary
    folder); the daemon is told to quit when the block ends, however it ends. ``control``: the daemon's
    program (default ``nvidia-cuda-mps-control`` on PATH, a ``ConfigError`` naming it when it is not there)."""

    def __init__(self, control: str | None = None, base: dict | None = None):
        self.control = control or shutil.which(MPS_CONTROL)
        if self.control is None:
            raise ConfigError(f"--mps: {MPS_CONTROL} is not on PATH (it comes with NVIDIA's driver); run without "
                              "--mps, or put the driver's bin folder on PATH")
        self.base = dict(os.environ if base is None else base)

    def __enter__(self) -> dict:
        self.dir = Path(tempfile.mkdtemp(prefix="simseam-mps-"))
        self.env = dict(self.base, CUDA_MPS_PIPE_DIRECTORY=str(self.dir / "pipe"),
                        CUDA_MPS_LOG_DIRECTORY=str(self.dir / "log"))
        for sub in ("pipe", "log"):
            (self.dir / sub).mkdir()
        started = subprocess.run([self.control, "-d"], env=self.env, capture_output=True, text=True, timeout=60)
        if started.returncode != 0:
            shutil.rmtree(self.dir, ignore_errors=True)
            why = (started.stderr or started.stdout).strip().splitlines()
            raise ConfigError(f"--mps: {self.control} -d failed (exit {started.returncode})"
                              + (f": {why[-1]}" if why else ""))
        return self.env

    def __exit__(self, *exc) -> None:
        try:
            subprocess.run([self.control], input="quit\n", text=True, env=self.env, capture_output=True, timeout=60)
        finally:
            shutil.rmtree(self.dir, ignore_errors=True)


def run_processes(argvs: Sequence[list[str]], logs: Sequence[Path], env: dict,
                  on_poll: Callable[[], None] | None = None, poll_s: float = 1.0) -> list[int]:
    """Run the commands at once, each writing its console to its log; ``on_poll()`` while they run. Returns
    their exit codes. Ctrl-C (or SIGTERM, raised as ``KeyboardInterrupt`` by the caller's guard) is passed on to
    every process still running as SIGINT, each then ends its run as an interrupted one (its finished episodes
    kept), and is raised again once all have ended. The last one's end is noticed at once (each pause waits on a
    process still running), not up to ``poll_s`` later."""
    procs = []
    try:
        for argv, log in zip(argvs, logs):
            log.parent.mkdir(parents=True, exist_ok=True)
            with open(log, "w") as f:
                procs.append(subprocess.Popen(argv, env=env, stdout=f, stderr=subprocess.STDOUT,
                                              stdin=subprocess.DEVNULL, start_new_session=True))
        while running := [p for p in procs if p.poll() is None]:
            if on_poll is not None:
                on_poll()
            with contextlib.suppress(subprocess.TimeoutExpired):
                running[0].wait(timeout=poll_s)
    except BaseException:
        _interrupt(procs)
        raise
    return [p.returncode for p in procs]


def _interrupt(procs: list) -> None:
    """SIGINT to each process still running, then wait for all (SIGKILL for one still running after 120 s)."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGINT)
    for p in procs:
        try:
            p.wait(timeout=120)
        except subprocess.TimeoutExpired:
            p.kill()
            p.wait()


def episodes_done(out: Path, k: int) -> int:
    """How many episodes the K shards have logged so far."""
    from simseam.runner.run_dir import LOG_FILE

    total = 0
    for i in range(k):
        try:
            with open(shard_dir(out, i) / LOG_FILE, "rb") as f:
                total += sum(1 for line in f if line.strip())
        except OSError:
            pass
    return total


def log_tail(path: Path, lines: int = 3) -> str:
    """The last non-empty lines of a process's log, joined (for a one-line error)."""
    try:
        text = [line for line in path.read_text(errors="replace").splitlines() if line.strip()]
    except OSError:
        return ""
    return " | ".join(text[-lines:])
