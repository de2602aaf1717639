"""The teamkf wire format: a fixed little-endian frame around a typed tree of raw arrays.

Frame, version 2 (every integer little-endian)::

    offset  size  field
    0       4     magic      b"TKFD"
    4       2     version    u16, 2
    6       1     kind       u8: 1 data (a payload), 2 hello (join and heartbeat), 3 bye (leave)
    7       1     flags      u8: bit 0 set = the sender dropped this message on purpose
                               (``--p-drop`` loss injection: an empty payload, recorded as a drop);
                               bit 1 set = unkeyed (``--insecure``: the tag is a plain SHA-256)
    8       8     run_id     u64: every frame of one run carries the same id
    16      4     sender     u32: agent id j
    20      4     receiver   u32: agent id i (the frame is for i only)
    24      4     step       u32: the step k at which the receiver fuses it (k = s + τ_ji);
                               for a hello, 0
    28      4     origin     u32: the step s at which the sender sent it; for a hello, the
                               sender's heartbeat counter (1, 2, ...: a replayed hello is refused)
    32      4     nbytes     u32: length of the payload that follows
    36      n     payload    the typed tree (below)
    36+n    32    tag        HMAC-SHA256 under the team key of bytes 0 .. 36+n-1 (header and
                               payload: every field above); unkeyed, their SHA-256

A frame is exactly 68 + n bytes. The tag is checked (:func:`hmac.compare_digest`) before
anything else of the frame is used, and the payload is decoded only after it matched:
a frame that was changed, re-stamped for another step, receiver, sender or run, or
forged without the key, is refused (reason ``auth``) without decoding a byte of its
payload. The payload is the agent's message, whatever
its family sends, as a tree of tagged values (one tag byte, then the value):

====  ==========  =====================================================================
tag   type        encoding after the tag
====  ==========  =====================================================================
0     None        nothing
1     bool        u8 (0 or 1)
2     int         i64
3     float       f64
4     str         u32 length, UTF-8 bytes
5     ndarray     u8 dtype code, u8 order (0 C, 1 Fortran), u8 ndim, ndim x u64 shape,
                  the raw little-endian elements in that order
6     list        u32 count, the items
7     tuple       u32 count, the items
8     dict        u32 count, (key, value) items
9     record      str "module:QualName", then the fields as a tuple: a NamedTuple or a
                  dataclass of a module the receiving process has already imported
====  ==========  =====================================================================

dtype codes: 1 float64, 2 float32, 3 int64, 4 int32, 5 bool, 6 complex128, 7 uint8,
8 int8, 9 uint32, 10 uint64. numpy scalars travel as 0-d arrays and come back as
numpy scalars, so the receiver computes with exactly the sender's bits. Nothing is
ever unpickled: a record names a class that must be a NamedTuple or a dataclass
already loaded by the receiver (the family's own module), anything else is refused.
"""

from __future__ import annotations

import dataclasses
import hashlib
import hmac
import struct
import sys
from dataclasses import dataclass
from typing import Any, NamedTuple

import numpy as np

from ..exceptions import TeamkfError

__all__ = [
    "MAGIC",
    "VERSION",
    "DATA",
    "HELLO",
    "BYE",
    "DROPPED",
    "UNKEYED",
    "HEADER_SIZE",
    "TAG_SIZE",
    "KEY_SIZE",
    "Frame",
    "Header",
    "open_frame",
    "FrameError",
    "encode_frame",
    "decode_frame",
    "encode_payload",
    "decode_payload",
]

MAGIC = b"TKFD"
VERSION = 2
DATA, HELLO, BYE = 1, 2, 3
#: flags bit 0: an injected drop (the message was not sent; the frame only says so)
DROPPED = 1
#: flags bit 1: the frame carries a plain SHA-256, not an HMAC (a sender without a key, ``--insecure``)
UNKEYED = 2
_HEADER = struct.Struct("<4sHBBQIIIII")
HEADER_SIZE = _HEADER.size  # 36
TAG_SIZE = 32
#: the team key's length in bytes (HMAC-SHA256); shorter keys are refused
KEY_SIZE = 32
_U32_MAX = 2**32 - 1

