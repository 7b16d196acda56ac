"""Compact step messages on the sidecar's local fast path (negotiated at ``attach``).

A msgpack message costs each side a few dozen Python calls (walk the body, build the header,
pack, unpack, replace the markers), and in situ, on caches the other process just used, that
is most of the local path's overhead. The two messages of a step keep one layout step after
step, so on the local path they travel as single binary frames instead:

- **Request** (client -> sidecar): a step whose ``observe`` is None (or ``FULL``, the same) or
  ``STATE_ONLY`` is one frame: ``<B 0xC1><B op 1 = step><B observe: 0 None, 1 STATE_ONLY><B 0>``
  + the action as little-endian float32. Any other request travels as msgpack.
- **Reply** (sidecar -> client), *templated*: the sidecar computes a structural signature of
  each ``ok`` body (keys in order, leaf types, array dtypes and shapes, and the values of
  strings, bytes and None, which belong to the template). The first body of a signature travels
  as the usual msgpack message with the header field ``tpl: <id>``, announcing it; both sides
  keep its template. A later body of the same signature is one frame: ``<B 0xC1><B op 2 =
  reply><B ring slot><B 0><u32 template id>`` + its scalars (``<d`` float, ``<q`` int, ``?``
  bool, in body order) + each inline array's bytes, each 8-byte aligned. Arrays of at least the
  ring's threshold go into the shared-memory ring as before: the frame names the slot, the
  offsets are the template's. The client rebuilds exactly the body ``wire.decode`` gives: the
  same dict structure, Python float / int / bool / str, read-only numpy arrays.

``0xC1`` is the one byte msgpack never uses, so a compact frame is never taken for a msgpack
header, nor the reverse. Template ids only grow; both sides keep the ``MAX_TEMPLATES`` most
recently announced (a request switching between state-only and images, a reset between steps:
each keeps its template). Replies the client drops (their request timed out) still go through
``ReplyDecoder.learn``, so both sides always hold the same templates. A malformed compact frame
(wrong length, unknown template, bad slot, a byte out of place) raises ``WireError`` naming what
and where, never anything else; sizes come from the template the client validated when it was
announced, never from the frame.

The templates themselves are not tied to a frame: ``signature(body)`` (the sending side: the structure,
the scalars, the arrays) and ``learn(body)`` (the receiving side: a ``Skeleton`` that unpacks the scalars
and rebuilds a body around them and the arrays) are what the vector runner's workers use too
(``simseam.runner.vector``), with their replies in a shared-memory block instead of a frame. There a
tuple and a numpy scalar come back as they went (the signature marks them: ``(``, ``n``); here, as
msgpack gives them.

Imports: the standard library, numpy and ``simseam.sidecar.wire`` (numpy + msgpack) only.
"""

from __future__ import annotations

import struct
from typing import Any

import numpy as np

from simseam.sidecar.wire import ALIGN, DTYPES, MAX_DEPTH, WireError, _decode, _repr, encode

COMPACT_VERSION = 1  # what the client asks for at attach, and the sidecar confirms
MAGIC = 0xC1  # the one byte msgpack never uses: a frame starting with it is compact
OP_STEP = 1
OP_REPLY = 2
REQ_HEAD = struct.Struct("<BBBB")  # magic, op, observe kind, 0
REPLY_HEAD = struct.Struct("<BBBBI")  # magic, op, ring slot, 0, template id
MAX_ACTION_DIM = 4096
MAX_TEMPLATES = 16
MAX_TEMPLATE_ID = (1 << 32) - 1
_REQ_HEADS = tuple(REQ_HEAD.pack(MAGIC, OP_STEP, kind, 0) for kind in (0, 1))
_PADS = tuple(bytes(n) for n in range(8))
_CODE = {float: "d", int: "q", bool: "?"}


def _align8(n: int) -> int:
    return (n + 7) & ~7


def is_compact(frames: list) -> bool:
    """Whether a received message is (meant as) a compact frame: its first frame starts with ``MAGIC``."""
    if not frames:
        return False
    first = frames[0]
    return len(first) > 0 and first[0] == MAGIC


