"""Sea states beyond one spectrum: several wave systems, directional tables, component lists.

``[waves] type = "sea"`` (protocol/scene.py ``SeaState``): each system is a spectrum S(w) with a
spreading D(theta; w) around its direction, or a directional table S(w, theta); their components
are concatenated (system after system, each system direction-major as ``irregular``). Per system:

- frequencies: ``"equal-width"`` bins over the band (component at each centre, dw the width, as
  ``irregular``), amplitude a_k = sqrt(2 S(w_k) dw); ``"equal-energy"`` (WEC-Sim's default idea):
  N bins of equal energy E/N, the component at each bin's energy centroid int w S / int S with
  a_k = sqrt(2 E/N), so the components' variance is the band's exactly (WEC-Sim's EqualEnergy puts
  them at the N inner edges of N + 1 bins with sqrt(2 S(w_k) (w_k - w_{k-1})), a quadrature biased
  by several per cent: docs/waves.md); ``"table"``: the table's own frequencies inside the band, dw
  by central differences (one-sided at the ends, as WEC-Sim's imported spectra), a_k = sqrt(2 S dw).
- directions: ``n`` equal-energy sectors of D(theta; w_k) (server/sea/waves.py
  equal_energy_sectors): cos-2s of one s, Mitsuyasu's s(w) = s_max (w/w_p)^5 (w <= w_p), s_max
  (w/w_p)^-2.5 (w > w_p) (frequency-dependent spreading, IEC TS 62600-101's practice), or the
  table's row S(w_k, theta) / int S dtheta, linear in theta and in w between rows. Each frequency
  bin is split into as many sub-bins as all systems have directions, each system's direction j at
  the centre of a sub-bin of its own (every component its own frequency, so the elevation is
  ergodic, also where systems overlap); amplitude sqrt(1/n) a_k. One system alone is split as
  ``irregular`` splits it.
- phases: uniform in [0, 2 pi) from one default_rng(seed), drawn system after system.

``type = "components"`` replays a list (w, theta, a, phase) exactly as given: eta(x, t) = sum a
cos(k . x - w t + phase) (the internal convention; OpenFAST's WaveMod 7 lists the same four).

The setup (``wave_energy_by_direction``, :func:`direction_bands`) gives the variance per direction
band of 30 degrees.
"""

from __future__ import annotations

import numpy as np

from hydrolink.protocol.scene import ComponentWaves, GaugeWaves, Scene, SeaState, Water, WaveSystem
from hydrolink.server.allocation import require_size
from hydrolink.server.sea.doppler import doppler_shift
from hydrolink.server.sea.gauges import gauge_components
from hydrolink.server.sea.waves import SPECTRA, WaveComponents, WaveError, cos2s_directions, equal_energy_sectors, wave_components

FINE = 20001      # points of the fine frequency grid the equal-energy edges are found on
SPREAD_FINE = 8001   # points of the fine heading grid of a frequency-dependent spreading (one per frequency)
BAND = 30.0       # degrees: the width of the direction bands the setup note reports


def run_components(waves, scene: Scene, omega_min: float, omega_max: float) -> WaveComponents:
    """The wave components a run's model steps with: ``waves`` (the scene's ``[waves]``, or a client's
    rebuilding of them) over the HDBs' common range, seen from the ground in the scene's current
    (server/sea/doppler.py). One recipe for the model (server/model.py) and for what clients
    compute from a run afterwards (its view, its loads along a body)."""
    return doppler_shift(sea_components(waves, omega_min, omega_max, scene.water), scene.current, scene.water.gravity,
                         scene.water.depth_m, getattr(waves, "excitation", "superposition"))


def sea_components(waves, omega_min: float, omega_max: float, water: Water | None = None) -> WaveComponents:
    """The components of any ``[waves]`` over the frequency range the HDBs share (``water``: the
    scene's, which the gauges' fit needs for the wave numbers: server/sea/gauges.py)."""
    if isinstance(waves, GaugeWaves):
        if water is None:
            raise WaveError("waves.type", "a sea from gauges needs the water's depth and gravity (sea_components' water)")
        return gauge_components(waves, water, omega_min, omega_max)
    if isinstance(waves, SeaState):
        return _sea(waves, omega_min, omega_max)
    if isinstance(waves, ComponentWaves):
        return _replay(waves, omega_min, omega_max)
    return wave_components(waves, omega_min, omega_max)


