"""Radiation impulse response function (IRF) and Ogilvie's infinite-frequency added mass.

    K(t)  = (2/pi) int_0^inf B(w) cos(w t) dw                       (trapezoid over the HDB grid,
                                                                      a (0, 0) point prepended)
    A_inf = A(w) + (1/w) int_0^T K(t) sin(w t) dt                   (one estimate per w)

The trapezoid sum over an (almost) uniform grid of spacing dw is periodic in t with period 2 pi/dw:
K is trustworthy only for t < pi/dw (see :func:`aliasing_time`).
"""

from __future__ import annotations

import numpy as np

COS_TABLE_ROWS = 2048  # rows of a transform's cos and sin tables together (half each; bounds memory for long IRFs)



def irf_samples(duration: float, dt: float, *, at_least: int = 0) -> int:
    """How many steps of ``dt`` an impulse response kept over ``duration`` spans after t = 0 (its
    samples are t = 0, dt, ..., that many times dt): round(duration / dt), at least ``at_least``. The
    one definition: the radiation memory, the excitation IRF (both sides of t = 0) and ``hydrolink
    steady``'s discrete radiation all take it."""
    return max(at_least, int(round(duration / dt)))

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


def uniform_step(t: np.ndarray) -> float:
    """The spacing of the uniform sample times t (0 for fewer than two); ValueError if they are
    not uniform (beyond 1e-9 of their span)."""
    if t.size < 2:
        return 0.0
    dt = float(t[-1] - t[0]) / (t.size - 1)
    if np.max(np.abs(t - (t[0] + dt * np.arange(t.size)))) > 1e-9 * max(abs(float(t[0])), abs(float(t[-1])), dt):
        raise ValueError(f"IRF sample times must be uniform ({t.size} times from {t[0]:g} to {t[-1]:g} s are not)")
    return dt


def _trig_blocks(omega: np.ndarray, t: np.ndarray, sine: bool):
    """The table sin(w t) (``sine``, else cos(w t)) between the frequencies omega and the uniform
    times t, in blocks of R = COS_TABLE_ROWS / 2 consecutive times t_s + j dt, without evaluating
    the function at every (t, w): the blocks share cos(w j dt) and sin(w j dt) (R, n_w), and

        cos(w (t_s + j dt)) = cos(w t_s) cos(w j dt) - sin(w t_s) sin(w j dt)
        sin(w (t_s + j dt)) = sin(w t_s) cos(w j dt) + cos(w t_s) sin(w j dt),

    so n_t n_w evaluations become (R + n_t / R) n_w (the 2e5-sample, 400-frequency IRF of a 2e-5 s
    step and its two checks: 8.0 s before, 3.0 s after). Yields (start row s, table (r, n_w));
    the table is overwritten by the next block. Times that fit one block get the table directly."""
    dt = uniform_step(t)
    rows = COS_TABLE_ROWS // 2
    if t.size <= rows:
        yield 0, (np.sin if sine else np.cos)(np.outer(t, omega))
        return
    phase = np.outer(dt * np.arange(rows), omega)
    cos_j, sin_j = np.cos(phase), np.sin(phase)
    start = np.outer(t[0] + dt * np.arange(0, t.size, rows), omega)
    cos_s, sin_s = np.cos(start), np.sin(start)                    # (blocks, n_w)
    table, term = np.empty_like(phase), phase                      # the phase's memory, reused
    for block, s in enumerate(range(0, t.size, rows)):
        r = min(rows, t.size - s)
        if sine:
            np.multiply(cos_j[:r], sin_s[block], out=table[:r])
            np.multiply(sin_j[:r], cos_s[block], out=term[:r])
            np.add(table[:r], term[:r], out=table[:r])
        else:
            np.multiply(cos_j[:r], cos_s[block], out=table[:r])
            np.multiply(sin_j[:r], sin_s[block], out=term[:r])
            np.subtract(table[:r], term[:r], out=table[:r])
        yield s, table[:r]


