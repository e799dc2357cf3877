"""server/terms/nonlinear/vector_math.py's vectorised cosine, sine and exponential, compiled as the kernels use
them, against the C library's (numpy's np.cos, np.sin, np.exp): within 2 ulp of the result (and
0.5 ulp of 1 absolute for the cosine and sine) over the reduction's whole range and past it (the
library's own there), at the special values, and for subnormal and overflowing exponentials."""

from __future__ import annotations

import numpy as np
import pytest
from hydrolink.server import compiler
from hydrolink.server.terms.nonlinear import kernels as incident_kernels

pytestmark = pytest.mark.skipif(not compiler.AVAILABLE, reason="numba not installed")


@pytest.fixture(scope="module")
def kernels():
    return incident_kernels._compiled()


def _ulps(value: np.ndarray, reference: np.ndarray) -> float:
    """The largest difference in units in the last place of the reference."""
    return float(np.max(np.abs(value - reference) / np.spacing(np.abs(reference))))


@pytest.mark.parametrize("half_width", [1.0, 30.0, 1e4, 5e7, 1e9])     # 5.3e7: the reduction's end
def test_sincos_is_the_c_library_within_two_ulp(kernels, half_width):
    x = np.random.default_rng(3).uniform(-half_width, half_width, 100_000)
    x[:4] = [0.0, np.pi / 4, -np.pi / 2, 3 * np.pi / 4]          # the quadrants' borders
    c, s = np.empty_like(x), np.empty_like(x)
    kernels.sincos(x, c, s)
    big = np.abs(np.cos(x)) > 1e-3                                # relative where not near a zero
    assert _ulps(c[big], np.cos(x[big])) <= 2.0
    big = np.abs(np.sin(x)) > 1e-3
    assert _ulps(s[big], np.sin(x[big])) <= 2.0
    assert np.max(np.abs(c - np.cos(x))) <= 0.5 * np.spacing(1.0)
    assert np.max(np.abs(s - np.sin(x))) <= 0.5 * np.spacing(1.0)


def test_sincos_special_values(kernels):
    x = np.array([0.0, -0.0, 5e-324, -1e-300, 1e300, np.inf, -np.inf, np.nan])
    c, s = np.empty_like(x), np.empty_like(x)
    kernels.sincos(x, c, s)
    with np.errstate(invalid="ignore"):
        np.testing.assert_array_equal(c, np.cos(x))
        np.testing.assert_array_equal(s, np.sin(x))


@pytest.mark.parametrize("low, high", [(-1.0, 1.0), (-40.0, 0.0), (-700.0, 700.0)])
def test_exp_is_the_c_library_within_two_ulp(kernels, low, high):
    x = np.random.default_rng(5).uniform(low, high, 100_000)
    out = np.empty_like(x)
    kernels.exp(x, out)
    assert _ulps(out, np.exp(x)) <= 2.0


def test_exp_underflow_overflow_and_special_values(kernels):
    x = np.random.default_rng(7).uniform(-746.0, -708.0, 10_000)          # subnormal results
    out = np.empty_like(x)
    kernels.exp(x, out)
    assert np.max(np.abs(out - np.exp(x))) <= 5e-324
    x = np.array([-1e300, -np.inf, -800.0, 709.78, 709.7828, 800.0, np.inf, np.nan, 0.0, -0.0, 1e-300])
    out = np.empty_like(x)
    kernels.exp(x, out)
    with np.errstate(over="ignore"):
        reference = np.exp(x)
    assert _ulps(out[3:4], reference[3:4]) <= 2.0
    out[3] = reference[3]
    np.testing.assert_array_equal(out, reference)
