"""The sidecar wire format: msgpack header + one raw frame per ndarray, zero-copy, validated.

Round trips of every allowed dtype and awkward shapes, zero-copy both ways (also through
real ZeroMQ frames), refusal of dtypes that cannot travel, one malformed message per
failure mode (each named in the WireError), and a seeded fuzz: decode() never raises
anything but WireError, whatever bytes arrive.
"""

from __future__ import annotations

import msgpack
import numpy as np
import pytest
import zmq
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st

from simseam.sidecar import wire
from simseam.sidecar.wire import (
    DTYPES,
    MAX_ARRAYS,
    MAX_DEPTH,
    MAX_HEADER_BYTES,
    PROTOCOL_VERSION,
    WireError,
    decode,
    encode,
)

SHAPES = [(), (0,), (3,), (2, 0, 4), (2, 3, 4), (1, 1, 1, 1, 1, 1, 1, 5)]


def _sample(dtype: np.dtype, shape: tuple, rng: np.random.Generator) -> np.ndarray:
    n = int(np.prod(shape))
    if dtype.kind == "b":
        return (rng.integers(0, 2, n) == 1).reshape(shape)
    if dtype.kind in "iu":
        info = np.iinfo(dtype)
        raw = rng.integers(info.min, info.max, n, dtype=dtype, endpoint=True)
        return raw.reshape(shape)
    vals = rng.standard_normal(n) * 1e3
    if n >= 3:
        vals[:3] = [np.inf, -0.0, np.nan]  # special values survive bit for bit
    return vals.astype(dtype).reshape(shape)


def _as_received(frames: list) -> list[bytes]:
    """What a peer receives: each frame as its own bytes object."""
    return [bytes(f) for f in frames]


def _frame_view(frame) -> np.ndarray:
    return np.frombuffer(frame, dtype=np.uint8)


def _hdr(**fields) -> bytes:
    return msgpack.packb({"v": PROTOCOL_VERSION, "op": "step", "body": None, "arrays": [], **fields},
                         use_bin_type=True)


# ----------------------------------------------------------------------------- round trips
@pytest.mark.parametrize("dtype", list(DTYPES))
def test_round_trip_every_dtype_and_shape(dtype):
    rng = np.random.default_rng(list(DTYPES).index(dtype))
    dt = np.dtype(dtype)
    arrays = [_sample(dt, s, rng) for s in SHAPES]
    body = {"token": "t", "arrays": arrays, "nested": {"deeper": [arrays[2], {"again": arrays[4]}]},
            "none": None, "flag": True, "i": -(2**63), "u": 2**64 - 1, "f": 1.5, "s": "päckchen", "b": b"\x00\xff",
            "tuple": (1, 2.5, "x"), "scalar": dt.type(0)}
    frames = _as_received(encode("step", body))
    assert len(frames) == 1 + len(SHAPES) + 2  # the header + one frame per ndarray (shared ones travel twice)
    op, out = decode(frames)
    assert op == "step"
    for src, got in zip(arrays, out["arrays"]):
        assert got.dtype == dt and got.shape == src.shape
        assert got.tobytes() == src.tobytes()  # bit for bit (NaN, -0.0 and inf included)
    assert out["nested"]["deeper"][0].tobytes() == arrays[2].tobytes()
    assert out["nested"]["deeper"][1]["again"].tobytes() == arrays[4].tobytes()
    assert out["none"] is None and out["flag"] is True and out["i"] == -(2**63) and out["u"] == 2**64 - 1
    assert out["f"] == 1.5 and out["s"] == "päckchen" and out["b"] == b"\x00\xff"
    assert out["tuple"] == [1, 2.5, "x"]  # tuples travel as lists
    assert out["scalar"] == 0 and not isinstance(out["scalar"], np.generic)  # numpy scalars travel as Python ones


def test_0d_and_0size_arrays_travel_with_their_shape():
    body = {"zero_d": np.array(3.25, dtype="<f8"), "empty": np.zeros((0, 7), dtype="<i4"),
            "empty3": np.zeros((4, 0, 2), dtype="|u1")}
    frames = _as_received(encode("x", body))
    assert [len(f) for f in frames[1:]] == [8, 0, 0]
    _, out = decode(frames)
    assert out["zero_d"].shape == () and out["zero_d"][()] == 3.25
    assert out["empty"].shape == (0, 7) and out["empty"].dtype == np.int32
    assert out["empty3"].shape == (4, 0, 2)