class _Spectrum:
    """S(w) (m^2 s/rad) of a system, its total variance m0 and the directional density D(theta; w)."""

    def __init__(self, system: WaveSystem, key: str):
        self.system, self.key = system, key
        self.mean = float(np.deg2rad(system.direction))
        self._cos2s: tuple[np.ndarray, np.ndarray] | None = None   # cos-2s sectors (directions), computed once
        if system.spectrum != "table":
            make, _ = SPECTRA[system.spectrum]
            self.s1 = make(system.hs, system.tp, system.gamma)
            self.m0 = system.hs ** 2 / 16.0
            self.peak = 2 * np.pi / system.tp
            self.omega = self.theta = self.table = None
            return
        if system.omega is None:     # a file's table not read in (Scene.with_spectra)
            raise WaveError(f"{key}.file", f"the table of {system.file!r} did not reach the model: a client reads "
                                           "the file and sends its table (hello.spectra, SPEC §5.1)")
        hz = system.units == "hz-deg"
        self.omega = np.asarray(system.omega, float) * (2 * np.pi if hz else 1.0)
        table = np.asarray(system.density, float) / (2 * np.pi if hz else 1.0)
        if system.theta is not None:
            self.theta = np.deg2rad(np.asarray(system.theta, float))
            self.table = table * (180.0 / np.pi if hz else 1.0)           # per rad
            d = np.diff(self.theta)
            row = (0.5 * (self.table[:, 1:] + self.table[:, :-1]) * d).sum(axis=1)
        else:
            self.theta, self.table, row = None, None, table
        self._row = row
        self.s1 = lambda w: np.interp(w, self.omega, self._row, left=0.0, right=0.0)
        self.m0 = float((0.5 * (row[1:] + row[:-1]) * np.diff(self.omega)).sum())
        self.peak = float(self.omega[np.argmax(row)])

    def directions(self, w: float, n: int) -> tuple[np.ndarray, np.ndarray]:
        """Headings (rad) and weights of ``n`` equal-energy sectors at frequency ``w``."""
        sy = self.system
        if n == 1 and self.theta is None:
            return np.array([self.mean]), np.ones(1)
        if self.theta is not None:
            rows = np.array([np.interp(w, self.omega, self.table[:, j]) for j in range(self.theta.size)])
            if not np.any(rows > 0):
                return np.full(n, self.mean), np.full(n, 1.0 / n)
            return equal_energy_sectors(self.theta, rows, n)
        if sy.spreading == "cos2s":       # one s: the same sectors at every frequency, computed once
            if self._cos2s is None or self._cos2s[0].size != n:
                self._cos2s = cos2s_directions(10.0 if sy.s is None else float(sy.s), n, self.mean)
            return self._cos2s
        s_max = 10.0 if sy.s_max is None else float(sy.s_max)
        x = w / self.peak
        s = s_max * (x ** 5 if x <= 1.0 else x ** -2.5)
        return cos2s_directions(max(s, 1e-3), n, self.mean, fine=SPREAD_FINE)


def _frequencies(spec: _Spectrum, lo: float, hi: float, n: int, rule: str, key: str) -> tuple[np.ndarray, np.ndarray]:
    """Component frequencies and their bin widths dw over [lo, hi] by ``rule`` (module docstring)."""
    if rule == "equal-width":
        edges = np.linspace(lo, hi, n + 1)
        return 0.5 * (edges[:-1] + edges[1:]), np.diff(edges)
    if rule == "table":
        w = spec.omega[(spec.omega >= lo * (1 - 1e-9)) & (spec.omega <= hi * (1 + 1e-9))]
        if w.size < 2:
            raise WaveError(key, f"fewer than two of the table's frequencies lie in the band {lo:.4g}-{hi:.4g} rad/s")
        dw = np.empty(w.size)
        dw[0], dw[-1] = w[1] - w[0], w[-1] - w[-2]
        dw[1:-1] = 0.5 * (w[2:] - w[:-2])
        return w, dw
    grid = np.linspace(lo, hi, FINE)
    s = spec.s1(grid)
    step = 0.5 * (s[1:] + s[:-1]) * np.diff(grid)
    cum = np.concatenate([[0.0], np.cumsum(step)])
    first = np.concatenate([[0.0], np.cumsum(0.5 * (grid[1:] * s[1:] + grid[:-1] * s[:-1]) * np.diff(grid))])
    if cum[-1] <= 0:
        raise WaveError(key, f"no energy in the band {lo:.4g}-{hi:.4g} rad/s")
    edges = np.interp(cum[-1] * np.arange(n + 1) / n, cum, grid)
    w = np.diff(np.interp(edges, grid, first)) / np.diff(np.interp(edges, grid, cum))   # energy centroids
    return w, np.diff(edges)


