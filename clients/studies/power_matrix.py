"""Sea states, power matrix and annual energy production after IEC TS 62600-100.

**Sea state of a case** (:func:`sea_state`), from the scene's own wave definition:

- irregular waves: the spectrum the force server synthesises (server/sea/waves.py: JONSWAP with the
  scene's ``gamma``, or Pierson-Moskowitz), as the continuous S(w) normalised to Hm0 = ``hs``.
  Energy period Te = m_-1 / m_0 (moments in Hz), so Te / Tp is that spectrum's own ratio
  (:func:`te_over_tp`: JONSWAP gamma 3.3: 0.9033, Pierson-Moskowitz: Gamma(5/4) / 1.25^(1/4) = 0.8572);
  omnidirectional energy flux J = rho g int c_g(f) S(f) df with the group velocity c_g of the
  scene's depth (deep water: J = rho g^2 Hm0^2 Te / (64 pi)). Directional spreading leaves J as it is.
- regular waves: height H and period T, J = rho g H^2 / 8 c_g(w).

**Capture width** CW = P / J (m) of the mean total PTO power P; capture width ratio CWR = CW / B
with the device's characteristic width B.

**Power matrix** (:func:`power_matrix`): cases are binned by (Hm0, Te) into the bins of a site's
scatter diagram (or, without a site, one bin per distinct sea state of the sweep); per bin the mean
capture width times the mean energy flux (IEC TS 62600-100's capture-length matrix times its
energy-flux matrix; MHKiT's ``capture_length_maxtrix``/``wave_energy_flux_matrix``/``power_matrix``),
which is the case's own P when a bin holds one case. **AEP** = 8766 h * sum over bins of
P(Hm0, Te) * occurrence (occurrence normalised to sum 1); bins of the site without a simulated case
add nothing, and the fraction of occurrence they hold is reported (``uncovered``).

**Scatter diagram files** (:func:`read_scatter`): CSV, ``#`` comment lines (cite the source there),
then a matrix: the first row the Te bin centres (its first cell a label, e.g. ``hm0\\te``), each
further row an Hm0 bin centre followed by its occurrences (counts, hours or fractions); or NetCDF
with a variable ``occurrence`` over dimensions (``hm0``, ``te``) holding the bin centres. Bin edges
lie halfway between centres (the outer ones half a spacing out).
"""

from __future__ import annotations

import csv
import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
from scipy.integrate import quad

from hydrolink.protocol.scene import IrregularWave, RegularWave, Scene
from hydrolink.server.sea.dispersion import wave_number
from hydrolink.server.sea.waves import wave_spectrum

HOURS_PER_YEAR = 8766.0   # IEC TS 62600-100 (365.25 days)


class PowerMatrixError(ValueError):
    """A scatter diagram or sea state that cannot be used; the message names the file and why."""


@dataclass(frozen=True)
class SeaState:
    """A case's sea state: ``kind`` "irregular" (height = Hm0, period = Te) or "regular" (H, T);
    ``energy_flux`` J in W/m; ``te_over_tp``: Te / Tp of the spectrum (irregular), else nan;
    ``spectrum`` says which."""
    kind: str
    height: float
    period: float
    energy_flux: float
    te_over_tp: float
    spectrum: str


# ------------------------------------------------------------------ waves

def group_velocity(omega, gravity: float, depth: float):
    """c_g(w) = (w / k) / 2 (1 + 2 k h / sinh 2 k h); deep water g / (2 w)."""
    w = np.atleast_1d(np.asarray(omega, float))
    out = np.empty_like(w)
    for i, wi in enumerate(w):
        k = wave_number(wi, gravity, depth)
        kh = k * depth
        factor = 1.0 if math.isinf(depth) or kh > 20.0 else 1.0 + 2 * kh / math.sinh(2 * kh)
        out[i] = 0.5 * wi / k * factor
    return out if np.ndim(omega) else float(out[0])


def _integral(f, wp: float) -> float:
    """int_0^inf f(w) dw, split around the spectral peak wp."""
    edges = (0.0, 0.6 * wp, 0.9 * wp, 1.1 * wp, 1.5 * wp, 4 * wp, 20 * wp, math.inf)
    return sum(quad(lambda w: float(f(w)), a, b, limit=200)[0] for a, b in zip(edges[:-1], edges[1:]))


