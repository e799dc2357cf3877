"""Incident waves: components, ramp, elevation and excitation by frequency-domain superposition.

Internal convention exp(-i w t): a component of amplitude a, phase phi gives at the origin
    eta(t)  = r(t) Re{a e^{i phi} e^{-i w t}} = r(t) a cos(w t - phi)
    F_ex(t) = r(t) Re{a X(w, beta) e^{i phi} e^{-i w t}}
with the ramp r(t) = (1 - cos(pi t / T_ramp))/2 for t < T_ramp, else 1 (T_ramp = 0: no ramp).
The ramp multiplies the elevation too, so eta is the wave the body actually feels.
Scene ``direction`` and ``phase`` are in degrees; the HDB's ``wave_direction`` is in radians.

Excitation by convolution (``[waves] excitation = "convolution"``, and ``type = "elevation"``).
With the transform pair of the exp(-i w t) convention,
    eta(t) = (1/2 pi) int_-inf^inf eta^(w) e^{-i w t} dw,   eta^(w) = int eta(t) e^{i w t} dt,
a linear force with transfer function X (F^ = X eta^, X(-w) = conj X(w) for a real force) is
    F_ex(t) = int_-inf^inf K_ex(tau) eta(t - tau) dtau,
    K_ex(t) = (1/2 pi) int_-inf^inf X(w) e^{-i w t} dw = (1/pi) Re int_0^inf X(w) e^{-i w t} dw
            = (1/pi) int_0^inf [Re X(w) cos(w t) + Im X(w) sin(w t)] dw.
Check on one component eta = Re{c e^{-i w t}}: int K(tau) c e^{-i w (t - tau)} dtau =
c e^{-i w t} int K(tau) e^{i w tau} dtau = c X(w) e^{-i w t}: the superposition formula above.
K_ex is non-causal (a body downstream of the origin feels the wave later: X ~ e^{i k x} puts
K_ex's peak at t = x / c_g > 0; upstream, at t < 0, i.e. the force needs the *future* eta).
X is known on the HDB grid [w_1, w_n] only. It is continued linearly to Re X(w_1) at w = 0 and
to 0 at 1.1 w_n (cut at pi/dt against aliasing), a continuous piecewise-linear X, whose
transform is evaluated in closed form (:func:`excitation_irf`) and decays like 1/t^2. The
convolution is the trapezoidal sum over tau_j = j dt, |j| <= M = round(T_c/dt); the ramp
multiplies the convolved force (as it multiplies the superposed one).
"""

from __future__ import annotations

import math
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from hydrolink.protocol.errors import KeyedError
from hydrolink.protocol.scene import ElevationWave, IrregularWave, RegularWave, StillWater
from hydrolink.server.allocation import require_size
from hydrolink.server.radiation.irf import irf_samples
from hydrolink.server.sea.dispersion import wave_number


class WaveError(KeyedError):
    """A wave definition the HDB cannot serve; ``key`` is the scene key at fault."""

    def __init__(self, key: str, why: str):
        super().__init__("", key, why)


@dataclass(frozen=True)
class WaveComponents:
    omega: np.ndarray       # rad/s (n_c,)
    amplitude: np.ndarray   # m (n_c,)
    phase: np.ndarray       # rad (n_c,)
    direction: float        # rad
    ramp: float             # s
    energy_outside: float   # fraction of the spectrum's m0 outside the HDB's omega range
    kind: str               # "still" | "regular" | "irregular" | "elevation" | "gauges"
    headings: np.ndarray | None = None  # rad (n_c,): each component's heading (directional spreading)
    heading_key: str | None = None      # the scene key a heading is refused under (None: waves.direction/spreading)
    intrinsic: np.ndarray | None = None  # rad/s (n_c,): in a current with the Doppler shift, the frequencies
    #                                      relative to the water (``omega`` is then the encounter frequency)
    fit_residual: float = 0.0           # a sea from gauges: the share of the records' variance in the band
    #                                      that the fitted components leave unexplained (server/sea/gauges.py)

    @property
    def hdb_omega(self) -> np.ndarray:
        """The frequencies the HDB is read at and the wave numbers follow from (the intrinsic ones)."""
        return self.omega if self.intrinsic is None else self.intrinsic

    def wave_numbers(self, gravity: float, depth: float) -> np.ndarray:
        """k (rad/m) of each component: linear dispersion of its intrinsic frequency."""
        return wave_number(self.hdb_omega, gravity, depth)

    def heading_of(self) -> np.ndarray:
        """Each component's heading (rad)."""
        return np.full(self.size, self.direction) if self.headings is None else self.headings

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