# ------------------------------------------------------------------------------ request
def encode_step(action: np.ndarray, state_only: bool) -> list:
    """The frames of a compact step request: ``action`` (float32, already checked by the caller)
    and whether the observation asked for is ``STATE_ONLY`` (else None: everything)."""
    return [_REQ_HEADS[state_only] + action.astype("<f4", copy=False).tobytes()]


def decode_step(frames: list) -> tuple[np.ndarray, bool]:
    """``(action, state_only)`` of a compact step request; ``WireError`` on anything malformed.
    The action is a read-only float32 view of the frame, of whatever length arrived: the scene's
    ``check_action`` judges it, as it does a msgpack request's."""
    if len(frames) != 1:
        raise WireError(f"compact step request: {len(frames)} frames, expected 1")
    frame = frames[0]
    n = len(frame)
    if n < REQ_HEAD.size:
        raise WireError(f"compact step request: {n} bytes, shorter than its {REQ_HEAD.size}-byte head")
    magic, op, kind, zero = REQ_HEAD.unpack_from(frame)
    if magic != MAGIC or op != OP_STEP:
        raise WireError(f"compact step request: head {magic:#04x} op {op}, expected {MAGIC:#04x} op {OP_STEP}")
    if kind > 1 or zero:
        raise WireError(f"compact step request: observe kind {kind}, reserved byte {zero} (expected 0 or 1, and 0)")
    size = n - REQ_HEAD.size
    if size % 4 or size > 4 * MAX_ACTION_DIM:
        raise WireError(f"compact step request: {size} action bytes, not a whole number of float32 "
                        f"(at most {MAX_ACTION_DIM} of them)")
    action = np.frombuffer(frame, dtype="<f4", offset=REQ_HEAD.size)
    action.flags.writeable = False
    return action, kind == 1


# ------------------------------------------------------------------------ sidecar side
class _NoTemplate(Exception):
    """The body holds something no template describes (it travels the general way)."""


_DTYPE_STRS: dict = {}  # dtype -> its wire string, or None when it cannot travel as it is (dtype.str is slow)


def _dtype_str(dt: np.dtype) -> str | None:
    got = _DTYPE_STRS.get(dt, False)
    if got is False:
        got = dt.str if dt.str in DTYPES else None
        if len(_DTYPE_STRS) < 256:
            _DTYPE_STRS[dt] = got
    return got


def _walk(v: Any, sig: Any, scal: Any, arrs: Any, depth: int) -> None:
    """Append ``v``'s signature entries, scalars and arrays (``sig``, ``scal``, ``arrs``: the lists'
    ``append`` methods). A container's common leaves are taken in its own loop, without a call each."""
    t = type(v)
    if t is dict:
        if depth >= MAX_DEPTH:
            raise _NoTemplate
        sig("{")
        sig(len(v))
        for k in v:
            if type(k) is not str:
                raise _NoTemplate
            sig(k)
        items = v.values()
    elif t is list or t is tuple:
        if depth >= MAX_DEPTH:
            raise _NoTemplate
        sig("[" if t is list else "(")
        sig(len(v))
        items = v
    else:
        _leaf(v, sig, scal, arrs, depth)
        return
    for x in items:
        tx = type(x)
        if tx is float:
            sig("d")
            scal(x)
        elif tx is np.ndarray:
            dt = _DTYPE_STRS.get(x.dtype) or _dtype_str(x.dtype)
            if dt is None:  # e.g. big-endian: wire.encode converts it
                raise _NoTemplate
            sig(dt)
            sig(x.shape)
            arrs(x)
        elif tx is bool:
            sig("?")
            scal(x)
        elif tx is int:
            sig("q")
            scal(x)
        elif tx is str or x is None:
            sig("c")
            sig(x)
        else:
            _walk(x, sig, scal, arrs, depth + 1)


