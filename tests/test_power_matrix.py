"""clients/studies/power_matrix.py: sea states, scatter diagrams, power matrix and AEP against MHKiT (the
marine energy community's IEC TS 62600-100 toolkit) and closed forms."""

from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr

from hydrolink.clients.studies.power_matrix import HOURS_PER_YEAR, PowerMatrixError, annual_energy, bin_edges, group_velocity, power_matrix, read_scatter, sea_state, te_over_tp
from hydrolink.protocol.scene import IrregularWave, parse_scene
from conftest import body, irregular_waves, regular_waves, scene_toml

mhkit_resource = pytest.importorskip("mhkit.wave.resource", reason="mhkit (test dependency) not installed")
mhkit_performance = pytest.importorskip("mhkit.wave.performance", reason="mhkit (test dependency) not installed")

RHO, G = 1025.0, 9.81


def _scene(waves, depth="inf"):
    return parse_scene(scene_toml(dt=0.1, duration=10.0, water={"density": RHO, "gravity": G, "depth": depth},
                                  waves=waves, bodies=[body("b", mass=1.0, center_of_mass=[0, 0, 0],
                                                            inertia=[1, 1, 1])]))


def test_te_over_tp_pierson_moskowitz_closed_form():
    # S ~ w^-5 exp(-5/4 (wp/w)^4): m_-1 / m_0 = Gamma(5/4) (5/4)^(-1/4) / wp, so Te = that * Tp
    w = IrregularWave(type="irregular", spectrum="pierson-moskowitz", hs=2.0, tp=9.0)
    assert te_over_tp(w) == pytest.approx(math.gamma(1.25) * 1.25 ** -0.25, rel=1e-7)
    # JONSWAP with gamma 1 is Pierson-Moskowitz; a peakier spectrum has Te nearer Tp
    j1 = IrregularWave(type="irregular", spectrum="jonswap", hs=2.0, tp=9.0, gamma=1.0)
    j33 = IrregularWave(type="irregular", spectrum="jonswap", hs=2.0, tp=9.0, gamma=3.3)
    assert te_over_tp(j1) == pytest.approx(te_over_tp(w), rel=1e-7)
    assert te_over_tp(w) < te_over_tp(j33) < 1.0


@pytest.mark.parametrize("spectrum,gamma", [("jonswap", 3.3), ("jonswap", 1.5), ("pierson-moskowitz", 3.3)])
def test_sea_state_against_mhkit_and_deep_water_closed_form(spectrum, gamma):
    """Hm0, Te and J of the scene's spectrum (server/sea/waves.py's S) against MHKiT's moments and energy
    flux of the same S(f) sampled finely, and J against rho g^2 Hm0^2 Te / (64 pi)."""
    from hydrolink.server.sea.waves import jonswap, pierson_moskowitz
    hs, tp = 2.5, 9.0
    state = sea_state(_scene(irregular_waves(hs, tp, spectrum, gamma=gamma)))
    f = np.arange(0.0025, 2.0, 0.0005)                    # Hz
    w = 2 * np.pi * f
    s_w = jonswap(w, hs, tp, gamma) if spectrum == "jonswap" else pierson_moskowitz(w, hs, tp)
    s_f = xr.DataArray(2 * np.pi * s_w, dims="frequency", coords={"frequency": f})   # S(f) df = S(w) dw
    te = float(mhkit_resource.energy_period(s_f, to_pandas=False))
    hm0 = float(mhkit_resource.significant_wave_height(s_f, to_pandas=False))
    j = float(mhkit_resource.energy_flux(s_f, h=1000.0, deep=True, rho=RHO, g=G, to_pandas=False))
    assert state.kind == "irregular"
    assert state.height == pytest.approx(hs, rel=1e-6) and hm0 == pytest.approx(hs, rel=2e-4)
    assert state.period == pytest.approx(te, rel=2e-4)
    assert state.energy_flux == pytest.approx(j, rel=5e-4)
    assert state.energy_flux == pytest.approx(RHO * G ** 2 * hs ** 2 * state.period / (64 * math.pi), rel=1e-6)
    assert state.te_over_tp == pytest.approx(state.period / tp)


def test_finite_depth_energy_flux_against_mhkit():
    """At 30 m the group velocity of the long components is below g/(2w): J against MHKiT's
    finite-depth flux (its own dispersion solver) of the same spectrum."""
    from hydrolink.server.sea.waves import jonswap
    hs, tp, depth = 2.0, 11.0, 30.0
    state = sea_state(_scene(irregular_waves(hs, tp), depth=depth))
    f = np.arange(0.0025, 1.2, 0.0005)
    s_f = xr.DataArray(2 * np.pi * jonswap(2 * np.pi * f, hs, tp, 3.3), dims="frequency", coords={"frequency": f})
    j = float(mhkit_resource.energy_flux(s_f, h=depth, deep=False, rho=RHO, g=G, to_pandas=False))
    deep = RHO * G ** 2 * hs ** 2 * state.period / (64 * math.pi)
    assert state.energy_flux == pytest.approx(j, rel=2e-3)
    assert abs(state.energy_flux / deep - 1) > 0.1      # intermediate depth: c_g above g / (2 w) here
    # shallow-water limit of the group velocity: sqrt(g h)
    assert group_velocity(0.01, G, 10.0) == pytest.approx(math.sqrt(G * 10.0), rel=1e-4)


def test_regular_wave_energy_flux():
    state = sea_state(_scene(regular_waves(2.0, 8.0)))
    assert (state.kind, state.height, state.period) == ("regular", 2.0, 8.0)
    assert state.energy_flux == pytest.approx(RHO * G ** 2 * 2.0 ** 2 * 8.0 / (32 * math.pi), rel=1e-12)
    assert math.isnan(state.te_over_tp)


