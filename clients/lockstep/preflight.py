"""The checks every lockstep adapter makes before anything runs (the Exudyn client and the FMU
master alike), and the derived values the run needs, computed once.

A refusal ends the results file with "refused: ..." and raises one SceneError naming the key; the
warnings (the server's setup warnings and the run's own) are logged once here and kept for the
summary and the results' ``warnings`` attribute.
"""

from __future__ import annotations

import logging
import math
from dataclasses import dataclass

from hydrolink.protocol.capabilities import refuse_unsupported
from hydrolink.protocol.scene import Scene, SceneError, wave_peaks
from hydrolink.protocol.setup import Setup

log = logging.getLogger(__name__)

#: period stretch of the trapezoidal rule (of the wave period at the exchange step) above which a run
#: is refused / warned: 10 % is dt > T/5.6 (T/5 is refused), 1 % is dt > T/18
DT_REFUSE, DT_WARN = 0.10, 0.01


@dataclass(frozen=True)
class Preflight:
    """What the run needs, derived once from the scene and the server's setup."""
    exchange_every: int     # client steps per server exchange
    exchange_dt: float      # s, the server's step = setup.dt
    n_exchanges: int        # exchanges to simulation.duration
    warnings: list[str]     # setup's warnings and the run's own, each naming the key to change

    @property
    def n_steps(self) -> int:
        """Client steps to simulation.duration."""
        return self.n_exchanges * self.exchange_every


def wave_resolution(scene: Scene, step: float) -> tuple[str, str] | None:
    """("refuse" | "warn", why) when ``step`` (the exchange step, exchange_every × dt) resolves the
    wave period (regular), peak period (irregular; each system's of a ``sea``) or the period of a
    component carrying at least 1 % of a component list's variance too coarsely: the trapezoidal
    rule stretches a period T by ωh / (2 atan(ωh/2)) − 1 (12 % at T/5, 3.2 % at T/10, 0.8 % at T/20)."""
    peaks = wave_peaks(scene.waves)
    if getattr(scene.waves, "type", "") == "components":
        total = sum(p.height ** 2 for p in peaks)
        peaks = [p for p in peaks if p.height ** 2 >= 0.01 * total]
    if not peaks:
        return None
    shortest = min(peaks, key=lambda p: p.period)
    period, what = shortest.period, shortest.period_key
    if what.startswith("waves.omega"):      # a component's frequency: say its period
        what = f"the period of {what}"
    wh = 2 * math.pi * step / period
    stretch = wh / (2 * math.atan(wh / 2)) - 1
    if stretch <= DT_WARN:
        return None
    kx = scene.coupling.exchange_every
    what_step = f"{step:g} s" + (f" (coupling.exchange_every = {kx} × dt)" if kx > 1 else "")
    why = (f"a step of {what_step} resolves {what} = {period:g} s with {period / step:.3g} steps: the "
           f"trapezoidal rule stretches that period by {100 * stretch:.2g} %; use simulation.dt <= "
           f"{period / 20 / kx:.3g} s (T/20: < 1 %)")
    if stretch > DT_REFUSE:
        return "refuse", f"{why} — refused above {100 * DT_REFUSE:g} %"
    return "warn", why


def preflight(scene: Scene, setup: Setup | None, writer, tool: str) -> Preflight:
    """The shared checks of a lockstep run (module docstring); ``tool`` the adapter's entry in
    protocol/capabilities.py ``TOOLS`` ("exudyn", "fmu_master"): a scene feature it cannot take is
    refused first, naming the key and the tool."""
    try:
        refuse_unsupported(scene, tool, lambda key, why: SceneError("scene", key, why))
    except SceneError as exc:
        writer.finish(f"refused: {exc.why}")
        raise
    big_h = scene.exchange_dt
    if setup is not None and setup.n and abs(setup.dt - big_h) > 1e-9 * big_h:
        raise ValueError(f"the server's step {setup.dt} s is not coupling.exchange_every × simulation.dt "
                         f"= {big_h} s")
    warnings = list(setup.warnings) if setup is not None else []
    note = wave_resolution(scene, big_h)
    if note and note[0] == "refuse":
        writer.finish(f"refused: {note[1]}")
        raise SceneError("scene", "simulation.dt", note[1])
    if note:
        warnings.append(f"simulation.dt: {note[1]}")
    for text in warnings:
        log.warning("%s", text)
    return Preflight(exchange_every=scene.coupling.exchange_every, exchange_dt=big_h,
                     n_exchanges=scene.n_exchanges, warnings=warnings)
