"""Second-order wave forces (server/terms/second_order.py, issue 23) against references written here:
the WAMIT formulas (F = rho g A^2 L Fbar for a .8 row; T = rho g L conj(Re + i Im) for a .12d/.12s
row), the two-component closed forms of the mean, Newman (arithmetic mean) and full-QTF forces, and the
static offset F/k of a body on a surge spring in a hydrolink run."""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from conftest import SPHERE_WATER, irregular_waves, regular_waves, scene_toml, sphere_body, write_scene

from hydrolink.protocol.hdb.layout import HDBError, hdb_warnings
from hydrolink.protocol.hdb.schema import to_netcdf
from hydrolink.protocol.hdb.schema import with_second_order
from hydrolink.protocol.scene import parse_scene
from hydrolink.server.errors import ModelError
from hydrolink.server.terms.base import TermContext
from hydrolink.server.hdb.wamit.second_order import read_drift, read_qtf
from hydrolink.server.hdb.wamit.table import Units
from hydrolink.server.model import HydroModel
from hydrolink.server.terms.second_order import SecondOrderTerm
from hydrolink.server.sea.waves import WaveComponents

ULEN = 5.0
PERIODS = (20.0, 12.0, 9.0, 7.0, 5.5, 4.5)
MASS = 261.8e3


def drift_bar(per: float, mode: int) -> float:
    """Nondimensional mean drift written into the .8 (surge, sway, yaw)."""
    return {1: 0.3 / (1 + (per / 7.0) ** 2), 2: 0.0, 6: 0.01 * per}[mode]


def qtf_bar(pi: float, pj: float, mode: int, kind: str) -> complex:
    """Nondimensional QTF written into the .12d / .12s (one triangle; the difference diagonal real)."""
    t = complex(0.2 + 0.01 * pi + 0.02 * pj + 0.1 * mode, 0.03 * (pi - pj) + (0.01 * mode if kind == "s" else 0))
    return t


def write_wamit_second_order(folder: Path) -> Path:
    """.8 mean drift (beta 0) and .12d/.12s QTFs (surge, heave) of stem ``folder/run``."""
    folder.mkdir(parents=True, exist_ok=True)
    rows = [f"{p} 0.0 0.0 {i} {abs(drift_bar(p, i))} 0.0 {drift_bar(p, i)} 0.0" for p in PERIODS for i in (1, 2, 6)]
    (folder / "run.8").write_text("\n".join(rows) + "\n")
    for kind in ("d", "s"):
        rows = []
        for a, pi in enumerate(PERIODS):
            for pj in PERIODS[a:]:
                for i in (1, 3):
                    t = qtf_bar(pi, pj, i, kind)
                    rows.append(f"{pi} {pj} 0.0 0.0 {i} {abs(t)} {np.degrees(np.angle(t))} {t.real} {t.imag}")
        (folder / f"run.12{kind}").write_text("\n".join(rows) + "\n")
    return folder / "run"


@pytest.fixture(scope="module")
def drift_hdb(sphere, tmp_path_factory) -> tuple[xr.Dataset, Path]:
    """The Task-10 sphere's HDB with the WAMIT second-order files above (read by the WAMIT readers)."""
    folder = tmp_path_factory.mktemp("drift")
    stem = write_wamit_second_order(folder)
    units = Units(float(sphere.attrs["rho"]), float(sphere.attrs["g"]), ULEN, 1)
    ds = with_second_order(sphere, mean_drift=read_drift(stem, units, 6), qtf=read_qtf(stem, units, 6))
    path = folder / "sphere_drift.nc"
    to_netcdf(ds, path)
    return ds, path


def _rho_g(ds: xr.Dataset) -> float:
    return float(ds.attrs["rho"]) * float(ds.attrs["g"])


def _t_file(ds: xr.Dataset, pi: float, pj: float, mode: int, kind: str) -> complex:
    """T of the file's row (or its mirror) in SI and exp(-iwt): rho g L conj(Re + i Im)."""
    if PERIODS.index(pi) > PERIODS.index(pj):
        t = qtf_bar(pj, pi, mode, kind)
        t = np.conj(t) if kind == "d" else t
    else:
        t = qtf_bar(pi, pj, mode, kind)
    return _rho_g(ds) * ULEN * np.conj(t)


def _scene(path: Path, waves: dict, **hydro) -> str:
    return scene_toml(dt=0.1, duration=10.0, water=SPHERE_WATER, waves=waves, hydro=hydro,
                      bodies=[sphere_body(str(path), mass=MASS)])


