"""The sidecar's local fast path: a Unix domain socket plus shared-memory ring slots.

Negotiated at ``hello`` (protocol 3) when client and sidecar share a machine (the
``ipc`` transport); ``tcp`` and remote peers keep the ZeroMQ path. After ``hello``
the client connects to ``<private 0700 dir>/local.sock`` and sends ``attach`` with the
launch token; the sidecar answers with the ring's layout and passes the ring's file
descriptor along (``SCM_RIGHTS``). From then on every request goes over this socket.

Messages: the ``simseam.sidecar.wire`` frames, framed as ``<u32 frame count><u64 byte
count>`` + one u64 length per frame + the frames, sent with one ``sendmsg``; a client that asks
at attach (``compact``) sends and gets most step messages as one compact frame instead
(``simseam.sidecar.compact``).

The ring: one anonymous ``memfd`` (never a name under ``/dev/shm``: nothing can leak,
whichever side dies; the memory is freed when the last mapping goes) of ``slots x
slot_bytes``, sized at attach from the ``RolloutSpec``'s declared fixed-shape
observation arrays of at least ``threshold`` bytes (the cameras, chiefly). The sidecar
writes each reply's large arrays into the next slot, round-robin; the reply names the
slot and offsets, the client maps the ring read-only and hands out read-only numpy
views. A view is valid until its slot is reused: ``slots - 1`` further replies (with
2 slots: the previous observation stays intact while the next step is computed).

Waiting: each side busy-polls its socket for up to ``spin_us`` microseconds before it
sleeps in ``poll`` (the client for the reply, the sidecar for the next request, the
value the client sent at attach). A process that sleeps between two messages pays the
wake-up and then runs its next few hundred microseconds on cold caches, about twice the
whole transport's cost; spinning keeps both processes on their cores. It is on by default
only with at least ``SPIN_MIN_CPUS`` usable cores (``default_spin_us``; the environment
variable ``SIMSEAM_SIDECAR_SPIN_US`` overrides it, ``0`` turns it off); the vector runner
turns it off when its workers and their sidecars outnumber the cores.

Shared memory (``create_block`` / ``map_block`` / ``array_at``, ``SlotRing``) is this module's for
both of simseam's same-machine transports: this one, and the vector runner's worker processes
(``simseam.runner.vector``: their images through a one-slot ``SlotRing``, their state-only step replies
through a block laid out from a ``simseam.sidecar.compact`` template).

Imports: the standard library and numpy only.
"""

from __future__ import annotations

import array
import fcntl
import mmap
import os
import socket
import struct
import time
from typing import Any

import numpy as np

from simseam.sidecar.wire import ALIGN, DTYPES, MAX_ARRAYS, MAX_HEADER_BYTES, WireError

PREFIX = struct.Struct("<IQ")  # frame count, bytes that follow (length table + frames)
LENGTH = struct.Struct("<Q")
MAX_MESSAGE_BYTES = MAX_HEADER_BYTES + (1 << 31)  # a header plus 2 GiB of inline arrays
DEFAULT_SLOTS = 2
DEFAULT_THRESHOLD = 1024  # arrays of at least this many bytes go through the ring
MAX_SLOT_BYTES = 1 << 30
SPIN_ENV = "SIMSEAM_SIDECAR_SPIN_US"
DEFAULT_SPIN_US = 1000  # about one state-only physics step: the reply comes before the client sleeps
SPIN_MIN_CPUS = 4
MAX_SPIN_US = 20_000
SEALS = fcntl.F_SEAL_SHRINK | fcntl.F_SEAL_GROW | fcntl.F_SEAL_SEAL


def align(n: int, to: int = ALIGN) -> int:
    """``n`` rounded up to a multiple of ``to`` (by default the ring's alignment, 64 bytes)."""
    return (n + to - 1) // to * to


