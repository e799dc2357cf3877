"""The lockstep driver: one multibody code, the force server, one coupling scheme, one loop.

The multibody side is an adapter (:class:`Multibody`: the Exudyn model in
:mod:`hydrolink.clients.exudyn.client`, an FMU in :mod:`hydrolink.clients.fmu.master`); the force
server is a :class:`ForceLink`; the coupling scheme (scene ``[coupling] scheme``, README "Coupling
schemes", docs/stability.md) is one object from :mod:`hydrolink.clients.lockstep.coupling_schemes`. The loop
itself (:func:`run`) only sequences exchanges, writes rows, watches for divergence and turns every
failure into one error that names the step and keeps the rows written so far.

Time: exchange e runs from e·H to (e+1)·H, H = ``exchange_every`` × dt, in ``substeps`` client
steps of dt; the server's sample of exchange e is taken at the state of time e·H (SPEC §5.2).
"""

from __future__ import annotations

import gc
import math
import signal
import threading
import time as _time
from collections.abc import Callable
from dataclasses import dataclass, field, replace
from types import MappingProxyType
from typing import Any, Mapping, NamedTuple, NoReturn, Protocol, runtime_checkable

import numpy as np

from hydrolink.protocol.pacing import PARTS, Pacer, StepRecord
from hydrolink.clients.lockstep.summary import CouplingReport, RunSummary
from hydrolink.clients.lockstep.connection import RemoteError
from hydrolink.clients.lockstep.rt_priority import rt_priority as held_priority
from hydrolink.protocol.codec import ProtocolError
from hydrolink.protocol.reply import OPTIONAL_FORCES, HydroStateChange

_sum = np.add.reduce   # ndarray.sum without its Python wrapper

#: default bound on |displacement| (m, rad) and |velocity| (m/s, rad/s) before a run is called diverged
BLOW_UP_LIMIT = 1.0e4

#: explicit schemes: the added-mass instability is called after this many consecutive steps whose
#: second difference of the fed-back accelerations alternates in sign and grows by more than
#: WATCH_GROWTH, once it exceeds WATCH_FLOOR times the largest acceleration seen (clear of round-off)
WATCH_STEPS, WATCH_GROWTH, WATCH_FLOOR = 6, 1.001, 1e-6

#: recent steps whose send times ForceLink keeps (a controller decision refers back at most this far)
SENT_RING = 256


class RunInterrupted(RuntimeError):
    """A run stopped before its end; every row computed before ``step`` is in the results file."""

    def __init__(self, message: str, *, step: int, time: float, rows: int):
        super().__init__(message)
        self.step, self.time, self.rows = step, time, rows


class SimulationDiverged(RunInterrupted):
    """The state went non-finite or absurdly large, or the added-mass instability set in."""


class CouplingError(RunInterrupted):
    """The iterated coupling did not converge within ``coupling.max_iterations``."""


# ------------------------------------------------------------------------------ the server side

class Sample(NamedTuple):
    """One server reply over the wet bodies' 6N DOFs (body-major); immutable (a tuple: cheap to
    make once a step). ``load`` = excitation + radiation + the optional forces: what the client
    applies as a force (hydrostatics are in its matrix); :meth:`of` computes it. ``optional``: the
    reply's optional forces present (protocol/reply.py OPTIONAL_FORCES), in that order."""

    excitation: np.ndarray
    radiation: np.ndarray
    hydrostatic: np.ndarray
    eta: float
    load: np.ndarray
    optional: Mapping[str, np.ndarray] = MappingProxyType({})

    @classmethod
    def of(cls, excitation: np.ndarray, radiation: np.ndarray, hydrostatic: np.ndarray, eta: float,
           optional: Mapping[str, np.ndarray] = MappingProxyType({})) -> "Sample":
        """A sample; ``optional`` the optional forces by reply field (none for a linear scene)."""
        load = excitation + radiation
        for part in optional.values():   # over the 6N rigid DOFs (the first entries with modes)
            load = load + part if part.size == load.size else np.concatenate((load[:part.size] + part,
                                                                              load[part.size:]))
        return cls(excitation, radiation, hydrostatic, eta, load, optional)

    def toward(self, other: "Sample", w: float) -> "Sample":
        """self + w (other − self): linear in time between (w in [0, 1]) or past (w > 1) two samples."""
        def lerp(a, b):
            return a + w * (b - a)
        return Sample.of(lerp(self.excitation, other.excitation), lerp(self.radiation, other.radiation),
                         lerp(self.hydrostatic, other.hydrostatic), self.eta + w * (other.eta - self.eta),
                         {k: lerp(a, other.optional[k]) for k, a in self.optional.items()})