def _leaf(v: Any, sig: Any, scal: Any, arrs: Any, depth: int) -> None:
    """``_walk`` of a value that is not a dict, a list or a tuple."""
    t = type(v)
    if t is float:
        sig("d")
        scal(v)
    elif t is bool:
        sig("?")
        scal(v)
    elif t is int:
        sig("q")
        scal(v)
    elif t is np.ndarray:
        dt = _dtype_str(v.dtype)
        if dt is None:
            raise _NoTemplate
        sig(dt)
        sig(v.shape)
        arrs(v)
    elif t is str or t is bytes or v is None:
        sig("c")
        sig(v)
    elif isinstance(v, np.generic):
        item = v.item()  # what msgpack sends; a receiver that learnt a numpy scalar makes one again
        if type(item) not in (float, bool, int, str, bytes):
            raise _NoTemplate
        sig("n")
        sig(v.dtype.str)
        _leaf(item, sig, scal, arrs, depth)
    else:
        raise _NoTemplate


def signature(body: Any) -> tuple[tuple, list, list] | None:
    """``(signature, scalars, arrays)`` of a reply body, the leaves in body order; None when it cannot
    be templated (a key that is not a str, a type neither msgpack nor a ``Skeleton`` takes as it is, an
    array whose dtype must be converted first).

    The signature is a flat tuple that reads one way only (a prefix code), so two bodies of equal
    signatures have one structure: a value is ``{`` + a dict's number of keys + its keys + its values, ``[``
    (a list) or ``(`` (a tuple) + its length + each value, a scalar code (``d``, ``q``, ``?``), ``c`` + a
    constant (str, bytes, None), ``n`` + a numpy scalar's dtype + its value's, or an array's dtype string
    (never one of those markers) + its shape."""
    sig: list = []
    scal: list = []
    arrs: list = []
    try:
        _walk(body, sig.append, scal.append, arrs.append, 0)
    except _NoTemplate:
        return None
    return tuple(sig), scal, arrs


def ring_plan(ring: Any, nbytes: list[int]) -> list[int | None]:
    """Where ``SlotRing.put`` puts arrays of these sizes, in this order, in one message: the offset
    in the slot, or None (inline). The same arithmetic as ``put``: a template's offsets."""
    out: list[int | None] = []
    pos = 0
    for n in nbytes:
        if ring is not None and n >= ring.threshold and pos + n <= ring.slot_bytes:
            out.append(pos)
            pos = (pos + n + ALIGN - 1) // ALIGN * ALIGN  # (SlotRing.put's alignment)
        else:
            out.append(None)
    return out


class _SendTemplate:
    """Sidecar side: how to pack a body of one signature."""

    __slots__ = ("tid", "scalars", "plan", "ring_arrays")

    def __init__(self, tid: int, scal: list, arrs: list, ring: Any):
        self.tid = tid
        self.scalars = struct.Struct("<" + "".join(_CODE[type(x)] for x in scal))
        offsets = ring_plan(ring, [a.nbytes for a in arrs])
        self.plan = []  # per array: (True, its offset in the slot) or (False, the padding before it)
        pos = REPLY_HEAD.size + self.scalars.size
        for a, off in zip(arrs, offsets):
            if off is not None:
                self.plan.append((True, off))
            else:
                pad = _align8(pos) - pos
                self.plan.append((False, pad))
                pos += pad + a.nbytes
        self.ring_arrays = any(off is not None for off in offsets)

    def pack(self, scal: list, arrs: list, ring: Any) -> bytes:
        """The compact frame; ``struct.error`` (before anything is written) when a scalar does not fit
        its code (an int beyond 64 bits)."""
        parts = [b"", self.scalars.pack(*scal)]
        slot = 0
        if self.ring_arrays:
            ring.begin()
        for a, (in_ring, x) in zip(arrs, self.plan):
            if in_ring:
                place = ring.put(a)
                if place is None or place[1] != x:  # ring_plan and put disagree: a bug, never silent
                    raise RuntimeError(f"compact reply: array {a.dtype}{a.shape} went to {place} in the ring, "
                                       f"its template says offset {x}")
                slot = place[0]
            else:
                if x:
                    parts.append(_PADS[x])
                parts.append(a.tobytes())
        parts[0] = REPLY_HEAD.pack(MAGIC, OP_REPLY, slot, 0, self.tid)
        return b"".join(parts)