def test_regular_wave_drift_is_rho_g_a2_l_fbar(drift_hdb):
    ds, path = drift_hdb
    a, period = 1.5, 7.0
    model = HydroModel(parse_scene(_scene(path, regular_waves(2 * a, period), second_order="mean-drift")),
                       {"sphere": ds})
    f = model.step(0.0, model.setup_info().equilibrium_position, np.zeros((1, 6)))["drift"][0]
    rg = _rho_g(ds)
    assert f[0] == pytest.approx(rg * a ** 2 * ULEN * drift_bar(period, 1), rel=1e-9)
    assert f[5] == pytest.approx(rg * a ** 2 * ULEN ** 2 * drift_bar(period, 6), rel=1e-9)
    assert np.all(f[1:5] == 0)
    # the full QTF in a regular wave: A^2 T-(w, w) plus the sum-frequency A^2 Re(T+ c^2 e^{-2iwt})
    scene = parse_scene(_scene(path, regular_waves(2 * a, period, phase=30.0), second_order="qtf",
                               sum_frequency=True))
    model = HydroModel(scene, {"sphere": ds})
    w, phi = 2 * np.pi / period, np.radians(30.0)
    x0 = model.setup_info().equilibrium_position
    for k in range(3):
        t = k * model.dt
        f = model.step(t, x0, np.zeros((1, 6)))["drift"][0]
        for mode, dof in ((1, 0), (3, 2)):
            mean = a ** 2 * _t_file(ds, period, period, mode, "d").real
            osc = (a ** 2 * _t_file(ds, period, period, mode, "s") * np.exp(2j * phi - 2j * w * t)).real
            assert f[dof] == pytest.approx(mean + osc, rel=1e-9)


def _bichromatic(omega, amp, phase) -> WaveComponents:
    return WaveComponents(np.array(omega), np.array(amp), np.array(phase), 0.0, 0.0, 0.0, "irregular")


def _term(ds: xr.Dataset, waves: WaveComponents, **hydro) -> SecondOrderTerm:
    scene = parse_scene(_scene(Path("sphere_drift.nc"), regular_waves(1.0, 7.0), **hydro))
    ctx = TermContext(scene, [0], np.ones((1, 6), bool), np.arange(6), waves, np.zeros((1, 6)),
                      np.zeros((6, 6)), [None], {}, {"sphere": ds})
    return SecondOrderTerm.build(ctx)


@pytest.mark.parametrize("mode", ["mean-drift", "newman", "qtf"])
def test_bichromatic_sea_against_the_closed_form(drift_hdb, mode):
    """Two components on the data's grid: the mean, Newman (T12 = (T11 + T22)/2) and full difference (+ sum)
    force against the two-component formulas written out here."""
    ds, _ = drift_hdb
    (p1, p2), amp, phase = (9.0, 7.0), (1.2, 0.7), (0.4, 2.1)
    w = [2 * np.pi / p1, 2 * np.pi / p2]
    term = _term(ds, _bichromatic(w, amp, phase), second_order=mode, sum_frequency=mode == "qtf")
    rg, (a1, a2), (f1, f2) = _rho_g(ds), amp, phase
    dw, dphi = w[0] - w[1], f1 - f2
    for t in (0.0, 3.3, 17.9, 101.0):
        f = term.force(t, np.zeros((1, 6)), np.zeros((1, 6)))[0][0]
        if mode in ("mean-drift", "newman"):
            t11, t22 = rg * ULEN * drift_bar(p1, 1), rg * ULEN * drift_bar(p2, 1)
            expect = a1 ** 2 * t11 + a2 ** 2 * t22
            if mode == "newman":   # Newman: T12 = T21 = (T11 + T22) / 2
                # (eta = sum A_i cos(w_i t - phi_i) here: the beat is cos((w1 - w2) t - (phi1 - phi2)))
                expect += a1 * a2 * (t11 + t22) * np.cos(dw * t - dphi)
            assert f[0] == pytest.approx(expect, rel=1e-9)
            continue
        for qmode, dof in ((1, 0), (3, 2)):
            t11, t22, t12 = (_t_file(ds, p1, p1, qmode, "d").real, _t_file(ds, p2, p2, qmode, "d").real,
                             _t_file(ds, p1, p2, qmode, "d"))
            diff = (a1 ** 2 * t11 + a2 ** 2 * t22
                    + 2 * a1 * a2 * (t12.real * np.cos(dw * t - dphi) + t12.imag * np.sin(dw * t - dphi)))
            s11, s22, s12 = (_t_file(ds, p1, p1, qmode, "s"), _t_file(ds, p2, p2, qmode, "s"),
                             _t_file(ds, p1, p2, qmode, "s"))
            total = (a1 ** 2 * abs(s11) * np.cos(2 * w[0] * t - 2 * f1 - np.angle(s11))
                     + a2 ** 2 * abs(s22) * np.cos(2 * w[1] * t - 2 * f2 - np.angle(s22))
                     + 2 * a1 * a2 * abs(s12) * np.cos((w[0] + w[1]) * t - f1 - f2 - np.angle(s12)))
            assert f[dof] == pytest.approx(diff + total, rel=1e-9, abs=1e-9 * abs(diff))


