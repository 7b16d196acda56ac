"""Compact step messages on the sidecar's local fast path (``simseam.sidecar.compact``).

The compact request and the templated reply rebuild exactly what the msgpack path gives (same
structure, same Python and numpy types, read-only arrays, images through the ring), step by step
over episodes of a real sidecar and of the real ``Server`` in process; a template change
mid-episode (an info key appearing, the observe request switching between state-only and images,
a reset between steps) is handled; clients that do not ask, and sidecars that do not answer, keep
msgpack; a wrong action length gets the very error it gets over msgpack; malformed compact frames
raise ``WireError`` naming what and where (the fuzzing is in test_local_path.py).
"""

from __future__ import annotations

import os
import threading

import msgpack
import numpy as np
import pytest
from sidecar_util import actions, assert_same, scene_options

from simseam.seam import FULL, STATE_ONLY, ObsRequest
from simseam.sidecar import compact, local
from simseam.sidecar.compact import MAGIC, REPLY_HEAD, ReplyDecoder, ReplyTemplates
from simseam.sidecar.errors import RemoteError
from simseam.sidecar.server import Server
from simseam.sidecar.wire import WireError, decode, encode

HANG_GUARD_S = 10.0
IMG = scene_options(image_size=(64, 64))  # 12 kB per camera: through the ring


def exact(a, b, path="body"):
    """``assert_same`` plus: the same container types, and every array read-only."""
    assert type(a) is type(b), f"{path}: {type(a).__name__} != {type(b).__name__}"
    if isinstance(a, dict):
        assert list(a) == list(b), f"{path}: keys {list(a)} != {list(b)}"
        for k in a:
            exact(a[k], b[k], f"{path}[{k!r}]")
    elif isinstance(a, list):
        assert len(a) == len(b), path
        for i, (x, y) in enumerate(zip(a, b)):
            exact(x, y, f"{path}[{i}]")
    elif isinstance(a, np.ndarray):
        assert not b.flags.writeable, f"{path}: writeable"
        assert_same(a, b, path)
    else:
        assert a == b or (a != a and b != b), f"{path}: {a!r} != {b!r}"


class Pair:
    """A sidecar-side ReplyTemplates and a client-side ReplyDecoder over one ring (or none)."""

    def __init__(self, ring_bytes: int = 0, slots: int = 2, threshold: int = 1024):
        self.ring = local.SlotRing(slots, ring_bytes, threshold) if ring_bytes else None
        self.slots = (local.map_slots(os.dup(self.ring.fd), self.ring.layout()) if self.ring is not None else None)
        self.tx, self.rx = ReplyTemplates(), ReplyDecoder(self.slots)

    def send(self, body):
        frames = [bytes(f) for f in self.tx.encode(body, self.ring)]
        return frames, self.rx.decode(frames)

    def close(self):
        self.slots = self.rx.slots = None
        if self.ring is not None:
            self.ring.close()


def reference(body, slots=None):
    """What the msgpack path gives for ``body``."""
    return decode([bytes(f) for f in encode("ok", body)])[1]


def step_body(rng, images: bool, extra: dict | None = None) -> dict:
    info = {"success": False, "steps": int(rng.integers(0, 100)),
            "diagnostics": {"cube_height": float(rng.standard_normal()), "grasped": bool(rng.integers(0, 2))}}
    info.update(extra or {})
    return {"obs": {"images": ({"camera1": rng.integers(0, 255, (32, 32, 3), dtype=np.uint8),
                                "camera2": rng.integers(0, 255, (32, 32, 3), dtype=np.uint8)} if images else {}),
                    "state": rng.standard_normal(8).astype(np.float32), "task": "lift the red cube",
                    "joint_positions": rng.standard_normal(9).astype(np.float32),
                    "sim_time_ns": int(rng.integers(0, 1 << 40))},
            "reward": float(rng.standard_normal()), "terminated": False, "truncated": bool(rng.integers(0, 2)),
            "info": info}


