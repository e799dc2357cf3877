"""The step of a session's own in-process client, on arrays this object allocated (issue 36).

:meth:`ForceServer.local_step <hydrolink.server.service.force_server.ForceServer.local_step>` gives
one to the client of a server without a socket (``ForceServer(None)``: ``hydrolink run``'s embedded
server, where no controller can join and no step is paced). The client writes each step's absolute
position and velocity into :attr:`LocalStep.position` and :attr:`LocalStep.velocity` (a session with
generalized modes also :attr:`LocalStep.modal_position` / ``modal_velocity``) and calls it with the
step's ``seq`` and ``iteration``: the arrays' type, dtype, shape and layout are this object's own,
so what a ``step`` message needs checked every time (its envelope, the fields' presence and types,
the time against seq · dt, the arrays' decoding and shapes) is settled here once; each step checks
what changes — the state's values against the wire's bounds (SPEC §5.2) and seq against the run's
end — then takes :meth:`Session.advance <hydrolink.server.service.session.Session.advance>`: the
sequencing rules, the model's step and the reply fields of a ``step`` message, bit for bit
(tests/test_local_step.py). A value out of bounds raises the ProtocolError the message would get.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from hydrolink.protocol import codec
from hydrolink.protocol.scene_bounds import MAX_COORDINATE, MAX_SPEED
from hydrolink.server.model import HydroModel
from hydrolink.server.service.session import Session

__all__ = ["CompiledStep", "LocalStep"]


@dataclass(frozen=True)
class CompiledStep:
    """A session's step as its model's compiled kernel, for a caller's own compiled code (an
    embedded client's whole exchange in one call, clients/exudyn/compiled_exchange.py): ``kernel``
    the :class:`~hydrolink.server.fused.kernel_numba.LinearState` to pass to ``kernel_numba.step``
    at time ``seq * dt`` for the absolute position and velocity (6N,), with no excitation from
    outside (zeros) and ``replace`` False; the caller checks the state against ``bounds`` (the
    wire's position and velocity bounds, SPEC §5.2) before the call, keeps ``seq <= last_seq``,
    and reports each step taken with :meth:`LocalStep.advanced`. ``damping``: the model's linear
    viscous damping (B_lin over the active DOFs, their positions in the 6N vector: server/model.py
    ``HydroModel.linear_damping``), whose reply field ``viscous`` (-B_lin v) the caller computes; None: none."""

    kernel: Any
    dt: float
    last_seq: int
    bounds: tuple[float, float] = (MAX_COORDINATE, MAX_SPEED)
    damping: tuple[np.ndarray, np.ndarray] | None = None


class LocalStep:
    """One session's step path for its in-process client (module docstring); valid until the
    session's ``bye``."""

    def __init__(self, session: Session):
        self._session = session
        shape, m = (session.n_bodies, 6), session.model.modes.size
        self.position, self.velocity = np.zeros(shape), np.zeros(shape)
        self.modal_position, self.modal_velocity = np.zeros(m), np.zeros(m)
        self._modal = (self.modal_position, self.modal_velocity) if m else ()
        self._shape = shape

    def __call__(self, seq: int, iteration: int = 0) -> dict:
        """The ``forces`` reply fields of step ``seq`` (``iteration``; both the caller's own counters,
        >= 0) for the state in the arrays (:meth:`Session.step
        <hydrolink.server.service.session.Session.step>`'s, bit for bit); ProtocolError, the session
        unchanged, where a ``step`` message would get an error."""
        self._check(seq)
        return self._session.advance(seq, iteration, self.position, self.velocity, self._modal)

    def _check(self, seq: int) -> None:
        """What a step ``seq`` of the arrays needs checked each time: seq against the run's end, the
        state's values against the wire's bounds (the session touched first, as a message's)."""
        s = self._session
        s.touch()
        s.within_run(seq)
        modal = self._modal
        if not (codec.within(self.position, MAX_COORDINATE) and codec.within(self.velocity, MAX_SPEED)
                and (not modal or (codec.within(modal[0], MAX_COORDINATE) and codec.within(modal[1], MAX_SPEED)))):
            self._refuse()

    def compiled(self) -> CompiledStep | None:
        """The step as the model's compiled kernel (:class:`CompiledStep`) when that kernel is the
        model's whole step (server/model.py ``HydroModel.fused_only``) and the session has no
        modes; None otherwise (the caller takes :meth:`__call__`)."""
        model = self._session.model
        fused = model.fused_only() if isinstance(model, HydroModel) else None   # (not a SwitchingModel)
        if fused is None or self._modal:
            return None
        return CompiledStep(fused.kernel_state, self._session.dt, model.last_seq, damping=model.linear_damping())

    def advanced(self, seq: int, seconds: float) -> None:
        """Step ``seq`` (the next new one) was taken by :meth:`compiled`'s kernel in ``seconds``."""
        self._session.advanced(seq, seconds)

    def _refuse(self) -> None:
        """Raise the error a ``step`` message with these arrays gets (the first field out of bounds)."""
        fields = {"position": self.position, "velocity": self.velocity}
        codec.require_array(fields, "position", self._shape, bound=MAX_COORDINATE)
        codec.require_array(fields, "velocity", self._shape, bound=MAX_SPEED)
        self._session.modal_state({"modal_position": self.modal_position, "modal_velocity": self.modal_velocity})
