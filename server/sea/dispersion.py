"""Linear dispersion: the wave number k of w^2 = g k tanh(k h), the one definition hydrolink uses."""

from __future__ import annotations

import math

import numpy as np

__all__ = ["wave_number"]


def _wave_number(omega: float, gravity: float, depth: float) -> float:
    """k of one frequency: deep water (w^2 / g) where k h > 20, else Newton from w^2 / (g sqrt(tanh))."""
    k_deep = omega ** 2 / gravity
    if math.isinf(depth) or k_deep * depth > 20.0:
        return k_deep
    k = k_deep / math.sqrt(math.tanh(k_deep * depth))      # a good start, then Newton
    for _ in range(50):
        t = math.tanh(k * depth)
        f = gravity * k * t - omega ** 2
        df = gravity * t + gravity * k * depth * (1 - t * t)
        step = f / df
        k -= step
        if abs(step) < 1e-14 * k:
            break
    return k


def wave_number(omega, gravity: float, depth: float):
    """k [rad/m] of w^2 = g k tanh(k h) (``depth`` inf: deep water): a float for a float ``omega``,
    an array of ``omega``'s shape for an array (each frequency solved alone, so a frequency's k
    does not depend on the others it comes with)."""
    if np.ndim(omega) == 0:
        return _wave_number(float(omega), gravity, depth)
    w = np.asarray(omega, float)
    return np.array([_wave_number(float(x), gravity, depth) for x in w.ravel()]).reshape(w.shape)
