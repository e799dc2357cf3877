"""The wire codec of protocol version 1 (see SPEC.md), shared by the server and every client.

Messages are flat msgpack maps (envelope + fields). Arrays travel as
``{"dtype", "shape", "data": <raw little-endian bytes>}``; decoders also take nested lists.
Optional HMAC-SHA256 signature: ``sig`` is the last map entry and signs every byte before it.
"""

from __future__ import annotations

import gc
import hashlib
import hmac
import itertools
import json
import math
import os
import sys
import re
import struct
from dataclasses import dataclass
from enum import IntEnum
from functools import cached_property
from typing import Any, Iterator

import msgpack
import numpy as np

PROTOCOL_VERSION = 1
SUPPORTED_VERSIONS = (1,)
MAX_MESSAGE_BYTES = 64 * 2**20        # default: all frames of a message together (SPEC §1; serve --max-message-mib)
FRAME_CAP_FACTOR = 2                  # a frame over this many times the limit is refused by ZeroMQ (SPEC §1)
MAX_DECODED_CONTAINERS = 2**14       # maps and lists in one decoded message (SPEC §2; revision 1.19, was 2**16)
MAX_DECODED_ITEMS = 2**16             # their entries (list items, map keys and values) in one decoded message (was
                                      # 2**18): what a refused message makes first holds the loop (~0.15 µs each)
SMALL_FRAME = 16 * 2**10              # a frame this small decodes without counting (as many objects as bytes at most:
                                      # within MAX_DECODED_CONTAINERS; was 32 KiB)
FEW_OBJECTS = 2**14                   # a larger frame of at most this many objects decodes without counting
MANY_OBJECTS_BYTES = 2**20            # a frame of more objects is at most this large (was 2 MiB; nil: a list slot, no object)
METER_BYTES = 16 * 2**10              # a many-object frame's decoding checks what it made every this many bytes
MAX_ROUTING_FRAMES = 8
MAX_ROUTING_FRAME_BYTES = 255         # a ZeroMQ routing identity's limit
DIRECT_HEADER = struct.Struct("<I")   # a direct channel frame's length, little-endian (SPEC §5.7.5)
SIG_TRAILER = b"\xa3sig\xc4\x20"  # fixstr "sig" + bin8 header of length 32
SIG_LEN = 32
ROLES = ("multibody", "controller", "monitor")
IMPLEMENTED_ROLES = ("multibody", "controller")
REQUEST_TYPES = ("hello", "step", "ping", "bye", "measure", "command", "upload", "save", "restore", "release")
REPLY_TYPES = ("welcome", "forces", "pong", "goodbye", "error", "measurements", "idle", "stop", "uploaded",
               "saved", "restored", "released")

# dtypes a decoder takes; senders use "<f8", "<c16", "<i8", "|b1"
ACCEPTED_DTYPES = {s: np.dtype(s) for s in ("<f8", "<f4", "<c16", "<i8", "<i4", "|b1")}
_F8 = np.dtype(np.float64)


class Code(IntEnum):
    """Numbered error codes (SPEC §5.6); ``name.lower()`` is the wire name."""

    MALFORMED = 1
    VERSION_MISMATCH = 2
    UNKNOWN_TYPE = 3
    MISSING_FIELD = 4
    BAD_VALUE = 5
    OUT_OF_ORDER = 6
    UNKNOWN_SESSION = 7
    BAD_SCENE = 8
    BAD_HDB = 9
    WRONG_STATE = 10
    BAD_SIGNATURE = 11
    NOT_IMPLEMENTED = 12
    MISSING_CONTENT = 13
    BUSY = 14
    UNAUTHORIZED = 15
    SESSION_FAILED = 16
    INTERNAL = 99


def code_name(code: int) -> str:
    """Wire name of an error code ("internal" for codes this version does not know)."""
    try:
        return Code(code).name.lower()
    except ValueError:
        return "internal"


class ProtocolError(Exception):
    """A request that breaks the protocol; becomes an ``error`` reply with these fields."""

    def __init__(self, code: int, field: str | None, message: str, name: str | None = None,
                 extra: dict | None = None):
        self.code = int(code)
        self.name = name or code_name(code)
        self.field = field
        self.message = message
        self.extra = extra or {}   # further reply fields a code defines (13: ``missing``)
        self.parent: Any = None  # msg_id of the offending request, when known only here
        where = f" [{field}]" if field else ""
        super().__init__(f"error {self.code} {self.name}{where}: {message}")


class EncodeError(ValueError):
    """A message holding a value msgpack cannot carry (an int outside [-2^63, 2^64), an object);
    ``field`` is the value's path in the message."""

    def __init__(self, field: str, why: str):
        self.field, self.why = field, why
        super().__init__(f"{field}: {why}")


# ---------------------------------------------------------------- arrays

def encode_array(a: np.ndarray) -> dict:
    """Array -> wire map with raw little-endian C-order bytes."""
    dt = a.dtype
    if dt.byteorder == ">" or (dt.byteorder == "=" and not np.little_endian and dt.itemsize > 1):
        a = a.astype(dt.newbyteorder("<"))
        dt = a.dtype
    return {"dtype": dt.str, "shape": list(a.shape), "data": a.tobytes()}


def _default(obj: Any) -> Any:
    if isinstance(obj, np.ndarray):
        return encode_array(obj)
    if isinstance(obj, np.generic):
        if isinstance(obj, np.complexfloating):
            return encode_array(np.asarray(obj))
        return obj.item()
    if isinstance(obj, (tuple, set, frozenset)):
        return list(obj)
    if isinstance(obj, int):
        raise TypeError(f"the int {obj:.6g} is outside the 64-bit range the wire carries ([-2^63, 2^64))")
    raise TypeError(f"cannot encode {type(obj).__name__} for the wire")