def radiation_irf(omega: np.ndarray, damping: np.ndarray, t: np.ndarray) -> np.ndarray:
    """K(t) from B(w): damping (n_w, n, n) on omega (n_w,) -> K (n_t, n, n) at the uniform times t."""
    omega = np.asarray(omega, float)
    damping = np.asarray(damping, float)
    t = np.asarray(t, float)
    w = np.concatenate(([0.0], omega))
    b = np.concatenate((np.zeros((1, *damping.shape[1:])), damping)).reshape(w.size, -1)
    bw = (2.0 / np.pi) * trapezoid_weights(w)[:, None] * b  # (n_w+1, n*n)
    out = np.empty((t.size, b.shape[1]))
    for s, table in _trig_blocks(w, t, sine=False):
        np.matmul(table, bw, out=out[s:s + len(table)])
    return out.reshape((t.size, *damping.shape[1:]))


def _sine_transform(omega: np.ndarray, t: np.ndarray, k: np.ndarray, sine: bool = True) -> np.ndarray:
    """int_0^T k(t) sin(w t) dt (``sine``, else with cos) by the trapezoid rule over the uniform
    times t: (n_t, ...) -> (n_w, ...)."""
    kw = trapezoid_weights(t)[:, None] * k.reshape(t.size, -1)
    out = np.zeros((omega.size, kw.shape[1]))
    for s, table in _trig_blocks(omega, t, sine):
        out += table.T @ kw[s:s + len(table)]
    return out.reshape((omega.size, *k.shape[1:]))


def added_mass_transform(omega: np.ndarray, t: np.ndarray, k: np.ndarray) -> np.ndarray:
    """int_0^T K(t) sin(w t) dt at the frequencies omega, (n_w, n, n): what Ogilvie's A_inf and
    :func:`ogilvie_report` both take from K (given to them as ``transform``, it is computed once)."""
    return _sine_transform(np.asarray(omega, float), np.asarray(t, float), np.asarray(k, float))


def ogilvie_estimates(omega: np.ndarray, added_mass: np.ndarray, t: np.ndarray,
                      k: np.ndarray, transform: np.ndarray | None = None) -> np.ndarray:
    """A_inf estimated at every HDB frequency: (n_w, n, n); ``transform``: :func:`added_mass_transform`
    of these arguments where the caller has it."""
    omega = np.asarray(omega, float)
    s = added_mass_transform(omega, t, k) if transform is None else transform
    return np.asarray(added_mass, float) + s / omega[:, None, None]


def ogilvie_added_mass_inf(omega: np.ndarray, added_mass: np.ndarray, t: np.ndarray,
                           k: np.ndarray, window: float = 0.2, transform: np.ndarray | None = None) -> np.ndarray:
    """Ogilvie's A_inf (n, n) from A(w) (n_w, n, n) and the IRF K sampled at t.

    The per-frequency estimates are wrong at both ends of the grid: at low w by the IRF's
    truncation at T (error ~ K(T)/w^2, oscillating), near w_max by the damping tail missing above
    the grid (growing towards w_max). They are combined by the median over the flattest contiguous
    run of ``window`` (20 %) of the grid's frequencies: flatness is the largest relative range
    (max - min)/|median| of the diagonal estimates in the run. The median ignores an odd irregular
    frequency. (Fed with the same truncated K as the simulation, this also makes the effective
    A_inf - (1/w) int K sin match the HDB's A(w) best over that run.) ``transform``: as for
    :func:`ogilvie_estimates`.
    """
    omega = np.asarray(omega, float)
    est = ogilvie_estimates(omega, added_mass, t, k, transform)
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
    b2 = _sine_transform(omega, np.asarray(t, float), np.asarray(k, float), sine=False)
    scale = np.max(np.abs(damping), axis=0)
    tiny = scale <= 1e-9 * max(float(scale.max(initial=0.0)), 1e-300)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(tiny, np.nan, np.max(np.abs(b2 - damping), axis=0) / scale)
    finite = rel[np.isfinite(rel)]
    return {"damping_retransformed": b2, "rel_error": rel,
            "worst": float(finite.max()) if finite.size else 0.0}


