"""The incident wave's pressure at a hull's points as power series in the complex height, by boxes
(issue 26; summed by the compiled pass of server/terms/nonlinear/kernels.py, server/terms/nonlinear/term.py
chooses which components it takes).

A component of wave number k along the heading (cos b, sin b), phasor X at the body's reference
point, has at a point with offset s along the heading and (stretched) height z in [-h, 0] the
pressure per unit rho g

    Re X f(z) e^{iks},   f(z) = cosh(k (z + h)) / cosh(k h) = D (e^{kz} + e^{-2kh} e^{-kz}),
    D = 1 / (1 + e^{-2kh})        (deep water: f = e^{kz}, D = 1),

so X f(z) e^{iks} = X D e^{kw} + X D e^{-2kh} e^{kw'} with w = z + is and w' = -z + is: each an
entire function of one complex variable. About the centre w_b = z_b + i s_b of a box of the
(s, z) plane, with zeta = (w - w_b) / rho (rho the box's half-diagonal: |zeta| <= 1 in it) and
w' - w'_b = -rho conj(zeta),

    e^{kw} = e^{kw_b} sum_n (k rho)^n / n! zeta^n,   e^{kw'} = e^{kw'_b} sum_n (k rho)^n / n! (-1)^n conj(zeta)^n,

and as Re(A (-1)^n conj(zeta^n)) = (-1)^n Re(conj(A) zeta^n), a box's pressure from all its
components is one series in zeta:

    p = Re sum_{n < N} B_n zeta^n,   B_n = sum_c m_cn (P_c + (-1)^n conj(Q_c)),   m_cn = (k_c rho)^n / n!,
    P_c = X_c D_c e^{k_c w_b},   Q_c = X_c D_c e^{-2 k_c h} e^{k_c w'_b}.

The factors of X_c are fixed (tabulated here per box); per step the occupied boxes' B by four
real matrix products and Horner's scheme at each point. In a row of boxes of centre height z_b, N
is the least order whose remainder bound, sum_c a_c D_c (e^{k_c z_b} + e^{-k_c (2h + z_b)})
(k_c rho)^N / N! e^{k_c rho}, is at most 2^-53 of the sea's amplitude sum (deeper rows need fewer:
their short waves are weaker): exact to round-off, like the recurrences and direct sums it stands
for, in any depth, for any k. Its cost, boxes x components x N + points x N, is low while k rho
is: :func:`layout` picks the box size that makes it least for a hull's points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from hydrolink.server.terms.nonlinear.kernels import BoxTable
from hydrolink.server.terms.nonlinear.elevation_series import flatten
from scipy.special import gammaln

__all__ = ["BoxGroup", "box_table", "layout"]

_ROUND = 2.0 ** -53
_MAX_ORDERS = 96      # a layout needing more is not considered
# Measured costs [ns] of the compiled kernel's pieces (server/terms/nonlinear/kernels_numba.py's box_sum on the
# bench's sphere hulls, 25-300 components, 1-14 columns of boxes; fitted, this 2-vCPU VM):
_BOX_COMPONENT = 21.0     # a component in an occupied box (its phasor times the box's factors, ...)
_BOX_PRODUCT = 0.13       # a component's order in an occupied box (the matrix products)
_POINT_ORDER = 0.6        # a point's order in Horner's scheme
_POINT = 14.0             # a point's box and place in the sort


@dataclass(frozen=True)
class BoxGroup:
    """One heading's components summed by boxes: the (s, z) region [-radius, radius] x [floor, 0]
    cut into ``n_s`` columns and as many rows of near-square boxes as ``row_orders`` has, its terms
    of the series in each row (from the floor up: the deeper rows need fewer, their short waves
    being weaker)."""
    columns: np.ndarray     # (n_g,) component indices, by increasing k (the seabed term only the first ones')
    direction: np.ndarray   # (2,) cos b, sin b
    n_s: int
    row_orders: np.ndarray  # (n_z,) int64, n_z the rows of _grid(n_s, ...)


def _grid(n_s: int, radius: float, floor: float) -> tuple[int, float, float, float]:
    """(n_z, side_s, side_z, rho) of near-square boxes with ``n_s`` columns over [-radius, radius]."""
    side_s = 2.0 * radius / n_s
    n_z = max(1, int(round(-floor / side_s)))
    side_z = -floor / n_z
    return n_z, side_s, side_z, 0.5 * math.hypot(side_s, side_z)


def _seabed(k: np.ndarray, depth: float) -> np.ndarray:
    """D = 1 / (1 + e^{-2kh}), the depth factor's normalisation (1 in deep water)."""
    return np.ones_like(k) if math.isinf(depth) else 1.0 / (1.0 + np.exp(-2.0 * k * depth))