def test_decoded_arrays_are_read_only_views_of_the_frames():
    src = np.arange(24, dtype="<f4").reshape(2, 3, 4)
    frames = _as_received(encode("x", {"a": src, "b": [src[0]]}))
    _, out = decode(frames)
    for arr, frame in ((out["a"], frames[1]), (out["b"][0], frames[2])):
        assert np.shares_memory(arr, _frame_view(frame)), "decode copied the frame"
        # the base chain ends at the received frame itself
        base = arr
        while isinstance(base, np.ndarray):
            base = base.base
        assert isinstance(base, memoryview) and base.obj is frame
        assert not arr.flags.writeable
        with pytest.raises(ValueError):
            arr[(0,) * arr.ndim] = 1.0


def test_encoding_hands_contiguous_buffers_over_without_copying():
    src = np.arange(12, dtype="<i8").reshape(3, 4)
    frames = encode("x", {"a": src})
    assert np.shares_memory(np.asarray(frames[1]), src), "encode copied a C-contiguous array"


def test_zero_copy_through_real_zmq_frames():
    """Across a real ZeroMQ socket pair the decoded array is a view of the received zmq.Frame."""
    ctx = zmq.Context()
    a, b = ctx.socket(zmq.PAIR), ctx.socket(zmq.PAIR)
    try:
        a.bind("inproc://wire-test")
        b.connect("inproc://wire-test")
        img = np.random.default_rng(0).integers(0, 255, (64, 64, 3), dtype=np.uint8)
        a.send_multipart(encode("ok", {"obs": {"images": {"camera1": img}}}), copy=False)
        assert b.poll(5000)
        frames = b.recv_multipart(copy=False)
        _, out = decode(frames)
        got = out["obs"]["images"]["camera1"]
        assert np.array_equal(got, img) and not got.flags.writeable
        assert np.shares_memory(got, np.asarray(frames[1].buffer))
    finally:
        a.close(0)
        b.close(0)
        ctx.term()


@pytest.mark.parametrize("make", [
    lambda a: a[:, ::2],  # strided
    lambda a: a.T,  # Fortran order
    lambda a: a[::-1, ::-1],  # negative strides
    lambda a: np.asfortranarray(a),
    lambda a: a.astype(">f4"),  # big-endian: converted to the wire's little-endian
], ids=["strided", "transposed", "reversed", "fortran", "big-endian"])
def test_non_contiguous_and_big_endian_inputs_encode_correctly(make):
    base = np.arange(48, dtype="<f4").reshape(6, 8) * 0.5
    src = make(base)
    _, out = decode(_as_received(encode("x", {"a": src})))
    got = out["a"]
    assert got.shape == src.shape and got.dtype == np.dtype("<f4")
    assert np.array_equal(got, src)


@pytest.mark.parametrize("value", [
    np.array([object()], dtype=object),
    np.array([1 + 2j], dtype=np.complex64),
    np.array([1 + 2j], dtype=np.complex128),
    np.zeros(2, dtype=[("a", "<f4"), ("b", "<i4")]),
    np.array(["2024-01-01"], dtype="datetime64[D]"),
    np.array([5], dtype="timedelta64[s]"),
    np.array(["abc"], dtype="<U3"),
    np.array([b"abc"], dtype="S3"),
    np.zeros(2, dtype=np.longdouble),
], ids=["object", "complex64", "complex128", "structured", "datetime", "timedelta", "unicode", "bytes", "longdouble"])
def test_disallowed_dtypes_are_refused(value):
    with pytest.raises(WireError, match="cannot travel on the wire"):
        encode("x", {"nested": [value]})


def test_non_wire_values_are_refused():
    with pytest.raises(WireError, match="set cannot travel"):
        encode("x", {"a": {1, 2}})
    with pytest.raises(WireError, match="object cannot travel"):
        encode("x", [object()])


# --------------------------------------------------------------------------- malformed input
F4x3 = [["<f4", [3]]]
ND0 = {"__nd__": 0}
_DEEP = 0
for _ in range(900):
    _DEEP = [_DEEP]

