"""Wall-clock pacing of a lockstep run (``hydrolink run --realtime [FACTOR]``, a ``hello`` with
``realtime``: SPEC §5.1; docs/realtime.md). One schedule for both sides: the client's loop waits for
each release (:meth:`Pacer.release`), a server holds each ``forces`` reply until its release
(:meth:`Pacer.release_time`; server/service/force_server.py).

Exchange e (simulated time e·H to (e+1)·H) is released at wall time t0 + e·H/FACTOR, t0 the first
release; its deadline is the next release, t0 + (e+1)·H/FACTOR. A step that completes after its
deadline is an **overrun**: counted, its lateness (completion − deadline) kept, and the schedule
stays anchored at t0 (the next step is released at once and has less time, never a shifted clock),
so a run that falls behind shows it in every following step instead of silently absorbing it.

The client (:class:`StepRecord`, clients/lockstep/driver.py) records per exchange its **latency**:
wall time from its *scheduled* release to the end of everything done in it (the server round trip,
the controllers' relay, the client's integration, its results rows), so latency > period exactly
when the step overran; and where that time went, :data:`PARTS`: ``behind`` (the scheduled release
to the moment the loop came to it, when that was later: the previous steps' overrun carried over),
``server`` (the round trips to the force server less the wait for controllers), ``controller`` (the
server's wait for the controllers' commands, from the decisions' latencies), ``client`` (the rest:
the multibody step, PTO sampling, the rows), ``io`` (waiting for the results writer) and ``wake``
(the wait for the release ending after it: a late wake-up, the host not running the thread, a
collection in the wait that ran over). An overrun's **cause** is its largest part: ``wake`` and a
step's own parts start a run of overruns, ``behind`` carries one on. The results file gets them per
row (``step_latency``, ``overrun``, ``step_time`` over ``step_part``) and the run summary a
:class:`PacedRunReport`, from the same arrays.

A server pacing a session (:meth:`Pacer.done`) reports the plain :class:`RealtimeReport` in
``goodbye``, its latency from each step's arrival to its reply being ready.

Waiting: ``time.sleep`` up to ``SPIN`` before the release, then a spin on ``perf_counter``
(Linux's sleep wakes 50–100 µs late, a large part of a 1 ms step; ``RT_SPIN`` for a thread under a
real-time policy, which wakes on time); before sleeping, an ``idle``
hook may use the time left (the client's garbage collection between steps).
"""

from __future__ import annotations

import math
import time
from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

SPIN = 3e-4   # s before a release spent spinning instead of sleeping
#: the spin of a thread under a real-time policy (SCHED_FIFO/RR: ``--rt-priority``), which wakes on
#: time (a 0.5 ms sleep woke 19 µs late at the median, 49 µs at p99, 105 µs at p99.9, at load 9.7 on
#: 2 cores) and must not keep its core busy: the kernel throttles a real-time thread that never
#: sleeps (``sched_rt_runtime_us``: 50 ms off in each second)
RT_SPIN = 1e-4
FACTOR_RANGE = (1e-3, 1e9)   # pace factors accepted: 1/1000 of wall clock to "as fast as it goes"
#: where a paced step's time goes (module docstring), the order of ``step_time``'s ``step_part``
PARTS = ("behind", "server", "controller", "client", "io", "wake")


def release_spin() -> float:
    """The calling thread's spin before a release: RT_SPIN under SCHED_FIFO or SCHED_RR, else SPIN."""
    import os
    get = getattr(os, "sched_getscheduler", None)
    return RT_SPIN if get is not None and get(0) in (os.SCHED_FIFO, os.SCHED_RR) else SPIN


def check_factor(factor: float, key: str) -> float:
    """``factor`` as a float within FACTOR_RANGE; ValueError naming ``key`` otherwise."""
    lo, hi = FACTOR_RANGE
    if not (isinstance(factor, (int, float)) and math.isfinite(factor) and lo <= factor <= hi):
        raise ValueError(f"{key} {factor!r}: the pace factor must be a number in [{lo:g}, {hi:g}] "
                         "(1 = wall clock, 2 = twice as fast)")
    return float(factor)


@dataclass(frozen=True)
class RealtimeReport:
    """How a paced run kept its pace. Times in s."""
    factor: float               # simulated seconds per wall second
    period: float               # wall seconds per exchange (H / factor)
    steps: int                  # paced exchanges
    overruns: int               # exchanges completed after their deadline
    worst_lateness: float       # largest completion − deadline (0 without overruns)
    latency_p50: float
    latency_p99: float
    latency_max: float


