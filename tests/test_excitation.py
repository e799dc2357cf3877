"""Excitation options ([waves] excitation = "convolution", type = "elevation", cos-2s spreading)
against independent references: a closed-form excitation IRF, the frequency superposition of the
same components, hand-summed directional forces, and quadrature of the spreading function.

Measured here (RM3 WAMIT HDB, JONSWAP Hs 2.5 m, Tp 8 s, dt 0.05 s, 400 components, every DOF):
convolution vs superposition of the excitation force, worst DOF with a non-negligible force,
max |dF| / max |F|: T_c = 5 s 31 %, 10 s 1.8 %, 20 s 0.06 %, 40 s 0.02 % (Tp 4 s: 116 %, 2.4 %,
0.09 %, 0.02 %). The short windows fail on the spar, whose excitation (a deep plate) has a long
non-causal tail; 20 s (the default) is enough for RM3.
"""

from __future__ import annotations

import dataclasses

import numpy as np
import pytest
from scipy.integrate import quad

from hydrolink.protocol.scene import parse_scene
from hydrolink.server.model import HydroModel, ModelError
from hydrolink.server.sea.waves import WaveError, convolution_kernel, cos2s, cos2s_directions, cos2s_normalisation, elevation, elevation_on_grid, excitation_irf, excitation_nodes, kernel_transfer, read_elevation, wave_components
from analytic_hdb import make_body_hdb
from conftest import body, irregular_waves, regular_waves, rm3_float, rm3_pto, rm3_spar, scene_toml, write_scene


def _rm3_scene(waves: dict, hdb: str = "h", dt: float = 0.05, duration: float = 200.0, dofs_all: bool = False) -> str:
    """RM3 (float, spar, damper) in ``waves``: heave only, or every DOF with ``dofs_all``."""
    dofs = {} if dofs_all else {"dofs": ["heave"]}
    return scene_toml(dt=dt, duration=duration, progress=False, water={"density": 1000.0}, waves=waves,
                      hydro={"irf_duration": 30.0}, bodies=[rm3_float(hdb, **dofs), rm3_spar(hdb, **dofs)],
                      ptos=[rm3_pto()])


def _irregular(exc: str, tc: float, **keys) -> dict:
    """The JONSWAP sea of these tests (Hs 2.5 m, Tp 8 s) with its excitation method and T_c."""
    return irregular_waves(2.5, 8.0, components=400, seed=3, ramp=10.0, excitation=exc, excitation_irf_duration=tc,
                           **keys)


def _elevation(file: str, **keys) -> dict:
    """A [waves] section of type "elevation"."""
    return {"type": "elevation", "file": file, **keys}


@pytest.fixture(scope="module")
def rm3(reference_data):
    from hydrolink.server.hdb.io import load_hdb
    return load_hdb(reference_data / "rm3_wamit" / "rm3.1")


def _forces(model: HydroModel, n: int) -> tuple[np.ndarray, np.ndarray]:
    pos = model.setup_info().equilibrium_position
    vel = np.zeros_like(pos)
    out = [model.step(k * model.dt, pos, vel) for k in range(n)]
    return np.array([o["excitation"].reshape(-1) for o in out]), np.array([o["wave_elevation"] for o in out])


# ------------------------------------------------------------------ the excitation IRF

