"""An embedded run's exchange in two compiled calls (issue 36).

``hydrolink run`` with its in-process server (no socket, no controller, not paced), the
``mass-matrix`` scheme, one client step per exchange, every scene body wet and a model whose step
is its compiled linear core alone (server/service/local_step.py ``LocalStep.compiled``): then an
exchange of :class:`~hydrolink.clients.lockstep.coupling_schemes.Predictor` is, per step,

1. one compiled call (clients/exudyn/exchange_kernel.py ``predict``): the wet DOFs' predicted state
   from the state read at the end of the last step, the wire's bounds, the server's linear step
   and the load at the hydro object's coordinates, into arrays made once;
2. one write of that load into Exudyn (``SetObjectParameter``) and its ``SolveSteps``;
3. one read of Exudyn's state (its three ODE2 getters), and one compiled call (``settle``) that
   keeps it for the next step, fills the results row and bounds the state for the divergence watch;
4. the mechanism's outputs: where they are linear PTOs only (up to seven), each connector's
   displacement and velocity (two ``GetObjectOutput``) and one compiled call (``linear_ptos``)
   into the row's slots (``ResultWriter.slots``); otherwise (joints, moorings, other PTOs) as the
   reference path stages them; and the row's commit.

The session's sequencing state and counters follow each step (``LocalStep.advanced``). Results
are the reference path's bit for bit (tests/test_compiled_exchange.py runs both). Anything off the
ordinary — a state out of the wire's bounds, non-finite forces, a state past the divergence bound
— goes to the reference path's code for that step, which raises its error (or, where a bound is
met only by round-off, goes on).
"""

from __future__ import annotations

import time as _time
from typing import Any, Callable

import exudyn as exu
import numpy as np

from hydrolink.clients.lockstep.coupling_schemes import Predictor
from hydrolink.clients.lockstep.driver import ForceLink, Lockstep, Sample
from hydrolink.server.service.local_step import CompiledStep

__all__ = ["CompiledExchange"]

#: the linear PTOs' results variables (clients/exudyn/client.py ``ExudynMultibody.outputs``), in linear_ptos' order
PTO_VARIABLES = ("pto_force", "pto_velocity", "pto_power", "total_pto_power")
_DISPLACEMENT, _VELOCITY = exu.OutputVariableType.Displacement, exu.OutputVariableType.Velocity


def _kernel():
    """clients/exudyn/exchange_kernel.py, imported (numba with it) on first use."""
    from hydrolink.clients.exudyn import exchange_kernel
    return exchange_kernel


class CompiledExchange:
    """``Predictor(feedback=False)``'s exchange for an embedded run (module docstring); made by
    :meth:`ExudynMultibody.compiled_exchange <hydrolink.clients.exudyn.client.ExudynMultibody.compiled_exchange>`,
    which checks the run qualifies. It takes the scheme's place in :func:`lockstep.run
    <hydrolink.clients.lockstep.driver.run>`; the :class:`Sample` an exchange returns holds views of
    arrays the next exchange overwrites."""

    feedback = False

    def __init__(self, model: Any, link: ForceLink, step: CompiledStep, *, wet_take: np.ndarray,
                 body_take: np.ndarray, state: Callable[[], np.ndarray], outputs: Callable[[], dict] | None,
                 refresh: Callable[[], None], n_exchanges: int,
                 linear_ptos: tuple[list[int], np.ndarray] | None = None):
        """``outputs``: the mechanism's outputs by results variable (None: none); ``linear_ptos``
        (``PTOSet.linear_table``) in its place where they are linear PTOs only."""
        k = _kernel()
        n = model.wet_index.size
        self._model, self._link, self._local = model, link, link.local
        self._outputs, self._refresh, self._last = outputs, refresh, n_exchanges - 1
        self._dt = step.dt
        self._state = state                        # the client's (3, n) q, v, a (its own copy, kept current)
        self._st = np.zeros(state().shape)
        self._status = np.zeros(1, np.int64)
        out = np.zeros((3, n))                     # excitation, radiation, hydrostatic (inactive DOFs: zero)
        self._load = np.zeros(n)
        force_index = np.arange(n) if model.force_index is None else np.asarray(model.force_index, np.int64)
        self._force = np.zeros(force_index.size)   # the hydro object's coordinates' load
        self._g = k.exchange_state(
            step.kernel, self._st, np.asarray(wet_take, np.int64), model.equilibrium.reshape(-1).copy(),
            np.zeros(n), np.zeros(n), out, self._load, np.zeros(np.count_nonzero(model.active)), force_index,
            self._force, np.asarray(body_take, np.int64), model.body_reference.reshape(-1).copy(),
            np.ascontiguousarray(model.stiffness, float), np.zeros(n), float(model.dt), np.array(step.bounds, float),
            self._status)
        self._predict, self._settle, self._linear_ptos = k.predict, k.settle, k.linear_ptos
        self._pto_objects, self._pto_table = linear_ptos if linear_ptos is not None else ([], None)
        self._dw = np.zeros((len(self._pto_objects), 2, 3))   # each PTO's displacement and velocity
        self._out = out
        self._primed = False

    def exchange(self, loop: Lockstep, e: int, s_prev: Sample) -> Sample:
        """Exchange ``e`` (time e H → (e + 1) H) as ``Predictor(feedback=False).exchange`` takes it."""
        if not self._primed:      # the client's state (after mb.begin, or a step the reference path took)
            np.copyto(self._st, self._state())
            self._primed = True
        seq = e + 1
        link, model = self._link, self._model
        t0 = _time.perf_counter()
        eta = self._predict(self._g, seq * self._dt)
        took = _time.perf_counter() - t0
        status = self._status[0]
        if status == 1:           # out of the wire's bounds: no step taken; the reference path raises
            self._refresh()
            self._primed = False
            return Predictor().exchange(loop, e, s_prev)
        link.seconds += took
        self._local.advanced(seq, took)
        if status:
            raise link.non_finite(seq)
        model.mbs.SetObjectParameter(model.hydro_object, "forceVector", self._force)
        h = model.dt
        t_e = e * h
        t1 = t_e + h
        model.advance(t_e, t1)
        loop.step += 1
        sd = model.mbs.systemData
        writer = loop.writer
        row = writer.row()
        ss = self._settle(self._g, sd.GetODE2Coordinates(), sd.GetODE2Coordinates_t(), sd.GetODE2Coordinates_tt(),
                          row)
        limit = loop.watch.limit
        if not ss < limit * limit or e == self._last:   # the watch's own check (raises) / the client's state, synced
            self._refresh()
            loop.watch.check(loop.mb, loop.step, t1, writer.rows, loop.mb.label)
        if self._pto_table is not None:
            get, dw = model.mbs.GetObjectOutput, self._dw
            for r, obj in enumerate(self._pto_objects):
                dw[r, 0] = get(obj, _DISPLACEMENT)
                dw[r, 1] = get(obj, _VELOCITY)
            self._linear_ptos(self._pto_table, dw, *writer.slots(PTO_VARIABLES))
        elif self._outputs is not None:
            out = self._outputs()
            if out:
                writer.stage_extra(out)
        writer.commit(t1, eta)
        if loop.bar is not None:
            loop.bar.update(1)
        o = self._out
        return Sample(o[0], o[1], o[2], eta, self._load)
