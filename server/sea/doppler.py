"""The Doppler shift of the waves in a steady current (``[current] doppler = true``).

The spectrum's (or list's) frequencies w are the waves' own, relative to the water; the water moves
at the current's surface speed U towards theta_c. A component of heading beta and wave number
k = k(w) (linear dispersion, unchanged) is seen at a point fixed on the ground at the encounter
frequency

    w_e = w + k U cos(beta - theta_c)

(a following current shortens the period: w_e > w; an opposing one lengthens it). The elevation
at a fixed point is a cos(k . x - w_e t + phi); the excitation and the QTFs are read from the HDB at
the intrinsic w (the wave of that length the BEM solved for) and oscillate at w_e. A component whose
energy cannot travel against the current (c_g + U cos(beta - theta_c) <= 0: wave blocking) is
refused naming the key. Not with an elevation series nor with excitation by convolution (both
take the elevation at the origin as the wave, whose frequency content is already the encounter
one).
"""

from __future__ import annotations

import math
from dataclasses import replace

import numpy as np

from hydrolink.protocol.current import Current
from hydrolink.server.sea.waves import WaveComponents, WaveError


def group_velocity(omega: np.ndarray, k: np.ndarray, gravity: float, depth: float) -> np.ndarray:
    """c_g = dw/dk of w^2 = g k tanh(k h) (deep water: g / (2 w))."""
    if math.isinf(depth):
        return gravity / (2 * omega)
    kh = np.minimum(k * depth, 350.0)
    return (gravity * np.tanh(kh) + gravity * kh / np.cosh(kh) ** 2) / (2 * omega)


def doppler_shift(comps: WaveComponents, current: Current | None, gravity: float, depth: float,
                  excitation: str) -> WaveComponents:
    """``comps`` seen from the ground in ``current`` when its ``doppler`` is on (module docstring)."""
    if current is None or not current.doppler:
        return comps
    if comps.kind == "elevation" or excitation == "convolution":
        raise WaveError("current.doppler", "not with an elevation series or excitation = \"convolution\" (they take "
                                           "the elevation at the origin, already at the encounter frequencies)")
    if comps.kind == "gauges":
        raise WaveError("current.doppler", "not with a sea from gauges: their records are at the encounter "
                                           "frequencies already, and the fit's wave numbers are still water's")
    if comps.size == 0:
        return comps
    k = comps.wave_numbers(gravity, depth)
    u = float(current.speed_at(np.zeros(1))[0])
    along = u * np.cos(comps.heading_of() - math.radians(current.direction))
    blocked = np.flatnonzero(group_velocity(comps.omega, k, gravity, depth) + along <= 0.0)
    if blocked.size:
        i = int(blocked[0])
        raise WaveError("current.doppler", f"the component at {comps.omega[i]:.4g} rad/s cannot travel against the "
                                           f"current ({u:g} m/s towards {current.direction:g} deg): its group velocity "
                                           f"is below the opposing current (wave blocking); narrow the band")
    return replace(comps, omega=comps.omega + k * along, intrinsic=comps.omega.copy())
