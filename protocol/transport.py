"""Transport settings both sides use (SPEC §1): ZeroMQ heartbeats on every connection."""

from __future__ import annotations

import zmq

HEARTBEAT_IVL_MS = 250        # ZeroMQ heartbeats (ZMTP PING) on every connection
LINK_TIMEOUT_S = 10.0         # default: a connection silent for this long is dropped


def apply_heartbeats(sock: zmq.Socket, link_timeout: float = LINK_TIMEOUT_S) -> None:
    """ZeroMQ heartbeats: a connection silent for ``link_timeout`` s is dropped (a dead host, a
    link that stays down); a slow but live peer keeps answering the pings from its I/O thread, and
    a link that is down for less (a few seconds of outage, TCP retransmitting lost frames) keeps
    its connection and the messages in flight."""
    ms = int(1000 * link_timeout)
    sock.setsockopt(zmq.HEARTBEAT_IVL, HEARTBEAT_IVL_MS)
    sock.setsockopt(zmq.HEARTBEAT_TIMEOUT, ms)
    sock.setsockopt(zmq.HEARTBEAT_TTL, ms)
