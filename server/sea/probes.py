"""Wave probes: the undisturbed incident elevation at points, now and at preview offsets (the
``wave_elevation`` measurements of controllers, SPEC §5.7)."""

from __future__ import annotations

import numpy as np

from hydrolink.server.sea.waves import WaveComponents, ramp_factor

__all__ = ["WaveProbes"]


class WaveProbes:
    """Undisturbed incident elevation at probe points (x, y), now and at preview offsets.

    Same convention as :mod:`hydrolink.server.sea.waves`: a component a, phi, heading beta gives
    eta(x, y, t) = r(t) a cos(k (x cos beta + y sin beta) - w t + phi), beta the component's own
    heading (at the origin exactly the model's ``wave_elevation``)."""

    def __init__(self, comps: WaveComponents, points: np.ndarray, preview_times: np.ndarray, g: float,
                 depth: float):
        self.comps = comps
        self.points = np.asarray(points, float).reshape(-1, 2)
        self.offsets = np.r_[0.0, np.asarray(preview_times, float)]   # column 0: now
        if comps.size:
            k = comps.wave_numbers(g, depth)
            b = comps.heading_of()            # each component's own heading (spread and crossing seas)
            kx = np.outer(self.points[:, 0], k * np.cos(b)) + np.outer(self.points[:, 1], k * np.sin(b))
            self._c = comps.amplitude * np.exp(1j * (comps.phase + kx))   # (n_p, n_c)

    def __call__(self, t: float) -> np.ndarray:
        """(n_p, 1 + n_h): elevation at t + offsets, the ramp included."""
        if not self.comps.size:
            return np.zeros((self.points.shape[0], self.offsets.size))
        times = t + self.offsets
        e = np.exp(-1j * np.outer(self.comps.omega, times))               # (n_c, n_t)
        return np.real(self._c @ e) * ramp_factor(times, self.comps.ramp)