def te_over_tp(waves: IrregularWave) -> float:
    """Te / Tp of the scene's spectrum (its shape in w / wp; Hs and Tp do not change it)."""
    spec, _ = wave_spectrum(waves)
    wp = 2 * math.pi / waves.tp
    m0 = _integral(spec, wp)
    m_1 = _integral(lambda w: spec(w) / w if w > 0 else 0.0, wp)      # int S(w)/w dw
    return float(2 * math.pi * m_1 / m0 / waves.tp)


def sea_state(scene: Scene) -> SeaState | None:
    """The sea state of a scene (module docstring), None for still water and elevation files."""
    rho, g, depth = scene.water.density, scene.water.gravity, scene.water.depth_m
    w = scene.waves
    if isinstance(w, RegularWave):
        omega = 2 * math.pi / w.period
        j = rho * g * w.height ** 2 / 8 * group_velocity(omega, g, depth)
        return SeaState("regular", w.height, w.period, float(j), math.nan, "regular")
    if isinstance(w, IrregularWave):
        spec, name = wave_spectrum(w)
        wp = 2 * math.pi / w.tp
        m0 = _integral(spec, wp)
        te = 2 * math.pi * _integral(lambda x: spec(x) / x if x > 0 else 0.0, wp) / m0
        flux = rho * g * _integral(lambda x: group_velocity(x, g, depth) * spec(x) if x > 0 else 0.0, wp)
        return SeaState("irregular", 4 * math.sqrt(m0), te, float(flux), te / w.tp, name)
    return None


# ------------------------------------------------------------------ scatter diagrams

@dataclass(frozen=True)
class Scatter:
    """A site's occurrence per (Hm0, Te) bin: centres, edges, occurrence normalised to sum 1."""
    hm0: np.ndarray
    te: np.ndarray
    occurrence: np.ndarray          # (hm0, te), sums to 1
    source: str                     # the file's comment lines (its citation)
    path: str

    @property
    def hm0_edges(self) -> np.ndarray:
        return bin_edges(self.hm0)

    @property
    def te_edges(self) -> np.ndarray:
        return bin_edges(self.te)


def bin_edges(centres) -> np.ndarray:
    """Edges halfway between increasing bin centres, the outer ones half a spacing out."""
    c = np.asarray(centres, float)
    if c.size == 1:
        return np.array([c[0] * 0.5, c[0] * 1.5]) if c[0] > 0 else np.array([c[0] - 0.5, c[0] + 0.5])
    mid = 0.5 * (c[1:] + c[:-1])
    return np.concatenate([[c[0] - (mid[0] - c[0])], mid, [c[-1] + (c[-1] - mid[-1])]])


def _check_scatter(path: Path, hm0, te, occ, source: str) -> Scatter:
    hm0, te, occ = np.asarray(hm0, float), np.asarray(te, float), np.asarray(occ, float)
    for name, c in (("hm0", hm0), ("te", te)):
        if c.size == 0 or not np.all(np.isfinite(c)) or np.any(np.diff(c) <= 0):
            raise PowerMatrixError(f"{path}: {name}: bin centres must be finite and increasing (got {c.tolist()})")
    if occ.shape != (hm0.size, te.size):
        raise PowerMatrixError(f"{path}: occurrence: {occ.shape} values for {hm0.size} Hm0 x {te.size} Te bins")
    if not np.all(np.isfinite(occ)) or np.any(occ < 0) or occ.sum() <= 0:
        raise PowerMatrixError(f"{path}: occurrence: finite, >= 0 and not all 0")
    return Scatter(hm0, te, occ / occ.sum(), source, str(path))