class ReplyTemplates:
    """Sidecar side, one per local connection that negotiated compact messages: ``encode(body,
    ring)`` gives the frames of an ``ok`` reply, compact when its template is known to the client."""

    def __init__(self, max_templates: int = MAX_TEMPLATES):
        self.max_templates = max_templates
        self._by_sig: dict[tuple, _SendTemplate] = {}
        self._next_id = 0
        self.compact = 0  # replies sent compact
        self.announced = 0  # templates announced

    def encode(self, body: Any, ring: Any = None) -> list:
        walked = signature(body)
        if walked is None:
            return encode("ok", body, ring)
        sig, scal, arrs = walked
        tpl = self._by_sig.get(sig)
        if tpl is not None:
            try:
                frame = tpl.pack(scal, arrs, ring)
            except struct.error:  # an int beyond 64 bits: plain msgpack, this once
                return encode("ok", body, ring)
            self.compact += 1
            return [frame]
        tid = self._next_id
        frames = encode("ok", body, ring, tpl=tid)  # raises (nothing kept) when the body cannot travel
        self._next_id = (tid + 1) & MAX_TEMPLATE_ID
        if len(self._by_sig) >= self.max_templates:  # the oldest goes, on both sides (ReplyDecoder)
            del self._by_sig[next(iter(self._by_sig))]
        self._by_sig[sig] = _SendTemplate(tid, scal, arrs, ring)
        self.announced += 1
        return frames


# ------------------------------------------------------------------------- client side
_VALUE, _CONST, _DICT, _LIST, _TUPLE, _CAST = range(6)


MAX_COMPILED_NODES = 512  # a larger template is rebuilt by walking its tree (compiling it would cost more)


def _build_dict(node: tuple, vals: list) -> dict:
    out = {}
    for k, kind, x in node:
        out[k] = vals[x] if kind == _VALUE else x if kind == _CONST else _build(kind, x, vals)
    return out


def _build(kind: int, x: Any, vals: list) -> Any:
    """The value of one node of a template's tree, from ``vals`` (its scalars, then its arrays)."""
    if kind == _VALUE:
        return vals[x]
    if kind == _CONST:
        return x
    if kind == _DICT:
        return _build_dict(x, vals)
    if kind == _LIST:
        return [_build(k, y, vals) for k, y in x]
    if kind == _TUPLE:
        return tuple(_build(k, y, vals) for k, y in x)
    index, numpy_type = x  # _CAST: a numpy scalar
    return numpy_type(vals[index])


def _tree_builder(root: tuple) -> Any:
    """``build(s, a)`` for a template too large to compile (``_builder``): a walk of its tree."""
    return lambda s, a: _build(*root, [*s, *a])


def _builder(root: tuple, n_scalars: int) -> Any:
    """A function ``build(s, a)`` that returns a fresh body of ``root``'s structure from the scalars ``s``
    and the arrays ``a``: one Python expression of literals (a dict, list or tuple display per container),
    compiled once per template, so a reply costs no walk of the structure. Keys, constants and numpy
    scalar types enter it as default arguments (``_0``, ``_1``, ...): nothing of the body's text becomes
    source code."""
    env: dict[str, Any] = {}

    def name(obj: Any) -> str:
        if type(obj) is str or obj is None:  # (repr of a str is a literal that makes an equal str)
            return repr(obj)
        n = f"_{len(env)}"
        env[n] = obj
        return n

    def expr(kind: int, x: Any) -> str:
        if kind == _VALUE:
            return f"s[{x}]" if x < n_scalars else f"a[{x - n_scalars}]"
        if kind == _CONST:
            return name(x)
        if kind == _DICT:
            return "{" + "".join(f"{name(k)}: {expr(kk, xx)}, " for k, kk, xx in x) + "}"
        if kind == _LIST:
            return "[" + "".join(expr(*e) + ", " for e in x) + "]"
        if kind == _TUPLE:
            return "(" + "".join(expr(*e) + ", " for e in x) + ")"
        index, numpy_type = x  # _CAST: a numpy scalar
        return f"{name(numpy_type)}({expr(_VALUE, index)})"

    body = expr(*root)
    code = f"def build(s, a{''.join(f', {n}={n}' for n in env)}):\n    return {body}\n"
    scope: dict[str, Any] = {}
    exec(compile(code, "<simseam template>", "exec"), {"__builtins__": {}, **env}, scope)  # noqa: S102
    return scope["build"]