def slot_bytes_for(spec_json: dict, threshold: int = DEFAULT_THRESHOLD) -> int:
    """Bytes one slot needs to hold every declared fixed-shape observation array of at least
    ``threshold`` bytes (each 64-byte aligned), from a ``RolloutSpec.to_json()``. Arrays whose
    size varies (``-1``) or that do not fit travel inline."""
    total = 0

    def visit(field: Any) -> None:
        nonlocal total
        if not isinstance(field, dict):
            return
        for entry in (field.get("entries") or {}).values():
            visit(entry)
        dt, shape = field.get("dtype"), field.get("shape") or []
        try:
            dtype = np.dtype(dt)
        except (TypeError, ValueError):
            return
        if dtype.str not in DTYPES or not all(isinstance(d, int) and d >= 0 for d in shape):
            return
        n = int(np.prod(shape, dtype=np.int64)) * dtype.itemsize
        if n >= threshold:
            total += align(n)

    fields = (spec_json or {}).get("observation") or {}  # ObservationSpec.to_json(): key -> field
    for field in (fields.values() if isinstance(fields, dict) else ()):
        visit(field)
    return min(total, MAX_SLOT_BYTES)


def default_spin_us() -> int:
    """Microseconds to busy-poll before sleeping: ``$SIMSEAM_SIDECAR_SPIN_US`` when set (an
    integer 0..20000, else ``ValueError`` naming it), else ``DEFAULT_SPIN_US`` on a machine where
    this process may use at least ``SPIN_MIN_CPUS`` cores with two of them free of the current load
    (1-minute average), and 0 otherwise (two spinning processes would take the cores the simulator
    and the machine's other work need)."""
    raw = os.environ.get(SPIN_ENV)
    if raw is not None and raw.strip() != "":
        try:
            value = int(raw)
        except ValueError:
            value = -1
        if not 0 <= value <= MAX_SPIN_US:
            raise ValueError(f"{SPIN_ENV}={raw!r}: expected an integer number of microseconds, 0..{MAX_SPIN_US}")
        return value
    cores = len(os.sched_getaffinity(0))
    return DEFAULT_SPIN_US if cores >= SPIN_MIN_CPUS and os.getloadavg()[0] + 2 <= cores else 0


def spin_until_readable(poller, spin_s: float) -> bool:
    """Busy-poll ``poller`` (a ``select.poll`` with one socket registered) for up to ``spin_s``
    seconds, yielding the core between polls; True as soon as it reports an event (data, or the
    peer's end)."""
    if spin_s <= 0:
        return False
    deadline = time.perf_counter() + spin_s
    while True:
        if poller.poll(0):
            return True
        if time.perf_counter() >= deadline:
            return False
        os.sched_yield()  # another runnable process on this core goes first


# ----------------------------------------------------------------------------- framing
ONE_FRAME = struct.Struct("<IQQ")  # the prefix and length table of a one-frame message
SMALL = 1 << 16


def send_message(sock: socket.socket, frames: list, fds: list[int] | None = None) -> None:
    """Send wire frames (bytes / memoryviews / zmq-free buffers) as one framed message."""
    if len(frames) == 1 and not fds and type(frames[0]) is bytes and len(frames[0]) < SMALL:  # a compact frame
        n = len(frames[0])
        sock.sendall(ONE_FRAME.pack(1, LENGTH.size + n, n) + frames[0])
        return
    views = [f if isinstance(f, (bytes, bytearray)) else memoryview(f).cast("B") for f in frames]
    lengths = b"".join(LENGTH.pack(len(v)) for v in views)
    total = len(lengths) + sum(len(v) for v in views)
    bufs = [PREFIX.pack(len(views), total) + lengths, *views]
    anc = [(socket.SOL_SOCKET, socket.SCM_RIGHTS, array.array("i", fds))] if fds else []
    sent = sock.sendmsg(bufs, anc)
    size = PREFIX.size + total
    if sent < size:  # the rest, without ancillary data (sent with the first byte)
        rest = memoryview(b"".join(bytes(b) for b in bufs))[sent:] if size < (1 << 16) else None
        if rest is not None:
            sock.sendall(rest)
        else:
            for b in bufs:
                n = len(b)
                if sent >= n:
                    sent -= n
                    continue
                sock.sendall(memoryview(b)[sent:])
                sent = 0


class Truncated(WireError):
    """The connection ended in the middle of a message (the peer died or gave up)."""