MALFORMED = {
    "empty": ([], "empty message"),
    "empty header": ([b""], "not valid msgpack"),
    "non-msgpack header": ([b"\xc1\xc1garbage"], "not valid msgpack"),
    "trailing bytes after header": ([msgpack.packb({"v": PROTOCOL_VERSION, "op": "x"}) + b"\x01"], "not valid msgpack"),
    "non-str map key": ([msgpack.packb({1: 2})], "not valid msgpack"),
    "header too large": ([msgpack.packb({"v": PROTOCOL_VERSION, "op": "x", "body": "a" * MAX_HEADER_BYTES})], "more than"),
    "non-map header (list)": ([msgpack.packb([1, "step"])], "header must be a map, got list"),
    "non-map header (int)": ([msgpack.packb(7)], "header must be a map, got int"),
    "wrong version": ([_hdr(v=99)], f"protocol version 99, this side speaks {PROTOCOL_VERSION}"),
    "missing version": ([msgpack.packb({"op": "x"})], "protocol version None"),
    "deep version": ([_hdr(v=_DEEP)], "protocol version"),
    "missing op": ([msgpack.packb({"v": PROTOCOL_VERSION, "body": {}})], "'op' must be a non-empty string, got None"),
    "empty op": ([_hdr(op="")], "'op' must be a non-empty string"),
    "non-str op": ([_hdr(op=5)], "'op' must be a non-empty string, got 5"),
    "arrays not a list": ([_hdr(arrays={"a": 1})], "'arrays' must be a list"),
    "too many arrays": ([_hdr(arrays=[["|u1", [0]]] * (MAX_ARRAYS + 1))] + [b""] * (MAX_ARRAYS + 1),
                        "'arrays' must be a list of at most"),
    "frame missing": ([_hdr(body=ND0, arrays=F4x3)], "announces 1 array frame(s), message has 0"),
    "frame extra": ([_hdr(), b"\x00" * 4], "announces 0 array frame(s), message has 1"),
    "truncated frame": ([_hdr(body=ND0, arrays=F4x3), b"\x00" * 11], "frame has 11 bytes, <f4(3,) needs 12"),
    "oversized frame": ([_hdr(body=ND0, arrays=F4x3), b"\x00" * 13], "frame has 13 bytes, <f4(3,) needs 12"),
    "bad dtype string": ([_hdr(body=ND0, arrays=[["float32", [3]]]), b"\x00" * 12], "dtype 'float32' is not allowed"),
    "object dtype": ([_hdr(body=ND0, arrays=[["|O", [1]]]), b"\x00" * 8], "dtype '|O' is not allowed"),
    "complex dtype": ([_hdr(body=ND0, arrays=[["<c8", [1]]]), b"\x00" * 8], "dtype '<c8' is not allowed"),
    "big-endian dtype": ([_hdr(body=ND0, arrays=[[">f4", [3]]]), b"\x00" * 12], "dtype '>f4' is not allowed"),
    "dtype not a str": ([_hdr(body=ND0, arrays=[[4, [3]]]), b"\x00" * 12], "spec must be [dtype, shape]"),
    "spec not a pair": ([_hdr(body=ND0, arrays=[["<f4"]]), b"\x00" * 12], "spec must be [dtype, shape]"),
    "shape not a list": ([_hdr(body=ND0, arrays=[["<f4", 3]]), b"\x00" * 12], "spec must be [dtype, shape]"),
    "negative shape": ([_hdr(body=ND0, arrays=[["<f4", [-3]]]), b""], "bad shape [-3]"),
    "float shape": ([_hdr(body=ND0, arrays=[["<f4", [1.5]]]), b"\x00" * 4], "bad shape [1.5]"),
    "str shape": ([_hdr(body=ND0, arrays=[["<f4", ["3"]]]), b"\x00" * 12], "bad shape ['3']"),
    "bool shape": ([_hdr(body=ND0, arrays=[["<f4", [True]]]), b"\x00" * 4], "bad shape [True]"),
    "too many dims": ([_hdr(body=ND0, arrays=[["|u1", [1] * 9]]), b"\x00"], "bad shape"),
    "array too large": ([_hdr(body=ND0, arrays=[["|u1", [1 << 20, 1 << 20]]]), b""], "is more than"),
    "0-size with overflowing extent": ([_hdr(body=ND0, arrays=[["|u1", [0, 2**63]]]), b""], "bad shape"),
    "0-size with overflowing product": ([_hdr(body=ND0, arrays=[["<f8", [0, 2**62, 2**62]]]), b""], "bad shape"),
    "marker out of range": ([_hdr(body={"a": {"__nd__": 1}}, arrays=F4x3), b"\x00" * 12], "bad array reference"),
    "negative marker": ([_hdr(body={"__nd__": -1}, arrays=F4x3), b"\x00" * 12], "bad array reference"),
    "marker not an int": ([_hdr(body={"__nd__": "0"}, arrays=F4x3), b"\x00" * 12], "bad array reference"),
    "marker is a bool": ([_hdr(body={"__nd__": True}, arrays=F4x3), b"\x00" * 12], "bad array reference"),
    "marker with extra keys": ([_hdr(body={"__nd__": 0, "x": _DEEP}, arrays=F4x3), b"\x00" * 12],
                               "bad array reference"),
    "marker without arrays": ([_hdr(body=[{"__nd__": 0}])], "bad array reference"),
    "unreferenced frame": ([_hdr(body={"a": ND0}, arrays=F4x3 * 2), b"\x00" * 12, b"\x00" * 12],
                           "array frame 2 is not referenced by the body"),
    "body nested too deep": ([_hdr(body=_DEEP)], f"nested deeper than {MAX_DEPTH} levels"),
}


