"""The step of a polled server's own run for a session with controllers, on arrays this object
allocated (issue 36).

``hydrolink run`` with controllers polls its own server from the run's thread (``ForceServer(bind,
polled=True)``); its controllers join over the server's socket or direct channel. Through
:meth:`ForceServer.step_map`'s fallback a step of the run went as a ``step`` map through
:meth:`ForceServer.handle`: its envelope, every field's presence and type, the time against
seq · dt and five measurement arrays were checked every step, though the run's own client made
them. :class:`ControlledStep` takes the path :class:`~hydrolink.server.service.local_step.LocalStep`
takes for an embedded run — the state in this object's own arrays, each step checking what
changes (the values against the wire's bounds, seq against the run's end, the measurements'
step, shapes and finiteness) — and then the controlled step of ``ForceServer._step`` in its order:
the measurements relayed before the model steps, the model's step, the decisions (SPEC §5.7),
the server's loop turned in this thread until the controllers' commands are in or their
deadline passes. The reply's fields are those of a ``step`` message, bit for bit
(tests/test_controlled_step.py); a value that a ``step`` message would have refused raises its
ProtocolError, the session unchanged.
"""

from __future__ import annotations

from typing import Protocol

from hydrolink.protocol import codec
from hydrolink.protocol.codec import ProtocolError
from hydrolink.server.service.controllers import ControlHub
from hydrolink.server.service.local_step import LocalStep
from hydrolink.server.service.session import Session

__all__ = ["ControlledStep", "PolledServer"]


class PolledServer(Protocol):
    """What a controlled step needs of the polled :class:`~hydrolink.server.service.force_server.ForceServer`
    it belongs to (a Protocol: this module is imported by force_server, never the other way)."""

    local_route: list

    def serve_ready(self) -> None:
        """Serve what is ready on the server's sockets and links, without waiting."""

    def await_local(self, timeout: float) -> dict:
        """Turn the server's loop until the reply to this process's own run's request is in."""


class ControlledStep(LocalStep):
    """One controlled session's step path for the polled server's own run (module docstring);
    valid until the session's ``bye``."""

    def __init__(self, server: PolledServer, session: Session, hub: ControlHub):
        super().__init__(session)
        self._server, self._hub = server, hub
        self._ids = codec.id_source("l")

    def __call__(self, seq: int, iteration: int = 0, measurements: dict | None = None,
                 timeout: float = 30.0) -> dict:
        """The ``forces`` reply of step ``seq`` (``iteration``) for the state in the arrays, with the
        ``measurements`` of step seq − 1 when it is a control step (the map
        ``ServerConnection.step`` sends): :meth:`ForceServer.respond_map`'s reply to that ``step``
        message, bit for bit. ProtocolError where that message gets an error; TimeoutError when
        the reply is not ready within ``timeout`` s."""
        server, s, hub = self._server, self._session, self._hub
        server.serve_ready()
        new = seq == s.last_seq + 1
        meas = hub.own_measurements(seq, measurements) if new and iteration == 0 and hub.measured_at(seq) else None
        self._check(seq)
        if meas is not None:   # relayed before the model steps (as ForceServer._step)
            hub.relay(meas, s.previews(hub.previews_due(meas), meas["step"]))
        fields = s.advance(seq, iteration, self.position, self.velocity, self._modal,
                           hub.hydro_command(seq) if new else None)
        msg_id = next(self._ids)
        fields = hub.after_step(seq, iteration, new, None, fields, server.local_route, msg_id)
        if fields is not None:
            return fields
        reply = server.await_local(timeout)
        if reply["type"] == "error":   # (what a step message's deferred reply could be: never sent today)
            raise ProtocolError(reply["code"], reply.get("field"), reply["message"])
        return reply

    def compiled(self) -> None:
        """No compiled kernel: a controlled step relays and waits (the caller takes :meth:`__call__`)."""
        return None
