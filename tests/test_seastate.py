"""Sea states (server/sea/seastate.py) against the frequency domain written here: the variance of
each excitation force in a crossing sea (wind sea + swell, cos-2s and Mitsuyasu spreading, and the
same wind sea as a directional table) equals sum |X(w, theta)|^2 S(w, theta) dw dtheta on a fine
grid within 3 %; a component list reproduces the elevation at three points to 1e-9; bad input
names its key."""

from __future__ import annotations

import numpy as np
import pytest
from scipy.integrate import quad
from scipy.optimize import brentq
from scipy.special import gammaln

from analytic_hdb import make_body_hdb
from conftest import body, scene_toml

from hydrolink.protocol.scene import SceneError, parse_scene
from hydrolink.server.errors import ModelError
from hydrolink.server.model import HydroModel
from hydrolink.server.sea.probes import WaveProbes

OMEGA = np.linspace(0.05, 4.0, 300)
BAND = (0.25, 2.5)


def x_true(w, beta):
    """The analytic HDB's X(w, beta) (tests/analytic_hdb.py's default), (..., 6)."""
    base = np.array([1e4, 1e4, 3e5, 2e5, 2e5, 1e4])
    rot = np.stack([np.cos(beta), np.sin(beta), np.ones_like(beta), np.sin(beta), np.cos(beta), 0.5 * np.sin(2 * beta)], -1)
    return base * rot * (np.exp(-0.3 * w ** 2) * np.exp(1j * (0.4 + 0.8 * w)))[..., None]


def jonswap(w, hs, tp, gamma):
    wp = 2 * np.pi / tp
    shape = lambda x: x ** -5 * np.exp(-1.25 * (wp / x) ** 4) * gamma ** np.exp(   # noqa: E731
        -(x - wp) ** 2 / (2 * (0.07 if x <= wp else 0.09) ** 2 * wp ** 2))
    m0 = quad(shape, 0.05 * wp, 30 * wp, points=[wp], limit=400)[0]
    return np.array([shape(x) for x in np.atleast_1d(w)]) * hs ** 2 / 16 / m0


def cos2s(theta, s):
    c = np.exp(gammaln(s + 1) - gammaln(s + 0.5)) / (2 * np.sqrt(np.pi))
    return c * np.abs(np.cos(theta / 2)) ** (2 * s)


WIND = dict(spectrum="jonswap", hs=2.0, tp=7.0, gamma=3.3, direction=30.0, spreading="cos2s", s=6.0, directions=11)
SWELL = dict(spectrum="pierson-moskowitz", hs=1.2, tp=13.0, direction=-120.0, spreading="mitsuyasu", s_max=25.0,
             directions=7)


def wind_density(w, theta):
    """S(w) D(theta - 30 deg) of WIND (m^2 s/rad^2)."""
    return jonswap(w, 2.0, 7.0, 3.3)[:, None] * cos2s(theta[None, :] - np.deg2rad(30.0), 6.0)


def swell_density(w, theta):
    wp = 2 * np.pi / 13.0
    s1 = 5 / 16 * 1.2 ** 2 * wp ** 4 * w ** -5 * np.exp(-1.25 * (wp / w) ** 4)
    s = 25.0 * np.where(w <= wp, (w / wp) ** 5, (w / wp) ** -2.5)
    return s1[:, None] * np.stack([cos2s(theta - np.deg2rad(-120.0), max(x, 1e-3)) for x in s])


def reference_variance(*densities) -> np.ndarray:
    """sum over a fine (w, theta) grid of |X|^2 S dw dtheta, per DOF."""
    w = np.linspace(*BAND, 1500)
    th = np.linspace(-np.pi, np.pi, 721)[:-1]
    x2 = np.abs(x_true(w[:, None], th[None, :])) ** 2              # (n_w, n_th, 6)
    s = sum(d(w, th) for d in densities)
    return np.einsum("wtd,wt->d", x2, s) * (w[1] - w[0]) * (th[1] - th[0])


def _model(waves: dict) -> HydroModel:
    ds = make_body_hdb(omega=OMEGA, directions=np.deg2rad(np.arange(-180.0, 180.0, 5.0)))
    text = scene_toml(dt=0.1, duration=10.0, water={"density": 1000.0}, waves=waves,
                      bodies=[body("float", hdb="h", mass=3.0e5, center_of_mass=[0, 0, 0], inertia=[1e6] * 3)])
    return HydroModel(parse_scene(text), {"float": ds})


