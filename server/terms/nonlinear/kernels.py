"""Compiled kernels for the incident wave on a hull's points (issue 26; numba, optional).

The kernels themselves are in server/kernels_numba.py, imported (and numba with it) on first
use; this module holds what the callers need without numba: whether it is there, the kernels'
typed tables and thin wrappers.

- :class:`HullPass`: one Froude–Krylov body's whole step in one compiled pass (no Python between
  the pieces): the pose's rotation, each component's phasor at the reference point, the vertices'
  heights, the elevation (the Jacobi–Anger series of server/terms/nonlinear/elevation_series.py by bins), the wet
  vertices, sorted from the surface down, their Wheeler-stretched heights, the pressure there (the
  short waves by :func:`deep_pressure`'s recurrence, the longer ones and those of any depth by the
  boxes' power series of server/terms/nonlinear/pressure_boxes.py, any others one by one) and its integral over the
  cut hull (server/terms/nonlinear/hull_kernel.py).
- :func:`deep_pressure`: sum_c Re(a_c e^{k_c (z_p + i xi_p)}) for components whose wave numbers
  are a quadratic in their index, k_c = k0 + c dk + c (c - 1) d2 / 2 (deep water, frequencies
  equally spaced: k = w^2 / g). Then e^{k_{c+1} zeta} = e^{k_c zeta} r_c with r_{c+1} = r_c q, q
  = e^{d2 zeta}: two complex products per point and component, three complex exponentials per
  point. A block of points stops where the remaining components add at most 2^-53 of the
  amplitude sum at its highest point. The products' round-off grows with c; over 300 components it
  stays below 1e-12 of the amplitude sum (tests/test_nonlinear_kernels.py).
- :func:`elevation` and :func:`box_pressure`: those two parts of the pass alone (the expansions'
  own uses and tests); :func:`chebyshev_sum` (Clenshaw, the elevation's sum with one bin) a
  building block.

Where numba is not installed (``compiler.AVAILABLE``) or does not import (``compiler.imports()``,
server/compiler.py) the callers take their numpy paths (the same sums as matrix products; slower, same results
to round-off).
"""

from __future__ import annotations

import functools
import math
from typing import Callable, NamedTuple

import numpy as np
from hydrolink.server.terms.nonlinear.rows import BodyConstants

__all__ = ["BoxTable", "ElevationTable", "HullPass", "HullTables", "RecurrenceTable", "box_pressure",
           "chebyshev_sum", "deep_pressure", "elevation", "reply_rows", "warm_up"]

class ElevationTable(NamedTuple):
    """The incident wave's elevation for :class:`HullPass`: per heading g (of G), its components'
    Jacobi–Anger series by bins (server/terms/nonlinear/elevation_series.py), the ragged parts flattened."""
    direction: np.ndarray      # (G, 2) cos b, sin b
    start: np.ndarray          # (G + 1,) int64: heading g's components are columns[start[g]:start[g + 1]] (by k)
    columns: np.ndarray        # (n_c,) int64
    bins: np.ndarray           # (G,) int64: bin count
    orders: np.ndarray         # (G,) int64: N, the series' orders per bin
    weights: np.ndarray        # from weight_start[g]: the (n_g, ceil(N/2)) even-order weights, then the odd ones
    weight_start: np.ndarray   # (G,) int64
    shift_re: np.ndarray       # from shift_start[g]: (bins, n_g) e^{i k s_j} of the bins' centres
    shift_im: np.ndarray
    shift_start: np.ndarray    # (G,) int64
    radius: float              # m: the expansion's half-width (every vertex's horizontal offset within it)


class RecurrenceTable(NamedTuple):
    """The short waves' pressure for :class:`HullPass`: per run g of evenly spaced deep-water
    components of one heading, k_c = k0 + c dk + c (c - 1) d2 / 2 (server/terms/nonlinear/term.py)."""
    direction: np.ndarray      # (R, 2)
    start: np.ndarray          # (R + 1,) int64 into columns
    columns: np.ndarray        # int64, by increasing frequency within each run
    tail: np.ndarray           # as columns: sum of |a| over the run's components from each on (for deep_pressure's stop)
    k0: np.ndarray             # (R,) 1/m
    dk: np.ndarray             # (R,)
    d2: np.ndarray             # (R,)
    floor: float               # m: the lowest stretched height the split into short and long waves holds for


