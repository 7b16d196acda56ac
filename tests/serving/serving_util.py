"""Helpers for the policy-server tests: raw websocket clients, and child processes whose output is
read with a deadline (reader threads + a queue: a stuck child fails its test with its output, it
never hangs the run)."""

from __future__ import annotations

import inspect
import os
import queue
import re
import socket
import subprocess
import sys
import threading
import time
from pathlib import Path

import pytest

from simseam.policies import openpi_wire as wire

REPO = Path(__file__).resolve().parents[2]
#: `simseam serve-policy` without the rest of the CLI (cli/main.py registers the same function)
CLI = ("import typer; from simseam.cli.serve_policy import serve_policy; "
       "app = typer.Typer(); app.command()(serve_policy); app()")
#: hang guard for child processes: far above what any of them needs, only there to turn a hang into a failure
CHILD_DEADLINE_S = 60.0


def raw_client(url, **kw):
    """A bare websockets client on ``url``; returns (connection, the server's metadata)."""
    ws = connect(url, **kw)
    return ws, wire.unpackb(ws.recv(timeout=30))


def connect(url, **kw):
    """``websockets.sync.client.connect`` with the options the tests need on every websockets version."""
    from websockets.sync.client import connect as _connect

    params = inspect.signature(_connect).parameters  # proxy: websockets >= 15, legacy: >= 17
    extra = {k: v for k, v in (("proxy", None), ("legacy", True)) if k in params}
    return _connect(url, **{"compression": None, "max_size": None, "open_timeout": 30, **extra, **kw})


def port_is_free(port):
    with socket.socket() as s:
        s.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
        try:
            s.bind(("127.0.0.1", port))
            s.listen()
        except OSError:
            return False
    return True


class Child:
    """A subprocess whose stdout and stderr are drained by reader threads from the start."""

    def __init__(self, args, **kw):
        env = {**os.environ, "PYTHONUNBUFFERED": "1", "MUJOCO_GL": os.environ.get("MUJOCO_GL", "egl"),
               **kw.pop("env", {})}
        self.args = args
        self.proc = subprocess.Popen(args, cwd=REPO, env=env, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                                     text=True, bufsize=1, **kw)
        self.stdout: list[str] = []
        self.stderr: list[str] = []
        self._lines: queue.Queue = queue.Queue()
        self._readers = [threading.Thread(target=self._drain, args=(self.proc.stdout, self.stdout, True), daemon=True),
                         threading.Thread(target=self._drain, args=(self.proc.stderr, self.stderr, False), daemon=True)]
        for t in self._readers:
            t.start()

    def _drain(self, stream, sink, to_queue):
        for line in stream:
            sink.append(line)
            if to_queue:
                self._lines.put(line)
        if to_queue:
            self._lines.put(None)  # end of stdout

    def output(self) -> str:
        code = self.proc.poll()
        return (f"exit code: {code if code is not None else 'still running'}\n--- stdout ---\n{''.join(self.stdout)}"
                f"--- stderr ---\n{''.join(self.stderr)}")

    def wait_line(self, pattern: str, timeout: float = CHILD_DEADLINE_S) -> re.Match:
        """The first stdout line (from here on) matching ``pattern``; fails with the child's output when
        none comes within ``timeout`` s or stdout ends."""
        deadline = time.monotonic() + timeout
        while True:
            left = deadline - time.monotonic()
            try:
                line = self._lines.get(timeout=max(0.0, left))
            except queue.Empty:
                self.kill()
                pytest.fail(f"no stdout line matching {pattern!r} within {timeout:g} s\n{self.output()}")
            if line is None:
                self.proc.wait(10)
                self._join_readers()
                pytest.fail(f"stdout ended without a line matching {pattern!r}\n{self.output()}")
            found = re.search(pattern, line)
            if found:
                return found

    def wait(self, timeout: float = CHILD_DEADLINE_S) -> int:
        """The exit code; a child still running after ``timeout`` s is killed and the test fails."""
        try:
            code = self.proc.wait(timeout)
        except subprocess.TimeoutExpired:
            self.kill()
            pytest.fail(f"the child did not exit within {timeout:g} s\n{self.output()}")
        self._join_readers()
        return code

    def _join_readers(self):
        for t in self._readers:
            t.join(10)

    def kill(self):
        if self.proc.poll() is None:
            self.proc.kill()
            self.proc.wait(30)
        self._join_readers()


def run_cli(*args, timeout: float = CHILD_DEADLINE_S) -> Child:
    """`serve-policy` with ``args`` run to its end (it must exit: a refusal), with its output."""
    child = Child([sys.executable, "-c", CLI, *args])
    child.wait(timeout)
    return child