# ----------------------------------------------------------------------- codec, in process
def test_templated_replies_rebuild_exactly_what_msgpack_gives_and_go_compact_from_the_second():
    p = Pair(ring_bytes=2 * 32 * 32 * 3 + 64)
    try:
        rng = np.random.default_rng(0)
        kinds = []
        for i in range(6):
            body = step_body(rng, images=True)
            frames, (op, got) = p.send(body)
            kinds.append(compact.is_compact(frames))
            assert op == "ok"
            exact(reference(body), got)
            cams = {a.ctypes.data for a in got["obs"]["images"].values()}
            assert all(any(np.shares_memory(a, np.frombuffer(s, np.uint8)) for s in p.slots)
                       for a in got["obs"]["images"].values()), "images must come through the ring"
            assert len(cams) == 2
        assert kinds == [False] + [True] * 5  # announced once, compact after
        # head 8 + scalars 36 (q d ? ? ? q d ?) + pad 4 + state 32 + joint positions 36: the images are in the ring
        assert len(frames) == 1 and len(frames[0]) == 116
        assert (p.tx.announced, p.tx.compact) == (1, 5)
    finally:
        p.close()


AWKWARD = {
    "scalars": {"f": -0.0, "nan": float("nan"), "inf": float("inf"), "i": -(1 << 63), "u": (1 << 63) - 1, "b": True,
                "n": None, "s": "héllo", "by": b"\x00\xff"},
    "numpy scalars": {"f32": np.float32(1.5), "i8": np.int8(-3), "b": np.bool_(True), "u64": np.uint64(7)},
    "arrays": {"0d": np.array(3.5), "empty": np.zeros((0, 3), np.int16), "bool": np.array([True, False]),
               "i64": np.arange(5, dtype=np.int64), "f16": np.ones((2, 2), np.float16),
               "strided": np.arange(20, dtype=np.float64)[::3], "fortran": np.asfortranarray(np.eye(3, dtype=np.float32))},
    "lists": {"l": [1, 2.5, "x", None, [True, {"deep": np.arange(3, dtype=np.uint8)}]], "t": (1, (2, 3)), "e": []},
    "nested": {"a": {"b": {"c": {"d": {}}}}},
    "top-level list": [1.0, {"x": np.zeros(2, np.float32)}],
    "top-level scalar": 4.25,
}


@pytest.mark.parametrize("name", list(AWKWARD))
def test_awkward_bodies_round_trip_exactly_both_ways(name):
    p = Pair(ring_bytes=4096, threshold=64)
    try:
        body = AWKWARD[name]
        for _ in range(3):
            frames, (op, got) = p.send(body)
            exact(reference(body), got)
        assert compact.is_compact(frames)
        if name == "lists":  # lists come back as fresh lists every time (callers may mutate them)
            assert p.send(body)[1][1]["l"] is not got["l"]
    finally:
        p.close()


def test_a_template_change_announces_a_new_template_and_known_ones_stay_compact():
    p = Pair(ring_bytes=2 * 32 * 32 * 3 + 64)
    try:
        rng = np.random.default_rng(1)
        seq = [("state", {}), ("state", {}), ("images", {}), ("state", {}), ("images", {}),
               ("state", {"extra": 1.0}), ("state", {"extra": 2.0}), ("state", {}),  # an info key appears, goes
               ("state", {"extra": "text"}), ("state", {"extra": "other text"})]  # a str value is in the template
        announced = []
        for kind, extra in seq:
            body = step_body(rng, images=kind == "images", extra=extra)
            frames, (_op, got) = p.send(body)
            exact(reference(body), got)
            announced.append(not compact.is_compact(frames))
        assert announced == [True, False, True, False, False, True, False, False, True, True]
    finally:
        p.close()