# ---------------------------------------------------------------------------------------------
# Pre-processing of B(w) before the transform (scene [hydro] irf_domega, irf_tail, irf_taper) and
# the Ogilvie consistency report. See docs/radiation.md.


def resample_damping(omega: np.ndarray, damping: np.ndarray, domega: float) -> tuple[np.ndarray, np.ndarray]:
    """B(w) (n_w, ...) resampled by a cubic spline through (0, 0) and the data onto the uniform grid
    k dw (k = 1, 2, ...) up to w_max (w_max itself is appended when the last step would be short
    by more than 1 %): the whole grid from 0 has spacing dw, so K(t) is alias-free up to pi/dw.
    Returns (omega_new, damping_new)."""
    from scipy.interpolate import CubicSpline

    omega = np.asarray(omega, float)
    damping = np.asarray(damping, float)
    if omega[0] > 0:
        omega = np.concatenate(([0.0], omega))
        damping = np.concatenate((np.zeros((1, *damping.shape[1:])), damping))
    n = int(np.floor(omega[-1] / domega + 1e-9))
    new = domega * np.arange(1, n + 1)
    if omega[-1] - new[-1] > 0.01 * domega:
        new = np.append(new, omega[-1])
    return new, CubicSpline(omega, damping, axis=0)(new)


def asymptotic_tail(omega: np.ndarray, damping: np.ndarray, cutoff: float, fraction: float = 0.25,
                    n_limits: tuple[float, float] = (1.0, 8.0)) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Extend B(w) beyond the grid with B(w) = B(w_max) (w_max / w)^n up to ``cutoff`` rad/s.

    The exponent n is fitted per DOF pair by least squares on log|B| over the last ``fraction`` of
    the grid (at least 4 points) when B keeps one sign there; it is clipped to ``n_limits``. Pairs
    whose B changes sign there take the median exponent of the fitted pairs (2 if none). The tail
    starts at B(w_max) itself (no jump: a jump in B would put a log singularity into A(w)). The
    tail points continue the grid's last spacing. Returns (omega_ext, damping_ext, n (n_pairs...))."""
    omega = np.asarray(omega, float)
    damping = np.asarray(damping, float)
    shape = damping.shape[1:]
    b = damping.reshape(omega.size, -1)
    m = max(4, int(round(fraction * omega.size)))
    w, tail = omega[-m:], b[-m:]
    one_sign = np.all(tail > 0, axis=0) | np.all(tail < 0, axis=0)
    x = np.log(w) - np.log(w).mean()
    n = np.full(b.shape[1], np.nan)
    if one_sign.any():
        y = np.log(np.abs(tail[:, one_sign]))
        slope = (x @ (y - y.mean(axis=0))) / (x @ x)
        n[one_sign] = np.clip(-slope, *n_limits)
    fill = float(np.median(n[one_sign])) if one_sign.any() else 2.0
    n = np.where(np.isnan(n), fill, n)
    step = omega[-1] - omega[-2]
    k = int(np.floor((cutoff - omega[-1]) / step + 1e-9))
    if k < 1:
        return omega, damping, n.reshape(shape)
    w_ext = omega[-1] + step * np.arange(1, k + 1)
    b_ext = b[-1] * (omega[-1] / w_ext[:, None]) ** n
    return (np.concatenate([omega, w_ext]), np.concatenate([b, b_ext]).reshape((-1, *shape)),
            n.reshape(shape))


def taper_window(t: np.ndarray, duration: float, fraction: float) -> np.ndarray:
    """1 up to T1 = (1 - fraction) T, then a cosine taper 1/2 (1 + cos(pi (t - T1) / (T - T1))) to 0 at T."""
    t = np.asarray(t, float)
    if fraction <= 0:
        return np.ones_like(t)
    t1 = (1.0 - fraction) * duration
    if not duration > t1:   # a fraction too small to shorten the IRF by anything
        return np.ones_like(t)
    u = np.clip((t - t1) / (duration - t1), 0.0, 1.0)
    return 0.5 * (1.0 + np.cos(np.pi * u))