class Skeleton:
    """The receiving side of a template, learnt from one body of its signature (``learn``): ``scalars``
    (a ``struct.Struct`` of the body's scalars in body order: ``<d`` float, ``<q`` int, ``?`` bool),
    ``arrays`` (``(dtype, shape)`` of its arrays in body order) and ``build(scalars, arrays)``: a fresh
    body of that structure around them (fresh dicts, lists and tuples each time: callers may change
    them)."""

    __slots__ = ("scalars", "arrays", "build")

    def __init__(self, codes: list[str], arrays: list, root: tuple, nodes: int):
        self.scalars, self.arrays = struct.Struct("<" + "".join(codes)), arrays
        self.build = _builder(root, len(codes)) if nodes <= MAX_COMPILED_NODES else _tree_builder(root)


def learn(body: Any, where: str = "template") -> tuple[Skeleton, list[np.ndarray]]:
    """The ``Skeleton`` of ``body``'s template, and the body's arrays in body order (for the caller to
    tell where each one travels). ``WireError`` naming ``where`` on a value no template describes."""
    codes: list[str] = []
    arrays: list[np.ndarray] = []

    nodes = 0

    def leaf(v: Any) -> tuple:  # (kind, x); a value's x: ("s" | "a", its index among scalars | arrays)
        nonlocal nodes
        nodes += 1
        t = type(v)
        if t is dict:
            return _DICT, tuple((k, *leaf(x)) for k, x in v.items())
        if t is list or t is tuple:
            return _LIST if t is list else _TUPLE, tuple(leaf(x) for x in v)
        if t in _CODE:
            codes.append(_CODE[t])
            return _VALUE, ("s", len(codes) - 1)
        if t is np.ndarray:
            arrays.append(v)
            return _VALUE, ("a", len(arrays) - 1)
        if t is str or t is bytes or v is None:
            return _CONST, v
        if isinstance(v, np.generic):
            item = v.item()
            if type(item) in _CODE:
                return _CAST, (leaf(item)[1], t)
            if type(item) in (str, bytes):
                return _CONST, v
        raise WireError(f"{where}: a value of type {t.__name__} cannot be templated")

    root = leaf(body)
    n_s = len(codes)

    def index(node: tuple) -> tuple:  # ("s" | "a", k) -> the index in [*scalars, *arrays]
        kind, x = node
        if kind == _VALUE:
            return kind, x[1] + (0 if x[0] == "s" else n_s)
        if kind == _CAST:
            return kind, (index((_VALUE, x[0]))[1], x[1])
        if kind == _DICT:
            return kind, tuple((k, *index((kk, xx))) for k, kk, xx in x)
        if kind in (_LIST, _TUPLE):
            return kind, tuple(index(e) for e in x)
        return node

    skeleton = Skeleton(codes, [(a.dtype, a.shape) for a in arrays], index(root), nodes)
    return skeleton, arrays