@pytest.mark.filterwarnings("ignore::scipy.integrate.IntegrationWarning")
def test_excitation_irf_closed_form_gaussian():
    """X(w) = exp(-w^2/2) e^{i w a} has K_ex(t) = exp(-(t-a)^2/2)/sqrt(2 pi) (peak at the lag a > 0:
    a body downstream of the origin feels the wave later)."""
    a = 3.0
    om = np.linspace(0.02, 8.0, 400)
    x = (np.exp(-om ** 2 / 2) * np.exp(1j * om * a))[:, None]
    nodes, values = excitation_nodes(om, x, 0.01)
    t = np.linspace(-10, 10, 2001)
    k = excitation_irf(nodes, values, t)[:, 0]
    ref = np.exp(-(t - a) ** 2 / 2) / np.sqrt(2 * np.pi)
    assert np.abs(k - ref).max() < 1e-3 * ref.max()   # X linear between the 0.02 rad/s grid points
    assert t[np.argmax(k)] == pytest.approx(a, abs=0.011)
    # the closed-form piecewise-linear transform = adaptive quadrature of (1/pi) Re int X e^{-iwt}
    for tt in (0.0, 0.37, 2.9, -1.3):
        f = lambda w: (np.interp(w, nodes, values[:, 0].real) * np.cos(w * tt)  # noqa: E731
                       + np.interp(w, nodes, values[:, 0].imag) * np.sin(w * tt)) / np.pi
        q = sum(quad(f, lo, hi, limit=200)[0] for lo, hi in zip(nodes[:-1:20], np.append(nodes[20::20], nodes[-1])))
        assert excitation_irf(nodes, values, [tt])[0, 0] == pytest.approx(q, abs=2e-6)


def test_discrete_convolution_reproduces_x(rm3):
    """sum_j dt w_j K(j dt) e^{i w j dt} -> X(w) on the HDB grid as T_c grows (RM3 float and spar heave)."""
    om = rm3["omega"].values
    x = rm3["excitation_force"].values[:, 0, [2, 8]]
    band = (om > 0.3) & (om < 3.0)
    errs = []
    for tc in (10.0, 20.0, 40.0):
        h = kernel_transfer(convolution_kernel(om, x, 0.05, tc), 0.05, om[band])
        errs.append(float((np.abs(h - x[band]).max(axis=0) / np.abs(x[band]).max(axis=0)).max()))
    assert errs[0] > errs[1] > errs[2]
    assert errs[1] < 5e-3 and errs[2] < 1e-3


# ------------------------------------------------------------------ convolution vs superposition

def test_convolution_matches_superposition_irregular(rm3):
    """Irregular sea (JONSWAP Hs 2.5 m, Tp 8 s), every DOF of both bodies: the force by convolution
    with the synthesized elevation vs the frequency superposition, as a function of T_c."""
    n = 3000
    sup = HydroModel(parse_scene(_rm3_scene(_irregular("superposition", 20), dofs_all=True)),
                     {"float": rm3, "spar": rm3})
    f_ref, eta_ref = _forces(sup, n)
    live = np.abs(f_ref).max(axis=0) > 1e-3 * np.abs(f_ref).max()
    err = {}
    for tc in (5.0, 10.0, 20.0, 40.0):
        conv = HydroModel(parse_scene(_rm3_scene(_irregular("convolution", tc), dofs_all=True)),
                          {"float": rm3, "spar": rm3})
        assert conv.setup_info().excitation == "convolution"
        f, eta = _forces(conv, n)
        np.testing.assert_allclose(eta, eta_ref, atol=1e-12)   # the same elevation, the same ramp
        d = np.abs(f - f_ref)[:, live].max(axis=0) / np.abs(f_ref)[:, live].max(axis=0)
        err[tc] = float(d.max())
    assert err[5.0] > err[10.0] > err[20.0] > err[40.0]
    assert err[20.0] < 2e-3 and err[40.0] < 5e-4 and err[10.0] < 0.03


def test_convolution_with_a_cut_hdb_range(rm3):
    """The HDB cut at 1.6 rad/s (the spectrum's tail beyond it is left out by both methods): the
    convolution still agrees with the superposition (the taper beyond w_max keeps K_ex short)."""
    cut = rm3.isel(omega=rm3["omega"].values <= 1.6)
    n = 2000
    models = [HydroModel(parse_scene(_rm3_scene(_irregular(e, 30))), {"float": cut, "spar": cut})
              for e in ("superposition", "convolution")]
    (f0, _), (f1, _) = (_forces(m, n) for m in models)
    assert np.abs(f1 - f0).max(axis=0).max() / np.abs(f0).max() < 3e-3
    assert models[0].waves.energy_outside > 0.01