def ramp_at(t: float, t_ramp: float) -> float:
    """:func:`ramp_factor` at one time, as a float (the per-step hot paths: no array calls)."""
    return 0.5 * (1.0 - math.cos(math.pi * max(t, 0.0) / t_ramp)) if (t_ramp > 0 and t < t_ramp) else 1.0


def _jonswap_shape(omega, tp: float, gamma: float):
    omega = np.asarray(omega, float)
    wp = 2 * np.pi / tp
    with np.errstate(divide="ignore", over="ignore", invalid="ignore"):
        pm = np.where(omega > 0, omega ** -5.0 * np.exp(-1.25 * (wp / omega) ** 4), 0.0)
    sigma = np.where(omega <= wp, 0.07, 0.09)
    peak = gamma ** np.exp(-((omega - wp) ** 2) / (2 * sigma ** 2 * wp ** 2))
    return pm * peak


def _m0_of_shape(tp: float, gamma: float) -> float:
    from scipy.integrate import quad      # here, not at the top: it adds 0.6 s to every server's start-up
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


#: the scene's ``waves.spectrum`` names: S(omega) of (hs, tp, gamma) and the name a report shows
SPECTRA = {
    "jonswap": (lambda hs, tp, gamma: jonswap_spectrum(hs, tp, gamma), "JONSWAP (gamma {gamma:g})"),
    "pierson-moskowitz": (lambda hs, tp, gamma: (lambda w: pierson_moskowitz(w, hs, tp)), "Pierson-Moskowitz"),
}


def wave_spectrum(waves: IrregularWave) -> tuple[Callable[[np.ndarray], np.ndarray], str]:
    """S(omega) (m^2 s/rad) of an irregular sea and its name (:data:`SPECTRA`)."""
    make, name = SPECTRA[waves.spectrum]
    return make(waves.hs, waves.tp, waves.gamma), name.format(gamma=waves.gamma)


def spectrum_fraction(spectrum, omega_min: float, omega_max: float, m0: float) -> float:
    """Fraction of m0 outside [omega_min, omega_max]."""
    from scipy.integrate import quad      # (as in _m0_of_shape)
    inside = quad(lambda w: float(spectrum(w)), omega_min, omega_max, limit=400)[0]
    return float(max(0.0, 1.0 - inside / m0))


