"""The sidecar wire format: one msgpack header frame + one raw frame per ndarray.

A message is a ZeroMQ multipart message ``[header, buf_0, buf_1, ...]``. The header
is a msgpack map ``{"v": PROTOCOL_VERSION, "op": str, "body": ..., "arrays":
[[dtype, [shape...]], ...]}``; inside ``body`` every ndarray is replaced by the
marker ``{"__nd__": i}`` and its bytes travel as frame ``i + 1``, C-ordered, with
the dtype and shape from ``arrays[i]``. Nothing else is ever decoded: no pickle,
no ``np.save`` blobs, no object dtypes, nothing executable.

Encoding is zero-copy for C-contiguous arrays (their buffers are handed to ZeroMQ
as they are); decoding is zero-copy too (arrays are read-only views of the
received frames). Decoding validates everything and raises ``WireError`` (never
anything else) on malformed input: version, header size and type, dtype whitelist,
shape, frame count and byte counts.

Shared-memory slots (protocol 3, the local fast path, ``simseam.sidecar.local``): an
array may instead live in one of the ring slots the server shares with the client.
Its marker is ``{"__shm__": i}`` and ``header["shm"][i]`` is ``[dtype, [shape...],
slot, offset]``; ``encode(..., ring=...)`` puts arrays of at least ``ring.threshold``
bytes there (when they fit), ``decode(..., slots=[memoryview, ...])`` returns read-only
views into the slot, after checking the slot index, the byte range and the alignment.

Compact step messages (``simseam.sidecar.compact``, negotiated on the local fast path): a
header may carry ``"tpl": id``, announcing that the body's structure is compact template ``id``.

Imports: numpy and msgpack only.
"""

from __future__ import annotations

import reprlib
from typing import Any

import msgpack
import numpy as np

PROTOCOL_VERSION = 3  # 2: hello carries the RolloutSpec; reset/step carry an observation request;
#                      3: hello offers the local fast path (Unix socket + shared-memory slots)
MAX_HEADER_BYTES = 1 << 20  # 1 MiB of msgpack is far more than any header needs
MAX_ARRAY_BYTES = 1 << 30  # 1 GiB per array
MAX_ARRAYS = 256
MAX_NDIM = 8
MAX_DEPTH = 32  # nesting levels of a body (observations need 4)
ND = "__nd__"
SHM = "__shm__"
_PLAIN = frozenset((bool, int, float, str, bytes, type(None)))
ALIGN = 64  # byte alignment of arrays inside a shared-memory slot

#: dtypes allowed on the wire (little-endian, fixed size, no objects)
DTYPES = {np.dtype(t).str: np.dtype(t) for t in ("|b1", "|u1", "|i1", "<u2", "<i2", "<u4", "<i4", "<u8", "<i8",
                                                   "<f2", "<f4", "<f8")}


class WireError(ValueError):
    """A message that does not follow the wire format. Says what and where."""


_repr = reprlib.Repr()  # bounded repr for error messages: peer data can be huge or deeply nested
_repr.maxlevel, _repr.maxstring, _repr.maxother = 3, 80, 80


def _pack_body(obj: Any, arrays: list[np.ndarray], shm: list | None = None, ring: Any = None) -> Any:
    if isinstance(obj, np.ndarray):
        arr = obj
        if arr.dtype.str not in DTYPES:
            if arr.dtype.byteorder == ">" and arr.dtype.newbyteorder("<").str in DTYPES:
                arr = arr.astype(arr.dtype.newbyteorder("<"))
            else:
                raise WireError(f"dtype {arr.dtype} cannot travel on the wire (allowed: {', '.join(DTYPES)})")
        if ring is not None and arr.nbytes >= ring.threshold:
            place = ring.put(arr)  # copies into the message's slot; None when it does not fit
            if place is not None:
                shm.append([arr.dtype.str, list(arr.shape), *place])
                return {SHM: len(shm) - 1}
        if not arr.flags.c_contiguous:
            arr = np.ascontiguousarray(arr)
        arrays.append(arr)
        return {ND: len(arrays) - 1}
    if isinstance(obj, dict):  # scalars of the exact plain types are taken as they are (no call per leaf)
        return {(k if type(k) is str else str(k)): (v if type(v) in _PLAIN else _pack_body(v, arrays, shm, ring))
                for k, v in obj.items()}
    if isinstance(obj, (list, tuple)):
        return [v if type(v) in _PLAIN else _pack_body(v, arrays, shm, ring) for v in obj]
    if isinstance(obj, np.generic):
        return obj.item()
    if obj is None or isinstance(obj, (bool, int, float, str, bytes)):
        return obj
    raise WireError(f"value of type {type(obj).__name__} cannot travel on the wire")