def test_interpolated_qtf_equals_the_dense_double_sum(drift_hdb):
    """Off-grid components: the factorised force equals the O(N^2) double sum over a T_ij
    interpolated bilinearly here (np.interp along each axis) from the file's square off the diagonal,
    and on it T_ii interpolated along the diagonal T(w, w) (np.interp), as mean-drift and newman take it."""
    ds, _ = drift_hdb
    rng = np.random.default_rng(3)
    w = np.sort(rng.uniform(2 * np.pi / 19.0, 2 * np.pi / 4.6, 40))
    amp, phase = rng.uniform(0.05, 0.3, w.size), rng.uniform(0, 2 * np.pi, w.size)
    term = _term(ds, _bichromatic(w, amp, phase), second_order="qtf")
    grid = np.sort([2 * np.pi / p for p in PERIODS])
    per = [2 * np.pi / g for g in grid]
    square = np.array([[_t_file(ds, pi, pj, 1, "d") for pj in per] for pi in per])
    rows = np.array([np.interp(w, grid, square[:, b].real) + 1j * np.interp(w, grid, square[:, b].imag)
                     for b in range(grid.size)]).T                      # (n_c, n_q)
    t_ij = np.array([np.interp(w, grid, r.real) + 1j * np.interp(w, grid, r.imag) for r in rows])
    t_ij[np.diag_indices(w.size)] = np.interp(w, grid, np.diag(square).real)
    for t in (0.0, 55.5):
        z = amp * np.exp(1j * phase - 1j * w * t)
        expect = np.real(np.sum(z[:, None] * np.conj(z)[None, :] * t_ij))
        assert term.force(t, np.zeros((1, 6)), np.zeros((1, 6)))[0][0, 0] == pytest.approx(expect, rel=1e-9)


# A difference QTF written here from an analytic T(w_i, w_j) (per DOF d, heading 0):
#   Re T = c0_d + c1_d (w_i + w_j)/2 + c2_d (w_i - w_j)^2,  Im T = c3_d (w_i - w_j)
# (Hermitian: T(w_j, w_i) = conj T(w_i, w_j)), whose diagonal T(w, w) = c0_d + c1_d w is linear in w:
# any interpolation along the diagonal is exact there, the bilinear one on the square is not (its
# off-diagonal neighbours carry the curvature c2 in).
QTF_GRID = np.linspace(0.4, 1.6, 7)                     # rad/s
QTF_C = np.array([[1e3 * (d + 1), 2e3 * (d + 1), 5e4 * (d + 1), 3e2 * (d + 1)] for d in range(6)])


def analytic_t(wi, wj) -> np.ndarray:
    """(..., 6) the analytic T(w_i, w_j) above."""
    wi, wj = np.asarray(wi, float)[..., None], np.asarray(wj, float)[..., None]
    c0, c1, c2, c3 = QTF_C.T
    return c0 + c1 * (wi + wj) / 2 + c2 * (wi - wj) ** 2 + 1j * c3 * (wi - wj)


@pytest.fixture(scope="module")
def qtf_only_hdb(sphere) -> xr.Dataset:
    """The sphere's HDB with only that difference QTF (no mean drift coefficients)."""
    from hydrolink.protocol.hdb.second_order import QTF
    wi, wj = np.meshgrid(QTF_GRID, QTF_GRID, indexing="ij")
    square = analytic_t(wi, wj)[:, :, None, :]                      # (n_q, n_q, 1 heading pair, 6)
    return with_second_order(sphere, qtf=QTF(QTF_GRID, np.zeros(1), np.zeros(1), square, None, "analytic (test)"))


def _scale(ds: xr.Dataset) -> float:
    """The term's rho g scaling from the HDB's to the test scene's water (SPHERE_WATER, g 9.81)."""
    scene = parse_scene(_scene(Path("x.nc"), regular_waves(1.0, 7.0)))
    return scene.water.density * scene.water.gravity / _rho_g(ds)


@pytest.mark.parametrize("mode", ["mean-drift", "newman", "qtf"])
def test_a_qtf_alone_gives_every_mode_the_exact_diagonal(qtf_only_hdb, mode):
    """An HDB holding only a difference QTF: mean-drift and newman take T_ii from its diagonal
    (before: refused, "holds no mean drift coefficients"), and all three modes interpolate the diagonal
    alike (before: qtf bilinearly on the square, its surge T_ii 910 N/m^2 (32 %) off at w = 0.93 rad/s).
    A regular wave off the grid gives A^2 T(w, w) exactly; over a beat period of a bichromatic sea the
    mean force is A1^2 T(w1, w1) + A2^2 T(w2, w2) (the cross terms beat at w2 - w1 and average out
    over the equally spaced samples); Newman's force is the closed form at every instant."""
    ds, k = qtf_only_hdb, _scale(qtf_only_hdb)
    a, w = 1.3, 0.93
    term = _term(ds, _bichromatic([w], [a], [0.7]), second_order=mode)
    for t in (0.0, 4.1):
        f = term.force(t, np.zeros((1, 6)), np.zeros((1, 6)))[0][0]
        np.testing.assert_allclose(f, k * a ** 2 * analytic_t(w, w).real, rtol=1e-9)
    (w1, w2), (a1, a2), (f1, f2) = (0.93, 1.27), (1.1, 0.6), (0.4, 2.1)
    term = _term(ds, _bichromatic([w1, w2], [a1, a2], [f1, f2]), second_order=mode)
    t11, t22 = k * analytic_t(w1, w1).real, k * analytic_t(w2, w2).real
    beat = 2 * np.pi / (w2 - w1)
    times = np.arange(64) * beat / 64
    forces = np.array([term.force(t, np.zeros((1, 6)), np.zeros((1, 6)))[0][0] for t in times])
    np.testing.assert_allclose(forces.mean(axis=0), a1 ** 2 * t11 + a2 ** 2 * t22, rtol=1e-9)
    if mode == "newman":
        expect = a1 ** 2 * t11 + a2 ** 2 * t22 + a1 * a2 * (t11 + t22) * np.cos((w1 - w2) * times - (f1 - f2))[:, None]
        np.testing.assert_allclose(forces, expect, rtol=1e-9, atol=1e-9 * np.abs(expect).max())