def _interval_exp(alpha: np.ndarray, a: float, b: float) -> np.ndarray:
    """int_a^b exp(i alpha t) dt, stable at alpha -> 0."""
    h = b - a
    return np.exp(0.5j * alpha * (a + b)) * h * np.sinc(alpha * h / (2 * np.pi))


def irf_transfer(omega: np.ndarray, damping: np.ndarray, duration: float, taper: float,
                 omega_eval: np.ndarray) -> np.ndarray:
    """The transfer function of the (truncated, tapered) IRF the simulation uses, in closed form:

        H(w) = int_0^T tau(t) K(t) exp(-i w t) dt = B_K(w) + i w (A_K(w) - A_inf)

    with K(t) = (2/pi) sum_n q_n B(w_n) cos(w_n t) exactly as :func:`radiation_irf` builds it
    (trapezoid weights q_n over the grid with (0, 0) prepended) and tau the taper window. No
    sampling in time: the integrals of cos * exp (* the cosine taper) are evaluated exactly.
    damping (n_w, ...) -> (n_eval, ...) complex."""
    omega = np.asarray(omega, float)
    damping = np.asarray(damping, float)
    we = np.asarray(omega_eval, float)
    q = (2.0 / np.pi) * trapezoid_weights(np.concatenate(([0.0], omega)))[1:]
    T = float(duration)
    t1 = (1.0 - taper) * T if taper > 0 else T
    g = np.zeros((we.size, omega.size), complex)
    for sign in (1.0, -1.0):
        alpha = sign * omega[None, :] - we[:, None]
        g += 0.5 * _interval_exp(alpha, 0.0, t1)
        if t1 < T:
            k = np.pi / (T - t1)
            g += 0.5 * (0.5 * _interval_exp(alpha, t1, T)
                        + 0.25 * np.exp(-1j * k * t1) * _interval_exp(alpha + k, t1, T)
                        + 0.25 * np.exp(1j * k * t1) * _interval_exp(alpha - k, t1, T))
    out = (g * q[None, :]) @ damping.reshape(omega.size, -1)
    return out.reshape((we.size, *damping.shape[1:]))


def ogilvie_report(omega: np.ndarray, added_mass: np.ndarray, a_inf: np.ndarray, t: np.ndarray,
                   k: np.ndarray, transform: np.ndarray | None = None) -> dict:
    """How well the (truncated, sampled) IRF reproduces A(w) (Ogilvie / Kramers-Kronig):
    A_K(w) = A_inf - (1/w) int_0^T K(t) sin(w t) dt against the HDB's A(w).

    ``rel_error`` (n, n): max_w |A_K - A| over max_w |A - A_inf| (diagonal scale; off-diagonal pairs
    use sqrt of the two diagonal scales; NaN where a scale is zero), ``worst`` the largest finite one.
    ``transform``: as for :func:`ogilvie_estimates`."""
    omega = np.asarray(omega, float)
    added_mass = np.asarray(added_mass, float)
    s = added_mass_transform(omega, t, k) if transform is None else transform
    a_k = np.asarray(a_inf, float)[None] - s / omega[:, None, None]
    var = np.max(np.abs(added_mass - np.asarray(a_inf, float)[None]), axis=0)
    d = np.diagonal(var).copy()
    scale = np.sqrt(np.outer(d, d))
    tiny = scale <= 1e-9 * max(float(scale.max(initial=0.0)), 1e-300)
    with np.errstate(invalid="ignore", divide="ignore"):
        rel = np.where(tiny, np.nan, np.max(np.abs(a_k - added_mass), axis=0) / scale)
    finite = rel[np.isfinite(rel)]
    return {"added_mass_irf": a_k, "rel_error": rel, "worst": float(finite.max()) if finite.size else 0.0}
