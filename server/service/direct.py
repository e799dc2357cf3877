"""A server's direct channel to its clients (SPEC §5.7.5): plain stream sockets read and written by
the thread that answers them, no ZeroMQ I/O thread on the way. A run's own (polled) server offers
it to its controllers (revision 1.12); ``hydrolink serve`` offers it to the multibody clients and
the controllers of its sessions (revision 1.16), its frames then counted in the front end's
receive budget (SPEC §1).

Why: on a 2-vCPU host a ZeroMQ round trip between two processes costs ~120–145 µs at the median
and 4–5 ms at the 99th percentile (each message wakes an I/O thread on both sides, three thread
wake-ups a direction); the same round trip over a plain loopback TCP or Unix socket costs 15–30 µs
(p99 0.03–0.1 ms, /tmp ping-pong measured beside it; docs/realtime.md). At 1 kHz that difference is
the controller's share of the step budget.

A frame is a 4-byte little-endian length and that many bytes: the first frame a connection sends
is its ticket (from the controller's ``welcome.direct``), every later one a message as on the
ZeroMQ socket (msgpack, signed when the server signs) or, from a controller whose welcome offered
them, a binary control frame (SPEC §5.7.6, revision 1.20). Replies go back as frames on the same
connection. A wrong ticket, a first frame longer than a ticket can be, a length over the server's
message limit or over what its receive budget has left, or a reply that cannot be written at once
closes the connection (the client goes on over ZeroMQ). A connection must have shown its whole
ticket within TICKET_S of being accepted (however its bytes trickle in), else it is closed; one
that comes when MAX_LINKS are open closes the oldest still without a ticket, or is itself closed
when every open one has shown its ticket: a stranger's idle connections cannot keep the channel
from the clients it was offered to (revision 1.18).
"""

from __future__ import annotations

import logging
import math
import os
import secrets
import select
import socket
import tempfile
import time
from pathlib import Path
from typing import Iterator

from hydrolink.protocol import codec
from hydrolink.server.service.log_limit import LimitedLog
from hydrolink.server.service.zmtp import Budget

log = logging.getLogger("hydrolink.server.service.direct")

HEADER = codec.DIRECT_HEADER   # a frame's length (SPEC §5.7.5)
TICKETS_KEPT = 64              # open offers (one per welcome); older ones are forgotten
READ_BYTES = 1 << 16           # what one read takes from a connection
TICKET_BYTES = 256             # the longest first frame (a ticket) a connection may send
FREE_BYTES = 1 << 16           # a frame up to this long is read without the receive budget (as zmtp.Reader's)
MAX_LINKS = 256                # connections at once; one more closes the oldest without a ticket, or itself
TICKET_S = 2.0                 # from its accept, a connection's whole ticket must have arrived within this
OFFER_WATCH_S = 2.0            # after an offer, the loop waits on the listener too (its client connects now)


def _loopback(host: str) -> bool:
    return host == "localhost" or host == "::1" or host.startswith("127.")


class DirectError(RuntimeError):
    """The direct channel cannot be offered on this endpoint."""


class DirectRoute(list):
    """The route of a request that came over a direct connection: one routing frame naming it (so
    it compares, logs and is held like a ZeroMQ route); replies are written to :attr:`link`."""

    link: "DirectLink"


