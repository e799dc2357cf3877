"""Where the force server's messages come in and its replies go out (SPEC §1): one object with the
interface the server's loop uses — ``recv()`` of one message as (frames kept, size, count) with the
identity to answer to first, ``send_multipart(frames)`` to an identity, ``set_timeout(ms)``, and
``socket`` / ``pending`` to wait on it beside other file descriptors.

- :class:`StreamFront` (no CURVE): a ``ZMQ_STREAM`` socket whose bytes this process reads as ZMTP
  itself (server/service/zmtp.py), so every message is bounded while it arrives, frame by frame
  (libzmq's ROUTER hands a multipart message over only once all of it is in memory). Peers are
  unmodified libzmq DEALER or REQ sockets. ZMTP heartbeats: a PING answered with PONG; a peer
  silent for a second is sent a PING (ZMTP 3.1 peers), one silent for the link timeout, or for
  the shorter TTL its own PINGs gave (RFC 37), is dropped; ZMTP 3.0 peers (no PING) are watched by
  TCP keepalive.
- :class:`RouterFront` (CURVE, ``serve --curve-secret``): libzmq's ROUTER, whose CURVE handshake
  and ZAP authentication run before any message frame is taken, so only an authorised key can send
  at all; its messages are bounded as libzmq allows (transport.recv_bounded, SPEC §9).
"""

from __future__ import annotations

import math
import time
from collections import deque

import zmq

from hydrolink.protocol import codec, transport
from hydrolink.server.service import zmtp

STREAM_RCVHWM = 16        # chunks (of at most 8 KiB) libzmq holds per connection before it stops reading it
PING_AFTER_S = 1.0        # a connection silent this long is sent a PING
SWEEP_S = 0.25            # how often silent connections are looked for
NOBLOCK, SNDMORE = int(zmq.NOBLOCK), int(zmq.SNDMORE)   # plain ints: no enum arithmetic per message


class OverBudget(transport.ReceiveMemoryError):
    """A message dropped because the bytes of the messages arriving at once passed the budget."""

    def __init__(self, identity: bytes, budget: int):
        super().__init__(identity)
        self.args = (f"the messages arriving at the server at once would hold over its {budget / 2**20:g} MiB "
                     "for messages being received (SPEC §1)",)


class _Peer:
    """One connection: its ZMTP reader and when it was last heard from."""
    __slots__ = ("reader", "heard")

    def __init__(self, reader: zmtp.Reader, now: float):
        self.reader, self.heard = reader, now


class _Front:
    """What both front ends do with their socket as it is."""

    socket: zmq.Socket

    @property
    def address(self) -> str:
        return self.socket.getsockopt_string(zmq.LAST_ENDPOINT)

    @property
    def closed(self) -> bool:
        return self.socket.closed

    def bind(self, endpoint: str) -> None:
        self.socket.bind(endpoint)

    def close(self, linger: int = 0) -> None:
        self.socket.close(linger)

    def tend(self) -> None:
        """What is due between messages when the socket is waited on by a poller, not by :meth:`recv`."""


