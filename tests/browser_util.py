"""Headless Chromium (Debian's ``chromium``) driven over the DevTools protocol, for tests that check what a
person would see in a page. The protocol travels over the ``websockets`` client simseam already depends on;
the browser resolves no host names and has no route out (an unreachable proxy), and every request it makes
is recorded (``requests``) so a test can assert that none left the machine."""

from __future__ import annotations

import contextlib
import json
import os
import select
import shutil
import signal
import subprocess
import tempfile
import time
from pathlib import Path

CHROMIUM = shutil.which("chromium") or shutil.which("chromium-browser")

#: what keeps the browser off the network and quiet: no name resolution, an unreachable proxy, no
#: background fetches (component updates, safe browsing, sync), autoplay allowed for the page's videos
FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--mute-audio",
         "--host-resolver-rules=MAP * ~NOTFOUND", "--proxy-server=socks5://127.0.0.1:9",
         "--disable-background-networking", "--disable-component-update", "--disable-sync",
         "--disable-default-apps", "--autoplay-policy=no-user-gesture-required", "--remote-debugging-port=0"]


def group_members(pgid: int) -> list[int]:
    """Live (not zombie) processes in the process group ``pgid``."""
    out = []
    for p in os.listdir("/proc"):
        try:
            stat = Path(f"/proc/{p}/stat").read_text() if p.isdigit() else ""
        except OSError:
            continue
        fields = stat[stat.rfind(")") + 2:].split()
        if fields and int(fields[2]) == pgid and fields[0] not in ("Z", "X"):
            out.append(int(p))
    return out


class Chromium:
    """``with Chromium() as b: b.open(url); b.evaluate(js)``; the browser and its helpers are ended on exit."""

    def __init__(self, timeout: float = 60.0):
        self.timeout = timeout
        self.requests: list[str] = []  # the URL of every request the page made
        self._id = 0
        self._events: list[str] = []

    def __enter__(self) -> "Chromium":
        from websockets.sync.client import connect

        self._profile = tempfile.mkdtemp(prefix="simseam-chromium-")
        self.proc = subprocess.Popen([CHROMIUM, *FLAGS, f"--user-data-dir={self._profile}", "about:blank"],
                                     stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, start_new_session=True)
        try:
            self._ws = connect(self._endpoint(), max_size=None, open_timeout=self.timeout)
            target = self.send("Target.createTarget", url="about:blank")["targetId"]
            self._session = self.send("Target.attachToTarget", targetId=target, flatten=True)["sessionId"]
            self.send("Network.enable", session=True)
            self.send("Page.enable", session=True)
        except BaseException:
            self._stop()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self._ws.close()
        self._stop()

    def _endpoint(self) -> str:
        """The browser's DevTools address, from the line Chromium prints once it listens (its readiness)."""
        deadline, seen = time.monotonic() + self.timeout, b""
        fd = self.proc.stderr.fileno()
        while time.monotonic() < deadline:
            ready, _, _ = select.select([fd], [], [], deadline - time.monotonic())
            chunk = os.read(fd, 65536) if ready else b""
            if not chunk:
                break
            seen += chunk
            for line in seen.decode(errors="replace").splitlines():
                if line.startswith("DevTools listening on "):
                    return line.split(" on ", 1)[1].strip()
        raise RuntimeError(f"chromium did not start its DevTools server; it printed:\n{seen.decode(errors='replace')}")

    def _stop(self) -> None:
        """End chromium and the helpers it started (its own process group), and wait until all are gone."""
        for sig in (signal.SIGTERM, signal.SIGKILL):
            with contextlib.suppress(ProcessLookupError):
                os.killpg(self.proc.pid, sig)
            with contextlib.suppress(subprocess.TimeoutExpired):
                self.proc.wait(timeout=30)
            deadline = time.monotonic() + 30
            while group_members(self.proc.pid) and time.monotonic() < deadline:
                time.sleep(0.05)
            if not group_members(self.proc.pid):
                break
        self.proc.stderr.close()
        shutil.rmtree(self._profile, ignore_errors=True)

    def send(self, method: str, session: bool = False, **params) -> dict:
        """One DevTools command; its result (events that arrive meanwhile are recorded)."""
        self._id += 1
        msg = {"id": self._id, "method": method, "params": params}
        if session:
            msg["sessionId"] = self._session
        self._ws.send(json.dumps(msg))
        while True:
            reply = self._receive()
            if reply.get("id") == self._id:
                if "error" in reply:
                    raise RuntimeError(f"{method}: {reply['error']}")
                return reply["result"]

    def _receive(self) -> dict:
        msg = json.loads(self._ws.recv(timeout=self.timeout))
        if msg.get("method") == "Network.requestWillBeSent":
            self.requests.append(msg["params"]["request"]["url"])
        if "method" in msg:
            self._events.append(msg["method"])
        return msg

    def open(self, url: str) -> None:
        """Load ``url`` and wait for its load event."""
        self._events = []
        self.send("Page.navigate", session=True, url=url)
        while "Page.loadEventFired" not in self._events:
            self._receive()

    def evaluate(self, expression: str):
        """The value of a JavaScript expression in the page (a promise is awaited)."""
        out = self.send("Runtime.evaluate", session=True, expression=expression, awaitPromise=True,
                        returnByValue=True, timeout=int(self.timeout * 1000))
        if "exceptionDetails" in out:
            raise RuntimeError(f"{expression[:80]}...: {out['exceptionDetails']}")
        return out["result"].get("value")
