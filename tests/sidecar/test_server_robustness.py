"""A real sidecar under hostile input: a second, raw ZeroMQ peer sends garbage.

Every malformed, unauthenticated or fuzzed message gets a typed error reply (never a
crash, never silence), and the real client's episode goes on exactly as if nothing had
happened: its next step gives the observation an undisturbed run gives, and the server's
request counter shows that not one of the hostile messages reached a handler.
"""

from __future__ import annotations

import random

import msgpack
import numpy as np
import pytest
import zmq
from sidecar_util import actions, assert_same, kept, running

from simseam.sidecar.wire import PROTOCOL_VERSION, decode, encode

REPLY_TIMEOUT_MS = 5000


class RawPeer:
    """A REQ socket of its own on the sidecar's endpoint (same user, so the ipc socket opens)."""

    def __init__(self, rollout):
        self.rollout = rollout
        self.ctx = zmq.Context()
        self.sock = self.ctx.socket(zmq.REQ)
        self.sock.setsockopt(zmq.LINGER, 0)
        self.sock.connect(rollout.endpoint)

    def ask(self, frames: list) -> tuple[str, dict]:
        self.sock.send_multipart(frames, copy=True)
        proc = self.rollout._proc
        for _ in range(REPLY_TIMEOUT_MS // 50):
            if self.sock.poll(50):
                return decode(self.sock.recv_multipart())
            if proc.exit_code() is not None:
                break
        pytest.fail(f"no reply to {frames!r:.200} (sidecar exit code {proc.exit_code()}); its stderr:\n"
                    f"{proc.stderr_tail()}")

    def close(self):
        self.sock.close(0)
        self.ctx.term()


@pytest.fixture
def peer_and_rollout(make_sidecar):
    rollout = make_sidecar()
    peer = RawPeer(rollout)
    yield peer, rollout
    peer.close()


def _hdr(**fields) -> bytes:
    return msgpack.packb({"v": PROTOCOL_VERSION, "op": "step", "body": None, "arrays": [], **fields},
                         use_bin_type=True)


def _deep(n: int):
    x = 0
    for _ in range(n):
        x = [x]
    return x


def _hostile_messages(seed: int, n: int, action_dim: int) -> list[tuple[str, list]]:
    """(expected error kind, frames): targeted cases first, then seeded random ones."""
    rng = random.Random(seed)
    good_action = np.zeros(action_dim, dtype="<f4")
    valid = encode("step", {"token": "not-the-token", "action": good_action})
    msgs: list[tuple[str, list]] = [
        ("WireError", [b""]),
        ("WireError", [b"\x00\x01garbage"]),
        ("WireError", [msgpack.packb([1, 2, 3])]),
        ("WireError", [_hdr(v=99)]),
        ("WireError", [msgpack.packb({"v": 1, "body": {}})]),
        ("WireError", [valid[0]]),  # array frame missing
        ("WireError", [valid[0], bytes(valid[1])[:-1]]),  # truncated frame
        ("WireError", [valid[0], bytes(valid[1]) + b"\x00"]),  # oversized frame
        ("WireError", [valid[0], bytes(valid[1]), b"extra"]),  # one frame too many
        ("WireError", [_hdr(body={"action": {"__nd__": 0}}, arrays=[["|O", [action_dim]]]), b"\x00" * 8 * action_dim]),
        ("WireError", [_hdr(body={"action": {"__nd__": 0}}, arrays=[["<c8", [action_dim]]]), b"\x00" * 8 * action_dim]),
        ("WireError", [_hdr(body={"action": {"__nd__": 0}}, arrays=[["<f4", [-1]]]), b""]),
        ("WireError", [_hdr(body={"action": {"__nd__": 3}}, arrays=[["<f4", [1]]]), b"\x00" * 4]),
        ("WireError", [_hdr(body={"a": 1}, arrays=[["<f4", [1]]]), b"\x00" * 4]),  # unreferenced frame
        ("WireError", [_hdr(body={"__nd__": 0}, arrays=[["|u1", [0, 2**63]]]), b""]),  # crashed the server once
        ("WireError", [_hdr(body=_deep(900))]),  # crashed the server once (RecursionError)
        ("WireError", [_hdr(v=_deep(900))]),
        ("AccessDenied", [_hdr(body=None)]),
        ("AccessDenied", [_hdr(body=[1, 2])]),
        ("AccessDenied", [_hdr(body={"action": [0.0] * action_dim})]),  # no token
        ("AccessDenied", valid),  # wrong token
        ("AccessDenied", encode("step", {"token": "é" * 32, "action": good_action})),  # crashed the server once
        ("AccessDenied", encode("step", {"token": 12345, "action": good_action})),
        ("AccessDenied", encode("step", {"token": b"\xff" * 32, "action": good_action})),
        ("AccessDenied", encode("close", {"token": ""})),
        ("AccessDenied", encode("reset", {"token": None, "seed": 1})),
    ]
    while len(msgs) < n:
        kind = rng.randrange(5)
        if kind == 0:  # random bytes, random frame count
            frames = [rng.randbytes(rng.randrange(0, 64)) for _ in range(rng.randrange(1, 4))]
            msgs.append(("", frames))
        elif kind == 1:  # a valid message with bytes flipped or frames cut
            frames = [bytearray(f) for f in valid]
            f = frames[rng.randrange(len(frames))]
            if f and rng.random() < 0.5:
                f[rng.randrange(len(f))] ^= rng.randrange(1, 256)
            else:
                del f[rng.randrange(len(f) + 1):]
            msgs.append(("", [bytes(x) for x in frames]))
        elif kind == 2:  # wrong dtype / size for the announced array
            dt = rng.choice(["<f4", "<f8", "|u1", "<i8", "|O", "<c16", ">f4", "f4", "<f16"])
            nbytes = rng.choice([0, 4 * action_dim - 1, 4 * action_dim, 4 * action_dim + 3, 8 * action_dim])
            msgs.append(("", [_hdr(body={"token": "x", "action": {"__nd__": 0}}, arrays=[[dt, [action_dim]]]),
                              b"\x00" * nbytes]))
        elif kind == 3:  # random msgpack values as the header
            val = rng.choice([None, 1, -1, 2**64 - 1, 1.5, "step", b"\x00", [1, "x"], {"v": 1}, {"op": "step"},
                              {"v": 1, "op": "step", "body": {"token": rng.randbytes(8).hex()}}])
            msgs.append(("", [msgpack.packb(val, use_bin_type=True)]))
        else:  # a well-formed request for a real op, with a random token
            op = rng.choice(["hello", "reset", "step", "render", "close", "_exit", "_sleep"])
            body = {"token": rng.randbytes(16).hex(), "action": good_action, "seed": 1, "code": 1, "seconds": 30,
                    "protocol": PROTOCOL_VERSION}
            msgs.append(("AccessDenied", encode(op, body)))
    return msgs


def _close_and_count(rollout) -> int:
    """Ask the sidecar to exit; its reply carries how many authorized requests it served."""
    return int(rollout._request("close", {}, timeout=30.0)["requests"])


def test_hostile_peer_gets_typed_errors_and_changes_nothing(peer_and_rollout, panda_spec):
    peer, rollout = peer_and_rollout
    acts = actions(seed=21, n=4, dim=rollout.action_dim)
    # the undisturbed run
    rollout.reset(seed=9)
    expected = [kept(rollout.step(a)) for a in acts]  # copies: kept across steps
    # the same episode with ~100 hostile messages in the middle
    rollout.reset(seed=9)
    rollout.step(acts[0])
    rollout.step(acts[1])
    kinds = {}
    msgs = _hostile_messages(seed=1234, n=110, action_dim=rollout.action_dim)
    for want, frames in msgs:
        op, reply = peer.ask(frames)
        assert op == "error", (frames, reply)
        assert reply["kind"] in ("WireError", "AccessDenied"), (frames, reply)
        assert isinstance(reply["message"], str) and reply["message"]
        if want:
            assert reply["kind"] == want, (frames, reply)
        kinds[reply["kind"]] = kinds.get(reply["kind"], 0) + 1
    assert kinds.get("WireError", 0) >= 30 and kinds.get("AccessDenied", 0) >= 15, kinds
    assert running(rollout.pid)
    # the real client goes on as if nothing happened
    for a, exp in zip(acts[2:], expected[2:]):
        got = rollout.step(a)
        assert_same(got.observation, exp.observation)
        assert got.reward == exp.reward and got.info == exp.info
    # hello + 2 resets + 8 steps + the close itself: not one hostile message reached a handler
    assert _close_and_count(rollout) == 1 + 2 + 8 + 1


def test_wire_error_reply_names_the_problem(peer_and_rollout):
    peer, rollout = peer_and_rollout
    op, reply = peer.ask([_hdr(body={"token": rollout._token, "action": {"__nd__": 0}}, arrays=[["<f4", [7]]]),
                          b"\x00" * 27])
    assert (op, reply["kind"]) == ("error", "WireError")
    assert "frame has 27 bytes, <f4(7,) needs 28" in reply["message"]
    op, reply = peer.ask([_hdr(v=7)])
    assert "protocol version 7" in reply["message"]


def test_wrong_token_is_denied_and_changes_nothing(peer_and_rollout):
    peer, rollout = peer_and_rollout
    acts = actions(seed=5, n=3, dim=rollout.action_dim)
    rollout.reset(seed=2)
    expected = [kept(rollout.step(a)) for a in acts]  # copies: kept across steps
    rollout.reset(seed=2)
    rollout.step(acts[0])
    wrong = "0" * len(rollout._token)
    for op, body in [("step", {"action": np.ones(rollout.action_dim, np.float32)}), ("reset", {"seed": 77}),
                     ("close", {}), ("hello", {"protocol": PROTOCOL_VERSION})]:
        kind, reply = peer.ask(encode(op, {**body, "token": wrong}))
        assert (kind, reply["kind"]) == ("error", "AccessDenied"), reply
        assert "token" in reply["message"] and "identity" not in reply  # nothing about the scene leaks
    assert running(rollout.pid)
    for a, exp in zip(acts[1:], expected[1:]):
        assert_same(rollout.step(a).observation, exp.observation)
    assert _close_and_count(rollout) == 1 + 2 + 6 + 1  # hello, 2 resets, 6 steps, close: no denied request counted


def test_unknown_op_and_disabled_test_hooks(peer_and_rollout):
    peer, rollout = peer_and_rollout
    token = rollout._token
    for op in ("frobnicate", "_sleep", "_exit", "STEP"):  # test hooks are off unless the env enables them
        kind, reply = peer.ask(encode(op, {"token": token, "seconds": 30, "code": 9}))
        assert (kind, reply["kind"]) == ("error", "UnknownOp"), reply
        assert repr(op) in reply["message"]
    assert running(rollout.pid)
    rollout.reset(seed=0)
    assert rollout.step(np.zeros(rollout.action_dim, np.float32)).info["steps"] == 1
