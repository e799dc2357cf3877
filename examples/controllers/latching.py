"""Latching control (impedance commands): hold the PTO locked (a very high damping) from the
moment its velocity changes sign until ``latch_time`` has passed, then release it to the
harvesting damping. Latching delays the motion so that it comes in phase with the excitation when
the device's natural period is shorter than the wave period; a common choice is
latch_time ~ (T_wave - T_natural) / 2.

Parameters: ``damping`` (N s/m, released), ``latch_damping`` (N s/m, latched), ``latch_time`` (s).
"""

from hydrolink.clients.control import Controller


class Latching(Controller):
    def on_start(self, info):
        p = info["parameters"]
        self.c, self.c_latch, self.t_latch = float(p["damping"]), float(p["latch_damping"]), float(p["latch_time"])
        self.sign = {name: 0.0 for name in self.ptos}
        self.until = {name: -1.0 for name in self.ptos}

    def on_step(self, t, m):
        out = {}
        for name, v in zip(self.ptos, m["pto_velocity"].tolist()):
            s = 1.0 if v > 0 else -1.0
            if self.sign[name] and s != self.sign[name] and t >= self.until[name]:
                self.until[name] = t + self.t_latch      # velocity crossed zero: latch
            self.sign[name] = s
            out[name] = {"damping": self.c_latch if t < self.until[name] else self.c}
        return out
