"""The client end of a server's direct channel (SPEC §5.7.5): one blocking stream socket read and
written by the thread that makes the requests, frames of a 4-byte little-endian length and a
message, no ZeroMQ I/O thread on the way. Used by controllers (clients/control.py) and, since
revision 1.16, by the multibody client's connection (clients/lockstep/connection.py).

Imports only the codec and the standard library, so a controller process starts fast.
"""

from __future__ import annotations

import math
import socket
import struct
import time
from typing import Any

from hydrolink.protocol import codec
from hydrolink.protocol.codec import ControlLayout, is_control_frame

HEADER = codec.DIRECT_HEADER
CONNECT_S = 1.0                # how long opening the direct channel may take before ZeroMQ is kept


class DirectChannel:
    """The direct channel's client end: one blocking stream socket, frames of a 4-byte length and a
    message (SPEC §5.7.5)."""

    def __init__(self, sock: socket.socket):
        self.sock = sock
        self.buffer = bytearray()
        self._within = -1.0    # the kernel's receive timeout set (SO_RCVTIMEO), s
        sock.settimeout(None)  # blocking: a request is one send and one receive, no poll before each

    @classmethod
    def open(cls, address: str, offer: dict, link_timeout: float | None = None) -> "DirectChannel":
        """Connect where ``offer`` says (``port`` on the host of the ZeroMQ ``address``, or ``path``)
        and show its ticket. ``link_timeout``: a TCP channel whose peer's host stops answering (a
        link down, a host gone) fails after about that long (:func:`watch_link`), as ZeroMQ's
        heartbeats drop its connection (SPEC §1); None: no such watch."""
        if "path" in offer:
            sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            target: Any = str(offer["path"])
        elif address.startswith("tcp://") and type(offer.get("port")) is int:
            host = address[6:].rsplit(":", 1)[0].strip("[]")
            sock = socket.socket(socket.AF_INET6 if ":" in host else socket.AF_INET, socket.SOCK_STREAM)
            target = (host, offer["port"])
        else:
            raise ValueError(f"an offer this client cannot reach from {address!r}: {sorted(offer)}")
        sock.settimeout(CONNECT_S)
        try:
            sock.connect(target)
            if sock.family != socket.AF_UNIX:
                sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
                if link_timeout is not None:
                    watch_link(sock, link_timeout)
            ticket = offer["ticket"].encode()
            sock.sendall(HEADER.pack(len(ticket)) + ticket)
        except OSError:
            sock.close()
            raise
        return cls(sock)

    def request(self, frame: bytes, msg_id: Any, within: float, key: bytes | None,
                layout: ControlLayout | None = None) -> dict:
        """Send ``frame`` and wait at most ``within`` s for the reply whose parent is ``msg_id``;
        OSError (a timeout included) when the channel fails. ``layout``: a controller's binary
        frames (SPEC §5.7.6): a measurements frame answering ``msg_id`` is returned as its reply,
        ``{"type": "measurements", "step", "time", "frame": the measurements}``."""
        if within != self._within:   # the kernel times the receive (and the send) out
            tv = struct.pack("ll", int(within), int(within % 1 * 1e6))
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_RCVTIMEO, tv)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_SNDTIMEO, tv)
            self._within = within
        self.sock.sendall(HEADER.pack(len(frame)) + frame)
        deadline = time.monotonic() + within
        while True:
            data = self._frame(deadline)
            if layout is not None and is_control_frame(data):
                try:
                    request, meas = layout.read_measurements(data)
                except ValueError as exc:   # not the layout of the welcome: the channel is not to be trusted
                    raise ConnectionError(f"a control frame not of the welcome's layout: {exc}") from None
                if request == msg_id:
                    return {"type": "measurements", "step": meas["step"], "time": meas["time"], "frame": meas}
                continue
            reply = codec.unpack(data, key)
            if reply.get("parent") == msg_id or codec.unread_error(reply):
                return reply

    def _frame(self, deadline: float) -> bytes:
        buf, size = self.buffer, HEADER.size
        while len(buf) < size or len(buf) < size + HEADER.unpack_from(buf)[0]:
            if time.monotonic() > deadline:   # a frame still arriving in pieces
                raise TimeoutError("no reply on the direct channel")
            try:
                data = self.sock.recv(1 << 16)
            except BlockingIOError:   # SO_RCVTIMEO passed
                raise TimeoutError("no reply on the direct channel") from None
            if not data:
                raise ConnectionResetError("the server closed the direct channel")
            buf += data
        n = size + HEADER.unpack_from(buf)[0]
        frame = bytes(buf[size:n])
        del buf[:n]
        return frame

    def close(self) -> None:
        self.sock.close()


def watch_link(sock: socket.socket, link_timeout: float) -> None:
    """A TCP connection closed by the kernel (the next receive fails) once its peer's host has not
    answered for about ``link_timeout`` s: keepalive probes after half of it idle, one a second for
    the rest; data left unacknowledged as long (TCP_USER_TIMEOUT). A busy but live server's kernel
    answers the probes, so a slow reply is still waited for."""
    idle = max(1, round(link_timeout / 2))
    sock.setsockopt(socket.SOL_SOCKET, socket.SO_KEEPALIVE, 1)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_KEEPIDLE, idle)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_KEEPINTVL, 1)
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_KEEPCNT, max(1, math.ceil(link_timeout - idle)))
    sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_USER_TIMEOUT, max(1, int(1000 * link_timeout)))
