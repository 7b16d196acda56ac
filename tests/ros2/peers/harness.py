"""Helpers for tests/ros2 and benchmarks/bench_ros2.py: real peers (scripts/setup_ros_peers.sh), a private
network namespace with only loopback, and JSON-line child processes. No pytest here."""

import hashlib
import json
import os
import shutil
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

REPO = Path(__file__).resolve().parents[3]
PEERS = Path(__file__).resolve().parent
CACHE = Path(os.environ.get("SIMSEAM_CACHE", Path.home() / ".cache" / "simseam"))
MOBILE_SCENE = """\
robot: panda_mobile
layout: nav_obstacles
image_size: [32, 32]
control_hz: 50
control_mode: joint_position
"""
SETUP_HINT = "run `bash scripts/setup_ros_peers.sh` (scripts/bootstrap.sh does)"


def pinned_dir(prefix: str, pins: str) -> Path:
    """Where scripts/setup_ros_peers.sh installs a peer: keyed by the hash of its pins file."""
    digest = hashlib.sha256((REPO / "scripts" / pins).read_bytes()).hexdigest()[:12]
    return CACHE / f"{prefix}-{digest}"


class Proc:
    """A child process in the namespace speaking JSON lines (stdout read by a thread)."""

    def __init__(self, args, env, name):
        self.name = name
        self.p = subprocess.Popen([str(a) for a in args], env=env, stdin=subprocess.PIPE, stdout=subprocess.PIPE,
                                  stderr=subprocess.STDOUT, text=True, start_new_session=True)
        self.lines: list[str] = []
        self._cv = threading.Condition()
        self._pos = 0
        threading.Thread(target=self._read, daemon=True).start()

    def _read(self):
        for line in self.p.stdout:
            with self._cv:
                self.lines.append(line.rstrip("\n"))
                self._cv.notify_all()
        with self._cv:
            self._cv.notify_all()

    def wait_line(self, pred, timeout: float = 120.0) -> str:
        """The next output line satisfying ``pred`` (a hang guard, not a timing assumption)."""
        end = time.monotonic() + timeout
        with self._cv:
            while True:
                while self._pos < len(self.lines):
                    line = self.lines[self._pos]
                    self._pos += 1
                    if pred(line):
                        return line
                if self.p.poll() is not None and self._pos >= len(self.lines):
                    raise AssertionError(f"{self.name} exited ({self.p.returncode}):\n" + "\n".join(self.lines[-40:]))
                left = end - time.monotonic()
                if left <= 0:
                    raise AssertionError(f"{self.name}: no expected line in {timeout} s:\n"
                                         + "\n".join(self.lines[-40:]))
                self._cv.wait(min(left, 0.5))

    def json(self, timeout: float = 120.0) -> dict:
        return json.loads(self.wait_line(lambda s: s.startswith("{"), timeout))

    def ask(self, timeout: float = 180.0, **req) -> dict:
        self.p.stdin.write(json.dumps(req) + "\n")
        self.p.stdin.flush()
        return self.json(timeout)

    def stop(self, sig=signal.SIGINT, timeout: float = 30.0) -> int:
        if self.p.poll() is None:
            try:
                os.killpg(self.p.pid, sig)
                self.p.wait(timeout)
            except (subprocess.TimeoutExpired, ProcessLookupError):
                try:
                    os.killpg(self.p.pid, signal.SIGKILL)
                except ProcessLookupError:
                    pass
                self.p.wait()
        return self.p.returncode

    def output(self) -> str:
        with self._cv:
            return "\n".join(self.lines)


def netns_possible() -> str | None:
    if shutil.which("unshare") is None or shutil.which("nsenter") is None or shutil.which("ip") is None:
        return "unshare/nsenter/ip (util-linux, iproute2) are not installed"
    r = subprocess.run(["unshare", "-n", "true"], capture_output=True, text=True)
    if r.returncode != 0:
        return f"cannot create a network namespace here (`unshare -n`: {r.stderr.strip()}); needs root/CAP_SYS_ADMIN"
    return None


class NetNS:
    """A private network namespace with only loopback (up); ``start`` runs a process inside it."""

    def __init__(self):
        self.holder = subprocess.Popen(["unshare", "-n", "sh", "-c", "ip link set lo up && echo up && exec sleep 3600"],
                                       stdout=subprocess.PIPE, text=True, start_new_session=True)
        line = self.holder.stdout.readline().strip()
        assert line == "up", f"network namespace set-up failed: {line!r}"
        self.procs: list[Proc] = []

    def start(self, args, env=None, name="proc") -> Proc:
        p = Proc(["nsenter", f"--net=/proc/{self.holder.pid}/ns/net", "--", *map(str, args)],
                 dict(env if env is not None else os.environ), name)
        self.procs.append(p)
        return p

    def close(self):
        for p in reversed(self.procs):
            p.stop()
        os.killpg(self.holder.pid, signal.SIGKILL)
        self.holder.wait()


def peer_env(ros_python: Path) -> dict:
    """The environment of a ROS 2 peer: the Jazzy defaults (Fast DDS, no discovery-range setting)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "RMW_", "CYCLONEDDS", "FASTRTPS",
                                                                     "FASTDDS", "AMENT", "PYTHON"))}
    env["PYTHONUNBUFFERED"] = "1"
    return env


def simseam_env(**extra) -> dict:
    """simseam's environment: its defaults (no CYCLONEDDS_URI, no ROS_* settings)."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(("ROS_", "CYCLONEDDS"))}
    env.update(MUJOCO_GL=os.environ.get("MUJOCO_GL", "egl"), PYTHONUNBUFFERED="1", COLUMNS="200", **extra)
    return env


SIMSEAM = [sys.executable, "-m", "simseam.cli.main"]
