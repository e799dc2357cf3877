"""The incident wave's elevation sum_c a_c cos(k_c s + psi_c) on the points of a moving hull for
many components at once, as real matrix products instead of one cosine per point and component
(issue 26; server/terms/nonlinear/term.py uses it).

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
is exact to round-off (tests/test_elevation_series.py holds it to the direct sums). Per step: the
Chebyshev values T_n(u) of the points (N recurrences over the points) and an (N, n_c) coefficient
matrix per heading; the elevation sum_c a_c cos(.) is then one matrix-vector product for the
series' coefficients and the series summed at the points (a product with the points' Chebyshev
values: the numpy path). The compiled path (server/terms/nonlinear/kernels.py) cuts [-rho, rho] into
equal bins, each with the series about its centre over its half-width (fewer orders per point,
the coefficients once per bin as two matrix products: :func:`_bins` picks their number),
Clenshaw's recurrence over each bin's points.

Its cost grows with k_max rho (N ~ k_max rho + 10): it pays for the elevation, one sum over the
components per point. The pressure, each component weighed by its depth factor at each point, is
server/terms/nonlinear/pressure_boxes.py's (power series in the complex height z + i s, by boxes) and the
recurrences' of server/terms/nonlinear/kernels.py.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from hydrolink.server.terms.nonlinear import kernels
from hydrolink.server.compiler import AVAILABLE
from hydrolink.server.terms.nonlinear.kernels import ElevationTable
from scipy.special import jv

__all__ = ["PhaseExpansion", "flatten"]

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


def _jacobi_anger(k: np.ndarray, radius: float) -> np.ndarray:
    """(N, n_c) complex: i^n eps_n J_n(k rho), N past the last order above the tail (module
    docstring). The terms below the tail are dropped here too: the long waves' high orders are
    subnormal numbers (J_n(x) ~ (x/2)^n / n!), which cost a hundred times a normal number's
    arithmetic in every product."""
    n = _orders(jv, float(k.max()) * radius)
    eps = np.where(np.arange(n) == 0, 1.0, 2.0)
    out = (1j ** np.arange(n) * eps)[:, None] * jv(np.arange(n)[:, None], k[None, :] * radius)
    out[np.abs(out) < _TAIL] = 0.0
    return out


def flatten(parts: list[np.ndarray], dtype=float) -> tuple[np.ndarray, np.ndarray]:
    """The arrays ``parts`` raveled one after the other, and where each starts (int64): the ragged
    tables of the compiled kernels (server/terms/nonlinear/kernels.py)."""
    sizes = [p.size for p in parts]
    flat = np.concatenate([np.ravel(p) for p in parts]).astype(dtype) if parts else np.zeros(0, dtype)
    return np.ascontiguousarray(flat), np.concatenate([[0], np.cumsum(sizes)[:-1]]).astype(np.int64) \
        if parts else np.zeros(0, np.int64)


@dataclass(frozen=True)
class _Bins:
    """The compiled path's expansion of one heading: [-rho, rho] along it cut into ``count`` equal
    bins, each with the series about its own centre over its own half-width rho / count (fewer
    orders per point; the coefficients once per bin). The order-n coefficient of a bin is
    Re(i^n eps_n sum_c J_n(k_c rho_b) X_c) = sum_c w_nc Re X_c (n even) or w_nc Im X_c (n odd),
    X_c the component's phasor at the bin's centre."""
    count: int
    orders: int          # N
    even: np.ndarray     # (n_g, ceil(N / 2)): w_{2m, c}, per component
    odd: np.ndarray      # (n_g, floor(N / 2)): w_{2m+1, c}
    shift: np.ndarray    # (count, n_g) complex: e^{i k s_j}, s_j the bin centres' offsets along the heading


@dataclass(frozen=True)
class _Heading:
    """The components of one heading and their expansion coefficients: over the whole radius for
    the numpy path, by bins (:class:`_Bins`) for the compiled one."""
    columns: np.ndarray        # (n_g,) component indices (by increasing k)
    direction: np.ndarray      # (2,) cos b, sin b
    k: np.ndarray              # (n_g,) wave numbers
    coefficients: np.ndarray | None   # (N, n_g) complex: i^n eps_n J_n(k rho) (numpy path)
    bins: _Bins | None                # (compiled path)


def _bins(k: np.ndarray, radius: float, points: int) -> _Bins:
    """The bin count, of 1 to 64, with the least work per evaluation at ``points`` points: the
    coefficients (a matrix product per heading, every component's weights to the bins' highest
    order: measured 0.12 ns a multiply-add) plus the points' orders (Clenshaw, 0.4 ns a point and
    order). The orders of J_n(x) above the tail, tabulated over x, give the bins' highest."""
    x = np.linspace(0.0, float(k.max()) * radius, 129)
    table = np.array([_orders(jv, v) for v in x])          # orders at x, growing with x

    def cost(count: int) -> float:
        orders = int(table[min(int(np.searchsorted(x, float(k.max()) * radius / count)), len(x) - 1)])
        return 0.3 * count * len(k) * orders + points * orders

    count = min(range(1, 65), key=cost)
    coefficients = _jacobi_anger(k, radius / count)
    weight = np.where((np.arange(len(coefficients)) % 2 == 0)[:, None], coefficients.real, -coefficients.imag)
    centres = radius * (-1.0 + (2.0 * np.arange(count) + 1.0) / count)
    return _Bins(count, len(weight), np.ascontiguousarray(weight[0::2].T), np.ascontiguousarray(weight[1::2].T),
                 np.exp(1j * np.outer(centres, k)))