def test_templates_beyond_the_limit_are_forgotten_on_both_sides_alike():
    p = Pair()
    try:
        bodies = [{"k": float(i), f"key{i}": i} for i in range(compact.MAX_TEMPLATES + 1)]
        for b in bodies:
            assert not compact.is_compact(p.send(b)[0])
        assert len(p.rx.templates) == compact.MAX_TEMPLATES and 0 not in p.rx.templates
        frames, (_op, got) = p.send(bodies[0])  # its template was the oldest: announced again
        assert not compact.is_compact(frames) and got == bodies[0]
        frames, (_op, got) = p.send(bodies[-1])
        assert compact.is_compact(frames) and got == bodies[-1]
    finally:
        p.close()


def test_bodies_without_a_template_travel_as_msgpack():
    p = Pair()
    try:
        for body in ({1: 2.0}, {"be": np.arange(3, dtype=">f4")}, {"o": object()}):
            if "o" in body:
                with pytest.raises(WireError):  # what msgpack says, unchanged
                    p.tx.encode(body)
                continue
            for _ in range(2):
                frames, (_op, got) = p.send(body)
                assert not compact.is_compact(frames)
                exact(reference(body), got)
        # an int beyond int64 (msgpack's uint64) under a known template: that reply is msgpack, the next compact again
        p.send({"n": 1})
        frames, (_op, got) = p.send({"n": 1 << 63})
        assert not compact.is_compact(frames) and got == {"n": 1 << 63}
        frames, (_op, got) = p.send({"n": -5})
        assert compact.is_compact(frames) and got == {"n": -5}
    finally:
        p.close()


def test_ring_plan_is_where_put_puts_arrays():
    ring = local.SlotRing(2, 4096, threshold=100)
    try:
        sizes = [50, 100, 1000, 3000, 64, 2000, 200]
        ring.begin()
        got = [ring.put(np.zeros(n, np.uint8)) if n >= ring.threshold else None for n in sizes]  # as wire.encode
        assert got.count(None) == 3  # two below the threshold, one that no longer fits
        assert compact.ring_plan(ring, sizes) == [None if g is None else g[1] for g in got]
        assert compact.ring_plan(None, sizes) == [None] * len(sizes)
    finally:
        ring.close()


def test_compact_step_requests_round_trip():
    a = np.array([0.5, -1.0, np.float32(1e-30), 3.0], np.float32)
    for state_only in (False, True):
        (frame,) = compact.encode_step(a, state_only)
        got, so = compact.decode_step([memoryview(bytearray(frame))])
        assert so is state_only and got.dtype == np.float32 and np.array_equal(got, a) and not got.flags.writeable
    assert compact.decode_step(compact.encode_step(np.zeros(0, np.float32), False))[0].shape == (0,)


def _good_reply(p: Pair) -> bytes:
    body = {"x": 1.5, "arr": np.arange(4, dtype=np.float32), "img": np.ones((16, 16, 3), np.uint8)}
    p.send(body)
    frames, _ = p.send(body)
    assert compact.is_compact(frames)
    return frames[0]


def _patched(frame: bytes, **head) -> bytes:
    fields = dict(zip(("magic", "op", "slot", "zero", "tid"), REPLY_HEAD.unpack_from(frame)))
    fields.update(head)
    return REPLY_HEAD.pack(*fields.values()) + frame[REPLY_HEAD.size:]