def read_scatter(path: str | Path) -> Scatter:
    """A scatter diagram from CSV or NetCDF (module docstring); PowerMatrixError naming the file."""
    path = Path(path)
    if not path.is_file():
        raise PowerMatrixError(f"{path}: file not found")
    if path.suffix.lower() in (".nc", ".nc4", ".netcdf"):
        import xarray as xr
        try:
            with xr.open_dataset(path, engine="netcdf4") as ds:
                if "occurrence" not in ds:
                    raise PowerMatrixError(f"{path}: no variable 'occurrence' (dims hm0, te)")
                occ = ds["occurrence"]
                if set(occ.dims) != {"hm0", "te"}:
                    raise PowerMatrixError(f"{path}: occurrence: dims must be (hm0, te), got {occ.dims}")
                occ = occ.transpose("hm0", "te")
                return _check_scatter(path, occ["hm0"].values, occ["te"].values, occ.values,
                                      str(ds.attrs.get("source", "")))
        except (OSError, ValueError) as exc:
            if isinstance(exc, PowerMatrixError):
                raise
            raise PowerMatrixError(f"{path}: not a readable NetCDF file ({exc})") from None
    lines = path.read_text().splitlines()
    comments = [ln.lstrip("#").strip() for ln in lines if ln.lstrip().startswith("#")]
    rows = [r for r in csv.reader(ln for ln in lines if ln.strip() and not ln.lstrip().startswith("#"))]
    if len(rows) < 2:
        raise PowerMatrixError(f"{path}: needs a header row of Te bin centres and one row per Hm0 bin")
    try:
        te = [float(x) for x in rows[0][1:]]
        hm0 = [float(r[0]) for r in rows[1:]]
        occ = [[float(x) for x in r[1:]] for r in rows[1:]]
    except ValueError as exc:
        raise PowerMatrixError(f"{path}: not a number ({exc})") from None
    for i, r in enumerate(occ):
        if len(r) != len(te):
            raise PowerMatrixError(f"{path}: row {i + 2} of the matrix has {len(r)} values for {len(te)} Te bins")
    return _check_scatter(path, hm0, te, occ, "\n".join(comments))


# ------------------------------------------------------------------ power matrix and AEP

@dataclass(frozen=True)
class PowerMatrix:
    """Per (Hm0, Te) bin: mean capture width (m), mean energy flux (W/m), their product the mean
    power (W; nan where no case), and the number of cases."""
    hm0: np.ndarray
    te: np.ndarray
    capture_width: np.ndarray
    energy_flux: np.ndarray
    power: np.ndarray
    count: np.ndarray


def _bin_index(x: np.ndarray, edges: np.ndarray) -> np.ndarray:
    """Bin of each value (-1 outside), bins closed on the left; the last bin closed on both sides."""
    i = np.searchsorted(edges, x, side="right") - 1
    i[x == edges[-1]] = edges.size - 2
    i[(x < edges[0]) | (x > edges[-1]) | ~np.isfinite(x)] = -1
    return i


def power_matrix(height, period, power, energy_flux, hm0_centres, te_centres) -> PowerMatrix:
    """Bin cases (arrays of equal length; nan power = failed, left out) by their sea state."""
    h, t = np.asarray(height, float), np.asarray(period, float)
    p, j = np.asarray(power, float), np.asarray(energy_flux, float)
    ok = np.isfinite(p) & np.isfinite(j) & (j > 0)
    he, te = bin_edges(hm0_centres), bin_edges(te_centres)
    ih, it = _bin_index(h, he), _bin_index(t, te)
    shape = (he.size - 1, te.size - 1)
    count = np.zeros(shape, int)
    cw_sum, j_sum = np.zeros(shape), np.zeros(shape)
    for a, b, pp, jj, good in zip(ih, it, p, j, ok):
        if good and a >= 0 and b >= 0:
            count[a, b] += 1
            cw_sum[a, b] += pp / jj
            j_sum[a, b] += jj
    with np.errstate(invalid="ignore", divide="ignore"):
        cw = np.where(count > 0, cw_sum / count, np.nan)
        jm = np.where(count > 0, j_sum / count, np.nan)
    return PowerMatrix(np.asarray(hm0_centres, float), np.asarray(te_centres, float), cw, jm, cw * jm, count)


def annual_energy(matrix: PowerMatrix, occurrence: np.ndarray) -> tuple[float, float]:
    """(AEP in Wh, uncovered occurrence fraction): 8766 h * sum P * occurrence over the bins with a
    simulated case; occurrence normalised to sum 1."""
    occ = np.asarray(occurrence, float)
    occ = occ / occ.sum()
    covered = np.isfinite(matrix.power)
    aep = HOURS_PER_YEAR * float(np.sum(np.where(covered, matrix.power, 0.0) * occ))
    return aep, float(occ[~covered].sum())