class ForceLink:
    """The force server as the loop sees it: a wet state in, a :class:`Sample` out.

    Positions go out absolute (equilibrium + displacement), rows in ``setup.bodies`` order. A server
    failure becomes one :class:`RunInterrupted` naming the step, the time and the rows kept; a
    non-finite reply a :class:`SimulationDiverged`. With no wet body nothing is asked."""

    def __init__(self, connection: Any, setup: Any, writer: Any):
        self.conn, self.writer = connection, writer
        self.n = setup.n if setup is not None else 0
        self.eq = setup.equilibrium_position.reshape(-1) if self.n else np.zeros(0)
        self.dt = setup.dt if self.n else 0.0
        self.seconds = 0.0              # wall time in round trips to the server
        self.controller_seconds = 0.0   # of which the server waited for controllers (estimated)
        self.decisions: dict | None = None
        self.hydro_state: HydroStateChange | None = None   # the newest reply's switch (SPEC §5.2 hydro_state)
        self._sent = np.zeros(SENT_RING)   # when each recent seq was sent (perf_counter), by seq % SENT_RING
        self._zero = Sample.of(np.zeros(0), np.zeros(0), np.zeros(0), 0.0)
        self._shape = (self.n, 6)
        self._pos = np.zeros(self._shape)   # the absolute position sent (reused: the server copies it)
        # generalized modes (setup.modes): the state's last M entries, sent as modal_position/velocity
        self.m = len(setup.mode_labels) if self.n else 0
        self._r = 6 * self.n
        # this process's own server (hydrolink run's embedded one, or its polled one with controllers):
        # the state goes into the arrays of its step path (server/service/local_step.py,
        # controlled_step.py), no message
        self._local = connection.local_step() if self.n else None
        self._controlled = connection.controlled_step() if self.n and self._local is None else None
        if self._controlled is not None:
            self._local = self._controlled
        if self._local is not None:
            self._pos = self._local.position
        self._pos_flat = self._pos.reshape(-1)
        self._vel_flat = self._local.velocity.reshape(-1) if self._local is not None else None

    def sample(self, seq: int, x: np.ndarray, v: np.ndarray, *, iteration: int = 0,
               measurements: dict | None = None, timeout: float | None = None) -> Sample:
        """The server's forces at step ``seq`` for displacement ``x`` and velocity ``v`` (6N, then
        the M modal coordinates of a session with generalized modes)."""
        if not self.n:
            return self._zero
        t = seq * self.dt
        t0 = _time.perf_counter()
        shape, pos, r, local = self._shape, self._pos, self._r, self._local
        extra = {"modal": (x[r:], v[r:])} if self.m else {}
        if self.m:
            x, v = x[:r], v[:r]
        np.add(self.eq, x, out=self._pos_flat)
        try:
            if local is not None:
                self._vel_flat[:] = v
                if extra:
                    local.modal_position[:], local.modal_velocity[:] = extra["modal"]
                if self._controlled is None:   # (no controller joins an embedded server: no measurements)
                    reply = local(seq, iteration)
                else:
                    reply = local(seq, iteration, measurements, self.conn.timeout if timeout is None else timeout)
            elif measurements is not None or timeout is not None or extra:
                reply = self.conn.step(seq, t, pos, v.reshape(shape), iteration, measurements=measurements,
                                       timeout=timeout, **extra)
            else:
                reply = self.conn.step(seq, t, pos, v.reshape(shape), iteration)
        except (KeyboardInterrupt, RunInterrupted):
            raise
        except Exception as exc:
            self.failed(seq, exc)
        self.answered(seq, t0, reply)
        eta = reply["wave_elevation"]
        eta = eta if type(eta) is float else float(np.asarray(eta, float).reshape(-1)[0])
        optional = {k: reply[k].reshape(-1) for k in OPTIONAL_FORCES if reply.get(k) is not None}
        if self.m:   # the modes' forces after the rigid DOFs' (the optional forces are the rigid DOFs')
            s = Sample.of(*(np.concatenate((reply[f].reshape(-1), reply["modal_" + f]))
                            for f in ("excitation", "radiation", "hydrostatic")), eta, optional)
        else:
            s = Sample.of(reply["excitation"].reshape(-1), reply["radiation"].reshape(-1),
                          reply["hydrostatic"].reshape(-1), eta, optional)
        # NaN or inf anywhere makes a sum non-finite (excitation and radiation through their sum)
        if not math.isfinite(float(_sum(s.load)) + float(_sum(s.hydrostatic)) + eta):
            raise self.non_finite(seq)
        return s

    def answered(self, seq: int, sent: float, reply: dict) -> None:
        """The reply to step ``seq``, asked for at ``sent`` (perf_counter), is in: the round trip's
        time (:attr:`seconds`, of which :attr:`controller_seconds`), the :attr:`decisions` and the
        :attr:`hydro_state` switch it carries."""
        rt = _time.perf_counter() - sent
        self.seconds += rt
        self._sent[seq % SENT_RING] = sent
        self.decisions = decisions = reply.get("control")
        change = reply.get("hydro_state")
        self.hydro_state = None if change is None else HydroStateChange.from_wire(change, self.n)
        if decisions:
            self.controller_seconds += self._controller_wait(seq, sent, rt, reply, decisions)

    def failed(self, seq: int, exc: Exception) -> NoReturn:
        """Raise the error that ends a run whose server failed step ``seq`` with ``exc``
        (:class:`RunInterrupted`; a local step's ProtocolError as the server's error reply says it)."""
        if isinstance(exc, ProtocolError):
            exc = RemoteError(exc.code, exc.name, exc.field, exc.message, self.conn.address, exc.extra)
        t, rows, where = seq * self.dt, self.writer.rows, getattr(self.writer, "path", "the results file")
        raise RunInterrupted(f"force server error at step {seq} (t = {t:.6g} s): {exc}; the {rows} rows "
                             f"before it are saved in {where}", step=seq, time=t, rows=rows) from exc

    @property
    def local(self) -> Any:
        """This process's own server's step path this link takes (server/service/local_step.py
        ``LocalStep``, or a polled server's controlled_step.py ``ControlledStep``; None: messages)."""
        return self._local

    def non_finite(self, seq: int) -> SimulationDiverged:
        """The error of a reply to step ``seq`` with non-finite forces."""
        t, rows = seq * self.dt, self.writer.rows
        return SimulationDiverged(f"the force server returned non-finite forces at step {seq} (t = {t:.6g} s); "
                                  f"the {rows} rows before it are saved", step=seq, time=t, rows=rows)

    def _controller_wait(self, seq: int, sent: float, rt: float, reply: dict, decisions: dict) -> float:
        """How long of this round trip the server waited for the controllers' commands: a
        decision's latency runs from the relay of step k's measurements (with the request of seq
        k + 1) to its command; the part after this request was sent, at most the round trip less
        the model's time (``compute_us``). A timeout: all of that."""
        spare = max(rt - 1e-6 * float(reply.get("compute_us") or 0.0), 0.0)
        wait = 0.0
        for d in decisions.values():
            status = d.get("status")
            if status == "timeout":
                return spare
            latency, k = d.get("latency"), d.get("step")
            if status == "ok" and latency is not None and k is not None and 0 <= seq - (k + 1) < SENT_RING:
                wait = max(wait, self._sent[(k + 1) % SENT_RING] + float(latency) - sent)
        return min(wait, spare)