def test_a_qtf_alone_with_a_drift_method_or_no_data_is_refused_naming_the_key(sphere, qtf_only_hdb):
    """drift_method names coefficients a QTF-only HDB lacks: an error saying to leave it unset; an
    HDB with neither mean drift nor a difference QTF: an error naming the mode's key and the file."""
    with pytest.raises(ModelError) as err:
        _term(qtf_only_hdb, _bichromatic([0.93], [1.0], [0.0]), second_order="newman", drift_method="momentum")
    assert err.value.key == "hydro.drift_method" and "only a difference QTF" in str(err.value)
    with pytest.raises(ModelError) as err:
        _term(sphere, _bichromatic([0.93], [1.0], [0.0]), second_order="newman")
    assert err.value.key == "hydro.second_order" and "no difference QTF" in str(err.value)


@pytest.mark.parametrize("hydro,key", [
    ({"second_order": "qtf", "sum_frequency": True}, None),
    ({"second_order": "mean-drift", "drift_method": "pressure"}, "hydro.drift_method"),
])
def test_missing_data_names_the_key_and_the_file(sphere, drift_hdb, hydro, key, sphere_path):
    ds, path = drift_hdb
    scene = parse_scene(_scene(path, regular_waves(1.0, 7.0), **hydro))
    if key is None:      # the plain sphere HDB has no second-order data at all
        with pytest.raises(ModelError) as err:
            HydroModel(scene, {"sphere": sphere})
        assert err.value.key == "hydro.second_order" and "sphere.h5" in str(err.value)
        return
    with pytest.raises(ModelError) as err:
        HydroModel(scene, {"sphere": ds})
    assert err.value.key == key and "momentum" in str(err.value)


def test_direction_and_period_outside_the_data_are_refused(drift_hdb):
    ds, path = drift_hdb
    for waves, key in ((regular_waves(1.0, 7.0, direction=30.0), "waves.direction"),
                       (regular_waves(1.0, 4.0), "waves.period")):
        with pytest.raises(ModelError) as err:
            HydroModel(parse_scene(_scene(path, waves, second_order="qtf")), {"sphere": ds})
        assert err.value.key == key, err.value


def test_surge_spring_sits_at_drift_over_k(drift_hdb, tmp_path):
    """A hydrolink run: the sphere in surge on a linear spring k (damped) in regular waves with
    the mean drift sits on average at F/k, F = rho g A^2 L Fbar of the .8 (the first-order motion
    averages out over whole wave periods)."""
    from hydrolink.clients.run import run_scene_file

    ds, path = drift_hdb
    a, period, k = 1.0, 7.0, 1.0e5
    text = scene_toml(dt=0.1, duration=231.0, water=SPHERE_WATER,
                      waves=regular_waves(2 * a, period, ramp=20.0), hydro={"second_order": "mean-drift"},
                      bodies=[sphere_body(str(path), mass=MASS, dofs=["surge"], linear_damping=[3e5, 0, 0, 0, 0, 0])],
                      moorings=[{"type": "linear", "body": "sphere", "point": [0.0, 0.0, 0.0],
                                 "stiffness": [k, 0, 0, 0, 0, 0]}])
    out = tmp_path / "spring.nc"
    run_scene_file(write_scene(tmp_path, text), out, progress=False)
    res = xr.load_dataset(out)
    t = res["time"].values
    window = t >= t[-1] - 20 * period - 1e-9
    x = res["position"].values[:, 0, 0]
    expect = _rho_g(ds) * a ** 2 * ULEN * drift_bar(period, 1) / k
    assert np.trapezoid(x[window], t[window]) / (20 * period) == pytest.approx(expect, rel=0.01)
    assert res["drift_force"].values[-1, 0, 0] == pytest.approx(expect * k, rel=1e-9)


def test_rotated_phasors_stay_on_the_exact_ones(drift_hdb):
    """Stepping by dt (phasors rotated, resynchronised every RESYNC steps) gives the force of a
    fresh evaluation at the same time to round-off, over 3000 steps; a rollback repeats bit for bit."""
    ds, _ = drift_hdb
    rng = np.random.default_rng(5)
    w = np.sort(rng.uniform(2 * np.pi / 19.0, 2 * np.pi / 4.6, 200))
    waves = _bichromatic(w, rng.uniform(0.05, 0.3, w.size), rng.uniform(0, 2 * np.pi, w.size))
    stepped, fresh = (_term(ds, waves, second_order="qtf", sum_frequency=True) for _ in range(2))
    zero = np.zeros((1, 6))
    for k in range(3001):
        f = stepped.force(k * 0.1, zero, zero)[0]
        if k == 1500:
            saved = stepped.state()
            again = [stepped.force(j * 0.1, zero, zero)[0] for j in (1501, 1502)]
            stepped.set_state(saved)
    np.testing.assert_allclose(f, fresh.force(3000 * 0.1, zero, zero)[0], rtol=1e-10, atol=1e-10 * np.abs(f).max())
    stepped.set_state(saved)
    np.testing.assert_array_equal([stepped.force(j * 0.1, zero, zero)[0] for j in (1501, 1502)], again)