_DTYPES: dict[int, np.dtype] = {
    1: np.dtype("<f8"),
    2: np.dtype("<f4"),
    3: np.dtype("<i8"),
    4: np.dtype("<i4"),
    5: np.dtype("?"),
    6: np.dtype("<c16"),
    7: np.dtype("u1"),
    8: np.dtype("i1"),
    9: np.dtype("<u4"),
    10: np.dtype("<u8"),
}
_CODES = {dt.str: c for c, dt in _DTYPES.items()}  # "<f8" -> 1, "|b1" -> 5, ...


class FrameError(TeamkfError, ValueError):
    """A frame that is refused: ``reason`` is one of short, magic, version, auth, unkeyed, checksum, payload."""

    def __init__(self, reason: str, message: str) -> None:
        super().__init__(message, argument="frame")
        self.reason = reason


@dataclass(frozen=True)
class Frame:
    """One decoded frame (see the module docstring for the layout)."""

    kind: int
    run_id: int
    sender: int
    receiver: int
    step: int
    origin: int
    payload: Any = None
    flags: int = 0


# ---------------------------------------------------------------------------
# frames
# ---------------------------------------------------------------------------
class Header(NamedTuple):
    """The header fields of a frame whose tag matched (:func:`open_frame`), and its payload bytes, not yet decoded."""

    kind: int
    flags: int
    run_id: int
    sender: int
    receiver: int
    step: int
    origin: int
    body: bytes


def _check_key(key: bytes | None) -> None:
    if key is not None and (not isinstance(key, (bytes, bytearray)) or len(key) < KEY_SIZE):
        raise FrameError(
            "auth", f"key: expected at least {KEY_SIZE} bytes, found {len(key) if isinstance(key, (bytes, bytearray)) else type(key).__name__}"
        )


def _tag(key: bytes | None, data: bytes) -> bytes:
    return hmac.new(key, data, hashlib.sha256).digest() if key is not None else hashlib.sha256(data).digest()


def encode_frame(frame: Frame, key: bytes | None = None) -> bytes:
    """The bytes of ``frame``: header, typed payload, tag (HMAC-SHA256 under ``key``; without one a SHA-256, flagged unkeyed)."""
    _check_key(key)
    for name in ("sender", "receiver", "step", "origin"):
        v = getattr(frame, name)
        if not 0 <= v <= _U32_MAX:
            raise FrameError("payload", f"frame.{name}: expected an integer in 0..{_U32_MAX}, found {v}")
    if not 0 <= frame.run_id < 2**64:
        raise FrameError("payload", f"frame.run_id: expected an integer in 0..2**64-1, found {frame.run_id}")
    body = encode_payload(frame.payload)
    flags = (frame.flags & ~UNKEYED) | (UNKEYED if key is None else 0)
    head = _HEADER.pack(MAGIC, VERSION, frame.kind, flags, frame.run_id, frame.sender, frame.receiver, frame.step, frame.origin, len(body))
    data = head + body
    return data + _tag(key, data)


def open_frame(data: bytes | bytearray | memoryview, key: bytes | None = None) -> Header:
    """Check a frame's length, magic, version and tag, and return its header and raw payload (decoded by nobody yet).

    With ``key`` only a frame whose HMAC-SHA256 under ``key`` matches is opened (reason ``auth``
    otherwise, ``unkeyed`` for a frame of a sender without a key); without a key, only the plain
    SHA-256 of an unkeyed frame is checked (``checksum``: it catches corruption, not an attacker).
    """
    _check_key(key)
    buf = bytes(data)
    if len(buf) < HEADER_SIZE + TAG_SIZE:
        raise FrameError("short", f"frame: expected at least {HEADER_SIZE + TAG_SIZE} bytes, found {len(buf)}")
    magic, version, kind, flags, run_id, sender, receiver, step, origin, n = _HEADER.unpack_from(buf, 0)
    if magic != MAGIC:
        raise FrameError("magic", f"frame: expected the magic {MAGIC!r}, found {magic!r}; not a teamkf frame")
    if version != VERSION:
        raise FrameError("version", f"frame: expected version {VERSION}, found {version}; run the same teamkf version on every agent")
    if len(buf) != HEADER_SIZE + n + TAG_SIZE:
        raise FrameError("short", f"frame: the header announces {n} payload bytes ({HEADER_SIZE + n + TAG_SIZE} in all), found {len(buf)} bytes")
    signed, tag = buf[: HEADER_SIZE + n], buf[HEADER_SIZE + n :]
    if not hmac.compare_digest(_tag(key, signed), tag):
        if key is None:
            raise FrameError("checksum", "frame: the SHA-256 does not match (corrupted in transit, or signed with a key this agent does not hold)")
        if flags & UNKEYED:
            raise FrameError("unkeyed", "frame: not signed with a key (a sender run with --insecure); give every agent the roster's key")
        raise FrameError("auth", "frame: the HMAC-SHA256 tag does not match the team key (forged, altered, or of another key)")
    if key is None and not flags & UNKEYED:
        raise FrameError("checksum", "frame: signed with a key this agent does not hold")
    return Header(kind, flags & ~UNKEYED, run_id, sender, receiver, step, origin, buf[HEADER_SIZE : HEADER_SIZE + n])


