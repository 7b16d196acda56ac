"""What the sidecar costs: per-step latency added by SidecarRollout, the wire codec, warm boot.

    .venv/bin/python benchmarks/bench_sidecar.py [--steps 300] [--rounds 5] [--boots 5] [--json PATH]
        [--cases state,rgb2x256,rgb5x480x560] [--parts step,alone,profile,codec,messages,breakdown,boot]
        [--ways inproc,tcp,ipc,local,spin,compact,cspin]

One run measures everything below on this machine (about 2-3 minutes with the defaults); nothing is
asserted: the script prints a table and a goals line and exits 0 whether goals are met or not.

Cases (Franka Panda, lift_cube layout, MuJoCo, 20 Hz control, JOINT_POSITION actions: one
smooth, seeded stream around the home pose, the same in every case; every case resets with
seed 0 at the start of every round, so all of them run the very same trajectory):

1. Step latency, three observation sizes x up to seven ways to run the scene (``--ways``):
   - observations: ``state`` (render_images=False, ~0.1 kB of arrays), ``rgb2x256`` (camera1 +
     wrist camera2 at 256x256: 2 x 192 kB), ``rgb5x480x560`` (the manifest's two cameras plus
     three more around the table, added with ``dataclasses.replace``, all at 480x560:
     5 x 806 kB = 4.03 MB of images per observation);
   - ways: ``inproc`` (``ManifestScene`` in this process), ``tcp`` and ``ipc`` (``SidecarRollout``
     over ZeroMQ with that transport, ``local=False`` for ipc: the path before the local fast
     path), ``local`` (ipc with the local fast path: Unix socket + shared-memory slots, neither
     side busy-polling: ``spin_us=0``) and ``spin`` (the same, each side busy-polling up to
     ``local.DEFAULT_SPIN_US`` for the other's next message: the default with >= 4 usable cores),
     both with msgpack messages (``compact=False``); ``compact`` and ``cspin``: ``local`` and ``spin``
     with compact step messages (``simseam.sidecar.compact``, the default on the local path);
     the sidecar runs this venv's python. All of them are interleaved in the same blocks.
   Within a round the ways of one observation size are interleaved in blocks (10 / 5 / 2
   steps), rotating which goes first in each block, so the slow and fast phases of this shared
   VM hit all of them alike. Per round and case: p50 / p90 of the per-step wall time around
   ``step()``. Reported: the median over rounds of those, and the *added* latency of a sidecar,
   ``median over rounds of (sidecar p50 - inproc p50 of the same round)`` (physics and
   rendering are the same work on both sides, so the difference is what the sidecar adds), and
   ``added paired``, the median over rounds of the median per-step difference (step i of the
   sidecar minus step i in process: the same state, the same work), which is less noisy when
   rendering dominates. Also checked: every sidecar ends each round on bit-identical joint
   positions to the in-process scene.
   ``alone`` (part 1b): the same ways, each stepping its round's steps in a row with the others
   idle (the order rotated every round): a policy loop's steady state, where the blocks above
   start every tenth step on caches another rollout just used. Added = the way's p50 minus the
   in-process p50 of the same round, median over rounds.

2. Codec alone: encode + decode of a real step reply (``{"obs": <observation>, "reward", ...}``,
   taken from the in-process scenes) with ``simseam.sidecar.wire`` (zero-copy: decode reads the
   frames encode produced; ``wire+copy`` first copies every frame into ``bytes``, as a copying
   transport would) vs ``blob``: each array ``np.save``-d into a BytesIO, the bytes in a msgpack
   map, ``np.load`` on decode. timeit-style: calls per measurement from ``Timer.autorange``, 7
   measurements per codec interleaved across codecs; reported: median (and min) per round trip.

3. Where the added time goes, in situ: one more sidecar per observation size and path (ipc over
   ZeroMQ, and each local-path way, whose socket calls are wrapped the same way; with compact
   messages the wrapped codec calls are ``compact.encode_step`` / ``decode_step`` /
   ``ReplyTemplates.encode`` / ``ReplyDecoder.decode``),
   started with ``SidecarRollout(python=<wrapper>)`` where the wrapper runs this file as an
   instrumented server (the real ``simseam.sidecar.server.main``, with its ``decode`` /
   ``encode`` / ``scene.step`` / ``send_multipart`` wrapped to take timestamps; src untouched),
   while the client's ``encode`` / ``decode`` and socket are wrapped the same way. Timestamps are
   ``time.perf_counter`` (CLOCK_MONOTONIC, one clock for both processes), so each step splits
   into: client pre-work, client encode, client send + request transfer + server wake-up, server
   decode, ``scene.step``, server encode, server send + reply transfer + client wake-up, client
   decode, the rest (the send calls are folded into the transfer legs: on 2 cores the sender is
   often preempted by the woken receiver before its send call returns). The instrumented sidecars
   of all ways are interleaved with each other and the in-process scene (same blocks, same actions,
   one round). Reported:
   the median of each part; ``overhead`` = their sum minus ``scene.step``; ``work+`` = the
   sidecar's ``scene.step`` minus the in-process step (the same work, slower or faster over
   there); ``added`` = sidecar p50 - in-process p50 in this round (about overhead + work+).

2b. Step messages (``messages``), warm, in process: one step's request and reply on the local path,
   msgpack vs compact (``simseam.sidecar.compact``; images through a real ring): each side's encode
   and decode, and the framing (``local.send_message`` + ``recv_message`` over a socketpair) of the
   request and of the reply; timeit, best of 5. The in-situ profile (3.) shows what they cost cold.

4. The same with no physics and everything hot: the component costs of one step request
   measured in process (client encode of the request, server decode of it, server encode of the
   reply, client decode of it), the ZeroMQ round trip alone (a subprocess answering pre-encoded
   replies to pre-encoded requests, same socket types and options as the real ones) and the
   whole path (a subprocess running the real ``simseam.sidecar.server.Server.handle`` over a
   stub scene that returns a fixed observation of the case's size; the client loop is
   ``SidecarRollout._request``'s: encode, send, poll, recv, decode). Median over rounds of p50.

5. Warm boot: ``SidecarRollout(...)`` construction until it returns (the sidecar is up, the
   scene built, ``hello`` done), ipc, for the 2x256x256 scene and the state-only one; one
   warm-up boot (the step cases' six boots come before it as well, so the page cache is warm),
   then 5 boots per config, interleaved; each sidecar is closed before the next starts. Median.

Goals: added p50 <= 0.3 ms state-only and <= 0.6 ms with 2x256x256 RGB (on the local fast path;
tcp and ipc over ZeroMQ are reported for comparison);
wire codec >= 5x faster than the blob codec on the 2x256x256 observation; warm boot <= 2 s.
Writes JSON to benchmarks/results/sidecar.json (``--json`` to change). Every sidecar and stub
process started here is closed at the end, and checked to be gone.
"""

from __future__ import annotations