def _recv_exact(sock: socket.socket, buf: memoryview) -> bool:
    """Fill ``buf``; False when the peer closed the connection before the first byte."""
    got = 0
    while got < len(buf):
        n = sock.recv_into(buf[got:])
        if n == 0:
            if got == 0:
                return False
            raise Truncated(f"connection closed mid-message ({got} of {len(buf)} bytes)")
        got += n
    return True


def recv_message(sock: socket.socket, want_fds: int = 0) -> tuple[list[memoryview], list[int]] | None:
    """One framed message as frames (memoryviews into one fresh buffer), plus any passed file
    descriptors; None when the peer closed the connection cleanly between messages."""
    fds: list[int] = []
    if want_fds:
        data, anc, _flags, _addr = sock.recvmsg(PREFIX.size, socket.CMSG_SPACE(want_fds * array.array("i").itemsize))
        for level, kind, payload in anc:
            if level == socket.SOL_SOCKET and kind == socket.SCM_RIGHTS:
                a = array.array("i")
                a.frombytes(payload[:len(payload) - len(payload) % a.itemsize])
                fds.extend(a)
        if not data:
            return None
        head = bytearray(PREFIX.size)
        head[:len(data)] = data
        if len(data) < PREFIX.size and not _recv_exact(sock, memoryview(head)[len(data):]):
            raise Truncated("connection closed mid-message (in the prefix)")
    else:
        head = sock.recv(PREFIX.size)  # all of it, nearly always: one call
        if len(head) < PREFIX.size:
            if not head:
                return None
            got, head = len(head), bytearray(head) + bytes(PREFIX.size - len(head))
            if not _recv_exact(sock, memoryview(head)[got:]):
                raise Truncated(f"connection closed mid-message ({got} of {PREFIX.size} bytes of the prefix)")
    try:
        count, total = PREFIX.unpack(head)
        if not 1 <= count <= MAX_ARRAYS + 1:
            raise WireError(f"message announces {count} frames (1 to {MAX_ARRAYS + 1} allowed)")
        if not count * LENGTH.size <= total <= MAX_MESSAGE_BYTES:
            raise WireError(f"message announces {total} bytes for {count} frames (at most {MAX_MESSAGE_BYTES})")
        buf = bytearray(total)
        view = memoryview(buf)
        got = sock.recv_into(view)  # all of it, nearly always: one call
        if got < total and (got == 0 or not _recv_exact(sock, view[got:])):
            raise Truncated(f"connection closed mid-message ({got} of {total} bytes after the prefix)")
        frames, pos = [], count * LENGTH.size
        for i in range(count):
            (n,) = LENGTH.unpack_from(buf, i * LENGTH.size)
            if n > total - pos:
                raise WireError(f"frame {i} announces {n} bytes, only {total - pos} left in the message")
            frames.append(view[pos:pos + n])
            pos += n
        if pos != total:
            raise WireError(f"message has {total - pos} bytes after its last frame")
        return frames, fds
    except BaseException:
        for fd in fds:
            os.close(fd)
        raise


# ---------------------------------------------------------------------------- shared memory
HAVE_MEMFD = hasattr(os, "memfd_create")  # Linux


def create_block(name: str, size: int, sealed: bool = False) -> tuple[int, mmap.mmap]:
    """A new block of ``size`` bytes, mapped read-write: ``(fd, mapping)``; the caller hands ``fd`` to
    the peer and closes it. ``sealed``: its size can never change (a peer that checks the seals never
    faults on it)."""
    fd = os.memfd_create(name, os.MFD_CLOEXEC | (os.MFD_ALLOW_SEALING if sealed else 0))
    try:
        os.ftruncate(fd, size)
        if sealed:
            fcntl.fcntl(fd, fcntl.F_ADD_SEALS, SEALS)
        return fd, mmap.mmap(fd, size)
    except BaseException:
        os.close(fd)
        raise


