"""ZMTP 3.x with the NULL mechanism (RFC 23 ZMTP 3.0, RFC 37 ZMTP 3.1), the server's side of one
connection, read from a byte stream: what the stream front end (server/service/frontend.py) uses
instead of libzmq's ROUTER, so that a message is bounded while it arrives (SPEC §1).

:class:`Reader` takes the bytes of one connection as they come and gives back whole messages. It
counts each message's bytes and frames as its frame headers arrive; once the message passes the
limit (bytes over all frames, or frames) it keeps nothing more of it and drops the rest as it
arrives, and the message is handed on as its size and count alone (answered with error 1). The
bytes kept of messages still arriving, over all connections, are bounded by one :class:`Budget`:
a message whose next bytes would pass it is dropped the same way and handed on as refused for
memory (error 14). Messages of at most FREE_BYTES (64 KiB: steps, pings) are kept outside the
budget (each connection has at most one arriving), so an attacker holding the budget with slow
large messages cannot get another session's steps refused. A large frame is received into a
mapping of its own whose pages are touched only as its bytes arrive (a header claiming 64 MiB costs
nothing until 64 MiB come) and which goes back to the system when the message is freed.

The server's own side: :data:`GREETING` (ZMTP 3.1, mechanism NULL) followed by :func:`ready`
(Socket-Type ROUTER); libzmq peers (DEALER, REQ) see a ROUTER. Commands after the handshake:
PING is answered with PONG (:attr:`Reader.replies`) and its TTL kept (:attr:`Reader.ttl`: the
peer asks to be dropped after that long without traffic), PONG and unknown commands are ignored;
anything that breaks the framing is a :class:`ZmtpError` (the front end closes the connection).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import mmap

GREETING = (b"\xff" + bytes(8) + b"\x7f"   # signature (padding, then 0x7F)
            + b"\x03\x01"                  # version 3.1
            + b"NULL".ljust(20, b"\x00")   # mechanism
            + b"\x00" + bytes(31))          # as-server (NULL: unused), filler
GREETING_SIZE = 64
MORE, LONG, COMMAND = 0x01, 0x02, 0x04
RESERVED = 0xF8               # flag bits that must be zero
MAX_COMMAND_BYTES = 4096      # a READY of a 255-byte identity and its socket type is < 300 bytes
COPY_BELOW = 64 * 2**10       # frames smaller than this are handed on as bytes, larger as a memoryview
FREE_BYTES = 64 * 2**10       # a message of at most this many bytes is kept outside the budget: a step or a
                              # ping is never refused for memory (each connection holds one message arriving)
PEER_TYPES = (b"DEALER", b"REQ")   # the sockets the protocol's clients use (SPEC §1)


class ZmtpError(ValueError):
    """The peer broke ZMTP (or sent a socket type the server does not talk to): its connection is
    closed; the message says what it sent."""


def command(name: bytes, body: bytes = b"") -> bytes:
    """A command frame (RFC 23 §"Commands")."""
    data = bytes([len(name)]) + name + body
    if len(data) <= 255:
        return bytes([COMMAND, len(data)]) + data
    return bytes([COMMAND | LONG]) + len(data).to_bytes(8, "big") + data


def ready(socket_type: bytes = b"ROUTER") -> bytes:
    """The NULL mechanism's READY command with its Socket-Type and an empty Identity, as libzmq's
    ROUTER sends."""
    props = b"".join(bytes([len(k)]) + k + len(v).to_bytes(4, "big") + v
                     for k, v in ((b"Socket-Type", socket_type), (b"Identity", b"")))
    return command(b"READY", props)


def ping(ttl_ds: int) -> bytes:
    """A ZMTP 3.1 PING asking the peer to drop the connection after ``ttl_ds`` tenths of a second
    without traffic, with an empty context."""
    return command(b"PING", min(ttl_ds, 0xFFFF).to_bytes(2, "big"))


def encode(frames: list[bytes | memoryview]) -> bytes:
    """Message frames on the wire: each with its flags (MORE on all but the last) and size."""
    parts: list[bytes | memoryview] = []
    last = len(frames) - 1
    for i, frame in enumerate(frames):
        n = len(frame)
        more = MORE if i < last else 0
        parts.append(bytes([more, n]) if n <= 255 else bytes([more | LONG]) + n.to_bytes(8, "big"))
        parts.append(frame)
    return b"".join(parts)


def properties(body: bytes) -> dict[bytes, bytes]:
    """A READY command's metadata (name: value), ZmtpError if it is not well formed."""
    props: dict[bytes, bytes] = {}
    pos = 0
    while pos < len(body):
        n = body[pos]
        name = body[pos + 1:pos + 1 + n]
        pos += 1 + n
        if n == 0 or len(name) < n or pos + 4 > len(body):
            raise ZmtpError("a READY command whose properties are cut short")
        size = int.from_bytes(body[pos:pos + 4], "big")
        if pos + 4 + size > len(body):
            raise ZmtpError(f"READY property {name!r} runs past its command")
        props[name.lower()] = body[pos + 4:pos + 4 + size]
        pos += 4 + size
    return props


