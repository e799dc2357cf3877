"""Interface-coupling numerics of the FMU master: added-mass ratio and Aitken-relaxed fixed point.

The FMU integrates its own body masses; A∞ that it cannot take as parameters must come back as the
force −A∞·a. Fed back explicitly (lagged by one step) that force multiplies an acceleration error by
−M⁻¹A∞ every step: stable only when the spectral radius of M⁻¹A∞ is below 1 — the added-mass
instability. Iterating the step to a fixed point (with rollback) removes the lag; Aitken's dynamic
relaxation makes the fixed-point iteration converge whatever the ratio.
"""

from __future__ import annotations

import numpy as np


def added_mass_ratio(mass: np.ndarray, added: np.ndarray) -> float:
    """Spectral radius of M⁻¹A: the per-step amplification of an explicitly fed-back −A·a."""
    if not added.size or not np.any(added):
        return 0.0
    return float(np.max(np.abs(np.linalg.eigvals(np.linalg.solve(mass, added)))))


class Aitken:
    """Aitken Δ² dynamic relaxation for the fixed point u = G(u), restarted every time step.

    ``update(u, g)`` takes an iterate and its image and returns the next iterate
    u + ω (g − u), ω from the last two residuals; the first ω of a step is the last one of the
    previous step (clipped to [omega_min, 1]), starting from ``omega0``."""

    def __init__(self, omega0: float = 0.5, omega_min: float = 0.01):
        self.omega = float(np.clip(omega0, omega_min, 1.0))
        self.omega_min = omega_min
        self._prev: np.ndarray | None = None

    def restart(self) -> None:
        self.omega = float(np.clip(abs(self.omega), self.omega_min, 1.0))
        self._prev = None

    def update(self, u: np.ndarray, g: np.ndarray) -> np.ndarray:
        r = g - u
        if self._prev is not None:
            dr = r - self._prev
            denom = float(dr @ dr)
            if denom > 0.0:
                self.omega = -self.omega * float(self._prev @ dr) / denom
        self._prev = r
        return u + self.omega * r