# ------------------------------------------------------------------------------ the multibody side

class Multibody(Protocol):
    """What the loop needs of a multibody code (an adapter around Exudyn or an FMU)."""

    label: str           # "the body state" / "the FMU state": for messages
    h: float             # the client's step
    substeps: int        # client steps per exchange

    def begin(self, s0: Sample, feedback: bool) -> int:
        """Initialise with the server's first sample; returns fixed-point iterations spent (0 if none)."""

    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Wet displacement and velocity (6N) and the acceleration a fed-back −A·a uses."""

    def extent(self, limit: float) -> float:
        """max(|x|, |v|) over everything it integrates (NaN if not finite), or any value below
        ``limit`` when that maximum is below it (a cheap bound may stand in)."""

    def inputs(self, s0: Sample, s1: Sample, acc: np.ndarray | None, x0: np.ndarray, x1: np.ndarray) -> np.ndarray:
        """Its input over a step from the samples at the step's start and end; ``acc`` the
        acceleration of the fed-back −A·a (None: A is in its mass matrix)."""

    def advance(self, t0: float, t1: float, u: np.ndarray) -> None:
        """Integrate one step with input ``u`` held."""

    def save(self) -> Any: ...

    def restore(self, saved: Any) -> None: ...

    def snapshot(self) -> Any:
        """What a results row needs of the current state (kept while a step is iterated)."""

    def write(self, t: float, s: Sample, snap: Any) -> None:
        """One results row."""

    def measurements(self, step: int) -> dict | None:
        """Controller measurements due at client step ``step`` (None: none due)."""

    def apply_control(self, decisions: dict | None) -> None: ...

    def apply_hydro_state(self, change: HydroStateChange) -> None:
        """A body's switch to another hydrodynamic state: its A∞, stiffness and net buoyancy into the
        matrices and constant forces of the step about to be integrated (only the Exudyn client has it:
        other clients refuse scenes with hydro_states, protocol/capabilities.py)."""


# ------------------------------------------------------------------------------ divergence

@dataclass
class DivergenceWatch:
    """Stops a run that blows up, or that shows the added-mass instability's signature: the second
    difference of the fed-back accelerations alternates in sign and grows every step (a lag error
    multiplied by −M⁻¹A every step; physical motion cannot alternate step by step)."""

    limit: float = BLOW_UP_LIMIT
    history: list = field(default_factory=list)
    run: int = 0
    top: float = 0.0

    def check(self, mb: Multibody, step: int, t: float, rows: int, where: str) -> None:
        big = mb.extent(self.limit)
        if big < self.limit:
            return
        bad = "absurdly large" if math.isfinite(big) else "non-finite"
        raise SimulationDiverged(
            f"simulation diverged at step {step} (t = {t:.6g} s): {where} is {bad} (max |x|, |v| = {big:.3g}, "
            f"limit {self.limit:g}); the {rows} rows before it are saved. Try a smaller dt or check the "
            f"scene's masses, stiffness and DOFs", step=step, time=t, rows=rows)

    def feedback(self, a: np.ndarray, step: int, t: float) -> None:
        """Explicit schemes: record the fed-back acceleration of this step."""
        hist = self.history
        hist.append(a.copy())
        self.top = max(self.top, float(np.abs(a).max(initial=0.0)))
        if len(hist) < 4:
            return
        d1, d2 = hist[2] - 2 * hist[1] + hist[0], hist[3] - 2 * hist[2] + hist[1]
        del hist[0]
        n1, n2 = float(np.abs(d1).max(initial=0.0)), float(np.abs(d2).max(initial=0.0))
        self.run = self.run + 1 if (float(d1 @ d2) < 0 and n2 > WATCH_GROWTH * n1
                                    and n2 > WATCH_FLOOR * self.top) else 0
        if self.run >= WATCH_STEPS:
            raise SimulationDiverged(
                f"stopped at step {step} (t = {t:.6g} s): the accelerations fed back as −A∞·a alternate in "
                f"sign and grow every step ({WATCH_STEPS} steps in a row, x{n2 / n1:.3g} in the last): the "
                f"added-mass instability; the {step} rows before it are saved", step=step, time=t, rows=step)


# ------------------------------------------------------------------------------ the loop

@dataclass
class Lockstep:
    """One run's parts: what the coupling schemes use to take an exchange."""

    mb: Multibody
    link: ForceLink
    writer: Any                             # a ResultWriter
    watch: DivergenceWatch
    between: str = "hold"                   # "hold" | "extrapolate" (exchange_every > 1)
    step: int = 0                           # client steps done
    bar: Any = None
    iterations: list[int] = field(default_factory=list)
    pacer: Pacer | None = None              # --realtime: wall-clock releases (protocol/pacing.py)

    @property
    def big_h(self) -> float:
        return self.mb.h * self.mb.substeps

    def between_samples(self, s0: Sample, s1: Sample, j: int, extrapolate: bool = False) -> Sample:
        """The sample at client step j (1..substeps) of an exchange: s1 held, or linear from s0 (the
        exchange's start) to s1 (its end), or on past them (``extrapolate``: both in the past)."""
        kx = self.mb.substeps
        if self.between == "hold" or kx == 1:
            return s1
        return s0.toward(s1, 1.0 + j / kx if extrapolate else j / kx)

    def client_step(self, t0: float, t1: float, u: np.ndarray, where: str | None = None) -> None:
        """Advance the multibody code one client step and check it."""
        self.mb.advance(t0, t1, u)
        self.step += 1
        self.watch.check(self.mb, self.step, t1, self.writer.rows, where or self.mb.label)

    def write(self, t: float, s: Sample, snap: Any = None) -> None:
        self.mb.write(t, s, self.mb.snapshot() if snap is None else snap)
        if self.bar is not None:
            self.bar.update(1)


