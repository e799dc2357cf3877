"""The boxes' power series of the incident wave's pressure (server/pressure_boxes.py, summed by the
compiled kernel) against one cosine and cosh depth factor per point and component: deep and
finite water, long to short waves, several headings, one box and many."""

from __future__ import annotations

import math

import numpy as np
import pytest
from hydrolink.server.terms.nonlinear import pressure_boxes
from hydrolink.server.terms.nonlinear.pressure_boxes import BoxGroup, box_table, layout
from hydrolink.server.compiler import AVAILABLE
from hydrolink.server.terms.nonlinear.kernels import box_pressure
from hydrolink.server.sea.dispersion import wave_number

G = 9.81
pytestmark = pytest.mark.skipif(not AVAILABLE, reason="numba not installed")


def _sea(depth: float, w_max: float, rng) -> tuple[np.ndarray, ...]:
    omega = np.linspace(0.05, w_max, 60)
    k = np.array([wave_number(float(w), G, depth) for w in omega])
    heading = np.where(np.arange(60) % 3 == 0, 0.2, -1.1)
    return k, heading, rng.uniform(0.0, 1.0, 60) / (1.0 + omega ** 2), rng.uniform(-20.0, 20.0, 60)


def _direct(k, heading, amp, psi, reference, offsets, z, depth) -> np.ndarray:
    pts = reference + offsets
    theta = np.outer(pts[:, 0], k * np.cos(heading)) + np.outer(pts[:, 1], k * np.sin(heading)) + psi
    factor = np.exp(np.outer(z, k)) if math.isinf(depth) else np.cosh(np.outer(z + depth, k)) / np.cosh(k * depth)
    return (factor * np.cos(theta)) @ amp


@pytest.mark.parametrize("depth, w_max, columns", [(math.inf, 3.0, None), (200.0, 2.0, 1), (30.0, 3.0, None),
                                               (30.0, 3.0, 7), (8.0, 4.0, None)])
def test_box_series_is_the_direct_sum(depth, w_max, columns):
    """Points over a 5 m radius and down to 10 m (the seabed at 8 m: to it), the grid by
    :func:`layout` for those points (or ``columns`` columns), against the direct sums at 1e-12 of the
    amplitude sum; every point in a box of its own heading's grid."""
    rng = np.random.default_rng(8)
    k, heading, amp, psi = _sea(depth, w_max, rng)
    radius, floor = 5.0, -10.0
    r, a = radius * np.sqrt(rng.uniform(0.0, 1.0, 500)), rng.uniform(0.0, 2 * np.pi, 500)
    offsets = np.column_stack([r * np.cos(a), r * np.sin(a)])
    z = -rng.uniform(0.0, min(10.0, depth), 500)
    z[:20] = 0.0                      # on the surface
    groups = []
    for b in (0.2, -1.1):
        cols = np.flatnonzero(heading == b)
        direction = np.array([np.cos(b), np.sin(b)])
        sz = np.column_stack([offsets @ direction, z])
        n_s, rows, cost = layout(k[cols], amp[cols], depth, radius, floor, sz, float(amp.sum()))
        if columns is not None:
            n_s, rows = columns, pressure_boxes.row_orders(k[cols], amp[cols], depth, columns, radius, floor,
                                                          float(amp.sum()))
        assert rows.max() <= pressure_boxes._MAX_ORDERS and cost < math.inf
        groups.append(BoxGroup(cols, direction, n_s, rows))
    table = box_table(groups, k, depth, radius, floor)
    assert bool(table.mirror.any()) == (not math.isinf(depth))        # the long waves feel the seabed
    reference = np.array([40.0, -7.0])
    phasor = amp * np.exp(1j * (k * (reference[0] * np.cos(heading) + reference[1] * np.sin(heading)) + psi))
    got = box_pressure(table, phasor, offsets, z)
    np.testing.assert_allclose(got, _direct(k, heading, amp, psi, reference, offsets, z, depth), rtol=0,
                               atol=1e-12 * amp.sum())


def test_row_orders_are_the_least_within_the_stated_bound():
    """One row (a 2 m x 2 m box about z_b = -1 m, rho = sqrt 2 m), deep water: the order chosen is
    the least whose remainder bound sum_c a_c e^{k z_b} (k rho)^N / N! e^{k rho} is below 2^-53 of
    the amplitude sum, and the series cut a few orders earlier is off by more than round-off at the
    box's corners (the bound is not loose by many orders of magnitude)."""
    k, amp = np.array([0.5, 1.0, 2.0]), np.array([1.0, 0.5, 0.1])
    rows = pressure_boxes.row_orders(k, amp, math.inf, 1, 1.0, -2.0, float(amp.sum()))
    assert rows.shape == (1,)
    n, rho, tol = int(rows[0]), math.sqrt(2.0), 2.0 ** -53 * amp.sum()
    bound = lambda m: float(np.sum(amp * np.exp(-k) * (k * rho) ** m / math.factorial(m) * np.exp(k * rho)))
    assert bound(n) <= tol < bound(n - 1)
    corners = np.array([1 + 1j, 1 - 1j, -1 + 1j, -1 - 1j])      # (z - z_b) + i s at the box's corners
    exact = (amp * np.exp(-k) * np.exp(np.outer(corners, k))).sum(axis=1)
    cut = sum((amp * np.exp(-k) * k ** m / math.factorial(m)).sum() * corners ** m for m in range(n - 4))
    assert np.abs(exact - cut).max() > 10 * tol