import argparse
import dataclasses
import io
import json
import math
import os
import platform
import shutil
import subprocess
import sys
import time
import timeit
from pathlib import Path

os.environ.setdefault("MUJOCO_GL", "egl")

import msgpack
import mujoco
import numpy as np
import zmq

from simseam.robot.spec import RobotSpec
from simseam.scene.manifest_scene import ManifestScene, SceneOptions
from simseam.sidecar.client import SidecarRollout
from simseam.sidecar.target import SceneTarget
from simseam.sidecar.wire import decode, encode

HERE = Path(__file__).resolve().parent
LAYOUT = "lift_cube"
MODE = "joint_position"
WARMUP = 5
# local: ipc + the local fast path (Unix socket, shared-memory slots) with msgpack messages, never
# busy-polling (spin_us=0); spin: the same with each side busy-polling DEFAULT_SPIN_US before it sleeps
# (the default on >= 4 cores); compact / cspin: local / spin with compact step messages (the default)
WAYS = ("inproc", "tcp", "ipc", "local", "spin", "compact", "cspin")
SPIN_US = {"local": 0, "spin": None, "compact": 0, "cspin": None}  # the local-path ways; None: local.DEFAULT_SPIN_US
COMPACT_WAYS = ("compact", "cspin")
LOCAL_WAYS = tuple(SPIN_US)
GOAL_ADDED_MS = {"state": 0.3, "rgb2x256": 0.6}
GOAL_CODEC_SPEEDUP = 5.0
GOAL_BOOT_S = 2.0
# a sidecar gets a sanitized environment; a machine whose packages come from PYTHONPATH (the GPU
# machine: wheels unpacked with pip --target) passes it on explicitly
SIDECAR_ENV = {"PYTHONPATH": os.environ["PYTHONPATH"]} if os.environ.get("PYTHONPATH") else {}
BIG = (480, 560)  # 5 cameras x 480 x 560 x 3 = 4.03 MB per observation


# ------------------------------------------------------------------ scenes and actions
def spin_us(way: str) -> int:
    from simseam.sidecar.local import DEFAULT_SPIN_US

    got = SPIN_US.get(way, 0)
    return DEFAULT_SPIN_US if got is None else got


def multicam_spec(spec: RobotSpec, total: int = 5) -> RobotSpec:
    """``spec`` with RGB cameras added around the table (copies of camera1, turned about z)."""
    base = next(s for s in spec.sensors if s.name == "camera1")
    extra = []
    for k in range(total - len(spec.sensors_of("rgb"))):
        yaw = (k + 1) * 2 * math.pi / 8 * (1 if k % 2 == 0 else -1)  # +45, -90, +135 deg ...
        r = base.xyz[0]
        extra.append(dataclasses.replace(
            base, name=f"camera{3 + k}", feature_key=f"camera{3 + k}",
            xyz=[r * math.cos(yaw), r * math.sin(yaw), base.xyz[2]],
            rpy=[base.rpy[0], base.rpy[1], base.rpy[2] + yaw]))
    return dataclasses.replace(spec, sensors=[*spec.sensors, *extra])


def obs_configs(spec: RobotSpec) -> dict[str, tuple[RobotSpec, dict]]:
    """Observation size name -> (robot spec, SceneOptions fields as JSON types)."""
    return {
        "state": (spec, {"render_images": False, "control_mode": MODE}),
        "rgb2x256": (spec, {"render_images": True, "image_size": [256, 256], "control_mode": MODE}),
        "rgb5x480x560": (multicam_spec(spec), {"render_images": True, "image_size": list(BIG), "control_mode": MODE}),
    }


def scene_options(opts: dict) -> SceneOptions:
    o = dict(opts)
    if o.get("image_size") is not None:
        o["image_size"] = tuple(o["image_size"])
    return SceneOptions(**o)


def joint_actions(spec: RobotSpec, n: int, seed: int = 1) -> np.ndarray:
    """Joint-position targets: home + a seeded sum of slow sinusoids (like a policy's), gripper swept."""
    rng = np.random.default_rng(seed)
    dim = len(spec.arm_joints) + (1 if spec.gripper else 0)
    t = np.arange(n)[:, None]
    freq = rng.uniform(0.02, 0.08, (1, dim))
    phase = rng.uniform(0, 2 * np.pi, (1, dim))
    acts = (0.4 * np.sin(2 * np.pi * freq * t + phase)).astype(np.float32)
    home = np.array([j.home for j in spec.arm_joints], dtype=np.float32)
    acts[:, :len(home)] = home + 0.5 * acts[:, :len(home)]
    return acts


class StepCase:
    """One rollout (in process or a sidecar) stepping through the shared action stream."""

    def __init__(self, rollout, actions: np.ndarray):
        self.rollout = rollout
        self.actions = actions
        self.last = None

    def start(self) -> None:
        self.rollout.reset(0)
        for i in range(WARMUP):
            self.rollout.step(self.actions[i])

    def step(self, i: int) -> None:
        self.last = self.rollout.step(self.actions[WARMUP + i])


def bench_alone(groups: dict[str, dict[str, StepCase]], steps: dict[str, int], rounds: int) -> dict:
    """Each way steps ``steps`` times in a row with nothing in between (the other rollouts idle), the
    ways taking turns in an order rotated every round; per round and way the p50, and the added
    latency = the way's p50 - the in-process p50 of the same round, median over rounds. Unlike the
    interleaved blocks, no step follows another rollout's work: this is a policy loop's steady state
    (on a shared machine it is more exposed to drift, hence the rotation and the rounds)."""
    out = {}
    for g, group in groups.items():
        names = list(group)
        per_round: dict[str, list[float]] = {w: [] for w in names}
        for r in range(rounds):
            k = r % len(names)
            for w in names[k:] + names[:k]:
                c = group[w]
                c.start()
                t = np.empty(steps[g])
                for i in range(steps[g]):
                    t0 = time.perf_counter()
                    c.step(i)
                    t[i] = (time.perf_counter() - t0) * 1e3
                per_round[w].append(float(np.percentile(t, 50)))
        for w in names:
            row = {"p50_ms": med(per_round[w]), "rounds_p50_ms": per_round[w]}
            if w != "inproc":
                row["added_p50_ms"] = med(x - b for x, b in zip(per_round[w], per_round["inproc"]))
            out[f"{g}/{w}"] = row
    return out


def interleaved(cases: dict[str, StepCase], steps: int, block: int) -> dict[str, np.ndarray]:
    """Time ``steps`` steps of each case, switching case every ``block`` steps (rotating the
    order from block to block), so the machine's slow phases fall on every case alike."""
    for c in cases.values():
        c.start()
    names = list(cases)
    times = {k: np.empty(steps) for k in cases}
    for nb, b0 in enumerate(range(0, steps, block)):
        k = nb % len(names)
        for name in names[k:] + names[:k]:
            c = cases[name]
            for i in range(b0, min(steps, b0 + block)):
                t0 = time.perf_counter()
                c.step(i)
                times[name][i] = (time.perf_counter() - t0) * 1e3
    return times