def wave_components(waves, omega_min: float, omega_max: float) -> WaveComponents:
    """Components of the scene's waves over the HDB frequency range [omega_min, omega_max].

    Irregular: ``components`` bins of equal width over the range, one component at each bin
    centre with a = sqrt(2 S(w) dw), phases uniform in [0, 2 pi) from default_rng(seed). With
    cos-2s spreading over n directions (equal-energy sectors, :func:`cos2s_directions`) each bin
    holds n components a / sqrt(n), direction j at the centre of the bin's j-th sub-bin of width
    dw / n (direction-major order; variance per bin exactly that of the unidirectional sea)."""
    if isinstance(waves, StillWater):
        e = np.zeros(0)
        return WaveComponents(e, e, e, 0.0, 0.0, 0.0, "still")
    direction = float(np.deg2rad(waves.direction))
    if isinstance(waves, ElevationWave):  # no components: the series comes from a file
        e = np.zeros(0)
        return WaveComponents(e, e, e, direction, waves.ramp, 0.0, "elevation")
    if isinstance(waves, RegularWave):
        w = 2 * np.pi / waves.period
        if not (omega_min * (1 - 1e-9) <= w <= omega_max * (1 + 1e-9)):
            raise WaveError("waves.period", f"{waves.period} s (omega {w:.4g} rad/s) is outside the HDB's "
                            f"range {2 * np.pi / omega_max:.4g}-{2 * np.pi / omega_min:.4g} s "
                            f"(omega {omega_min:.4g}-{omega_max:.4g} rad/s)")
        return WaveComponents(np.array([w]), np.array([waves.height / 2]),
                              np.array([np.deg2rad(waves.phase)]), direction, waves.ramp, 0.0, "regular")
    if isinstance(waves, IrregularWave):
        spec, _ = wave_spectrum(waves)
        if waves.omega_range is not None:
            lo, hi = waves.omega_range
            if lo < omega_min * (1 - 1e-9) or hi > omega_max * (1 + 1e-9):
                raise WaveError("waves.omega_range", f"[{lo:g}, {hi:g}] rad/s reaches outside the HDB's range "
                                f"{omega_min:.4g}-{omega_max:.4g} rad/s")
            omega_min, omega_max = lo, hi
        n_dir = waves.spreading_directions
        require_size("waves.components", "the wave components (amplitude, frequency, phase, heading)",
                     (4, n_dir, waves.components), hint=f"fewer components ({waves.components}) or directions ({n_dir})")
        edges = np.linspace(omega_min, omega_max, waves.components + 1)
        dw = edges[1] - edges[0]
        w = 0.5 * (edges[:-1] + edges[1:])
        amp = np.sqrt(2 * spec(w) * dw)
        outside = spectrum_fraction(spec, omega_min, omega_max, waves.hs ** 2 / 16)
        # phases: one draw of n_dir x n_c (direction-major); with no spreading the same draw as ever
        phase = np.random.default_rng(waves.seed).uniform(0.0, 2 * np.pi, n_dir * w.size)
        if waves.spreading == "none":
            return WaveComponents(w, amp, phase, direction, waves.ramp, outside, "irregular")
        # each frequency bin is split into n_dir sub-bins, one per direction (sub-bin centres): every
        # component has its own frequency, so the elevation at a point is ergodic (its time variance
        # tends to m0; equal frequencies in several directions would beat into a random variance)
        heads, weights = cos2s_directions(waves.spreading_s, n_dir, direction)
        shift = ((np.arange(n_dir) + 0.5) / n_dir - 0.5) * dw
        return WaveComponents((w[None, :] + shift[:, None]).reshape(-1),
                              (np.sqrt(weights)[:, None] * amp[None, :]).reshape(-1), phase,
                              direction, waves.ramp, outside, "irregular", np.repeat(heads, w.size))
    raise WaveError("waves.type", f"unsupported wave type {type(waves).__name__}")


# ------------------------------------------------------------------ directional spreading

def cos2s_normalisation(s: float) -> float:
    """C(s) = Gamma(s + 1) / (2 sqrt(pi) Gamma(s + 1/2)), so that int_-pi^pi C cos^2s(theta/2) = 1."""
    from scipy.special import gammaln
    return float(np.exp(gammaln(s + 1.0) - gammaln(s + 0.5)) / (2.0 * np.sqrt(np.pi)))


def cos2s(theta, s: float):
    """Spreading function D(theta) = C(s) cos^2s(theta/2) on (-pi, pi] (theta from the mean direction)."""
    th = np.angle(np.exp(1j * np.asarray(theta, float)))
    return cos2s_normalisation(s) * np.abs(np.cos(th / 2.0)) ** (2.0 * s)