def map_block(fd: int, size: int, *, writable: bool = True, sealed: bool = False,
              where: str = "shared memory", needs: str = "the mapping needs") -> mmap.mmap:
    """The peer's block ``fd`` mapped (``size`` bytes; read-only unless ``writable``); ``fd`` is closed
    either way. ``WireError`` naming ``where`` when the block is smaller than ``size`` (``needs``: who
    says it must have that much), or, with ``sealed``, when it could still be resized under the mapping."""
    try:
        if sealed:
            try:
                seals = fcntl.fcntl(fd, fcntl.F_GET_SEALS)
            except OSError:
                seals = 0
            if seals & SEALS != SEALS:  # a segment that could shrink under our mapping would fault us
                raise WireError(f"{where}: the shared-memory segment is not sealed against resizing")
        have = os.fstat(fd).st_size
        if have < size:
            raise WireError(f"{where}: shared-memory segment has {have} bytes, {needs} {size} (truncated)")
        return mmap.mmap(fd, size, prot=mmap.PROT_READ | (mmap.PROT_WRITE if writable else 0))
    finally:
        os.close(fd)


def release(mapping: Any) -> None:
    """Close a mapping; one that a view still holds goes with the last view (the GC frees it)."""
    try:
        mapping.close()
    except BufferError:
        pass


def array_at(buf: Any, dtype: Any, shape: tuple, offset: int) -> np.ndarray:
    """The array of ``dtype`` and ``shape`` at ``offset`` in ``buf`` (a mapping or a memoryview), no copy."""
    count = 1
    for d in shape:
        count *= d
    a = np.frombuffer(buf, dtype=dtype, count=count, offset=offset)
    return a if len(shape) == 1 else a.reshape(shape)


# ------------------------------------------------------------------------------- ring
class SlotRing:
    """The writing side: ``slots`` slots of ``slot_bytes`` in one sealed block; arrays go into the next
    slot (``begin``, then ``put`` each)."""

    def __init__(self, slots: int, slot_bytes: int, threshold: int = DEFAULT_THRESHOLD,
                 name: str = "simseam-sidecar-ring"):
        self.slots, self.slot_bytes, self.threshold = slots, slot_bytes, threshold
        self.fd, self._map = create_block(name, slots * slot_bytes, sealed=True)
        self._buf = np.frombuffer(self._map, dtype=np.uint8)
        self._next = 0
        self._slot = 0
        self._pos = 0

    def begin(self) -> None:
        """A new message: its arrays go into the next slot."""
        self._slot, self._pos = self._next, 0
        self._used = False

    def put(self, arr: np.ndarray) -> tuple[int, int] | None:
        """Copy ``arr`` into the current slot; ``(slot, offset)``, or None when it does not fit."""
        n = arr.nbytes
        if self._pos + n > self.slot_bytes:
            return None
        if not self._used:
            self._used = True
            self._next = (self._slot + 1) % self.slots
        off = self._pos
        start = self._slot * self.slot_bytes + off
        dst = self._buf[start:start + n].view(arr.dtype).reshape(arr.shape)
        np.copyto(dst, arr, casting="no")
        self._pos = align(off + n)
        return self._slot, off

    def layout(self) -> dict:
        return {"slots": self.slots, "slot_bytes": self.slot_bytes, "threshold": self.threshold}

    def close(self) -> None:
        if self.fd >= 0:
            os.close(self.fd)
            self.fd = -1
        self._buf = None
        release(self._map)


def map_slots(fd: int, layout: Any) -> list[memoryview]:
    """Client side: map the ring read-only; one memoryview per slot. Raises ``WireError`` when
    the layout is malformed or the segment is smaller than it says (the fd is closed either way)."""
    try:
        if not (isinstance(layout, dict) and all(isinstance(layout.get(k), int) and not isinstance(layout.get(k), bool)
                                                 for k in ("slots", "slot_bytes"))):
            raise WireError(f"attach: bad ring layout {layout!r:.200}")
        slots, slot_bytes = layout["slots"], layout["slot_bytes"]
        if not 2 <= slots <= 64 or not 0 < slot_bytes <= MAX_SLOT_BYTES or slot_bytes % ALIGN:
            raise WireError(f"attach: ring layout {slots} slots x {slot_bytes} bytes is out of range")
    except BaseException:
        os.close(fd)
        raise
    m = map_block(fd, slots * slot_bytes, writable=False, sealed=True, where="attach",
                  needs=f"the layout ({slots} x {slot_bytes}) needs")
    view = memoryview(m)
    return [view[i * slot_bytes:(i + 1) * slot_bytes] for i in range(slots)]


class PeerClosed(ConnectionError):
    """The sidecar closed the local connection (it died, or dropped this client)."""