def stats(ms: np.ndarray) -> dict:
    return {"p50_ms": float(np.percentile(ms, 50)), "p90_ms": float(np.percentile(ms, 90)),
            "mean_ms": float(ms.mean()), "n": int(ms.size)}


def med(xs) -> float:
    return float(np.median(list(xs)))


# ---------------------------------------------------------------------------- codecs
def reply_body(obs: dict) -> dict:
    """What the server encodes for one step (see Server.handle)."""
    return {"obs": obs, "reward": 0.0, "terminated": False, "truncated": False,
            "info": {"success": False, "steps": 7}}


def blob_encode(body) -> bytes:
    def pack(x):
        if isinstance(x, np.ndarray):
            buf = io.BytesIO()
            np.save(buf, x, allow_pickle=False)
            return {"__npy__": buf.getvalue()}
        if isinstance(x, dict):
            return {k: pack(v) for k, v in x.items()}
        if isinstance(x, (list, tuple)):
            return [pack(v) for v in x]
        return x

    return msgpack.packb(pack(body), use_bin_type=True)


def blob_decode(data: bytes):
    def unpack(x):
        if isinstance(x, dict):
            if "__npy__" in x:
                return np.load(io.BytesIO(x["__npy__"]), allow_pickle=False)
            return {k: unpack(v) for k, v in x.items()}
        if isinstance(x, list):
            return [unpack(v) for v in x]
        return x

    return unpack(msgpack.unpackb(data, raw=False))


def codec_funcs(body: dict) -> dict:
    def wire():
        decode(encode("ok", body))

    def wire_copy():
        decode([bytes(f) for f in encode("ok", body)])

    def blob():
        blob_decode(blob_encode(body))

    return {"wire": wire, "wire+copy": wire_copy, "blob": blob}


def check_codecs(body: dict) -> None:
    """Both codecs give back the arrays they were given (so the timing compares like with like)."""
    _, w = decode(encode("ok", body))
    b = blob_decode(blob_encode(body))
    for got in (w, b):
        for k, v in body["obs"]["images"].items():
            assert np.array_equal(got["obs"]["images"][k], v)
        assert np.array_equal(got["obs"]["state"], body["obs"]["state"])


def bench_codecs(bodies: dict[str, dict], repeats: int = 7) -> dict:
    out = {}
    for name, body in bodies.items():
        check_codecs(body)
        funcs = codec_funcs(body)
        timers = {k: timeit.Timer(f) for k, f in funcs.items()}
        number = {k: t.autorange()[0] for k, t in timers.items()}
        per_call = {k: [] for k in funcs}
        for r in range(repeats):
            order = list(funcs)
            k0 = r % len(order)
            for k in order[k0:] + order[:k0]:
                per_call[k].append(timers[k].timeit(number[k]) / number[k] * 1e3)
        res = {k: {"median_ms": med(v), "min_ms": float(min(v)), "number": number[k], "runs_ms": v}
               for k, v in per_call.items()}
        frames = encode("ok", body)
        res["sizes"] = {"wire_bytes": int(sum(memoryview(f).nbytes for f in frames)),
                        "blob_bytes": len(blob_encode(body))}
        res["speedup_wire_vs_blob"] = res["blob"]["median_ms"] / res["wire"]["median_ms"]
        res["speedup_wire_copy_vs_blob"] = res["blob"]["median_ms"] / res["wire+copy"]["median_ms"]
        out[name] = res
    return out


# ----------------------------------------------------- breakdown: stub server process
def _obs_like(shapes: dict) -> dict:
    rng = np.random.default_rng(0)
    return {
        "images": {k: rng.integers(0, 256, (h, w, 3), dtype=np.uint8) for k, (h, w) in shapes["images"].items()},
        "state": rng.standard_normal(shapes["state"]).astype(np.float32),
        "task": "lift the red cube",
        "joint_positions": rng.standard_normal(shapes["joints"]).astype(np.float32),
        "joint_velocities": rng.standard_normal(shapes["joints"]).astype(np.float32),
        "sim_time_ns": 123_000_000,
    }


def obs_shapes(obs: dict) -> dict:
    return {"images": {k: list(v.shape[:2]) for k, v in obs["images"].items()},
            "state": int(obs["state"].shape[0]), "joints": int(obs["joint_positions"].shape[0])}


def stub_server(cfg: dict) -> int:
    """Subprocess: a REP socket like the real server's, over ``cfg['endpoint']``.

    mode ``echo``: answer each request with a pre-encoded reply (no decode, no encode): the
    ZeroMQ round trip alone. mode ``server``: the real ``Server.handle`` over a stub scene whose
    ``step`` returns a fixed observation (no physics). In both, ``action[0]`` picks which
    observation size (index into ``cfg['cases']``) to answer with.
    """
    from simseam.seam import StepResult
    from simseam.sidecar.server import Server

    obs = [_obs_like(s) for s in cfg["cases"]]

    class StubScene:
        def step(self, action):
            return StepResult(obs[int(action[0])], 0.0, False, False, {"success": False, "steps": 7})

    server = Server(StubScene(), cfg["token"], "stub")
    replies = [encode("ok", reply_body(o)) for o in obs]
    ctx = zmq.Context()
    sock = ctx.socket(zmq.REP)
    sock.setsockopt(zmq.LINGER, 0)
    sock.bind(cfg["endpoint"])
    print(json.dumps({"endpoint": sock.getsockopt_string(zmq.LAST_ENDPOINT)}), flush=True)
    parent = os.getppid()
    echo = cfg["mode"] == "echo"
    try:
        while True:
            if not sock.poll(500):
                if os.getppid() != parent:
                    return 0
                continue
            frames = sock.recv_multipart(copy=False)
            if echo:
                if len(frames) == 1:  # close
                    sock.send(b"bye")
                    return 0
                idx = int(np.frombuffer(frames[1].buffer, dtype=np.float32)[0])
                sock.send_multipart(replies[idx], copy=False)
            else:
                reply, stop = server.handle(frames)
                sock.send_multipart(reply, copy=False)
                if stop:
                    return 0
    finally:
        sock.close(0)
        ctx.term()