def cos2s_directions(s: float, n: int, mean: float = 0.0, fine: int = 40001) -> tuple[np.ndarray, np.ndarray]:
    """``n`` equal-energy sectors of the cos-2s spreading: headings (rad, each sector's centroid
    int theta D / int D, plus ``mean``) and weights (1/n each, summing to 1 exactly).

    The sectors of :func:`equal_energy_sectors` on a fine grid over (-pi, pi]; by symmetry the
    weighted mean of the headings is ``mean``."""
    th = np.linspace(-np.pi, np.pi, fine)
    heads, weights = equal_energy_sectors(th, cos2s(th, s), n)
    heads = 0.5 * (heads - heads[::-1])  # exact symmetry about the mean
    return heads + mean, weights


def equal_energy_sectors(theta: np.ndarray, density: np.ndarray, n: int) -> tuple[np.ndarray, np.ndarray]:
    """``n`` sectors of equal energy of a directional density given at ``theta`` (rad, increasing;
    linear between): each sector's heading is its centroid int theta D / int D and its weight 1/n.
    The sectors' edges are the quantiles k/n of D's cumulative (trapezoid) integral."""
    th = np.asarray(theta, float)
    d = np.asarray(density, float)
    cdf = np.concatenate([[0.0], np.cumsum(0.5 * (d[1:] + d[:-1]) * np.diff(th))])
    first = np.concatenate([[0.0], np.cumsum(0.5 * (th[1:] * d[1:] + th[:-1] * d[:-1]) * np.diff(th))])
    edges = np.interp(np.linspace(0.0, 1.0, n + 1), cdf / cdf[-1], th)
    mass = np.diff(np.interp(edges, th, cdf))
    moment = np.diff(np.interp(edges, th, first))
    with np.errstate(invalid="ignore", divide="ignore"):
        heads = np.where(mass > 0, moment / np.where(mass > 0, mass, 1.0), 0.5 * (edges[1:] + edges[:-1]))
    return heads, np.full(n, 1.0 / n)


def elevation(comps: WaveComponents, t) -> np.ndarray:
    """eta(t) at the origin (ramp included) for an array of times."""
    t = np.atleast_1d(np.asarray(t, float))
    if comps.size == 0:
        return np.zeros_like(t)
    c = comps.amplitude * np.exp(1j * comps.phase)
    return ramp_factor(t, comps.ramp) * np.real(np.exp(-1j * np.outer(t, comps.omega)) @ c)


class WavePhases:
    """[cos(w t); sin(w t)] of the wave components, computed once per time for every user of a
    step (the linear excitation, the incident-wave kinematics of drag and Morison terms)."""

    def __init__(self, omega: np.ndarray):
        self.omega = np.array(omega, float)
        self._trig = np.empty(2 * self.omega.size)
        #: (2 n_c,) read-only: the values of the last :meth:`at` (views of it follow each step)
        self.values = self._trig.view()
        self.values.flags.writeable = False
        self._t: float | None = None

    def at(self, t: float) -> np.ndarray:
        """(2 n_c,) read-only [cos(w t); sin(w t)] at time ``t`` (computed when ``t`` changes)."""
        if t != self._t:
            n = self.omega.size
            wt = self.omega * t
            np.cos(wt, out=self._trig[:n])
            np.sin(wt, out=self._trig[n:])
            self._t = t
        return self.values


