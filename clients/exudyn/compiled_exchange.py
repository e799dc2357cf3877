"""A run's exchange in two compiled calls, inside Exudyn's own step loop (issue 36).

``hydrolink run`` with its in-process server (embedded, or polled with controllers), the
``mass-matrix`` scheme, one client step per exchange, a wet body (dry ones beside it: their rows'
forces zero, as the reference path writes them) and a model whose step
is its compiled linear core alone (server/service/local_step.py ``LocalStep.compiled``): then an
exchange of :class:`~hydrolink.clients.lockstep.coupling_schemes.Predictor` is, per step,

1. one compiled call (clients/exudyn/kernels/exchange.py ``predict``): the wet DOFs' predicted state
   from the state read at the end of the last step, the wire's bounds, the server's linear step
   and the load at the hydro object's coordinates, into arrays made once;
2. one write of that load into Exudyn (``SetObjectParameter``) and its step;
3. one compiled call (``settle``) that reads Exudyn's state through views of its own current-state
   vectors (``copy=False``: no getter a step), keeps it for the next step, fills the results row
   and bounds the state for the divergence watch;
4. the mechanism's outputs: the linear PTOs' (up to seven), each connector's displacement and
   velocity (two ``GetObjectOutput``) and one compiled call (``linear_ptos``) into the row's
   slots (``ResultWriter.slots``); the joints' (no point-mass joint), their four outputs each and
   one compiled call (``JointOutputs.compiled``) into the row's slots — either or both, where
   they are all the mechanism's outputs; otherwise (moorings, other PTOs) as the reference path
   stages them; and the row's commit.

A run takes every exchange inside one Exudyn ``SolveSteps`` (:meth:`CompiledExchange.run_exchanges`:
a PreStep user function does 4 of the last step, a paced run's record of it and release of the
next, and 1-2 of the next), not a ``SolveSteps`` call a step. The compiled calls are made through
their entry points (numba's dispatch, which types each argument every call, skipped).

With controllers (the polled server's ``ControlledStep``, server/service/controlled_step.py) step
1 is split in ``ControlledStep``'s order: the prediction and the bounds (``prepare``), the
measurements of the last step relayed (the linear PTOs' extension, velocity and force as
``linear_ptos`` left them, every body's q and v from the kept state), the server's step and the
load (``forces``), then the decisions and the wait for the commands, applied to the PTOs by
``PTOControl.apply`` (clients/exudyn/pto_control.py) as the reference path applies them; the
control's results variables are staged with the row. Runs with controllers qualify where the
PTOs are linear ones only, without moorings (joints beside them: WaveStar's arm and float).

The session's sequencing state and counters follow each step (``LocalStep.advanced``). Results
are the reference path's bit for bit (tests/test_compiled_exchange.py runs both). Anything off the
ordinary — a state out of the wire's bounds, non-finite forces, a state past the divergence bound
— goes to the reference path's code for that step, which raises its error (or, where a bound is
met only by round-off, goes on).
"""

from __future__ import annotations

import math
import time as _time
from typing import Any, Callable

import exudyn as exu
import numpy as np

from hydrolink.clients.exudyn.pto_control import PTOControl
from hydrolink.clients.lockstep.coupling_schemes import Predictor
from hydrolink.clients.lockstep.driver import ForceLink, Lockstep, PacedSteps, RunInterrupted, Sample
from hydrolink.server.service.local_step import CompiledStep

__all__ = ["CompiledExchange"]

#: the linear PTOs' results variables (clients/exudyn/client.py ``ExudynMultibody.outputs``), in linear_ptos' order
PTO_VARIABLES = ("pto_force", "pto_velocity", "pto_power", "total_pto_power")
#: the joints' results variables, in ``JointOutputs.compiled``'s order (clients/exudyn/mechanism.py)
JOINT_VARIABLES = ("joint_force", "joint_violation", "joint_rotation_violation")
_DISPLACEMENT, _VELOCITY = exu.OutputVariableType.Displacement, exu.OutputVariableType.Velocity


def _kernel():
    """clients/exudyn/kernels/exchange.py, imported (numba with it) on first use."""
    from hydrolink.clients.exudyn.kernels import exchange
    return exchange