@pytest.mark.parametrize("name, mutate, expect", [
    ("truncated", lambda f: f[:-1], "bytes, the template needs"),
    ("extended", lambda f: f + b"\0", "bytes, the template needs"),
    ("only the head", lambda f: f[:REPLY_HEAD.size], "bytes, the template needs"),
    ("shorter than the head", lambda f: f[:5], "shorter than its 8-byte head"),
    ("unknown template", lambda f: _patched(f, tid=7), "unknown template id 7 (known: [0])"),
    ("slot out of range", lambda f: _patched(f, slot=2), "slot 2 is out of range (the ring has 2 slots)"),
    ("wrong op", lambda f: _patched(f, op=1), "compact reply: op 1"),
    ("reserved byte", lambda f: _patched(f, zero=9), "reserved byte 9"),
])
def test_malformed_compact_replies_raise_wire_error_naming_the_problem(name, mutate, expect):
    p = Pair(ring_bytes=1024, threshold=512)
    try:
        frame = _good_reply(p)
        with pytest.raises(WireError) as ei:
            p.rx.decode([mutate(frame)])
        assert expect in str(ei.value), (name, str(ei.value))
        with pytest.raises(WireError, match="2 frames, expected 1"):
            p.rx.decode([frame, b""])
        p.rx.slots = p.slots[:1]  # fewer slots mapped than the frame names
        with pytest.raises(WireError, match="slot 1 is out of range"):
            p.rx.decode([_patched(frame, slot=1)])
        p.rx.slots = [memoryview(bytearray(256))] * 2  # slots smaller than the template's ring arrays
        with pytest.raises(WireError, match=r"ring arrays end at byte 768, slot \d has 256"):
            p.rx.decode([frame])
    finally:
        p.close()


def test_a_slot_named_by_a_template_without_ring_arrays_is_refused():
    p = Pair()
    try:
        p.send({"x": 1.0})
        frames, _ = p.send({"x": 2.0})
        with pytest.raises(WireError, match="names ring slot 1 but the template has no ring arrays"):
            p.rx.decode([_patched(frames[0], slot=1)])
    finally:
        p.close()


@pytest.mark.parametrize("name, tpl, op, expect", [
    ("not an int", "3", "ok", "header field 'tpl' must be a template id"),
    ("a bool", True, "ok", "header field 'tpl' must be a template id"),
    ("negative", -1, "ok", "header field 'tpl' must be a template id"),
    ("too large", 1 << 32, "ok", "header field 'tpl' must be a template id"),
    ("on an error reply", 0, "error", "announced by an 'error' reply"),
])
def test_a_malformed_template_announcement_raises_wire_error(name, tpl, op, expect):
    header = msgpack.packb({"v": 3, "op": op, "body": {"x": 1.0}, "arrays": [], "tpl": tpl}, use_bin_type=True)
    with pytest.raises(WireError) as ei:
        ReplyDecoder().decode([header])
    assert expect in str(ei.value), (name, str(ei.value))


def test_an_announcement_with_a_value_no_template_describes_is_refused():
    header = msgpack.packb({"v": 3, "op": "ok", "body": {"t": msgpack.ExtType(5, b"x")}, "arrays": [], "tpl": 0},
                           use_bin_type=True)
    with pytest.raises(WireError, match="template 0: a value of type ExtType cannot be templated"):
        ReplyDecoder().decode([header])


@pytest.mark.parametrize("name, frame, expect", [
    ("short", bytes([MAGIC, 1, 0]), "3 bytes, shorter than its 4-byte head"),
    ("wrong op", bytes([MAGIC, 2, 0, 0]) + bytes(4), "op 2"),
    ("observe kind", bytes([MAGIC, 1, 2, 0]) + bytes(4), "observe kind 2"),
    ("reserved byte", bytes([MAGIC, 1, 0, 1]) + bytes(4), "reserved byte 1"),
    ("ragged action", bytes([MAGIC, 1, 0, 0]) + bytes(6), "6 action bytes, not a whole number of float32"),
    ("huge action", bytes([MAGIC, 1, 0, 0]) + bytes(4 * 4097), "16388 action bytes"),
])
def test_malformed_compact_requests_raise_wire_error_naming_the_problem(name, frame, expect):
    with pytest.raises(WireError) as ei:
        compact.decode_step([frame])
    assert expect in str(ei.value), (name, str(ei.value))
    with pytest.raises(WireError, match="2 frames"):
        compact.decode_step([frame, b""])


