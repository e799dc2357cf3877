"""WAPPAC's controller signature as a hydrolink controller: a file that defines
``my_controller(x, v, t, eta10)`` (the WavePiston control competition's entry,
https://emg-mu.github.io/WAPPAC_docs/) runs unchanged with ``hydrolink control FILE``.

Each control period the function is called with the PTO's displacement ``x`` (m) and velocity
``v`` (m/s) of the measurements, the measurements' time ``t`` (s) and ``eta10``: the wave elevation
(m) at the controller's first ``wave_points`` probe, which stands for WAPPAC's gauge 10 m up-wave
(put it where the scene's device needs it). Its return value is the PTO force (N), WAPPAC's
F_pto with absorbed power F_pto v: the same sign as hydrolink's force command (a damper returns
c v). Like WAPPAC's ZOH, the force is held over the period (the scene's ``period``, ``latency``).

The scene's controller must drive one PTO with ``command = "force"`` and measure
``pto_displacement``, ``pto_velocity`` and ``wave_elevation``; anything else is refused naming the
key. A folder ``external_packages`` beside the file is importable, as in WAPPAC's distribution.
"""

from __future__ import annotations

import math
from typing import Callable

from hydrolink.clients.control import Controller, ControllerError

NEEDED = ("pto_displacement", "pto_velocity", "wave_elevation")


class WappacController(Controller):
    """Calls ``function(x, v, t, eta10)`` every control period; its value is the force command."""

    def __init__(self, function: Callable[[float, float, float, float], float], source: str):
        self.function, self.source = function, source

    def on_start(self, info: dict) -> None:
        where = f"controllers[{info['name']!r}]"
        if len(info["ptos"]) != 1:
            raise ControllerError(f"{self.source}: my_controller drives one PTO; the scene's {where}.ptos "
                                  f"lists {info['ptos']}", field="ptos")
        if info["command"] != "force":
            raise ControllerError(f"{self.source}: my_controller returns a force; the scene's {where}.command is "
                                  f"{info['command']!r} (use \"force\")", field="command")
        missing = [m for m in NEEDED if m not in info["measurements"]]
        if missing:
            raise ControllerError(f"{self.source}: my_controller needs {list(NEEDED)}; add {missing} to the "
                                  f"scene's {where}.measurements", field="measurements")

    def on_step(self, t: float, m: dict) -> dict:
        force = self.function(float(m["pto_displacement"][0]), float(m["pto_velocity"][0]), t,
                              float(m["wave_elevation"][0]))
        try:
            value = float(force)
        except (TypeError, ValueError):
            raise ControllerError(f"{self.source}: my_controller returned {force!r} at t = {t:g} s, not a "
                                  "number (the PTO force in N)") from None
        if not math.isfinite(value):
            raise ControllerError(f"{self.source}: my_controller returned {value} at t = {t:g} s")
        return {self.ptos[0]: value}