def _band_energy(spec: _Spectrum, lo: float, hi: float) -> float:
    """int_lo^hi S(w) dw (trapezoid on the fine grid)."""
    fine = np.linspace(lo, hi, FINE)
    s = spec.s1(fine)
    return float((0.5 * (s[1:] + s[:-1]) * np.diff(fine)).sum())


def _band(waves: SeaState, omega_min: float, omega_max: float) -> tuple[float, float]:
    if waves.omega_range is not None:
        lo, hi = waves.omega_range
        if lo < omega_min * (1 - 1e-9) or hi > omega_max * (1 + 1e-9):
            raise WaveError("waves.omega_range", f"[{lo:g}, {hi:g}] rad/s reaches outside the HDB's range "
                            f"{omega_min:.4g}-{omega_max:.4g} rad/s")
        return lo, hi
    if not np.isfinite(omega_max) or omega_min <= 1e-6:
        raise WaveError("waves.omega_range", "required without an HDB (no frequency range to span)")
    return omega_min, omega_max


def _sea(waves: SeaState, omega_min: float, omega_max: float) -> WaveComponents:
    lo, hi = _band(waves, omega_min, omega_max)
    rng = np.random.default_rng(waves.seed)
    parts, m0, inside = [], 0.0, 0.0
    offset, n_sub = 0, sum(s.sectors for s in waves.systems)   # every system's directions: their own sub-bins
    for i, system in enumerate(waves.systems):
        key = f"waves.systems[{i}]"
        spec = _Spectrum(system, key)
        n_dir = system.sectors
        require_size("waves.components", "the wave components (amplitude, frequency, phase, heading)",
                     (4, n_dir, waves.components), hint=f"fewer components or directions (systems[{i}].directions)")
        w, dw = _frequencies(spec, lo, hi, waves.components, waves.frequencies, key)
        amp = np.sqrt(2 * (np.full(w.size, _band_energy(spec, lo, hi) / w.size)
                           if waves.frequencies == "equal-energy" else spec.s1(w) * dw))
        heads, weights = zip(*(spec.directions(float(wk), n_dir) for wk in w))
        heads, weights = np.array(heads).T, np.array(weights).T             # (n_dir, n_w)
        shift = ((offset + np.arange(n_dir) + 0.5) / n_sub - 0.5)[:, None] * dw[None, :]
        offset += n_dir
        parts.append(((w[None, :] + shift).reshape(-1), (np.sqrt(weights) * amp[None, :]).reshape(-1),
                      rng.uniform(0.0, 2 * np.pi, n_dir * w.size), heads.reshape(-1)))
        m0 += spec.m0
        inside += _band_energy(spec, lo, hi)
    omega, amp, phase, heads = (np.concatenate(x) for x in zip(*parts))
    keep = amp > 0.0
    comps = WaveComponents(omega[keep], amp[keep], phase[keep], float(np.deg2rad(waves.direction)), waves.ramp,
                           float(max(0.0, 1.0 - inside / m0)), "irregular", heads[keep], "waves.systems")
    return comps


def _replay(waves: ComponentWaves, omega_min: float, omega_max: float) -> WaveComponents:
    w = np.asarray(waves.omega, float)
    out = np.flatnonzero((w < omega_min * (1 - 1e-9)) | (w > omega_max * (1 + 1e-9)))
    if out.size:
        raise WaveError("waves.omega", f"component {out[0]} at {w[out[0]]:g} rad/s lies outside the HDB's range "
                                       f"{omega_min:.4g}-{omega_max:.4g} rad/s")
    if len(set(zip(waves.omega, waves.direction))) < w.size:
        raise WaveError("waves.omega", "two components share a frequency and a direction: add their amplitudes")
    heads = np.deg2rad(np.asarray(waves.direction, float))
    comps = WaveComponents(w, np.asarray(waves.amplitude, float), np.deg2rad(np.asarray(waves.phase, float)),
                           float(heads[0]), waves.ramp, 0.0, "irregular", heads, "waves.direction")
    return comps


def direction_bands(comps: WaveComponents) -> list[tuple[float, float]]:
    """(band centre in degrees, fraction of the variance) of the components per 30-degree band
    centred on multiples of 30 degrees in (-180, 180]; bands without energy are left out."""
    if comps.size == 0:
        return []
    var = 0.5 * comps.amplitude ** 2
    deg = np.rad2deg(np.angle(np.exp(1j * comps.heading_of())))
    centre = BAND * np.round(deg / BAND) + 0.0    # + 0.0: no "-0" band
    centre[centre <= -180.0] += 360.0
    total = var.sum()
    return [(float(c), float(var[centre == c].sum() / total)) for c in np.unique(centre) if var[centre == c].sum() > 0]