# ------------------------------------------------------------ the real Server, in process
class InfoGrows:
    """A scene whose step info gains a key from step 3 on (a template change mid-episode)."""

    def __init__(self, scene):
        self.scene, self.spec = scene, scene.spec

    def reset(self, seed, request=None):
        self.n = 0
        return self.scene.reset(seed, request)

    def step(self, action, request=None):
        r = self.scene.step(action, request)
        self.n += 1
        if self.n >= 3:
            r.info["late"] = self.n
        return r

    def render(self):
        return self.scene.render()


def _attached(server: Server, want_compact: bool):
    reply, fds = server.attach(encode("attach", {"token": server.token, "compact": 1 if want_compact else 0}))
    op, body = decode(reply)
    assert op == "ok", body
    slots = local.map_slots(os.dup(fds[0]), body["ring"]) if fds else None  # (the fd is the ring's own)
    return body, slots


def test_the_server_in_process_serves_compact_and_msgpack_alike_through_a_template_change(make_scene, panda_spec):
    servers, decoders = [], []
    for want in (True, False):
        s = Server(InfoGrows(make_scene(panda_spec, "lift_cube", image_size=(32, 32))), "t" * 32, "x")
        body, slots = _attached(s, want)
        assert body.get("compact") == (1 if want else None)
        servers.append(s)
        decoders.append((ReplyDecoder(slots), slots))
    try:
        requests = [None, STATE_ONLY, STATE_ONLY, None, ObsRequest(images=frozenset({"camera2"})), STATE_ONLY, STATE_ONLY]
        for s, (dec, slots) in zip(servers, decoders):
            op, _ = dec.decode(s.handle(encode("reset", {"seed": 3}), s.ring, attached=True)[0])
            assert op == "ok"
        kinds = []
        for i, (a, want) in enumerate(zip(actions(seed=4, n=len(requests), dim=7), requests)):
            got = []
            for s, (dec, slots) in zip(servers, decoders):
                if s.templates is not None and (want is None or want == STATE_ONLY):
                    frames = compact.encode_step(a, want is not None)
                else:
                    frames = encode("step", {"action": a, **({"observe": want.to_json()} if want else {})})
                reply, _stop = s.handle([bytes(f) for f in frames], s.ring, attached=True)
                if s.templates is not None:
                    kinds.append(compact.is_compact(reply))
                else:
                    assert not compact.is_compact(reply)
                got.append(dec.decode([bytes(f) for f in reply]))
            (op1, b1), (op2, b2) = got
            assert op1 == op2 == "ok", (b1, b2)
            exact(b2, b1, f"step {i}")
            assert ("late" in b1["info"]) == (i >= 2)
        # step 0 announces (full), 1 announces (state-only), 2 announces (the info key appears), 3 announces
        # (full + late), 4 is msgpack both ways (a camera subset), 5 is compact (state-only + late: known)
        assert kinds == [False, False, False, False, False, True, True]
    finally:
        for s in servers:
            s.detach()


def test_attach_negotiates_compact_by_version_and_refuses_a_bad_one(make_scene, panda_spec):
    s = Server(make_scene(panda_spec, "lift_cube", render_images=False), "t" * 32, "x")
    try:
        for asked, granted in ((0, None), (1, 1), (7, 1)):  # a newer client's version: the sidecar speaks 1
            op, body = decode(s.attach(encode("attach", {"token": s.token, "compact": asked}))[0])
            assert op == "ok" and body.get("compact") == granted and (s.templates is not None) == bool(granted)
        for bad in (True, -1, "1", 1.0):
            op, body = decode(s.attach(encode("attach", {"token": s.token, "compact": bad}))[0])
            assert (op, body["kind"]) == ("error", "WireError") and "attach: compact must be a version number" in \
                body["message"], body
        assert s.templates is not None  # a refused attach leaves the attached client as it was
    finally:
        s.detach()
    assert s.templates is None