class StreamFront(_Front):
    """The ZMTP front end on a ``ZMQ_STREAM`` socket (module docstring). ``max_bytes`` /
    ``max_frames``: a message's limits, its identity frame included (as transport.recv_bounded
    counts them); ``budget``: the bytes kept of messages still arriving, over all connections."""

    def __init__(self, ctx: zmq.Context, max_bytes: int, max_frames: int, budget: int,
                 link_timeout: float = transport.LINK_TIMEOUT_S):
        self.max_bytes, self.max_frames = max_bytes, max_frames
        self.budget = zmtp.Budget(budget)
        self.link_timeout = float(link_timeout)
        self.socket = ctx.socket(zmq.STREAM)
        self.socket.setsockopt(zmq.LINGER, 0)
        self.socket.setsockopt(zmq.RCVHWM, STREAM_RCVHWM)
        self._keepalive()
        self._peers: dict[bytes, _Peer] = {}
        self._ready: deque[tuple[list, int, int, str | None]] = deque()
        self._timeout_s = 0.05
        self._next_sweep = time.monotonic()

    def _keepalive(self) -> None:
        """TCP keepalive on every connection: after half the link timeout without traffic the
        kernel probes the peer's host once a second and ends the connection when the probes have
        gone unanswered for the rest of it. The kernels answer the probes, so a live peer that is
        only quiet keeps its connection; a ZMTP 3.0 peer, which cannot answer the front end's
        PINGs, is dropped this way when its host or link is gone (SPEC §1)."""
        idle = max(1, round(self.link_timeout / 2))
        self.socket.setsockopt(zmq.TCP_KEEPALIVE, 1)
        self.socket.setsockopt(zmq.TCP_KEEPALIVE_IDLE, idle)
        self.socket.setsockopt(zmq.TCP_KEEPALIVE_INTVL, 1)
        self.socket.setsockopt(zmq.TCP_KEEPALIVE_CNT, max(1, math.ceil(self.link_timeout - idle)))

    # ------------------------------------------------------------ the socket's interface

    @property
    def pending(self) -> bool:
        """Messages already read (a read can complete several): take them before waiting."""
        return bool(self._ready)

    def ready(self) -> bool:
        """Whether a message can be taken now without waiting: what has arrived is read (never
        waiting) and parsed first."""
        while not self._ready and self.socket.getsockopt(zmq.EVENTS) & zmq.POLLIN:
            self._read(NOBLOCK)
        return bool(self._ready)

    def close(self, linger: int = 0) -> None:
        for peer in self._peers.values():
            peer.reader.close()
        self._peers.clear()
        super().close(linger)

    def tend(self) -> None:
        """The sweep of silent connections (:meth:`_sweep`) when due: :meth:`recv` does it while it
        waits, a loop that waits on a poller instead (the direct channel beside) calls this."""
        now = time.monotonic()
        if now >= self._next_sweep:
            self._sweep(now)

    def set_timeout(self, ms: int) -> None:
        """How long :meth:`recv` waits for a message (ms)."""
        self.socket.setsockopt(zmq.RCVTIMEO, ms)
        self._timeout_s = ms / 1000

    def recv(self) -> tuple[list[bytes | memoryview], int, int]:
        """One message: (its frames, identity first — the identity alone when it was over the
        limits —, its size in bytes, its number of frames), as transport.recv_bounded. zmq.Again
        when none completed within the timeout; OverBudget (a transport.ReceiveMemoryError naming the
        identity) for one dropped because the bytes arriving passed the budget (error 14 ``memory``)."""
        started = None
        flags = 0
        while not self._ready:
            try:
                now = self._read(flags)
            except zmq.Again:   # nothing (more) now
                if time.monotonic() >= self._next_sweep:
                    self._sweep(time.monotonic())
                raise
            if now >= self._next_sweep:
                self._sweep(now)
            started = started or now
            if now - started > self._timeout_s:
                raise zmq.Again()
            flags = NOBLOCK
        frames, size, count, refused = self._ready.popleft()
        if refused == "memory":
            raise OverBudget(frames[0], self.budget.limit)
        return frames, size, count

    def send_multipart(self, frames: list[bytes | memoryview], flags: int = zmq.NOBLOCK) -> None:
        """Send ``frames[1:]`` as one message to the connection ``frames[0]``; a reply to a
        connection that is gone is dropped (as a ROUTER does). zmq.Again when the connection's
        queue is full."""
        if frames[0] not in self._peers:
            return
        self.socket.send(frames[0], flags | SNDMORE)
        self.socket.send(zmtp.encode(frames[1:]), flags)   # a STREAM socket takes both or neither

    # ------------------------------------------------------------ connections

    def _read(self, flags: int) -> float:
        """Take one read of a connection (zmq.Again: none within the timeout, or none now with
        NOBLOCK); returns when it came (time.monotonic). A STREAM socket's message is always
        two frames, the connection's identity and the bytes read, so they are taken as such
        (no RCVMORE look-up between them)."""
        ident = self.socket.recv(flags)
        data = self.socket.recv(NOBLOCK)
        now = time.monotonic()
        self._take(ident, data, now)
        return now

    def _take(self, ident: bytes, data: bytes, now: float) -> None:
        """A read from connection ``ident`` (empty: it connected or went away)."""
        peer = self._peers.get(ident)
        if not data:
            if peer is None:
                self._connect(ident, now)
            else:
                self._drop(ident, None)
            return
        if peer is None:   # pragma: no cover - libzmq announces every connection (ZMQ_STREAM_NOTIFY)
            return
        peer.heard = now
        try:
            messages = peer.reader.feed(data)
        except zmtp.ZmtpError as exc:
            self._drop(ident, str(exc))
            return
        for msg in messages:
            self._ready.append(([ident, *msg.frames], msg.size + len(ident), msg.count + 1, msg.refused))
        if peer.reader.replies:
            for reply in peer.reader.replies:
                self._write(ident, reply)
            peer.reader.replies.clear()

    def _connect(self, ident: bytes, now: float) -> None:
        """A new connection: the server's greeting and READY at once (RFC 23 allows it)."""
        reader = zmtp.Reader(self.max_bytes - len(ident), self.max_frames - 1, self.budget)
        if self._write(ident, zmtp.GREETING + zmtp.ready()):
            self._peers[ident] = _Peer(reader, now)

    def _drop(self, ident: bytes, why: str | None) -> None:
        """Forget connection ``ident`` and give back what it held; ``why`` (it broke ZMTP): an
        ERROR command to it, then it is closed."""
        peer = self._peers.pop(ident, None)
        if peer is not None:
            peer.reader.close()
        if why is not None:
            reason = why.encode()[:255]
            self._write(ident, zmtp.command(b"ERROR", bytes([len(reason)]) + reason))
            self._write(ident, b"")   # a ZMQ_STREAM socket closes a connection sent an empty frame

    def _write(self, ident: bytes, data: bytes) -> bool:
        try:
            self.socket.send_multipart([ident, data], zmq.NOBLOCK)
            return True
        except zmq.ZMQError:   # gone, or its queue full: a PONG or an ERROR is not owed
            return False

    def _sweep(self, now: float) -> None:
        """Drop the connections silent for longer than they may be; PING the ZMTP 3.1 peers silent
        for a second. A peer may be silent for the link timeout, or for the TTL of its last PING
        when it gave a shorter one (RFC 37: it asked to be dropped then). A ZMTP 3.0 peer (libzmq
        4.1) has no PING to answer, so its silence alone is not held against it: TCP keepalive
        ends its connection when its host is gone (:meth:`_keepalive`)."""
        self._next_sweep = now + SWEEP_S
        ping = zmtp.ping(int(self.link_timeout * 10))
        for ident, peer in list(self._peers.items()):
            reader = peer.reader
            silent = now - peer.heard
            allowed = math.inf if reader.version == 0 else self.link_timeout
            if reader.ttl:
                allowed = min(allowed, reader.ttl)
            if silent > allowed:
                self._drop(ident, "silent for its heartbeat TTL" if allowed == reader.ttl else
                           "silent for the link timeout")
            elif silent > PING_AFTER_S and reader.version and reader.ready:
                self._write(ident, ping)