class WaveForcing:
    """Per-step excitation and elevation: one real matvec over [cos(w t); sin(w t)].

    Re{c e^{-i w t}} = Re(c) cos(w t) + Im(c) sin(w t); the elevation is one extra row."""

    def __init__(self, comps: WaveComponents, x_components: np.ndarray, phases: WavePhases | None = None):
        """x_components (n_c, n): X at the component frequencies and the wave heading; ``phases``
        the step's shared [cos; sin] of ``comps`` (None: its own)."""
        self.comps = comps
        n = x_components.shape[1]
        c = comps.amplitude * np.exp(1j * comps.phase)  # (n_c,)
        coef = np.vstack([x_components.T * c[None, :], c[None, :]])  # (n+1, n_c)
        self._m = np.ascontiguousarray(np.hstack([coef.real, coef.imag]))  # (n+1, 2 n_c)
        if comps.size == 1:   # regular wave: the two columns contiguous
            self._m0, self._m1 = self._m[:, 0].copy(), self._m[:, 1].copy()
        self._phases = WavePhases(comps.omega) if phases is None else phases
        self._n = n
        self._still = comps.size == 0
        self._w0 = float(comps.omega[0]) if comps.size else 0.0

    @property
    def matrix(self) -> np.ndarray:
        """(n + 1, 2 n_c) read-only: the force rows then the elevation row over [cos wt; sin wt]
        (before the ramp): what a step sums (the fused step's, server/fused/step.py)."""
        view = self._m.view()
        view.flags.writeable = False
        return view

    def sum(self, t: float, matrix: np.ndarray | None = None) -> np.ndarray:
        """(n + 1,) ``matrix`` (default :attr:`matrix`; another of its shape: a passive-yaw body's,
        server/sea/passive_yaw.py) over [cos wt; sin wt] at time t, before the ramp: the same
        arithmetic for every matrix, so equal matrices give equal bits."""
        if self.comps.size == 1:  # regular wave: scalar trig is cheaper than array calls
            wt = self._w0 * t
            if matrix is None:
                return self._m0 * math.cos(wt) + self._m1 * math.sin(wt)
            return matrix[:, 0] * math.cos(wt) + matrix[:, 1] * math.sin(wt)
        return (self._m if matrix is None else matrix) @ self._phases.at(t)

    def __call__(self, t: float) -> tuple[np.ndarray, float]:
        """(F_ex (n,), eta) at time t."""
        if self._still:
            return np.zeros(self._n), 0.0
        out = self.sum(t)
        out *= ramp_at(t, self.comps.ramp)
        return out[:-1], float(out[-1])


# ------------------------------------------------------------------ excitation by convolution

EXCITATION_TAPER = 0.1  # X is continued linearly from X(w_n) to 0 at (1 + EXCITATION_TAPER) w_n


