"""A directional linear sea reconstructed from elevation records at several gauges
(``[waves] type = "gauges"``, protocol/scene.py ``GaugeWaves``; docs/waves.md).

Method (per frequency, a least-squares fit over direction bins). The G records share one time grid
t_m = t0 + m dt, m = 0 .. N-1 (checked: same length, step and first time). Over that window a
record is exactly its discrete Fourier series at w_n = 2 pi n / (N dt); the gauge at x_g carries
at w_n the complex amplitude C_gn = (2/N) conj(X_gn) e^{i w_n t0} (X = rfft of the record), so
that eta_g(t_m) = sum_n Re{C_gn e^{-i w_n t_m}} (+ the mean and Nyquist terms, left out). The sea
is modelled as one component per frequency bin and scene direction theta_j:
eta(x, t) = sum_nj Re{c_nj e^{i(k_n (x cos theta_j + y sin theta_j) - w_n t)}}, so at each w_n
C_n = E_n c_n with E_n[g, j] = exp(i k_n e_j . x_g) (G x J), solved in the least-squares sense
(c_n = E_n^+ C_n). A component's amplitude is |c_nj|, its phase arg c_nj (moved to simulation
t = 0 at file time ``start``), its heading theta_j. A record of the surface slope (a pitch-roll
buoy's d eta/dx, d eta/dy) enters divided by k_n, its row i cos theta_j (i sin theta_j) times the
exponential: one such buoy (elevation and both slopes at one point) resolves three directions at
every frequency alike (its rows do not depend on k), weighting slopes as elevation k_n^-1.

Identifiability: E_n must have full column rank with a bounded condition number at every
frequency of the band: J <= G, and the array must be large against the wavelength (k D >~ 1, D
its extent, else every direction looks the same at low frequency) and its spacings below half a
wavelength along the directions' differences (else two directions alias at high frequency). A
frequency where cond(E_n) exceeds ``max_condition`` (noise in the records is amplified that much)
is refused naming ``waves.directions`` with the frequencies it fails at; narrowing
``waves.omega_range`` to where the array resolves the directions, or fewer directions, is the fix.
With J < G the fit is over-determined (least squares): the share of the records' band variance
it leaves unexplained is ``fit_residual`` (a setup warning naming ``waves.directions`` above 5 %). Energy at directions between the bins is spread over
the neighbouring bins (the sea between the gauges is then only approximated), and the sea is
periodic with the window: the run must stay inside the records (checked on the scene).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrolink.protocol.scene import GaugeWaves, Water
from hydrolink.server.sea.dispersion import wave_number
from hydrolink.server.sea.waves import WaveComponents, WaveError


@dataclass(frozen=True)
class GaugeRecords:
    """The gauges' records on their common grid: positions (G, 2) m, first time t0 and step dt (s),
    records (G, N) (elevation m or slope m/m) and what each holds (``quantity``: 0 elevation,
    1 slope d eta/dx, 2 slope d eta/dy)."""
    positions: np.ndarray
    t0: float
    dt: float
    eta: np.ndarray
    quantity: np.ndarray

    @property
    def slope(self) -> np.ndarray:
        """(G,) bool: the records of a slope."""
        return self.quantity > 0

    def factors(self, heads: np.ndarray) -> np.ndarray:
        """(G, J): what a unit component of heading theta_j puts in each record, over its wave
        number for a slope: 1 (elevation), i cos theta_j (d eta/dx / k), i sin theta_j (d eta/dy / k)."""
        return np.choose(self.quantity[:, None], [np.ones(heads.size, complex), 1j * np.cos(heads),
                                                  1j * np.sin(heads)])

    @property
    def duration(self) -> float:
        """s: the window the Fourier series spans (N dt)."""
        return self.eta.shape[1] * self.dt


def gauge_records(waves: GaugeWaves) -> GaugeRecords:
    """The records of ``waves.gauges`` (their ``time``/``eta`` filled by Scene.with_gauges) checked
    to share one uniform grid; WaveError naming ``waves.gauges[i].file`` and the file otherwise."""
    first = None
    rows = []
    for i, gauge in enumerate(waves.gauges):
        key = f"waves.gauges[{i}].file"
        if gauge.time is None or gauge.eta is None:
            raise WaveError(key, f"the record of {gauge.file!r} did not reach the model: a client reads the file "
                                 "and sends it (hello.gauges, SPEC §5.1)")
        t, e = np.asarray(gauge.time, float), np.asarray(gauge.eta, float)
        if t.size != e.size or t.size < 8:
            raise WaveError(key, f"{gauge.file}: needs at least 8 samples of (time, eta), got {min(t.size, e.size)}")
        if not (np.all(np.isfinite(t)) and np.all(np.isfinite(e))):
            raise WaveError(key, f"{gauge.file}: non-finite value at sample {int(np.flatnonzero(~np.isfinite(t + e))[0])}")
        h = np.diff(t)
        step = (t[-1] - t[0]) / (t.size - 1)
        if step <= 0 or np.max(np.abs(h - step)) > 1e-6 * step:
            raise WaveError(key, f"{gauge.file}: not sampled at a uniform step (steps from {h.min():.6g} to "
                                 f"{h.max():.6g} s): the gauges' records are fitted on one uniform grid")
        if first is None:
            first = (t.size, t[0], step, waves.gauges[0].file)
        elif t.size != first[0]:
            raise WaveError(key, f"{gauge.file}: {t.size} samples where {first[3]} (waves.gauges[0].file) has "
                                 f"{first[0]}: every gauge's record must cover the same times")
        elif abs(step - first[2]) > 1e-9 * first[2]:
            raise WaveError(key, f"{gauge.file}: sampled every {step:.9g} s where {first[3]} (waves.gauges[0].file) "
                                 f"is sampled every {first[2]:.9g} s: the records must share one time step")
        elif abs(t[0] - first[1]) > 1e-6 * first[2]:
            raise WaveError(key, f"{gauge.file}: starts at {t[0]:.9g} s where {first[3]} (waves.gauges[0].file) "
                                 f"starts at {first[1]:.9g} s: the records must share their times")
        rows.append(e)
    positions = np.array([[g.x, g.y] for g in waves.gauges], float)
    quantity = np.array([("elevation", "slope-x", "slope-y").index(g.quantity) for g in waves.gauges])
    return GaugeRecords(positions, float(first[1]), float(first[2]), np.array(rows), quantity)


def gauge_components(waves: GaugeWaves, water: Water, omega_min: float, omega_max: float) -> WaveComponents:
    """The directional sea the gauges' records give (module docstring) over the band
    ``waves.omega_range`` (default: the HDB's [omega_min, omega_max])."""
    rec = gauge_records(waves)
    lo, hi = omega_min, omega_max
    if waves.omega_range is not None:
        lo, hi = waves.omega_range
        if lo < omega_min * (1 - 1e-9) or hi > omega_max * (1 + 1e-9):
            raise WaveError("waves.omega_range", f"[{lo:g}, {hi:g}] rad/s reaches outside the HDB's range "
                            f"{omega_min:.4g}-{omega_max:.4g} rad/s")
    n = rec.eta.shape[1]
    omega = 2 * np.pi * np.arange(n // 2 + 1) / rec.duration
    inside = (omega >= lo * (1 - 1e-12)) & (omega <= hi * (1 + 1e-12)) & (np.arange(omega.size) > 0) \
        & (np.arange(omega.size) < (n + 1) // 2)        # neither the mean nor the Nyquist term
    if not inside.any():
        raise WaveError("waves.omega_range", f"no frequency of the records' Fourier series (step "
                                             f"{omega[1]:.4g} rad/s over {rec.duration:.6g} s) lies in "
                                             f"[{lo:.4g}, {hi:.4g}] rad/s")
    spectrum = np.fft.rfft(rec.eta, axis=1)                        # (G, N/2 + 1)
    power = np.abs(spectrum[~rec.slope, 1:(n + 1) // 2]) ** 2             # the elevation records' variance
    outside = float(1.0 - power[:, inside[1:(n + 1) // 2]].sum() / power.sum()) if power.sum() > 0 else 0.0
    w = omega[inside]
    measured = (2.0 / n) * np.conj(spectrum[:, inside]).T * np.exp(1j * w * rec.t0)[:, None]      # (F, G)
    heads = np.deg2rad(np.asarray(waves.directions, float))
    k = wave_number(w, water.gravity, water.depth_m)
    along = rec.positions @ np.array([np.cos(heads), np.sin(heads)])                          # (G, J)
    e = np.exp(1j * k[:, None, None] * along[None, :, :]) * rec.factors(heads)[None]          # (F, G, J)
    measured = measured / np.where(rec.slope, k[:, None], 1.0)            # slopes over k: elevation's units
    u, sv, vh = _resolvable(e, w, waves)
    c = np.einsum("fkj,fk->fj", vh.conj(), np.einsum("fgk,fg->fk", u.conj(), measured) / sv)   # E^+ C
    residual = measured - np.einsum("fgj,fj->fg", e, c)
    total = float(np.sum(np.abs(measured) ** 2))
    unexplained = float(np.sum(np.abs(residual) ** 2)) / total if total > 0 else 0.0
    start = rec.t0 if waves.start is None else float(waves.start)
    c = c * np.exp(-1j * w * start)[:, None]                       # phases at simulation t = 0
    amp = np.abs(c).reshape(-1)
    keep = amp > 0.0
    return WaveComponents(np.repeat(w, heads.size)[keep], amp[keep], np.angle(c).reshape(-1)[keep],
                          float(heads[0]), waves.ramp, outside, "gauges",
                          np.tile(heads, w.size)[keep], "waves.directions", fit_residual=unexplained)


def _resolvable(e: np.ndarray, w: np.ndarray, waves: GaugeWaves) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The thin SVD (U, s, V^H) of each frequency's E_n, refused (naming ``waves.directions``) where
    the array cannot tell the directions apart at some frequency of the band: more directions than
    gauges, or cond(E_n) = s_max / s_min above ``waves.max_condition``."""
    g, j = e.shape[1:]
    if j > g:
        raise WaveError("waves.directions", f"{j} directions from {g} gauges: an array of G gauges resolves at "
                                            f"most G directions per frequency (give at most {g}, or more gauges)")
    u, s, vh = np.linalg.svd(e, full_matrices=False)
    cond = s[:, 0] / np.maximum(s[:, -1], np.finfo(float).tiny)
    bad = cond > waves.max_condition
    if bad.any():
        ok = w[~bad]
        fix = (f"the array resolves them over {ok.min():.4g}-{ok.max():.4g} rad/s at most (narrow waves.omega_range "
               "to where it does)" if ok.size else "it resolves them at no frequency of the band")
        raise WaveError("waves.directions", f"the gauges cannot tell the directions {list(waves.directions)} deg apart "
                                            f"at {bad.sum()} of {w.size} frequencies ({w[bad].min():.4g}-"
                                            f"{w[bad].max():.4g} rad/s; condition number up to {cond.max():.3g} > "
                                            f"waves.max_condition = {waves.max_condition:g}): {fix}, or use fewer "
                                            "directions or a wider array")
    return u, s, vh