class BoxTable(NamedTuple):
    """The pressure of the components summed by boxes (server/terms/nonlinear/pressure_boxes.py) for
    :class:`HullPass`, per heading g (of B): the (s, z) region [-radius, radius] x [floor, 0] cut
    into n_s x n_z boxes (box q = j n_s + i: row j from the floor up, column i along the heading),
    up to N orders of the series in each, N_j in row j."""
    direction: np.ndarray      # (B, 2)
    start: np.ndarray          # (B + 1,) int64 into columns
    columns: np.ndarray        # int64
    grid: np.ndarray           # (B, 2) int64: n_s, n_z
    orders: np.ndarray         # (B,) int64: N, the most of any row
    row_orders: np.ndarray     # from row_start[g]: (n_z,) int64 N_j
    row_start: np.ndarray      # (B,) int64
    weights: np.ndarray        # from weight_start[g]: (ceil(N/2), n_g) m_cn of the even orders, then (floor(N/2), n_g) odd
    weight_start: np.ndarray   # (B,) int64
    factor_re: np.ndarray      # from factor_start[g]: (n_g, n_s n_z) D_c e^{k_c w_b} of each box
    factor_im: np.ndarray
    factor_start: np.ndarray   # (B,) int64
    mirror_re: np.ndarray      # from mirror_start[g]: (n_m, n_s n_z) D_c e^{-2 k_c h} e^{k_c w'_b} of the first n_m components
    mirror_im: np.ndarray
    mirror_start: np.ndarray   # (B,) int64
    mirror: np.ndarray         # (B,) int64: n_m, the components (by increasing k) whose seabed term reaches round-off
    radius: float              # m
    floor: float               # m


@functools.cache
def _compiled():
    """The kernels' module (server/terms/nonlinear/kernels_numba.py), compiled or loaded from numba's cache on
    first use: numba is imported only by a scene that needs it (its import costs about half a
    second)."""
    from hydrolink.server.terms.nonlinear import kernels_numba
    return kernels_numba


def deep_pressure(xi: np.ndarray, z: np.ndarray, a: np.ndarray, k0: float, dk: float, d2: float,
                  out: np.ndarray) -> None:
    """Adds sum_c Re(a_c e^{k_c (z + i xi)}) to ``out`` (P,), k_c = k0 + c dk + c (c - 1) d2 / 2,
    at points with horizontal coordinates ``xi`` (P,) along the heading and heights ``z`` (P,)
    <= 0, for the complex amplitudes ``a`` (n_c,) (module docstring)."""
    tail = np.ascontiguousarray(np.cumsum(np.abs(a)[::-1])[::-1])
    _compiled().deep_pressure(np.ascontiguousarray(xi, float), np.ascontiguousarray(z, float),
                              np.ascontiguousarray(a.real), np.ascontiguousarray(a.imag), tail, float(k0), float(dk),
                              float(d2), out)


def chebyshev_sum(u: np.ndarray, c: np.ndarray, out: np.ndarray) -> None:
    """Adds sum_n c_n T_n(u) to ``out`` (P,) at points ``u`` (P,) in [-1, 1] (Clenshaw; the
    elevation's kernel with one bin)."""
    if c.size:
        _compiled().binned_chebyshev_sum(np.ascontiguousarray(u, float), np.ascontiguousarray(c[None, :], float), out)


def elevation(table: ElevationTable, phasor: np.ndarray, offsets: np.ndarray) -> np.ndarray:
    """(P,): the elevation sum_c Re(X_c e^{i k_c (offset . (cos b_c, sin b_c))}) at points with
    horizontal ``offsets`` (P, 2) from the reference point, the components' phasors there
    ``phasor`` X (n_c,) (the pass :class:`HullPass` runs)."""
    out, u = np.zeros(len(offsets)), np.empty(len(offsets))
    off = np.ascontiguousarray(offsets, float)
    _compiled().elevation_sum(table, np.ascontiguousarray(phasor.real), np.ascontiguousarray(phasor.imag),
                              np.ascontiguousarray(off[:, 0]), np.ascontiguousarray(off[:, 1]), u, out)
    return out


def box_pressure(table: BoxTable, phasor: np.ndarray, offsets: np.ndarray, z: np.ndarray) -> np.ndarray:
    """(P,): the pressure per unit rho g of the table's components, sum_c Re(X_c e^{i k_c (offset .
    (cos b_c, sin b_c))}) f_c(z), at points with horizontal ``offsets`` (P, 2) from the reference
    point and (stretched) heights ``z`` (P,) in [floor, 0], by the boxes' series (as
    :class:`HullPass` sums them); ``phasor`` X (n_c,) of all the components."""
    out = np.zeros(len(z))
    off = np.ascontiguousarray(offsets, float)
    _compiled().box_sum(table, np.ascontiguousarray(phasor.real), np.ascontiguousarray(phasor.imag),
                        np.ascontiguousarray(off[:, 0]), np.ascontiguousarray(off[:, 1]),
                        np.ascontiguousarray(z, float), out)
    return out


