"""The force server: one ZeroMQ ROUTER socket, a poll loop, many sessions (protocol: SPEC.md).

Every request gets exactly one reply; any exception while handling a message becomes an ``error``
reply to that message and the loop carries on. A hello's set-up (HDB parsing, the model) runs in a
worker thread (server/service/setup_workers.py): the loop answers other sessions' steps meanwhile and the
``welcome`` when the set-up is done.
"""

from __future__ import annotations

import contextvars
import heapq
import itertools
import logging
import math
import os
import secrets
import threading
import time
from collections import deque
from concurrent.futures import Future
from dataclasses import asdict, dataclass
from importlib import metadata
from typing import TYPE_CHECKING, Any, Callable

import zmq

from hydrolink.protocol import codec, transport
from hydrolink.protocol.codec import Code, ControlLayout, ProtocolError, is_control_frame
from hydrolink.protocol.pacing import check_factor
from hydrolink.server.service.capacity import MAX_SESSIONS, MAX_SETUPS, HelloLimits, MemoryBudget
from hydrolink.server.service.controllers import ControlHub, join_token, token_matches
from hydrolink.server.errors import ModelError
from hydrolink.server.hdb.file_set import FileSetReader
from hydrolink.server.hdb.store import HASH, ContentStore, ContentTooLarge, default_folder
from hydrolink.server.processes import start_children
from hydrolink.server.service import frontend
from hydrolink.server.service.direct import DirectError, DirectLink, DirectListener, DirectRoute
from hydrolink.server.service.controlled_step import ControlledStep
from hydrolink.server.service.local_step import LocalStep
from hydrolink.server.service.log_limit import LimitedLog, limit_lines
from hydrolink.server.service.session import PlantBuilder, Session, build_model
from hydrolink.server.service.setup_workers import SetupWorkers
from hydrolink.server.service.step_worker import (ISOLATE_STEP_S, MAX_WORKERS, STEP_TIMEOUT, Flight, Placed,
                                                  WorkerFailed, WorkerSession, WorkerSlots, place)

if TYPE_CHECKING:   # (imported where CURVE is on: zmq.auth's authenticator thread)
    from hydrolink.protocol.security import ServerKeys

log = logging.getLogger("hydrolink.server")

POLL_MS = 50
SETUP_POLL_MS = 5   # the receive timeout while set-ups run: a finished one is answered within it
CONTROLLER_REQUESTS = ("hello", "measure", "command", "ping", "bye")   # what a controller's session id may send
PLANT_DT = (1e-6, 3600.0)   # s: the sampling times a controller may ask its plant at (SPEC §5.7.2)
RELEASE_SPIN = 1.5e-3   # s: a held reply due sooner is waited for by spinning (the receive timeout is in ms)
IN_PROCESS = "in-process"  # the address of a server without a socket (bind=None)
TOMBSTONES = 1000  # remembered closed sessions, for a helpful error 7
RCVHWM = 4         # whole messages ZeroMQ queues per client before it stops reading that connection (SPEC §1)
IO_THREADS = 2     # ZeroMQ I/O threads of a server's own context: a client streaming a huge message into
                   # one does not hold up the others' small ones as much (bench_attacks: p99 28-48 -> 5-6 ms)
RECEIVE_BUDGET = 128 * 2**20   # the bytes kept of messages arriving at once, over all connections, and at least
                               # two message limits (SPEC §1)
MAX_QUEUED = 64    # requests held behind a session's deferred step (SPEC §1); their bytes: the message limit
LOCAL_ROUTE = [b""]   # a polled server's own caller: a ROUTER never gives a peer an empty identity
POLLED_LINGER_MS = 500   # a polled server's last replies (its controllers' stop) get this long to leave at close


class BindError(RuntimeError):
    """The server's endpoint cannot be bound (the address in use, or not one of this host's)."""


@dataclass(frozen=True)
class PendingHello:
    """A multibody hello whose set-up runs in a worker: answered when ``model`` is done."""
    msg: dict
    msg_id: Any
    route: list[bytes]
    client: dict
    realtime: float | None
    started: float
    model: Future   # of a step_worker.Placed


def server_version() -> str:
    try:
        return metadata.version("hydrolink")
    except metadata.PackageNotFoundError:  # pragma: no cover
        return "unknown"