@pytest.mark.parametrize("name", list(MALFORMED))
def test_malformed_message_raises_wire_error_naming_the_problem(name):
    frames, expected = MALFORMED[name]
    with pytest.raises(WireError) as ei:
        decode(frames)
    assert expected in str(ei.value), f"{name}: {ei.value}"
    assert len(str(ei.value)) < 400, "error messages stay short even for huge or deep input"


def test_just_inside_the_limits_decodes():
    nested = 0
    for _ in range(MAX_DEPTH - 1):
        nested = [nested]
    op, body = decode([_hdr(body=nested)])
    assert op == "step"
    frames = [_hdr(body=[{"__nd__": i} for i in range(MAX_ARRAYS)], arrays=[["|u1", [0]]] * MAX_ARRAYS)]
    op, body = decode(frames + [b""] * MAX_ARRAYS)
    assert len(body) == MAX_ARRAYS and all(a.shape == (0,) for a in body)


# ------------------------------------------------------------------------------------ fuzz
def _decode_or_wire_error(frames) -> None:
    try:
        op, _ = decode(frames)
    except WireError:
        return
    assert isinstance(op, str) and op


_scalars = st.one_of(st.none(), st.booleans(), st.integers(-(2**63), 2**64 - 1), st.floats(allow_nan=True),
                     st.text(max_size=8), st.binary(max_size=8))
_values = st.recursive(_scalars, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=4)), max_leaves=20)
_dtype_strs = st.one_of(st.sampled_from(list(DTYPES)), st.sampled_from(["|O", "<c8", ">f4", "<M8[D]", "V8"]),
                        st.text(max_size=5), _scalars)
_shapes = st.one_of(st.lists(st.integers(-3, 2**64 - 1) | st.integers(0, 4), max_size=10), _values)
_specs = st.lists(st.one_of(st.tuples(_dtype_strs, _shapes).map(list), _values), max_size=4)
_markers = st.one_of(st.integers(-2, 5).map(lambda i: {"__nd__": i}), _values)
_bodies = st.recursive(_markers, lambda inner: st.one_of(
    st.lists(inner, max_size=4), st.dictionaries(st.text(max_size=6), inner, max_size=4)), max_leaves=12)