class LocalChannel:
    """Client side: the local connection, shaped like the ZeroMQ REQ socket it replaces
    (``send_multipart`` / ``poll`` / ``recv_multipart`` / ``close``), so the client's request loop,
    with its crash and hang checks, is the same on both paths. Replies to requests abandoned
    after a timeout are read and dropped (ZeroMQ's REQ_CORRELATE, by counting)."""

    def __init__(self, path: str, token: str, slots: int = DEFAULT_SLOTS, timeout: float = 30.0,
                 spin_us: int = 0, compact: bool = False):
        import select

        from simseam.sidecar.compact import COMPACT_VERSION
        from simseam.sidecar.wire import decode, encode

        self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
        try:
            self.sock.settimeout(timeout)
            self.sock.connect(path)
            ask = {"token": token, "slots": slots, "spin_us": int(spin_us)}
            if compact:
                ask["compact"] = COMPACT_VERSION
            send_message(self.sock, encode("attach", ask))
            msg = recv_message(self.sock, want_fds=1)
            if msg is None:
                raise PeerClosed("the sidecar closed the local connection during attach")
            frames, fds = msg
            try:
                op, body = decode(frames)
                if op != "ok":
                    raise WireError(f"attach refused: {body!r:.300}")
                if len(fds) > 1 or not isinstance(body, dict):
                    raise WireError(f"attach: bad reply ({len(fds)} descriptors)")
                layout = body.get("ring")
                if (layout is None) != (not fds):
                    raise WireError(f"attach: ring layout {layout!r:.200} does not match the {len(fds)} "
                                    "descriptor(s) passed")
                granted = body.get("compact")  # an older sidecar does not answer: msgpack only
                if granted is not None and (not compact or granted != COMPACT_VERSION):
                    raise WireError(f"attach: compact messages version {granted!r}, asked for "
                                    f"{COMPACT_VERSION if compact else 'none'}")
            except BaseException:
                for fd in fds:
                    os.close(fd)
                raise
            self.slots = map_slots(fds[0], layout) if fds else None
            self.layout = layout
            self.compact = granted is not None  # step messages may travel compact (simseam.sidecar.compact)
            self.sock.settimeout(timeout)  # a reply that starts must finish within the request timeout
        except BaseException:
            self.sock.close()
            raise
        self._poll = select.poll()
        self._poll.register(self.sock, select.POLLIN)
        self._outstanding = 0
        self._spin_s = spin_us * 1e-6
        self._spin_due = False
        self.closed = False
        self.on_stale = None  # called with each stale reply's frames before it is dropped (compact templates)

    def send_multipart(self, frames: list, copy: bool = False) -> None:
        send_message(self.sock, frames)
        self._outstanding += 1
        self._spin_due = True

    def poll(self, timeout_ms: int) -> int:
        """1 when the reply to the latest request (or the end of the connection) can be read. The
        first poll after a request busy-polls for up to ``spin_us`` before it sleeps."""
        if self._spin_due:
            self._spin_due = False
            if self._outstanding <= 1 and spin_until_readable(self._poll, self._spin_s):
                return 1
        while self._poll.poll(timeout_ms):
            if self._outstanding <= 1:
                return 1
            try:
                stale = recv_message(self.sock)  # a stale reply (its request timed out): drop it
                if stale is None:
                    return 1
            except Truncated:  # the sidecar died mid-reply: recv_multipart reports the end
                return 1
            if self.on_stale is not None:
                self.on_stale(stale[0])
            self._outstanding -= 1
            timeout_ms = 0
        return 0

    def recv_multipart(self, copy: bool = False) -> list:
        try:
            msg = recv_message(self.sock)
        except Truncated as exc:  # the sidecar died mid-reply: a crash, not a malformed message
            raise PeerClosed(str(exc)) from None
        if msg is None:
            raise PeerClosed("the sidecar closed the local connection")
        self._outstanding -= 1
        return msg[0]

    def close(self, linger: int | None = None) -> None:
        if not self.closed:
            self.closed = True
            self.sock.close()
            self.slots = None  # the mapping goes with the last observation that views it
            self.on_stale = None  # (the client's decoder holds the slots too)
