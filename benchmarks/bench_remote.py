"""What a remote policy costs per step: the openpi websocket round trip over localhost.

    .venv/bin/python benchmarks/bench_remote.py [--steps 300] [--rounds 5] [--json PATH]

Server: ``serve-policy --policy zero`` in a subprocess (the real CLI command and
``PolicyServer``; the zero policy answers in microseconds, so what is timed is the protocol).
Observations: real ones from a Franka lift_cube scene, taken once: ``state`` (state-only: state,
joint positions / velocities, sim time; ~0.1 kB of arrays) and ``rgb2x256`` (plus camera1 and the
wrist camera2 at 256x256: 2 x 192 kB). Cases, per observation:

- ``remote``: ``RemotePolicy.act(obs)`` (simseam format, one request per step since the zero
  policy is per-step): flatten + encode, send, server decode + rebuild + policy + encode, reply,
  decode + validation. This is the per-step round trip a ``remote:`` policy adds.
- ``openpi_client``: openpi-client's ``WebsocketClientPolicy.infer`` with the same request
  (the reference client; skipped when openpi-client is not installed).
- ``codec``: the msgpack-numpy part alone, in process: encode + decode of the request and of
  the reply.
- ``inproc``: ``ZeroPolicy.act(obs)`` in this process (the baseline a remote policy replaces).

Per round, each case runs ``--steps`` calls (rgb: ``steps // 3``) after 20 warm-up calls, the
cases in rotating order; reported: the median over rounds of each case's p50 and p90 (ms), and
the server's own ``infer_ms`` (p50). Nothing is asserted. Writes JSON to
``benchmarks/results/remote.json`` (``--json`` to change); the server process is stopped
(SIGINT, exit code checked) at the end.
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import re
import signal
import subprocess
import sys
import time
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import msgpack  # noqa: E402
import numpy as np  # noqa: E402
import websockets  # noqa: E402

from simseam.policies import openpi_wire as wire  # noqa: E402
from simseam.policies.remote import RemotePolicy  # noqa: E402
from simseam.policies.simple import ZeroPolicy  # noqa: E402
from simseam.robot.manifest import load_robot  # noqa: E402
from simseam.scene.manifest_scene import ManifestScene, SceneOptions  # noqa: E402

HERE = Path(__file__).resolve().parent
WARMUP = 20
SERVE = ("import typer; from simseam.cli.serve_policy import serve_policy; "
         "app = typer.Typer(); app.command()(serve_policy); app()")


def start_server() -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([sys.executable, "-u", "-c", SERVE, "--policy", "zero", "--port", "0"],
                            cwd=HERE.parent, stdout=subprocess.PIPE, stderr=subprocess.DEVNULL, text=True)
    line = proc.stdout.readline()
    found = re.search(r"ws://127\.0\.0\.1:\d+", line)
    if not found:
        proc.kill()
        raise SystemExit(f"serve-policy did not print its URL: {line!r}")
    return proc, found.group(0)


def observations() -> dict[str, tuple]:
    """Observation name -> (scene, observation), one real observation each."""
    spec = load_robot("franka_panda")
    out = {}
    for name, images in (("state", False), ("rgb2x256", True)):
        scene = ManifestScene(spec, "lift_cube", "mujoco", SceneOptions(render_images=images, image_size=(256, 256)))
        scene.reset(0)
        out[name] = (scene, scene.step(np.zeros(scene.action_dim, np.float32)).observation)
    return out


def stats(ms: list[float]) -> dict:
    a = np.asarray(ms)
    return {"p50_ms": float(np.percentile(a, 50)), "p90_ms": float(np.percentile(a, 90)), "n": int(a.size)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=300, help="timed calls per case and round (rgb: steps // 3)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--json", default=str(HERE / "results" / "remote.json"))
    args = ap.parse_args()
    t_start = time.perf_counter()

    try:
        from openpi_client.websocket_client_policy import WebsocketClientPolicy
    except ImportError:
        WebsocketClientPolicy = None
        print("openpi-client not installed: the openpi_client case is skipped")

    proc, url = start_server()
    entries: dict[str, dict] = {}
    server_infer: dict[str, list[float]] = {}
    scenes = []
    try:
        for name, (scene, obs) in observations().items():
            scenes.append(scene)
            with RemotePolicy(url) as probe:  # the request RemotePolicy sends mid-episode
                probe.reset(scene.spec)
                probe.act(obs)
                request = probe._payload(obs)
            entries[name] = {"scene": scene, "obs": obs, "request": request,
                             "reply": {"actions": np.zeros((1, scene.action_dim), np.float32),
                                       "server_timing": {"infer_ms": 0.1, "prev_total_ms": 0.2}}}
            server_infer[name] = []

        results: dict[str, dict] = {}
        for name, entry in entries.items():
            n = args.steps if name == "state" else max(30, args.steps // 3)
            per_round: dict[str, list[dict]] = {}
            for r in range(args.rounds):
                order = ["remote", "openpi_client", "codec", "inproc"]
                order = order[r % 4:] + order[:r % 4]
                for case in order:
                    fn, cleanup = make_case(case, entry, url, name, server_infer, WebsocketClientPolicy)
                    if fn is None:
                        continue
                    try:
                        for _ in range(WARMUP):
                            fn()
                        ms = []
                        for _ in range(n):
                            t0 = time.perf_counter()
                            fn()
                            ms.append((time.perf_counter() - t0) * 1e3)
                    finally:
                        cleanup()
                    per_round.setdefault(case, []).append(stats(ms))
            results[name] = {case: {"p50_ms": float(np.median([x["p50_ms"] for x in rs])),
                                    "p90_ms": float(np.median([x["p90_ms"] for x in rs])), "rounds": rs}
                             for case, rs in per_round.items()}
            results[name]["server_infer_p50_ms"] = float(np.median(server_infer[name])) if server_infer[name] else None
            results[name]["request_bytes"] = len(wire.packb(entry["request"]))
            print(f"{name}: done ({time.perf_counter() - t_start:.0f} s)")
    finally:
        for scene in scenes:
            scene.close()
        proc.send_signal(signal.SIGINT)
        try:
            server_rc = proc.wait(10)
        except subprocess.TimeoutExpired:
            proc.kill()
            server_rc = proc.wait()

    print(f"\n{'observation':12s} {'case':14s} {'p50 ms':>8s} {'p90 ms':>8s}")
    for name, res in results.items():
        for case in ("remote", "openpi_client", "codec", "inproc"):
            if case in res:
                print(f"{name:12s} {case:14s} {res[case]['p50_ms']:8.3f} {res[case]['p90_ms']:8.3f}")
        print(f"{name:12s} {'(server infer)':14s} {res['server_infer_p50_ms'] or float('nan'):8.3f}"
              f"          request {res['request_bytes'] / 1e3:.1f} kB")
    print(f"server exit code on SIGINT: {server_rc}")

    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "machine": {"python": platform.python_version(), "platform": platform.platform(), "cpus": os.cpu_count(),
                    "websockets": websockets.__version__, "msgpack": ".".join(map(str, msgpack.version)),
                    "numpy": np.__version__},
        "steps": args.steps, "rounds": args.rounds, "warmup": WARMUP, "server": "serve-policy --policy zero",
        "results": results, "server_exit_code": server_rc, "wall_s": time.perf_counter() - t_start,
    }, indent=2))
    print(f"wrote {out} (total {time.perf_counter() - t_start:.0f} s)")


def make_case(case, entry, url, name, server_infer, client_cls):
    """(call, cleanup) for one case and observation, or (None, None) when it cannot run. Clients
    connect for one block and close after it (the server takes one client at a time); the
    episode-start request of each connection is sent untimed."""
    scene, obs, request = entry["scene"], entry["obs"], entry["request"]
    if case == "remote":
        pol = RemotePolicy(url)
        pol.reset(scene.spec)
        pol.act(obs)

        def call():
            pol.act(obs)
            server_infer[name].append(pol.last_server_timing["infer_ms"])

        return call, pol.close
    if case == "openpi_client":
        if client_cls is None:
            return None, None
        client = client_cls(url)
        client.infer({**request, **episode_keys(scene)})
        return (lambda: client.infer(request)), client._ws.close
    if case == "codec":
        reply = entry["reply"]
        return (lambda: (wire.unpackb(wire.packb(request)), wire.unpackb(wire.packb(reply)))), (lambda: None)
    local = ZeroPolicy()
    local.reset(scene.spec)
    return (lambda: local.act(obs)), (lambda: None)


def episode_keys(scene) -> dict:
    return {wire.RESET: True, wire.SPEC: scene.spec.to_json()}


if __name__ == "__main__":
    main()