def test_a_compact_frame_where_none_was_negotiated_gets_a_wire_error_reply(make_scene, panda_spec):
    s = Server(make_scene(panda_spec, "lift_cube", render_images=False), "t" * 32, "x")
    _attached(s, want_compact=False)
    frames = compact.encode_step(np.zeros(7, np.float32), True)
    for attached in (True, False):  # the local socket without compact, and the ZeroMQ socket
        reply, stop = s.handle(frames, s.ring, attached=attached)
        op, body = decode(reply)
        assert (op, body["kind"], stop) == ("error", "WireError", False) and "not valid msgpack" in body["message"]
    s.detach()


# ------------------------------------------------------------------- real sidecars
def _same_step(got, exp, where):
    assert_same(got.observation, exp.observation, f"{where}: obs")
    assert (got.reward, got.terminated, got.truncated) == (exp.reward, exp.terminated, exp.truncated), where
    assert type(got.reward) is float
    assert_same(got.info, exp.info, f"{where}: info")


@pytest.mark.parametrize("options", [scene_options(render_images=False), IMG], ids=["state", "images"])
def test_compact_and_msgpack_sidecars_give_identical_episodes(make_sidecar, make_scene, panda_spec, options):
    fast = make_sidecar(options=options, spin_us=0)
    slow = make_sidecar(options=options, spin_us=0, compact=False)
    assert fast.fast and fast.compact and slow.fast and not slow.compact
    opts = {k: v for k, v in options.items()}
    opts["image_size"] = tuple(opts["image_size"])
    ref = make_scene(panda_spec, "lift_cube", **opts)
    images = bool(options["render_images"])
    requests = [None, None, STATE_ONLY, STATE_ONLY, FULL, ObsRequest(images=frozenset({"camera1"}), depth=False),
                STATE_ONLY, None] * 3
    for ep, seed in enumerate((11, 12)):
        exp = ref.reset(seed)
        for r in (fast, slow):
            assert_same(r.reset(seed), exp)
        for i, (a, want) in enumerate(zip(actions(seed=ep, n=len(requests), dim=7), requests)):
            exp = ref.step(a, want)
            for r in (fast, slow):
                got = r.step(a, want)
                _same_step(got, exp, f"episode {ep} step {i} ({'compact' if r.compact else 'msgpack'})")
                if images and want is None:
                    assert any(np.shares_memory(got.observation["images"]["camera1"], np.frombuffer(s, np.uint8))
                               for s in r._slots), "images through the ring"
    assert np.array_equal(fast.render(), ref.render())
    used = fast._request("close", {})
    # every reply but each structure's first (its announcement: reset, full, state-only, camera subset,
    # render, close) travelled compact
    assert used["requests"] >= 51 and used["compact"] >= used["requests"] - 6, used
    assert slow._request("close", {})["compact"] == 0


def test_a_wrong_action_length_gets_the_same_error_compact_or_not(make_sidecar):
    r = make_sidecar(options=scene_options(render_images=False), spin_us=0)
    assert r.compact
    r.reset(seed=0)
    errors = []
    for frames in (compact.encode_step(np.zeros(6, np.float32), True),
                   encode("step", {"action": np.zeros(6, np.float32), "observe": STATE_ONLY.to_json()})):
        with pytest.raises(RemoteError) as ei:
            r._request("step", None, frames=frames)
        errors.append((type(ei.value), ei.value.kind, ei.value.remote_message))
    assert errors[0] == errors[1] and errors[0][1] == "InvalidActionError", errors
    assert errors[0][2] == "action has shape (6,), expected (7,)"
    assert r.step(np.zeros(7, np.float32), STATE_ONLY).info["steps"] == 1  # and the sidecar goes on


