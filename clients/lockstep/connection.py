"""Client side of the wire protocol (SPEC.md): one DEALER socket, one request in flight.

Used by the Exudyn client, the FMU master and controllers::

    with ServerConnection("tcp://127.0.0.1:5555") as conn:
        setup = conn.hello(scene_text, {"sphere.h5": ds})
        f = conn.step(0, 0.0, position, velocity)
        conn.bye()
"""

from __future__ import annotations

import logging
import time
from typing import TYPE_CHECKING, Any

import numpy as np
import xarray as xr
import zmq

from hydrolink.clients.lockstep.direct_channel import DirectChannel
from hydrolink.protocol import codec
from hydrolink.protocol.codec import ProtocolError
from hydrolink.protocol.hdb.external_matrices import MATRICES, ExternalMatrices
from hydrolink.protocol.reply import read_forces
from hydrolink.protocol.setup import Setup
from hydrolink.protocol.hdb.wire import HDBFiles, to_wire
from hydrolink.protocol.transport import apply_heartbeats

if TYPE_CHECKING:
    from hydrolink.server.service.controlled_step import ControlledStep
    from hydrolink.server.service.local_step import LocalStep

log = logging.getLogger("hydrolink.clients.connection")

ENVELOPE_AND_ERROR = ("v", "type", "msg_id", "session", "parent", "code", "name", "field", "message", "sig")
WATCH_S = 0.2                 # a pending reply's link is checked this often


class LinkWatch:
    """The state of a DEALER's connection from its monitor socket: connected, or lost since when;
    how often ZeroMQ's reconnects were refused since (a stopped server on a live host refuses at
    once; a link that is down does not answer at all); how many times it came back."""

    def __init__(self, sock: zmq.Socket):
        self._monitor = sock.get_monitor_socket(zmq.EVENT_HANDSHAKE_SUCCEEDED | zmq.EVENT_DISCONNECTED
                                                | zmq.EVENT_CONNECT_RETRIED)
        self.lost_since: float | None = None
        self.refused = 0
        self.reconnects = 0
        self.ever_connected = False

    def update(self) -> None:
        from zmq.utils.monitor import recv_monitor_message
        while True:
            try:
                event = recv_monitor_message(self._monitor, zmq.NOBLOCK)["event"]
            except zmq.Again:
                return
            if event == zmq.EVENT_DISCONNECTED:
                self.lost_since, self.refused = time.monotonic(), 0
            elif event == zmq.EVENT_CONNECT_RETRIED:
                self.refused += self.lost_since is not None
            else:
                self.reconnects += self.ever_connected and self.lost_since is not None
                self.ever_connected, self.lost_since = True, None

    def close(self) -> None:
        self._monitor.close(0)


class RemoteError(RuntimeError):
    """The server answered with an ``error`` (SPEC §5.6)."""

    def __init__(self, code: int, name: str, field: str | None, message: str, address: str = "",
                 extra: dict | None = None):
        self.code, self.name, self.field, self.message = code, name, field, message
        self.extra = extra or {}   # the further fields of the error (13: ``missing``)
        where = f" [{field}]" if field else ""
        at = f" from {address}" if address else ""
        super().__init__(f"server error {code} {name}{where}{at}: {message}")