def row_orders(k: np.ndarray, amplitude: np.ndarray, depth: float, n_s: int, radius: float, floor: float,
               total: float) -> np.ndarray:
    """(n_z,) each row's orders: the least N whose remainder bound, sum_c a_c D_c (e^{k_c z_b} +
    e^{-k_c (2h + z_b)}) (k_c rho)^N / N! e^{k_c rho} (z_b the row's centre), is at most 2^-53 of
    the sea's amplitude sum ``total`` (more than _MAX_ORDERS where none up to it is)."""
    n_z, _, side_z, rho = _grid(n_s, radius, floor)
    z_b = floor + (np.arange(n_z) + 0.5) * side_z
    d = _seabed(k, depth)
    weight = amplitude * d * np.exp(np.outer(z_b, k))                    # (n_z, n_c)
    if not math.isinf(depth):
        weight += amplitude * d * np.exp(-np.outer(2.0 * depth + z_b, k))
    x = np.maximum(k * rho, 1e-300)
    n = np.arange(1, _MAX_ORDERS + 1)
    with np.errstate(under="ignore"):      # (n_c, N), held below overflow (a bound that large fails anyway)
        tail = np.exp(np.minimum(np.outer(np.log(x), n) - gammaln(n + 1.0)[None, :] + x[:, None], 700.0))
    fits = weight @ tail <= _ROUND * total
    return np.where(fits.any(axis=1), n[np.argmax(fits, axis=1)], _MAX_ORDERS + 1).astype(np.int64)


def layout(k: np.ndarray, amplitude: np.ndarray, depth: float, radius: float, floor: float, points: np.ndarray,
           total: float) -> tuple[int, np.ndarray, float]:
    """(n_s, row orders, cost [ns]) of the least costly box grid for components of wave numbers
    ``k`` and amplitudes ``amplitude`` at ``points`` (P, 2), their (s, z) (the hull at rest, to
    count the occupied boxes, a third more for its motion); ``total`` the sea's amplitude sum.
    The cost is infinite where no grid is feasible."""
    best = (1, np.zeros(0, np.int64), math.inf)
    for n_s in (1, 2, 3, 4, 5, 6, 7, 8, 10, 12, 14, 17, 20, 24, 28, 34, 40):
        rows = row_orders(k, amplitude, depth, n_s, radius, floor, total)
        if rows.max() > _MAX_ORDERS:
            continue
        n_z, side_s, side_z, _ = _grid(n_s, radius, floor)
        i = np.clip(((points[:, 0] + radius) / side_s).astype(int), 0, n_s - 1)
        j = np.clip(((points[:, 1] - floor) / side_z).astype(int), 0, n_z - 1)
        occupied = np.unique(j * n_s + i) // n_s           # the occupied boxes' rows
        cost = 1.33 * len(k) * (_BOX_COMPONENT * len(occupied) + _BOX_PRODUCT * rows[occupied].sum()) \
            + _POINT * len(points) + _POINT_ORDER * rows[j].sum()
        if cost < best[2]:
            best = (n_s, rows, cost)
    return best


def box_table(groups: list[BoxGroup], k: np.ndarray, depth: float, radius: float, floor: float) -> BoxTable:
    """The groups as the compiled pass's flat table (``k`` of all the components)."""
    weights, factors, mirrors, flags, rows = [], [], [], [], []
    for g in groups:
        n_z, side_s, side_z, rho = _grid(g.n_s, radius, floor)
        kg = k[g.columns]
        row = np.asarray(g.row_orders, np.int64)
        n = np.arange(int(row.max()))
        with np.errstate(divide="ignore", under="ignore"):
            m = np.exp(n[None, :] * np.log(kg[:, None] * rho) - gammaln(n + 1.0)[None, :])     # (n_g, N)
        m[:, 0] = 1.0
        m[m < 1e-200] = 0.0      # no subnormal numbers in the products (each far below round-off)
        weights.append(np.concatenate([m[:, 0::2].T.ravel(), m[:, 1::2].T.ravel()]))
        rows.append(row)
        s_b = -radius + (np.arange(g.n_s) + 0.5) * side_s
        z_b = floor + (np.arange(n_z) + 0.5) * side_z
        s_box, z_box = np.tile(s_b, n_z), np.repeat(z_b, g.n_s)          # box q = j n_s + i
        d = _seabed(kg, depth)
        turn = np.exp(1j * np.outer(s_box, kg))
        factors.append((d * np.exp(np.outer(z_box, kg)) * turn).T)         # (n_g, boxes): a component's row
        near = np.zeros(len(kg), bool) if math.isinf(depth) else 2.0 * kg * (depth + floor) < 40.0
        n_m = int(np.flatnonzero(near)[-1]) + 1 if near.any() else 0     # the seabed term to round-off: a prefix by k
        mirrors.append((d[:n_m] * np.exp(-np.outer(2.0 * depth + z_box, kg[:n_m])) * turn[:, :n_m]).T)
        flags.append(n_m)
    w, w_start = flatten(weights)
    f_re, f_start = flatten([f.real for f in factors])
    m_re, m_start = flatten([q.real for q in mirrors])
    row_flat, row_start = flatten(rows, np.int64)
    return BoxTable(
        direction=np.array([g.direction for g in groups], float).reshape(-1, 2),
        start=np.cumsum([0] + [len(g.columns) for g in groups]).astype(np.int64),
        columns=flatten([g.columns for g in groups], np.int64)[0],
        grid=np.array([[g.n_s, _grid(g.n_s, radius, floor)[0]] for g in groups], np.int64).reshape(-1, 2),
        orders=np.array([int(r.max()) for r in rows], np.int64), row_orders=row_flat, row_start=row_start,
        weights=w, weight_start=w_start, factor_re=f_re, factor_im=flatten([f.imag for f in factors])[0],
        factor_start=f_start, mirror_re=m_re, mirror_im=flatten([q.imag for q in mirrors])[0], mirror_start=m_start,
        mirror=np.array(flags, np.int64), radius=float(radius), floor=float(floor))