def _unencodable(value: Any, path: str, depth: int = 0) -> tuple[str, str] | None:
    """(path, why) of the first value in ``value`` msgpack cannot carry (the cold path of :func:`pack`)."""
    if depth > MAX_TREE_DEPTH + 4:
        return None
    if isinstance(value, dict):
        for k, v in value.items():
            found = _unencodable(v, key_path(path, k) if path else str(k), depth + 1)
            if found:
                return found
        return None
    if isinstance(value, (list, tuple)):
        for i, v in enumerate(value):
            found = _unencodable(v, f"{path}[{i}]", depth + 1)
            if found:
                return found
        return None
    try:
        msgpack.packb(value, default=_default)
    except (TypeError, ValueError, OverflowError) as exc:
        return path, str(exc)
    return None


def _is_array_map(value: Any) -> bool:
    return isinstance(value, dict) and "dtype" in value and "shape" in value and "data" in value


def decode_array(value: Any, field: str, kind: str = "f") -> np.ndarray:
    """Wire value -> ndarray. ``kind``: "f" float64, "c" complex128, "i" int64, "b" bool, "" as sent.

    Takes the binary map or nested lists / a plain number; raises ProtocolError 5 naming ``field``."""
    if isinstance(value, dict):
        try:
            dtype = ACCEPTED_DTYPES[value["dtype"]]
        except (KeyError, TypeError):
            raise ProtocolError(Code.BAD_VALUE, field,
                                f"array dtype must be one of {sorted(ACCEPTED_DTYPES)}, got {describe(value.get('dtype'))}") from None
        shape, data = value.get("shape"), value.get("data")
        if not isinstance(shape, list) or not all(type(n) is int and n >= 0 for n in shape):
            raise ProtocolError(Code.BAD_VALUE, field, f"array shape must be a list of ints >= 0, got {describe(shape)}")
        if not isinstance(data, (bytes, bytearray)):
            raise ProtocolError(Code.BAD_VALUE, field, f"array data must be bin, got {type(data).__name__}")
        if len(data) != math.prod(shape) * dtype.itemsize:
            raise ProtocolError(Code.BAD_VALUE, field,
                                f"array data has {len(data)} bytes, shape {shape} of {value['dtype']} needs "
                                f"{math.prod(shape) * dtype.itemsize}")
        arr = np.frombuffer(data, dtype).reshape(shape)
    elif isinstance(value, np.ndarray):  # in-process callers
        arr = value
    elif isinstance(value, list) or (isinstance(value, (int, float)) and not isinstance(value, bool)):
        target = {"f": np.float64, "i": np.int64, "b": np.bool_, "c": None, "": None}[kind]
        try:
            arr = np.asarray(value, dtype=target)
        except (ValueError, TypeError) as exc:
            raise ProtocolError(Code.BAD_VALUE, field, f"not a rectangular array of numbers ({exc})") from None
        if arr.dtype == object or arr.dtype.kind in "USV":
            raise ProtocolError(Code.BAD_VALUE, field, "not a rectangular array of numbers")
    else:
        raise ProtocolError(Code.BAD_VALUE, field,
                            f"must be an array (map with dtype/shape/data, or nested lists), got {type(value).__name__}")
    if kind == "f":
        if arr.dtype.kind not in "fiub":
            raise ProtocolError(Code.BAD_VALUE, field, f"must be a real array, got dtype {arr.dtype.str}")
        if arr.dtype != np.float64:
            arr = arr.astype(np.float64)
    elif kind == "c":
        if arr.dtype.kind not in "fiubc":
            raise ProtocolError(Code.BAD_VALUE, field, f"must be a numeric array, got dtype {arr.dtype.str}")
        arr = arr.astype(np.complex128, copy=False)
    elif kind == "i":
        if arr.dtype.kind not in "iub":
            raise ProtocolError(Code.BAD_VALUE, field, f"must be an integer array, got dtype {arr.dtype.str}")
        arr = arr.astype(np.int64, copy=False)
    elif kind == "b":
        arr = arr.astype(np.bool_, copy=False)
    return arr


MAX_TREE_DEPTH = 16   # maps and lists nested deeper than this in a setup map are refused


def decode_tree(obj: Any, field: str = "", depth: int = 0) -> Any:
    """Recursively replace every array map by an ndarray (for setup/HDB maps, not the hot path);
    ``field`` is the value's error path. Nesting deeper than MAX_TREE_DEPTH is error 5."""
    if depth > MAX_TREE_DEPTH:
        raise ProtocolError(Code.BAD_VALUE, field or None, f"nested deeper than {MAX_TREE_DEPTH} levels")
    if _is_array_map(obj):
        return decode_array(obj, field, kind="")
    if isinstance(obj, dict):
        return {k: decode_tree(v, key_path(field, k) if field else str(k), depth + 1) for k, v in obj.items()}
    if isinstance(obj, list):
        return [decode_tree(v, f"{field}[{i}]", depth + 1) for i, v in enumerate(obj)]
    return obj


# ---------------------------------------------------------------- frames

def _packb(msg: dict) -> bytes:
    try:
        return msgpack.packb(msg, default=_default)
    except (TypeError, ValueError, OverflowError) as exc:
        field, why = _unencodable(msg, "") or ("", str(exc))
        raise EncodeError(field, why) from None