class _HandOff(Exception):
    """Raised in the PreStep to end Exudyn's step loop before a step the reference path takes."""


class CompiledExchange:
    """``Predictor(feedback=False)``'s exchange for a run on its own in-process server (module docstring); made by
    :meth:`ExudynMultibody.compiled_exchange <hydrolink.clients.exudyn.client.ExudynMultibody.compiled_exchange>`,
    which checks the run qualifies. It takes the scheme's place in :func:`lockstep.run
    <hydrolink.clients.lockstep.driver.run>`, which calls :meth:`run_exchanges` (every exchange
    inside one ``SolveSteps``: a :class:`~hydrolink.clients.lockstep.driver.LoopsItself`)."""

    feedback = False

    def __init__(self, model: Any, link: ForceLink, step: CompiledStep, *, wet_take: np.ndarray,
                 body_take: np.ndarray, state: Callable[[], np.ndarray], outputs: Callable[[], dict] | None,
                 refresh: Callable[[], None], n_exchanges: int,
                 linear_ptos: tuple[list[int], np.ndarray] | None = None, control: PTOControl | None = None,
                 joints: Callable[[tuple[np.ndarray, ...]], None] | None = None, wet_flat: np.ndarray | None = None):
        """``outputs``: the mechanism's outputs by results variable, where the compiled calls do not
        make them (None: none, or all by the compiled calls); ``linear_ptos`` (``PTOSet.linear_table``,
        filling the row's PTO_VARIABLES slots) and ``joints`` (filling its JOINT_VARIABLES slots:
        ``JointOutputs.compiled``), each alone or both, where they are the whole mechanism's outputs.
        ``control``: the run's controllers (clients/exudyn/pto_control.py; ``link.local`` is then the
        polled server's ``ControlledStep`` and ``linear_ptos`` given): each step relays the
        measurements from the kernels' arrays, takes the decisions and applies them (:meth:`_controlled`).
        ``wet_flat``: the wet DOFs' positions in the rows' (B, 6) (where the server's linear viscous
        damping is compiled, ``step.damping``: its force staged as the reply's ``viscous`` is)."""
        n = model.wet_index.size
        self._model, self._link, self._local = model, link, link.local
        self._outputs, self._refresh, self._last = outputs, refresh, n_exchanges - 1
        self._joints = joints
        self._dt = step.dt
        self._state = state                        # the client's (3, n) q, v, a (its own copy, kept current)
        self._st = np.zeros(state().shape)
        self._status = np.zeros(1, np.int64)
        out = np.zeros((3, n))                     # excitation, radiation, hydrostatic (inactive DOFs: zero)
        self._load = np.zeros(n)
        force_index = np.arange(n) if model.force_index is None else np.asarray(model.force_index, np.int64)
        self._force = np.zeros(force_index.size)   # the hydro object's coordinates' load
        # the server's linear viscous damping (CompiledStep.damping): its force is the reply's "viscous"
        damp, active = step.damping if step.damping is not None else (np.zeros((0, 0)), np.zeros(0, np.int64))
        visc = np.zeros(n)
        self._optional = {"viscous": visc} if step.damping is not None else {}
        self._wet_flat = wet_flat
        damping = (np.ascontiguousarray(damp, float), np.asarray(active, np.int64), np.zeros(len(active)),
                   np.zeros(len(active)), visc)
        # the ExchangeState's arrays after Exudyn's three views (made at the first exchange: the
        # views are of the state vectors the solver's initialisation leaves, _bind)
        self._arrays = (
            np.asarray(wet_take, np.int64), model.equilibrium.reshape(-1).copy(), np.zeros(n), np.zeros(n), out,
            self._load, np.zeros(np.count_nonzero(model.active)), force_index, self._force,
            np.asarray(body_take, np.int64), model.body_reference.reshape(-1).copy(), _wet_of(model),
            np.ascontiguousarray(model.stiffness, float), np.zeros(n), np.zeros(n), float(model.dt), np.array(step.bounds, float),
            self._status, *damping)
        self._kernel_state = step.kernel
        self._g = None
        self._views: tuple[np.ndarray, ...] = ()
        self._pto_objects, self._pto_table = linear_ptos if linear_ptos is not None else ([], None)
        n_pto = len(self._pto_objects)
        self._dw = np.zeros((n_pto, 2, 3))     # each PTO's displacement and velocity
        self._pto_meas = np.zeros((3, n_pto))   # each PTO's extension, velocity and force (linear_ptos)
        self._out = out
        self._primed = False
        self._control = control
        self._forces_of = self._predicted if control is None else self._controlled
        if control is not None:
            control.table = self._pto_table     # the commands' stiffness, damping and force, as linear_ptos reads them
            bodies = np.zeros((2, model.body_reference.shape[0], 6))   # every body's q and v
            # np.take's source (the kept state, flat), indices (every body's q, then v) and output
            self._take_bodies = (self._st.reshape(-1), np.asarray(body_take, np.int64), bodies.reshape(-1))
            # the measurements map (PTOControl.measurements'): views of the arrays above, its step set each time
            self._measurements = {"step": 0, "pto_displacement": self._pto_meas[0], "pto_velocity": self._pto_meas[1],
                                  "pto_force": self._pto_meas[2], "body_position": bodies[0],
                                  "body_velocity": bodies[1]}

    def _bind(self) -> None:
        """The kernel's state over views of Exudyn's current q, v, a (``copy=False``: the solver's
        own vectors, updated in place by each step, so no getter is called a step) and its three
        calls' compiled entry points (numba's dispatch, which types every argument a call, skipped)."""
        k, sd = _kernel(), self._model.mbs.systemData
        now = exu.ConfigurationType.Current
        self._views = (sd.GetODE2Coordinates(now, False), sd.GetODE2Coordinates_t(now, False),
                       sd.GetODE2Coordinates_tt(now, False))
        self._g = k.exchange_state(self._kernel_state, self._st, *self._views, *self._arrays)
        row = np.zeros((5, 2, self._model.body_reference.shape[0], 6))[:, 0]   # as ResultWriter.row's (strided)
        self._predict = _entry(k.predict, self._g, 0.0)
        self._settle = _entry(k.settle, self._g, row)
        if self._control is not None:
            self._prepare = _entry(k.prepare, self._g)
            self._forces = _entry(k.forces, self._g, 0.0)
        if self._pto_table is not None:
            force = np.zeros((1, self._pto_table.shape[0]))
            self._linear_ptos = _entry(k.linear_ptos, self._pto_table, self._dw, force, force, force, np.zeros(1),
                                       self._pto_meas)

    def prepare(self) -> None:
        """The compiled calls' entry points (compiled, or loaded from numba's cache) before the first
        exchange: set-up, not the loop's work (the driver takes the loop's priority after it)."""
        if self._g is None:
            self._bind()

    def _prime(self) -> None:
        """The kernel's copy of the client's state (after mb.begin, or a step the reference path took)."""
        if self._g is None:
            self._bind()
        np.copyto(self._st, self._state())
        if self._control is not None:   # the PTOs' measurements of the state the reference path left
            entries = np.zeros((1, len(self._model.ptos.names)))
            self._sample_ptos((entries, entries, entries, np.zeros(1)))
        self._model.load = self._load    # the load each step writes (held bodies' reactions: mechanism.py JointOutputs)
        self._primed = True

    def _views_held(self) -> bool:
        """Exudyn's current-state vectors still where the views point (they are never reallocated
        while a run steps; checked where the client's state is synced)."""
        sd, now = self._model.mbs.systemData, exu.ConfigurationType.Current
        fresh = (sd.GetODE2Coordinates(now, False), sd.GetODE2Coordinates_t(now, False),
                 sd.GetODE2Coordinates_tt(now, False))
        return all(a.__array_interface__["data"] == b.__array_interface__["data"] for a, b in zip(self._views, fresh))

    def _predicted(self, e: int) -> tuple[int, float]:
        """The forces of exchange ``e`` (predict); (its status, the elevation)."""
        seq = e + 1
        t0 = _time.perf_counter()
        eta = self._predict(self._g, seq * self._dt)
        took = _time.perf_counter() - t0
        status = self._status[0]
        if status != 1:
            self._link.seconds += took
            self._local.advanced(seq, took)
            if status:
                raise self._link.non_finite(seq)
        return status, eta

    def _controlled(self, e: int) -> tuple[int, float]:
        """The forces of exchange ``e`` in a run with controllers, in ``ControlledStep``'s order
        (server/service/controlled_step.py): the predicted state checked (prepare), the
        measurements of step e relayed when it is a control step, the model's step (forces), the
        decisions and the wait for the commands, which are then applied (``PTOControl.apply``);
        (the status, the elevation), as :meth:`_predicted`'s."""
        g, link, control = self._g, self._link, self._control
        if self._prepare(g) == 1:   # out of the wire's bounds: the reference path takes the exchange
            return 1, math.nan
        seq = e + 1
        t0 = _time.perf_counter()
        try:
            self._local.relayed(seq, self._measured(e) if control.is_sample(e) else None)
            t1 = _time.perf_counter()
            eta = self._forces(g, seq * self._dt)
            status = self._status[0]
            reply = self._local.decided(seq, _time.perf_counter() - t1, link.conn.timeout)
        except (KeyboardInterrupt, RunInterrupted):
            raise
        except Exception as exc:
            link.failed(seq, exc)
        link.answered(seq, t0, reply)
        if status:
            raise link.non_finite(seq)
        control.apply(link.decisions)
        return status, eta

    def _measured(self, k: int) -> dict:
        """The measurements of step ``k`` (``PTOControl.measurements``' map): the PTOs' from the last
        linear_ptos, every body's q and v from the state the last settle kept."""
        src, take, out = self._take_bodies
        np.take(src, take, out=out)
        meas = self._measurements
        meas["step"] = k
        return meas

    def _reference(self, loop: Lockstep, e: int, s_prev: Sample | None) -> Sample:
        """Exchange ``e`` by the reference path (its state out of the wire's bounds: it raises its error,
        or, where the bound is met only by round-off, takes the step)."""
        self._refresh()
        self._primed = False
        o = self._out
        return Predictor().exchange(loop, e, s_prev if s_prev is not None else Sample(o[0], o[1], o[2], 0.0, self._load,
                                                                                      self._optional))

    def _settled(self, loop: Lockstep, e: int, eta: float) -> None:
        """Exchange ``e``'s step done: the row (settle), the divergence watch, the mechanism's outputs,
        the commit."""
        model = self._model
        t1 = e * model.dt + model.dt
        loop.step += 1
        writer = loop.writer
        row = writer.row()
        ss = self._settle(self._g, row)
        limit = loop.watch.limit
        if not ss < limit * limit or e == self._last:   # the watch's own check (raises) / the client's state, synced
            self._refresh()
            if not self._views_held():
                raise RuntimeError("Exudyn's state vectors moved during the run (the compiled exchange reads them "
                                   "in place): the run's results cannot be vouched for")
            loop.watch.check(loop.mb, loop.step, t1, writer.rows, loop.mb.label)
        if self._outputs is not None:
            out = self._outputs()
            if out:
                writer.stage_extra(out)
        if self._pto_table is not None:
            self._sample_ptos(writer.slots(PTO_VARIABLES))
        if self._joints is not None:
            self._joints(writer.slots(JOINT_VARIABLES))
        if self._optional:   # the viscous force and power, as the reference path stages a reply's
            writer.stage_forces(self._optional, self._wet_flat, row[1])
        if self._control is not None:
            self._control.stage()
        writer.commit(t1, eta)
        if loop.bar is not None:
            loop.bar.update(1)

    def _sample_ptos(self, slots: tuple[np.ndarray, ...]) -> None:
        """The linear PTOs' outputs at Exudyn's current state into ``slots`` (the row's, PTO_VARIABLES)
        and their measurements: each connector's displacement and velocity (two ``GetObjectOutput``)
        and one compiled call (linear_ptos)."""
        get, dw = self._model.mbs.GetObjectOutput, self._dw
        for r, obj in enumerate(self._pto_objects):
            dw[r, 0] = get(obj, _DISPLACEMENT)
            dw[r, 1] = get(obj, _VELOCITY)
        self._linear_ptos(self._pto_table, dw, *slots, self._pto_meas)

    def run_exchanges(self, loop: Lockstep, n_exchanges: int, check: Callable[[], None],
                      paced: PacedSteps | None = None) -> None:
        """Every exchange of the run inside Exudyn's own step loop: one ``SolveSteps`` over
        the run, a PreStep user function taking each exchange (the last step's row, the watch, the
        outputs, the commit, a paced run's record of it, ``check`` — the driver's SIGINT latch —
        then a paced run's release of the next, and its forces) instead of a ``SolveSteps`` call
        and two solver-time writes an exchange (measured: 8.7 µs a step for a 1-DOF system that
        way, 2.1 µs in one call with an empty PreStep 2.7 µs). Exudyn steps with the fixed step
        size its solver was initialised with (``dt``) either way, so the states are the same bits.
        ``paced``: the driver's :class:`PacedSteps` (begun), whose ``release`` and ``done`` frame
        each exchange as the driver's paced loop does. An error raised in the PreStep (the
        watch's, SIGINT, the server's) ends Exudyn's loop before that step and is raised here as it
        was; an exchange whose state the compiled check refuses ends it likewise and is taken by
        the reference path, after which a new loop starts."""
        e = 0
        while e < n_exchanges:
            e = self._loop(loop, e, n_exchanges, check, paced)
            if e < n_exchanges:       # handed off (released, when paced): the reference path takes exchange e
                self._reference(loop, e, None)
                if paced is not None:
                    paced.done(e)
                check()
                e += 1

    def _loop(self, loop: Lockstep, start: int, stop: int, check: Callable[[], None], paced: PacedSteps | None) -> int:
        """Exchanges ``start`` .. ``stop`` - 1 in one ``SolveSteps``; returns ``stop``, or the exchange
        handed to the reference path."""
        if not self._primed:
            self._prime()
        model = self._model
        mbs, solver, h = model.mbs, model.solver, model.dt
        set_force, hydro, force = mbs.SetObjectParameter, model.hydro_object, self._force
        predicted, settled = self._forces_of, self._settled
        release, done = (paced.release, paced.done) if paced is not None else (None, None)
        nxt = [start, 0.0]            # the next exchange, the elevation of the last one taken
        error: list[BaseException] = []

        def pre_step(_mbs, _t) -> bool:
            e = nxt[0]
            try:
                if e > start:
                    settled(loop, e - 1, nxt[1])
                    if done is not None:
                        done(e - 1)
                    check()
                if e >= stop:
                    raise RuntimeError(f"Exudyn began a step past exchange {stop} (its loop was set to end there)")
                if release is not None:
                    release(e)
                status, nxt[1] = predicted(e)
                if status == 1:
                    raise _HandOff
                set_force(hydro, "forceVector", force)
                nxt[0] = e + 1
                return True
            except BaseException as exc:   # noqa: BLE001 - raised again after Exudyn's loop ends
                error.append(exc)
                raise

        it = solver.it
        it.startTime, it.endTime = start * h, (stop - 0.5) * h   # stop - start steps of h (it ends within 1e-10)
        mbs.SetPreStepUserFunction(pre_step)
        try:
            ok = solver.SolveSteps(mbs, model.settings)
        except Exception:
            if not error:
                raise
            ok = True
        finally:
            mbs.SetPreStepUserFunction(0)
        if error:
            if isinstance(error[0], _HandOff):
                return nxt[0]
            raise error[0]
        if not ok:
            t0 = (nxt[0] - 1) * h
            raise RuntimeError(f"Exudyn solver failed on the step {t0:g} s -> {t0 + h:g} s: "
                               f"{solver.GetErrorString()}{model.failure_hint}")
        if nxt[0] != stop:
            raise RuntimeError(f"Exudyn's loop ended after exchange {nxt[0]}, not {stop}")
        settled(loop, stop - 1, nxt[1])
        if done is not None:
            done(stop - 1)
        check()
        return stop


def _wet_of(model: Any) -> np.ndarray:
    """Each body row's wet body (its block of the wet DOFs, ``model.wet_rows``' order), -1 for a dry body."""
    wet_of = np.full(model.body_reference.shape[0], -1, np.int64)
    wet_of[np.asarray(model.wet_rows, np.int64)] = np.arange(len(model.wet_rows))
    return wet_of


def _entry(dispatcher, *args):
    """The compiled entry point of ``dispatcher`` for these arguments' types (compiled, or loaded from
    numba's cache, now): called directly, it skips the dispatcher's typing of each argument."""
    from numba import typeof
    return dispatcher.compile(tuple(typeof(a) for a in args))
