"""The incident wave's pressure at a hull's points as power series in the complex height, by boxes
(issue 26; summed by the compiled pass of server/incident_kernels.py, server/nonlinear_hydro.py
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
real matrix products and Horner's scheme at each point. N is the least order whose remainder
bound, sum_c a_c D_c (e^{k_c z_top} + e^{-k_c (2h + z_low)}) (k_c rho)^N / N! e^{k_c rho} (z_top,
z_low the highest and lowest boxes' centres), is at most 2^-53 of the sea's amplitude sum: exact
to round-off, like the recurrences and direct sums it stands for, in any depth, for any k. Its
cost, boxes x components x N + points x N, is low while k rho is: :func:`layout` picks the box size
that makes it least for a hull's points.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from hydrolink.server.incident_kernels import BoxTable
from hydrolink.server.phase_expansion import flatten
from scipy.special import gammaln

__all__ = ["BoxGroup", "box_table", "layout"]

_ROUND = 2.0 ** -53
_MAX_ORDERS = 96      # a layout needing more is not considered
# Measured costs [ns] of the compiled kernel's pieces (server/incident_numba.py, this 2-vCPU VM):
_BOX_COMPONENT = 3.0      # a component's phasor times its box factors, per occupied box
_BOX_PRODUCT = 0.25       # a component's order in the box's matrix products
_POINT_ORDER = 0.6        # a point's order in Horner's scheme
_POINT = 10.0             # a point's box and place in the sort


@dataclass(frozen=True)
class BoxGroup:
    """One heading's components summed by boxes: the (s, z) region [-radius, radius] x [floor, 0]
    cut into ``n_s`` x ``n_z`` equal boxes, ``orders`` terms of the series in each."""
    columns: np.ndarray     # (n_g,) component indices
    direction: np.ndarray   # (2,) cos b, sin b
    n_s: int
    n_z: int
    orders: int


def _orders(k: np.ndarray, weight: np.ndarray, rho: float, tol: float) -> int:
    """The least N <= _MAX_ORDERS with sum_c weight_c (k_c rho)^N / N! e^{k_c rho} <= tol (else
    _MAX_ORDERS + 1)."""
    x = k * rho
    keep = (weight > 0.0) & (x > 0.0)
    if not keep.any():
        return 1
    x, lw = x[keep], np.log(weight[keep]) + x[keep]
    lx = np.log(x)
    for n in range(1, _MAX_ORDERS + 1):
        if np.exp(lw + n * lx - gammaln(n + 1.0)).sum() <= tol:
            return n
    return _MAX_ORDERS + 1


def _grid(n_s: int, radius: float, floor: float) -> tuple[int, float, float, float]:
    """(n_z, side_s, side_z, rho) of near-square boxes with ``n_s`` columns over [-radius, radius]."""
    side_s = 2.0 * radius / n_s
    n_z = max(1, int(round(-floor / side_s)))
    side_z = -floor / n_z
    return n_z, side_s, side_z, 0.5 * math.hypot(side_s, side_z)


def _weights(k: np.ndarray, amplitude: np.ndarray, depth: float, z_top: float, z_low: float) -> np.ndarray:
    """Each component's a_c D_c (e^{k z_top} + e^{-k (2h + z_low)}): the bound of its P and Q."""
    if math.isinf(depth):
        return amplitude * np.exp(k * z_top)
    d = 1.0 / (1.0 + np.exp(-2.0 * k * depth))
    return amplitude * d * (np.exp(k * z_top) + np.exp(-k * (2.0 * depth + z_low)))


def layout(k: np.ndarray, amplitude: np.ndarray, depth: float, radius: float, floor: float, points: np.ndarray,
           total: float) -> tuple[int, int, int, float]:
    """(n_s, n_z, orders, cost [ns]) of the least costly box grid for components of wave numbers
    ``k`` and amplitudes ``amplitude`` at ``points`` (P, 2), their (s, z) (the hull at rest, to
    count the occupied boxes, a third more for its motion); ``total`` the sea's amplitude sum."""
    best = (1, 1, _MAX_ORDERS + 1, math.inf)
    for n_s in range(1, 41):
        n_z, side_s, side_z, rho = _grid(n_s, radius, floor)
        n_o = _orders(k, _weights(k, amplitude, depth, floor + (n_z - 0.5) * side_z, floor + 0.5 * side_z), rho,
                      _ROUND * total)
        if n_o > _MAX_ORDERS:
            continue
        i = np.clip(((points[:, 0] + radius) / side_s).astype(int), 0, n_s - 1)
        j = np.clip(((points[:, 1] - floor) / side_z).astype(int), 0, n_z - 1)
        boxes = 1.33 * len(np.unique(i * n_z + j))
        cost = boxes * len(k) * (_BOX_COMPONENT + _BOX_PRODUCT * n_o) + len(points) * (_POINT + _POINT_ORDER * n_o)
        if cost < best[3]:
            best = (n_s, n_z, n_o, cost)
    return best


def box_table(groups: list[BoxGroup], k: np.ndarray, depth: float, radius: float, floor: float) -> BoxTable:
    """The groups as the compiled pass's flat table (``k`` of all the components)."""
    weights, factors, mirrors, flags = [], [], [], []
    for g in groups:
        n_z, side_s, side_z, rho = _grid(g.n_s, radius, floor)
        kg = k[g.columns]
        n = np.arange(g.orders)
        with np.errstate(divide="ignore", under="ignore"):
            m = np.exp(n[None, :] * np.log(kg[:, None] * rho) - gammaln(n + 1.0)[None, :])     # (n_g, N)
        m[:, 0] = 1.0
        m[m < 1e-200] = 0.0      # no subnormal numbers in the products (each far below round-off)
        weights.append(np.concatenate([m[:, 0::2].ravel(), m[:, 1::2].ravel()]))
        s_b = -radius + (np.arange(g.n_s) + 0.5) * side_s
        z_b = floor + (np.arange(n_z) + 0.5) * side_z
        s_box, z_box = np.repeat(s_b, n_z), np.tile(z_b, g.n_s)          # box q = i n_z + j
        d = np.ones_like(kg) if math.isinf(depth) else 1.0 / (1.0 + np.exp(-2.0 * kg * depth))
        turn = np.exp(1j * np.outer(s_box, kg))
        factors.append(d * np.exp(np.outer(z_box, kg)) * turn)
        mirror = not math.isinf(depth) and bool(np.any(2.0 * kg * (depth + floor) < 40.0))
        mirrors.append(d * np.exp(-np.outer(2.0 * depth + z_box, kg)) * turn if mirror else np.zeros_like(turn))
        flags.append(int(mirror))
    w, w_start = flatten(weights)
    f_re, f_start = flatten([f.real for f in factors])
    return BoxTable(
        direction=np.array([g.direction for g in groups], float).reshape(-1, 2),
        start=np.cumsum([0] + [len(g.columns) for g in groups]).astype(np.int64),
        columns=flatten([g.columns for g in groups], np.int64)[0],
        grid=np.array([[g.n_s, _grid(g.n_s, radius, floor)[0]] for g in groups], np.int64).reshape(-1, 2),
        orders=np.array([g.orders for g in groups], np.int64), weights=w, weight_start=w_start,
        factor_re=f_re, factor_im=flatten([f.imag for f in factors])[0], mirror_re=flatten([q.real for q in mirrors])[0],
        mirror_im=flatten([q.imag for q in mirrors])[0], factor_start=f_start, mirror=np.array(flags, np.int64),
        radius=float(radius), floor=float(floor))