def progress_bar(total: int, enabled: bool, desc: str = "hydrolink run"):
    """The run's tqdm bar on stderr; tqdm's own ``disable=None`` leaves it out where stderr is not a
    terminal (a log, a pipe: no carriage-return redraws in it)."""
    from tqdm import tqdm
    return tqdm(total=total, unit="step", desc=desc, mininterval=0.5, disable=None if enabled else True)


class GcBetweenSteps:
    """A paced run's garbage collection, kept out of the steps: the heap frozen and automatic
    collection off for the loop (:meth:`PacedSteps.begin`), a young-generation collection (1 when
    generation 1 is due, else 0) in the wait before a release when one is due and the time left
    exceeds twice the dearest seen so far plus the spin; past ``FORCE`` times the threshold, at
    once (between steps, never inside one)."""

    FORCE = 50

    def __init__(self) -> None:
        self.threshold = max(gc.get_threshold()[0], 1)
        self.threshold1 = max(gc.get_threshold()[1], 1)
        self.cost = 5e-5            # s: the dearest collection seen (a guess until measured)
        self.collections, self.seconds = 0, 0.0

    def __call__(self, left: float) -> None:
        n = gc.get_count()
        if n[0] < self.threshold or (left < 2 * self.cost + 5e-4 and n[0] < self.FORCE * self.threshold):
            return
        t0 = _time.perf_counter()
        gc.collect(1 if n[1] >= self.threshold1 else 0)
        dt = _time.perf_counter() - t0
        self.collections += 1
        self.seconds += dt
        self.cost = max(self.cost, dt)


