"""Model-based PI (spring-damper) control designed on the device's linear plant: the causal
complex-conjugate approximation at the sea's peak frequency, held inside the closed loop's
stability region by the plant.

At join the controller asks for the plant (SPEC §5.7.2, ``plant = "continuous"``). For each PTO it
reads the PTO's own response to its force command, H(iw) = v_pto / F (input ``pto:<name>``, output
``pto:<name>.velocity``): the device seen from the PTO is a source with intrinsic impedance
Z_i = -1/H = R + iX (e^{+iwt}). A force F = c v + k x (x the extension) is Z_c = c - i k/w and
absorbs 1/2 Re(Z_c) |F_th|^2 / |Z_i + Z_c|^2: at w_p the best k is the conjugate match
k = w_p X, and for any k the best c is |R + i(X - k/w_p)|. A negative spring (a device tuned to
longer waves than its resonance) can make the closed loop unstable — for RM3 at Tp = 8 s the
conjugate k = -2.0e6 N/m exceeds the spar's restoring stiffness — so k is raised (bisection) until
every closed-loop pole of the plant with F = c v + k x has Re p <= -``stability_margin``; c
follows k. The force is clipped at the scene's ``max_force``.

Parameters (``[[controllers]] parameters``): ``peak_period`` (s; default the scene's ``waves.tp`` or
``waves.period``), ``stability_margin`` (1/s, default MARGIN = 0.005: RM3's slowest open-loop mode
decays at ~0.009 1/s). Measurements: ``pto_displacement``,
``pto_velocity``.
"""

import math
import tomllib

import numpy as np

from hydrolink.clients.control import Controller

MARGIN = 0.005   # 1/s: the slowest closed-loop pole decays at least this fast


def closed_loop_decay(plant, pto: str, c: float, k: float) -> float:
    """-max Re p of the plant's poles with the PTO force F = c v + k x fed back."""
    b = plant.B[:, plant.inputs.index(f"pto:{pto}")]
    row = c * plant.C[plant.outputs.index(f"pto:{pto}.velocity")] + k * plant.C[plant.outputs.index(f"pto:{pto}.displacement")]
    return -float(np.linalg.eigvals(plant.A + np.outer(b, row)).real.max())


def design(plant, pto: str, omega: float, margin: float = MARGIN) -> tuple[float, float]:
    """(c, k): the conjugate match at ``omega``, k raised until the loop decays at >= ``margin``."""
    h = plant.frequency_response([omega])[0][plant.outputs.index(f"pto:{pto}.velocity"),
                                             plant.inputs.index(f"pto:{pto}")]
    z = -1.0 / h
    r, x = float(z.real), float(z.imag)

    def gains(k: float) -> tuple[float, float]:
        return math.hypot(r, x - k / omega), k

    lo = omega * x
    if closed_loop_decay(plant, pto, *gains(lo)) >= margin:
        return gains(lo)
    hi = max(abs(lo), 1.0)
    while closed_loop_decay(plant, pto, *gains(hi)) < margin:
        hi *= 2.0
        if hi > 1e15:
            raise ValueError(f"pto {pto!r}: no spring-damper keeps the loop decaying at {margin} 1/s")
    for _ in range(60):
        mid = 0.5 * (lo + hi)
        lo, hi = (lo, mid) if closed_loop_decay(plant, pto, *gains(mid)) >= margin else (mid, hi)
    return gains(hi)


class PlantPI(Controller):
    plant = "continuous"

    def on_start(self, info):
        waves = tomllib.loads(info["scene"])["waves"]
        p = info["parameters"]
        period = float(p.get("peak_period", waves.get("tp", waves.get("period"))))
        margin = float(p.get("stability_margin", MARGIN))
        self.gains = [design(info["plant"], name, 2 * math.pi / period, margin) for name in self.ptos]
        limit = info["limits"]["max_force"]
        self.limit = math.inf if limit is None else float(limit)

    def on_step(self, t, m):
        v, x = m["pto_velocity"], m["pto_displacement"]
        return {p: float(np.clip(c * v[i] + k * x[i], -self.limit, self.limit))
                for i, (p, (c, k)) in enumerate(zip(self.ptos, self.gains))}