class ServerConnection:
    """A connection to a hydrolink server; every receive times out after ``timeout`` seconds.

    ``address`` is a ZeroMQ endpoint, or an in-process server (``ForceServer(None)``, or a polled
    ``ForceServer(bind, polled=True)`` whose controllers connect to its socket: an object with
    ``respond_map(map, timeout) -> map``, or ``respond(frame, timeout) -> frame``): then each request is handed
    to it directly, without the transport's wake-ups and — as a map, when there is no signing
    ``key`` — without msgpack. The server checks a map as it checks a frame's content and the
    reply carries the same values (float64 arrays, bit for bit; tests/test_force_server.py).

    ``curve``: a :class:`hydrolink.protocol.security.ClientKeys` for a server that requires CURVE.

    ``direct``: after the welcome, take the server's direct channel when it offers one (SPEC
    §5.7.5, revision 1.16: ``hydrolink serve`` without CURVE): the requests then go over a plain
    stream socket, one send and one receive in this thread, no ZeroMQ I/O thread on either side; a
    channel that fails is closed and the request sent again over ZeroMQ (a step is answered from the
    server's cache, SPEC §5.3). False: ZeroMQ only."""

    def __init__(self, address: Any, *, timeout: float = 30.0, context: zmq.Context | None = None,
                 key: bytes | None = None, client_name: str = "hydrolink-python", curve=None,
                 lost_after: float = 1.0, link_timeout: float = 10.0, direct: bool = True):
        self.timeout = float(timeout)
        self.lost_after = float(lost_after)       # s of refused reconnects before the server counts as stopped
        self.link_timeout = float(link_timeout)   # s a silent link may stay down while a reply is pending
        self.key = key
        self.client_name = client_name
        self.session: str | None = None
        self.setup: Setup | None = None
        self.server_info: dict | None = None
        self.protocol: int | None = None
        self.session_timeout: float | None = None
        self.uploads: list[str] = []   # contents the last hello uploaded (SPEC §5.8)
        self._ids = codec.id_source("c")
        self._local = None if isinstance(address, str) else address
        self._maps = self._local is not None and key is None and hasattr(address, "respond_map")
        self._steps = self._maps and hasattr(address, "step_map")
        self._sock: zmq.Socket | None = None
        self._pending: bytes | None = None  # the in-process server's reply, until received
        self._own_context = False
        self.direct = direct                   # whether to take a direct channel offered
        self._direct: DirectChannel | None = None
        if self._local is not None:
            self.address = getattr(address, "address", "in-process")
            return
        self.address = address
        self._own_context = context is None
        self._ctx = context or zmq.Context()
        self._sock = self._ctx.socket(zmq.DEALER)
        self._sock.setsockopt(zmq.LINGER, 0)
        apply_heartbeats(self._sock, self.link_timeout)
        self._watch = LinkWatch(self._sock)
        self.curve = curve
        if curve is not None:
            curve.apply(self._sock)
        self._sock.connect(address)
        self._recv_timeout_ms = -1
        self._in_flight: tuple[str, bytes] | None = None   # the pending request (type, frame)
        self._reconnects_seen = 0

    # ------------------------------------------------------------ requests

    def _send(self, frame: bytes, deadline: float, mtype: str, limit: float) -> None:
        """Send a request frame; TimeoutError (as for a missing reply) when the socket cannot take it
        by ``deadline``: a DEALER with no connected peer (nothing listening yet, a refused CURVE
        handshake) or a full queue blocks a plain send for ever."""
        if self._local is not None:
            self._pending = self._local.respond(frame, limit)
            return
        try:
            self._sock.send(frame, zmq.NOBLOCK)
            return
        except zmq.Again:
            pass
        while (left := deadline - time.monotonic()) > 0:
            if self._sock.poll(max(1, int(min(left, WATCH_S) * 1000)), zmq.POLLOUT):
                try:
                    self._sock.send(frame, zmq.NOBLOCK)
                    return
                except zmq.Again:
                    continue
            self._check_link(mtype)   # a link lost mid-run (e.g. found by a broken direct channel) ends it
        raise self._no_reply(mtype, limit)

    def _recv(self, deadline: float, mtype: str, limit: float) -> bytes:
        """The next reply frame; TimeoutError once ``deadline`` (time.monotonic) has passed."""
        if self._local is not None:
            frame, self._pending = self._pending, None
            if frame is not None:
                return frame
        else:
            while (left := deadline - time.monotonic()) > 0:
                # a receive timeout on the socket (cheaper than a poller), reset only when it
                # changes by more than 1 ms: once per run in lockstep; between slices of WATCH_S
                # the link is checked, so a dead server is noticed within ~lost_after + WATCH_S
                ms = max(1, int(min(left, WATCH_S) * 1000))
                if abs(ms - self._recv_timeout_ms) > 1:
                    self._sock.setsockopt(zmq.RCVTIMEO, ms)
                    self._recv_timeout_ms = ms
                try:
                    return self._sock.recv()
                except zmq.Again:
                    self._check_link(mtype)
        raise self._no_reply(mtype, limit)

    def _no_reply(self, mtype: str, limit: float) -> TimeoutError:
        """The error of a request the server did not answer within ``limit`` s, with the likely causes."""
        hint = ("; with CURVE: is this client's public key in the server's --curve-clients directory, and "
                "--curve-server-key the server's key?" if getattr(self, "curve", None) is not None else
                "; a server started with --curve-secret refuses plaintext clients")
        size = len(self._in_flight[1]) if self._in_flight is not None else 0
        if size > codec.MAX_MESSAGE_BYTES:
            hint += (f"; this request is {size / 2**20:.1f} MiB, over the default message limit of "
                     f"{codec.MAX_MESSAGE_BYTES // 2**20} MiB: a server drops a frame over twice its limit "
                     "unanswered (under that it answers error 1 naming its limit; a server before protocol "
                     "revision 1.2 drops any frame over its limit: SPEC §1): send the HDB files by hash "
                     "(hydrolink run --hdb-files) or start the server with a larger --max-message-mib")
        return TimeoutError(f"no reply to {mtype!r} from the hydrolink server at {self.address} "
                            f"within {limit:g} s (is it running and reachable?{hint})")

    def _check_link(self, mtype: str) -> None:
        """While a reply is pending: ConnectionError when the server refuses reconnects for
        ``lost_after`` s (it stopped) or the link stays down for ``link_timeout`` s; a link that
        came back gets an idempotent request (step, ping: SPEC §5.3 answers a repeated step from
        its cache) sent again, as the reply may have been lost with the old connection. A link
        that never came up (nothing listening, a refused CURVE handshake) is left to the timeout
        and its hints."""
        w = self._watch
        w.update()
        if w.reconnects > self._reconnects_seen:
            self._reconnects_seen = w.reconnects
            if self._in_flight is not None and self._in_flight[0] in ("step", "ping"):
                try:
                    self._sock.send(self._in_flight[1], zmq.NOBLOCK)
                except zmq.Again:   # the link went down again: tried once more at the next check
                    self._reconnects_seen -= 1
        if w.lost_since is None or not w.ever_connected:
            return
        down = time.monotonic() - w.lost_since
        if w.refused >= 2 and down >= self.lost_after:
            raise ConnectionError(f"the hydrolink server at {self.address} went away while this client waited for "
                                  f"the reply to {mtype!r}: the connection closed and its host refuses to reconnect "
                                  f"({down:.1f} s): the server stopped")
        if down >= self.link_timeout:
            raise ConnectionError(f"lost the connection to the hydrolink server at {self.address} while waiting for "
                                  f"the reply to {mtype!r}: no link for {down:.1f} s (link_timeout "
                                  f"{self.link_timeout:g} s): the network is down or the server's host stopped")

    def request(self, mtype: str, timeout: float | None = None, **fields: Any) -> dict:
        """Send one request, wait for its reply (matched by ``parent``); RemoteError on ``error``."""
        return self._request(mtype, timeout, fields, False)

    def _request(self, mtype: str, timeout: float | None, fields: dict, as_map: bool) -> dict:
        """:meth:`request`; ``as_map``: hand an in-process server the map (no msgpack)."""
        if self._sock is None and self._local is None:
            raise ConnectionError(f"connection to {self.address} is closed")
        msg_id = next(self._ids)
        msg = codec.message(mtype, msg_id, self.session, **fields)
        if as_map:
            return self._checked(self._local.respond_map(msg, self.timeout if timeout is None else timeout), msg_id)
        frame = codec.pack(msg, self.key)
        self._in_flight = (mtype, frame)
        limit = self.timeout if timeout is None else timeout
        if self._direct is not None:
            reply = self._request_direct(frame, msg_id, mtype, limit)
            if reply is not None:
                return self._checked(reply, msg_id)
        deadline = time.monotonic() + limit
        self._send(frame, deadline, mtype, limit)
        while True:
            frame = self._recv(deadline, mtype, limit)
            try:
                reply = codec.unpack(frame, self.key)
            except ProtocolError as exc:
                raise ConnectionError(f"unreadable reply from {self.address}: {exc}") from None
            if reply.get("parent") == msg_id or codec.unread_error(reply):
                return self._checked(reply, msg_id)

    def _request_direct(self, frame: bytes, msg_id: str, mtype: str, limit: float) -> dict | None:
        """The reply to ``frame`` over the direct channel; None when the channel failed (it is
        closed then, and the caller sends the request over ZeroMQ); TimeoutError as over ZeroMQ."""
        try:
            return self._direct.request(frame, msg_id, limit, self.key)
        except ProtocolError as exc:
            raise ConnectionError(f"unreadable reply from {self.address}: {exc}") from None
        except OSError as exc:   # closed by the server (its budget, a restart) or broken: ZeroMQ from now on
            if isinstance(exc, TimeoutError) and exc.errno is None:   # no reply within ``limit`` (not the
                raise self._no_reply(mtype, limit) from None          # kernel's ETIMEDOUT: a link lost)
            log.warning("direct channel to %s lost (%s): continuing over ZeroMQ", self.address, exc)
            self._direct.close()
            self._direct = None
            return None

    def _go_direct(self, offer: Any) -> None:
        """Open the direct channel a welcome offers (``welcome.direct``, SPEC §5.7.5); without one,
        or when it cannot be opened within direct_channel.CONNECT_S, the requests stay on ZeroMQ."""
        if not self.direct or self._sock is None or not isinstance(offer, dict) \
                or not isinstance(offer.get("ticket"), str):
            return
        try:
            self._direct = DirectChannel.open(self.address, offer, self.link_timeout)
        except (OSError, ValueError) as exc:
            log.info("direct channel to %s not opened (%s): requests stay on ZeroMQ", self.address, exc)

    def _checked(self, reply: dict, msg_id: str) -> dict:
        """The reply to ``msg_id``; RemoteError on ``error`` (also on an error to a request the
        server could not read: a message over its limit, SPEC §1, whose ``parent`` is nil)."""
        if reply.get("parent") != msg_id and not codec.unread_error(reply):
            raise ConnectionError(f"the in-process server answered {reply.get('parent')!r}, not {msg_id!r}")
        if reply.get("type") == "error":
            raise RemoteError(reply.get("code", 99), reply.get("name", "internal"), reply.get("field"),
                              reply.get("message", ""), self.address,
                              {k: v for k, v in reply.items() if k not in ENVELOPE_AND_ERROR})
        return reply

    def hello(self, scene_text: str, hdbs: dict[str, xr.Dataset | HDBFiles], role: str = "multibody",
              client: dict | None = None, wave_elevation: tuple | None = None,
              meshes: dict[str, tuple[np.ndarray, np.ndarray]] | None = None,
              realtime: float | None = None, control_token: str | None = None,
              spectra: dict[str, tuple] | None = None, gauges: dict[str, tuple] | None = None,
              modal_structure: dict[str, ExternalMatrices] | None = None) -> Setup:
        """Open a session and return its :class:`Setup`; the session id, the server's name/version,
        the protocol version and the session timeout stay on the connection (``session``,
        ``server_info``, ``protocol``, ``session_timeout``). ``wave_elevation``: the (time, eta)
        series of a scene with ``[waves] type = "elevation"`` (clients/run.py load_wave_elevation);
        ``meshes``: the closed hulls (vertices, faces) of its nonlinear bodies by name
        (clients/run.py load_scene_hulls); ``realtime``: ask the server to pace the session, each
        ``forces`` reply held until its wall-clock time at that factor (SPEC §5.1); ``control_token``:
        the secret the scene's controllers must show to join (SPEC §5.7.2; None: the server draws one),
        kept as :attr:`control_token` from the welcome; ``spectra``: the tables of the scene's
        spectrum files by key (clients/scene_inputs.py load_spectrum_files); ``gauges``: the (time, eta)
        records of a ``type = "gauges"`` sea by key (load_gauge_files); ``modal_structure``: each
        body's block of its modes' structure file by key (load_modal_structures).

        An HDB given as :class:`HDBFiles` goes by its files' SHA-256 (SPEC §5.8): the contents the
        server lacks (error 13) are uploaded, once each, and the ``hello`` is sent again;
        ``uploads`` then lists what was sent."""
        from importlib import metadata
        try:
            version = metadata.version("hydrolink")
        except metadata.PackageNotFoundError:  # pragma: no cover
            version = "unknown"
        extra = {} if wave_elevation is None else {"wave_elevation": {
            "time": np.ascontiguousarray(wave_elevation[0], np.float64),
            "eta": np.ascontiguousarray(wave_elevation[1], np.float64)}}
        if spectra:   # the scene's spectrum files' tables (SPEC §5.1 hello.spectra)
            extra["spectra"] = {key: {"omega": np.asarray(w, np.float64), "density": np.asarray(d, np.float64),
                                      "theta": None if th is None else np.asarray(th, np.float64)}
                                for key, (w, th, d) in spectra.items()}
        if gauges:    # the gauges' records (SPEC §5.1 hello.gauges)
            extra["gauges"] = {key: {"time": np.ascontiguousarray(t, np.float64), "eta": np.ascontiguousarray(e, np.float64)}
                               for key, (t, e) in gauges.items()}
        if modal_structure:   # the modes' structure files' body blocks (SPEC §5.1 hello.modal_structure)
            extra["modal_structure"] = {key: {"modes": list(b.modes), **{k: np.ascontiguousarray(getattr(b, k), np.float64)
                                                                          for k in MATRICES}}
                                        for key, b in modal_structure.items()}
        if meshes:
            extra["meshes"] = {name: {"vertices": np.ascontiguousarray(v, np.float64),
                                      "faces": np.ascontiguousarray(f, np.int64)} for name, (v, f) in meshes.items()}
        if realtime is not None:
            extra["realtime"] = float(realtime)
        if control_token is not None:
            extra["control_token"] = control_token
        wire = {k: (ds.entry() if isinstance(ds, HDBFiles) else to_wire(ds)) for k, ds in hdbs.items()}
        client = client or {"name": self.client_name, "version": version}
        self.uploads = []
        try:
            reply = self.request("hello", role=role, scene=scene_text, hdbs=wire, client=client, **extra)
        except RemoteError as exc:
            if exc.code != codec.Code.MISSING_CONTENT:
                raise
            contents = {d: data for ds in hdbs.values() if isinstance(ds, HDBFiles)
                        for d, data in ds.contents().items()}
            for digest in exc.extra.get("missing") or ():
                if digest not in contents:
                    raise ConnectionError(f"the server at {self.address} asked for content {digest!r}, "
                                          "which this hello did not name") from None
                self.request("upload", sha256=digest, data=contents[digest])
                self.uploads.append(digest)
            reply = self.request("hello", role=role, scene=scene_text, hdbs=wire, client=client, **extra)
        self.session = reply["session"]
        self.control_token: str | None = reply.get("control_token")
        self.server_info, self.protocol = reply.get("server"), reply.get("protocol")
        self.session_timeout = reply.get("session_timeout")
        self._go_direct(reply.get("direct"))
        try:
            self.setup = Setup.from_wire(reply.get("setup"))
        except ProtocolError as exc:
            raise ConnectionError(f"the server at {self.address} sent an unusable setup: "
                                  f"[{exc.field}] {exc.message}") from None
        return self.setup

    def step(self, seq: int, time: float, position: np.ndarray, velocity: np.ndarray,
             iteration: int = 0, *, measurements: dict | None = None, timeout: float | None = None,
             modal: tuple[np.ndarray, np.ndarray] | None = None) -> dict:
        """The ``forces`` reply for the state at step ``seq``: excitation/radiation/hydrostatic (N, 6)
        arrays (read-only) and the optional forces of the scene's terms (protocol/reply.py), wave_elevation, seq, iteration, time, compute_us (and the envelope); with controllers (SPEC §5.7) the
        ``measurements`` of step seq - 1 go along and the reply's ``control`` decisions come back;
        ``modal``: the generalized modes' (position, velocity) (M,), whose forces come back as
        ``modal_excitation``/``modal_radiation``/``modal_hydrostatic``."""
        position = np.ascontiguousarray(position, dtype=np.float64)
        fields = {"seq": int(seq), "time": float(time), "iteration": int(iteration), "position": position,
                  "velocity": np.ascontiguousarray(velocity, dtype=np.float64)}
        if measurements is not None:
            fields["measurements"] = measurements
        if modal is not None:   # generalized modes: (M,) coordinates and rates (SPEC §5.2, revision 1.15)
            fields["modal_position"] = np.ascontiguousarray(modal[0], dtype=np.float64)
            fields["modal_velocity"] = np.ascontiguousarray(modal[1], dtype=np.float64)
        # the map path only for what this method and the adapters' measurements hold (ints, floats,
        # float64 arrays: a server checks a map's arrays as a frame's)
        as_map = self._maps
        if as_map and self._steps:   # an in-process server's step path (ForceServer.step_map)
            msg_id = next(self._ids)
            return self._checked(self._local.step_map(self.session, msg_id, fields, self.timeout if timeout is None
                                                      else timeout), msg_id)
        reply = self._request("step", timeout, fields, as_map)
        if not as_map:   # a frame's arrays checked (N, 6) like the state sent; a map's are the server's own
            read_forces(reply, position.shape)   # (the caller checks the values)
        return reply

    def local_step(self) -> LocalStep | None:
        """The in-process server's step path for this session (server/service/local_step.py), for
        a loop that steps it many times: None unless the server is this process's own, without a
        socket and without a signing key, and the session steps there unpaced (then :meth:`step`)."""
        if not self._steps or self.session is None:
            return None
        return self._local.local_step(self.session)

    def controlled_step(self) -> ControlledStep | None:
        """The polled in-process server's step path for this session with controllers
        (server/service/controlled_step.py): None unless the server is this process's own polled
        one, without a signing key, and the session steps there unpaced (then :meth:`step`)."""
        if not self._maps or self.session is None or not hasattr(self._local, "controlled_step"):
            return None
        return self._local.controlled_step(self.session)

    def save(self) -> int:
        """Keep the session's state at this point (SPEC §5.9); the id to :meth:`restore` it."""
        return self.request("save")["state"]

    def restore(self, state: int) -> int:
        """Roll the session back to a saved state; the last step seq it holds (-1: none)."""
        return self.request("restore", state=int(state))["seq"]

    def release(self, state: int) -> None:
        """Forget a saved state."""
        self.request("release", state=int(state))

    def ping(self) -> dict:
        """Heartbeat: refreshes the session's idle timer."""
        return self.request("ping")

    def bye(self) -> dict:
        """Close the session; returns ``goodbye`` (steps, compute_s; realtime for a paced session)."""
        reply = self.request("bye")
        self.session = None
        return {k: reply[k] for k in ("steps", "compute_s", "realtime") if k in reply}

    # ------------------------------------------------------------ lifecycle

    def close(self) -> None:
        """Close the socket (linger 0); does not send ``bye``."""
        self._local = None
        if self._direct is not None:
            self._direct.close()
            self._direct = None
        if self._sock is not None:
            self._watch.close()
            self._sock.close(0)
            self._sock = None
            if self._own_context:
                self._ctx.term()

    def __enter__(self) -> "ServerConnection":
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.session is not None and (self._sock is not None or self._local is not None):
            try:
                self.request("bye", timeout=min(self.timeout, 2.0))
            except (TimeoutError, RemoteError, ConnectionError):
                pass
            self.session = None
        self.close()