def decode_frame(data: bytes | bytearray | memoryview, key: bytes | None = None) -> Frame:
    """Check (:func:`open_frame`) and decode one frame; :class:`FrameError` (with ``reason``) for anything refused."""
    h = open_frame(data, key)
    return Frame(h.kind, h.run_id, h.sender, h.receiver, h.step, h.origin, decode_payload(h.body), h.flags)


# ---------------------------------------------------------------------------
# the typed tree
# ---------------------------------------------------------------------------
def encode_payload(obj: Any) -> bytes:
    """The typed-tree bytes of a payload (the module docstring's table)."""
    out: list[bytes] = []
    _enc(obj, out)
    return b"".join(out)


def _enc(obj: Any, out: list[bytes]) -> None:
    if obj is None:
        out.append(b"\x00")
    elif isinstance(obj, bool):
        out.append(struct.pack("<BB", 1, int(obj)))
    elif isinstance(obj, np.ndarray) or isinstance(obj, np.generic):
        _enc_array(np.asarray(obj), out)
    elif isinstance(obj, int):
        out.append(struct.pack("<Bq", 2, obj))
    elif isinstance(obj, float):
        out.append(struct.pack("<Bd", 3, obj))
    elif isinstance(obj, str):
        b = obj.encode("utf-8")
        out.append(struct.pack("<BI", 4, len(b)) + b)
    elif isinstance(obj, tuple) and hasattr(obj, "_fields"):  # NamedTuple
        _enc_record(obj, tuple(obj), out)
    elif dataclasses.is_dataclass(obj) and not isinstance(obj, type):
        _enc_record(obj, tuple(getattr(obj, f.name) for f in dataclasses.fields(obj)), out)
    elif isinstance(obj, (list, tuple)):
        out.append(struct.pack("<BI", 6 if isinstance(obj, list) else 7, len(obj)))
        for x in obj:
            _enc(x, out)
    elif isinstance(obj, dict):
        out.append(struct.pack("<BI", 8, len(obj)))
        for k, v in obj.items():
            _enc(k, out)
            _enc(v, out)
    else:
        raise FrameError(
            "payload",
            f"payload: cannot encode a {type(obj).__name__} (expected None, numbers, str, arrays, lists, tuples, dicts, NamedTuples or dataclasses)",
        )


def _enc_array(a: np.ndarray, out: list[bytes]) -> None:
    code = _CODES.get(a.dtype.str.replace(">", "<"))
    if code is None:
        raise FrameError(
            "payload", f"payload: arrays of dtype {a.dtype} cannot travel; expected one of {', '.join(str(d) for d in _DTYPES.values())}"
        )
    fortran = a.ndim > 1 and a.flags.f_contiguous and not a.flags.c_contiguous
    raw = np.asarray(a, dtype=_DTYPES[code]).tobytes(order="F" if fortran else "C")
    out.append(struct.pack(f"<BBBB{a.ndim}Q", 5, code, int(fortran), a.ndim, *a.shape) + raw)


def _enc_record(obj: Any, values: tuple, out: list[bytes]) -> None:
    cls = type(obj)
    name = f"{cls.__module__}:{cls.__qualname__}".encode("utf-8")
    out.append(struct.pack("<BI", 9, len(name)) + name)
    _enc(values, out)


def decode_payload(data: bytes) -> Any:
    """The payload of typed-tree bytes; :class:`FrameError` ("payload") when malformed."""
    try:
        obj, pos = _dec(memoryview(data), 0, 0)
    except FrameError:
        raise
    except (struct.error, ValueError, IndexError, UnicodeDecodeError, OverflowError) as exc:
        raise FrameError("payload", f"payload: malformed typed tree ({exc})") from None
    if pos != len(data):
        raise FrameError("payload", f"payload: {len(data) - pos} trailing bytes after the typed tree")
    return obj


