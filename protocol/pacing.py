"""Wall-clock pacing of a lockstep run (``hydrolink run --realtime [FACTOR]``, a ``hello`` with
``realtime``: SPEC §5.1; docs/realtime.md). One schedule for both sides: the client's loop waits for
each release (:meth:`Pacer.release`), a server holds each ``forces`` reply until its release
(:meth:`Pacer.release_time`; server/service/force_server.py).

Exchange e (simulated time e·H to (e+1)·H) is released at wall time t0 + e·H/FACTOR, t0 the first
release; its deadline is the next release, t0 + (e+1)·H/FACTOR. A step that completes after its
deadline is an **overrun**: counted, its lateness (completion − deadline) kept, and the schedule
stays anchored at t0 (the next step is released at once and has less time, never a shifted clock),
so a run that falls behind shows it in every following step instead of silently absorbing it.

Per step the pacer records the **latency**: wall time from the step's release to its completion
(the server round trip and the client's integration: what a controller or a hardware rig sees).
The results file gets it as ``step_latency`` (time,) (NaN on the initial row, which is not paced);
the run summary's :class:`RealtimeReport` gives the count of overruns, the worst lateness and the
50th/99th percentile and maximum latency.

Waiting: ``time.sleep`` up to ``SPIN`` before the release, then a spin on ``perf_counter``
(Linux's sleep wakes 50–100 µs late, a large part of a 1 ms step).
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, field

import numpy as np

SPIN = 3e-4   # s before a release spent spinning instead of sleeping
FACTOR_RANGE = (1e-3, 1e9)   # pace factors accepted: 1/1000 of wall clock to "as fast as it goes"


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
    released: float = math.nan
    latencies: list[float] = field(default_factory=list)
    overruns: int = 0
    worst_lateness: float = 0.0

    def __post_init__(self) -> None:
        self.factor = check_factor(self.factor, "--realtime")

    @property
    def period(self) -> float:
        return self.exchange_dt / self.factor

    def release_time(self, e: int) -> float:
        """Exchange ``e``'s release (``time.perf_counter`` clock); the first call anchors t0 now."""
        if self.t0 is None:
            self.t0 = time.perf_counter()
        return self.t0 + e * self.period

    def release(self, e: int) -> None:
        """Wait until exchange ``e``'s wall-clock time (at once when it has passed)."""
        target = self.release_time(e)
        now = time.perf_counter()
        if target - now > SPIN:
            time.sleep(target - now - SPIN)
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