def excitation_nodes(omega: np.ndarray, x: np.ndarray, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """The continuous piecewise-linear X(w) on [0, W] whose transform is K_ex (module docstring).

    ``omega`` (n_w,) increasing, ``x`` (n_w, n) complex. Nodes: 0 (value Re X(w_1)), the HDB
    frequencies up to w_hi = min(w_n, W / (1 + taper)), w_hi (interpolated), W = min((1 + taper)
    w_n, pi/dt) with value 0. Returns (nodes (L,), values (L, n))."""
    omega = np.asarray(omega, float)
    x = np.asarray(x, complex).reshape(omega.size, -1)
    top = min((1.0 + EXCITATION_TAPER) * omega[-1], np.pi / dt)
    hi = min(omega[-1], top / (1.0 + EXCITATION_TAPER))
    keep = omega < hi * (1 - 1e-12)
    x_hi = np.array([np.interp(hi, omega, x[:, m].real) + 1j * np.interp(hi, omega, x[:, m].imag)
                     for m in range(x.shape[1])])
    nodes = [omega[keep], [hi, top]]
    values = [x[keep], x_hi[None, :], np.zeros((1, x.shape[1]), complex)]
    if omega[0] > 0 and keep.any():
        nodes.insert(0, [0.0])
        values.insert(0, x[:1].real.astype(complex))
    return np.concatenate(nodes), np.concatenate(values, axis=0)


def excitation_irf(nodes: np.ndarray, values: np.ndarray, t) -> np.ndarray:
    """K_ex(t) = (1/pi) Re int_0^W f(w) e^{-i w t} dw for the continuous piecewise-linear f given
    at ``nodes`` (L,) with ``values`` (L, n) complex and f(W) = values[-1]; exact (two
    integrations by parts: (i/t)[f e^{-iwt}]_0^W + (1/t^2) sum_s m_s [e^{-iwt}]_{w_s}^{w_s+1},
    m_s the segment slopes). Returns (n_t, n)."""
    t = np.atleast_1d(np.asarray(t, float))
    w = np.asarray(nodes, float)
    f = np.asarray(values, complex).reshape(w.size, -1)
    dw = np.diff(w)
    slope = np.diff(f, axis=0) / dw[:, None]
    out = np.empty((t.size, f.shape[1]))
    zero = t == 0.0
    if zero.any():
        out[zero] = (0.5 * (f[1:] + f[:-1]) * dw[:, None]).sum(axis=0).real / np.pi
    tz = t[~zero]
    rows = np.flatnonzero(~zero)
    chunk = max(1, int(4e6 // max(w.size, 1)))
    for a in range(0, tz.size, chunk):
        tt = tz[a:a + chunk]
        e = np.exp(-1j * np.outer(tt, w))                    # (n_t, L)
        i = (1j / tt)[:, None] * (e[:, -1:] * f[-1][None, :] - f[0][None, :]) \
            + (1.0 / tt ** 2)[:, None] * (np.diff(e, axis=1) @ slope)
        out[rows[a:a + chunk]] = i.real / np.pi
    return out


def convolution_kernel(omega: np.ndarray, x: np.ndarray, dt: float, duration: float) -> np.ndarray:
    """Trapezoid-weighted samples dt w_j K_ex(j dt), j = -M..M, M = round(duration/dt): (2M+1, n)."""
    m = irf_samples(duration, dt, at_least=1)
    nodes, values = excitation_nodes(omega, x, dt)
    k = excitation_irf(nodes, values, np.arange(-m, m + 1) * dt) * dt
    k[[0, -1]] *= 0.5
    return k


def kernel_transfer(kernel: np.ndarray, dt: float, omega) -> np.ndarray:
    """What the discrete convolution realises: sum_j kernel_j e^{i w j dt} (n_w, n) (equals X(w) up
    to the truncation at +-T_c and the sampling)."""
    m = (kernel.shape[0] - 1) // 2
    tau = np.arange(-m, m + 1) * dt
    return np.exp(1j * np.outer(np.asarray(omega, float), tau)) @ kernel


class ConvolutionForcing:
    """Per-step excitation by convolution (same interface as :class:`WaveForcing`).

    ``kernels`` (S, 2M+1, n): one trapezoid-weighted excitation IRF per elevation series (one
    series per heading); ``eta(k0, k1)`` -> (S, k1 - k0) the series at t = k dt, k0 <= k < k1
    (raises ModelError-like errors itself when out of range). The forces are computed a block of
    steps at a time by FFT convolution, so a step is a lookup."""

    def __init__(self, kernels: np.ndarray, eta, dt: float, ramp: float, block: int = 4096):
        self.kernels = np.asarray(kernels, float)
        self._eta = eta
        self.dt = float(dt)
        self.ramp = float(ramp)
        self.m = (self.kernels.shape[1] - 1) // 2
        self.block = max(int(block), 4 * self.m, 256)
        self._k0, self._f, self._e = 0, None, None
        n = self.block + 4 * self.m                               # >= len(segment) + len(kernel) - 1
        self._nfft = 1 << int(math.ceil(math.log2(n)))
        require_size("waves.excitation_irf_duration", "the excitation kernels' spectra",
                     (self.kernels.shape[0], self._nfft // 2 + 1, self.kernels.shape[2]), 16,
                     hint="a shorter excitation_irf_duration or a longer dt")
        self._kf = np.fft.rfft(self.kernels, self._nfft, axis=1)  # (S, nfft/2 + 1, n)

    def _compute(self, k0: int) -> None:
        m, b = self.m, self.block
        seg = np.atleast_2d(self._eta(k0 - m, k0 + b + m))      # (S, b + 2m)
        spec = np.einsum("sf,sfn->fn", np.fft.rfft(seg, self._nfft, axis=1), self._kf)
        full = np.fft.irfft(spec, self._nfft, axis=0)             # full linear convolution
        self._k0, self._f, self._e = k0, full[2 * m:2 * m + b], seg[:, m:m + b].sum(axis=0)

    def __call__(self, t: float) -> tuple[np.ndarray, float]:
        k = int(round(t / self.dt))
        if self._f is None or not (self._k0 <= k < self._k0 + self.block):
            self._compute(k)
        i = k - self._k0
        fac = ramp_at(t, self.ramp)
        return self._f[i] * fac, float(self._e[i] * fac)


# ------------------------------------------------------------------ elevation time series (files)

_SEPARATORS = str.maketrans({",": " ", ";": " ", ":": " "})   # column separators of elevation text files


def read_elevation(path, key: str = "waves.file", variable: str = "eta") -> tuple[np.ndarray, np.ndarray]:
    """(time, eta) from a text file (two columns time, eta; header lines allowed before the first
    row; separated by whitespace, a comma, a semicolon or a colon: CSV, and HydroChrono's ``t : eta``
    eta files) or a NetCDF file (variable ``variable``, default ``eta``, over ``time``).
    WaveError(key) naming the file when it is missing or malformed."""
    from pathlib import Path
    path = Path(path)
    if not path.is_file():
        raise WaveError(key, f"elevation file not found: {path}")
    if path.suffix.lower() in (".nc", ".nc4", ".netcdf", ".cdf", ".h5"):
        import xarray as xr
        try:
            with xr.open_dataset(path, engine="netcdf4") as ds:
                if variable not in ds:
                    raise WaveError(key, f"{path}: no variable {variable!r} (it holds {sorted(map(str, ds.data_vars))})")
                da = ds[variable]
                if da.dims != ("time",) or "time" not in da.coords:
                    raise WaveError(key, f"{path}: {variable!r} must be 1-D over a 'time' coordinate (dims {da.dims})")
                t = np.asarray(da["time"].values)
                if np.issubdtype(t.dtype, np.timedelta64):
                    t = t / np.timedelta64(1, "s")
                return np.asarray(t, float), np.asarray(da.values, float)
        except WaveError:
            raise
        except Exception as exc:  # noqa: BLE001 - any reader failure is a malformed file
            raise WaveError(key, f"{path}: not a readable NetCDF file ({exc})") from None
    rows: list[tuple[float, float]] = []
    try:
        text = path.read_text()
    except (OSError, UnicodeDecodeError) as exc:
        raise WaveError(key, f"{path}: cannot read ({exc})") from None
    for n, line in enumerate(text.splitlines(), 1):
        line = line.split("#", 1)[0].strip()
        if not line:
            continue
        parts = line.translate(_SEPARATORS).split()
        try:
            vals = [float(p) for p in parts]
        except ValueError:
            if not rows:
                continue  # header line(s) before the first data row
            raise WaveError(key, f"{path}: line {n}: not two numbers (time, eta): {line!r}") from None
        if len(vals) != 2:
            raise WaveError(key, f"{path}: line {n}: expected two columns (time, eta), got {len(vals)}")
        rows.append((vals[0], vals[1]))
    if not rows:
        first = next((ln.strip() for ln in text.splitlines() if ln.strip()), "")
        raise WaveError(key, f"{path}: no data rows: expected lines of two numbers, time and eta, separated by "
                             f"spaces, ',', ';' or ':' (HydroChrono's 't : eta'); its first line is {first[:80]!r}")
    a = np.asarray(rows, float)
    return a[:, 0], a[:, 1]


@dataclass(frozen=True)
class ElevationSeries:
    """An elevation file put on the simulation grid: eta_k = eta(start + k dt), k >= k_first."""
    eta: np.ndarray
    k_first: int
    start: float
    resampled: bool
    key: str = "waves.file"

    def __call__(self, k0: int, k1: int) -> np.ndarray:
        i0, i1 = k0 - self.k_first, k1 - self.k_first
        out = np.zeros(k1 - k0)
        a, b = max(i0, 0), min(i1, self.eta.size)
        if b > a:
            out[a - i0:b - i0] = self.eta[a:b]
        return out[None, :]


def elevation_on_grid(time: np.ndarray, eta: np.ndarray, dt: float, n_steps: int, irf_duration: float,
                      start: float | None, omega_max: float, key: str = "waves.file") -> ElevationSeries:
    """Check an elevation series and sample it at start + k dt for k = -M .. n_steps + M + 1
    (M = round(irf_duration/dt): the convolution's past and future).

    Taken as it is when sampled uniformly at dt with start on a sample; otherwise resampled by a
    cubic spline, which is refused (WaveError) when a gap exceeds pi/omega_max (the file cannot
    carry the HDB's highest frequency). Also refused: fewer than 4 rows, non-finite values, times
    not strictly increasing, and a file that does not cover [start - T_c, start + duration + T_c]."""
    t = np.asarray(time, float).reshape(-1)
    e = np.asarray(eta, float).reshape(-1)
    if t.size != e.size or t.size < 4:
        raise WaveError(key, f"needs at least 4 samples of (time, eta), got {t.size}")
    if not (np.all(np.isfinite(t)) and np.all(np.isfinite(e))):
        bad = int(np.flatnonzero(~(np.isfinite(t) & np.isfinite(e)))[0])
        raise WaveError(key, f"non-finite value at sample {bad} (t = {t[bad]!r})")
    h = np.diff(t)
    if np.any(h <= 0):
        bad = int(np.flatnonzero(h <= 0)[0])
        raise WaveError(key, f"time must increase strictly: sample {bad + 1} (t = {t[bad + 1]:.9g} s) follows "
                             f"t = {t[bad]:.9g} s")
    m = irf_samples(irf_duration, dt, at_least=1)
    if start is None:
        start = float(t[0] + m * dt)
    need0, need1 = start - m * dt, start + (n_steps + m + 1) * dt
    slack = 1e-6 * dt
    if t[0] > need0 + slack or t[-1] < need1 - slack:
        raise WaveError(key, f"too short: the run needs eta over [{need0:.6g}, {need1:.6g}] s of the file "
                             f"(start {start:.6g} s - excitation_irf_duration .. start + duration + "
                             f"excitation_irf_duration), the file covers [{t[0]:.6g}, {t[-1]:.6g}] s")
    k_first = -m
    n = n_steps + 2 * m + 2
    require_size("simulation.duration", "the elevation series on the step grid", (n,),
                 hint="a shorter run or a longer dt")
    h_mean = (t[-1] - t[0]) / (t.size - 1)
    uniform = np.max(np.abs(h - h_mean)) <= 1e-6 * h_mean
    offset = (need0 - t[0]) / dt
    if uniform and abs(h_mean - dt) <= 1e-9 * dt and abs(offset - round(offset)) < 1e-6:
        i0 = int(round(offset))
        return ElevationSeries(e[i0:i0 + n].copy(), k_first, float(start), False, key)
    if h.max() > np.pi / omega_max:
        raise WaveError(key, f"sampled every {h.max():.4g} s (largest gap), coarser than pi/w_max = "
                             f"{np.pi / omega_max:.4g} s for the HDB's highest frequency {omega_max:.4g} rad/s: "
                             "it cannot be resampled to dt without losing waves the HDB covers; give it at dt")
    from scipy.interpolate import CubicSpline
    grid = need0 + np.arange(n) * dt
    return ElevationSeries(CubicSpline(t, e)(np.clip(grid, t[0], t[-1])), k_first, float(start), True, key)