def test_fixed_body_drift_on_a_moving_body_is_a_warning_naming_the_key(sphere, tmp_path):
    from hydrolink.protocol.hdb.second_order import MeanDrift
    w = sphere["omega"].values
    values = np.zeros((1, w.size, 1, 6))
    values[0, :, 0, 0] = 500.0
    ds = with_second_order(sphere, mean_drift=MeanDrift(("far-field",), w, np.zeros(1), values,
                                                        "Capytaine far-field (Kochin)", body_fixed=True))
    text = scene_toml(dt=0.1, duration=10.0, water=SPHERE_WATER, waves=regular_waves(1.0, 7.0),
                      bodies=[sphere_body("sphere_drift.nc", mass=MASS, second_order="mean-drift")])
    model = HydroModel(parse_scene(text), {"sphere": ds})
    assert any(m.startswith("bodies[0].second_order:") and "fixed" in m for m in model.warnings)
    # the typed field decides, not the note's words: the same note with the body's motions warns nothing
    free = with_second_order(sphere, mean_drift=MeanDrift(("far-field",), w, np.zeros(1), values,
                                                          "Capytaine far-field (Kochin), body fixed"))
    assert not HydroModel(parse_scene(text), {"sphere": free}).warnings
    # and it survives the NetCDF file and the wire
    from hydrolink.protocol.hdb.schema import from_netcdf_dataset
    from hydrolink.protocol.hdb.second_order import drift_body_fixed
    from hydrolink.protocol.hdb.wire import from_wire, to_wire
    to_netcdf(ds, tmp_path / "fixed.nc")
    with xr.open_dataset(tmp_path / "fixed.nc") as raw:
        assert drift_body_fixed(from_netcdf_dataset(raw.load(), "fixed.nc"))
    assert drift_body_fixed(from_wire(to_wire(ds), "h")) and not drift_body_fixed(from_wire(to_wire(free), "h"))
    bad = ds.copy()
    bad.attrs["mean_drift_body_fixed"] = "yes"
    with pytest.raises(HDBError, match="mean_drift_body_fixed"):
        with_second_order(bad)
    f = model.step(0.0, model.setup_info().equilibrium_position, np.zeros((1, 6)))["drift"][0]
    assert f[0] == pytest.approx(500.0 * 0.5 ** 2, rel=1e-12)


@pytest.mark.parametrize("body,hydro,key", [
    ({"hdb": None, "center_of_mass": [0, 0, 0], "second_order": "newman"}, {}, "bodies[0].second_order"),
    ({}, {"sum_frequency": True}, "hydro.sum_frequency"),
    ({}, {"second_order": "slow"}, "hydro.second_order"),
])
def test_bad_scene_keys_are_named(body, hydro, key):
    from hydrolink.protocol.scene import SceneError
    keys = {**sphere_body("x.nc", mass=MASS), **body}
    keys = {k: v for k, v in keys.items() if v is not None}
    with pytest.raises(SceneError) as err:
        parse_scene(scene_toml(dt=0.1, duration=1.0, hydro=hydro, bodies=[keys]))
    assert err.value.key == key, err.value


def test_a_qtf_too_large_for_the_headings_is_refused_before_allocating(drift_hdb, monkeypatch):
    from hydrolink.server import allocation
    ds, _ = drift_hdb
    monkeypatch.setattr(allocation, "MAX_ARRAY_BYTES", 1000)
    with pytest.raises(ModelError) as err:
        _term(ds, _bichromatic([0.7, 0.9], [1.0, 1.0], [0.0, 0.0]), second_order="qtf")
    assert err.value.key == "waves.direction" and "QTF" in str(err.value)


def test_steady_mean_offset_on_a_surge_spring_is_drift_over_k(drift_hdb, tmp_path):
    """hydrolink steady (the drift a load at its collocation nodes): the sphere on a surge spring k
    in a regular wave sits on average at F/k, F = rho g A^2 L Fbar of the .8."""
    from hydrolink.clients.analysis.steady import steady_scene_file

    ds, path = drift_hdb
    a, period, k = 1.0, 7.0, 1.0e5
    text = scene_toml(dt=period / 64, duration=10 * period, progress=False, water=SPHERE_WATER,
                      waves=regular_waves(2 * a, period, ramp=period), hydro={"second_order": "mean-drift"},
                      steady={"order": 3},
                      bodies=[sphere_body(str(path), mass=MASS, dofs=["surge"])],
                      moorings=[{"type": "linear", "body": "sphere", "point": [0.0, 0.0, 0.0],
                                 "stiffness": [k, 0, 0, 0, 0, 0]}])
    steady_scene_file(write_scene(tmp_path, text, "steady.toml"), tmp_path / "steady.nc", progress=False)
    x = xr.load_dataset(tmp_path / "steady.nc")["position"].sel(body="sphere", dof="surge").values
    assert x.mean() == pytest.approx(_rho_g(ds) * a ** 2 * ULEN * drift_bar(period, 1) / k, rel=1e-6)