def model_variance(m: HydroModel) -> np.ndarray:
    """Time variance of each force: a sum of sinusoids at distinct frequencies has sum |F_c|^2 / 2
    (checked distinct here)."""
    omega, f, _ = m.excitation_phasors()
    assert np.unique(np.round(omega, 12)).size == omega.size
    return 0.5 * (np.abs(f) ** 2).sum(axis=0)


def _sea(*systems, **keys) -> dict:
    return {"type": "sea", "systems": list(systems), "omega_range": list(BAND), **keys}


@pytest.mark.parametrize("frequencies", ["equal-width", "equal-energy"])
def test_crossing_sea_force_variance_matches_the_frequency_domain(frequencies):
    m = _model(_sea(WIND, SWELL, components=80, frequencies=frequencies, seed=3))
    got, ref = model_variance(m), reference_variance(wind_density, swell_density)
    np.testing.assert_allclose(got, ref, rtol=0.03)
    # the setup's variance per direction band: the swell's share from -120 deg, the wind sea's around +30
    bands = m.setup_info().wave_energy_by_direction
    assert sum(bands.values()) == pytest.approx(1.0, abs=1e-12)
    swell = (1.2 / 4) ** 2 / ((1.2 / 4) ** 2 + (2.0 / 4) ** 2)
    assert bands["-120"] + bands.get("-150", 0.0) + bands.get("-90", 0.0) == pytest.approx(swell, abs=0.03)
    assert sum(bands.get(f"{c:+d}", 0.0) for c in range(-30, 91, 30)) == pytest.approx(1 - swell, abs=0.03)


def test_directional_table_and_buoy_units():
    """The wind sea as a table S(w, theta) (m^2 s/rad^2), and the same table in Hz and per degree
    (a buoy's units): the same variance, and the two tables give the same components."""
    w = np.linspace(0.2, 2.6, 121)
    th = np.arange(-175.0, 180.0, 5.0)
    table = wind_density(w, np.deg2rad(th))
    rad = dict(spectrum="table", omega=w.tolist(), theta=th.tolist(), density=table.tolist(), directions=11)
    m = _model(_sea(rad, components=80, frequencies="equal-energy"))
    np.testing.assert_allclose(model_variance(m), reference_variance(wind_density), rtol=0.03)
    hz = dict(rad, omega=(w / (2 * np.pi)).tolist(), density=(table * 2 * np.pi * np.pi / 180).tolist(), units="hz-deg")
    m_hz = _model(_sea(hz, components=80, frequencies="equal-energy"))
    np.testing.assert_allclose(m_hz.waves.amplitude, m.waves.amplitude, rtol=1e-9)
    np.testing.assert_allclose(m_hz.waves.headings, m.waves.headings, atol=1e-9)
    # the table's own frequencies
    own = _model(_sea(rad, frequencies="table"))
    assert own.waves.size == 11 * int(((w >= BAND[0] - 1e-9) & (w <= BAND[1] + 1e-9)).sum())


def wave_number(w, g, h):
    return brentq(lambda k: g * k * np.tanh(k * h) - w ** 2, 1e-9, 10 * w ** 2 / g + 10)


def test_component_list_reproduces_the_elevation_at_three_points():
    rng = np.random.default_rng(1)
    n = 12
    comps = dict(type="components", omega=np.linspace(0.4, 2.0, n).tolist(),
                 direction=rng.uniform(-180, 180, n).tolist(), amplitude=rng.uniform(0.05, 0.5, n).tolist(),
                 phase=rng.uniform(-180, 180, n).tolist())
    ds = make_body_hdb(omega=OMEGA, directions=np.deg2rad(np.arange(-180.0, 180.0, 15.0)), depth=30.0)
    text = scene_toml(dt=0.1, duration=10.0, water={"density": 1000.0, "depth": 30.0}, waves=comps,
                      bodies=[body("float", hdb="h", mass=3.0e5, center_of_mass=[0, 0, 0], inertia=[1e6] * 3)])
    m = HydroModel(parse_scene(text), {"float": ds})
    points = np.array([[0.0, 0.0], [12.0, -7.0], [-40.0, 25.0]])
    probes = WaveProbes(m.waves, points, np.zeros(0), 9.81, 30.0)
    k = np.array([wave_number(w, 9.81, 30.0) for w in comps["omega"]])
    b, ph = np.deg2rad(comps["direction"]), np.deg2rad(comps["phase"])
    for t in (0.0, 3.7, 101.3):
        ref = [sum(a * np.cos(kk * (p[0] * np.cos(bb) + p[1] * np.sin(bb)) - w * t + phi)
                   for a, kk, bb, w, phi in zip(comps["amplitude"], k, b, comps["omega"], ph)) for p in points]
        np.testing.assert_allclose(probes(t)[:, 0], ref, atol=1e-9)
    x0 = m.setup_info().equilibrium_position
    assert m.step(0.0, x0, np.zeros_like(x0))["wave_elevation"] == pytest.approx(probes(0.0)[0, 0], abs=1e-12)


