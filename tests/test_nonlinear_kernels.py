"""The compiled sums of server/kernels.py against numpy's direct evaluation: the deep-water
pressure recurrence over 300 evenly spaced components (to k = 14.7 /m, points to 6 m deep and 7 m
across) and Clenshaw's Chebyshev sum."""

from __future__ import annotations

import numpy as np
import pytest
from hydrolink.server import compiler
from hydrolink.server.terms.nonlinear import kernels
from numpy.polynomial import chebyshev

pytestmark = pytest.mark.skipif(not compiler.AVAILABLE, reason="numba not installed")


def test_deep_pressure_recurrence_is_the_direct_sum():
    g, rng = 9.81, np.random.default_rng(11)
    w = np.linspace(0.05, 12.0, 300)
    k = w ** 2 / g
    a = rng.uniform(0.0, 1.0, 300) * np.exp(1j * rng.uniform(0.0, 2 * np.pi, 300))
    xi, z = rng.uniform(-7.0, 7.0, 3000), -rng.uniform(0.0, 6.0, 3000)
    z[:10] = 0.0                                                 # on the surface: no decay at all
    dw = w[1] - w[0]
    out = np.zeros(3000)
    kernels.deep_pressure(xi, z, a, w[0] ** 2 / g, (2 * w[0] * dw + dw * dw) / g, 2 * dw * dw / g, out)
    direct = np.real(np.exp(np.outer(z, k) + 1j * np.outer(xi, k)) @ a)
    np.testing.assert_allclose(out, direct, rtol=0, atol=1e-12 * np.abs(a).sum())


def test_chebyshev_sum_is_clenshaw():
    rng = np.random.default_rng(2)
    u, c = rng.uniform(-1.0, 1.0, 500), rng.standard_normal(90)
    out = np.full(500, 3.0)
    kernels.chebyshev_sum(u, c, out)
    np.testing.assert_allclose(out - 3.0, chebyshev.chebval(u, c), rtol=0, atol=1e-12 * np.abs(c).sum())