def pack(msg: dict, key: bytes | None = None) -> bytes:
    """Message map -> one frame; with ``key`` appends the HMAC ``sig`` as the last entry.
    EncodeError naming the field when a value cannot travel (an int past 64 bits)."""
    if key is None:
        return _packb(msg)
    body = {k: v for k, v in msg.items() if k != "sig"}
    body["sig"] = bytes(SIG_LEN)
    frame = _packb(body)
    head = frame[:-SIG_LEN]
    return head + hmac.new(key, head, hashlib.sha256).digest()


def verify(frame: bytes, key: bytes) -> None:
    """Check a frame's trailing signature in constant time; ProtocolError 11 if absent or wrong."""
    if len(frame) < len(SIG_TRAILER) + SIG_LEN or frame[-SIG_LEN - len(SIG_TRAILER):-SIG_LEN] != SIG_TRAILER:
        raise ProtocolError(Code.BAD_SIGNATURE, "sig", "message is not signed (a key is required): "
                            "'sig' must be the last map entry, a 32-byte bin")
    head = frame[:-SIG_LEN]
    if not hmac.compare_digest(hmac.new(key, head, hashlib.sha256).digest(), frame[-SIG_LEN:]):
        raise ProtocolError(Code.BAD_SIGNATURE, "sig", "signature does not match (wrong key or altered message)")


def frame_cap(max_message_bytes: int) -> int:
    """The largest single frame a receiver takes from ZeroMQ (``ZMQ_MAXMSGSIZE``) for a message
    limit: over it the connection is dropped unanswered; between the limit and it the message is
    received and refused with error 1 naming the limit (SPEC §1)."""
    return FRAME_CAP_FACTOR * int(max_message_bytes)


def over_limit(size: int, max_message_bytes: int) -> ProtocolError:
    """Error 1 for a message of ``size`` bytes over a receiver's limit (SPEC §1): names the limit,
    and carries it as ``limit`` = "message_bytes", ``maximum`` (bytes)."""
    return ProtocolError(Code.MALFORMED, None,
                         f"message of {size} bytes over all its frames; at most {max_message_bytes} "
                         f"({max_message_bytes / 2**20:g} MiB, this server's --max-message-mib; SPEC §1): "
                         "send HDB files by hash, one upload each (SPEC §5.8)",
                         extra={"limit": "message_bytes", "maximum": int(max_message_bytes)})


class _TooMany(Exception):
    """Raised from inside msgpack's hooks: the decoded message passed a bound (``args``: which)."""


class _Metered:
    """The frame as a file msgpack's Unpacker reads in chunks; before each chunk, the objects made
    since the start (pymalloc blocks: every str, int, float, map and list an entry makes, also in
    lists not yet complete, which msgpack's hooks do not see) are checked against the bound."""

    def __init__(self, frame, bound: int):
        self.buf, self.pos, self.bound = memoryview(frame).cast("B"), 0, bound
        self.start = sys.getallocatedblocks()

    def read(self, n: int) -> bytes:
        if sys.getallocatedblocks() - self.start > self.bound:
            raise _TooMany("items")
        if self.pos >= MANY_OBJECTS_BYTES:
            raise _TooMany("bytes")
        chunk = self.buf[self.pos:self.pos + n]
        self.pos += len(chunk)
        return bytes(chunk)