class DirectLink:
    """One accepted connection: its ticket not yet shown (``own`` None) or the controller's id."""

    def __init__(self, sock: socket.socket, number: int, max_bytes: int, budget: Budget | None = None):
        self.sock, self.max_bytes, self.budget = sock, max_bytes, budget
        self.number = sock.fileno()   # kept: a closed socket's fileno is -1
        self.buffer = bytearray()
        self.held = 0                 # bytes of the frame arriving counted in ``budget``
        self.own: str | None = None
        self.route = DirectRoute([b"direct-%d" % number])
        self.route.link = self

    def fileno(self) -> int:
        return self.number

    @property
    def closed(self) -> bool:
        return self.sock.fileno() < 0

    def read(self) -> Iterator[bytes]:
        """The complete frames that have arrived (never waits); raises ConnectionError when the
        peer closed or broke the framing."""
        try:
            data = self.sock.recv(READ_BYTES)
        except BlockingIOError:
            return
        if not data:
            raise ConnectionError("closed by the controller")
        self.buffer += data
        while len(self.buffer) >= HEADER.size:
            (n,) = HEADER.unpack_from(self.buffer)
            if self.own is None and n > TICKET_BYTES:
                raise ConnectionError(f"a first frame of {n} bytes; a ticket is at most {TICKET_BYTES}")
            if n > self.max_bytes:
                raise ConnectionError(f"a frame of {n} bytes; at most {self.max_bytes} (SPEC §1)")
            if len(self.buffer) < HEADER.size + n:
                if n > FREE_BYTES and self.budget is not None and not self.held:
                    if not self.budget.take(n):
                        raise ConnectionError(f"a frame of {n} bytes would pass the server's "
                                              f"{self.budget.limit / 2**20:g} MiB for messages being received (SPEC §1)")
                    self.held = n
                return
            frame = bytes(self.buffer[HEADER.size:HEADER.size + n])
            del self.buffer[:HEADER.size + n]
            self._give()
            yield frame

    def _give(self) -> None:
        """The budget held for the frame that was arriving, given back."""
        if self.held:
            self.budget.give(self.held)
            self.held = 0

    def write(self, frame: bytes) -> bool:
        """Send one frame now; whether it left. A connection whose buffer is full or that is gone
        is closed (its controller's request is then unanswered here and it goes on over ZeroMQ)."""
        if self.closed:
            return False
        data = HEADER.pack(len(frame)) + frame
        try:
            sent = self.sock.send(data)
        except OSError as exc:
            log.info("direct connection %s dropped: %s", self.route[0].decode(), exc)
            self.close()
            return False
        if sent < len(data):
            log.warning("direct connection %s dropped: its controller does not read (%d of %d bytes sent)",
                        self.route[0].decode(), sent, len(data))
            self.close()
            return False
        return True

    def close(self) -> None:
        self._give()
        self.sock.close()


