"""Transport settings both sides use (SPEC §1): ZeroMQ heartbeats on every connection, and the
bounded receive of a multipart message."""

from __future__ import annotations

import zmq

HEARTBEAT_IVL_MS = 250        # ZeroMQ heartbeats (ZMTP PING) on every connection
LINK_TIMEOUT_S = 10.0         # default: a connection silent for this long is dropped
COPY_BELOW = 64 * 2**10       # received frames smaller than this are copied to bytes; larger ones are viewed


def apply_heartbeats(sock: zmq.Socket, link_timeout: float = LINK_TIMEOUT_S) -> None:
    """ZeroMQ heartbeats: a connection silent for ``link_timeout`` s is dropped (a dead host, a
    link that stays down); a slow but live peer keeps answering the pings from its I/O thread, and
    a link that is down for less (a few seconds of outage, TCP retransmitting lost frames) keeps
    its connection and the messages in flight."""
    ms = int(1000 * link_timeout)
    sock.setsockopt(zmq.HEARTBEAT_IVL, HEARTBEAT_IVL_MS)
    sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, ms)
    sock.setsockopt(zmq.HEARTBEAT_TTL, ms)


class ReceiveMemoryError(MemoryError):
    """Out of memory while a message was received: the rest of it was dropped; ``identity`` is its
    first frame (a ROUTER's routing identity, to answer to), b"" if it was not received."""

    def __init__(self, identity: bytes):
        super().__init__("out of memory receiving a message")
        self.identity = identity


def recv_bounded(sock: zmq.Socket, max_bytes: int, max_frames: int) -> tuple[list[bytes | memoryview], int, int]:
    """One multipart message, frame by frame without copying (``copy=False``): (the frames kept,
    the message's size in bytes over all its frames, its number of frames). Frames are kept while
    the running total is at most ``max_bytes`` and their number at most ``max_frames``; past either
    only the first frame (a ROUTER's routing identity) is kept and the rest of the message is
    received and dropped at once, so a message over the limit costs no copy. Kept frames are bytes,
    or a memoryview of the received frame from COPY_BELOW bytes on. zmq.Again when no message came
    within the socket's receive timeout; ReceiveMemoryError (the rest of the message dropped) when
    memory ran out on the way.

    ZeroMQ hands a multipart message over only once all its frames are in (its pipes deliver whole
    messages): what this bounds is what the receiver copies and decodes, not ZeroMQ's own buffer,
    which ``ZMQ_MAXMSGSIZE`` bounds per frame."""
    kept: list[bytes | memoryview] = []
    size = count = 0
    frame = None
    try:
        frame = sock.recv(copy=False)
        while True:
            n = len(frame)
            size += n
            count += 1
            if size <= max_bytes and count <= max_frames:
                kept.append(frame.bytes if n < COPY_BELOW else frame.buffer)
            elif count == 1:
                kept.append(frame.bytes if n <= 255 else b"")
            elif len(kept) > 1:
                del kept[1:]
            if not frame.more:
                return kept, size, count
            frame = sock.recv(copy=False)
    except MemoryError:
        identity = kept[0] if kept and type(kept[0]) is bytes else b""
        kept = frame = None
        while sock.getsockopt(zmq.RCVMORE):   # the rest of the message: dropped, so the next starts clean
            sock.recv(copy=False)
        raise ReceiveMemoryError(identity) from None
