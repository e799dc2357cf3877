"""Radiation impulse response function (IRF) and Ogilvie's infinite-frequency added mass.

    K(t)  = (2/pi) int_0^inf B(w) cos(w t) dw                       (trapezoid over the HDB grid,
                                                                      a (0, 0) point prepended)
    A_inf = A(w) + (1/w) int_0^T K(t) sin(w t) dt                   (one estimate per w)

The trapezoid sum over an (almost) uniform grid of spacing dw is periodic in t with period 2 pi/dw:
K is trustworthy only for t < pi/dw (see :func:`aliasing_time`).
"""

from __future__ import annotations

import numpy as np

_CHUNK = 2048  # rows of the cos/sin table evaluated at once (bounds memory for long IRFs)


def trapezoid_weights(x: np.ndarray) -> np.ndarray:
    """Weights w such that sum(w * f(x)) is the trapezoid rule on the (non-uniform) grid x."""
    x = np.asarray(x, float)
    w = np.zeros_like(x)
    if x.size < 2:
        return w
    dx = np.diff(x)
    w[:-1] += dx / 2
    w[1:] += dx / 2
    return w


def aliasing_time(omega: np.ndarray) -> float:
    """Half the period of the trapezoid transform on this grid: pi / (largest spacing, incl. 0)."""
    w = np.concatenate(([0.0], np.asarray(omega, float)))
    return float(np.pi / np.max(np.diff(w)))


def radiation_irf(omega: np.ndarray, damping: np.ndarray, t: np.ndarray) -> np.ndarray:
    """K(t) from B(w): damping (n_w, n, n) on omega (n_w,) -> K (n_t, n, n)."""
    omega = np.asarray(omega, float)
    damping = np.asarray(damping, float)
    t = np.asarray(t, float)
    w = np.concatenate(([0.0], omega))
    b = np.concatenate((np.zeros((1, *damping.shape[1:])), damping)).reshape(w.size, -1)
    bw = (2.0 / np.pi) * trapezoid_weights(w)[:, None] * b  # (n_w+1, n*n)
    out = np.empty((t.size, b.shape[1]))
    for s in range(0, t.size, _CHUNK):
        out[s:s + _CHUNK] = np.cos(np.outer(t[s:s + _CHUNK], w)) @ bw
    return out.reshape((t.size, *damping.shape[1:]))


def _sine_transform(omega: np.ndarray, t: np.ndarray, k: np.ndarray, fun=np.sin) -> np.ndarray:
    """int_0^T k(t) fun(w t) dt by the trapezoid rule over t: (n_t, ...) -> (n_w, ...)."""
    kw = trapezoid_weights(t)[:, None] * k.reshape(t.size, -1)
    out = np.zeros((omega.size, kw.shape[1]))
    for s in range(0, t.size, _CHUNK):
        out += fun(np.outer(omega, t[s:s + _CHUNK])) @ kw[s:s + _CHUNK]
    return out.reshape((omega.size, *k.shape[1:]))


def ogilvie_estimates(omega: np.ndarray, added_mass: np.ndarray, t: np.ndarray,
                      k: np.ndarray) -> np.ndarray:
    """A_inf estimated at every HDB frequency: (n_w, n, n)."""
    omega = np.asarray(omega, float)
    s = _sine_transform(omega, np.asarray(t, float), np.asarray(k, float))
    return np.asarray(added_mass, float) + s / omega[:, None, None]


def ogilvie_added_mass_inf(omega: np.ndarray, added_mass: np.ndarray, t: np.ndarray,
                           k: np.ndarray, window: float = 0.2) -> np.ndarray:
    """Ogilvie's A_inf (n, n) from A(w) (n_w, n, n) and the IRF K sampled at t.

    The per-frequency estimates are wrong at both ends of the grid: at low w by the IRF's
    truncation at T (error ~ K(T)/w^2, oscillating), near w_max by the damping tail missing above
    the grid (growing towards w_max). They are combined by the median over the flattest contiguous
    run of ``window`` (20 %) of the grid's frequencies: flatness is the largest relative range
    (max - min)/|median| of the diagonal estimates in the run. The median ignores an odd irregular
    frequency. (Fed with the same truncated K as the simulation, this also makes the effective
    A_inf - (1/w) int K sin match the HDB's A(w) best over that run.)
    """
    omega = np.asarray(omega, float)
    est = ogilvie_estimates(omega, added_mass, t, k)
    nw = omega.size
    m = min(nw, max(3, int(round(window * nw))))
    diag = np.diagonal(est, axis1=1, axis2=2)  # (n_w, n)
    runs = np.lib.stride_tricks.sliding_window_view(diag, m, axis=0)  # (n_runs, n, m)
    med = np.abs(np.median(runs, axis=-1))
    scale = np.maximum(med, 1e-12 * max(float(np.abs(diag).max(initial=0.0)), 1e-300))
    score = np.max((runs.max(axis=-1) - runs.min(axis=-1)) / scale, axis=1)  # (n_runs,)
    s = int(np.argmin(score))
    return np.median(est[s:s + m], axis=0)


def irf_report(omega: np.ndarray, damping: np.ndarray, t: np.ndarray, k: np.ndarray) -> dict:
    """How well the (truncated, sampled) IRF reproduces B: re-transform B'(w) = int_0^T K cos(w t) dt.

    Returns ``damping_retransformed`` (n_w, n, n), ``rel_error`` (n, n): max_w |B' - B| over
    max_w |B| per mode (NaN for modes with no damping), and ``worst`` (the largest finite one)."""
    omega = np.asarray(omega, float)
    damping = np.asarray(damping, float)
    b2 = _sine_transform(omega, np.asarray(t, float), np.asarray(k, float), fun=np.cos)
    scale = np.max(np.abs(damping), axis=0)
    tiny = scale <= 1e-9 * max(float(scale.max(initial=0.0)), 1e-300)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(tiny, np.nan, np.max(np.abs(b2 - damping), axis=0) / scale)
    finite = rel[np.isfinite(rel)]
    return {"damping_retransformed": b2, "rel_error": rel,
            "worst": float(finite.max()) if finite.size else 0.0}