@pytest.mark.filterwarnings("ignore:.*IEC TS 62600-100 limit:UserWarning")
def test_power_matrix_and_aep_equal_mhkit():
    """Cases (several per bin, some bins empty, one failed case) binned by (Hm0, Te): capture width,
    energy flux and power matrices and the AEP equal MHKiT's on the same inputs and bins."""
    rng = np.random.default_rng(3)
    n = 60
    hm0 = rng.uniform(0.5, 4.0, n)
    te = rng.uniform(5.0, 12.0, n)
    j = RHO * G ** 2 * hm0 ** 2 * te / (64 * math.pi)
    p = j * rng.uniform(2.0, 8.0, n)                     # capture widths 2 - 8 m
    p[7] = np.nan                                        # a failed case: left out
    hc = np.arange(0.25, 4.5, 0.5)                       # IEC: bins of 0.5 m ...
    tc = np.arange(5.5, 12.5, 1.0)                       # ... and 1 s
    pm = power_matrix(hm0, te, p, j, hc, tc)
    ok = np.isfinite(p)
    he, tb = bin_edges(hc), bin_edges(tc)
    # MHKiT takes bin centres; its lowest bins reach down to 0 (the same bins as ours for these cases)
    cw_matrix = getattr(mhkit_performance, "capture_width_matrix", None) or mhkit_performance.capture_length_maxtrix
    cwm = cw_matrix(hm0[ok], te[ok], p[ok] / j[ok], "mean", hc, tc, to_pandas=False)
    jm = mhkit_performance.wave_energy_flux_matrix(hm0[ok], te[ok], j[ok], "mean", hc, tc, to_pandas=False)
    count = cw_matrix(hm0[ok], te[ok], p[ok] / j[ok], "count", hc, tc, to_pandas=False)
    pmm = mhkit_performance.power_matrix(cwm, jm)
    np.testing.assert_allclose(pm.capture_width, cwm.values, rtol=1e-12, equal_nan=True)
    np.testing.assert_allclose(pm.energy_flux, jm.values, rtol=1e-12, equal_nan=True)
    np.testing.assert_allclose(pm.power, pmm.values, rtol=1e-12, equal_nan=True)
    np.testing.assert_array_equal(pm.count, np.nan_to_num(count.values).astype(int))
    # a bin with one case: its own power
    one = np.flatnonzero(pm.count.ravel() == 1)[0]
    i = [k for k in range(n) if ok[k] and np.ravel_multi_index(
        (np.searchsorted(he, hm0[k]) - 1, np.searchsorted(tb, te[k]) - 1), pm.count.shape) == one][0]
    assert pm.power.ravel()[one] == pytest.approx(p[i], rel=1e-12)
    occurrence = rng.uniform(0, 1, pm.power.shape) * (rng.uniform(0, 1, pm.power.shape) > 0.2)
    aep, uncovered = annual_energy(pm, occurrence)
    freq = xr.DataArray(occurrence / occurrence.sum(), dims=cwm.dims, coords=cwm.coords)
    expected = mhkit_performance.mean_annual_energy_production_matrix(cwm, jm, freq)
    assert aep == pytest.approx(float(expected), rel=1e-12)
    covered = pm.count > 0
    assert uncovered == pytest.approx(occurrence[~covered].sum() / occurrence.sum(), rel=1e-12)
    assert aep == pytest.approx(HOURS_PER_YEAR * np.nansum(pm.power * occurrence / occurrence.sum()), rel=1e-12)


def test_scatter_csv_and_netcdf(tmp_path):
    csv = tmp_path / "scatter.csv"
    csv.write_text("# Site X, buoy Y (the source)\n# occurrence in hours\nhm0\\te,6.5,7.5,8.5\n"
                   "0.75,10,20,0\n1.25,5,40,25\n")
    s = read_scatter(csv)
    np.testing.assert_allclose(s.hm0, [0.75, 1.25])
    np.testing.assert_allclose(s.te, [6.5, 7.5, 8.5])
    np.testing.assert_allclose(s.occurrence.sum(), 1.0)
    np.testing.assert_allclose(s.occurrence[1, 1], 40 / 100)
    assert "Site X, buoy Y" in s.source
    np.testing.assert_allclose(s.hm0_edges, [0.5, 1.0, 1.5])
    np.testing.assert_allclose(s.te_edges, [6.0, 7.0, 8.0, 9.0])
    nc = tmp_path / "scatter.nc"
    xr.Dataset({"occurrence": (("te", "hm0"), s.occurrence.T * 100)}, coords={"hm0": s.hm0, "te": s.te},
               attrs={"source": "the same"}).to_netcdf(nc)
    s2 = read_scatter(nc)
    np.testing.assert_allclose(s2.occurrence, s.occurrence)
    assert s2.source == "the same"


@pytest.mark.parametrize("text,why", [
    ("hm0\\te,6.5,7.5\n1.0,1,2,3\n", "row 2 of the matrix has 3 values for 2 Te bins"),
    ("hm0\\te,6.5,7.5\n1.0,1,x\n", "not a number"),
    ("hm0\\te,7.5,6.5\n1.0,1,2\n", "te: bin centres must be finite and increasing"),
    ("hm0\\te,6.5,7.5\n1.0,0,0\n", "occurrence: finite, >= 0 and not all 0"),
    ("hm0\\te,6.5,7.5\n", "needs a header row"),
])
def test_scatter_errors(tmp_path, text, why):
    path = tmp_path / "bad.csv"
    path.write_text(text)
    with pytest.raises(PowerMatrixError) as err:
        read_scatter(path)
    assert str(err.value).startswith(str(path)) and why in str(err.value)
    assert "\n" not in str(err.value)
