"""Client side of the wire protocol (SPEC.md): one DEALER socket, one request in flight.

Used by the Exudyn client, the FMU master and controllers::

    with ServerConnection("tcp://127.0.0.1:5555") as conn:
        setup = conn.hello(scene_text, {"sphere.h5": ds})
        f = conn.step(0, 0.0, position, velocity)
        conn.bye()
"""

from __future__ import annotations

import time
from typing import Any

import numpy as np
import xarray as xr
import zmq

from hydrolink.protocol import codec
from hydrolink.protocol.codec import ProtocolError
from hydrolink.server.hdb.schema import to_wire

FORCE_FIELDS = ("excitation", "radiation", "hydrostatic")


class RemoteError(RuntimeError):
    """The server answered with an ``error`` (SPEC §5.6)."""

    def __init__(self, code: int, name: str, field: str | None, message: str, address: str = ""):
        self.code, self.name, self.field, self.message = code, name, field, message
        where = f" [{field}]" if field else ""
        at = f" from {address}" if address else ""
        super().__init__(f"server error {code} {name}{where}{at}: {message}")


class ServerConnection:
    """A connection to a hydrolink server; every receive times out after ``timeout`` seconds."""

    def __init__(self, address: str, *, timeout: float = 30.0, context: zmq.Context | None = None,
                 key: bytes | None = None, client_name: str = "hydrolink-python"):
        self.address = address
        self.timeout = float(timeout)
        self.key = key
        self.client_name = client_name
        self.session: str | None = None
        self.setup: dict | None = None
        self._own_context = context is None
        self._ctx = context or zmq.Context()
        self._sock = self._ctx.socket(zmq.DEALER)
        self._sock.setsockopt(zmq.LINGER, 0)
        self._sock.connect(address)
        self._ids = codec.id_source("c")
        self._poller = zmq.Poller()
        self._poller.register(self._sock, zmq.POLLIN)

    # ------------------------------------------------------------ requests

    def request(self, mtype: str, timeout: float | None = None, **fields: Any) -> dict:
        """Send one request, wait for its reply (matched by ``parent``); RemoteError on ``error``."""
        if self._sock is None:
            raise ConnectionError(f"connection to {self.address} is closed")
        msg_id = next(self._ids)
        self._sock.send(codec.pack(codec.message(mtype, msg_id, self.session, **fields), self.key))
        limit = self.timeout if timeout is None else timeout
        deadline = time.monotonic() + limit
        while True:
            left = deadline - time.monotonic()
            if left <= 0 or not self._poller.poll(left * 1000):
                raise TimeoutError(f"no reply to {mtype!r} from the hydrolink server at {self.address} "
                                   f"within {limit:g} s (is it running and reachable?)")
            frame = self._sock.recv()
            try:
                reply = codec.unpack(frame, self.key)
            except ProtocolError as exc:
                raise ConnectionError(f"unreadable reply from {self.address}: {exc}") from None
            if reply.get("parent") != msg_id:
                continue  # a late reply to an earlier, timed-out request
            if reply.get("type") == "error":
                raise RemoteError(reply.get("code", 99), reply.get("name", "internal"), reply.get("field"),
                                  reply.get("message", ""), self.address)
            return reply

    def hello(self, scene_text: str, hdbs: dict[str, xr.Dataset], role: str = "multibody",
              client: dict | None = None) -> dict:
        """Open a session: returns the model's setup (arrays as numpy) plus ``session``, ``server``,
        ``protocol`` and ``session_timeout``."""
        from importlib import metadata
        try:
            version = metadata.version("hydrolink")
        except metadata.PackageNotFoundError:  # pragma: no cover
            version = "unknown"
        reply = self.request("hello", role=role, scene=scene_text,
                             hdbs={k: to_wire(ds) for k, ds in hdbs.items()},
                             client=client or {"name": self.client_name, "version": version})
        self.session = reply["session"]
        self.setup = codec.decode_tree(reply.get("setup", {}))
        return {**self.setup, "session": self.session, "server": reply.get("server"),
                "protocol": reply.get("protocol"), "session_timeout": reply.get("session_timeout")}

    def step(self, seq: int, time: float, position: np.ndarray, velocity: np.ndarray,
             iteration: int = 0) -> dict:
        """Forces for the state at step ``seq``: excitation/radiation/hydrostatic (N, 6) arrays,
        wave_elevation, seq, iteration, time, compute_us."""
        reply = self.request("step", seq=int(seq), time=float(time), iteration=int(iteration),
                             position=np.ascontiguousarray(position, dtype=np.float64),
                             velocity=np.ascontiguousarray(velocity, dtype=np.float64))
        out = {k: reply[k] for k in ("seq", "iteration", "time", "compute_us") if k in reply}
        for k in FORCE_FIELDS:
            out[k] = codec.decode_array(reply[k], k)
        eta = reply.get("wave_elevation")
        out["wave_elevation"] = codec.decode_array(eta, "wave_elevation") if isinstance(eta, dict) else eta
        return out

    def ping(self) -> dict:
        """Heartbeat: refreshes the session's idle timer."""
        return self.request("ping")

    def bye(self) -> dict:
        """Close the session; returns ``goodbye`` (steps, compute_s)."""
        reply = self.request("bye")
        self.session = None
        return {k: reply[k] for k in ("steps", "compute_s") if k in reply}

    # ------------------------------------------------------------ lifecycle

    def close(self) -> None:
        """Close the socket (linger 0); does not send ``bye``."""
        if self._sock is not None:
            self._sock.close(0)
            self._sock = None
            if self._own_context:
                self._ctx.term()

    def __enter__(self) -> "ServerConnection":
        return self

    def __exit__(self, *exc: Any) -> None:
        if self.session is not None and self._sock is not None:
            try:
                self.request("bye", timeout=min(self.timeout, 2.0))
            except (TimeoutError, RemoteError, ConnectionError):
                pass
            self.session = None
        self.close()
