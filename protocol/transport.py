"""Transport settings both sides use (SPEC §1): ZeroMQ heartbeats on every connection."""

from __future__ import annotations

import zmq

HEARTBEAT_IVL_MS = 250        # ZeroMQ heartbeats (ZMTP PING) on every connection
HEARTBEAT_TIMEOUT_MS = 1000   # no traffic for this long: the connection is dropped


def apply_heartbeats(sock: zmq.Socket) -> None:
    """ZeroMQ heartbeats: a silent or dead peer's connection is dropped after
    HEARTBEAT_TIMEOUT_MS; a slow but live peer keeps answering the pings from its I/O thread."""
    sock.setsockopt(zmq.HEARTBEAT_IVL, HEARTBEAT_IVL_MS)
    sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, HEARTBEAT_TIMEOUT_MS)
    sock.setsockopt(zmq.HEARTBEAT_TTL, 2 * HEARTBEAT_TIMEOUT_MS)