def _dec(b: memoryview, pos: int, depth: int) -> tuple[Any, int]:
    if depth > 64:
        raise FrameError("payload", "payload: nested deeper than 64 levels")
    tag = b[pos]
    pos += 1
    if tag == 0:
        return None, pos
    if tag == 1:
        return bool(b[pos]), pos + 1
    if tag == 2:
        return struct.unpack_from("<q", b, pos)[0], pos + 8
    if tag == 3:
        return struct.unpack_from("<d", b, pos)[0], pos + 8
    if tag == 4:
        (n,) = struct.unpack_from("<I", b, pos)
        pos += 4
        if pos + n > len(b):
            raise FrameError("payload", "payload: a string runs past the end")
        return bytes(b[pos : pos + n]).decode("utf-8"), pos + n
    if tag == 5:
        code, fortran, ndim = struct.unpack_from("<BBB", b, pos)
        pos += 3
        if code not in _DTYPES:
            raise FrameError("payload", f"payload: unknown dtype code {code}")
        shape = struct.unpack_from(f"<{ndim}Q", b, pos)
        pos += 8 * ndim
        dt = _DTYPES[code]
        count = int(np.prod(shape, dtype=np.uint64)) if ndim else 1
        nbytes = count * dt.itemsize
        if pos + nbytes > len(b):
            raise FrameError("payload", f"payload: an array of shape {tuple(shape)} runs past the end")
        flat = np.frombuffer(b[pos : pos + nbytes], dtype=dt).astype(dt.newbyteorder("="), copy=True)
        arr = flat.reshape(shape, order="F" if fortran else "C")
        return (arr[()] if ndim == 0 else arr), pos + nbytes
    if tag in (6, 7, 8):
        (n,) = struct.unpack_from("<I", b, pos)
        pos += 4
        if n > len(b) - pos:
            raise FrameError("payload", f"payload: a container announces {n} items in {len(b) - pos} bytes")
        if tag == 8:
            d = {}
            for _ in range(n):
                k, pos = _dec(b, pos, depth + 1)
                v, pos = _dec(b, pos, depth + 1)
                try:
                    d[k] = v
                except TypeError:
                    raise FrameError("payload", f"payload: a dict key of type {type(k).__name__} is not hashable") from None
            return d, pos
        items = []
        for _ in range(n):
            x, pos = _dec(b, pos, depth + 1)
            items.append(x)
        return (items if tag == 6 else tuple(items)), pos
    if tag == 9:
        (n,) = struct.unpack_from("<I", b, pos)
        pos += 4
        name = bytes(b[pos : pos + n]).decode("utf-8")
        pos += n
        values, pos = _dec(b, pos, depth + 1)
        if not isinstance(values, tuple):
            raise FrameError("payload", f"payload: the fields of record {name} are not a tuple")
        return _record(name, values), pos
    raise FrameError("payload", f"payload: unknown tag {tag}")


def _record(name: str, values: tuple) -> Any:
    """Rebuild a NamedTuple or dataclass from a module that is already imported (never imports, never unpickles)."""
    mod_name, _, qual = name.partition(":")
    obj: Any = sys.modules.get(mod_name)
    if obj is None:
        raise FrameError("payload", f"payload: record type {name}: module {mod_name!r} is not loaded by this agent")
    for part in qual.split("."):
        obj = getattr(obj, part, None)
    if not isinstance(obj, type) or not ((issubclass(obj, tuple) and hasattr(obj, "_fields")) or dataclasses.is_dataclass(obj)):
        raise FrameError("payload", f"payload: record type {name} is not a NamedTuple or a dataclass of a loaded module")
    try:
        if issubclass(obj, tuple):
            return obj(*values)
        fields = [f.name for f in dataclasses.fields(obj)]
        if len(fields) != len(values):
            raise FrameError("payload", f"payload: record type {name} has {len(fields)} fields, found {len(values)} values")
        inst = object.__new__(obj)
        for f, v in zip(fields, values):
            object.__setattr__(inst, f, v)
        return inst
    except TypeError as exc:
        raise FrameError("payload", f"payload: record type {name}: {exc}") from None