class PacedSteps:
    """A paced run's bookkeeping around each exchange (protocol/pacing.py): the release, where the
    exchange's time went, the row that ends it amended with ``step_latency``, ``overrun`` and
    ``step_time`` before its block goes to the writer (the writer holds blocks meanwhile)."""

    def __init__(self, pacer: Pacer, loop: Lockstep, n_exchanges: int):
        self.pacer, self.link, self.writer = pacer, loop.link, loop.writer
        self.record = StepRecord(pacer, n_exchanges)
        self.gc = GcBetweenSteps()
        self._gc_was = gc.isenabled()
        self._marks = (0.0, 0.0, 0.0)
        w = self.writer
        w.add_variable("step_latency", (), units="s", fill=np.nan,
                       long_name="wall time from the scheduled release of the exchange ending at this row to the "
                                 "end of everything done in it (paced run; NaN: the row ends no exchange)")
        w.add_variable("overrun", (), units="1", dtype="i1", fill=0,
                       long_name="1: the exchange ending at this row completed after its deadline (the next release)")
        w.add_variable("step_time", ("step_part",), {"step_part": list(PARTS)}, "s", fill=np.nan,
                       long_name="where step_latency went: behind (scheduled release to the loop's coming to "
                                 "it: earlier overruns carried), server (round trips less the wait for controllers), "
                                 "controller, client (the rest), io (waiting for the results writer), wake (the wait "
                                 "for the release ending late); an overrun's cause is its largest part")

    def begin(self) -> None:
        """Before the first release: the results written by a process of their own (no write takes
        the loop's GIL or CPU), GC out of the loop, blocks held until their rows are complete."""
        self.writer.write_in_process()
        gc.collect()
        gc.freeze()
        gc.disable()
        self.pacer.idle = self.gc
        self.writer.hold = True

    def release(self, e: int) -> None:
        self.pacer.release(e)
        link = self.link
        self._marks = (link.seconds, link.controller_seconds, self.writer.io_seconds)

    def done(self, e: int) -> None:
        """Exchange ``e`` is complete (its rows committed): record it, amend its last row."""
        end = _time.perf_counter()
        link, w = self.link, self.writer
        s0, c0, io0 = self._marks
        lat, over, parts = self.record.step(e, end, link.seconds - s0 - (link.controller_seconds - c0),
                                            link.controller_seconds - c0, w.io_seconds - io0)
        extra, i = w.amend(w.rows - 1)
        extra["step_latency"][i] = lat
        extra["overrun"][i] = over
        extra["step_time"][i] = parts
        w.release_held()
        if gc.get_count()[0] >= self.gc.FORCE * self.gc.threshold:
            self.gc(float("inf"))

    def end(self) -> None:
        """After the loop (or its failure): blocks flow again, GC as it was."""
        self.writer.hold = False
        self.writer.release_held()
        self.pacer.idle = None
        gc.unfreeze()
        if self._gc_was:
            gc.enable()

    def report(self):
        return self.record.report(self.gc.collections, self.gc.seconds)