def encode(op: str, body: Any = None, ring: Any = None, tpl: int | None = None) -> list:
    """Message frames for ``op`` with ``body`` (JSON-like data and ndarrays).

    ``ring`` (server side of the local fast path: a ``simseam.sidecar.local.SlotRing``):
    arrays of at least ``ring.threshold`` bytes are copied into the ring's next slot
    instead of travelling as frames. ``tpl``: the header field announcing that this body's
    structure is compact template ``tpl`` (``simseam.sidecar.compact``)."""
    arrays: list[np.ndarray] = []
    shm: list = []
    if ring is not None:
        ring.begin()
    packed = _pack_body(body, arrays, shm, ring)
    head = {"v": PROTOCOL_VERSION, "op": op, "body": packed, "arrays": [[a.dtype.str, list(a.shape)] for a in arrays]}
    if shm:
        head["shm"] = shm
    if tpl is not None:
        head["tpl"] = tpl
    header = msgpack.packb(head, use_bin_type=True)
    return [header, *(memoryview(a).cast("B") if a.size else b"" for a in arrays)]


def _unpack_body(obj: Any, arrays: list[np.ndarray], used: list[bool], depth: int = 0,
                 shm: list | None = None, shm_used: list[bool] | None = None) -> Any:
    """The body with its array markers replaced, in place (``obj`` is freshly unpacked msgpack:
    only dict, list and scalars)."""
    t = type(obj)
    if t is not dict and t is not list:
        return obj
    if depth >= MAX_DEPTH:
        raise WireError(f"body is nested deeper than {MAX_DEPTH} levels")
    if t is dict:
        if ND in obj:
            idx = obj[ND]
            if len(obj) != 1 or not isinstance(idx, int) or isinstance(idx, bool) or not 0 <= idx < len(arrays):
                raise WireError(f"bad array reference {_repr.repr(obj)}")
            used[idx] = True
            return arrays[idx]
        if SHM in obj:
            idx = obj[SHM]
            if (len(obj) != 1 or not isinstance(idx, int) or isinstance(idx, bool)
                    or not 0 <= idx < len(shm or ())):
                raise WireError(f"bad shared-memory array reference {_repr.repr(obj)}")
            shm_used[idx] = True
            return shm[idx]
        for k, v in obj.items():
            tv = type(v)
            if tv is dict or tv is list:
                obj[k] = _unpack_body(v, arrays, used, depth + 1, shm, shm_used)
        return obj
    for i, v in enumerate(obj):
        tv = type(v)
        if tv is dict or tv is list:
            obj[i] = _unpack_body(v, arrays, used, depth + 1, shm, shm_used)
    return obj


def decode(frames: list, slots: list | None = None) -> tuple[str, Any]:
    """``(op, body)`` of a received message; raises ``WireError`` on anything malformed.

    ``slots``: the shared-memory slots (memoryviews) a message may reference (client
    side of the local fast path); without them a message referencing one is refused."""
    _header, op, body, _arrays, _shm = _decode(frames, slots)
    return op, body


def _decode(frames: list, slots: list | None = None) -> tuple[dict, str, Any, list, list]:
    """``decode``, also giving the header and the decoded arrays (inline, then shared-memory)."""
    if not frames:
        raise WireError("empty message")
    head = frames[0]
    head_bytes = head.bytes if hasattr(head, "bytes") else bytes(head)
    if len(head_bytes) > MAX_HEADER_BYTES:
        raise WireError(f"header is {len(head_bytes)} bytes, more than {MAX_HEADER_BYTES}")
    try:
        header = msgpack.unpackb(head_bytes, raw=False, strict_map_key=True, use_list=True)
    except Exception as exc:  # msgpack raises several unrelated types on garbage
        raise WireError(f"header is not valid msgpack: {type(exc).__name__}: {exc}") from None
    if not isinstance(header, dict):
        raise WireError(f"header must be a map, got {type(header).__name__}")
    if header.get("v") != PROTOCOL_VERSION:
        raise WireError(f"protocol version {_repr.repr(header.get('v'))}, this side speaks {PROTOCOL_VERSION}")
    op, specs = header.get("op"), header.get("arrays", [])
    if not isinstance(op, str) or not op:
        raise WireError(f"header field 'op' must be a non-empty string, got {_repr.repr(op)}")
    if not isinstance(specs, list) or len(specs) > MAX_ARRAYS:
        raise WireError("header field 'arrays' must be a list of at most %d [dtype, shape] pairs" % MAX_ARRAYS)
    if len(frames) != len(specs) + 1:
        raise WireError(f"header announces {len(specs)} array frame(s), message has {len(frames) - 1}")
    arrays = []
    for i, (spec, frame) in enumerate(zip(specs, frames[1:])):
        arrays.append(_array(i, spec, frame))
    shm_specs = header.get("shm", [])
    if not isinstance(shm_specs, list) or len(shm_specs) > MAX_ARRAYS:
        raise WireError("header field 'shm' must be a list of at most %d [dtype, shape, slot, offset]" % MAX_ARRAYS)
    if shm_specs and not slots:
        raise WireError(f"message references {len(shm_specs)} shared-memory array(s) but no slots are mapped")
    shm = [_shm_array(i, spec, slots) for i, spec in enumerate(shm_specs)]
    used = [False] * len(arrays)
    shm_used = [False] * len(shm)
    body = _unpack_body(header.get("body"), arrays, used, 0, shm, shm_used)
    if not all(used):
        raise WireError(f"array frame {used.index(False) + 1} is not referenced by the body")
    if not all(shm_used):
        raise WireError(f"shared-memory array {shm_used.index(False)} is not referenced by the body")
    return header, op, body, arrays, shm