def test_regular_wave_convolution_run_matches_superposition(rm3, tmp_path, reference_data):
    """End to end (hydrolink run, Exudyn client): RM3 in a regular wave, excitation by convolution
    vs superposition: heave motions and PTO power agree."""
    import xarray as xr
    from hydrolink.clients.run import run_scene_file
    hdb = reference_data / "rm3_wamit" / "rm3.1"
    res = {}
    for exc in ("superposition", "convolution"):
        waves = regular_waves(2.5, 8.0, ramp=20.0, excitation=exc, excitation_irf_duration=30.0)
        p = write_scene(tmp_path, _rm3_scene(waves, hdb=str(hdb), dt=0.08, duration=120.0), f"{exc}.toml")
        run_scene_file(p, tmp_path / f"{exc}.nc", progress=False, hdbs={str(hdb): rm3})
        with xr.open_dataset(tmp_path / f"{exc}.nc") as ds:
            res[exc] = (ds["position"].values[:, :, 2], ds["total_pto_power"].values)
    (x0, p0), (x1, p1) = res["superposition"], res["convolution"]
    assert np.abs(x1 - x0).max() < 2e-3 * np.abs(x0 - x0[0]).max()
    assert p1[-500:].mean() == pytest.approx(p0[-500:].mean(), rel=3e-3)


# ------------------------------------------------------------------ elevation files

def _components(rm3):
    om = rm3["omega"].values
    w = parse_scene(_rm3_scene(_irregular("superposition", 20))).waves
    return wave_components(w, float(om[0]), float(om[-1]))


@pytest.mark.parametrize("fmt,spacing", [("csv", 0.05), ("nc", 0.05), ("csv", 0.02)])
def test_elevation_file_matches_superposition(rm3, tmp_path, fmt, spacing):
    """eta(t) of an irregular sea written to a file (CSV with a header, or NetCDF; at dt or at 0.02 s
    -> resampled), run as type = "elevation": the force equals the superposition of the same waves."""
    comps = _components(rm3)
    start = 30.0                               # file time of simulation t = 0
    t = np.arange(0.0, 300.0, spacing)
    eta = elevation(dataclasses.replace(comps, ramp=0.0), t - start)   # the sea without its ramp
    path = tmp_path / f"eta.{fmt}"
    if fmt == "csv":
        path.write_text("time,eta\n" + "".join(f"{a:.6f},{b:.12e}\n" for a, b in zip(t, eta)))
    else:
        import xarray as xr
        xr.Dataset({"eta": ("time", eta)}, coords={"time": t}).to_netcdf(path)
    tt, ee = read_elevation(path)
    np.testing.assert_allclose(ee, eta, rtol=1e-10, atol=1e-12)
    n = 2000
    waves = _elevation(str(path), start=start, ramp=10.0, excitation_irf_duration=25.0)
    model = HydroModel(parse_scene(_rm3_scene(waves)), {"float": rm3, "spar": rm3}, (tt, ee))
    assert model.setup_info().elevation_resampled == (spacing != 0.05)
    f, e = _forces(model, n)
    sup = HydroModel(parse_scene(_rm3_scene(_irregular("superposition", 20))),
                     {"float": rm3, "spar": rm3})
    f0, e0 = _forces(sup, n)
    np.testing.assert_allclose(e, e0, atol=2e-5 * np.abs(e0).max())
    assert np.abs(f - f0).max() < 2e-3 * np.abs(f0).max()


def test_elevation_run_end_to_end(rm3, tmp_path, reference_data):
    """hydrolink run with a CSV (default start = first time + T_c): results' wave_elevation is the
    file's eta from there on."""
    import xarray as xr
    from hydrolink.clients.run import run_scene_file
    t = np.arange(0.0, 100.0, 0.08)
    eta = 0.8 * np.cos(2 * np.pi / 8.0 * t) + 0.3 * np.sin(2 * np.pi / 5.5 * t + 1.0)
    (tmp_path / "eta.csv").write_text("\n".join(f"{a:.4f} {b:.10f}" for a, b in zip(t, eta)))
    hdb = reference_data / "rm3_wamit" / "rm3.1"
    p = write_scene(tmp_path, _rm3_scene(_elevation("eta.csv", excitation_irf_duration=20.0), hdb=str(hdb), dt=0.08,
                                         duration=40.0))
    s = run_scene_file(p, tmp_path / "out.nc", progress=False, hdbs={str(hdb): rm3})
    assert s.status == "complete"
    with xr.open_dataset(tmp_path / "out.nc") as ds:
        np.testing.assert_allclose(ds["wave_elevation"].values, eta[250:250 + 501], atol=1e-9)
        assert np.isfinite(ds["position"].values).all() and np.abs(ds["position"].values[:, :, 2]).max() > 0.1