def test_a_client_that_does_not_ask_keeps_msgpack_on_the_local_path(make_sidecar):
    """What an older client does: attach without 'compact'; every reply is plain msgpack."""
    r = make_sidecar(options=IMG, spin_us=0)
    r.reset(seed=0)
    path = os.path.join(os.path.dirname(r.endpoint[len("ipc://"):]), "local.sock")
    chan = local.LocalChannel(path, r._token, spin_us=0, timeout=HANG_GUARD_S)  # compact not asked
    try:
        assert not chan.compact
        for i in range(3):
            chan.send_multipart(encode("step", {"action": np.zeros(7, np.float32), "observe": STATE_ONLY.to_json()}))
            assert chan.poll(int(HANG_GUARD_S * 1000))
            frames = chan.recv_multipart()
            assert not compact.is_compact(frames)
            op, body = decode(frames, chan.slots)
            assert op == "ok" and body["info"]["steps"] == i + 1, body
    finally:
        chan.close()
    r._sock = None  # the sidecar dropped the first connection for ours


def test_a_sidecar_that_does_not_answer_compact_keeps_the_client_on_msgpack(tmp_path):
    """What an older sidecar does: its attach reply has no 'compact'."""
    from simseam.sidecar.server import local_listener

    path = str(tmp_path / "local.sock")
    lsock = local_listener(path)
    lsock.settimeout(HANG_GUARD_S)
    seen = {}

    def old_sidecar():
        conn, _ = lsock.accept()
        with conn:
            frames, _ = local.recv_message(conn)
            seen["attach"] = decode(frames)[1]
            local.send_message(conn, encode("ok", {"ring": None}))
            frames, _ = local.recv_message(conn)
            seen["request"] = frames
            local.send_message(conn, encode("ok", {"x": 1.0}))

    t = threading.Thread(target=old_sidecar, daemon=True)
    t.start()
    try:
        chan = local.LocalChannel(path, "t" * 32, spin_us=0, timeout=HANG_GUARD_S, compact=True)
        try:
            assert seen["attach"]["compact"] == compact.COMPACT_VERSION and not chan.compact
            chan.send_multipart(encode("step", {"action": np.zeros(2, np.float32)}))
            assert chan.poll(int(HANG_GUARD_S * 1000))
            assert decode(chan.recv_multipart()) == ("ok", {"x": 1.0})
        finally:
            chan.close()
        t.join(HANG_GUARD_S)
        assert not t.is_alive()
    finally:
        lsock.close()


def test_a_reply_dropped_after_a_timeout_still_teaches_its_template(make_sidecar):
    """The stale reply to a timed-out step announced the state-only template; the client drops the
    reply but keeps the template, so the following compact replies decode."""
    r = make_sidecar(options=scene_options(render_images=False), env={"SIMSEAM_SIDECAR_TEST_HOOKS": "1"}, spin_us=0)
    assert r.compact
    r.reset(seed=0)
    r.request_timeout = 0.2
    from simseam.sidecar.errors import SidecarTimeout

    with pytest.raises(SidecarTimeout):
        r._request("_sleep", {"seconds": 1.0})  # its reply, {} (a new template), arrives late and is dropped
    r.request_timeout = 30.0
    known = set(r._decoder.templates)
    for i in range(3):
        assert r.step(np.zeros(7, np.float32), STATE_ONLY).info["steps"] == i + 1
    assert len(r._decoder.templates) == len(known) + 2  # {} (learnt from the dropped reply) and the step's
    assert r._request("_sleep", {"seconds": 0.0}) == {}  # compact now: its template was learnt
    assert r._request("close", {})["compact"] >= 3


def test_the_codec_modules_import_only_the_standard_library_numpy_and_msgpack():
    """wire, local and compact run in any sidecar interpreter: nothing of simseam beyond them, no ZeroMQ."""
    import subprocess
    import sys

    code = ("import sys, simseam.sidecar.wire, simseam.sidecar.local, simseam.sidecar.compact\n"
            "print(','.join(sorted(m for m in sys.modules if m.startswith(('simseam.', 'zmq', 'pydantic')))))")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout.strip()
    assert out.split(",") == ["simseam.sidecar", "simseam.sidecar.compact", "simseam.sidecar.local",
                              "simseam.sidecar.wire"], out