_FUZZ = settings(max_examples=400, derandomize=True, database=None, deadline=None,
                 suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@_FUZZ
@given(st.lists(st.binary(max_size=64), max_size=5))
def test_fuzz_random_frames_only_raise_wire_error(frames):
    _decode_or_wire_error(frames)


@_FUZZ
@given(header=st.dictionaries(st.sampled_from(["v", "op", "body", "arrays", "x"]), _values, max_size=5),
       frames=st.lists(st.binary(max_size=32), max_size=4))
def test_fuzz_random_headers_only_raise_wire_error(header, frames):
    _decode_or_wire_error([msgpack.packb(header, use_bin_type=True), *frames])


@_FUZZ
@given(body=_bodies, specs=_specs, frame_sizes=st.lists(st.integers(0, 64), max_size=5),
       v=st.sampled_from([1, 1, 1, 0, 2, True, 1.0, "1"]), op=st.sampled_from(["step", "", 3, None]))
def test_fuzz_structured_messages_only_raise_wire_error(body, specs, frame_sizes, v, op):
    header = msgpack.packb({"v": v, "op": op, "body": body, "arrays": specs}, use_bin_type=True)
    _decode_or_wire_error([header, *(b"\x01" * n for n in frame_sizes)])


def _nest(depth: int, container: str, leaf):
    for _ in range(depth):
        leaf = [leaf] if container == "list" else {"k": leaf}
    return leaf


@_FUZZ
@given(depth=st.integers(0, 1000), where=st.sampled_from(["v", "op", "body", "marker", "spec", "shape", "extra"]),
       container=st.sampled_from(["list", "dict"]))
def test_fuzz_deeply_nested_headers_only_raise_wire_error(depth, where, container):
    """msgpack accepts ~1000 levels of nesting; nothing downstream may recurse itself to death."""
    deep = _nest(depth, container, 0)
    header = {"v": PROTOCOL_VERSION, "op": "step", "body": {"a": ND0}, "arrays": F4x3, "extra": None}
    if where == "marker":
        header["body"] = {"__nd__": 0, "x": deep}
    elif where == "spec":
        header["arrays"] = [deep]
    elif where == "shape":
        header["arrays"] = [["<f4", deep]]
    else:
        header[where] = deep
    _decode_or_wire_error([msgpack.packb(header, use_bin_type=True), b"\x00" * 12])


@_FUZZ
@given(dtype=st.sampled_from(list(DTYPES)),
       shape=st.lists(st.sampled_from([0, 1, 3, 2**31, 2**32 + 1, 2**62, 2**63, 2**64 - 1]), max_size=8),
       frame=st.sampled_from([b"", b"\x00" * 8]))
def test_fuzz_extreme_shapes_only_raise_wire_error(dtype, shape, frame):
    _decode_or_wire_error([_hdr(body=ND0, arrays=[[dtype, shape]]), frame])


@_FUZZ
@given(data=st.data())
def test_fuzz_mutated_valid_messages_only_raise_wire_error(data):
    rng = np.random.default_rng(data.draw(st.integers(0, 2**32 - 1)))
    body = {"token": "abc", "action": rng.standard_normal(7).astype("<f4"),
            "obs": {"images": {"c": rng.integers(0, 255, (4, 4, 3), dtype=np.uint8)}, "t": 3}}
    frames = [bytearray(f) for f in _as_received(encode("step", body))]
    for _ in range(data.draw(st.integers(1, 4))):
        i = data.draw(st.integers(0, len(frames) - 1))
        kind = data.draw(st.sampled_from(["flip", "truncate", "extend", "drop", "dup"]))
        f = frames[i]
        if kind == "flip" and f:
            j = data.draw(st.integers(0, len(f) - 1))
            f[j] ^= data.draw(st.integers(1, 255))
        elif kind == "truncate":
            del f[data.draw(st.integers(0, len(f))):]
        elif kind == "extend":
            f.extend(data.draw(st.binary(min_size=1, max_size=8)))
        elif kind == "drop" and len(frames) > 1:
            frames.pop(i)
        elif kind == "dup":
            frames.insert(i, bytearray(f))
    _decode_or_wire_error([bytes(f) for f in frames])


def test_wire_module_imports_only_numpy_and_msgpack():
    import ast
    import inspect

    tree = ast.parse(inspect.getsource(wire))
    top = set()
    for node in ast.walk(tree):
        if isinstance(node, ast.Import):
            top.update(a.name.split(".")[0] for a in node.names)
        elif isinstance(node, ast.ImportFrom) and node.module:
            top.add(node.module.split(".")[0])
    assert top <= {"__future__", "typing", "reprlib", "msgpack", "numpy"}, top
    assert "pickle" not in inspect.getsource(wire).replace("no pickle", "")
