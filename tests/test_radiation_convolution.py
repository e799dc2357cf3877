"""Radiation convolution against scipy.signal / an explicit sum, and the replace-last semantics."""

from __future__ import annotations

import numpy as np
from scipy.signal import lfilter

from hydrolink.server.radiation.convolution import RadiationMemory


def _explicit(kernel, v, dt):
    """F_n = -dt sum_j w_j K_j v_{n-j} written out (v = 0 before the first sample)."""
    L = kernel.shape[0]
    w = np.ones(L)
    w[0] = w[-1] = 0.5
    out = np.zeros_like(v)
    for n in range(v.shape[0]):
        for j in range(min(L, n + 1)):
            out[n] -= dt * w[j] * kernel[j] @ v[n - j]
    return out


def test_scalar_matches_lfilter():
    dt, L = 0.05, 41
    t = np.arange(L) * dt
    k = np.exp(-t) * np.cos(3 * t)
    rng = np.random.default_rng(1)
    v = rng.standard_normal(300)
    mem = RadiationMemory(k[:, None, None], dt)
    got = np.array([mem.push(np.array([x]))[0] for x in v])
    taps = -dt * k * np.r_[0.5, np.ones(L - 2), 0.5]
    np.testing.assert_allclose(got, lfilter(taps, [1.0], v), rtol=1e-12, atol=1e-14)


def test_coupled_matches_explicit_sum_and_replace():
    dt, L, n = 0.1, 17, 3
    rng = np.random.default_rng(2)
    kernel = rng.standard_normal((L, n, n))
    v = rng.standard_normal((60, n))
    mem = RadiationMemory(kernel, dt)
    got = []
    for k, x in enumerate(v):
        # first send a wrong guess, then replace it with the true sample (iterative coupling)
        mem.push(x + 10.0)
        mem.push(x + 3.0, replace_last=True)
        got.append(mem.push(x, replace_last=True))
    np.testing.assert_allclose(np.array(got), _explicit(kernel, v, dt), rtol=1e-12, atol=1e-12)
    assert mem.count == 60
    np.testing.assert_array_equal(mem.window(), v[::-1][:L])


def test_disabled_when_no_memory():
    mem = RadiationMemory(np.ones((1, 2, 2)), 0.01)
    assert not mem.enabled
    np.testing.assert_array_equal(mem.push(np.ones(2)), 0.0)