def _dtype_shape(what: str, dtype_str: Any, shape: Any) -> tuple[np.dtype, list, int, int]:
    dtype = DTYPES.get(dtype_str)
    if dtype is None:
        raise WireError(f"{what}: dtype {_repr.repr(dtype_str)} is not allowed (allowed: {', '.join(DTYPES)})")
    if len(shape) > MAX_NDIM or not all(isinstance(d, int) and not isinstance(d, bool) and d >= 0 for d in shape):
        raise WireError(f"{what}: bad shape {_repr.repr(shape)}")
    count = 1
    for d in shape:
        count *= d
    nbytes = count * dtype.itemsize
    if nbytes > MAX_ARRAY_BYTES:
        raise WireError(f"{what}: {nbytes} bytes is more than {MAX_ARRAY_BYTES}")
    return dtype, shape, count, nbytes


def _shm_array(i: int, spec: Any, slots: list) -> np.ndarray:
    what = f"shared-memory array {i}"
    if not (isinstance(spec, list) and len(spec) == 4 and isinstance(spec[0], str) and isinstance(spec[1], list)):
        raise WireError(f"{what}: spec must be [dtype, shape, slot, offset], got {_repr.repr(spec)}")
    dtype, shape, count, nbytes = _dtype_shape(what, spec[0], spec[1])
    slot, offset = spec[2], spec[3]
    if not isinstance(slot, int) or isinstance(slot, bool) or not 0 <= slot < len(slots):
        raise WireError(f"{what}: slot {_repr.repr(slot)} is out of range (the ring has {len(slots)} slots)")
    size = slots[slot].nbytes
    if not isinstance(offset, int) or isinstance(offset, bool) or offset < 0 or offset % ALIGN:
        raise WireError(f"{what}: offset {_repr.repr(offset)} is not a non-negative multiple of {ALIGN}")
    if offset + nbytes > size:
        raise WireError(f"{what}: bytes [{offset}, {offset + nbytes}) of {spec[0]}{tuple(shape)} do not fit "
                        f"slot {slot} ({size} bytes)")
    try:
        arr = np.frombuffer(slots[slot], dtype=dtype, count=count, offset=offset).reshape(shape)
    except ValueError as exc:
        raise WireError(f"{what}: bad shape {_repr.repr(shape)}: {exc}") from None
    arr.flags.writeable = False
    return arr


def _array(i: int, spec: Any, frame: Any) -> np.ndarray:
    if not (isinstance(spec, list) and len(spec) == 2 and isinstance(spec[0], str) and isinstance(spec[1], list)):
        raise WireError(f"array {i}: spec must be [dtype, shape], got {_repr.repr(spec)}")
    dtype, shape, count, nbytes = _dtype_shape(f"array {i}", spec[0], spec[1])
    buf = frame.buffer if hasattr(frame, "buffer") else memoryview(frame)
    if buf.nbytes != nbytes:
        raise WireError(f"array {i}: frame has {buf.nbytes} bytes, {spec[0]}{tuple(shape)} needs {nbytes}")
    try:  # numpy refuses some 0-size shapes whose other extents overflow (e.g. [0, 2**63])
        arr = np.frombuffer(buf, dtype=dtype, count=count).reshape(shape)
    except ValueError as exc:
        raise WireError(f"array {i}: bad shape {_repr.repr(shape)}: {exc}") from None
    arr.flags.writeable = False
    return arr
