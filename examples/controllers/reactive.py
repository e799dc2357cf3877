"""Reactive (spring-damper) control: F = c v + k x on each PTO (force commands, x = extension).

Tuned for a target period: give ``damping`` and ``stiffness`` directly, or ``target_period``
with the device's equivalent ``mass`` (kg, added mass included), ``hydrostatic_stiffness`` (N/m)
and ``radiation_damping`` (N s/m) at that period, seen by the PTO: then c = B and
k = w^2 m - C, the complex-conjugate (impedance-matching) choice for that period.

``examples/controllers/c/reactive.c`` is the same controller in C (same formula, same order of
floating-point operations: bit-identical commands).
"""

import math

from hydrolink.clients.control import Controller


def tuning(p: dict) -> tuple[float, float]:
    if "damping" in p and "stiffness" in p:
        return float(p["damping"]), float(p["stiffness"])
    w = 2 * math.pi / float(p["target_period"])
    return float(p["radiation_damping"]), w * w * float(p["mass"]) - float(p["hydrostatic_stiffness"])


class Reactive(Controller):
    def on_start(self, info):
        self.c, self.k = tuning(info["parameters"])

    def on_step(self, t, m):
        v, x = m["pto_velocity"].tolist(), m["pto_displacement"].tolist()
        return {p: self.c * v[i] + self.k * x[i] for i, p in enumerate(self.ptos)}