class Budget:
    """The bytes kept of messages still arriving, over all connections, at most ``limit``."""

    def __init__(self, limit: int):
        self.limit = int(limit)
        self.held = 0

    def take(self, n: int) -> bool:
        """Hold ``n`` more bytes; False (nothing held) when that would pass the limit."""
        if self.held + n > self.limit:
            return False
        self.held += n
        return True

    def give(self, n: int) -> None:
        self.held -= n


@dataclass
class Message:
    """One message as received: its frames (empty when it was refused), its size in bytes over
    all its frames and its number of frames, and why it was refused: None, "limit" (over the
    message limit in bytes or frames) or "memory" (over the budget while it arrived)."""
    frames: list[bytes | memoryview] = field(default_factory=list)
    size: int = 0
    count: int = 0
    refused: str | None = None
    kept: int = 0   # bytes kept so far
    held: int = 0   # of them, counted in the budget (all once past FREE_BYTES, else none)


class Reader:
    """One connection's incoming bytes -> messages (module docstring). ``feed`` returns the
    messages that the bytes completed; ``replies`` collects what the server owes the peer (PONGs);
    ``version`` is the peer's ZMTP minor version (None before its greeting)."""

    def __init__(self, max_bytes: int, max_frames: int, budget: Budget):
        self.max_bytes, self.max_frames, self.budget = max_bytes, max_frames, budget
        self.version: int | None = None
        self.socket_type = b""
        self.ttl = 0.0                  # s: the peer's heartbeat TTL from its last PING (0: none given)
        self.replies: list[bytes] = []
        self._greeting = bytearray()
        self._head = bytearray()        # a frame header cut between two reads
        self._left = 0                  # bytes of the current frame's body still to come
        self._flags = 0
        self._body: bytearray | memoryview | None = None   # where the current frame's body goes (None: dropped)
        self._filled = 0
        self._msg = Message()

    @property
    def ready(self) -> bool:
        """The handshake is done (the peer's READY was read): messages may follow."""
        return bool(self.socket_type)

    def close(self) -> None:
        """The connection is gone: what was held of a message arriving is given back."""
        self.budget.give(self._msg.held)
        self._msg = Message()
        self._body = None

    def feed(self, data: bytes) -> list[Message]:
        """The messages ``data`` completed (ZmtpError when it breaks ZMTP)."""
        if self._msg.count == 0 and not self._left and not self._head and self.socket_type:
            whole = self._whole_messages(data)
            if whole is not None:
                return whole
        view = memoryview(data)
        pos, end = 0, len(data)
        if self.version is None:
            pos = self._read_greeting(view)
        done: list[Message] = []
        while pos < end:
            if self._left:
                n = min(self._left, end - pos)
                if self._body is not None:
                    self._keep(view[pos:pos + n])
                pos += n
                self._left -= n
                if not self._left:
                    self._frame_done(done)
                continue
            pos = self._read_header(view, pos, end)
            if not self._left and not self._head:
                self._frame_done(done)   # an empty frame
        return done

    def _whole_messages(self, data: bytes) -> list[Message] | None:
        """The common case in one pass: ``data`` is whole messages of small frames (a step, a
        ping), within the limits and under FREE_BYTES each — their
        frames sliced out of ``data`` with no per-frame state. None (nothing read) when it is
        anything else (a command, a frame cut between reads, a large or refused message): the
        frame-by-frame path reads it."""
        done: list[Message] = []
        frames: list[bytes] = []
        pos, end, size = 0, len(data), 0
        while pos < end:
            flags = data[pos]
            if flags & ~(MORE | LONG):   # a command, or reserved bits: the general path
                return None
            if flags & LONG:
                if end - pos < 9:
                    return None
                n, pos = int.from_bytes(data[pos + 1:pos + 9], "big"), pos + 9
            elif end - pos < 2:
                return None
            else:
                n, pos = data[pos + 1], pos + 2
            size += n
            if pos + n > end or size >= FREE_BYTES or size > self.max_bytes or len(frames) >= self.max_frames:
                return None
            frames.append(data[pos:pos + n])
            pos += n
            if not flags & MORE:
                done.append(Message(frames, size, len(frames)))
                frames, size = [], 0
        return None if frames else done

    # ------------------------------------------------------------ handshake

    def _read_greeting(self, view: memoryview) -> int:
        take = min(GREETING_SIZE - len(self._greeting), len(view))
        self._greeting += view[:take]
        g = self._greeting
        if g[0] != 0xFF or (len(g) > 9 and g[9] != 0x7F):
            raise ZmtpError("not a ZMTP greeting (its signature is not 0xFF, 8 bytes, 0x7F)")
        if len(g) > 10 and g[10] < 3:
            raise ZmtpError(f"ZMTP version {g[10]}: the server speaks 3.x (libzmq 4.x)")
        if len(g) < GREETING_SIZE:
            return len(view)
        mechanism = bytes(g[12:32]).rstrip(b"\x00")
        if mechanism != b"NULL":
            raise ZmtpError(f"security mechanism {mechanism.decode('ascii', 'replace')!r}: this server "
                            "speaks NULL (no CURVE; start it with --curve-secret for CURVE)")
        self.version = g[11]
        self._greeting = bytearray()
        return take

    def _command(self, body: bytes) -> None:
        n = body[0] if body else 0
        name = body[1:1 + n]
        if len(name) < n or n == 0:
            raise ZmtpError("a command without a name")
        data = body[1 + n:]
        if not self.ready:
            if name != b"READY":
                raise ZmtpError(f"{name!r} before READY")
            kind = properties(data).get(b"socket-type", b"")
            if kind not in PEER_TYPES:
                raise ZmtpError(f"socket type {kind.decode('ascii', 'replace')!r}: the server talks to "
                                "DEALER and REQ sockets")
            self.socket_type = kind
        elif name == b"PING":
            if len(data) < 2 or len(data) > 18:
                raise ZmtpError("a PING of the wrong length")
            self.ttl = int.from_bytes(data[:2], "big") / 10   # RFC 37: tenths of a second, 0 = none
            self.replies.append(command(b"PONG", bytes(data[2:])))
        # PONG, and commands of later minor versions: nothing to do (RFC 37: ignored)

    # ------------------------------------------------------------ frames

    def _read_header(self, view: memoryview, pos: int, end: int) -> int:
        """Read (the rest of) a frame header from ``pos``; set up its body. Returns the new position."""
        head = self._head
        if head:
            need = (9 if head[0] & LONG else 2) - len(head)
            head += view[pos:pos + need]
            pos += min(need, end - pos)
            flags = head[0]
        else:
            flags = view[pos]
            if flags & RESERVED:
                raise ZmtpError(f"frame flags {flags:#04x}: reserved bits set")
            size_len = 8 if flags & LONG else 1
            if end - pos < 1 + size_len:
                self._head = bytearray(view[pos:end])
                return end
            head = view[pos:pos + 1 + size_len]
            pos += 1 + size_len
        if len(head) < (9 if flags & LONG else 2):
            return pos   # still cut
        size = int.from_bytes(head[1:], "big")
        self._head = bytearray()
        self._begin(flags, size)
        return pos

    def _begin(self, flags: int, size: int) -> None:
        """A frame of ``size`` bytes begins: where its body goes."""
        self._flags, self._left, self._filled = flags, size, 0
        if flags & COMMAND:
            if flags & MORE or size > MAX_COMMAND_BYTES:
                raise ZmtpError(f"a command frame of {size} bytes{' with MORE' if flags & MORE else ''}")
            self._body = bytearray(size)
            return
        if not self.ready:
            raise ZmtpError("a message frame before the READY command")
        msg = self._msg
        msg.size += size
        msg.count += 1
        if msg.refused is None and (msg.size > self.max_bytes or msg.count > self.max_frames):
            self._refuse("limit")
        if msg.refused is not None:
            self._body = None
        elif size < COPY_BELOW:
            self._body = bytearray(size)
        else:   # an anonymous mapping of its own: pages touched only as bytes arrive, 4 KiB at a time
            self._body = memoryview(mmap.mmap(-1, size))   # (numpy's large arrays ask for 2 MiB huge pages)

    def _keep(self, chunk: memoryview) -> None:
        n = len(chunk)
        msg = self._msg
        if not self._flags & COMMAND:
            msg.kept += n
            if msg.kept > FREE_BYTES:   # from here on all of the message counts
                if not self.budget.take(msg.kept - msg.held):
                    self._refuse("memory")
                    return
                msg.held = msg.kept
        self._body[self._filled:self._filled + n] = chunk
        self._filled += n

    def _refuse(self, why: str) -> None:
        """Keep nothing more of the message arriving (``why``: Message.refused)."""
        msg = self._msg
        self.budget.give(msg.held)
        msg.held, msg.kept, msg.refused, msg.frames = 0, 0, why, []
        self._body = None

    def _frame_done(self, done: list[Message]) -> None:
        body, self._body = self._body, None
        if self._flags & COMMAND:
            self._command(bytes(body))
            return
        msg = self._msg
        if body is not None:
            # read-only, as libzmq's frames are: arrays decoded from it are read-only too (a compiled
            # step's signature, server/fused, is specialised on that)
            msg.frames.append(bytes(body) if type(body) is bytearray else body.toreadonly())
        if not self._flags & MORE:
            self.budget.give(msg.held)
            msg.held = 0
            done.append(msg)
            self._msg = Message()