@pytest.mark.parametrize("mode", ["mean-drift", "newman", "qtf"])
def test_still_water_gives_zero(drift_hdb, mode):
    ds, path = drift_hdb
    text = scene_toml(dt=0.1, duration=1.0, water=SPHERE_WATER, hydro={"second_order": mode, "sum_frequency": True},
                      bodies=[sphere_body(str(path), mass=MASS)])
    model = HydroModel(parse_scene(text), {"sphere": ds})
    f = model.step(0.0, model.setup_info().equilibrium_position, np.zeros((1, 6)))["drift"]
    assert f.shape == (1, 6) and not f.any()


def test_irregular_sea_slow_drift_averages_to_the_mean_drift(drift_hdb):
    """A JONSWAP sea of equally spaced components: over one beat period 2 pi / dw every
    difference-frequency term averages out, so the time mean of the Newman force is the mean
    drift sum A_i^2 T_ii (mode "mean-drift"); and spreading over headings the data lack is refused."""
    ds, path = drift_hdb
    waves = irregular_waves(2.0, 8.0, components=30, seed=4, omega_range=[0.35, 1.35])
    mean = HydroModel(parse_scene(_scene(path, waves, second_order="mean-drift")), {"sphere": ds})
    newman = HydroModel(parse_scene(_scene(path, waves, second_order="newman")), {"sphere": ds})
    x0 = mean.setup_info().equilibrium_position
    f_mean = mean.step(0.0, x0, np.zeros((1, 6)))["drift"][0]
    term = newman.terms[0]
    dw = 1.0 / 30
    times = np.arange(64) * (2 * np.pi / dw) / 64
    avg = np.mean([term.force(t, x0, np.zeros((1, 6)))[0][0] for t in times], axis=0)
    np.testing.assert_allclose(avg, f_mean, rtol=1e-9, atol=1e-9 * np.abs(f_mean).max())
    spread = irregular_waves(2.0, 8.0, components=30, omega_range=[0.35, 1.35], spreading="cos2s", s=10.0)
    with pytest.raises(ModelError) as err:
        HydroModel(parse_scene(_scene(path, spread, second_order="mean-drift")), {"sphere": ds})
    assert err.value.key == "waves.spreading"


# ------------------------------------------------------------------------------------------------
# WEC-Sim BEMIO QTF groups (server/hdb/bemio_qtf.py)
# ------------------------------------------------------------------------------------------------

BEMIO_PERIODS = (7.0, 9.0, 5.5)      # the file's order (as WEC-Sim's assignIDs keeps it): not sorted


def bemio_t(pi: float, pj: float, mode: int) -> complex:
    """The QTF per A_i A_j / (rho g) written into the BEMIO file, exp(-iwt) (Hermitian: T_ji = conj T_ij)."""
    return complex(0.2 + 0.01 * (pi + pj) + 0.1 * mode, 0.03 * (pi - pj) * mode)


def write_bemio_qtf(src: Path, dst: Path, rho_g: float, *, sum_groups: bool = True) -> Path:
    """``src`` (a BEMIO file) with body1's QTF1 groups in writeBEMIOH5's layout (WEC-Sim v6.1-v7.1):
    per DOF, PER_i / BETA_i / BETA_j as MATLAB (n, 1) columns (h5py (1, n)) and the full square,
    dimensional, as MATLAB's column-major F(:) in Re_F_ij / Im_F_ij (h5py (1, n^2)); Diff holds the
    conjugate of the WAMIT (exp(+iwt)) row, i.e. the exp(-iwt) value. Surge and heave non-zero."""
    import shutil

    import h5py

    shutil.copy(src, dst)
    n = len(BEMIO_PERIODS)
    with h5py.File(dst, "a") as fh:
        for dof in range(1, 7):
            square = np.array([[rho_g * bemio_t(pi, pj, dof) if dof in (1, 3) else 0j for pj in BEMIO_PERIODS]
                               for pi in BEMIO_PERIODS])
            flat = square.ravel(order="F")[None, :]
            for kind in ("Diff", "Sum") if sum_groups else ("Diff",):
                g = fh.create_group(f"body1/hydro_coeffs/excitation/QTF1/{kind}{dof}")
                g["PER_i"] = np.array(BEMIO_PERIODS)[None, :]
                g["BETA_i"] = np.zeros((1, n))
                g["BETA_j"] = np.zeros((1, n))
                g["Re_F_ij"] = flat.real
                g["Im_F_ij"] = flat.imag
                g["PHS_F_ij"] = np.angle(flat)
    return dst