class SigintLatch:
    """Ctrl-C during a run, never lost: while the loop runs (on the main thread, with Python's own
    SIGINT handler in place) the handler both raises KeyboardInterrupt, as Python's does, and
    latches it; :meth:`check`, once an exchange, raises it again if the first was swallowed — a
    signal that lands in a finalizer (the loop's GC collections run them) is only printed as
    "Exception ignored" by Python, and the run would go on to its end."""

    def __init__(self) -> None:
        self.pending = False
        self._previous: Any = None

    def _handle(self, signum: int, frame: Any) -> None:
        self.pending = True
        raise KeyboardInterrupt

    def __enter__(self) -> "SigintLatch":
        if threading.current_thread() is threading.main_thread() and \
                signal.getsignal(signal.SIGINT) is signal.default_int_handler:
            self._previous = signal.signal(signal.SIGINT, self._handle)
        return self

    def __exit__(self, *exc: Any) -> None:
        if self._previous is not None:
            signal.signal(signal.SIGINT, self._previous)
            self._previous = None

    def check(self) -> None:
        if self.pending:
            raise KeyboardInterrupt


@runtime_checkable
class LoopsItself(Protocol):
    """A scheme that takes every exchange of a run in a loop of its own (clients/exudyn/compiled_exchange.py
    ``CompiledExchange``: inside Exudyn's own step loop) instead of :func:`run` calling its ``exchange``
    once an exchange (the schemes of clients/lockstep/coupling_schemes.py)."""

    feedback: bool

    def prepare(self) -> None:
        """What it does once before its first exchange (after the initial sample): made before the
        loop takes its real-time priority (:func:`run`'s ``rt_priority``)."""

    def run_exchanges(self, loop: Lockstep, n_exchanges: int, check: Callable[[], None],
                      paced: "PacedSteps | None") -> None:
        """Exchanges 0 .. ``n_exchanges`` - 1 after the initial sample; ``check`` (the SIGINT latch)
        after each, and ``paced``'s release and record around each when paced."""