class ForceServer:
    """Serve hydrodynamic forces on ``bind`` (e.g. ``tcp://127.0.0.1:*``) until :meth:`stop`.

    ``polled=True``: no :meth:`serve_forever` thread: the caller's thread runs the loop. A request of
    its own (:meth:`respond`, :meth:`respond_map`) is handled at once and, when its reply is deferred
    (a step waiting for the controllers' commands, SPEC §5.7), the socket is served from that call
    (:meth:`serve_once`) until the reply is ready: ``hydrolink run``'s own server for a scene with
    controllers (no second thread fighting the run for the GIL, no loopback hop to its server)."""

    _local_reply: tuple[dict, float | None] | None = None   # polled: the caller's deferred reply, until taken
    local_route = LOCAL_ROUTE   # the routing frames of this process's own run's requests (polled)
    _direct: DirectListener | None = None   # polled: the controllers' direct channel (SPEC §5.7.5)
    _poller: zmq.Poller | None = None       # polled with a direct channel: the socket, the listener, its links
    _poller_links = -1                      # the listener's ``version`` (its links) the poller was built over
    _next_sweep = 0.0   # polled: when serve_once next expires idle sessions

    def __init__(self, bind: str | None, *, context: zmq.Context | None = None, session_timeout: float = 300.0,
                 key: bytes | None = None, curve: ServerKeys | None = None,
                 max_message_bytes: int = codec.MAX_MESSAGE_BYTES, store: ContentStore | None = None,
                 max_setups: int = MAX_SETUPS, max_sessions: int = MAX_SESSIONS,
                 plant_builder: PlantBuilder | None = None, max_memory_bytes: int | None = None,
                 isolate_step_s: float = ISOLATE_STEP_S, max_workers: int = MAX_WORKERS,
                 step_timeout: float = STEP_TIMEOUT, polled: bool = False, direct_port: int | None = None,
                 children_after_s: float | None = None):
        """``bind=None`` makes an in-process server without a socket: clients in the same process
        call :meth:`respond` with the same frames a socket would carry (see ServerConnection).

        ``curve`` (protocol/security.py ``server_keys``: the server's key pair and the allowed
        clients' keys, read and checked by the caller) requires CURVE authentication and encryption
        (SPEC §1.1).

        ``store``: the content store of HDB files sent by hash (SPEC §5.8); default a store in
        :func:`hydrolink.server.hdb.store.default_folder`, opened on first use.

        ``max_setups`` / ``max_sessions``: the multibody hellos being set up, and the sessions open
        or being set up, beyond which a hello is refused at once with error 14 ``busy`` (SPEC §4.2;
        server/service/capacity.py).

        ``plant_builder``: what builds a session's linear plant for the controllers that ask for one
        (SPEC §5.7.2; the clients hand in clients/analysis/plant.py's); None: such a hello is refused.

        ``max_memory_bytes``: what the open sessions' models may hold together (their arrays,
        server/allocation.py ``footprint``); a hello whose model would pass it is refused with error
        14 ``busy``, limit ``memory`` (SPEC §4.2); None: no bound.

        ``isolate_step_s``: a session of a socket server whose model's step (timed at set-up) takes
        longer steps in a worker process of its own (server/service/step_worker.py; 0: every
        session, ``math.inf``: none), at most ``max_workers`` at once (beyond: error 14
        ``workers``); a worker that takes longer than ``step_timeout`` s for a request, or dies,
        ends its session with error 16. The in-process server (``bind=None``) steps every session
        in the caller's thread. ``polled``: see the class docstring.

        ``direct_port``: the TCP port of the direct channel (SPEC §5.7.5; ``hydrolink serve
        --direct-port``) on the host of a ``tcp://`` ``bind``, loopback included; DirectError (the
        socket released) when it cannot be bound; unused with CURVE (no direct channel: a log
        line). None: a free port, or a Unix socket on loopback, and no channel (a log line) when it
        cannot be had.

        ``children_after_s``: the forkserver of HDB parses and session workers (server/processes.py)
        is started when first needed, and, with a loop of its own, also this long after the loop
        started once no set-up runs (``hydrolink serve``: WARM_CHILDREN_S), so that a stranger's
        first file set is not parsed behind its imports; None: only when needed."""
        self.polled, self.plant_builder = bool(polled), plant_builder
        # the bytes the open sessions' models may hold together (None: unbounded, as in-process)
        self.memory = MemoryBudget(int(max_memory_bytes)) if max_memory_bytes is not None else None
        self.limits = HelloLimits(max_setups, max_sessions)   # checked before a socket is bound
        self._own_context = context is None and bind is not None
        self._security = None  # CURVE (protocol/security.py)
        self._ctx = context
        self._sock: frontend.StreamFront | frontend.RouterFront | None = None
        self._address = IN_PROCESS
        if bind is not None:
            self._bind(bind, context, polled, curve, max_message_bytes, direct_port)
        self.session_timeout = float(session_timeout)
        self.max_message_bytes = int(max_message_bytes)
        self._store = store
        self._files: FileSetReader | None = None
        self.key = key
        self.sessions: dict[str, Session] = {}
        self._closed: dict[str, str] = {}
        self._stop = threading.Event()
        self._running = False
        self._ids = codec.id_source("s")
        self._error_log = LimitedLog(log)     # error replies' log lines, per code (server/service/log_limit.py)
        self._log_limit = LimitedLog(log)     # every other line of the server's loggers, per message (limit_lines)
        self._queued: dict[str, deque[int]] = {}   # the sizes of the requests each session holds (MAX_QUEUED)
        self._version = server_version()
        self._handlers: dict[str, Callable[[dict, Any, str | None], tuple[str, dict, str | None] | None]] = {
            "hello": self._hello, "step": self._step, "ping": self._ping, "bye": self._bye,
            "measure": self._measure, "command": self._command, "upload": self._upload,
            "save": self._rollback, "restore": self._rollback, "release": self._rollback}
        self._route: list[bytes] | None = None   # routing frames of the request being handled
        self._hubs: dict[str, ControlHub] = {}   # sessions with controllers (SPEC §5.7)
        # a joined controller's own session id -> (the session's id, the controller's name): a controller
        # never learns the owner's id, so it cannot step, roll back or end the session (SPEC §5.7.2)
        self._controllers: dict[str, tuple[str, str]] = {}
        # a joined controller's own id -> the layout of its binary frames, when its hello asked for them
        # and its welcome offered them on the direct channel (SPEC §5.7.6)
        self._framed: dict[str, ControlLayout] = {}
        self._rcv_ms = POLL_MS
        self._workers = SetupWorkers()
        self._setups: list[PendingHello] = []    # hellos being set up, oldest first (at most max_setups)
        self._paced: list[tuple[float, int, list[bytes]]] = []   # held replies: (release, order, frames)
        self._order = itertools.count()
        self.isolate_step_s = float(isolate_step_s)
        self.step_timeout = float(step_timeout)
        self._worker_slots = WorkerSlots(max_workers)
        self._flying: dict[int, WorkerSession] = {}   # a worker's pipe -> its session, while it computes
        self._hold: float | None = None   # release time of the reply being handled (paced session)
        self.children_after_s = children_after_s
        self._children_at = math.inf   # when the loop starts the forkserver if nothing has needed it (monotonic)

    def _bind(self, bind: str, context: zmq.Context | None, polled: bool, curve: ServerKeys | None,
              max_message_bytes: int, direct_port: int | None) -> None:
        """The server's socket bound at ``bind``: the ZMTP front end, or libzmq's ROUTER with CURVE;
        the direct channel (SPEC §5.7.5) for a polled server's controllers, or a loop's clients."""
        secure = curve is not None
        self._ctx = context or zmq.Context(io_threads=1 if polled else IO_THREADS)   # polled: a run's own
        # CURVE: libzmq's ROUTER (only authorised keys send); else the ZMTP front end that bounds a
        # message while it arrives (server/service/frontend.py, SPEC §1)
        self._sock = (frontend.RouterFront(self._ctx, max_message_bytes, codec.MAX_ROUTING_FRAMES + 1, RCVHWM)
                      if secure else frontend.StreamFront(self._ctx, max_message_bytes, codec.MAX_ROUTING_FRAMES + 1,
                                                          max(RECEIVE_BUDGET, 2 * max_message_bytes)))
        self._sock.set_timeout(POLL_MS)
        if secure:
            from hydrolink.protocol.security import ServerSecurity
            try:
                self._security = ServerSecurity(self._ctx, self._sock.socket, curve,
                                                LimitedLog(logging.getLogger("hydrolink.server.auth")))
            except Exception:
                self._unbind()
                raise
        try:
            self._sock.bind(bind)
        except zmq.ZMQError as exc:   # in use, or not an endpoint here: the caller's to say (serve: one line)
            self._unbind()
            raise BindError(f"cannot listen on {bind}: {zmq.strerror(exc.errno)}") from None
        self._address = self._sock.address
        if secure and direct_port is not None:
            log.warning("direct port %d unused: a CURVE server offers no direct channel (it would bypass the "
                        "encryption)", direct_port)
        if not secure:   # the direct channel (SPEC §5.7.5): not beside CURVE; a shared server's in its budget
            try:
                self._direct = DirectListener(self._address, max_message_bytes, None if polled else self._sock.budget,
                                              direct_port)
            except (DirectError, OSError) as exc:
                if direct_port is not None:   # asked for: its failure is the server's
                    self._unbind()
                    raise DirectError(str(exc)) from None
                log.info("no direct channel: %s", exc)

    def _unbind(self) -> None:
        """What :meth:`_bind` made released when it fails after the socket (the CURVE keys refused
        included): the CURVE authenticator, the socket, the context if it is the server's own."""
        if self._security is not None:
            self._security.close()
        self._sock.close(0)
        if self._own_context:
            self._ctx.term()

    @property
    def address(self) -> str:
        """The bound endpoint, with the actual port (e.g. ``tcp://127.0.0.1:41235``)."""
        return self._address

    def close(self) -> None:
        """Stop and release the socket now (idempotent; for a server whose loop is not running)."""
        self._stop.set()
        if not self._running:
            self._shutdown()

    def stop(self) -> None:
        """Ask :meth:`serve_forever` to return (within one poll interval); thread-safe."""
        self._stop.set()

    def serve_forever(self) -> None:
        """Poll loop: handle requests, expire idle sessions; returns after :meth:`stop`."""
        log.info("hydrolink server %s listening on %s (protocol %d, session timeout %g s, at most %d set-ups "
                 "and %d sessions%s%s)", self._version, self._address, codec.PROTOCOL_VERSION, self.session_timeout,
                 self.limits.max_setups, self.limits.max_sessions,
                 ", signed" if self.key else "", ", CURVE" if self._security else "")
        if self._sock is None or self.polled:
            raise RuntimeError("an in-process or polled server has no loop thread: call respond() (and, polled, "
                               "serve_once())")
        next_sweep = time.monotonic()
        if self.children_after_s is not None:
            self._children_at = next_sweep + self.children_after_s
        self._running = True
        lines = limit_lines(self._log_limit)   # every log line of this loop (and its set-ups) bounded a minute
        try:
            while not self._stop.is_set():
                try:
                    next_sweep = self._turn(next_sweep)
                except MemoryError:   # not the end of serve: what was being done is dropped, the loop goes on
                    self._error_log.log("memory", logging.ERROR, "out of memory in the server loop (not in a "
                                        "request: those get error 14); it goes on")
        finally:
            self._running = False
            lines.close()
            self._shutdown()

    def serve_once(self) -> None:
        """One turn of a polled server's loop in the caller's thread: at most one request received
        (waiting at most POLL_MS, less when a controller's deadline comes sooner) and answered, then
        what is due (deadlines, idle replies, expiry)."""
        self._next_sweep = self._turn(self._next_sweep)

    def _serve_ready(self) -> None:
        """Polled, before a request of the caller's: the messages already on the socket answered
        and the controllers' deadlines that passed kept (idle replies), without waiting: a
        controller is heard even while no step waits for it (one that missed a deadline and is
        absent, SPEC §5.7, comes back with its next request). At most MAX_QUEUED messages a call:
        a flood on the socket delays the run's step by that many, never holds it. The direct
        connections are read too (what has arrived on them, never waiting): with them, one poll of the
        loop's poller (the socket, the listener, the links) says what is ready, and a turn with
        nothing (the run's usual case) ends there."""
        socket_ready = True
        if self._direct is not None:
            self._direct.expire(time.monotonic())
            ready = self._direct_ready(0)
            self._serve_direct(ready)
            socket_ready = self._sock.pending or self._sock.socket in ready
        for _ in range(MAX_QUEUED) if socket_ready else ():
            if not self._sock.ready():
                break
            self._receive()
        if self._hubs:
            now = time.monotonic()
            for hub in list(self._hubs.values()):
                if hub.next_deadline() <= now:
                    hub.poll(now)

    def _turn(self, next_sweep: float) -> float:
        """One turn of the loop: at most one request received and answered, then what is due."""
        # a blocking receive with a POLL_MS timeout (RCVTIMEO): no poller and no exception
        # per message on the hot path, only when the socket was idle for POLL_MS; shorter
        # when a controller deadline (SPEC §5.7) or a paced reply comes sooner, or a set-up runs
        if self._hubs or self._paced or self._setups or self._rcv_ms != POLL_MS:
            self._set_rcv_timeout()
        if self._flying:
            self._poll_workers()
        elif self._direct is not None and (self.polled or self._direct.watched):
            self._receive_direct()
        else:
            self._receive()
            if self._direct is not None:   # no direct connection expected: one is taken after the receive
                self._serve_direct(self._direct.ready_now())   # (no poller per message for ZeroMQ's clients)
        if self._setups:
            self._finish_setups()
        if self._paced:
            self._send_due()
        now = time.monotonic()
        if self._direct is not None:   # connections without a ticket in time closed
            self._direct.expire(now)
        if self._hubs:
            for hub in list(self._hubs.values()):
                if hub.next_deadline() <= now:
                    hub.poll(now)
            self._resume_held()
        if self._flying:
            self._check_flights(now)
        if now >= next_sweep:
            if now >= self._children_at and not self._setups:   # after the start-up and its first set-ups
                self._children_at = math.inf
                start_children()
            self._expire(now)
            next_sweep = now + min(1.0, self.session_timeout / 4)
        return next_sweep

    # ------------------------------------------------------------ dispatch

    def _set_rcv_timeout(self) -> None:
        left = min((hub.next_deadline() - time.monotonic() for hub in self._hubs.values()), default=math.inf)
        if self._paced:
            left = min(left, self._paced[0][0] - time.perf_counter())
        cap = SETUP_POLL_MS if self._setups else POLL_MS
        ms = cap if left >= cap / 1000 else max(1, int(left * 1000))
        if ms != self._rcv_ms:
            self._sock.set_timeout(ms)
            self._rcv_ms = ms

    def _receive_direct(self) -> None:
        """Polled with a direct channel: wait at most the receive timeout for the ZeroMQ socket, the
        direct listener or a direct connection, then serve what came (at most one ZeroMQ message,
        every complete direct frame, every new connection)."""
        if self._sock.pending:
            self._receive()
            return
        ready = self._direct_ready(self._rcv_ms)
        self._serve_direct(ready)
        if self._sock.socket in ready:
            self._receive()
        else:
            self._sock.tend()   # its silent connections swept (recv does it only while it waits)

    def _wait_direct(self, ms: int) -> bool:
        """The turn of :meth:`await_local` while nothing else is due: wait at most ``ms`` for the
        ZeroMQ socket, the direct listener or a direct connection and serve what came (as
        :meth:`_receive_direct`, without the receive timeout's setsockopt: the poll takes ``ms``);
        whether anything did."""
        ready = self._direct_ready(ms)
        if not ready:
            self._sock.tend()
            return False
        self._serve_direct(ready)
        if self._sock.socket in ready:
            self._receive()
        return True

    def _direct_ready(self, ms: int) -> dict:
        """What is readable within ``ms``: the ZeroMQ socket, the direct listener, its connections
        (one poll, rebuilt only when a connection came or went: however it was found gone)."""
        self._direct.prune()   # a link closed since (a failed write) forgotten
        if self._poller_links != self._direct.version:
            self._poller_links = self._direct.version
            self._poller = zmq.Poller()
            for item in (self._sock.socket, self._direct.fileno(), *(link.fileno() for link in self._direct.links)):
                self._poller.register(item, zmq.POLLIN)
        return dict(self._poller.poll(ms))

    def _serve_direct(self, ready: dict | set) -> None:
        """Answer what the ready direct connections sent (a new one's ticket first, then requests,
        each handled as one from the socket: SPEC §5.7.5) and accept the new connections."""
        for link in list(self._direct.links) if len(ready) > (self._sock.socket in ready) else ():
            if link.fileno() not in ready:
                continue
            try:
                for frame in link.read():
                    if link.own is None:
                        if not self._direct.admit(link, frame):
                            raise ConnectionError("not a ticket this server offered")
                        continue
                    reply = self._command_frame(link, frame) if is_control_frame(frame) else self.handle(frame, link.route)
                    if reply is not None:
                        self._send(link.route, reply, self._hold)
            except OSError as exc:   # ConnectionError included: closed, or broke the framing
                self._direct.drop(link, str(exc))
        if self._direct.fileno() in ready:
            while self._direct.accept() is not None:
                pass

    def _receive(self) -> None:
        """Receive one message, bounded (SPEC §1: the front end's recv), and answer it. A
        MemoryError on the way is that message's error 14 (``limit`` "memory"), never the loop's end."""
        try:
            frames, size, count = self._sock.recv()
        except zmq.Again:
            return
        except transport.ReceiveMemoryError as exc:   # the rest of that message was dropped
            route, count, why = [exc.identity], 2, str(exc)
        else:
            why = "the server ran out of memory handling this message"
            route = frames[:1]
            try:
                self._serve_one(frames, size, count)
                return
            except MemoryError:
                pass   # answered below, once the exception (and what its traceback holds) is gone
            del frames
        self._error_log.log("memory", logging.ERROR, "refused a message busy: %s", why)
        if count >= 2 and 0 < len(route[0]) <= codec.MAX_ROUTING_FRAME_BYTES:
            self._send(route, codec.error_reply(next(self._ids), None, None, Code.BUSY, None,
                                                f"{why}; send it again later", limit="memory"))

    def _serve_one(self, frames: list[bytes | memoryview], size: int | None = None, count: int | None = None) -> None:
        """Answer one received message: ``frames`` as kept by transport.recv_bounded (all of them
        when ``size``/``count``, the message's, are within the limits; else the identity alone)."""
        size = sum(map(len, frames)) if size is None else size
        count = len(frames) if count is None else count
        if count < 2:
            return  # no routing identity: nothing to answer to
        over = self._over_limits(frames, size, count)
        if over is not None:   # answered to the identity alone: nothing the sender added is echoed
            self._error_log.log(Code.MALFORMED, logging.INFO, "refused a message: %s", over.message)
            reply = codec.error_from(over, next(self._ids), None, None)
            route, release = frames[:1], None
        else:
            route = frames[:-1]
            reply = self.handle(frames[-1], route)
            release = self._hold
        if reply is not None:   # None: deferred (SPEC §5.7, a hello being set up), sent later
            self._send(route, reply, release)

    def _send(self, route: list[bytes], reply: dict, release: float | None = None) -> None:
        """Send a reply map to the routing frames it answers (kept in front, verbatim); a paced
        session's reply waits for its ``release`` time (perf_counter s)."""
        if route is LOCAL_ROUTE:   # the polled server's own caller (_answer_local) takes it as it is
            self._local_reply = (reply, release)
            return
        if type(route) is DirectRoute:   # a controller's direct connection (never paced: no forces)
            frame = None
            if reply["type"] == "measurements" and type(reply["parent"]) is int and reply["session"] in self._framed:
                frame = self._framed[reply["session"]].measurements_frame(reply["parent"], reply)   # SPEC §5.7.6
            if not route.link.write(frame or self._frame(reply)) and reply.get("type") == "measurements":
                joined = self._controllers.get(reply.get("session"))   # (session, controller name)
                hub = self._hubs.get(joined[0]) if joined is not None else None
                if hub is not None:   # lost with the channel: sent again at the controller's next request
                    hub.undelivered(joined[1], reply["step"])
            return
        frames = [*route, self._frame(reply)]
        if release is not None and release > time.perf_counter():
            heapq.heappush(self._paced, (release, next(self._order), frames))
            return
        try:
            self._sock.send_multipart(frames, zmq.NOBLOCK)
        except zmq.ZMQError as exc:  # peer gone or its queue full: drop the reply
            log.warning("reply dropped: %s", exc)

    def _over_limits(self, frames: list[bytes | memoryview], size: int, count: int) -> ProtocolError | None:
        """Error 1 for a received message that breaks SPEC §1's limits (None when it does not)."""
        if size > self.max_message_bytes:
            return codec.over_limit(size, self.max_message_bytes)
        if count - 1 > codec.MAX_ROUTING_FRAMES:   # the ROUTER's identity frame included
            return ProtocolError(Code.MALFORMED, None, f"{count - 1} routing frames before the message; at most "
                                 f"{codec.MAX_ROUTING_FRAMES} (SPEC §1)", extra={"limit": "routing_frames",
                                                                               "maximum": codec.MAX_ROUTING_FRAMES})
        routing = frames[:-1]
        big = next((i for i, f in enumerate(routing) if len(f) > codec.MAX_ROUTING_FRAME_BYTES), None)
        if big is not None:
            return ProtocolError(Code.MALFORMED, None, f"routing frame {big} is {len(routing[big])} bytes; at most "
                                 f"{codec.MAX_ROUTING_FRAME_BYTES} (SPEC §1)",
                                 extra={"limit": "routing_frame_bytes", "maximum": codec.MAX_ROUTING_FRAME_BYTES})
        return None

    def _send_due(self) -> None:
        """Send the held replies of paced sessions whose release has come."""
        now = time.perf_counter()
        while self._paced and now < self._paced[0][0] < now + RELEASE_SPIN:   # the receive timeout is in whole ms
            now = time.perf_counter()
        while self._paced and self._paced[0][0] <= now:
            frames = heapq.heappop(self._paced)[2]
            try:
                self._sock.send_multipart(frames, zmq.NOBLOCK)
            except zmq.ZMQError as exc:
                log.warning("paced reply dropped: %s", exc)

    def _send_later(self, session: str, route: list[bytes], mtype: str, parent: Any, fields: dict,
                    own: str | None = None) -> None:
        """Send a deferred reply (a ControlHub's callback): to a controller under its own session id
        ``own``, to the multibody under the session's; a paced session's ``forces`` wait for their
        release."""
        s = self.sessions.get(session)
        due = s.pacer.release_time(fields["seq"]) if s is not None and s.pacer and mtype == "forces" else None
        self._send(route, codec.message(mtype, next(self._ids), own or session, parent, **fields), due)

    def _frame(self, reply: dict) -> bytes:
        """A reply as its frame (signed with the server's key); a reply holding a value the wire
        cannot carry (a server fault: scene bounds keep every sent value in range) becomes an
        internal error naming the field, so the loop never dies packing it."""
        try:
            return codec.pack(reply, self.key)
        except codec.EncodeError as exc:
            log.error("cannot send a %s reply: %s", reply.get("type"), exc)
            return codec.pack(codec.error_reply(next(self._ids), reply.get("parent"), reply.get("session"),
                                                Code.INTERNAL, exc.field, f"internal server error: the reply's {exc}"),
                              self.key)

    def respond(self, frame: bytes, timeout: float = math.inf) -> bytes:
        """One request frame -> its reply frame: what the socket loop sends back (a paced session's
        reply when its release has come: this in-process caller waits). Never raises, but a polled
        server raises TimeoutError when a deferred reply is not ready within ``timeout`` s."""
        reply = self._frame(self._answer_local(frame, timeout))
        self._wait_hold()
        return reply

    def _answer_local(self, request: bytes | dict, timeout: float) -> dict:
        """The reply to a request of this process's own client: at once, or on a polled server,
        when deferred, after turns of the loop in this thread until it is sent (to LOCAL_ROUTE)."""
        if not self.polled:
            return self.handle(request)
        self._serve_ready()
        reply = self.handle(request, LOCAL_ROUTE)
        return reply if reply is not None else self.await_local(timeout)

    def serve_ready(self) -> None:
        """Polled: what is already on the socket and the direct links answered, the deadlines that
        passed kept — before a request of this process's own run (server/service/controlled_step.py)."""
        self._serve_ready()

    def await_local(self, timeout: float) -> dict:
        """Polled: the deferred reply to this process's own run (sent to :attr:`local_route`), after
        turns of the loop in this thread until it is sent; TimeoutError after ``timeout`` s."""
        hold, give_up = self._hold, time.monotonic() + timeout
        due: float | None = None   # the controllers' next deadline: recomputed only after a message was served
        while self._local_reply is None:
            now = time.monotonic()
            if now > give_up:
                raise TimeoutError(f"no reply to a request of this run within {timeout:g} s from its own force "
                                   f"server (its controllers on {self._address})")
            if due is None:
                due = min((hub.next_deadline() for hub in self._hubs.values()), default=math.inf)
            if due <= now or now >= self._next_sweep or self._direct is None or self._sock.pending \
                    or self._flying or self._setups or self._paced:
                self.serve_once()   # a whole turn: what is due, the sweep, or no direct channel
                due = None
            elif self._wait_direct(POLL_MS if due - now >= POLL_MS / 1000 else max(1, int((due - now) * 1000))):
                due = None
        (reply, release), self._local_reply = self._local_reply, None
        self._hold = release if release is not None else hold
        return reply

    def _wait_hold(self) -> None:
        """In-process: sleep until the reply being handled may leave (paced sessions)."""
        if self._hold is not None:
            time.sleep(max(0.0, self._hold - time.perf_counter()))

    def respond_map(self, msg: dict, timeout: float = math.inf) -> dict:
        """One request map -> its reply map (never raises), for a client in this process: the
        frame path without msgpack. The map gets every check a frame's content gets (envelope,
        fields, arrays: :mod:`hydrolink.protocol.codec`) and the reply carries the same values a
        frame would (arrays as read-only ndarrays). A signing server takes frames only. ``timeout``:
        as for :meth:`respond`."""
        if self.key is not None:
            return codec.error_reply(next(self._ids), codec.readable_id(msg), None, Code.BAD_SIGNATURE, "sig",
                                     "a signing server takes frames only (respond), not maps")
        reply = self._answer_local(msg, timeout)
        self._wait_hold()
        return reply

    def step_map(self, session: str, msg_id: str, fields: dict, timeout: float = math.inf) -> dict:
        """The ``step`` of this process's own client (ServerConnection, no signing key): the reply
        :meth:`respond_map` gives, bit for bit, without what that client's map does not need — its
        envelope is the connection's own (not checked again), it holds no nil, and the dispatch is
        known; its fields get every check (Session.step). A session with controllers, paced, in a
        worker, or a polled server's, takes :meth:`respond_map`."""
        s = self.sessions.get(session)
        if s is None or self.polled or type(s) is not Session or s.pacer is not None or s.id in self._hubs:
            return self.respond_map(codec.message("step", msg_id, session, **fields), timeout)
        s.touch()
        try:
            reply = s.step(fields)
        except Exception as exc:  # noqa: BLE001 - as handle: an error reply, never a raise
            return self._error(exc, {"type": "step", "msg_id": msg_id}, session, None)
        return {"v": codec.PROTOCOL_VERSION, "type": "forces", "msg_id": next(self._ids), "session": session,
                "parent": msg_id, **reply}

    def local_step(self, session: str) -> LocalStep | None:
        """The step path of this server's own in-process client for ``session``
        (server/service/local_step.py): a server without a socket (no controller can join), a
        session that steps here, unpaced; None otherwise (the client takes :meth:`step_map`)."""
        s = self.sessions.get(session)
        if s is None or self._sock is not None or type(s) is not Session or s.pacer is not None \
                or s.id in self._hubs:
            return None
        return LocalStep(s)

    def controlled_step(self, session: str) -> ControlledStep | None:
        """The step path of a polled server's own run for ``session`` with controllers
        (server/service/controlled_step.py): a session that steps here, unpaced; None otherwise
        (the run takes :meth:`respond_map`)."""
        s = self.sessions.get(session)
        hub = self._hubs.get(session)
        if s is None or hub is None or not self.polled or type(s) is not Session or s.pacer is not None:
            return None
        return ControlledStep(self, s, hub)

    def handle(self, frame: bytes | dict, route: list[bytes] | None = None) -> dict | None:
        """One request frame (or, in-process, its unpacked map) -> its reply message (never
        raises); None when the reply is deferred (only with ``route``, the routing frames, from
        the socket loop)."""
        msg: Any = None
        session: str | None = None
        self._hold = None
        if route is not None and type(frame) is not dict and len(frame) > codec.SMALL_FRAME:
            busy = self._refused_unread(frame, route)
            if busy is not None:
                return busy
        try:
            msg = frame if type(frame) is dict else codec.unpack(frame, self.key)
            session = msg.get("session") if isinstance(msg.get("session"), str) else None
            mtype, msg_id, session = codec.check_envelope(msg)
            msg = codec.without_nil(msg)   # SPEC §2: a nil field is an absent one, for every field
            if session in self._controllers and mtype not in CONTROLLER_REQUESTS:
                raise ProtocolError(Code.UNKNOWN_TYPE, "type", f"{mtype!r} is not a controller's request: a "
                                    f"controller's session id allows only {', '.join(CONTROLLER_REQUESTS)}")
            isolated = self.sessions.get(session) if session is not None else None
            if type(isolated) is WorkerSession and isolated.flight is not None and route is not None:
                self._wait_behind(isolated, msg, route, len(frame) if type(frame) is not dict else 0)
                return None   # answered in order once the worker answers the one before (SPEC §1)
            hub = self._hubs.get(session) if session is not None else None
            if hub is not None and route is not None and self._running and hub.holds(mtype, msg, route):
                self._queue(hub, len(frame) if type(frame) is not dict else 0)
                return None   # answered in order once the session's deferred step is (SPEC §1, §5.7)
            self._route = route
            out = self._handlers[mtype](msg, msg_id, session)
            if out is None:
                return None
            rtype, fields, session = out
            return codec.message(rtype, next(self._ids), session, msg_id, **fields)
        except Exception as exc:  # noqa: BLE001 - the loop must never die
            return self._error(exc, msg, session, route)

    def _refused_unread(self, frame: bytes | memoryview, route: list[bytes]) -> dict | None:
        """Error 14 ``busy`` for a large multibody hello to a full server (SPEC §4.2), read from its
        envelope alone (codec.peek): its content (a padded scene, inline HDBs) is neither copied nor
        decoded, so a flood of them costs the loop microseconds each. None otherwise (a signing
        server checks every signature first)."""
        if self.key is not None:
            return None
        try:
            self.limits.admit(len(self._setups), len(self.sessions))
            return None
        except ProtocolError as busy:
            env = codec.peek(frame, ("v", "type", "msg_id", "role", "session"))
            if env is None or (env.get("type"), env.get("role"), env.get("session")) != ("hello", "multibody", None) \
                    or type(env.get("v")) is not int or env["v"] not in codec.SUPPORTED_VERSIONS:
                return None
            return self._error(busy, env, None, route)

    def _error(self, exc: Exception, msg: Any, session: str | None, route: list[bytes] | None) -> dict:
        """The ``error`` reply to a request that raised ``exc`` (logged; code 99 unless a ProtocolError)."""
        if isinstance(exc, MemoryError):   # not the request's fault, nor a bug: busy (SPEC §5.6)
            exc = ProtocolError(Code.BUSY, None, "the server ran out of memory handling this request; send it "
                                "again later", extra={"limit": "memory"})
        if not isinstance(exc, ProtocolError):
            self._error_log.log(Code.INTERNAL, logging.ERROR, "internal error handling a %s (session %s)",
                                msg.get("type") if isinstance(msg, dict) else "message", session, exc_info=exc)
            return codec.error_reply(next(self._ids), codec.readable_id(msg), session, Code.INTERNAL, None,
                                     f"internal server error: {type(exc).__name__}: {exc}")
        if exc.code == Code.BAD_SIGNATURE:
            self._error_log.log(exc.code, logging.WARNING, "refused a request: %s (from routing identity %s)",
                                exc.message, route[0].hex() if route else "in-process")
        elif exc.code not in (Code.OUT_OF_ORDER,):
            self._error_log.log(exc.code, logging.INFO, "error %d %s [%s] session %s: %s", exc.code, exc.name,
                                exc.field, session, exc.message)
        parent = codec.readable_id(msg) if msg is not None else exc.parent
        return codec.error_from(exc, next(self._ids), parent, session)

    @property
    def files(self) -> FileSetReader:
        """The reader of HDB file sets over this server's content store (opened on first use)."""
        if self._files is None:
            self._files = FileSetReader(self._store or ContentStore(default_folder()))
        return self._files

    def _session(self, session: str | None) -> Session:
        if session is None:
            raise ProtocolError(Code.MISSING_FIELD, "session", "this message needs the session id from welcome")
        try:
            s = self.sessions[session]
        except KeyError:
            why = self._closed.get(session, "no such session on this server")
            raise ProtocolError(Code.UNKNOWN_SESSION, "session", f"session {session!r}: {why}") from None
        s.touch()
        return s

    # ------------------------------------------------------------ handlers

    def _hello(self, msg: dict, msg_id: Any, session: str | None) -> tuple[str, dict, str | None]:
        role = codec.require_str(msg, "role")
        if role not in codec.ROLES:
            raise ProtocolError(Code.BAD_VALUE, "role", f"must be one of {list(codec.ROLES)}, got {codec.describe(role)}")
        if role not in codec.IMPLEMENTED_ROLES:
            raise ProtocolError(Code.NOT_IMPLEMENTED, "role", f"role {role!r} is reserved; protocol 1 "
                                f"servers implement only {list(codec.IMPLEMENTED_ROLES)}")
        if role == "controller":
            return self._controller_hello(msg, session)
        if session is not None:
            if session in self.sessions:
                raise ProtocolError(Code.WRONG_STATE, "session", f"session {session!r} is already set up "
                                    f"({self.sessions[session].state}); a multibody hello creates a new session")
            raise ProtocolError(Code.BAD_VALUE, "session", "a multibody hello must not carry a session id")
        client = codec.require_map(msg, "client", default={})
        realtime = None
        if msg.get("realtime") is not None:   # pace the session's replies (SPEC §5.1)
            try:
                realtime = check_factor(codec.require_float(msg, "realtime"), "realtime")
            except ValueError as exc:
                raise ProtocolError(Code.BAD_VALUE, "realtime", str(exc)) from None
        self.limits.admit(len(self._setups), len(self.sessions))
        t0 = time.perf_counter()
        if self._route is None or not self._running:   # no loop to answer later: the caller waits
            try:
                model = build_model(msg, self.files)
            except MemoryError:
                raise self._out_of_memory() from None
            return self._open(msg, client, realtime, t0, Placed.of(os.urandom(16).hex(), model, 0.0))
        work = self._workers.submit(contextvars.copy_context().run,   # its log lines too: limit_lines
                                    place, msg, self.files, self.isolate_step_s, self._worker_slots)
        self._setups.append(PendingHello(msg, msg_id, self._route, client, realtime, t0, work))
        return None   # answered by _finish_setups

    def _finish_setups(self) -> None:
        """Answer the hellos whose set-up is done (in the loop: sessions change only here)."""
        running = []
        for hello in self._setups:
            if not hello.model.done():
                running.append(hello)
                continue
            try:
                try:
                    placed = hello.model.result()
                except MemoryError:
                    raise self._out_of_memory() from None
                rtype, fields, sid = self._open(hello.msg, hello.client, hello.realtime, hello.started, placed)
                reply = codec.message(rtype, next(self._ids), sid, hello.msg_id, **fields)
            except Exception as exc:  # noqa: BLE001 - a failed set-up is that hello's error reply
                reply = self._error(exc, hello.msg, None, hello.route)
            self._send(hello.route, reply)
        self._setups = running

    def _open(self, msg: dict, client: dict, realtime: float | None, t0: float,
              placed: Placed) -> tuple[str, dict, str]:
        """A new session over a built model (stepping here, or in its worker): its ``welcome``;
        error 14 (memory) when its model would pass the server's memory budget beside the open
        sessions'. A refused session's worker is stopped."""
        try:
            return self._welcome(msg, client, realtime, t0, placed)
        except BaseException:
            if placed.worker is not None and placed.session_id not in self.sessions:
                placed.worker.stop()
                self._worker_slots.give_back()
            raise

    def _welcome(self, msg: dict, client: dict, realtime: float | None, t0: float,
                 placed: Placed) -> tuple[str, dict, str]:
        if self.memory is not None:
            self.memory.admit(self.held_bytes(), placed.footprint)
        sid = placed.session_id
        if placed.scene.controllers:
            if self._sock is None:
                raise ProtocolError(Code.BAD_SCENE, "scene.controllers", "controllers connect over the network: "
                                    "this in-process server has no socket (run the session on a server with one, "
                                    "e.g. hydrolink serve, or hydrolink run without an embedded server)")
            try:
                self._hubs[sid] = ControlHub(placed.scene, msg["scene"], placed.n_waves, sid,
                                             lambda route, mtype, parent, fields, own=None, _sid=sid:
                                             self._send_later(_sid, route, mtype, parent, fields, own),
                                             join_token(msg))
            except ModelError as exc:
                raise ProtocolError(Code.BAD_SCENE, f"scene.{exc.key}", str(exc)) from None
        if placed.model is not None:
            self.sessions[sid] = Session(sid, placed.model, client, realtime, self.plant_builder)
        else:
            self.sessions[sid] = WorkerSession(placed, client, realtime, self.plant_builder)
        self.sessions[sid].footprint = placed.footprint
        log.info("session %s opened by %s %s: %d bodies, dt %g, setup %.3f s, step %.3f ms%s", sid,
                 client.get("name", "?"), client.get("version", "?"), placed.n_bodies, placed.dt,
                 time.perf_counter() - t0, placed.cost * 1e3,
                 f", in worker process {placed.worker.process.pid}" if placed.worker else "")
        welcome = {
            "protocol": codec.PROTOCOL_VERSION,
            "server": {"name": "hydrolink", "version": self._version},
            "session_timeout": self.session_timeout,
            "setup": placed.setup,
        }
        if sid in self._hubs:
            welcome["control_token"] = self._hubs[sid].token   # the owner hands it to its controllers
        if self._direct is not None and not self.polled and realtime is None:   # paced replies wait: ZeroMQ only
            welcome["direct"] = self._direct.offer(sid)   # the multibody client's direct channel (SPEC §5.7.5, 1.16)
        return "welcome", welcome, sid

    def held_bytes(self) -> int:
        """The bytes the open sessions' models hold (as measured when each opened)."""
        return sum(s.footprint for s in self.sessions.values())

    def _out_of_memory(self) -> ProtocolError:
        """Error 14 (memory) for a set-up that ran out of memory building its model."""
        budget = self.memory or MemoryBudget(0)
        return budget.out_of_memory(self.held_bytes())

    def _resume_held(self) -> None:
        """Handle the requests held behind a deferred step once it is answered, in their order."""
        for hub in list(self._hubs.values()):
            self._answer_held(hub)

    def _queue(self, hub: ControlHub, size: int) -> None:
        """Count a request ``hub.holds`` just queued behind the session's deferred step (SPEC §1):
        beyond MAX_QUEUED requests, or the message limit in bytes, it is taken back and refused
        with error 14 ``busy`` (``limit`` "queued")."""
        sizes = self._queued.setdefault(hub.session_id, deque())
        total = sum(sizes) + size
        if len(sizes) < MAX_QUEUED and total <= self.max_message_bytes:
            sizes.append(size)
            return
        hub.held.pop()
        raise ProtocolError(Code.BUSY, None, f"session {hub.session_id} already holds {len(sizes)} requests "
                            f"({sum(sizes)} bytes) behind its deferred step; at most {MAX_QUEUED} requests and "
                            f"{self.max_message_bytes} bytes (SPEC §1): wait for the deferred reply",
                            extra={"limit": "queued", "maximum": MAX_QUEUED, "current": len(sizes)})

    def _answer_held(self, hub: ControlHub) -> None:
        sizes = self._queued.get(hub.session_id)
        while hub.held and hub.pending is None:
            if sizes:
                sizes.popleft()
            msg, route = hub.held.popleft()
            reply = self.handle(msg, route)
            if reply is not None:
                self._send(route, reply, self._hold)

    def _step(self, msg: dict, msg_id: Any, session: str | None) -> tuple[str, dict, str | None] | None:
        s = self._session(session)
        arrived = time.perf_counter()
        hub = self._hubs.get(s.id)
        if type(s) is WorkerSession:
            return self._step_in_worker(s, hub, msg, msg_id, arrived)
        if hub is None:
            fields = s.step(msg)
            self._hold = s.release_time(fields["seq"], arrived)
            return "forces", fields, session
        seq, iteration = msg.get("seq"), codec.require_int(msg, "iteration", default=0, minimum=0)
        new = type(seq) is int and seq == s.last_seq + 1
        meas = hub.step_request(msg, seq, iteration, new) if new else None
        checked = s.step_input(msg)
        if meas is not None:   # relayed before the model steps: the controllers' round trip overlaps it
            hub.relay_with(meas, s.previews)
        fields = s.advance(*checked, hub.hydro_command(seq) if new else None)
        self._hold = s.release_time(fields["seq"], arrived)
        fields = hub.after_step(seq, iteration, new, None, fields, self._route, msg_id)
        return None if fields is None else ("forces", fields, session)

    # ------------------------------------------------------------ sessions in worker processes

    def _step_in_worker(self, s: WorkerSession, hub: ControlHub | None, msg: dict, msg_id: Any,
                        arrived: float) -> None:
        """Hand a step to the session's worker (answered by :meth:`_worker_answer`): a controlled
        step's measurements are checked here first, and the wave probes due go with it."""
        control, grids, k, hydro = None, {}, 0, None
        if hub is not None:
            seq, iteration = msg.get("seq"), codec.require_int(msg, "iteration", default=0, minimum=0)
            new = type(seq) is int and seq == s.last_seq + 1
            meas = hub.step_request(msg, seq, iteration, new) if new else None
            control = (seq, iteration, new, meas)
            hydro = hub.hydro_command(seq) if new else None
            if meas is not None:
                grids, k = hub.previews_due(meas), meas["step"]
        self._submit(s, Flight("step", msg, msg_id, self._route, time.monotonic(), arrived, control),
                     (msg, grids, k, hydro))

    def _submit(self, s: WorkerSession, flight: Flight, args: tuple) -> None:
        if flight.route is None:   # pragma: no cover - workers exist only under the socket loop
            raise ProtocolError(Code.WRONG_STATE, "type", "an in-process server steps no session in a worker")
        try:
            s.submit(flight, args)
        except WorkerFailed as exc:
            self._worker_failed(s, None, exc.why)
            raise self._failed(s, exc.why) from None
        self._flying[s.worker.fileno()] = s

    def _poll_workers(self) -> None:
        """Wait for the next request or a worker's answer (whichever comes first) and handle it."""
        poller = zmq.Poller()
        poller.register(self._sock.socket, zmq.POLLIN)
        if self._direct is not None:
            self._direct.prune()   # a link closed since (a failed write): its descriptor not polled
        direct = () if self._direct is None else (self._direct.fileno(), *(link.fileno() for link in self._direct.links))
        for fd in (*self._flying, *direct):
            poller.register(fd, zmq.POLLIN)
        ready = dict(poller.poll(0 if self._sock.pending else self._rcv_ms))
        for fd in [fd for fd in self._flying if fd in ready]:
            self._worker_answer(self._flying.pop(fd))
        if direct:
            self._serve_direct(ready)
        if self._sock.socket in ready or self._sock.pending:
            self._receive()
        else:
            self._sock.tend()

    def _worker_answer(self, s: WorkerSession) -> None:
        """Reply to the request the worker of ``s`` answered, then hand it the next one waiting."""
        flight = s.flight
        try:
            _, (status, value) = s.done()
        except WorkerFailed as exc:
            self._worker_failed(s, flight, exc.why)
            return
        self._hold = None
        try:
            reply = self._flight_reply(s, flight, status, value)
        except Exception as exc:  # noqa: BLE001 - the loop must never die
            reply = self._error(exc, flight.msg, s.id, flight.route)
        if reply is not None:
            self._send(flight.route, reply, self._hold)
        while s.waiting and s.flight is None:
            msg, route, _ = s.waiting.popleft()
            reply = self.handle(msg, route)
            if reply is not None:
                self._send(route, reply, self._hold)

    def _flight_reply(self, s: WorkerSession, flight: Flight, status: str, value: Any) -> dict | None:
        """The reply to a request a worker answered (None: deferred by the session's controllers)."""
        if status == "error":
            code, field, message, extra = value
            return self._error(ProtocolError(code, field, message, extra=extra), flight.msg, s.id, flight.route)
        if status != "ok":
            return self._error(RuntimeError(f"in the session's worker: {value}"), flight.msg, s.id, flight.route)
        fields, waves = value[0], value[1]
        if flight.op != "step":
            return codec.message({"save": "saved", "restore": "restored", "release": "released"}[flight.op],
                                 next(self._ids), s.id, flight.msg_id, **fields)
        self._hold = s.release_time(fields["seq"], flight.arrived)
        hub = self._hubs.get(s.id)
        if flight.control is not None and hub is not None:
            seq, iteration, new, meas = flight.control
            fields = hub.after_step(seq, iteration, new, meas, fields, flight.route, flight.msg_id, waves)
            if fields is None:
                return None
        return codec.message("forces", next(self._ids), s.id, flight.msg_id, **fields)

    def _wait_behind(self, s: WorkerSession, msg: dict, route: list[bytes], size: int) -> None:
        """Keep a request of ``s`` until its worker answers the one before (SPEC §1: in order);
        beyond MAX_QUEUED requests or the message limit in bytes, error 14 ``busy`` (``queued``)."""
        held = sum(n for _, _, n in s.waiting)
        if len(s.waiting) >= MAX_QUEUED or held + size > self.max_message_bytes:
            raise ProtocolError(Code.BUSY, None, f"session {s.id} already holds {len(s.waiting)} requests "
                                f"({held} bytes) behind the one its worker computes; at most {MAX_QUEUED} requests "
                                f"and {self.max_message_bytes} bytes (SPEC §1): wait for its reply",
                                extra={"limit": "queued", "maximum": MAX_QUEUED, "current": len(s.waiting)})
        s.waiting.append((msg, route, size))

    def _failed(self, s: WorkerSession, why: str) -> ProtocolError:
        return ProtocolError(Code.SESSION_FAILED, None, f"session {s.id} ended: {why}; its state is gone "
                             "(open a new session with hello)")

    def _worker_failed(self, s: WorkerSession, flight: Flight | None, why: str) -> None:
        """End a session whose worker died or passed its time budget: error 16 to the request in
        flight, error 7 (naming why) to those waiting; the worker reaped."""
        self._close(s, f"ended: {why}")
        if flight is not None:
            self._send(flight.route, self._error(self._failed(s, why), flight.msg, s.id, flight.route))
        while s.waiting:
            msg, route, _ = s.waiting.popleft()
            reply = self.handle(msg, route)
            if reply is not None:
                self._send(route, reply)

    def _check_flights(self, now: float) -> None:
        """End the sessions whose worker took longer than ``step_timeout`` for a request."""
        for fd, s in list(self._flying.items()):
            if s.flight is not None and now - s.flight.started > self.step_timeout:
                del self._flying[fd]
                flight, s.flight = s.flight, None
                self._worker_failed(s, flight, f"its worker took longer than {self.step_timeout:g} s for a "
                                               f"{flight.op} (stopped)")

    # ------------------------------------------------------------ controllers (SPEC §5.7)

    def _controller_hello(self, msg: dict, session: str | None) -> tuple[str, dict, str | None]:
        """A controller joins the session whose join token its hello carries (SPEC §5.7.2)."""
        name = msg.get("controller")
        if name is not None and not isinstance(name, str):
            raise ProtocolError(Code.BAD_VALUE, "controller", f"must be a str or nil, got {type(name).__name__}")
        codec.require_map(msg, "client", default={})
        token = codec.require_str(msg, "token")
        if session in self._controllers:   # a rejoin over its own id: the session it joined
            session = self._controllers[session][0]
        if session is not None:
            hub = self._hubs.get(self._session(session).id)
            if hub is None:
                raise ProtocolError(Code.BAD_VALUE, "controller", f"session {session!r} declares no controllers")
            if not token_matches(hub, token):
                raise ProtocolError(Code.UNAUTHORIZED, "token", "not this session's join token (the owner's "
                                    "welcome carries it: control_token)")
        else:
            fits = [sid for sid, hub in self._hubs.items() if token_matches(hub, token)
                    and ((name in hub.slots) if name is not None else len(hub.slots) == 1)]
            if not fits:
                raise ProtocolError(Code.UNKNOWN_SESSION, "token", "no open session holds this join token"
                                    + (f" and declares a controller {name!r}" if name else " and exactly one controller")
                                    + " (is the multibody run started?)")
            session = fits[0]   # tokens are drawn per session: two sessions share one only by the owners' choice
        s = self._session(session)
        hub = self._hubs[s.id]
        plant = None
        if msg.get("plant") is not None:   # the device as a linear plant (SPEC §5.7.2)
            ask = codec.require_map(msg, "plant")
            dt = None if ask.get("dt") is None else codec.require_float(ask, "dt", "plant.dt")
            if dt is not None and not PLANT_DT[0] <= dt <= PLANT_DT[1]:
                raise ProtocolError(Code.BAD_VALUE, "plant.dt", f"must be in [{PLANT_DT[0]:g}, {PLANT_DT[1]:g}] s "
                                    f"(nil: continuous time), got {dt}")
            plant = s.plant(dt)
        slot, rejoined = hub.join(name)
        control = hub.info(slot)
        if plant is not None:
            control = {**control, "plant": plant.to_wire()}
        own = secrets.token_hex(16)
        earlier = [c for c, joined in self._controllers.items() if joined == (s.id, slot.name)]
        for c in earlier[:max(0, len(earlier) - 7)]:   # a controller's last 8 connections keep their ids
            del self._controllers[c]
        self._controllers[own] = (s.id, slot.name)
        direct = self._direct.offer(own) if self._direct is not None else None
        self._framed = {c: layout for c, layout in self._framed.items() if c in self._controllers}
        if direct is not None and self.key is None and msg.get("frames") is True:   # not signed: SPEC §5.7.6
            layout = hub.layout(slot)
            self._framed[own] = layout
            direct["frames"] = layout.to_wire()
        return "welcome", {
            "protocol": codec.PROTOCOL_VERSION,
            "server": {"name": "hydrolink", "version": self._version},
            "session_timeout": self.session_timeout,
            "epoch": slot.epoch, "rejoined": rejoined, "control": control,
            **({"direct": direct} if direct is not None else {}),
        }, own

    def _controller_request(self, kind: str, msg: dict, msg_id: Any,
                            session: str | None) -> tuple[str, dict, str | None] | None:
        own = session
        session, name = self._joined(kind, own)
        if msg.get("controller") != name:
            raise ProtocolError(Code.UNAUTHORIZED, "controller", f"this session id is controller {name!r}'s "
                                f"(got {codec.describe(msg.get('controller'))})")
        hub = self._controller_hub(kind, session)
        if type(hub) is str:
            return "stop", {"reason": hub}, own
        out = (hub.measure if kind == "measure" else hub.command)(msg, self._route, msg_id, own)
        if out is None:
            if self._route is None:
                raise ProtocolError(Code.WRONG_STATE, "type", "an in-process server cannot defer a reply")
            return None
        return out[0], out[1], own

    def _joined(self, kind: str, own: str | None) -> tuple[str, str]:
        """(session id, controller name) of the joined controller whose own session id is ``own``;
        ProtocolError 7 when it is none's."""
        if own not in self._controllers:
            raise ProtocolError(Code.UNKNOWN_SESSION, "session", f"{kind!r} needs the session id of the controller's "
                                "welcome (a controller joins with the session's join token, SPEC §5.7.2)")
        return self._controllers[own]

    def _controller_hub(self, kind: str, session: str) -> ControlHub | str:
        """The controllers of ``session``, or why its controllers' requests get ``stop`` (it closed)."""
        if session not in self.sessions and session in self._closed:
            return f"session {self._closed[session]}"
        s = self._session(session)
        hub = self._hubs.get(s.id)
        if hub is None:
            raise ProtocolError(Code.UNKNOWN_TYPE, "type", f"{kind!r} is a controller request; session "
                                f"{session!r} declares no controllers")
        return hub

    def _command_frame(self, link: DirectLink, frame: bytes) -> dict | None:
        """The reply to a command frame from ``link`` (SPEC §5.7.6), or None when deferred: handled as
        its ``command`` map would be (the same checks, errors and decisions), never raising."""
        own, request = link.own, None
        self._hold = None
        try:
            layout = self._framed.get(own)
            if layout is None:
                raise ProtocolError(Code.MALFORMED, None, "a control frame (first byte 0xC1) from a controller whose "
                                    "welcome offered none (SPEC §5.7.6): send msgpack messages")
            cmd = layout.read_command(frame)
            request = cmd.request
            self._route = link.route
            session, name = self._joined("command", own)
            hub = self._controller_hub("command", session)
            if type(hub) is str:
                return codec.message("stop", next(self._ids), own, request, reason=hub)
            out = hub.command_frame(name, cmd, link.route, own)
            return None if out is None else codec.message(out[0], next(self._ids), own, request, **out[1])
        except Exception as exc:  # noqa: BLE001 - the loop must never die
            return self._error(exc, {"msg_id": request} if request is not None else None, own, link.route)

    def _measure(self, msg: dict, msg_id: Any, session: str | None):
        return self._controller_request("measure", msg, msg_id, session)

    def _command(self, msg: dict, msg_id: Any, session: str | None):
        return self._controller_request("command", msg, msg_id, session)

    def _upload(self, msg: dict, msg_id: Any, session: str | None) -> tuple[str, dict, str | None]:
        """One content into the HDB store (SPEC §5.8): checked against its SHA-256, bounded. The
        file-set hello that follows parses it in a child: their forkserver started now."""
        start_children()
        data = codec.require(msg, "data")
        if not isinstance(data, (bytes, bytearray, memoryview)):
            raise ProtocolError(Code.BAD_VALUE, "data", f"must be bin (the file's bytes), got {codec.describe(data)}")
        digest = codec.require_str(msg, "sha256")
        if not HASH.fullmatch(digest):
            raise ProtocolError(Code.BAD_VALUE, "sha256", "must be the lowercase hex SHA-256 of data "
                                f"(64 characters), got {codec.describe(digest)}")
        try:
            _, new = self.files.store.put(bytes(data), digest)
        except ContentTooLarge as exc:
            raise ProtocolError(Code.BAD_VALUE, "data", str(exc)) from None
        except ValueError as exc:
            raise ProtocolError(Code.BAD_VALUE, "sha256", str(exc)) from None
        log.info("HDB store: %s %s (%d bytes)", "stored" if new else "already held", digest[:12], len(data))
        return "uploaded", {"sha256": digest, "size": len(data), "new": new}, session

    def _rollback(self, msg: dict, msg_id: Any, session: str | None) -> tuple[str, dict, str | None] | None:
        """save / restore / release a session's state (SPEC §5.9)."""
        s = self._session(session)
        kind = msg["type"]
        if s.id in self._hubs:
            raise ProtocolError(Code.NOT_IMPLEMENTED, "type", f"{kind!r}: a session with controllers cannot be "
                                "rolled back (its controllers' decisions are not part of a saved state)")
        if type(s) is WorkerSession:
            self._submit(s, Flight(kind, msg, msg_id, self._route, time.monotonic(), time.perf_counter()),
                         () if kind == "save" else (msg,))
            return None
        if kind == "save":
            return "saved", s.save(), session
        if kind == "restore":
            return "restored", s.restore(msg), session
        return "released", s.release(msg), session

    def _ping(self, msg: dict, msg_id: Any, session: str | None) -> tuple[str, dict, str | None]:
        if session is not None:
            self._session(self._controllers[session][0] if session in self._controllers else session)
        return "pong", {"time": time.time(), "sessions": len(self.sessions)}, session

    def _bye(self, msg: dict, msg_id: Any, session: str | None) -> tuple[str, dict, str | None]:
        if session in self._controllers:   # a controller leaves; the session goes on (its fallback decides)
            sid, name = self._controllers.pop(session)
            log.info("session %s: controller %r said bye", sid, name)
            return "goodbye", {"controller": name}, session
        s = self._session(session)
        self._close(s, "closed by bye")
        out = {"steps": s.steps, "compute_s": s.compute_s}
        if s.pacer is not None:
            out["realtime"] = asdict(s.pacer.report())
        return "goodbye", out, session

    # ------------------------------------------------------------ lifecycle

    def _close(self, s: Session | WorkerSession, why: str) -> None:
        if self.sessions.pop(s.id, None) is not None and type(s) is WorkerSession:
            self._flying.pop(s.worker.fileno(), None)
            s.worker.stop()   # killed and reaped
            self._worker_slots.give_back()
        hub = self._hubs.pop(s.id, None)
        self._queued.pop(s.id, None)
        self._closed[s.id] = f"{why} at {time.strftime('%H:%M:%S')}"
        if hub is not None:
            hub.end(why)
            self._answer_held(hub)   # the held requests learn why (error 7)
            log.info("session %s controllers: %s", s.id, hub.summary())
        while len(self._closed) > TOMBSTONES:
            gone = next(iter(self._closed))
            self._closed.pop(gone)
            for own in [c for c, (sid, _) in self._controllers.items() if sid == gone]:
                del self._controllers[own]
        log.info("session %s %s after %d steps (%.3f s model time)", s.id, why, s.steps, s.compute_s)

    def _expire(self, now: float) -> None:
        for s in [s for s in self.sessions.values() if now - s.last_seen > self.session_timeout]:
            self._close(s, f"expired after {self.session_timeout:g} s idle")

    def _shutdown(self) -> None:
        self._workers.close()
        for hello in self._setups:   # a set-up still running: its worker (if it starts one) is stopped
            hello.model.add_done_callback(_stop_placed)
        self._setups = []
        for s in list(self.sessions.values()):
            self._close(s, "closed by server shutdown")
        if self._sock is None or self._sock.closed:
            return
        if self._security is not None:
            self._security.close()
        self._sock.close(POLLED_LINGER_MS if self.polled else 0)
        if self._direct is not None:   # the controllers' stop already written (sessions closed above)
            self._direct.close()
        if self._own_context:
            self._ctx.term()
        log.info("hydrolink server on %s stopped", self._address)


def _stop_placed(future: Future) -> None:
    """A set-up finished after its server stopped: its worker process (if any) stopped and reaped."""
    if not future.cancelled() and future.exception() is None and future.result().worker is not None:
        future.result().worker.stop()


def serve_in_thread(bind: str = "tcp://127.0.0.1:*", **kw: Any) -> tuple[ForceServer, threading.Thread]:
    """Start a :class:`ForceServer` in a daemon thread; stop it with ``server.stop(); thread.join()``."""
    server = ForceServer(bind, **kw)
    thread = threading.Thread(target=server.serve_forever, name=f"hydrolink-server {server.address}",
                              daemon=True)
    thread.start()
    return server, thread