class DirectListener:
    """Where a polled server's controllers open their direct connections (module docstring)."""

    def __init__(self, endpoint: str, max_bytes: int, budget: Budget | None = None, port: int | None = None):
        """``budget``: the front end's receive budget, which a frame longer than FREE_BYTES holds
        while it arrives (None: none, a run's own server). ``endpoint``: the server's bound ZeroMQ endpoint; the listener takes the same interface
        (``tcp://HOST:PORT`` → HOST on a port of its own; ``ipc://PATH`` or a loopback HOST → a
        Unix socket in a private folder: the peers share the host, and a Unix socket costs both
        sides less kernel time a message than loopback TCP). DirectError for any other transport.
        ``port``: that TCP port on HOST (``hydrolink serve --direct-port``: one a container can
        publish), on a loopback HOST too; DirectError when it cannot be bound or the endpoint is not
        ``tcp://``. None: a free port, or the Unix socket."""
        self.max_bytes, self.budget = int(max_bytes), budget
        self._folder: Path | None = None
        host = endpoint[6:].rsplit(":", 1)[0].strip("[]") if endpoint.startswith("tcp://") else None
        if port is not None and host is None:
            raise DirectError(f"a direct channel on port {port} needs a tcp:// endpoint, not {endpoint!r}")
        if host is not None and (port is not None or not _loopback(host)):
            family = socket.AF_INET6 if ":" in host else socket.AF_INET
            self.sock = socket.socket(family, socket.SOCK_STREAM)
            self.sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)
            try:
                self.sock.bind(("" if host in ("*", "0.0.0.0") else host, port or 0))
            except OSError as exc:
                self.sock.close()
                raise DirectError(f"no direct channel on port {port or 0} of {host}: {exc.strerror or exc}") from None
            self.offer_address: dict = {"port": self.sock.getsockname()[1]}
        elif host is not None or endpoint.startswith("ipc://"):
            self._folder = Path(tempfile.mkdtemp(prefix="hydrolink-direct-"))   # mode 0700: this user only
            path = str(self._folder / "s")
            self.sock = socket.socket(socket.AF_UNIX, socket.SOCK_STREAM)
            self.sock.bind(path)
            self.offer_address = {"path": path}
        else:
            raise DirectError(f"no direct channel on {endpoint!r} (tcp:// and ipc:// only)")
        self.sock.listen(8)
        self.sock.setblocking(False)
        self.links: list[DirectLink] = []
        self.version = 0                     # changed whenever ``links`` changes: a poller over them is then stale
        self._waiting: dict[DirectLink, float] = {}   # the links still without a ticket -> their deadline, oldest first
        self.closed_unticketed = 0           # connections closed for want of a ticket (the log counts them)
        self._log = LimitedLog(log)          # those closures' lines, bounded a minute (server/service/log_limit.py)
        self._tickets: dict[str, str] = {}   # ticket -> the controller's own session id
        self._count = 0
        self._offered = -math.inf            # when the newest offer was made (time.monotonic)
        self._fds = select.poll()            # the listener and its links, for ready_now
        self._fds.register(self.sock, select.POLLIN)

    def fileno(self) -> int:
        return self.sock.fileno()

    def offer(self, own: str) -> dict:
        """``welcome.direct`` for the controller whose own session id is ``own``: where to connect
        and the one-use ticket that binds the connection to it."""
        ticket = secrets.token_urlsafe(32)
        self._tickets[ticket] = own
        self._offered = time.monotonic()
        while len(self._tickets) > TICKETS_KEPT:
            del self._tickets[next(iter(self._tickets))]
        return {**self.offer_address, "ticket": ticket}

    @property
    def watched(self) -> bool:
        """Whether a loop should wait on the listener and the connections now: one is open, or an
        offer was made within OFFER_WATCH_S (its client is connecting: its first request is not
        left until the loop's receive on the other socket times out)."""
        return bool(self.links) or time.monotonic() - self._offered < OFFER_WATCH_S

    def accept(self) -> DirectLink | None:
        """A new connection (its ticket still to come), or None."""
        self.prune()   # a link closed since gives back its descriptor's number before a new one may take it
        while True:
            try:
                conn, _ = self.sock.accept()
            except BlockingIOError:
                return None
            if len(self.links) < MAX_LINKS:
                break
            if self._waiting:   # full: the oldest still without a ticket makes room
                self._close_unticketed([next(iter(self._waiting))], f"{MAX_LINKS} open, the oldest without a ticket "
                                                                      "closed for a new one")
                self.prune()
                break
            conn.close()   # every open one has shown its ticket: the next one waiting, if any, is refused the same way
            self._log.log("full", logging.WARNING, "direct connection refused: %d open already, each with its ticket",
                          MAX_LINKS)
        conn.setblocking(False)
        if conn.family in (socket.AF_INET, socket.AF_INET6):
            conn.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self._count += 1
        link = DirectLink(conn, self._count, self.max_bytes, self.budget)
        self.links.append(link)
        self.version += 1
        self._waiting[link] = time.monotonic() + TICKET_S
        self._fds.register(link.sock, select.POLLIN)
        return link

    def admit(self, link: DirectLink, ticket: bytes) -> bool:
        """The connection's first frame: its ticket. False (the caller closes it) for one not offered."""
        own = self._tickets.pop(ticket.decode("ascii", "replace"), None)
        if own is None:
            log.warning("direct connection %s closed: not a ticket this server offered", link.route[0].decode())
            return False
        link.own = own
        del self._waiting[link]
        return True

    def expire(self, now: float) -> bool:
        """Close the connections that have not shown their whole ticket within TICKET_S of their
        accept (``now``: time.monotonic()); whether any were (then forgotten: :meth:`prune`)."""
        if not self._waiting or next(iter(self._waiting.values())) > now:
            return False
        late = [link for link, deadline in self._waiting.items() if deadline <= now]   # oldest first
        self._close_unticketed(late, f"no ticket within {TICKET_S:g} s")
        return self.prune()

    def _close_unticketed(self, links: list[DirectLink], why: str) -> None:
        """Close ``links`` (none has shown a ticket yet) and count them in one log line through the limiter."""
        for link in links:
            link.close()
        self.closed_unticketed += len(links)
        self._log.log("unticketed", logging.WARNING, "direct channel: %d connection(s) closed (%s); %d so far",
                      len(links), why, self.closed_unticketed)

    def prune(self) -> bool:
        """Forget the links closed since (a reply they did not take); whether there were any."""
        gone = [link for link in self.links if link.closed]
        for link in gone:
            self.links.remove(link)
            self._waiting.pop(link, None)
            self._fds.unregister(link.number)
        if gone:
            self.version += 1
        return bool(gone)

    def ready_now(self) -> set[int]:
        """The descriptors (the listener's, the links') with something to read now, never waiting."""
        self.prune()
        return {fd for fd, _ in self._fds.poll(0)}

    def drop(self, link: DirectLink, why: str) -> None:
        log.info("direct connection %s closed: %s", link.route[0].decode(), why)
        link.close()
        self.prune()

    def close(self) -> None:
        for link in self.links:
            link.close()
        self.links.clear()
        self.version += 1
        self._waiting.clear()
        self.sock.close()
        if self._folder is not None:
            for p in self._folder.iterdir():
                p.unlink()
            os.rmdir(self._folder)