class Stub:
    """A stub server subprocess and a REQ socket to it (options as SidecarRollout's)."""

    def __init__(self, mode: str, transport: str, cases: list[dict], tmpdir: Path):
        self.token = "0" * 32
        endpoint = f"ipc://{tmpdir}/stub-{mode}.sock" if transport == "ipc" else "tcp://127.0.0.1:*"
        cfg = {"mode": mode, "endpoint": endpoint, "token": self.token, "cases": cases}
        self.proc = subprocess.Popen([sys.executable, str(Path(__file__).resolve()), "--stub-server", json.dumps(cfg)],
                                     stdout=subprocess.PIPE, stdin=subprocess.DEVNULL, text=True)
        self.pid = self.proc.pid
        line = self.proc.stdout.readline()
        if not line:
            raise RuntimeError(f"stub server ({mode}, {transport}) did not start")
        self.sock = zmq.Context.instance().socket(zmq.REQ)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.setsockopt(zmq.REQ_RELAXED, 1)
        self.sock.setsockopt(zmq.REQ_CORRELATE, 1)
        self.sock.connect(json.loads(line)["endpoint"])
        self.mode = mode

    def request_frames(self, idx: int, dim: int) -> list:
        return encode("step", {"action": np.full(dim, idx, dtype=np.float32), "token": self.token})

    def round_trip(self, action: np.ndarray, frames: list) -> None:
        sock = self.sock
        if self.mode == "echo":  # pre-encoded request, reply frames not decoded: transport only
            sock.send_multipart(frames, copy=False)
            while not sock.poll(50):
                pass
            sock.recv_multipart(copy=False)
        else:  # what SidecarRollout._request does
            body = {"action": action, "token": self.token}
            sock.send_multipart(encode("step", body), copy=False)
            while not sock.poll(50):
                pass
            kind, reply = decode(sock.recv_multipart(copy=False))
            assert kind == "ok", reply

    def close(self) -> None:
        try:
            if self.mode == "echo":
                self.sock.send(b"close")
            else:
                self.sock.send_multipart(encode("close", {"token": self.token}), copy=False)
            self.sock.poll(2000)
        finally:
            self.sock.close(0)
            try:
                self.proc.wait(3)
            except subprocess.TimeoutExpired:
                self.proc.kill()
                self.proc.wait(3)
            self.proc.stdout.close()


