"""The openpi policy-server wire: msgpack with numpy arrays, and the message flow.

Codec (byte-compatible with ``openpi_client.msgpack_numpy``):

- an ``np.ndarray`` travels as the map ``{b"__ndarray__": True, b"data": <raw bytes, C order>,
  b"dtype": <dtype.str, e.g. "<f4">, b"shape": [dims]}``;
- a numpy scalar (``np.generic``) as ``{b"__npgeneric__": True, b"data": <item()>, b"dtype": ...}``;
- everything else is plain msgpack (str as str, bytes as bin, tuples come back as lists;
  ``np.float64`` subclasses ``float`` and so travels, and comes back, as a plain float).

Object, void (structured) and complex dtypes are refused on both sides. Decoded arrays are
read-only views of the received message (no copy): copy one before writing to it.

Protocol (websocket, binary frames, no compression, websockets' default keepalive: ping every
20 s, 20 s to answer; openpi sets no message size limit, simseam's ends bound each message to
``DEFAULT_MAX_MESSAGE_BYTES`` unless told otherwise, and ``unpackb`` checks the bound too):

1. on connect the server sends one message: its metadata (a map);
2. then, per request, the client sends an observation map and the server answers with a map
   holding ``"actions"`` (``(H, action_dim)``) and ``"server_timing"`` (``infer_ms``, and
   ``prev_total_ms`` from the second request on);
3. when inference fails the server sends the traceback as a *text* frame and closes the
   connection with code 1011 (internal error). A client treats any text frame as an error.

``GET /healthz`` on the server's port answers ``200 OK`` (openpi's health check).

A server may require a token in the opening handshake (simseam's does off loopback): openpi's
``Authorization: Api-Key <token>`` header, which ``remote:ws://host:port?token=<token>`` sends.
"""

from __future__ import annotations

import ipaddress
import math
from typing import Any

import msgpack
import numpy as np

#: bound on one message, both ends (64 MiB: a request with several full-HD cameras fits easily)
DEFAULT_MAX_MESSAGE_BYTES = 64 * 2**20
#: the URL query parameter that carries a policy server's token (``remote:ws://h:p?token=...``)
TOKEN_QUERY = "token"
#: more dimensions than any observation has; a header claiming more is refused
_MAX_NDIM = 32

#: dtype kinds that cannot cross the wire (object, void/structured, complex), as in openpi
_REFUSED_KINDS = {"O": "object", "V": "void/structured", "c": "complex"}


def _refuse(dtype: np.dtype) -> None:
    if dtype.kind in _REFUSED_KINDS:
        raise ValueError(f"numpy dtype {dtype} ({_REFUSED_KINDS[dtype.kind]}) cannot cross the openpi wire; "
                         "convert it to a numeric, bool or string dtype first")


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        _refuse(obj.dtype)
        return {b"__ndarray__": True, b"data": obj.tobytes(), b"dtype": obj.dtype.str, b"shape": obj.shape}
    if isinstance(obj, np.generic):
        _refuse(obj.dtype)
        return {b"__npgeneric__": True, b"data": obj.item(), b"dtype": obj.dtype.str}
    raise TypeError(f"cannot send {type(obj).__name__} over the openpi wire")


def _object_hook(obj: dict) -> Any:
    if b"__ndarray__" in obj:
        dtype = np.dtype(obj[b"dtype"])
        _refuse(dtype)
        data, shape = obj[b"data"], obj[b"shape"]
        if not isinstance(data, bytes):
            raise ValueError(f"ndarray data must be bytes, got {type(data).__name__}")
        if not (isinstance(shape, (list, tuple)) and len(shape) <= _MAX_NDIM
                and all(isinstance(n, int) and n >= 0 for n in shape)):
            raise ValueError(f"ndarray shape must be at most {_MAX_NDIM} non-negative ints, got {shape!r:.80}")
        if math.prod(shape) * dtype.itemsize != len(data):  # exactly what the header claims, never more
            raise ValueError(f"ndarray of shape {tuple(shape)} and dtype {dtype.str} needs "
                             f"{math.prod(shape) * dtype.itemsize} bytes, the message carries {len(data)}")
        return np.ndarray(buffer=data, dtype=dtype, shape=tuple(shape))
    if b"__npgeneric__" in obj:
        dtype = np.dtype(obj[b"dtype"])
        _refuse(dtype)
        return dtype.type(obj[b"data"])
    return obj


