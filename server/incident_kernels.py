"""Compiled kernels for the incident wave on a hull's points (issue 26; numba, optional).

Two sums over many points and components, each a loop over the components outside and over the
points inside (vectorised by the compiler), with no transcendental function in the loops:

- :func:`deep_pressure`: sum_c Re(a_c e^{k_c (z_p + i xi_p)}) for components whose wave numbers
  are a quadratic in their index, k_c = k0 + c dk + c (c - 1) d2 / 2 (deep water, frequencies
  equally spaced: k = w^2 / g). Then e^{k_{c+1} zeta} = e^{k_c zeta} r_c with r_{c+1} = r_c q, q
  = e^{d2 zeta}: two complex products per point and component, three complex exponentials per
  point. The products' round-off grows with c; over 300 components it stays below 1e-12 of the
  amplitude sum (tests/test_incident_kernels.py).
- :func:`chebyshev_sum`: sum_n c_n T_n(u_p) by Clenshaw's recurrence (the Jacobi–Anger expansion of
  server/phase_expansion.py); :func:`chebyshev_sum2` the two-dimensional sum of its long-wave
  pressure series, the depth series' Chebyshev values by their recurrence, then Clenshaw.

``AVAILABLE`` is False where numba is not installed: the callers then take their numpy paths
(the same sums as matrix products; slower, same results to round-off).
"""

from __future__ import annotations

import functools
import importlib.util
import math

import numpy as np

__all__ = ["AVAILABLE", "chebyshev_sum", "chebyshev_sum2", "deep_pressure", "imports", "warm_up"]

AVAILABLE = importlib.util.find_spec("numba") is not None   # numba itself imported on first use


@functools.cache
def imports() -> bool:
    """Whether numba, installed, also imports here (a numba built for another numpy raises): the
    set-ups ask this before choosing the compiled paths, so such a machine runs the numpy ones."""
    try:
        import numba  # noqa: F401
    except Exception:  # noqa: BLE001 - any failure to import means: no compiled paths
        return False
    return True


def _deep_pressure(xi, z, ar, ai, k0, dk, d2, out):
    p_n, n_c = xi.size, ar.size
    ur, ui = np.empty(p_n), np.empty(p_n)
    rr, ri = np.empty(p_n), np.empty(p_n)
    qr, qi = np.empty(p_n), np.empty(p_n)
    for p in range(p_n):
        m = math.exp(k0 * z[p])
        ur[p], ui[p] = m * math.cos(k0 * xi[p]), m * math.sin(k0 * xi[p])
        m = math.exp(dk * z[p])
        rr[p], ri[p] = m * math.cos(dk * xi[p]), m * math.sin(dk * xi[p])
        m = math.exp(d2 * z[p])
        qr[p], qi[p] = m * math.cos(d2 * xi[p]), m * math.sin(d2 * xi[p])
    c = 0
    while c + 2 <= n_c:         # two components per pass over the points: half the loads and stores
        for p in range(p_n):
            xr, xi_, yr, yi, zr, zi = ur[p], ui[p], rr[p], ri[p], qr[p], qi[p]
            s = 0.0
            for q in range(2):
                s += ar[c + q] * xr - ai[c + q] * xi_
                t = xr * yr - xi_ * yi
                xi_ = xr * yi + xi_ * yr
                xr = t
                t = yr * zr - yi * zi
                yi = yr * zi + yi * zr
                yr = t
            out[p] += s
            ur[p], ui[p], rr[p], ri[p] = xr, xi_, yr, yi
        c += 2
    if c < n_c:
        for p in range(p_n):
            out[p] += ar[c] * ur[p] - ai[c] * ui[p]


def _chebyshev_sum(u, c, out):
    p_n, n = u.size, c.size
    b1, b2 = np.zeros(p_n), np.zeros(p_n)
    for m in range(n - 1, 0, -1):
        cm = c[m]
        for p in range(p_n):
            t = 2.0 * u[p] * b1[p] - b2[p] + cm
            b2[p] = b1[p]
            b1[p] = t
    c0 = c[0]
    for p in range(p_n):
        out[p] += u[p] * b1[p] - b2[p] + c0


def _chebyshev_sum2(u, v, c, out):
    p_n, n, m = u.size, c.shape[0], c.shape[1]
    tv = np.empty((m, p_n))                 # T_m(v) by their recurrence
    for p in range(p_n):
        tv[0, p] = 1.0
    if m > 1:
        for p in range(p_n):
            tv[1, p] = v[p]
    for j in range(2, m):
        for p in range(p_n):
            tv[j, p] = 2.0 * v[p] * tv[j - 1, p] - tv[j - 2, p]
    s, b1, b2 = np.empty(p_n), np.zeros(p_n), np.zeros(p_n)
    for i in range(n - 1, -1, -1):          # Clenshaw in u over s_i = sum_m c_im T_m(v)
        for p in range(p_n):
            s[p] = 0.0
        for j in range(m):
            cij = c[i, j]
            for p in range(p_n):
                s[p] += cij * tv[j, p]
        if i > 0:
            for p in range(p_n):
                t = 2.0 * u[p] * b1[p] - b2[p] + s[p]
                b2[p] = b1[p]
                b1[p] = t
        else:
            for p in range(p_n):
                out[p] += u[p] * b1[p] - b2[p] + s[p]


@functools.cache
def _compiled():
    """Both kernels compiled (or loaded from numba's cache) on first use: numba is imported only by
    a scene that needs it (its import costs about half a second)."""
    import numba
    jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    return jit(_deep_pressure), jit(_chebyshev_sum), jit(_chebyshev_sum2)


def deep_pressure(xi: np.ndarray, z: np.ndarray, a: np.ndarray, k0: float, dk: float, d2: float,
                  out: np.ndarray) -> None:
    """Adds sum_c Re(a_c e^{k_c (z + i xi)}) to ``out`` (P,), k_c = k0 + c dk + c (c - 1) d2 / 2,
    at points with horizontal coordinates ``xi`` (P,) along the heading and heights ``z`` (P,)
    <= 0, for the complex amplitudes ``a`` (n_c,) (module docstring)."""
    _compiled()[0](np.ascontiguousarray(xi, float), np.ascontiguousarray(z, float),
                   np.ascontiguousarray(a.real), np.ascontiguousarray(a.imag), float(k0), float(dk), float(d2), out)


def chebyshev_sum(u: np.ndarray, c: np.ndarray, out: np.ndarray) -> None:
    """Adds sum_n c_n T_n(u) to ``out`` (P,) at points ``u`` (P,) in [-1, 1] (Clenshaw)."""
    if c.size:
        _compiled()[1](np.ascontiguousarray(u, float), np.ascontiguousarray(c, float), out)


def chebyshev_sum2(u: np.ndarray, v: np.ndarray, c: np.ndarray, out: np.ndarray) -> None:
    """Adds sum_{n, m} c_nm T_n(u) T_m(v) to ``out`` (P,) at points ``u``, ``v`` (P,) in [-1, 1]."""
    if c.size:
        _compiled()[2](np.ascontiguousarray(u, float), np.ascontiguousarray(v, float),
                       np.ascontiguousarray(c, float), out)


def warm_up() -> None:
    """Compile (or load from numba's cache) both kernels now, at set-up, not in a run's first step."""
    out = np.zeros(1)
    deep_pressure(np.zeros(1), np.zeros(1), np.ones(1, complex), 0.0, 0.0, 0.0, out)
    chebyshev_sum(np.zeros(1), np.ones(2), out)
    chebyshev_sum2(np.zeros(1), np.zeros(1), np.ones((2, 2)), out)