class RouterFront(_Front):
    """libzmq's ROUTER, for CURVE (module docstring), behind the same interface as StreamFront."""

    pending = False

    def __init__(self, ctx: zmq.Context, max_bytes: int, max_frames: int, rcvhwm: int):
        self.max_bytes, self.max_frames = max_bytes, max_frames
        self.socket = ctx.socket(zmq.ROUTER)
        self.socket.setsockopt(zmq.LINGER, 0)
        # per frame: a frame up to twice the limit is received and refused by size, one beyond it
        # drops its connection; each client's queue holds at most ``rcvhwm`` messages
        self.socket.setsockopt(zmq.MAXMSGSIZE, codec.frame_cap(max_bytes))
        self.socket.setsockopt(zmq.RCVHWM, rcvhwm)
        self.socket.setsockopt(zmq.ROUTER_MANDATORY, 0)
        transport.apply_heartbeats(self.socket)   # a dead client's connection is dropped (SPEC §1)

    def set_timeout(self, ms: int) -> None:
        self.socket.setsockopt(zmq.RCVTIMEO, ms)

    def recv(self) -> tuple[list[bytes | memoryview], int, int]:
        return transport.recv_bounded(self.socket, self.max_bytes, self.max_frames)

    def ready(self) -> bool:
        """Whether a message can be taken now without waiting."""
        return bool(self.socket.getsockopt(zmq.EVENTS) & zmq.POLLIN)

    def send_multipart(self, frames: list[bytes | memoryview], flags: int = zmq.NOBLOCK) -> None:
        self.socket.send_multipart(frames, flags)