def packb(obj: Any) -> bytes:
    """Encode ``obj`` (maps, lists, scalars, str, bytes, numpy arrays and scalars).

    Raises ``ValueError`` for a refused dtype and ``TypeError`` for a type msgpack cannot carry."""
    return msgpack.packb(obj, default=_default, use_bin_type=True)


def unpackb(data: bytes, max_bytes: int | None = DEFAULT_MAX_MESSAGE_BYTES) -> Any:
    """Decode one message; anything that is not a well-formed msgpack-numpy message, or a message
    longer than ``max_bytes`` (None: no bound), raises ``ValueError`` saying why."""
    if max_bytes is not None and len(data) > max_bytes:
        raise ValueError(f"message of {len(data)} bytes is over the limit of {max_bytes} bytes")
    try:
        # msgpack bounds every string, bin, array and map length by len(data), and the nesting depth
        return msgpack.unpackb(data, object_hook=_object_hook, raw=False)
    except ValueError as exc:
        raise ValueError(f"not a msgpack-numpy message: {exc}") from None
    except Exception as exc:  # noqa: BLE001  (msgpack and numpy raise many kinds for garbage)
        raise ValueError(f"not a msgpack-numpy message: {type(exc).__name__}: {exc}") from None


def is_loopback(host: str) -> bool:
    """``host`` names this machine only: ``localhost`` or a loopback IP (127.0.0.0/8, ``::1``).
    Anything else (``0.0.0.0``, a hostname, an interface address) counts as reachable from outside."""
    host = host.strip().strip("[]")
    if host.lower() == "localhost":
        return True
    try:
        return ipaddress.ip_address(host).is_loopback
    except ValueError:
        return False


def check_bind_host(host: str) -> None:
    """``ConfigError`` unless ``host`` can be bound: an IP address, ``localhost``, empty or ``0.0.0.0`` / ``::``
    (every interface), or a name that resolves. Checked before the loopback rule, so a mistyped address is
    named as one (not as 'not a loopback address')."""
    import socket

    from simseam.seam import ConfigError

    name = host.strip().strip("[]")
    if name == "" or name.lower() == "localhost":
        return
    try:
        ipaddress.ip_address(name)
        return
    except ValueError:
        pass
    if all(c.isdigit() or c == "." for c in name):  # a dotted number that is no IPv4 address: no DNS lookup
        raise ConfigError(f"--host {host}: not an IP address (an IPv4 address is four numbers 0-255, e.g. 127.0.0.1)")
    try:
        socket.getaddrinfo(name, None, type=socket.SOCK_STREAM)
    except (socket.gaierror, UnicodeError) as exc:
        reason = exc.strerror if isinstance(exc, socket.gaierror) else str(exc)
        raise ConfigError(f"--host {host}: not an IP address, and the name does not resolve ({reason})") from None


def require_websockets() -> None:
    """Raise ``BackendUnavailableError`` with the install line when ``websockets`` is missing."""
    try:
        import websockets.sync.client  # noqa: F401
    except ImportError:
        from simseam.seam import BackendUnavailableError

        raise BackendUnavailableError("remote policies need the `websockets` package (>= 13, sync API): "
                                      "pip install 'websockets>=13'") from None


# --------------------------------------------------------------- simseam observation format
PREFIX = "observation/"
PROMPT = "prompt"
RESET = "simseam/reset"
SPEC = "simseam/spec"  # RolloutSpec.to_json(), sent with the first request of each episode


def flatten(tree: dict, prefix: str) -> dict[str, Any]:
    """``{"a": {"b": x}}`` -> ``{prefix + "a/b": x}`` (nested maps become ``/`` paths)."""
    out: dict[str, Any] = {}
    for key, value in tree.items():
        if isinstance(value, dict):
            out.update(flatten(value, f"{prefix}{key}/"))
        else:
            out[f"{prefix}{key}"] = value
    return out


def unflatten(flat: dict[str, Any], prefix: str) -> dict[str, Any]:
    """Inverse of ``flatten`` for the keys that start with ``prefix`` (others are ignored)."""
    out: dict[str, Any] = {}
    for key, value in flat.items():
        if not isinstance(key, str) or not key.startswith(prefix):
            continue
        *parents, leaf = key[len(prefix):].split("/")
        node = out
        for p in parents:
            node = node.setdefault(p, {})
            if not isinstance(node, dict):
                raise ValueError(f"observation key {key!r} nests under a non-map entry")
        node[leaf] = value
    return out