def test_bemio_difference_qtf_against_the_bichromatic_closed_form(sphere_path, tmp_path):
    """The BEMIO file's Diff square read in SI and exp(-iwt): the full-QTF force of a bichromatic sea
    against the two-component closed form over the coefficients written into the file; its Sum
    groups are left out with a warning (their sign depends on the WEC-Sim version), so
    sum_frequency is refused naming the key."""
    from hydrolink.server.hdb.io import load_hdb

    rho_g = 1000.0 * 9.81
    ds = load_hdb(write_bemio_qtf(sphere_path, tmp_path / "sphere_qtf.h5", rho_g))
    assert [re.search("QTF1/Sum1.*left out", n) is not None for n in hdb_warnings(ds)] == [True]
    assert "sum_qtf" not in ds and "Diff (WEC-Sim BEMIO)" in ds.attrs["qtf_source"]
    (p1, p2), amp, phase = (9.0, 5.5), (0.9, 0.6), (1.1, -0.3)
    w = [2 * np.pi / p1, 2 * np.pi / p2]
    term = _term(ds, _bichromatic(w, amp, phase), second_order="qtf")
    (a1, a2), (f1, f2) = amp, phase
    dw, dphi = w[0] - w[1], f1 - f2
    for t in (0.0, 2.9, 41.3):
        f = term.force(t, np.zeros((1, 6)), np.zeros((1, 6)))[0][0]
        for dof in (1, 3):
            t11, t22, t12 = (rho_g * bemio_t(p1, p1, dof).real, rho_g * bemio_t(p2, p2, dof).real,
                             rho_g * bemio_t(p1, p2, dof))
            expect = (a1 ** 2 * t11 + a2 ** 2 * t22
                      + 2 * a1 * a2 * (t12.real * np.cos(dw * t - dphi) + t12.imag * np.sin(dw * t - dphi)))
            assert f[dof - 1] == pytest.approx(expect, rel=1e-9)
        assert np.all(f[[1, 3, 4, 5]] == 0)
    with pytest.raises(ModelError) as err:
        _term(ds, _bichromatic(w, amp, phase), second_order="qtf", sum_frequency=True)
    assert err.value.key == "hydro.sum_frequency"


@pytest.mark.parametrize("edit, field", [
    (lambda g: g.__setitem__("Re_F_ij", np.zeros((1, 5))), "Diff2/Re_F_ij"),
    (lambda g: g.__setitem__("BETA_i", np.array([[0.0, 30.0, 0.0]])), "Diff2/BETA_i"),
    (lambda g: g.__setitem__("PER_i", np.array([[7.0, 7.0, 5.5]])), "Diff2/PER_i"),
    (lambda g: g.__delitem__("Im_F_ij"), "Diff2/Im_F_ij"),
])
def test_bad_bemio_qtf_names_the_dataset(sphere_path, tmp_path, edit, field):
    import h5py

    from hydrolink.server.hdb.io import load_hdb

    path = write_bemio_qtf(sphere_path, tmp_path / "bad.h5", 9810.0, sum_groups=False)
    with h5py.File(path, "a") as fh:
        g = fh["body1/hydro_coeffs/excitation/QTF1/Diff2"]
        name = field.split("/")[1]
        if name in g and name != "Im_F_ij":
            del g[name]
        edit(g)
    with pytest.raises(HDBError) as err:
        load_hdb(path)
    assert err.value.field.endswith(field) and "bad.h5" in str(err.value)


# ------------------------------------------------------------------------------------------------
# NEMOH QTF files named by a scene (bodies[i].qtf)
# ------------------------------------------------------------------------------------------------

NEMOH_PERIODS = (9.0, 7.0, 5.5)


def nemoh_t(wa: float, wb: float, dof: int) -> complex:
    """The QTF / (rho g) written into OUT_QTFM_N.dat for (w_a, w_b), w_a >= w_b, exp(+iwt)."""
    return complex(0.3 + 0.05 * (wa + wb) + 0.1 * dof, 0.0 if wa == wb else 0.04 * (wa - wb) * dof)


def write_nemoh_difference(folder: Path) -> Path:
    """A NEMOH v3 OUT_QTFM_N.dat: a header line, the lower triangle (w1 >= w2) of surge and heave,
    frequencies in Hz (as a Nemoh.cal QTF line may choose), complex values exp(+iwt) / (rho g)."""
    w = sorted(2 * np.pi / p for p in NEMOH_PERIODS)
    rows = ["    w1[Hz]    w2[Hz]  beta1  beta2  DOF  |QTF|/rho/g  arg  Re  Im"]
    for a, wa in enumerate(w):
        for wb in w[:a + 1]:
            for dof in (1, 3):
                t = nemoh_t(wa, wb, dof)
                rows.append(f"{wa / (2 * np.pi):.12g} {wb / (2 * np.pi):.12g} 0.0 0.0 {dof} {abs(t):.12g} "
                            f"{np.degrees(np.angle(t)):.12g} {t.real:.12g} {t.imag:.12g}")
    path = folder / "QTF" / "OUT_QTFM_N.dat"
    path.parent.mkdir(exist_ok=True)
    path.write_text("\n".join(rows) + "\n")
    return path


def _nemoh_scene(folder: Path, hdb: Path, waves: dict, **qtf) -> Path:
    qtf = {"difference": "QTF/OUT_QTFM_N.dat", "frequency_unit": "Hz", "convention": "exp(+iwt)", **qtf}
    qtf = {k: v for k, v in qtf.items() if v is not None}
    text = scene_toml(dt=0.1, duration=10.0, water=SPHERE_WATER, waves=waves, hydro={"second_order": "qtf"},
                      bodies=[sphere_body(str(hdb), mass=MASS, qtf=qtf)])
    return write_scene(folder, text)