class HullTables(NamedTuple):
    """What :class:`HullPass` needs of the sea beyond the hull: how each component's pressure is
    summed (the split of server/terms/nonlinear/term.py) and the elevation's series."""
    elevation: ElevationTable
    recurrences: RecurrenceTable
    boxes: BoxTable
    direct: np.ndarray           # int64: the components summed one by one (neither a recurrence nor the series)
    direct_direction: np.ndarray   # (n, 2) their headings' cos b, sin b
    heading: np.ndarray          # (n_c, 2) every component's cos b, sin b


class HullPass:
    """One Froude–Krylov body's step in one compiled pass (the kernel ``hull_step`` of
    server/kernels_numba.py), with what does not change between steps made once: the hull
    (``local`` (V, 3) vertices about the reference point, ``triangles``, their corner ``loads`` and
    ``vertex_loads``, server/terms/nonlinear/hull_kernel.py), the components' ``omega``, complex
    ``amplitude`` a_c e^{i phi_c} and wave numbers ``k``, the water ``depth``, the ``tables``,
    ``fk_linear`` (6, n_c) complex, the ``body``'s constants of its reply rows, and the buffers the
    kernel writes. The fixed inputs are handed to the compiled code once (a ``HullState``): a step
    passes the pose, time and ramp."""

    def __init__(self, local: np.ndarray, triangles: np.ndarray, loads: np.ndarray, vertex_loads: np.ndarray,
                 omega: np.ndarray, amplitude: np.ndarray, k: np.ndarray, depth: float, tables: HullTables,
                 fk_linear: np.ndarray, body: BodyConstants):
        f, c = np.float64, np.ascontiguousarray      # one compiled signature
        self._state = _compiled().hull_state(c(local, f), c(triangles, np.int64), c(loads, f), c(vertex_loads, f),
                                             c(omega, f), c(amplitude.real, f), c(amplitude.imag, f), c(k, f),
                                             c(tables.heading, f), float(depth), *tables[:3], tables.direct,
                                             tables.direct_direction, c(fk_linear.real, f), c(fk_linear.imag, f), body)
        self._out, self._rot, self._v = np.zeros((3, 6)), np.empty((3, 3)), np.empty((3, len(local)))  # scratch

    def __call__(self, pose: np.ndarray, t: float, ramp: float, hs: np.ndarray, fk: np.ndarray) -> bool:
        """Writes the body's rows ``hs`` and ``fk`` (6,) (server/terms/nonlinear/rows.py) for the pose (6,) at
        time ``t`` [s] with the ``ramp`` factor: the hydrostatic and the Froude–Krylov load over the
        part of the hull below the incident free surface, the pressure at the wet vertices the
        Wheeler-stretched Froude–Krylov one, by the tables. False (the rows not written) where a
        wet vertex's stretched height is below the tables' floor: the caller then takes the numpy
        path."""
        return _compiled().hull_step(self._state, pose, float(t), float(ramp), self._rot, self._v, self._out, hs, fk)


def reply_rows() -> Callable[..., None]:
    """server/terms/nonlinear/rows.py's ``reply_rows`` compiled."""
    return _compiled().reply_rows


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernels now, at set-up, not in a run's first step:
    each with the one signature the callers use (tables of empty headings have their types)."""
    out = np.zeros(1)
    deep_pressure(np.zeros(1), np.zeros(1), np.ones(1, complex), 0.0, 0.0, 0.0, out)
    chebyshev_sum(np.zeros(1), np.ones(2), out)
    none, count, heads, start = np.zeros(0), np.zeros(0, np.int64), np.zeros((0, 2)), np.zeros(1, np.int64)
    elevation = ElevationTable(heads, start, count, count, count, np.zeros(0), count, none, none, count, 1.0)
    recurrences = RecurrenceTable(heads, start, count, none, none, none, none, -1.0)
    boxes = BoxTable(heads, start, count, np.zeros((0, 2), np.int64), count, count, count, none, count, none, none, count,
                     none, none, count, count, 1.0, -1.0)
    tables = HullTables(elevation, recurrences, boxes, count, heads, np.ones((1, 2)))
    local = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]])
    six = np.zeros(6)
    body = BodyConstants(1.0, np.zeros(3), 0.0, np.zeros((6, 6)), six, 0.0, np.ones(6))
    step = HullPass(local, np.array([[0, 1, 2]]), np.zeros((1, 3, 6)), np.zeros((3, 6)), np.ones(1),
                    np.ones(1, complex), np.ones(1), math.inf, tables, np.zeros((6, 1), complex), body)
    step(six, 0.0, 1.0, np.zeros(6), np.zeros(6))
    reply_rows()(np.zeros((2, 6)), six, np.eye(3), six, body, np.zeros(6), np.zeros(6))