def test_hydrochrono_eta_file_is_read(tmp_path):
    """HydroChrono's eta file format: one 't : eta' pair a line (its IrregularWaves reads
    'time >> delimiter >> eta' with delimiter ':'), as in its data/verification/rm3_mooring/inputs
    eta file ('0.000000 : -1.7947502460e+00'); also without spaces. Read to the values written."""
    t = np.arange(0.0, 20.0, 0.01)
    eta = 1.2 * np.cos(2 * np.pi / 8.0 * t + 0.4) - 0.3 * np.sin(2 * np.pi / 5.0 * t)
    spaced, tight = tmp_path / "eta.txt", tmp_path / "eta_tight.txt"
    spaced.write_text("".join(f"{a:.6f} : {b:.10e}\n" for a, b in zip(t, eta)))
    tight.write_text("".join(f"{a:.6f}:{b:.10e}\n" for a, b in zip(t, eta)))
    for path in (spaced, tight):
        tt, ee = read_elevation(path)
        np.testing.assert_allclose(tt, np.round(t, 6), rtol=0, atol=1e-12)
        np.testing.assert_allclose(ee, eta, rtol=1e-10, atol=1e-12)
    words = tmp_path / "words.txt"
    words.write_text("time eta\nseconds metres\n")
    with pytest.raises(WaveError, match=r"no data rows: expected lines of two numbers, time and eta, separated by "
                                        r"spaces, ',', ';' or ':' \(HydroChrono's 't : eta'\); its first line is "
                                        r"'time eta'"):
        read_elevation(words)


def test_elevation_errors_name_the_key(rm3, tmp_path):
    from hydrolink.clients.run import run_scene_file
    from hydrolink.protocol.scene import SceneError
    with pytest.raises(WaveError, match="waves.file: elevation file not found"):
        read_elevation(tmp_path / "none.csv")
    bad = tmp_path / "bad.csv"
    bad.write_text("time,eta\n0,0\n0.1,abc\n")
    with pytest.raises(WaveError, match="line 3"):
        read_elevation(bad)
    three = tmp_path / "three.csv"
    three.write_text("0 0 1\n")
    with pytest.raises(WaveError, match="two columns"):
        read_elevation(three)
    t = np.arange(0, 50, 0.05)
    e = np.sin(t)
    with pytest.raises(WaveError, match="too short"):
        elevation_on_grid(t, e, 0.05, 1000, 20.0, None, 5.2)   # needs 20 + 50 + 20 s
    with pytest.raises(WaveError, match="increase strictly"):
        elevation_on_grid(np.r_[t[:10], t[9:]], np.r_[e[:10], e[9:]], 0.05, 10, 1.0, None, 5.2)
    with pytest.raises(WaveError, match="coarser than pi/w_max"):
        elevation_on_grid(np.arange(0, 500, 1.0), np.sin(np.arange(500.0)), 0.05, 100, 5.0, None, 5.2)
    with pytest.raises(WaveError, match="non-finite"):
        elevation_on_grid(t, np.where(t > 3, np.nan, e), 0.05, 10, 1.0, None, 5.2)
    # through the model and the run: the key is named
    with pytest.raises(ModelError, match="waves.file"):
        HydroModel(parse_scene(_rm3_scene(_elevation("x.csv"))), {"float": rm3, "spar": rm3})
    with pytest.raises(ModelError, match=r"waves.file: x.csv: too short"):
        HydroModel(parse_scene(_rm3_scene(_elevation("x.csv"))), {"float": rm3, "spar": rm3}, (t, e))
    p = write_scene(tmp_path, _rm3_scene(_elevation("missing.csv"), hdb="h.nc"))
    with pytest.raises(SceneError, match="waves.file: elevation file not found"):
        run_scene_file(p, tmp_path / "o.nc", progress=False, hdbs={"h.nc": rm3})