def run(loop: Lockstep, scheme: Any, n_exchanges: int, coupling: CouplingReport, *,
        first_timeout: float | None = None, hint: Callable[[SimulationDiverged], str] = lambda exc: "",
        pacer: Pacer | None = None, rt_priority: int | None = None) -> RunSummary:
    """Run ``n_exchanges`` exchanges of ``scheme`` (module docstring); the writer gets its final
    status before this returns or raises. Returns the loop's counts and costs, with ``coupling``
    (the adapter's description of the scheme) completed by the iterations it took. ``pacer``: release
    each exchange at its wall-clock time (protocol/pacing.py, :class:`PacedSteps`); the summary's
    ``realtime``. ``rt_priority``: the exchanges under ``SCHED_FIFO`` at that priority
    (clients/lockstep/rt_priority.py; checked by the caller before its set-up), taken after the
    initial sample (a controlled run's join), the scheme's :meth:`~LoopsItself.prepare` and the
    paced run's writer process, given back before the results file is finished. BLAS/OpenMP pools
    are held to one thread for the loop (the per-step products are small: a second thread only
    fights the other participants for a core)."""
    from threadpoolctl import threadpool_limits

    mb, link, writer = loop.mb, loop.link, loop.writer
    paced = PacedSteps(pacer, loop, n_exchanges) if pacer is not None else None
    loop.pacer = pacer
    wall0 = _time.perf_counter()
    init_iterations = 0
    try:
        with threadpool_limits(limits=1), SigintLatch() as sigint:
            x, v, _ = mb.state()
            loop.watch.check(mb, 0, 0.0, 0, "the initial state")
            s = link.sample(0, x, v, timeout=first_timeout)
            init_iterations = mb.begin(s, scheme.feedback)
            loop.write(0.0, s)
            if isinstance(scheme, LoopsItself):
                scheme.prepare()
            if paced is not None:
                paced.begin()
            with held_priority(rt_priority):
                if isinstance(scheme, LoopsItself):
                    scheme.run_exchanges(loop, n_exchanges, sigint.check, paced)
                elif paced is None:
                    for e in range(n_exchanges):
                        s = scheme.exchange(loop, e, s)
                        sigint.check()
                else:
                    for e in range(n_exchanges):
                        paced.release(e)
                        s = scheme.exchange(loop, e, s)
                        paced.done(e)
                        sigint.check()
    except KeyboardInterrupt:
        t = loop.step * mb.h
        _end(paced)
        writer.finish(f"interrupted: KeyboardInterrupt at step {loop.step} (t = {t:.6g} s)")
        raise KeyboardInterrupt(f"run interrupted at step {loop.step} (t = {t:.6g} s); {writer.rows_written} "
                                f"rows saved in {getattr(writer, 'path', 'the results file')}") from None
    except SimulationDiverged as exc:
        _end(paced)
        extra = hint(exc)
        if extra:
            exc = SimulationDiverged(f"{exc}. {extra}", step=exc.step, time=exc.time, rows=exc.rows)
        writer.finish(f"interrupted: {exc}")
        raise exc from None
    except RunInterrupted as exc:
        _end(paced)
        writer.finish(f"interrupted: {exc}")
        raise
    except BaseException as exc:
        _end(paced)
        t = loop.step * mb.h
        writer.finish(f"interrupted: {type(exc).__name__} at step {loop.step} (t = {t:.6g} s): {exc}")
        raise
    finally:
        if loop.bar is not None:
            loop.bar.close()
    _end(paced)
    writer.finish("complete")
    wall = _time.perf_counter() - wall0
    steps = max(loop.step, 1)
    its = np.asarray(loop.iterations or [1])
    coupling = replace(coupling, initial_iterations=init_iterations, iterations_mean=float(its.mean()),
                       iterations_max=int(its.max()),
                       iterations=np.asarray(loop.iterations, int) if coupling.scheme == "implicit" else None)
    return RunSummary(steps=loop.step, time=loop.step * mb.h, wall_time=wall, rows=writer.rows_written,
                      status="complete", coupling=coupling, client_us_per_step=(wall - link.seconds) / steps * 1e6,
                      round_trip_us_per_step=link.seconds / steps * 1e6,
                      realtime=paced.report() if paced is not None else None)


def _end(paced: PacedSteps | None) -> None:
    if paced is not None:
        paced.end()