def test_nemoh_qtf_named_by_the_scene_against_the_closed_form(sphere_path, tmp_path):
    """bodies[0].qtf names a NEMOH difference file (Hz, exp(+iwt)) beside the scene: the HDB the
    scene loads carries rho g conj(Re + i Im) per A_i A_j, and the full-QTF force of a regular and
    a bichromatic sea equals the closed forms over the coefficients written into the file."""
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import load_scene

    write_nemoh_difference(tmp_path)
    a, period = 1.3, 7.0
    path = _nemoh_scene(tmp_path, sphere_path, regular_waves(2 * a, period))
    scene, _ = load_scene(path)
    ds = load_scene_hdbs(scene, path, progress=False)[str(sphere_path)]
    assert "OUT_QTFM_N.dat (NEMOH)" in ds.attrs["qtf_source"]
    rho_g = 1000.0 * 9.81
    model = HydroModel(scene, {"sphere": ds})
    f = model.step(0.0, model.setup_info().equilibrium_position, np.zeros((1, 6)))["drift"][0]
    w = 2 * np.pi / period
    assert f[0] == pytest.approx(rho_g * a ** 2 * nemoh_t(w, w, 1).real, rel=1e-9)
    assert f[2] == pytest.approx(rho_g * a ** 2 * nemoh_t(w, w, 3).real, rel=1e-9)
    # hydrolink run sending the HDBs as files: this one goes as a map with its QTF (the server
    # cannot read the scene's NEMOH files): the recorded drift force is the same
    from hydrolink.clients.run import run_scene_file
    run_scene_file(path, tmp_path / "out.nc", progress=False, hdb_files=True)
    with xr.open_dataset(tmp_path / "out.nc") as out:
        np.testing.assert_allclose(out["drift_force"].sel(body="sphere", dof="surge").values,
                                   rho_g * a ** 2 * nemoh_t(w, w, 1).real, rtol=1e-9)

    w1, w2 = 2 * np.pi / 5.5, 2 * np.pi / 9.0     # w1 > w2: the file's own row
    (a1, a2), (f1, f2) = (0.8, 0.5), (0.3, 2.4)
    term = _term(ds, _bichromatic([w1, w2], (a1, a2), (f1, f2)), second_order="qtf")
    for t in (0.0, 5.1, 33.3):
        f = term.force(t, np.zeros((1, 6)), np.zeros((1, 6)))[0][0]
        for dof in (1, 3):
            t12 = rho_g * np.conj(nemoh_t(w1, w2, dof))           # exp(+iwt) conjugated
            expect = (rho_g * (a1 ** 2 * nemoh_t(w1, w1, dof).real + a2 ** 2 * nemoh_t(w2, w2, dof).real)
                      + 2 * a1 * a2 * (t12.real * np.cos((w1 - w2) * t - (f1 - f2))
                                       + t12.imag * np.sin((w1 - w2) * t - (f1 - f2))))
            assert f[dof - 1] == pytest.approx(expect, rel=1e-9)


@pytest.mark.parametrize("qtf, key", [
    ({"frequency_unit": None}, "bodies[0].qtf.frequency_unit"),
    ({"convention": None}, "bodies[0].qtf.convention"),
    ({"frequency_unit": "rpm"}, "bodies[0].qtf.frequency_unit"),
    ({"difference": None}, "bodies[0].qtf.difference"),
    ({"difference": "QTF/missing.dat"}, "bodies[0].qtf.difference"),
])
def test_nemoh_qtf_scene_keys_are_named(sphere_path, tmp_path, qtf, key):
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import SceneError, load_scene

    write_nemoh_difference(tmp_path)
    path = _nemoh_scene(tmp_path, sphere_path, regular_waves(1.0, 7.0), **qtf)
    with pytest.raises(SceneError) as err:
        scene, _ = load_scene(path)
        load_scene_hdbs(scene, path, progress=False)
    assert err.value.key == key


def test_nemoh_qtf_file_errors_name_the_key_and_the_line(sphere_path, drift_hdb, tmp_path):
    """A bad row names bodies[0].qtf.difference with the file and line; an HDB that already holds a
    QTF (the WAMIT .12d here) is refused naming bodies[0].qtf."""
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import SceneError, load_scene

    bad = write_nemoh_difference(tmp_path)
    lines = bad.read_text().splitlines()
    lines[3] = lines[3].replace(" 0.0 0.0 1 ", " 0.0 0.0 9 ", 1)
    bad.write_text("\n".join(lines) + "\n")
    path = _nemoh_scene(tmp_path, sphere_path, regular_waves(1.0, 7.0))
    scene, _ = load_scene(path)
    with pytest.raises(SceneError) as err:
        load_scene_hdbs(scene, path, progress=False)
    assert err.value.key == "bodies[0].qtf.difference" and "OUT_QTFM_N.dat" in str(err.value) and "line 4" in str(err.value)
    write_nemoh_difference(tmp_path)
    path = _nemoh_scene(tmp_path, drift_hdb[1], regular_waves(1.0, 7.0))
    scene, _ = load_scene(path)
    with pytest.raises(SceneError) as err:
        load_scene_hdbs(scene, path, progress=False)
    assert err.value.key == "bodies[0].qtf" and "already holds a QTF" in str(err.value)