# ------------------------------------------------------------------ directional spreading

@pytest.mark.parametrize("s", [1.0, 4.0, 15.0, 75.0])
def test_cos2s_integrates_to_one_and_sectors(s):
    assert quad(lambda th: float(cos2s(th, s)), -np.pi, np.pi, limit=400)[0] == pytest.approx(1.0, rel=1e-9)
    assert cos2s_normalisation(1.0) == pytest.approx(1 / np.pi, rel=1e-12)  # int cos^2(th/2) = pi
    mean = np.deg2rad(30.0)
    heads, wts = cos2s_directions(s, 7, mean)
    assert wts.sum() == pytest.approx(1.0, abs=1e-15)
    assert np.sum(wts * heads) == pytest.approx(mean, abs=1e-12)          # mean direction
    assert np.angle(np.sum(wts * np.exp(1j * heads))) == pytest.approx(mean, abs=1e-12)
    # each sector carries 1/7 of int D and its heading is the sector's centroid (independent quad)
    edges = [-np.pi]
    for k in range(1, 7):   # quantiles by bisection on the quadrature CDF
        lo, hi = -np.pi, np.pi
        for _ in range(60):
            mid = 0.5 * (lo + hi)
            lo, hi = (mid, hi) if quad(lambda th: float(cos2s(th, s)), -np.pi, mid, limit=200)[0] < k / 7 else (lo, mid)
        edges.append(0.5 * (lo + hi))
    edges.append(np.pi)
    cent = [quad(lambda th: th * float(cos2s(th, s)), a, b, limit=200)[0] * 7 for a, b in zip(edges[:-1], edges[1:])]
    np.testing.assert_allclose(heads - mean, cent, atol=2e-4)


def test_spread_sea_variance_direction_and_elevation_statistics():
    from hydrolink.protocol.scene import IrregularWave
    kw = dict(type="irregular", spectrum="jonswap", hs=2.5, tp=8.0, components=150, seed=3)
    c = wave_components(IrregularWave(**kw, direction=20.0, spreading="cos2s", s=6.0, directions=11), 0.02, 5.2)
    c1 = wave_components(IrregularWave(**kw), 0.02, 5.2)
    assert c.size == 11 * c1.size and np.unique(c.omega).size == c.size   # every component its own frequency
    # total variance preserved (the spectrum's m0 within the range), per frequency bin too
    assert np.sum(c.amplitude ** 2) / 2 == pytest.approx(np.sum(c1.amplitude ** 2) / 2, rel=1e-12)
    np.testing.assert_allclose((c.amplitude ** 2).reshape(11, -1).sum(axis=0), c1.amplitude ** 2, rtol=1e-12)
    dw = c1.omega[1] - c1.omega[0]
    assert np.abs(c.omega.reshape(11, -1) - c1.omega[None, :]).max() < dw / 2
    # energy-weighted mean direction; each direction carries 1/11 of the energy
    e = c.amplitude ** 2
    assert np.degrees(np.sum(e * c.headings) / e.sum()) == pytest.approx(20.0, abs=1e-9)
    np.testing.assert_allclose(e.reshape(11, -1).sum(axis=1), e.sum() / 11, rtol=1e-12)
    # elevation statistics over 2 hours (longer than the 2 pi / (dw / 11) = 1,800 s repeat period)
    t = np.arange(0.0, 7200.0, 0.5)
    eta = elevation(c, t)
    m0 = np.sum(e) / 2
    assert eta.var() == pytest.approx(m0, rel=0.03)
    assert 4 * eta.std() == pytest.approx(2.5 * np.sqrt(1 - c.energy_outside), rel=0.02)
    assert abs(eta.mean()) < 0.02 * eta.std()
    zero_up = np.sum((eta[:-1] < 0) & (eta[1:] >= 0))          # mean zero-crossing period ~ 2 pi sqrt(m0/m2)
    m2 = np.sum(e / 2 * c.omega ** 2)
    assert 7200.0 / zero_up == pytest.approx(2 * np.pi * np.sqrt(m0 / m2), rel=0.05)


