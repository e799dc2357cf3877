"""Model-based PI (spring-damper) control designed on the device's linear plant: a causal
approximation of complex-conjugate control, tuned at the sea's peak frequency.

At join the controller asks for the plant (SPEC §5.7.2, ``plant = "continuous"``) and reads the
PTO's own response to its force command, H(iw) = v_pto / F (input ``pto:<name>``, output
``pto:<name>.velocity``). The device seen from the PTO is a source with intrinsic impedance
Z_i = -1/H (e^{+iwt}): a PTO force F = c v + k x (x the extension, v = iw x) is the impedance
Z_c = c - i k / w, the absorbed power 1/2 Re(Z_c) |F_th|^2 / |Z_i + Z_c|^2 is largest at
Z_c = conj(Z_i): c = Re Z_i(w_p), k = w_p Im Z_i(w_p). Exact at w_p only (that is the
approximation); the force is clipped at the scene's ``max_force``.

Parameters (``[[controllers]] parameters``): ``peak_period`` (s; default the scene's wave period,
``waves.tp`` or ``waves.period``). Measurements: ``pto_displacement``, ``pto_velocity``.
"""

import math
import tomllib

import numpy as np

from hydrolink.clients.control import Controller


def conjugate_gains(plant, pto: str, omega: float) -> tuple[float, float]:
    """(c, k) of the spring-damper that matches the conjugate of the plant's intrinsic impedance at
    ``omega`` for PTO ``pto``."""
    h = plant.frequency_response([omega])[0][plant.outputs.index(f"pto:{pto}.velocity"),
                                             plant.inputs.index(f"pto:{pto}")]
    z = -1.0 / h
    return float(z.real), float(omega * z.imag)


class PlantPI(Controller):
    plant = "continuous"

    def on_start(self, info):
        waves = tomllib.loads(info["scene"])["waves"]
        period = float(info["parameters"].get("peak_period", waves.get("tp", waves.get("period"))))
        self.gains = [conjugate_gains(info["plant"], p, 2 * math.pi / period) for p in self.ptos]
        limit = info["limits"]["max_force"]
        self.limit = math.inf if limit is None else float(limit)

    def on_step(self, t, m):
        v, x = m["pto_velocity"], m["pto_displacement"]
        return {p: float(np.clip(c * v[i] + k * x[i], -self.limit, self.limit))
                for i, (p, (c, k)) in enumerate(zip(self.ptos, self.gains))}
