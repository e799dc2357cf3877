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
ProtocolError, the session unchanged. A run whose model steps as its compiled kernel takes that
kernel itself between :meth:`ControlledStep.relayed` and :meth:`ControlledStep.decided` (the
same order; no forces in the reply: the caller's kernel computed them).
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
    valid until the session's ``bye``. Where the model's step is its compiled linear core
    (:meth:`LocalStep.compiled`), a caller may take each new step as :meth:`relayed`, the
    kernel, then :meth:`decided`: :meth:`__call__`'s order, the model's step in the caller's
    compiled code (clients/exudyn/compiled_exchange.py)."""

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
        s, hub = self._session, self._hub
        self._server.serve_ready()
        new = seq == s.last_seq + 1
        meas = hub.own_measurements(seq, measurements) if new and iteration == 0 and hub.measured_at(seq) else None
        self._check(seq)
        if meas is not None:   # relayed before the model steps (as ForceServer._step)
            hub.relay_with(meas, s.previews)
        fields = s.advance(seq, iteration, self.position, self.velocity, self._modal,
                           hub.hydro_command(seq) if new else None)
        return self._decided(seq, iteration, new, fields, timeout)

    def relayed(self, seq: int, measurements: dict | None) -> None:
        """Before the compiled kernel takes the new step ``seq`` (its state already checked against
        the wire's bounds by the caller): what :meth:`__call__` does before the model's step — the
        server's ready messages served, the session touched, the ``measurements`` checked and
        relayed when seq − 1 is a control step. ProtocolError as :meth:`__call__`'s."""
        s, hub = self._session, self._hub
        self._server.serve_ready()
        s.touch()
        if hub.measured_at(seq):
            hub.relay_with(hub.own_measurements(seq, measurements), s.previews)

    def decided(self, seq: int, seconds: float, timeout: float = 30.0) -> dict:
        """The new step ``seq`` was taken by the compiled kernel in ``seconds``: the session told
        (:meth:`LocalStep.advanced`), then what :meth:`__call__` does after the model's step — the
        decisions due, the wait for the commands. The reply's fields that are not the forces
        (``control``, ``compute_us``: the kernel's time); TimeoutError as :meth:`__call__`'s."""
        self.advanced(seq, seconds)
        return self._decided(seq, 0, True, {"compute_us": seconds * 1e6}, timeout)

    def _decided(self, seq: int, iteration: int, new: bool, fields: dict, timeout: float) -> dict:
        """The decisions due at ``seq`` into ``fields``, at once or after the server's loop turned
        until the commands are in or their deadline passed."""
        server = self._server
        fields = self._hub.after_step(seq, iteration, new, None, fields, server.local_route, next(self._ids))
        if fields is not None:
            return fields
        reply = server.await_local(timeout)
        if reply["type"] == "error":   # (what a step message's deferred reply could be: never sent today)
            raise ProtocolError(reply["code"], reply.get("field"), reply["message"])
        return reply
