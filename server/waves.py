"""Incident waves: components, ramp, elevation and excitation by frequency-domain superposition.

Internal convention exp(-i w t): a component of amplitude a, phase phi gives at the origin
    eta(t)  = r(t) Re{a e^{i phi} e^{-i w t}} = r(t) a cos(w t - phi)
    F_ex(t) = r(t) Re{a X(w, beta) e^{i phi} e^{-i w t}}
with the ramp r(t) = (1 - cos(pi t / T_ramp))/2 for t < T_ramp, else 1 (T_ramp = 0: no ramp).
The ramp multiplies the elevation too, so eta is the wave the body actually feels.
Scene ``direction`` and ``phase`` are in degrees; the HDB's ``wave_direction`` is in radians.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import numpy as np
from scipy.integrate import quad

from hydrolink.protocol.scene import IrregularWave, RegularWave, StillWater


class WaveError(ValueError):
    """A wave definition the HDB cannot serve; ``key`` is the scene key at fault."""

    def __init__(self, key: str, why: str):
        self.key, self.why = key, why
        super().__init__(f"{key}: {why}")


@dataclass(frozen=True)
class WaveComponents:
    omega: np.ndarray       # rad/s (n_c,)
    amplitude: np.ndarray   # m (n_c,)
    phase: np.ndarray       # rad (n_c,)
    direction: float        # rad
    ramp: float             # s
    energy_outside: float   # fraction of the spectrum's m0 outside the HDB's omega range
    kind: str               # "still" | "regular" | "irregular"

    @property
    def size(self) -> int:
        return int(self.omega.size)


def ramp_factor(t, t_ramp: float):
    """Cosine ramp r(t) = (1 - cos(pi t/T))/2 for 0 <= t < T, 1 afterwards (and for T = 0)."""
    t = np.asarray(t, float)
    if t_ramp <= 0:
        return np.ones_like(t)[()]
    r = 0.5 * (1.0 - np.cos(np.pi * np.clip(t, 0.0, t_ramp) / t_ramp))
    return r[()]


def _jonswap_shape(omega, tp: float, gamma: float):
    omega = np.asarray(omega, float)
    wp = 2 * np.pi / tp
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        pm = np.where(omega > 0, omega ** -5.0 * np.exp(-1.25 * (wp / omega) ** 4), 0.0)
    sigma = np.where(omega <= wp, 0.07, 0.09)
    peak = gamma ** np.exp(-((omega - wp) ** 2) / (2 * sigma ** 2 * wp ** 2))
    return pm * peak


def _m0_of_shape(tp: float, gamma: float) -> float:
    wp = 2 * np.pi / tp
    f = lambda w: float(_jonswap_shape(w, tp, gamma))  # noqa: E731
    return sum(quad(f, a, b, limit=200)[0] for a, b in ((0, 0.8 * wp), (0.8 * wp, 1.5 * wp),
                                                        (1.5 * wp, 10 * wp), (10 * wp, np.inf)))


def jonswap_spectrum(hs: float, tp: float, gamma: float = 3.3):
    """S(w) [m^2 s/rad] as a function, normalised once so that int_0^inf S dw = hs^2/16.

    Shape: w^-5 exp(-5/4 (wp/w)^4) gamma^exp(-(w-wp)^2/(2 sigma^2 wp^2)), sigma 0.07 / 0.09."""
    scale = (hs ** 2 / 16.0) / _m0_of_shape(tp, gamma)
    return lambda w: _jonswap_shape(w, tp, gamma) * scale


def jonswap(omega, hs: float, tp: float, gamma: float = 3.3):
    """JONSWAP S(w) at omega (see :func:`jonswap_spectrum`)."""
    return jonswap_spectrum(hs, tp, gamma)(omega)


def pierson_moskowitz(omega, hs: float, tp: float):
    """Pierson-Moskowitz (Bretschneider) S(w) = 5/16 hs^2 wp^4 w^-5 exp(-5/4 (wp/w)^4)."""
    wp = 2 * np.pi / tp
    return (5.0 / 16.0) * hs ** 2 * wp ** 4 * _jonswap_shape(omega, tp, 1.0)


def spectrum_fraction(spectrum, omega_min: float, omega_max: float, m0: float) -> float:
    """Fraction of m0 outside [omega_min, omega_max]."""
    inside = quad(lambda w: float(spectrum(w)), omega_min, omega_max, limit=400)[0]
    return float(max(0.0, 1.0 - inside / m0))


def wave_components(waves, omega_min: float, omega_max: float) -> WaveComponents:
    """Components of the scene's waves over the HDB frequency range [omega_min, omega_max].

    Irregular: ``components`` bins of equal width over the range, one component at each bin
    centre with a = sqrt(2 S(w) dw), phases uniform in [0, 2 pi) from default_rng(seed)."""
    if isinstance(waves, StillWater):
        e = np.zeros(0)
        return WaveComponents(e, e, e, 0.0, 0.0, 0.0, "still")
    direction = float(np.deg2rad(waves.direction))
    if isinstance(waves, RegularWave):
        w = 2 * np.pi / waves.period
        if not (omega_min * (1 - 1e-9) <= w <= omega_max * (1 + 1e-9)):
            raise WaveError("waves.period", f"{waves.period} s (omega {w:.4g} rad/s) is outside the HDB's "
                            f"range {2 * np.pi / omega_max:.4g}-{2 * np.pi / omega_min:.4g} s "
                            f"(omega {omega_min:.4g}-{omega_max:.4g} rad/s)")
        return WaveComponents(np.array([w]), np.array([waves.height / 2]),
                              np.array([np.deg2rad(waves.phase)]), direction, waves.ramp, 0.0, "regular")
    if isinstance(waves, IrregularWave):
        if waves.spectrum == "jonswap":
            spec = jonswap_spectrum(waves.hs, waves.tp, waves.gamma)
        else:
            spec = lambda w: pierson_moskowitz(w, waves.hs, waves.tp)  # noqa: E731
        edges = np.linspace(omega_min, omega_max, waves.components + 1)
        dw = edges[1] - edges[0]
        w = 0.5 * (edges[:-1] + edges[1:])
        amp = np.sqrt(2 * spec(w) * dw)
        phase = np.random.default_rng(waves.seed).uniform(0.0, 2 * np.pi, w.size)
        outside = spectrum_fraction(spec, omega_min, omega_max, waves.hs ** 2 / 16)
        return WaveComponents(w, amp, phase, direction, waves.ramp, outside, "irregular")
    raise WaveError("waves.type", f"unsupported wave type {type(waves).__name__}")


def elevation(comps: WaveComponents, t) -> np.ndarray:
    """eta(t) at the origin (ramp included) for an array of times."""
    t = np.atleast_1d(np.asarray(t, float))
    if comps.size == 0:
        return np.zeros_like(t)
    c = comps.amplitude * np.exp(1j * comps.phase)
    return ramp_factor(t, comps.ramp) * np.real(np.exp(-1j * np.outer(t, comps.omega)) @ c)


def _heading_weights(directions: np.ndarray, beta: float) -> tuple[int, int, float]:
    """Indices (i, j) and weight s so that X(beta) = (1-s) X_i + s X_j; None if not covered."""
    d = np.asarray(directions, float)
    tol = 1e-6
    diff = np.angle(np.exp(1j * (d - beta)))  # wrapped difference in (-pi, pi]
    if np.any(np.abs(diff) < tol):
        i = int(np.argmin(np.abs(diff)))
        return i, i, 0.0
    order = np.argsort(d)
    ds = d[order]
    b = ds[0] + np.mod(beta - ds[0], 2 * np.pi)  # beta mapped into [min, min + 2 pi)
    if ds.size < 2 or b > ds[-1] + tol:
        return None
    k = int(np.clip(np.searchsorted(ds, b) - 1, 0, ds.size - 2))
    s = float((b - ds[k]) / (ds[k + 1] - ds[k]))
    return int(order[k]), int(order[k + 1]), s


def interpolate_excitation(omega_hdb: np.ndarray, directions: np.ndarray, x: np.ndarray,
                           omega: np.ndarray, beta: float) -> np.ndarray:
    """X at (omega, beta): x (n_w, n_b, n) complex -> (n_c, n); linear in re/im in w and heading.

    Raises WaveError("waves.direction") if beta is not within the HDB's headings (no wrap-around
    interpolation beyond the outermost headings)."""
    hw = _heading_weights(directions, beta)
    if hw is None:
        raise WaveError("waves.direction", f"{np.rad2deg(beta):.6g} deg is not covered by the HDB's headings "
                        f"{np.round(np.rad2deg(directions), 4).tolist()} deg")
    i, j, s = hw
    xb = (1 - s) * x[:, i, :] + s * x[:, j, :]  # (n_w, n)
    omega = np.asarray(omega, float)
    if omega.size == 0:
        return np.zeros((0, x.shape[2]), complex)
    re = np.stack([np.interp(omega, omega_hdb, xb[:, m].real) for m in range(xb.shape[1])], axis=1)
    im = np.stack([np.interp(omega, omega_hdb, xb[:, m].imag) for m in range(xb.shape[1])], axis=1)
    return re + 1j * im


class WaveForcing:
    """Per-step excitation and elevation: one real matvec over [cos(w t); sin(w t)].

    Re{c e^{-i w t}} = Re(c) cos(w t) + Im(c) sin(w t); the elevation is one extra row."""

    def __init__(self, comps: WaveComponents, x_components: np.ndarray):
        """x_components (n_c, n): X at the component frequencies and the wave heading."""
        self.comps = comps
        n = x_components.shape[1]
        c = comps.amplitude * np.exp(1j * comps.phase)  # (n_c,)
        coef = np.vstack([x_components.T * c[None, :], c[None, :]])  # (n+1, n_c)
        self._m = np.ascontiguousarray(np.hstack([coef.real, coef.imag]))  # (n+1, 2 n_c)
        self._trig = np.empty(2 * comps.size)
        self._n = n
        self._still = comps.size == 0
        self._w0 = float(comps.omega[0]) if comps.size else 0.0

    def __call__(self, t: float) -> tuple[np.ndarray, float]:
        """(F_ex (n,), eta) at time t."""
        if self._still:
            return np.zeros(self._n), 0.0
        nc = self.comps.size
        if nc == 1:  # regular wave: scalar trig is cheaper than array calls
            wt = self._w0 * t
            out = self._m[:, 0] * math.cos(wt) + self._m[:, 1] * math.sin(wt)
        else:
            wt = self.comps.omega * t
            np.cos(wt, out=self._trig[:nc])
            np.sin(wt, out=self._trig[nc:])
            out = self._m @ self._trig
        r = self.comps.ramp
        if r > 0 and t < r:
            out *= 0.5 * (1.0 - math.cos(math.pi * max(t, 0.0) / r))
        return out[:-1], float(out[-1])