@dataclass
class Pacer:
    """Releases exchanges at their wall-clock times and measures them (module docstring)."""
    exchange_dt: float          # simulated seconds per exchange (H)
    factor: float = 1.0
    t0: float | None = None
    called: float = math.nan    # when the loop asked for the current exchange's release
    released: float = math.nan
    latencies: list[float] = field(default_factory=list)
    overruns: int = 0
    worst_lateness: float = 0.0
    idle: Callable[[float], None] | None = None   # called with the seconds left before a wait
    #: s spun before a release; None: the releasing thread's (:func:`release_spin`), taken at the first
    #: release (a loop's priority, ``--rt-priority``, is taken after the Pacer is made)
    spin: float | None = None

    def __post_init__(self) -> None:
        self.factor = check_factor(self.factor, "--realtime")

    @property
    def period(self) -> float:
        return self.exchange_dt / self.factor

    def release_time(self, e: int) -> float:
        """Exchange ``e``'s release (``time.perf_counter`` clock); the first call anchors t0 now."""
        if self.t0 is None:
            self.t0 = time.perf_counter()
            if self.spin is None:
                self.spin = release_spin()
        return self.t0 + e * self.period

    def release(self, e: int) -> None:
        """Wait until exchange ``e``'s wall-clock time (at once when it has passed)."""
        target = self.release_time(e)
        self.called = now = time.perf_counter()
        spin = self.spin
        if target - now > spin:
            if self.idle is not None:
                self.idle(target - now)
                now = time.perf_counter()
        if target - now > spin:
            time.sleep(target - now - spin)
        while (now := time.perf_counter()) < target:
            pass
        self.released = now

    def since_release(self) -> float:
        """Wall seconds since the current exchange's release (NaN before the first)."""
        return time.perf_counter() - self.released

    def done(self, e: int, started: float | None = None) -> None:
        """Exchange ``e`` completed now: its latency (from ``started``, default its release) and an
        overrun if past its deadline, the release of e + 1."""
        now = time.perf_counter()
        self.latencies.append(now - (self.released if started is None else started))
        late = now - self.release_time(e + 1)
        if late > 0:
            self.overruns += 1
            self.worst_lateness = max(self.worst_lateness, late)

    def report(self) -> RealtimeReport:
        lat = np.asarray(self.latencies) if self.latencies else np.zeros(1)
        p50, p99 = np.percentile(lat, [50, 99])
        return RealtimeReport(factor=self.factor, period=self.period, steps=len(self.latencies),
                              overruns=self.overruns, worst_lateness=self.worst_lateness,
                              latency_p50=float(p50), latency_p99=float(p99), latency_max=float(lat.max()))


@dataclass(frozen=True)
class PacedRunReport(RealtimeReport):
    """A paced client run: :class:`RealtimeReport` (latencies from the scheduled releases) and
    where the time went (:data:`PARTS`, s)."""
    parts_mean: dict[str, float] = field(default_factory=dict)   # per step
    parts_max: dict[str, float] = field(default_factory=dict)
    overrun_causes: dict[str, int] = field(default_factory=dict)  # overruns by their largest part
    gc_collections: int = 0       # young-generation collections run between steps
    gc_seconds: float = 0.0


class StepRecord:
    """A paced client run's per-exchange record, in arrays made before the loop (module docstring)."""

    def __init__(self, pacer: Pacer, n: int):
        self.pacer, self.n = pacer, int(n)
        self.latency = np.full(self.n, np.nan)
        self.parts = np.zeros((self.n, len(PARTS)))
        self.overrun = np.zeros(self.n, bool)
        self.steps = 0

    def step(self, e: int, end: float, server: float, controller: float, io: float) -> tuple[float, bool, np.ndarray]:
        """Exchange ``e`` ended at ``end`` (perf_counter) after ``server``, ``controller`` and
        ``io`` seconds; returns its latency, overrun and parts (a row of :attr:`parts`)."""
        p = self.pacer
        release = p.release_time(e)
        lat = end - release
        row = self.parts[e]
        ready = p.called if p.called > release else release
        row[0] = ready - release
        row[5] = p.released - ready
        row[1] = server
        row[2] = controller
        row[4] = io
        row[3] = end - p.released - server - controller - io
        late = end - p.release_time(e + 1)
        over = late > 0.0
        self.latency[e], self.overrun[e] = lat, over
        if over:
            p.overruns += 1
            if late > p.worst_lateness:
                p.worst_lateness = late
        self.steps = e + 1
        return lat, over, row

    def report(self, gc_collections: int = 0, gc_seconds: float = 0.0) -> PacedRunReport:
        m = self.steps
        lat = self.latency[:m] if m else np.zeros(1)
        parts = self.parts[:m] if m else np.zeros((1, len(PARTS)))
        p50, p99 = np.percentile(lat, [50, 99])
        causes = np.argmax(parts[self.overrun[:m]], axis=1) if m else np.zeros(0, int)
        return PacedRunReport(
            factor=self.pacer.factor, period=self.pacer.period, steps=m, overruns=int(self.overrun[:m].sum()),
            worst_lateness=self.pacer.worst_lateness, latency_p50=float(p50), latency_p99=float(p99),
            latency_max=float(lat.max()), parts_mean={k: float(v) for k, v in zip(PARTS, parts.mean(axis=0))},
            parts_max={k: float(v) for k, v in zip(PARTS, parts.max(axis=0))},
            overrun_causes={k: int((causes == i).sum()) for i, k in enumerate(PARTS)},
            gc_collections=gc_collections, gc_seconds=gc_seconds)