def _heading_hdb():
    """Analytic single body over headings -90..90 deg every 1 deg: X(w, beta) known in closed form."""
    def exc(w, beta):
        base = np.array([1e4, 1e4, 3e5, 2e5, 2e5, 1e4])
        rot = np.array([np.cos(beta), np.sin(beta), 1.0, np.sin(beta), np.cos(beta), 0.5 * np.sin(2 * beta)])
        return (base * rot)[None, :] * np.exp(-0.3 * w[:, None] ** 2) * np.exp(1j * (0.4 + 0.8 * w[:, None]))
    return make_body_hdb(omega=np.linspace(0.05, 4.0, 300), directions=np.deg2rad(np.arange(-90, 91, 1.0)),
                         exc=exc), exc


def _spread_scene(exc: str) -> str:
    """One float in a cos-2s spread sea (s = 4, 9 directions around 10 deg)."""
    return scene_toml(dt=0.05, duration=100.0, water={"density": 1000.0},
                      waves=irregular_waves(2.0, 7.0, components=120, seed=5, direction=10.0, spreading="cos2s", s=4.0,
                                            directions=9, excitation=exc, excitation_irf_duration=60.0),
                      bodies=[body("float", hdb="h", mass=3.0e5, center_of_mass=[0, 0, 0], inertia=[1e6, 1e6, 1e6])])


def test_spread_excitation_against_hand_sum_and_convolution():
    """Every component's force uses X at its own heading: the model's force equals the hand sum
    over the components with the closed-form X(w, beta); sway/roll (zero in head seas) appear.
    Convolution (one elevation series and one K_ex per heading) agrees with it. (T_c = 60 s: this
    made-up X keeps a phase of 0.4 rad at w -> 0, unlike a physical X(0), which is real, so its K_ex
    has a slow tail from the low-frequency end; 30 s gives 1 %.)"""
    ds, exc = _heading_hdb()
    m = HydroModel(parse_scene(_spread_scene("superposition")), {"float": ds})
    c = m.waves
    assert np.unique(c.headings).size == 9
    f, eta = _forces(m, 600)
    t = np.arange(600) * 0.05
    ref = np.zeros((600, 6))
    for head in np.unique(c.headings):
        on = c.headings == head
        x = exc(c.omega[on], head)  # (n, 6)
        ref += np.real(np.exp(-1j * np.outer(t, c.omega[on])) @ ((c.amplitude[on] * np.exp(1j * c.phase[on]))[:, None] * x))
    scale = np.abs(ref).max(axis=0)
    assert (np.abs(f - ref).max(axis=0) / scale).max() < 1e-3   # heading + frequency interpolation only
    assert np.abs(f[:, 1]).max() > 0.05 * np.abs(f[:, 0]).max()   # spreading excites sway
    mc = HydroModel(parse_scene(_spread_scene("convolution")), {"float": ds})
    fc, etac = _forces(mc, 600)
    np.testing.assert_allclose(etac, eta, atol=1e-12)
    assert (np.abs(fc - f).max(axis=0) / scale).max() < 2e-3


def test_spreading_beyond_the_hdb_headings_names_the_key(rm3):
    with pytest.raises(ModelError, match="waves.spreading"):
        HydroModel(parse_scene(_rm3_scene(_irregular("superposition", 20, spreading="cos2s", s=10.0,
                                                     directions=5))),
                   {"float": rm3, "spar": rm3})
    # one direction = the unidirectional sea (the centroid of the whole circle is the mean)
    m = HydroModel(parse_scene(_rm3_scene(_irregular("superposition", 20, spreading="cos2s",
                                                     directions=1))), {"float": rm3, "spar": rm3})
    m0 = HydroModel(parse_scene(_rm3_scene(_irregular("superposition", 20))),
                    {"float": rm3, "spar": rm3})
    np.testing.assert_allclose(_forces(m, 50)[0], _forces(m0, 50)[0], rtol=1e-12, atol=1e-6)