def bench_messages(obs_by_case: dict[str, dict], dim: int) -> dict:
    """Warm, in process: what one step's messages cost on the local path, msgpack vs compact
    (``simseam.sidecar.compact``): each side's encode / decode (images through a real ring), and
    the framing (``local.send_message`` + ``recv_message`` of the request and of the reply over a
    socketpair). timeit: calls per measurement from ``autorange`` / 4, the best of 5."""
    import socket

    from simseam.sidecar import compact, local

    def best(f) -> float:
        t = timeit.Timer(f)
        n = max(1, t.autorange()[0] // 4)
        return min(t.repeat(5, n)) / n * 1e3

    out = {}
    action = np.zeros(dim, dtype=np.float32)
    for g, obs in obs_by_case.items():
        body = reply_body(obs)
        size = sum((a.nbytes + 63) // 64 * 64 for a in obs["images"].values() if a.nbytes >= local.DEFAULT_THRESHOLD)
        ring = local.SlotRing(2, size) if size else None
        slots = local.map_slots(os.dup(ring.fd), ring.layout()) if ring is not None else None
        tx, rx = compact.ReplyTemplates(), compact.ReplyDecoder(slots)
        rx.decode([bytes(f) for f in tx.encode(body, ring)])  # the announcement: later replies go compact
        a_sock, b_sock = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            req = {"msgpack": encode("step", {"action": action}), "compact": compact.encode_step(action, False)}
            rep = {"msgpack": encode("ok", body, ring), "compact": tx.encode(body, ring)}
            assert compact.is_compact(rep["compact"]) and compact.is_compact(req["compact"])
            got = {k: [bytes(f) for f in v] for k, v in rep.items()}
            rin = {k: [bytes(f) for f in v] for k, v in req.items()}

            def framing(frames):
                def f():
                    local.send_message(a_sock, frames)
                    local.recv_message(b_sock)
                return f

            row = {}
            for way, enc_req, dec_req, enc_rep, dec_rep in (
                    ("msgpack", lambda: encode("step", {"action": action}), lambda: decode(rin["msgpack"]),
                     lambda: encode("ok", body, ring), lambda: decode(got["msgpack"], slots)),
                    ("compact", lambda: compact.encode_step(action, False), lambda: compact.decode_step(rin["compact"]),
                     lambda: tx.encode(body, ring), lambda: rx.decode(got["compact"]))):
                comp = {"client_encode_request": best(enc_req), "server_decode_request": best(dec_req),
                        "server_encode_reply": best(enc_rep), "client_decode_reply": best(dec_rep),
                        "framing_request": best(framing(req[way])), "framing_reply": best(framing(rep[way]))}
                row[way] = {**comp, "total_ms": sum(comp.values()),
                            "bytes": {"request": sum(len(bytes(f)) for f in req[way]),
                                      "reply": sum(len(bytes(f)) for f in rep[way])},
                            "frames": {"request": len(req[way]), "reply": len(rep[way])}}
            out[g] = row
        finally:
            a_sock.close()
            b_sock.close()
            rx.slots = slots = None
            if ring is not None:
                ring.close()
    return out


def component_times(obs: dict, dim: int) -> dict:
    """In-process cost (ms) of each codec step of one request/reply, as frames arrive (zmq.Frame)."""
    token = "0" * 32
    action = np.zeros(dim, dtype=np.float32)
    body = reply_body(obs)
    req_in = [zmq.Frame(bytes(f)) for f in encode("step", {"action": action, "token": token})]
    rep_in = [zmq.Frame(bytes(f)) for f in encode("ok", body)]
    funcs = {
        "client_encode_request": lambda: encode("step", {"action": action, "token": token}),
        "server_decode_request": lambda: decode(req_in),
        "server_encode_reply": lambda: encode("ok", body),
        "client_decode_reply": lambda: decode(rep_in),
    }
    out = {}
    for k, f in funcs.items():
        t = timeit.Timer(f)
        n = max(1, t.autorange()[0] // 4)
        out[k] = min(t.repeat(5, n)) / n * 1e3
    return out


def bench_breakdown(obs_by_case: dict[str, dict], dim: int, rounds: int, tmpdir: Path, pids: list) -> dict:
    names = list(obs_by_case)
    reps = {"state": 300, "rgb2x256": 150, "rgb5x480x560": 30}
    shapes = [obs_shapes(obs_by_case[n]) for n in names]
    stubs = {}
    try:
        for transport in ("tcp", "ipc"):
            for mode in ("echo", "server"):
                s = Stub(mode, transport, shapes, tmpdir / transport)
                pids.append(s.pid)
                stubs[(transport, mode)] = s
        runs = {(n, t, m): [] for n in names for (t, m) in stubs}
        for r in range(rounds):
            for idx, n in enumerate(names):
                action = np.full(dim, idx, dtype=np.float32)
                keys = list(stubs)
                k0 = r % len(keys)
                for key in keys[k0:] + keys[:k0]:
                    s = stubs[key]
                    frames = s.request_frames(idx, dim)
                    for _ in range(5):
                        s.round_trip(action, frames)
                    ms = np.empty(reps.get(n, 50))
                    for i in range(ms.size):
                        t0 = time.perf_counter()
                        s.round_trip(action, frames)
                        ms[i] = (time.perf_counter() - t0) * 1e3
                    runs[(n, *key)].append(float(np.percentile(ms, 50)))
    finally:
        for s in stubs.values():
            s.close()
    out = {}
    for n in names:
        comp = component_times(obs_by_case[n], dim)
        row = {"codec_components_ms": comp, "codec_total_ms": sum(comp.values())}
        for t in ("tcp", "ipc"):
            row[f"zmq_round_trip_{t}_ms"] = med(runs[(n, t, "echo")])
            row[f"stub_sidecar_{t}_ms"] = med(runs[(n, t, "server")])
            row[f"rounds_{t}"] = {"echo": runs[(n, t, "echo")], "server": runs[(n, t, "server")]}
        out[n] = row
    return out


# ------------------------------------------------------- in-situ profile (instrumented)
PROF_ENV = "SIMSEAM_BENCH_PROFILE_OUT"
PROF_PARTS = (  # (name, from timestamp, to timestamp); c_* client side, s_* server side; contiguous
    ("cli_pre", "c_t0", "c_enc0"),      # check_action, request body
    ("cli_enc", "c_enc0", "c_enc1"),    # wire.encode of the request
    ("req_leg", "c_enc1", "s_recv1"),   # client send_multipart + transfer + server wake-up + recv
    ("srv_dec", "s_recv1", "s_dec1"),   # wire.decode of the request
    ("srv_disp", "s_dec1", "s_step0"),  # token check, dispatch
    ("scene_step", "s_step0", "s_step1"),
    ("srv_post", "s_step1", "s_enc0"),  # reply body
    ("srv_enc", "s_enc0", "s_enc1"),    # wire.encode of the reply
    ("rep_leg", "s_enc1", "c_recv1"),   # server send_multipart + transfer + client wake-up + recv
    ("cli_dec", "c_recv1", "c_dec1"),   # wire.decode of the reply
    ("cli_post", "c_dec1", "c_t1"),     # StepResult
)


def instrumented_server(argv: list[str]) -> int:
    """Subprocess (``--instrumented-server -m simseam.sidecar.server --boot PATH``): the real
    sidecar server with timestamps around recv, decode, scene.step, encode and send."""
    import atexit

    import simseam.sidecar.server as srv

    log: list[dict] = []
    cur: dict = {}
    dec, enc, build, send, recv = srv.decode, srv.encode, srv.build_scene, zmq.Socket.send_multipart, \
        zmq.Socket.recv_multipart

    def t_recv(self, *a, _real=None, **k):
        r = (_real or recv)(self, *a, **k)
        cur.clear()
        cur["s_recv1"] = time.perf_counter()
        return r

    def t_decode(frames, *args):
        r = dec(frames, *args)
        cur["s_dec1"] = time.perf_counter()
        return r

    def t_encode(op, body=None, *args):
        cur["s_enc0"] = time.perf_counter()
        r = enc(op, body, *args)
        cur["s_enc1"] = time.perf_counter()
        return r

    def t_send(self, frames, *a, _real=None, **k):
        r = (_real or send)(self, frames, *a, **k)
        cur["s_send1"] = time.perf_counter()
        if "s_step0" in cur:
            log.append(dict(cur))
        return r

    def t_build(*args):
        scene = build(*args)
        step = scene.step

        def t_step(action, *a, **k):
            cur["s_step0"] = time.perf_counter()
            r = step(action, *a, **k)
            cur["s_step1"] = time.perf_counter()
            return r

        scene.step = t_step
        return scene

    def dump():
        import signal

        signal.signal(signal.SIGTERM, signal.SIG_IGN)  # the client's reaping SIGTERM must not cut the log short
        Path(os.environ[PROF_ENV]).write_text(json.dumps(log))

    srv.decode, srv.encode, srv.build_scene = t_decode, t_encode, t_build
    # compact step messages: the request's decode_step, the reply's templated encode (whose plain msgpack
    # fallback calls wire.encode directly, never srv.encode: one pair of timestamps per reply)
    dec_step, tpl_encode = srv.decode_step, srv.ReplyTemplates.encode

    def t_decode_step(frames):
        r = dec_step(frames)
        cur["s_dec1"] = time.perf_counter()
        return r

    def t_tpl_encode(self, body, ring=None):
        cur["s_enc0"] = time.perf_counter()
        r = tpl_encode(self, body, ring)
        cur["s_enc1"] = time.perf_counter()
        return r

    srv.decode_step, srv.ReplyTemplates.encode = t_decode_step, t_tpl_encode
    zmq.Socket.send_multipart, zmq.Socket.recv_multipart = t_send, t_recv
    lsend, lrecv = srv.local.send_message, srv.local.recv_message  # the local fast path's framing

    def t_lrecv(sock, *a, **k):
        return t_recv(sock, *a, _real=lrecv, **k)

    def t_lsend(sock, frames, *a, **k):
        return t_send(sock, frames, *a, _real=lsend, **k)

    srv.local.send_message, srv.local.recv_message = t_lsend, t_lrecv
    atexit.register(dump)
    return srv.main(argv[argv.index("--boot"):])


class _TimedSocket:
    """The client's REQ socket, with a timestamp after each send and recv."""

    def __init__(self, sock, cur: dict):
        self._s, self._cur = sock, cur

    def send_multipart(self, *a, **k):
        r = self._s.send_multipart(*a, **k)
        self._cur["c_send1"] = time.perf_counter()
        return r

    def recv_multipart(self, *a, **k):
        r = self._s.recv_multipart(*a, **k)
        self._cur["c_recv1"] = time.perf_counter()
        return r

    def __getattr__(self, name):
        return getattr(self._s, name)


class _ProfCase(StepCase):
    """A sidecar StepCase that keeps the client-side timestamps of each timed step."""

    def __init__(self, rollout, actions: np.ndarray, cur: dict, log: list):
        super().__init__(rollout, actions)
        self.cur, self.log = cur, log

    def step(self, i: int) -> None:
        self.cur.clear()
        t0 = time.perf_counter()
        super().step(i)
        self.cur["c_t1"] = time.perf_counter()
        self.cur["c_t0"] = t0
        self.log.append(dict(self.cur))


def profile_in_situ(configs: dict, inproc: dict[str, StepCase], actions: np.ndarray, steps: dict, blocks: dict,
                    tmpdir: Path, pids: list, ways: tuple = ("ipc", *LOCAL_WAYS)) -> dict:
    """Per observation size and transport (``ways``: ipc and the local-path ways): an instrumented
    sidecar, all of them interleaved with each other and the in-process scene, their steps split into
    parts (see PROF_PARTS)."""
    import simseam.sidecar.client as client_mod
    import simseam.sidecar.compact as compact_mod

    wrapper = tmpdir / "instrumented-python"
    wrapper.write_text(f'#!/bin/sh\nexec "{sys.executable}" "{Path(__file__).resolve()}" --instrumented-server "$@"\n')
    wrapper.chmod(0o700)
    enc, dec = client_mod.encode, client_mod.decode
    enc_step, rdec = client_mod.encode_step, compact_mod.ReplyDecoder.decode
    cur: dict = {}

    def t_encode(op, body=None):
        cur["c_enc0"] = time.perf_counter()
        r = enc(op, body)
        cur["c_enc1"] = time.perf_counter()
        return r

    def t_decode(frames, *args):
        r = dec(frames, *args)
        cur["c_dec1"] = time.perf_counter()
        return r

    def t_encode_step(action, state_only):
        cur["c_enc0"] = time.perf_counter()
        r = enc_step(action, state_only)
        cur["c_enc1"] = time.perf_counter()
        return r

    def t_rdecode(self, frames):
        r = rdec(self, frames)
        cur["c_dec1"] = time.perf_counter()
        return r

    out = {}
    for g, (cspec, opts) in configs.items():
        # every way's instrumented sidecar of this size, interleaved with each other and the in-process scene
        n = steps[g]
        cases: dict[str, _ProfCase] = {}
        logs: dict[str, tuple[Path, list]] = {}
        try:
            for transport in ways:
                log_path = tmpdir / f"profile-{g}-{transport}.json"
                sc = SidecarRollout(SceneTarget(cspec.to_json(), LAYOUT, "mujoco", opts), transport="ipc", python=str(wrapper),
                                    env={**SIDECAR_ENV, PROF_ENV: str(log_path)}, local=transport in SPIN_US,
                                    spin_us=spin_us(transport), compact=transport in COMPACT_WAYS)
                pids.append(sc.pid)
                assert sc.compact == (transport in COMPACT_WAYS)
                sc._sock = _TimedSocket(sc._sock, cur)
                logs[transport] = (log_path, [])
                cases[transport] = _ProfCase(sc, actions, cur, logs[transport][1])
            client_mod.encode, client_mod.decode, client_mod.encode_step = t_encode, t_decode, t_encode_step
            compact_mod.ReplyDecoder.decode = t_rdecode
            times = interleaved({"inproc": inproc[g], **cases}, n, blocks[g])
        finally:
            client_mod.encode, client_mod.decode, client_mod.encode_step = enc, dec, enc_step
            compact_mod.ReplyDecoder.decode = rdec
            for c in cases.values():
                if isinstance(c.rollout._sock, _TimedSocket):
                    c.rollout._sock = c.rollout._sock._s
                c.rollout.close()
        inproc_p50 = float(np.percentile(times["inproc"], 50))
        for transport, (log_path, clog) in logs.items():
            try:
                slog = json.loads(log_path.read_text())[-n:]  # the timed steps come last
            except (OSError, ValueError):
                print(f"profile {g}/{transport}: no server log")
                continue
            rows = [{**c, **sv} for c, sv in zip(clog, slog)]
            parts = {name: med((r[b] - r[a]) * 1e3 for r in rows) for name, a, b in PROF_PARTS}
            sidecar_p50 = float(np.percentile(times[transport], 50))
            out[f"{g}/{transport}"] = {
                "parts_p50_ms": parts,
                "overhead_sum_ms": sum(v for k, v in parts.items() if k != "scene_step"),
                "step_p50_ms": sidecar_p50, "inproc_step_p50_ms": inproc_p50, "added_p50_ms": sidecar_p50 - inproc_p50,
                # the same work, timed inside the sidecar vs in this process: > 0 when it runs slower there
                "scene_step_minus_inproc_ms": parts["scene_step"] - inproc_p50,
                "n": len(rows)}
    return out


# --------------------------------------------------------------------------- boot
def bench_boot(spec: RobotSpec, configs: dict[str, dict], reps: int, pids: list) -> dict:
    spec_json = spec.to_json()
    times = {k: [] for k in configs}
    stages = {k: [] for k in configs}

    def boot(opts: dict) -> tuple[float, float | None]:
        t0 = time.perf_counter()
        seen = {}

        def progress(stage: str) -> None:
            if stage.startswith("building scene"):
                seen["building"] = time.perf_counter() - t0

        sc = SidecarRollout(SceneTarget(spec_json, LAYOUT, "mujoco", opts), transport="ipc", progress=progress)
        dt = time.perf_counter() - t0
        pids.append(sc.pid)
        sc.close()
        return dt, seen.get("building")

    boot(configs[next(iter(configs))])  # warm-up: page cache, EGL/driver files
    for r in range(reps):
        order = list(configs)
        k0 = r % len(order)
        for k in order[k0:] + order[:k0]:
            dt, building = boot(configs[k])
            times[k].append(dt)
            stages[k].append(building)
    return {k: {"median_s": med(v), "min_s": float(min(v)), "max_s": float(max(v)), "runs_s": v,
                "to_building_scene_s": med(x for x in stages[k] if x is not None) if any(stages[k]) else None}
            for k, v in times.items()}


def alive_sidecars(pids: list[int]) -> list[int]:
    """Those of ``pids`` that still run a sidecar or a stub server started here."""
    out = []
    for pid in pids:
        try:
            cmd = Path(f"/proc/{pid}/cmdline").read_bytes()
        except OSError:
            continue
        if b"simseam.sidecar.server" in cmd or b"--stub-server" in cmd:
            out.append(pid)
    return out


# --------------------------------------------------------------------------- main
def main() -> None:
    if len(sys.argv) > 1 and sys.argv[1] == "--instrumented-server":
        sys.exit(instrumented_server(sys.argv[2:]))
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=300, help="timed steps per round, state-only (rgb: /5, 4 MB: /10)")
    ap.add_argument("--rounds", type=int, default=5)
    ap.add_argument("--boots", type=int, default=5, help="timed warm boots per config")
    ap.add_argument("--json", default=str(HERE / "results" / "sidecar.json"))
    ap.add_argument("--cases", default="state,rgb2x256,rgb5x480x560", help="observation sizes to run (comma list)")
    ap.add_argument("--parts", default="step,alone,profile,codec,messages,breakdown,boot", help="what to run (comma list)")
    ap.add_argument("--ways", default=",".join(WAYS),
                    help=f"ways to run the scene, interleaved (comma list of {', '.join(WAYS)}; inproc always runs)")
    ap.add_argument("--robot-json", help="the Panda as a RobotSpec JSON (machines without pydantic), with --urdf")
    ap.add_argument("--urdf", help="the URDF path for --robot-json")
    ap.add_argument("--stub-server", help=argparse.SUPPRESS)
    args = ap.parse_args()
    if args.stub_server:
        sys.exit(stub_server(json.loads(args.stub_server)))

    t_start = time.perf_counter()
    if args.robot_json:
        spec = RobotSpec.from_json(json.loads(Path(args.robot_json).read_text()))
        if args.urdf:
            spec = dataclasses.replace(spec, urdf="file:" + str(Path(args.urdf).resolve()))
    else:
        from simseam.robot.manifest import load_robot  # pydantic

        spec = load_robot("franka_panda")
    configs = {k: v for k, v in obs_configs(spec).items() if k in args.cases.split(",")}
    parts = set(args.parts.split(","))
    unknown = set(args.ways.split(",")) - set(WAYS)
    if unknown:
        ap.error(f"--ways: unknown {sorted(unknown)} (known: {', '.join(WAYS)})")
    ways = tuple(w for w in WAYS if w == "inproc" or w in args.ways.split(","))
    steps = {"state": args.steps, "rgb2x256": max(30, args.steps // 5), "rgb5x480x560": max(15, args.steps // 10)}
    blocks = {"state": 10, "rgb2x256": 5, "rgb5x480x560": 2}
    profile_steps = {"state": 200, "rgb2x256": 40, "rgb5x480x560": 15}
    actions = joint_actions(spec, WARMUP + max(*steps.values(), *profile_steps.values()))
    dim = actions.shape[1]

    pids: list[int] = []
    rollouts: list = []
    tmpdir = Path(os.environ.get("TMPDIR", "/tmp")) / f"simseam-bench-sidecar-{os.getpid()}"
    (tmpdir / "tcp").mkdir(parents=True, exist_ok=True)
    (tmpdir / "ipc").mkdir(parents=True, exist_ok=True)
    results: dict = {}
    try:
        # ---- 1. step latency
        groups: dict[str, dict[str, StepCase]] = {}
        for name, (cspec, opts) in configs.items():
            group = {}
            for way in ways:
                if way == "inproc":
                    ro = ManifestScene(cspec, LAYOUT, "mujoco", scene_options(opts))
                else:
                    ro = SidecarRollout(SceneTarget(cspec.to_json(), LAYOUT, "mujoco", opts),
                                        transport="tcp" if way == "tcp" else "ipc",
                                        local=way in SPIN_US, env=SIDECAR_ENV, spin_us=spin_us(way),
                                        compact=way in COMPACT_WAYS)
                    assert ro.fast == (way in SPIN_US), f"{way}: fast path {'not ' if not ro.fast else ''}taken"
                    assert ro.compact == (way in COMPACT_WAYS), f"{way}: compact messages {ro.compact}"
                    pids.append(ro.pid)
                rollouts.append(ro)
                group[way] = StepCase(ro, actions)
            assert group["inproc"].rollout.action_dim == dim
            groups[name] = group
        print(f"scenes up ({len(rollouts)}, {len(pids)} sidecars) in {time.perf_counter() - t_start:.1f} s; "
              f"steps per round {steps}, {args.rounds} rounds")

        per_round = {f"{g}/{w}": [] for g in groups for w in ways}
        paired = {f"{g}/{w}": [] for g in groups for w in ways if w != "inproc"}
        same_traj = {f"{g}/{w}": True for g in groups for w in ways if w != "inproc"}
        obs_bytes = {}
        for r in range(args.rounds):
            t0 = time.perf_counter()
            for g, group in groups.items():
                times = interleaved(group, steps[g], blocks[g])
                ref = group["inproc"].last.observation
                for w in ways:
                    per_round[f"{g}/{w}"].append(stats(times[w]))
                    if w != "inproc":
                        paired[f"{g}/{w}"].append(float(np.median(times[w] - times["inproc"])))
                        got = group[w].last.observation["joint_positions"]
                        same_traj[f"{g}/{w}"] &= bool(np.array_equal(got, ref["joint_positions"]))
                obs_bytes[g] = int(sum(v.nbytes for v in ref["images"].values()) + ref["state"].nbytes
                                   + ref["joint_positions"].nbytes + ref["joint_velocities"].nbytes)
            print(f"round {r + 1}/{args.rounds} done ({time.perf_counter() - t0:.1f} s)")

        step_res = {}
        for key, rs in per_round.items():
            g, w = key.split("/")
            row = {"p50_ms": med(x["p50_ms"] for x in rs), "p90_ms": med(x["p90_ms"] for x in rs),
                   "obs_bytes": obs_bytes[g], "rounds": rs}
            if w != "inproc":
                base = per_round[f"{g}/inproc"]
                row["added_p50_ms"] = med(x["p50_ms"] - b["p50_ms"] for x, b in zip(rs, base))
                row["added_p50_ms_of_medians"] = row["p50_ms"] - med(b["p50_ms"] for b in base)
                row["added_paired_ms"] = med(paired[key])
                row["same_trajectory_as_inproc"] = same_traj[key]
            step_res[key] = row
        results["step"] = step_res

        # ---- 1b. each way alone: consecutive steps of one rollout, as a user's loop runs them
        if "alone" in parts:
            print("alone ...")
            results["alone"] = bench_alone(groups, steps, args.rounds)

        # ---- 3. in-situ profile (with the in-process scenes, interleaved)
        if "profile" in parts:
            print("profile ...")
            results["profile"] = profile_in_situ(configs, {g: grp["inproc"] for g, grp in groups.items()}, actions,
                                             profile_steps, blocks, tmpdir, pids,
                                             tuple(w for w in ("ipc", *LOCAL_WAYS) if w in ways))

        # real observations (copied) for the codec and the breakdown, then the scenes go
        obs_by_case = {}
        for g, group in groups.items():
            o = group["inproc"].last.observation
            obs_by_case[g] = {k: ({ik: np.array(iv) for ik, iv in v.items()} if isinstance(v, dict)
                                  else (np.array(v) if isinstance(v, np.ndarray) else v)) for k, v in o.items()}
        for ro in rollouts:
            ro.close()
        rollouts.clear()

        # ---- 2. codec alone
        if "codec" in parts:
            print("codec ...")
            results["codec"] = bench_codecs({g: reply_body(obs_by_case[g]) for g in ("rgb2x256", "rgb5x480x560")
                                             if g in obs_by_case})

        # ---- 4. breakdown (no physics)
        if "messages" in parts:
            print("messages ...")
            results["messages"] = bench_messages(obs_by_case, dim)

        if "breakdown" in parts:
            print("breakdown ...")
            results["breakdown"] = bench_breakdown(obs_by_case, dim, args.rounds, tmpdir, pids)

        # ---- 5. warm boot
        if "boot" in parts:
            print("boot ...")
            results["boot"] = bench_boot(spec, {"rgb2x256": obs_configs(spec)["rgb2x256"][1],
                                                "state": obs_configs(spec)["state"][1]}, args.boots, pids)
    finally:
        for ro in rollouts:
            try:
                ro.close()
            except Exception as exc:  # noqa: BLE001 (report, keep closing the others)
                print(f"close failed: {exc!r}")
        shutil.rmtree(tmpdir, ignore_errors=True)

    orphans = alive_sidecars(pids)

    # ---------------------------------------------------------------------- report
    print(f"\n{'case':24s} {'p50 ms':>9s} {'p90 ms':>9s} {'added p50':>10s} {'added paired':>13s}  obs")
    for key, row in results["step"].items():
        added = f"{row['added_p50_ms']:+10.3f}" if "added_p50_ms" in row else f"{'':>10s}"
        pair = f"{row['added_paired_ms']:+13.3f}" if "added_paired_ms" in row else f"{'':>13s}"
        print(f"{key:24s} {row['p50_ms']:9.3f} {row['p90_ms']:9.3f} {added} {pair}  {row['obs_bytes'] / 1e6:.3f} MB")
    if results.get("alone"):
        print(f"\n{'alone (consecutive steps)':24s} {'p50 ms':>9s} {'added p50':>10s}")
        for key, row in results["alone"].items():
            added = f"{row['added_p50_ms']:+10.3f}" if "added_p50_ms" in row else f"{'':>10s}"
            print(f"{key:24s} {row['p50_ms']:9.3f} {added}")
    bad = [k for k, r in results["step"].items() if r.get("same_trajectory_as_inproc") is False]
    print("trajectories: " + ("all sidecars bit-identical to in-process" if not bad else f"DIFFER: {bad}"))

    print(f"\n{'codec round trip':24s} {'median ms':>10s} {'min ms':>9s} {'bytes':>10s}")
    for g, res in results.get("codec", {}).items():
        for k in ("wire", "wire+copy", "blob"):
            size = res["sizes"]["blob_bytes" if k == "blob" else "wire_bytes"]
            print(f"{g + ' ' + k:24s} {res[k]['median_ms']:10.4f} {res[k]['min_ms']:9.4f} {size:10d}")
        print(f"{g + ' speedup':24s} wire {res['speedup_wire_vs_blob']:.1f}x, "
              f"wire+copy {res['speedup_wire_copy_vs_blob']:.1f}x vs blob")

    if results.get("messages"):
        names = ("client_encode_request", "server_decode_request", "server_encode_reply", "client_decode_reply",
                 "framing_request", "framing_reply")
        print(f"\nstep messages, warm (ms)  {'cli-enc':>8s} {'srv-dec':>8s} {'srv-enc':>8s} {'cli-dec':>8s} "
              f"{'frm-req':>8s} {'frm-rep':>8s} {'total':>8s}   bytes (frames) request / reply")
        for g, row in results["messages"].items():
            for way, r in row.items():
                print(f"{g + ' ' + way:24s}  {' '.join(f'{r[n]:8.4f}' for n in names)} {r['total_ms']:8.4f}   "
                      f"{r['bytes']['request']} ({r['frames']['request']}) / {r['bytes']['reply']} ({r['frames']['reply']})")

    print(f"\nbreakdown (no physics, ms)   {'codec':>7s} {'zmq tcp':>8s} {'zmq ipc':>8s} {'stub tcp':>9s} "
          f"{'stub ipc':>9s}   codec: cli-enc / srv-dec / srv-enc / cli-dec")
    for g, row in results.get("breakdown", {}).items():
        c = row["codec_components_ms"]
        print(f"{g:28s} {row['codec_total_ms']:7.3f} {row['zmq_round_trip_tcp_ms']:8.3f} "
              f"{row['zmq_round_trip_ipc_ms']:8.3f} {row['stub_sidecar_tcp_ms']:9.3f} {row['stub_sidecar_ipc_ms']:9.3f}"
              f"   {c['client_encode_request']:.3f} / {c['server_decode_request']:.3f} / "
              f"{c['server_encode_reply']:.3f} / {c['client_decode_reply']:.3f}")

    names = [p[0] for p in PROF_PARTS if p[0] != "scene_step"]
    print(f"\nin-situ profile (p50 ms)  {' '.join(f'{n:>8s}' for n in names)} {'overhead':>9s} "
          f"{'work+':>7s} {'added':>7s}   (work+: scene.step in the sidecar - the same step in process)")
    for key, row in results.get("profile", {}).items():
        p = row["parts_p50_ms"]
        print(f"{key:24s}  {' '.join(f'{p[n]:8.3f}' for n in names)} {row['overhead_sum_ms']:9.3f} "
              f"{row['scene_step_minus_inproc_ms']:+7.3f} {row['added_p50_ms']:+7.3f}")

    print("\nwarm boot (ipc, construction -> hello done): " + ", ".join(
        f"{k} median {v['median_s']:.3f} s (min {v['min_s']:.3f}, max {v['max_s']:.3f}; "
        f"interpreter up after {v['to_building_scene_s'] or float('nan'):.3f} s)" for k, v in results.get("boot", {}).items()))
    print(f"sidecars/stubs started: {len(pids)}, still running: {len(orphans)}" + (f" {orphans}" if orphans else ""))

    goals = {}
    for g, limit in GOAL_ADDED_MS.items():
        for w in LOCAL_WAYS:  # the goals are the local fast path's (tcp/ipc: ZeroMQ, for reference)
            if f"{g}/{w}" in results["step"]:
                goals[f"added_p50_{g}_{w}_le_{limit}ms"] = results["step"][f"{g}/{w}"]["added_p50_ms"] <= limit
                if results.get("alone"):
                    goals[f"alone_added_p50_{g}_{w}_le_{limit}ms"] = results["alone"][f"{g}/{w}"]["added_p50_ms"] <= limit
    if "rgb2x256" in results.get("codec", {}):
        goals[f"wire_codec_ge_{GOAL_CODEC_SPEEDUP:g}x_blob_rgb2x256"] = (
            results["codec"]["rgb2x256"]["speedup_wire_vs_blob"] >= GOAL_CODEC_SPEEDUP)
    if "boot" in results:
        goals[f"warm_boot_le_{GOAL_BOOT_S:g}s"] = all(v["median_s"] <= GOAL_BOOT_S for v in results["boot"].values())
    goals["no_orphan_sidecars"] = not orphans
    print("\ngoals: " + ", ".join(f"{k}={'met' if v else 'NOT met'}" for k, v in goals.items()))

    out = Path(args.json)
    out.parent.mkdir(parents=True, exist_ok=True)
    out.write_text(json.dumps({
        "machine": {"python": platform.python_version(), "mujoco": mujoco.__version__, "pyzmq": zmq.__version__,
                    "libzmq": zmq.zmq_version(), "msgpack": ".".join(map(str, msgpack.version)),
                    "numpy": np.__version__, "cpus": os.cpu_count(), "MUJOCO_GL": os.environ.get("MUJOCO_GL")},
        "steps": steps, "rounds": args.rounds, "boots": args.boots, "control_mode": MODE, "layout": LAYOUT,
        "obs_cases": {g: {"cameras": [s.name for s in cs.sensors_of("rgb")] if o.get("render_images") else [],
                          "image_size": o.get("image_size"), "obs_bytes": results["step"][f"{g}/inproc"]["obs_bytes"]}
                      for g, (cs, o) in configs.items()},
        "results": results, "goals": goals, "orphans": orphans,
        "wall_s": time.perf_counter() - t_start,
    }, indent=2))
    print(f"wrote {out} (total {time.perf_counter() - t_start:.0f} s)")
    sys.exit(0)


if __name__ == "__main__":
    main()