def test_bad_sea_input_names_the_key():
    bad = dict(spectrum="table", omega=[0.5, 1.0, 1.5], density=[0.1, -0.2, 0.1])
    with pytest.raises(SceneError, match=r"waves.systems\[0\].*density.*negative"):
        _model(_sea(bad))
    with pytest.raises(SceneError, match="phase"):
        _model(dict(type="components", omega=[1.0], direction=[0.0], amplitude=[0.1], phase=[0.0, 1.0]))
    with pytest.raises(SceneError, match="tp"):
        _model(_sea(dict(spectrum="jonswap", hs=1.0)))
    # a sea from headings the HDB leaves out: the systems' key
    ds = make_body_hdb(omega=OMEGA, directions=np.deg2rad([0.0, 30.0, 60.0]))
    text = scene_toml(dt=0.1, duration=10.0, water={"density": 1000.0}, waves=_sea(WIND, SWELL, components=20),
                      bodies=[body("float", hdb="h", mass=3.0e5, center_of_mass=[0, 0, 0], inertia=[1e6] * 3)])
    with pytest.raises(ModelError) as err:
        HydroModel(parse_scene(text), {"float": ds})
    assert err.value.key == "waves.systems"


def test_breaking_and_time_step_checks_take_every_sea():
    """The breaking check (server/model.py) and the time-step check (clients/lockstep/preflight.py)
    read each system of a ``sea``, a table's peak and significant height from its own values, and
    each component of a list: the steepest (shortest) is refused by its own key. Deep water:
    lambda = g T^2 / (2 pi)."""
    from hydrolink.clients.lockstep.preflight import wave_resolution
    from hydrolink.protocol.scene import wave_peaks
    lam = lambda t: 9.81 * t ** 2 / (2 * np.pi)     # noqa: E731
    steep_wind = dict(WIND, hs=lam(7.0) / 6)        # H/lambda = 1/6 > 1/7
    with pytest.raises(ModelError) as err:
        _model(_sea(SWELL, steep_wind, components=20))
    assert err.value.key == "waves.systems[1].hs" and f"<= {lam(7.0) / 7:.4g} m" in err.value.why
    steep = dict(type="components", omega=[0.5, 2 * np.pi / 4.0], direction=[0.0, 30.0],
                 amplitude=[0.5, lam(4.0) / 12], phase=[0.0, 90.0])    # 2a/lambda = 1/6
    with pytest.raises(ModelError) as err:
        _model(steep)
    assert err.value.key == "waves.amplitude[1]" and f"<= {lam(4.0) / 14:.4g} m" in err.value.why
    # a table: peak at 1.0 rad/s, m0 = trapezoid of S = 0.25 * 1.0 -> Hs = 4 sqrt(0.25) = 2 m
    table = dict(spectrum="table", omega=[0.5, 1.0, 1.5], density=[0.0, 0.5, 0.0])
    (peak,) = wave_peaks(parse_scene(scene_toml(dt=0.1, duration=1.0, waves=_sea(table),
                                                bodies=[body("b", mass=1.0, center_of_mass=[0, 0, 0],
                                                             inertia=[1.0] * 3)])).waves)
    assert peak.period == pytest.approx(2 * np.pi) and peak.height == pytest.approx(2.0)
    # the time step: refused by the wind sea's peak period (4.5 s at dt = 1 s: 17 %), not the swell's
    scene = parse_scene(scene_toml(dt=1.0, duration=10.0, waves=_sea(SWELL, dict(WIND, tp=4.5)),
                                   bodies=[body("b", mass=1.0, center_of_mass=[0, 0, 0], inertia=[1.0] * 3)]))
    verdict, why = wave_resolution(scene, 1.0)
    assert verdict == "refuse" and "waves.systems[1].tp = 4.5 s" in why
    # a component list: only components with >= 1 % of the variance count (the 2 s ripple has 0.04 %)
    comps = dict(type="components", omega=[2 * np.pi / 12, 2 * np.pi / 2.0], direction=[0.0, 0.0],
                 amplitude=[1.0, 0.02], phase=[0.0, 0.0])
    scene = parse_scene(scene_toml(dt=0.5, duration=10.0, waves=comps,
                                   bodies=[body("b", mass=1.0, center_of_mass=[0, 0, 0], inertia=[1.0] * 3)]))
    assert wave_resolution(scene, 0.5) is None
    comps["amplitude"] = [1.0, 0.5]
    scene = parse_scene(scene_toml(dt=0.5, duration=10.0, waves=comps,
                                   bodies=[body("b", mass=1.0, center_of_mass=[0, 0, 0], inertia=[1.0] * 3)]))
    verdict, why = wave_resolution(scene, 0.5)
    assert verdict == "refuse" and "the period of waves.omega[1] = 2 s" in why