class _RecvTemplate:
    """Client side: how to read a compact frame of one template (its ``Skeleton``: the scalars, then
    each array inline in the frame or in the ring slot), and rebuild its body."""

    __slots__ = ("tid", "skeleton", "scalars", "arrays", "ring", "ring_end", "nbytes")

    def __init__(self, tid: int, body: Any, arrays: list, shm: list, shm_specs: list):
        self.tid = tid
        where = f"template {tid}"
        self.skeleton, in_body = learn(body, where)
        self.scalars = self.skeleton.scalars
        shm_at = {id(a): i for i, a in enumerate(shm)}
        inline_at = {id(a) for a in arrays}
        slots_used = set()
        pos = REPLY_HEAD.size + self.scalars.size
        self.arrays = []  # per array, in body order: (dtype, shape, count, offset, reshape, in the ring)
        self.ring_end = 0
        for v in in_body:
            j = shm_at.get(id(v))
            if j is not None:
                _dt, _shape, slot, off = shm_specs[j]
                slots_used.add(slot)
                self.ring_end = max(self.ring_end, off + v.nbytes)
            elif id(v) in inline_at:
                off = pos = _align8(pos)
                pos += v.nbytes
            else:  # pragma: no cover - decode's arrays are its frames' or its slots'
                raise WireError(f"{where}: an array that is neither inline nor in the ring")
            self.arrays.append((v.dtype, v.shape, v.size, off, len(v.shape) != 1, j is not None))
        if len(slots_used) > 1:
            raise WireError(f"{where}: its ring arrays lie in {len(slots_used)} slots (one reply, one slot)")
        self.ring = bool(slots_used)
        self.nbytes = pos

    def read(self, frame: Any, slot: int, slots: list | None) -> Any:
        where = f"compact reply (template {self.tid})"
        if len(frame) != self.nbytes:
            raise WireError(f"{where}: {len(frame)} bytes, the template needs {self.nbytes}")
        mem = None
        if self.ring:
            if slots is None or slot >= len(slots):
                raise WireError(f"{where}: slot {slot} is out of range (the ring has {len(slots or ())} slots)")
            mem = slots[slot]
            if self.ring_end > mem.nbytes:
                raise WireError(f"{where}: its ring arrays end at byte {self.ring_end}, slot {slot} has {mem.nbytes}")
        elif slot:
            raise WireError(f"{where}: names ring slot {slot} but the template has no ring arrays")
        arrays = []
        for dtype, shape, count, off, reshape, in_ring in self.arrays:
            a = np.frombuffer(mem if in_ring else frame, dtype, count, off)
            if reshape:
                a = a.reshape(shape)
            a.flags.writeable = False
            arrays.append(a)
        return self.skeleton.build(self.scalars.unpack_from(frame, REPLY_HEAD.size), arrays)

class ReplyDecoder:
    """Client side, one per local connection that negotiated compact messages: ``decode(frames)``
    reads a compact frame or a msgpack message (``wire.decode``), learning the templates the latter
    announce. ``slots``: the ring's slots (memoryviews), if any."""

    def __init__(self, slots: list | None = None, max_templates: int = MAX_TEMPLATES):
        self.slots = slots
        self.max_templates = max_templates
        self.templates: dict[int, _RecvTemplate] = {}

    def decode(self, frames: list) -> tuple[str, Any]:
        if frames and len(frames[0]) > 0 and frames[0][0] == MAGIC:
            if len(frames) != 1:
                raise WireError(f"compact reply: {len(frames)} frames, expected 1")
            frame = frames[0]
            if len(frame) < REPLY_HEAD.size:
                raise WireError(f"compact reply: {len(frame)} bytes, shorter than its {REPLY_HEAD.size}-byte head")
            _magic, op, slot, zero, tid = REPLY_HEAD.unpack_from(frame)
            if op != OP_REPLY or zero:
                raise WireError(f"compact reply: op {op}, reserved byte {zero} (expected {OP_REPLY} and 0)")
            tpl = self.templates.get(tid)
            if tpl is None:
                raise WireError(f"compact reply: unknown template id {tid} (known: {sorted(self.templates)})")
            return "ok", tpl.read(frame, slot, self.slots)
        header, op, body, arrays, shm = _decode(frames, self.slots)
        tid = header.get("tpl")
        if tid is not None:
            self._learn(tid, op, body, arrays, shm, header.get("shm") or [])
        return op, body

    def learn(self, frames: list) -> None:
        """A reply that is dropped (its request timed out): keep the template it may announce, so the
        next compact frames are read as the sidecar meant them. A malformed one is ignored (a
        compact frame naming a template it failed to announce then fails as unknown)."""
        try:
            self.decode(frames)
        except WireError:
            pass

    def _learn(self, tid: Any, op: str, body: Any, arrays: list, shm: list, shm_specs: list) -> None:
        if not isinstance(tid, int) or isinstance(tid, bool) or not 0 <= tid <= MAX_TEMPLATE_ID:
            raise WireError(f"header field 'tpl' must be a template id 0..{MAX_TEMPLATE_ID}, got {_repr.repr(tid)}")
        if op != "ok":
            raise WireError(f"a template is announced by an {op!r} reply (only 'ok' replies have templates)")
        tpl = _RecvTemplate(tid, body, arrays, shm, shm_specs)
        self.templates.pop(tid, None)
        self.templates[tid] = tpl
        while len(self.templates) > self.max_templates:  # the oldest goes, as on the sidecar
            del self.templates[next(iter(self.templates))]