class PhaseExpansion:
    """The incident wave's elevation at points within ``radius`` of a reference point (module
    docstring)."""

    def __init__(self, k: np.ndarray, heading: np.ndarray, radius: float, compiled: bool = AVAILABLE,
                 points: int = 1000):
        """``compiled``: sum the series by bins with the compiled kernels (server/terms/nonlinear/kernels.py,
        the bins chosen for ``points`` points per evaluation), else over the whole radius as a
        matrix product of the points' Chebyshev values."""
        self.compiled = compiled
        self.radius = float(radius) * (1.0 + 1e-12) or 1.0
        self.k = np.asarray(k, float)
        self.n_components = len(k)
        groups = []
        for b in np.unique(heading):
            cols = np.flatnonzero(heading == b)
            cols = cols[np.argsort(self.k[cols], kind="stable")]
            kg = self.k[cols]
            groups.append(_Heading(cols, np.array([np.cos(b), np.sin(b)]), kg,
                                   None if compiled else _jacobi_anger(kg, self.radius),
                                   _bins(kg, self.radius, points) if compiled else None))
        self.groups = tuple(groups)
        self.table = self._table() if compiled else None   # the compiled kernels' form of the bins

    def elevation(self, offsets: np.ndarray, reference: np.ndarray, psi: np.ndarray,
                  amplitude: np.ndarray) -> np.ndarray:
        """(P,): sum_c a_c cos(k_c s + psi_c) at points whose horizontal offsets from the reference
        point are ``offsets`` (P, 2) (|offset| <= radius), the reference point at ``reference`` (2,),
        the components' amplitudes ``amplitude`` and phases ``psi`` (n_c,) (phi_c - w_c t)."""
        if self.table is not None:
            phasor = np.empty(self.n_components, complex)
            for g in self.groups:
                phasor[g.columns] = amplitude[g.columns] * np.exp(1j * (g.k * float(reference @ g.direction)
                                                                        + psi[g.columns]))
            return kernels.elevation(self.table, phasor, offsets)
        out = np.zeros(len(offsets))
        for g in self.groups:
            u = np.clip(offsets @ g.direction / self.radius, -1.0, 1.0)
            turn = amplitude[g.columns] * np.exp(1j * (g.k * float(reference @ g.direction) + psi[g.columns]))
            c = np.real(g.coefficients @ turn)                   # (N,): the series' coefficients now
            out += _chebyshev(u, len(c)).T @ c
        return out

    def _table(self) -> ElevationTable:
        """The compiled path's bins as one flat table (server/terms/nonlinear/kernels.py)."""
        bins = [g.bins for g in self.groups]
        weights, weight_start = flatten([np.concatenate([b.even.ravel(), b.odd.ravel()]) for b in bins])
        shift_re, shift_start = flatten([b.shift.real for b in bins])
        shift_im, _ = flatten([b.shift.imag for b in bins])
        return ElevationTable(
            direction=np.array([g.direction for g in self.groups]).reshape(-1, 2),
            start=np.cumsum([0] + [len(g.columns) for g in self.groups]).astype(np.int64),
            columns=flatten([g.columns for g in self.groups], np.int64)[0],
            bins=np.array([b.count for b in bins], np.int64), orders=np.array([b.orders for b in bins], np.int64),
            weights=weights, weight_start=weight_start, shift_re=shift_re, shift_im=shift_im,
            shift_start=shift_start, radius=self.radius)