@pytest.mark.parametrize("fmt", ["csv", "netcdf"])
def test_directional_table_from_a_file(tmp_path, fmt):
    """The wind sea's table S(w, theta) in a CSV or NetCDF file (waves.systems[i].file): the same
    components as the inline table, bit for bit, and the force variance of the frequency domain (3 %);
    through a server in hello.spectra, the same setup; negative values are refused naming the key
    and the file; a server without the table refuses naming the key."""
    import xarray as xr
    from hydrolink.clients.lockstep.connection import RemoteError, ServerConnection
    from hydrolink.clients.scene_inputs import load_spectrum_files
    from hydrolink.server.service.force_server import ForceServer
    w = np.linspace(0.2, 2.6, 121)
    th = np.arange(-175.0, 180.0, 5.0)
    table = wind_density(w, np.deg2rad(th))

    def write(name: str, values: np.ndarray) -> str:
        path = tmp_path / f"{name}.{'csv' if fmt == 'csv' else 'nc'}"
        if fmt == "csv":
            rows = ["omega/theta," + ",".join(repr(float(t)) for t in th)]
            rows += [repr(float(x)) + "," + ",".join(repr(float(v)) for v in row) for x, row in zip(w, values)]
            path.write_text("\n".join(rows) + "\n")
        else:
            xr.Dataset({"density": (("omega", "theta"), values)}, coords={"omega": w, "theta": th}).to_netcdf(path)
        return str(path)

    inline = dict(spectrum="table", omega=w.tolist(), theta=th.tolist(), density=table.tolist(), directions=11)
    filed = dict(spectrum="table", file=write("wind", table), directions=11)
    hdb = make_body_hdb(omega=OMEGA, directions=np.deg2rad(np.arange(-180.0, 180.0, 5.0)))
    bodies = [body("float", hdb="h", mass=3.0e5, center_of_mass=[0, 0, 0], inertia=[1e6] * 3)]
    text = scene_toml(dt=0.1, duration=10.0, water={"density": 1000.0}, bodies=bodies,
                      waves=_sea(filed, components=80, frequencies="equal-energy"))
    scene_path = tmp_path / "scene.toml"
    scene = parse_scene(text, scene_path)
    tables = load_spectrum_files(scene, scene_path)
    m = HydroModel(scene.with_spectra(tables), {"float": hdb})
    ref = _model(_sea(inline, components=80, frequencies="equal-energy"))
    for key in ("omega", "amplitude", "phase", "headings"):
        np.testing.assert_array_equal(getattr(m.waves, key), getattr(ref.waves, key))
    np.testing.assert_allclose(model_variance(m), reference_variance(wind_density), rtol=0.03)
    with ServerConnection(ForceServer(None)) as conn:
        setup = conn.hello(text, {"h": hdb}, spectra=tables)
        assert setup.wave_components == ref.waves.size
    with ServerConnection(ForceServer(None)) as conn, pytest.raises(RemoteError) as err:
        conn.hello(text, {"h": hdb})
    assert err.value.field == "scene.waves.systems[0].file"
    bad = table.copy()
    bad[40, 10] = -1e-3
    neg = text.replace(filed["file"], write("negative", bad))
    with pytest.raises(SceneError) as err:
        load_spectrum_files(parse_scene(neg, scene_path), scene_path)
    assert err.value.key == "waves.systems[0].file" and "negative" in str(err.value) and "negative." in str(err.value)
