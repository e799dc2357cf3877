"""The incident wave's elevation sum_c a_c cos(k_c s + psi_c) on the points of a moving hull for
many components at once, as real matrix products instead of one cosine per point and component
(issue 26; server/nonlinear_hydro.py uses it).

For a component of wave number k along the heading (cos b, sin b), the spatial phase at a point is
k s with s = (x, y).(cos b, sin b) = s_ref + rho u: s_ref that of the body's reference point and
u in [-1, 1] the point's offset from it along the heading divided by ``rho``, a radius bounding
every offset of the hull (fixed in the body's frame, so any pose keeps |u| <= 1). The
Jacobi–Anger expansion e^{i z cos t} = sum_n i^n eps_n J_n(z) cos(n t) (eps_0 = 1, eps_n = 2),
with cos t = u and cos(n t) = T_n(u) the Chebyshev polynomials, gives

    cos(k s + psi) = Re( e^{i (k s_ref + psi)} sum_{n < N} i^n eps_n J_n(k rho) T_n(u) ) + tail,

the tail bounded by sum_{n >= N} 2 |J_n(k rho)|. J_n(x) falls faster than geometrically once
n > x; N is the smallest order with |J_n(k_max rho)| <= 1e-17 for every n >= N (and J_n(x) grows
with x for x < n, so every component of the group is bounded by its largest), so the expansion
is exact to round-off (tests/test_phase_expansion.py holds it to the direct sums). Per step: the
Chebyshev values T_n(u) of the points (N recurrences over the points) and an (N, n_c) coefficient
matrix per heading; the elevation sum_c a_c cos(.) is then one matrix-vector product for the
series' coefficients and the series summed at the points (Clenshaw's recurrence, compiled, or a
product with the points' Chebyshev values).

Its cost grows with k_max rho (N ~ k_max rho + 10): it pays for the elevation, which needs one
sum over the components per point, not for a sum weighted per point and component (the
pressure's depth factor), where the direct cosines are cheaper when N is large.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.special import jv

from hydrolink.server.incident_kernels import AVAILABLE, chebyshev_sum

__all__ = ["PhaseExpansion"]

_TAIL = 1e-17   # coefficient magnitude below which the expansions' terms are dropped


def _chebyshev(u: np.ndarray, n: int) -> np.ndarray:
    """(n, P): T_m(u) for m < n at points u (P,) in [-1, 1] (three-term recurrence)."""
    out = np.empty((n, len(u)))
    out[0] = 1.0
    if n > 1:
        out[1] = u
    for m in range(2, n):
        np.multiply(2.0 * u, out[m - 1], out=out[m])
        out[m] -= out[m - 2]
    return out


def _orders(coefficient, x_max: float) -> int:
    """The number of terms: past the last order whose ``coefficient(m, x_max)`` exceeds the tail."""
    m = np.arange(int(x_max + 20.0 * x_max ** (1.0 / 3.0)) + 60)
    big = np.flatnonzero(np.abs(coefficient(m, x_max)) > _TAIL)
    return int(big[-1]) + 1 if len(big) else 1


@dataclass(frozen=True)
class _Heading:
    """The components of one heading and their expansion coefficients."""
    columns: np.ndarray        # (n_g,) component indices
    direction: np.ndarray      # (2,) cos b, sin b
    k: np.ndarray              # (n_g,) wave numbers
    coefficients: np.ndarray   # (N, n_g) complex: i^n eps_n J_n(k rho)


class PhaseExpansion:
    """The incident wave's elevation at points within ``radius`` of a reference point (module
    docstring)."""

    def __init__(self, k: np.ndarray, heading: np.ndarray, radius: float, compiled: bool = AVAILABLE):
        """``compiled``: sum the series with the compiled kernel (server/incident_kernels.py), else
        as a matrix product of the points' Chebyshev values."""
        self.compiled = compiled
        self.radius = float(radius) * (1.0 + 1e-12) or 1.0
        self.k = np.asarray(k, float)
        self.n_components = len(k)
        groups = []
        for b in np.unique(heading):
            cols = np.flatnonzero(heading == b)
            kg = self.k[cols]
            n = _orders(jv, float(kg.max()) * self.radius)
            n_eps = np.where(np.arange(n) == 0, 1.0, 2.0)
            coef = (1j ** np.arange(n) * n_eps)[:, None] * jv(np.arange(n)[:, None], kg[None, :] * self.radius)
            # the terms below the truncation's tail dropped here too: the long waves' high orders
            # are subnormal numbers (J_n(x) ~ (x/2)^n / n!), which cost a hundred times a normal
            # number's arithmetic in every product
            coef[np.abs(coef) < _TAIL] = 0.0
            groups.append(_Heading(cols, np.array([np.cos(b), np.sin(b)]), kg, coef))
        self.groups = tuple(groups)

    def elevation(self, offsets: np.ndarray, reference: np.ndarray, psi: np.ndarray,
                  amplitude: np.ndarray) -> np.ndarray:
        """(P,): sum_c a_c cos(k_c s + psi_c) at points whose horizontal offsets from the reference
        point are ``offsets`` (P, 2) (|offset| <= radius), the reference point at ``reference`` (2,),
        the components' amplitudes ``amplitude`` and phases ``psi`` (n_c,) (phi_c - w_c t)."""
        out = np.zeros(len(offsets))
        for g in self.groups:
            u = np.clip(offsets @ g.direction / self.radius, -1.0, 1.0)
            turn = amplitude[g.columns] * np.exp(1j * (g.k * float(reference @ g.direction) + psi[g.columns]))
            c = np.real(g.coefficients @ turn)                   # (N,): the series' coefficients now
            if self.compiled:
                chebyshev_sum(u, c, out)
            else:
                out += _chebyshev(u, len(c)).T @ c
        return out