def _counted_unpackb(frame, max_bytes: int) -> Any:
    """msgpack's decoding with SPEC §2's bounds, for a frame of many objects (``_few_objects`` said
    no): no str/bin over the frame's own size, at most MAX_DECODED_CONTAINERS maps and lists and
    MAX_DECODED_ITEMS entries (a map's counting two, key and value), counted as each container
    completes, and the objects made so far metered every METER_BYTES read (:class:`_Metered`: lists
    nested in lists not yet complete), of at most MANY_OBJECTS_BYTES read (what such lists hold
    costs 8 B a byte read, singletons such as nil too); _TooMany past a bound. Python's cyclic garbage collector is
    paused meanwhile: it would walk every container made so far, again and again (2 million empty
    lists, counted, on a loaded 2-core machine: 1.6 s with it, 0.6 s without)."""
    containers, items = MAX_DECODED_CONTAINERS, MAX_DECODED_ITEMS

    def listed(container):
        nonlocal containers, items
        containers -= 1
        items -= len(container)
        if containers < 0 or items < 0:
            raise _TooMany("containers" if containers < 0 else "items")
        return container

    def mapped(container):
        nonlocal containers, items
        containers -= 1
        items -= 2 * len(container)
        if containers < 0 or items < 0:
            raise _TooMany("containers" if containers < 0 else "items")
        return container

    collecting = gc.isenabled()
    gc.disable()
    try:
        reader = _Metered(frame, MAX_DECODED_ITEMS + MAX_DECODED_CONTAINERS)
        unpacker = msgpack.Unpacker(reader, read_size=METER_BYTES, max_buffer_size=max(max_bytes, METER_BYTES), raw=False,
                                    strict_map_key=True, list_hook=listed, object_hook=mapped,
                                    max_str_len=max_bytes, max_bin_len=max_bytes, max_ext_len=max_bytes,
                                    max_array_len=MAX_DECODED_ITEMS, max_map_len=MAX_DECODED_ITEMS // 2)
        msg = unpacker.unpack()
        if unpacker.tell() != len(reader.buf):
            raise ValueError(f"{len(reader.buf) - unpacker.tell()} bytes of extra data after the message")
        return msg
    finally:
        if collecting:
            gc.enable()


def _few_objects(frame, budget: int = FEW_OBJECTS) -> bool:
    """Whether a frame holds at most ``budget`` msgpack objects, from their headers alone (str and
    bin payloads jumped over): then decoding it cannot make much more than the frame's own size. A
    frame malformed within the budget is True too (msgpack refuses it at the same place)."""
    try:
        buf = memoryview(frame).cast("B")
        pos, left = 0, 1
        while left:
            budget -= 1
            if budget < 0:
                return False
            pos, inner = _head(buf, pos)
            left += inner - 1
        return True
    except (_Unpeekable, IndexError, ValueError):
        return True


def unpack(frame: bytes | memoryview, key: bytes | None = None) -> dict:
    """Frame -> message map (``sig`` removed). ProtocolError 1 if not a msgpack map or over the
    decoding bounds (SPEC §2: MAX_DECODED_CONTAINERS maps and lists, MAX_DECODED_ITEMS entries; a
    frame of at most SMALL_FRAME bytes, or of at most FEW_OBJECTS objects by their headers, cannot
    reach them and is decoded without counting), then 11
    if badly signed (the error carries the unverified ``msg_id`` as ``exc.parent``). ``frame`` may
    be a memoryview (a received frame, not copied); values never refer to it."""
    try:
        if len(frame) <= SMALL_FRAME or _few_objects(frame):
            msg = msgpack.unpackb(frame, raw=False, strict_map_key=True)
        else:
            msg = _counted_unpackb(frame, len(frame))
    except _TooMany as exc:
        if exc.args[0] == "bytes":
            raise ProtocolError(Code.MALFORMED, None, f"a message of more than {FEW_OBJECTS} msgpack objects is at "
                                f"most {MANY_OBJECTS_BYTES} bytes; this one is {len(frame)} (SPEC §2: send arrays as "
                                "binary array maps)", extra={"limit": "many_objects_bytes",
                                                             "maximum": MANY_OBJECTS_BYTES}) from None
        kind, bound, what = (("decoded_containers", MAX_DECODED_CONTAINERS, "maps and lists")
                             if exc.args[0] == "containers" else
                             ("decoded_items", MAX_DECODED_ITEMS, "entries (list items, map keys and values)"))
        raise ProtocolError(Code.MALFORMED, None, f"message holds more {what} than a message may: at most {bound} "
                            "(SPEC §2: send arrays as binary array maps)",
                            extra={"limit": kind, "maximum": bound}) from None
    except MemoryError:
        raise ProtocolError(Code.BUSY, None, f"the server has no memory to decode a message of {len(frame)} bytes "
                            "now; send it again later", extra={"limit": "memory"}) from None
    except Exception as exc:  # msgpack raises several unrelated types for garbage
        raise ProtocolError(Code.MALFORMED, None, f"frame is not a msgpack object ({type(exc).__name__}: {exc})") from None
    if not isinstance(msg, dict):
        raise ProtocolError(Code.MALFORMED, None, f"message must be a msgpack map, got {type(msg).__name__}")
    if key is not None:
        try:
            verify(frame, key)
        except ProtocolError as exc:
            exc.parent = readable_id(msg)
            raise
    msg.pop("sig", None)
    return msg


# msgpack type bytes 0xc4-0xdf: (bytes of a length field, fixed size after the type byte, kind)
# kind: "s" scalar, "b" a payload of that length (bin, str, ext: +1 type byte), "a" array, "m" map
_HEADS = {0xc4: (1, 0, "b"), 0xc5: (2, 0, "b"), 0xc6: (4, 0, "b"), 0xc7: (1, 1, "b"), 0xc8: (2, 1, "b"),
          0xc9: (4, 1, "b"), 0xca: (0, 4, "s"), 0xcb: (0, 8, "s"), 0xcc: (0, 1, "s"), 0xcd: (0, 2, "s"),
          0xce: (0, 4, "s"), 0xcf: (0, 8, "s"), 0xd0: (0, 1, "s"), 0xd1: (0, 2, "s"), 0xd2: (0, 4, "s"),
          0xd3: (0, 8, "s"), 0xd4: (0, 2, "s"), 0xd5: (0, 3, "s"), 0xd6: (0, 5, "s"), 0xd7: (0, 9, "s"),
          0xd8: (0, 17, "s"), 0xd9: (1, 0, "b"), 0xda: (2, 0, "b"), 0xdb: (4, 0, "b"), 0xdc: (2, 0, "a"),
          0xdd: (4, 0, "a"), 0xde: (2, 0, "m"), 0xdf: (4, 0, "m")}


class _Unpeekable(Exception):
    """A frame :func:`peek` cannot read within its budget (then it is decoded as usual)."""


def _head(buf, pos: int) -> tuple[int, int]:
    """(where the object at ``pos`` ends, or its first entry for a map/list; how many objects it holds)."""
    b = buf[pos]
    if b <= 0x7f or b >= 0xe0 or b in (0xc0, 0xc2, 0xc3):
        return pos + 1, 0
    if b <= 0x8f:
        return pos + 1, 2 * (b & 0x0F)
    if b <= 0x9f:
        return pos + 1, b & 0x0F
    if b <= 0xbf:
        return pos + 1 + (b & 0x1F), 0
    if b not in _HEADS:
        raise _Unpeekable
    size, fixed, kind = _HEADS[b]
    n = int.from_bytes(buf[pos + 1:pos + 1 + size], "big")
    end = pos + 1 + size
    if kind == "s":
        return end + fixed, 0
    if kind == "b":
        return end + fixed + n, 0
    return end, 2 * n if kind == "m" else n


def _plain(b: int) -> bool:
    """Whether a msgpack type byte starts a scalar or a str (not a map, list, bin or ext)."""
    return b <= 0x7f or b >= 0xe0 or b in (0xc0, 0xc2, 0xc3) or 0xa0 <= b <= 0xbf or 0xca <= b <= 0xd3 \
        or 0xd9 <= b <= 0xdb


def peek(frame: bytes | memoryview, keys: tuple[str, ...], budget: int = 4096) -> dict | None:
    """The top-level entries named ``keys`` of a msgpack map frame whose values are scalars (nil,
    bool, int, float, str), read without decoding the rest: str and bin payloads are jumped over,
    nested maps and lists walked by their headers, at most ``budget`` objects in all. None for a
    frame that is not such a map or needs a longer walk. For a receiver that can refuse a request
    by its envelope alone (a hello to a full server) without copying its content."""
    try:
        buf = memoryview(frame).cast("B")
        pos, n = _head(buf, 0)
        if buf[0] not in (0xde, 0xdf) and not 0x80 <= buf[0] <= 0x8f:
            return None
        out: dict = {}
        for _ in range(n // 2):
            start = pos
            pos, inner = _head(buf, pos)
            if inner or pos - start > 64:
                return None   # keys are short strings
            key = msgpack.unpackb(buf[start:pos])
            start, left = pos, 1
            while left:   # the value: one object, with everything nested in it
                budget -= 1
                if budget < 0:
                    return None
                pos, inner = _head(buf, pos)
                left += inner - 1
            if key in keys and _plain(buf[start]) and pos - start <= 1024:
                out[key] = msgpack.unpackb(buf[start:pos], raw=False)
        return out if pos == len(buf) else None
    except (_Unpeekable, IndexError, ValueError, TypeError, UnicodeDecodeError, msgpack.UnpackException):
        return None


# ---------------------------------------------------------------- fields

_IDENTIFIER = re.compile(r"[A-Za-z_][A-Za-z0-9_]*")


def key_path(prefix: str, key: str) -> str:
    """The error path of map entry ``key`` under ``prefix`` (SPEC §5.6): ``prefix.key`` for an
    identifier, else ``prefix["key"]`` (JSON string), so keys holding dots stay one step."""
    key = str(key)
    return f"{prefix}.{key}" if _IDENTIFIER.fullmatch(key) else f"{prefix}[{json.dumps(key)}]"


def describe(value: Any, limit: int = 60) -> str:
    """A client's value as an error message shows it: scalars by their repr cut to ``limit``
    characters, containers by their type and length only (never walked: a value nested a
    million deep, or a 100 MB string, costs nothing to describe)."""
    if value is None or isinstance(value, (bool, int, float)):
        text = repr(value)
    elif isinstance(value, str):
        text = repr(value[:limit + 1])
    elif isinstance(value, (bytes, bytearray, memoryview)):
        return f"bin of {len(value)} bytes"
    elif isinstance(value, (list, tuple)):
        return f"array of {len(value)} items"
    elif isinstance(value, dict):
        return f"map of {len(value)} entries"
    else:
        return type(value).__name__
    return text if len(text) <= limit else text[:limit] + "..."


def without_nil(msg: dict, depth: int = 0) -> dict:
    """The request map with every nil entry removed, in nested maps too (SPEC §2: a field whose
    value is nil counts as absent): one rule for every optional field, applied once on receipt.
    Array maps (§2.1) are values and lists hold values, not fields: both are left as sent, as are
    maps nested deeper than MAX_TREE_DEPTH (:func:`decode_tree` refuses them). A map with neither
    nil nor a nested map is returned as it is (a step: no copy on the hot path)."""
    if depth > MAX_TREE_DEPTH:
        return msg
    for v in msg.values():
        if v is None or (type(v) is dict and not _is_array_map(v)):
            break
    else:
        return msg
    return {k: without_nil(v, depth + 1) if type(v) is dict and not _is_array_map(v) else v
            for k, v in msg.items() if v is not None}


def require(msg: dict, field: str, path: str | None = None) -> Any:
    """The value of a required field (nil counts as missing); ProtocolError 4 otherwise."""
    value = msg.get(field)
    if value is None:
        raise ProtocolError(Code.MISSING_FIELD, path or field, f"required field {field!r} is missing")
    return value


def require_int(msg: dict, field: str, *, default: int | None = None, minimum: int | None = None,
                path: str | None = None) -> int:
    """A required (or defaulted) int field, optionally >= minimum."""
    value = msg.get(field)
    if value is None:
        if default is not None:
            return default
        return require(msg, field, path)
    if type(value) is not int:
        raise ProtocolError(Code.BAD_VALUE, path or field, f"must be an int, got {describe(value)}")
    if minimum is not None and value < minimum:
        raise ProtocolError(Code.BAD_VALUE, path or field, f"must be >= {minimum}, got {value}")
    return value


def require_float(msg: dict, field: str, path: str | None = None) -> float:
    """A required finite number."""
    value = require(msg, field, path)
    if type(value) not in (float, int):
        raise ProtocolError(Code.BAD_VALUE, path or field, f"must be a number, got {describe(value)}")
    if not math.isfinite(value):
        raise ProtocolError(Code.BAD_VALUE, path or field, f"must be finite, got {value}")
    return float(value)


def _require_typed(msg: dict, field: str, kind: type, kind_name: str, default, path: str | None):
    value = msg.get(field)
    if value is None and default is not None:
        return default
    value = require(msg, field, path)
    if not isinstance(value, kind):
        raise ProtocolError(Code.BAD_VALUE, path or field, f"must be a {kind_name}, got {type(value).__name__}")
    return value


def require_str(msg: dict, field: str, *, default: str | None = None, path: str | None = None) -> str:
    """A required (or defaulted) str field."""
    return _require_typed(msg, field, str, "str", default, path)


def require_map(msg: dict, field: str, *, default: dict | None = None, path: str | None = None) -> dict:
    """A required (or defaulted) map field."""
    return _require_typed(msg, field, dict, "map", default, path)


def unread_error(reply: dict) -> bool:
    """An error to a request the server could not read (``parent`` nil: SPEC §5.6), such as one over
    its message limit (SPEC §1): with one request in flight, it is that request's answer."""
    return reply.get("type") == "error" and reply.get("parent") is None


def within(arr: np.ndarray, bound: float) -> bool:
    """Every element of float64 ``arr`` within [-bound, bound] (NaN and inf fail it)."""
    if arr.size <= 64:   # max |x| <= bound; NaN and inf (which max can pass over) fail the sum
        values = arr.ravel().tolist()
        return not values or (max(map(abs, values)) <= bound and math.isfinite(sum(values)))
    return bool(np.all(np.abs(arr) <= bound))


def require_array(msg: dict, field: str, shape: tuple[int | None, ...], *, finite: bool = True,
                  bound: float | None = None, path: str | None = None) -> np.ndarray:
    """A required float64 array of ``shape`` (None = any length), all finite by default; with
    ``bound`` every element within [-bound, bound] (NaN and inf fail it too)."""
    name = path or field
    value = msg.get(field)
    if type(value) is np.ndarray and value.dtype is _F8 and value.shape == shape:
        arr = value  # hot path in-process (a map handed over without msgpack): float64 of the shape
    elif type(value) is dict and value.get("dtype") == "<f8" and value.get("shape") == list(shape) \
            and type(value.get("data")) is bytes and len(value["data"]) == 8 * math.prod(shape):
        arr = np.frombuffer(value["data"], np.float64).reshape(shape)  # hot path: well-formed binary
    else:
        arr = decode_array(require(msg, field, path), name, "f")
    if arr.shape != shape and (arr.ndim != len(shape)
                               or any(w is not None and w != n for w, n in zip(shape, arr.shape))):
        want = "(" + ", ".join("*" if w is None else str(w) for w in shape) + ")"
        raise ProtocolError(Code.BAD_VALUE, name, f"shape must be {want}, got {tuple(arr.shape)}")
    if bound is not None:
        inside = within(arr, bound)
    else:
        inside = not finite or (all(map(math.isfinite, arr.ravel().tolist())) if arr.size <= 64
                                else bool(np.isfinite(arr).all()))
    if not inside:
        if not np.isfinite(arr).all():
            bad = tuple(int(i) for i in np.argwhere(~np.isfinite(arr))[0])
            raise ProtocolError(Code.BAD_VALUE, name, f"contains NaN or inf (first at index {list(bad)})")
        bad = tuple(int(i) for i in np.argwhere(np.abs(arr) > bound)[0])
        raise ProtocolError(Code.BAD_VALUE, name, f"|value| must be <= {bound:g}, got {float(arr[bad]):g} at index "
                                                  f"{list(bad)}")
    return arr


# ---------------------------------------------------------------- envelope

def check_envelope(msg: dict) -> tuple[str, Any, str | None]:
    """Validate ``v``, ``type``, ``msg_id``, ``session``; returns (type, msg_id, session)."""
    if "v" not in msg or msg["v"] is None:
        raise ProtocolError(Code.MISSING_FIELD, "v", "required field 'v' (protocol version) is missing")
    if msg["v"] not in SUPPORTED_VERSIONS or type(msg["v"]) is not int:
        raise ProtocolError(Code.VERSION_MISMATCH, "v",
                            f"protocol version {describe(msg['v'])} not supported; this server speaks {list(SUPPORTED_VERSIONS)}")
    mtype = msg.get("type")
    if mtype is None:
        raise ProtocolError(Code.MISSING_FIELD, "type", "required field 'type' is missing")
    if mtype not in REQUEST_TYPES or not isinstance(mtype, str):
        raise ProtocolError(Code.UNKNOWN_TYPE, "type",
                            f"unknown request type {describe(mtype)}; expected one of {list(REQUEST_TYPES)}")
    msg_id = msg.get("msg_id")
    if msg_id is None:
        raise ProtocolError(Code.MISSING_FIELD, "msg_id", "required field 'msg_id' is missing")
    if type(msg_id) not in (str, int):
        raise ProtocolError(Code.BAD_VALUE, "msg_id", f"must be a str or int, got {type(msg_id).__name__}")
    session = msg.get("session")
    if session is not None and not isinstance(session, str):
        raise ProtocolError(Code.BAD_VALUE, "session", f"must be a str or nil, got {type(session).__name__}")
    return mtype, msg_id, session


def readable_id(msg: Any) -> Any:
    """The request's msg_id if it can be read (for ``parent`` of an error), else None."""
    if isinstance(msg, dict) and type(msg.get("msg_id")) in (str, int):
        return msg["msg_id"]
    return None


def message(mtype: str, msg_id: Any, session: str | None, parent: Any = None, **fields: Any) -> dict:
    """Build a message map (envelope first, then fields)."""
    msg = {"v": PROTOCOL_VERSION, "type": mtype, "msg_id": msg_id, "session": session}
    if mtype in REPLY_TYPES:
        msg["parent"] = parent
    msg.update(fields)
    return msg


def error_reply(msg_id: Any, parent: Any, session: str | None, code: int, field: str | None,
                text: str, name: str | None = None, **extra: Any) -> dict:
    """An ``error`` message (SPEC §5.6), with the further fields its code defines."""
    return message("error", msg_id, session, parent, code=int(code), name=name or code_name(code),
                   field=field, message=text, **extra)


def error_from(exc: ProtocolError, msg_id: Any, parent: Any, session: str | None) -> dict:
    """``error`` message for a ProtocolError."""
    return error_reply(msg_id, parent, session, exc.code, exc.field, exc.message, exc.name, **exc.extra)


def id_source(prefix: str) -> Iterator[str]:
    """Endless unique message ids "<prefix>-<random>-<n>" (cheap: one format per id)."""
    tag = os.urandom(4).hex()
    return (f"{prefix}-{tag}-{n}" for n in itertools.count(1))

# ---------------------------------------------------------------- control frames
# A joined controller's measurements and commands as fixed-layout binary frames on the direct
# channel (SPEC §5.7.6, revision 1.20): no msgpack map on the controller's hot round trip.
#
# The layout is fixed once, at the controller's ``welcome`` (``direct.frames``): the measurements'
# names and shapes in order (float64, C order) and the command's slots (per PTO, the setpoints of
# its command kind). Both frames start with the byte 0xC1, which msgpack never uses, so a receiver
# tells a frame from a msgpack message by its first byte:
#
# - a **command frame** (controller → server): a 32-byte header ``<BBHIIIqd`` (0xC1, ``C``, 0,
#   ``request``, ``epoch``, 0, ``step``, ``wait``), then one float64 per command slot;
# - a **measurements frame** (server → controller, the reply to a command frame): a 32-byte header
#   ``<BBHIqqd`` (0xC1, ``M``, 0, ``request`` of the command it answers, ``step``, ``seq``,
#   ``time``), then the measurements' float64 values, array after array in the layout's order.

_F8_LE = np.dtype("<f8")
FRAME_MAGIC = 0xC1                  # "never used" in msgpack: no msgpack message starts with it
FRAME_COMMAND, FRAME_MEASUREMENTS = ord("C"), ord("M")
COMMAND_FRAME_HEAD = struct.Struct("<BBHIIIqd")        # magic, kind, 0, request, epoch, 0, step, wait
MEASUREMENTS_FRAME_HEAD = struct.Struct("<BBHIqqd")    # magic, kind, 0, request, step, seq, time
FRAME_REQUESTS = 1 << 32            # a frame's request number is a uint32
_FRAME_NUMBERS = (int, float, np.integer, np.floating)


def is_control_frame(frame: bytes | memoryview) -> bool:
    """Whether ``frame`` is a control frame (not a msgpack message)."""
    return len(frame) > 0 and frame[0] == FRAME_MAGIC


def _frame_kind(frame: bytes | memoryview) -> str:
    """A control frame's kind byte, for an error (a frame may end before it)."""
    return f"kind {frame[1]:#x}" if len(frame) > 1 else "no kind byte"


@dataclass(frozen=True)
class CommandFrame:
    """A command frame's content: the values in the layout's slot order."""

    request: int
    epoch: int
    step: int
    wait: float
    values: tuple[float, ...]


@dataclass(frozen=True)
class ControlLayout:
    """The frames of one joined controller: ``measurements`` ((name, shape) in order) and
    ``commands`` ((pto, setpoint) slots in order, each PTO's setpoints together)."""

    measurements: tuple[tuple[str, tuple[int, ...]], ...]
    commands: tuple[tuple[str, str], ...]

    @cached_property
    def setpoints(self) -> int:
        """Setpoints per PTO (1 for force, 2 for impedance)."""
        ptos = {p for p, _ in self.commands}
        return len(self.commands) // max(len(ptos), 1)

    @cached_property
    def _arrays(self) -> tuple[tuple[str, tuple[int, ...], int, int], ...]:
        """Each measurement's (name, shape, values, byte offset in the measurements frame)."""
        out, at = [], MEASUREMENTS_FRAME_HEAD.size
        for name, shape in self.measurements:
            out.append((name, shape, math.prod(shape), at))
            at += 8 * math.prod(shape)
        return tuple(out)

    def to_wire(self) -> dict:
        """``welcome.direct.frames``: {"measurements": [[name, shape], ...], "commands": [[pto, setpoint], ...]}."""
        return {"measurements": [[n, list(s)] for n, s in self.measurements],
                "commands": [[p, k] for p, k in self.commands]}

    @classmethod
    def from_wire(cls, value: Any) -> "ControlLayout":
        """The layout of ``welcome.direct.frames``; ValueError when it is not one."""
        try:
            meas = tuple((str(n), tuple(int(d) for d in s)) for n, s in value["measurements"])
            cmds = tuple((str(p), str(k)) for p, k in value["commands"])
        except (KeyError, TypeError, ValueError) as exc:
            raise ValueError(f"not a control frame layout: {exc}") from None
        if any(d < 0 for _, s in meas for d in s):
            raise ValueError("a measurement's shape has a negative length")
        return cls(meas, cmds)

    # ------------------------------------------------------------ commands

    def command_frame(self, request: int, epoch: int, step: int, wait: float, commands: Any) -> bytes | None:
        """The command frame of ``commands`` (what ``Controller.on_step`` returns: {pto: number or
        {setpoint: number}}), or None when the layout cannot carry them (another PTO set, a missing
        or extra setpoint, a value not a number): those go as a msgpack ``command``, whose errors the
        server gives as before."""
        if type(commands) is not dict or len(commands) * self.setpoints != len(self.commands):
            return None
        values = []
        for pto, key in self.commands:
            v = commands.get(pto)
            if type(v) is dict:
                if len(v) != self.setpoints:
                    return None
                v = v.get(key)
            elif key != "force":
                return None
            if not isinstance(v, _FRAME_NUMBERS) or isinstance(v, (bool, np.bool_)):
                return None
            values.append(float(v))
        return COMMAND_FRAME_HEAD.pack(FRAME_MAGIC, FRAME_COMMAND, 0, request % FRAME_REQUESTS, epoch % FRAME_REQUESTS, 0, step, wait) \
            + struct.pack(f"<{len(values)}d", *values)

    def read_command(self, frame: bytes | memoryview) -> CommandFrame:
        """A command frame's content; ProtocolError 1 (malformed) for a frame not of this layout."""
        n = len(self.commands)
        if len(frame) != COMMAND_FRAME_HEAD.size + 8 * n or frame[1] != FRAME_COMMAND:
            raise ProtocolError(Code.MALFORMED, None, f"a control frame of {len(frame)} bytes, {_frame_kind(frame)}; "
                                f"this controller's command frame is kind {FRAME_COMMAND:#x} of {COMMAND_FRAME_HEAD.size + 8 * n} "
                                f"bytes ({n} setpoints, SPEC §5.7.6)")
        _, _, _, request, epoch, _, step, wait = COMMAND_FRAME_HEAD.unpack_from(frame)
        return CommandFrame(request, epoch, step, wait, struct.unpack_from(f"<{n}d", frame, COMMAND_FRAME_HEAD.size))

    # ------------------------------------------------------------ measurements

    def measurements_frame(self, request: int, sample: dict) -> bytes | None:
        """The measurements frame of a controller's ``measurements`` reply fields ``sample`` answering
        request ``request``, or None when the request's number is not a uint32 or ``sample`` does not
        hold the layout's arrays (measurements relayed without their wave probes): those go as msgpack."""
        if type(request) is not int or not 0 <= request < FRAME_REQUESTS:
            return None
        parts = [MEASUREMENTS_FRAME_HEAD.pack(FRAME_MAGIC, FRAME_MEASUREMENTS, 0, request, sample["step"], sample["seq"], sample["time"])]
        for name, shape in self.measurements:
            v = sample.get(name)
            if type(v) is not np.ndarray or v.shape != shape or v.dtype != _F8_LE:
                return None
            parts.append(v.tobytes())
        return b"".join(parts)

    def read_measurements(self, frame: bytes) -> tuple[int, dict]:
        """(request, the measurements: ``step``, ``seq``, ``time`` and the arrays, read-only views of
        ``frame`` as a msgpack reply's are); ValueError for a frame not of this layout."""
        last = self._arrays[-1] if self._arrays else ("", (), 0, MEASUREMENTS_FRAME_HEAD.size)
        size = last[3] + 8 * last[2]
        if len(frame) != size or frame[1] != FRAME_MEASUREMENTS:
            raise ValueError(f"a control frame of {len(frame)} bytes, {_frame_kind(frame)}; the measurements frame "
                             f"is kind {FRAME_MEASUREMENTS:#x} of {size} bytes")
        _, _, _, request, step, seq, time = MEASUREMENTS_FRAME_HEAD.unpack_from(frame)
        out: dict[str, Any] = {"step": step, "seq": seq, "time": time}
        for name, shape, n, at in self._arrays:
            out[name] = np.frombuffer(frame, _F8_LE, n, at).reshape(shape)
        return request, out


# ---------------------------------------------------------------- benchmark

def _bench(n_bodies: int = 1, repeat: int = 20000) -> dict[str, float]:
    """Best-of-7 mean µs for pack+unpack of a step and a forces message (binary arrays vs lists)."""
    import time
    rng = np.random.default_rng(0)
    pos, vel = rng.standard_normal((2, n_bodies, 6))
    step = message("step", "c-1", "s" * 32, seq=12, time=1.2, position=pos, velocity=vel, iteration=0)
    forces = message("forces", "s-1", "s" * 32, "c-1", seq=12, iteration=0, time=1.2,
                     excitation=pos, radiation=vel, hydrostatic=pos, wave_elevation=0.1, compute_us=1.0)
    step_lists = dict(step, position=pos.tolist(), velocity=vel.tolist())

    def timed(fn) -> float:  # best of 7 batch means: robust to a busy shared machine
        batch = max(1, repeat // 7)
        best = math.inf
        for _ in range(7):
            t0 = time.perf_counter()
            for _ in range(batch):
                fn()
            best = min(best, (time.perf_counter() - t0) / batch)
        return best * 1e6

    def roundtrip_step(m=step, key=None):
        got = unpack(pack(m, key), key)
        require_array(got, "position", (n_bodies, 6))
        require_array(got, "velocity", (n_bodies, 6))

    def roundtrip_forces():
        got = unpack(pack(forces))
        for f in ("excitation", "radiation", "hydrostatic"):
            decode_array(got[f], f)

    return {
        "step binary": timed(roundtrip_step),
        "step lists": timed(lambda: roundtrip_step(step_lists)),
        "step binary signed": timed(lambda: roundtrip_step(key=b"k" * 32)),
        "forces binary": timed(roundtrip_forces),
    }


if __name__ == "__main__":  # python -m hydrolink.protocol.codec
    for n in (1, 3, 100):
        for name, us in _bench(n).items():
            print(f"N={n:3d}  {name:22s} pack+unpack+validate  {us:7.2f} µs")
