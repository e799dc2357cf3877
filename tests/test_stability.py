"""Stability at the extremes (issue 4): coupling schemes, added-mass ratio, dt, stiffness, IRF length,
steep waves, badly sampled HDBs, unstable state-space fits. Every case asserts its expected outcome:
stable and accurate against an independent reference written here (a monolithic Cummins
integration, the frequency-domain RAO), or an early stop whose message names the cause and the
setting to change. Long runs and the stability map: bench/bench_stability.py, docs/stability.md.

The body is the IEA Task-10 sphere in heave with its mass scaled to set A∞/m (its displaced volume
dropped from the HDB so that no net buoyancy acts on the lighter or heavier body).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from conftest import SPHERE_WATER, body, linear_pto, regular_waves, scene_toml, sphere_body

from hydrolink.clients.lockstep.connection import ServerConnection
from hydrolink.clients.exudyn.client import SimulationDiverged, build_model, run
from hydrolink.clients.lockstep.results import ResultWriter
from hydrolink.protocol.scene import Scene, SceneError, parse_scene
from hydrolink.server.hdb.io import load_hdb
from hydrolink.server.model import HydroModel, ModelError
from hydrolink.server.service.force_server import ForceServer

HEAVE = 2


@pytest.fixture(scope="module")
def sphere(reference_data: Path) -> xr.Dataset:
    ds = load_hdb(reference_data / "sphere_task10" / "sphere.h5")
    return ds.drop_vars(["displaced_volume", "center_of_buoyancy"])


@pytest.fixture(scope="module")
def a33(sphere) -> float:
    return float(sphere["added_mass_inf"].values[HEAVE, HEAVE])


@pytest.fixture(scope="module")
def c33(sphere) -> float:
    return float(sphere["hydrostatic_stiffness"].values[HEAVE, HEAVE])


def scene_text(mass: float, *, dt: float = 0.01, duration: float = 8.0, scheme: str = "mass-matrix",
               coupling: dict | None = None, hydro: dict | None = None, irf: float = 20.0, x0: float = 0.5,
               waves: dict | None = None, **sections) -> str:
    """The sphere in heave, of ``mass``, started at heave ``x0``; ``coupling`` and ``hydro`` keys
    besides the scheme and irf_duration; further ``sections`` (ptos, moorings) as scene_toml takes them."""
    return scene_toml(dt=dt, duration=duration, progress=False, water=SPHERE_WATER, waves=waves,
                      hydro={"irf_duration": irf, **(hydro or {})}, coupling={"scheme": scheme, **(coupling or {})},
                      bodies=[sphere_body("sphere.h5", mass=mass, inertia=[1e5, 1e5, 1e5], dofs=["heave"],
                                          initial_displacement=[0, 0, x0, 0, 0, 0])], **sections)


def simulate(text: str, hdb, out: Path, **kw):
    """A run through the in-process force server: (summary, dataset, setup)."""
    scene = parse_scene(text)
    with ServerConnection(ForceServer(None)) as conn:
        setup = conn.hello(text, {"sphere.h5": hdb})
        with ResultWriter(out, scene=scene, scene_text=text, setup=setup) as writer:
            summary = run(scene, text, conn, setup, writer, progress=False, **kw)
    return summary, xr.load_dataset(out), setup


def heave(ds: xr.Dataset) -> np.ndarray:
    return ds["position"].values[:, 0, HEAVE] - ds["equilibrium_position"].values[0, HEAVE]


def kernel(hdb, t: np.ndarray) -> np.ndarray:
    """Heave K(t) = (2/π) ∫ B(ω) cos(ωt) dω, trapezoid on the HDB grid from (0, 0)."""
    w = np.r_[0.0, hdb["omega"].values]
    b = np.r_[0.0, hdb["radiation_damping"].values[:, HEAVE, HEAVE]]
    return (2 / np.pi) * np.trapezoid(b[None, :] * np.cos(np.outer(t, w)), w, axis=1)


def cummins(m_total: float, c: float, k: np.ndarray, x0: float, h: float, n: int) -> np.ndarray:
    """Monolithic reference: m ẍ + Σ K ẋ h + c x = 0, average-acceleration Newmark, the memory
    integral by the trapezoid rule over the kernel ``k`` (samples at j h), solved for each step."""
    x, v, a = np.zeros(n + 1), np.zeros(n + 1), np.zeros(n + 1)
    x[0], a[0] = x0, -c * x0 / m_total
    nk = k.size
    for i in range(n):
        j = np.arange(1, min(i, nk - 1) + 1)
        mem = h * np.dot(k[j], v[i + 1 - j]) if j.size else 0.0
        if i + 1 < nk:
            mem += 0.5 * h * k[i + 1] * v[0]
        vb, xb = v[i] + 0.5 * h * a[i], x[i] + h * v[i] + 0.25 * h * h * a[i]
        a[i + 1] = -(0.5 * h * k[0] * vb + mem + c * xb) / (m_total + 0.25 * h * h * (k[0] + c))
        v[i + 1] = vb + 0.5 * h * a[i + 1]
        x[i + 1] = xb + 0.25 * h * h * a[i + 1]
    return x


def decay_reference(sphere, mass, a33, c33, dt, duration, irf, x0=0.5):
    n = int(round(duration / dt))
    k = kernel(sphere, np.arange(int(round(irf / dt)) + 1) * dt)
    return cummins(mass + a33, c33, k, x0, dt, n)


# ------------------------------------------------------------------ the added-mass instability

@pytest.mark.parametrize("ratio", [0.5, 2.0])
def test_classic_added_mass_instability(sphere, a33, c33, tmp_path, ratio):
    """−A∞·a fed back one step late (explicit) is stable at A∞/m = 0.5 and diverges at 2, stopped
    early with the cause named; A∞ in the mass matrix is stable and accurate at both."""
    mass = a33 / ratio
    ref = decay_reference(sphere, mass, a33, c33, 0.01, 8.0, 20.0)
    _, ds, _ = simulate(scene_text(mass), sphere, tmp_path / "mm.nc")
    assert np.abs(heave(ds) - ref).max() < 0.005 * 0.5
    if ratio < 1:
        summary, ds, _ = simulate(scene_text(mass, scheme="explicit"), sphere, tmp_path / "ex.nc")
        assert summary.coupling.added_mass_ratio == pytest.approx(ratio, rel=1e-6)
        assert np.abs(heave(ds) - ref).max() < 0.05 * 0.5      # stable, first order in the lag
        return
    with pytest.raises(SimulationDiverged, match=r"added-mass instability.*A∞/m > 1.*mass-matrix") as info:
        simulate(scene_text(mass, scheme="explicit"), sphere, tmp_path / "ex.nc", allow_unstable=True)
    assert info.value.step < 50                                   # early: within half a second
    ds = xr.load_dataset(tmp_path / "ex.nc")
    assert ds.attrs["status"].startswith("interrupted") and np.isfinite(ds["position"].values).all()
    assert np.abs(heave(ds)).max() <= 0.5 + 1e-3                  # nothing absurd reached the file


@pytest.mark.parametrize("scheme", ["explicit", "explicit-predictor"])
def test_explicit_refused_above_the_limit(sphere, a33, tmp_path, scheme):
    with pytest.raises(SceneError, match=r"coupling\.scheme.*unstable for A∞/m > 1.*1\.5 > "
                                         r"coupling\.explicit_limit = 0\.9.*\"mass-matrix\""):
        simulate(scene_text(a33 / 1.5, scheme=scheme), sphere, tmp_path / "r.nc")
    assert xr.load_dataset(tmp_path / "r.nc").attrs["status"].startswith("refused")


@pytest.mark.parametrize("ratio", [0.01, 1.0, 100.0])
def test_implicit_and_mass_matrix_across_mass_ratios(sphere, a33, c33, tmp_path, ratio):
    """A∞/m from 0.01 to 100: mass-matrix and implicit (−A∞·a iterated with rollback) both match the
    monolithic reference; the implicit scheme needs few iterations per step at any ratio."""
    mass = a33 / ratio
    ref = decay_reference(sphere, mass, a33, c33, 0.01, 6.0, 20.0)
    for scheme in ("mass-matrix", "implicit"):
        summary, ds, _ = simulate(scene_text(mass, duration=6.0, scheme=scheme), sphere, tmp_path / f"{scheme}.nc")
        err = np.abs(heave(ds) - ref).max() / 0.5
        print(f"A/m = {ratio:g} {scheme}: max error {err:.2e}, iterations/step "
              f"{summary.coupling.iterations_mean:.3f} (max {summary.coupling.iterations_max})")
        assert err < 0.005
    assert summary.coupling.iterations_mean <= 3.0 and summary.coupling.iterations_max <= 6


def test_implicit_rollback_is_bit_exact(sphere, a33):
    """The Newmark integrator of the implicit scheme redoes a rolled-back step bit for bit."""
    text = scene_text(a33, scheme="implicit")
    scene = parse_scene(text)
    setup = HydroModel(scene, {"sphere": sphere}).setup_info()
    model = build_model(scene, setup, added_mass_in_matrix=False, newmark=True)
    model.set_force(np.array([0, 0, 1e4, 0, 0, 0.0]))
    model.initialize()
    for k in range(3):
        model.advance(k * 0.01, (k + 1) * 0.01)
    saved = model.save()
    runs = []
    for _ in range(2):
        model.restore(saved)
        for k, f in ((3, 2e4), (4, -5e3)):
            model.set_force(np.array([0, 0, f, 0, 0, 0.0]))
            model.advance(k * 0.01, (k + 1) * 0.01)
        runs.append(np.concatenate(model.state()))
        model.set_force(np.array([0, 0, 7e4, 0, 0, 0.0]))   # a different redo in between
        model.restore(saved)
        model.advance(0.03, 0.04)
    model.finalize()
    assert np.array_equal(runs[0], runs[1])


# ------------------------------------------------------------------ exchange every k steps

def test_exchange_every_hold_and_extrapolate(sphere, tmp_path):
    """k = 5 client steps per exchange: stable; forces varied linearly between exchanges are closer
    to the every-step run than held ones; the server steps at k dt."""
    mass = 261.724e3
    w = regular_waves(1.0, 5.0, ramp=5.0)
    _, base, _ = simulate(scene_text(mass, duration=20.0, x0=0.0, waves=w), sphere, tmp_path / "b.nc")
    err = {}
    for between in ("hold", "extrapolate"):
        cpl = {"exchange_every": 5, "between_exchanges": between}
        summary, ds, setup = simulate(scene_text(mass, duration=20.0, x0=0.0, waves=w, coupling=cpl), sphere,
                                      tmp_path / f"{between}.nc")
        assert setup.dt == pytest.approx(0.05) and ds.sizes["time"] == 2001
        err[between] = np.abs(heave(ds) - heave(base)).max() / np.abs(heave(base)).max()
    print("exchange_every = 5: relative max difference to every step", err)
    assert err["extrapolate"] < 0.02 and err["extrapolate"] < err["hold"] < 0.2


# ------------------------------------------------------------------ dt extremes

def test_tiny_dt_matches_reference(sphere, a33, c33, tmp_path):
    """dt = 1e-4 s (3000 steps, a 2 s memory of 20,000 samples) agrees with the reference."""
    mass = 261.724e3
    ref = decay_reference(sphere, mass, a33, c33, 1e-4, 0.3, 2.0)
    _, ds, _ = simulate(scene_text(mass, dt=1e-4, duration=0.3, irf=2.0), sphere, tmp_path / "tiny.nc")
    assert np.abs(heave(ds) - ref).max() < 1e-4 * 0.5


def test_coarse_dt_refused_or_warned(sphere, tmp_path):
    """dt = T/5 of the wave period is refused naming simulation.dt; T/10 runs with a warning."""
    mass = 261.724e3
    with pytest.raises(SceneError, match=r"simulation\.dt.*waves\.period = 5 s with 5 steps.*12 %.*T/20"):
        simulate(scene_text(mass, dt=1.0, duration=20.0, waves=regular_waves(1.0, 5.0)), sphere, tmp_path / "c.nc")
    summary, ds, _ = simulate(scene_text(mass, dt=0.5, duration=20.0, waves=regular_waves(1.0, 5.0)), sphere,
                              tmp_path / "w.nc")
    assert any("simulation.dt" in w and "3.2 %" in w for w in summary.warnings)
    assert np.isfinite(heave(ds)).all()


# ------------------------------------------------------------------ stiffness up to 1e9

@pytest.mark.parametrize("stiffness", [1e6, 1e7, 1e9])
def test_stiff_pto_and_mooring(sphere, tmp_path, stiffness):
    """A heave PTO spring and a linear mooring of up to 1e7 N/m each: stable, and the heave
    amplitude equals the frequency-domain |F| / |c + 2k − ω²(m + A) − iωB|. At 1e9 Exudyn's Newton
    iteration stalls: the run stops early, the message names the stiffness and the settings."""
    mass, period = 261.724e3, 5.0
    w0 = 2 * np.pi / period
    text = scene_text(mass, dt=0.01, duration=40.0, x0=0.0, waves=regular_waves(1.0, period, ramp=5.0),
                      ptos=[linear_pto("pto", "sphere", [0.0, 0.0, -2.0], "ground", [0.0, 0.0, -32.0],
                                       stiffness=stiffness)],
                      moorings=[{"type": "linear", "body": "sphere", "point": [0.0, 0.0, -2.0],
                                 "stiffness": [0.0, 0.0, stiffness, 0.0, 0.0, 0.0]}])
    if stiffness > 1e7:
        with pytest.raises(RuntimeError, match=r"(ptos|moorings)\[0\]\.stiffness = 1e\+09.*Newton iteration can "
                                               r"stall.*simulation\.dt"):
            simulate(text, sphere, tmp_path / "stiff.nc")
        ds = xr.load_dataset(tmp_path / "stiff.nc")
        assert ds.attrs["status"].startswith("interrupted") and np.isfinite(ds["position"].values).all()
        return
    _, ds, _ = simulate(text, sphere, tmp_path / "stiff.nc")
    z, t = heave(ds), ds["time"].values
    assert np.isfinite(z).all()
    om = sphere["omega"].values
    a, b = (np.interp(w0, om, sphere[v].values[:, HEAVE, HEAVE]) for v in ("added_mass", "radiation_damping"))
    f = 0.5 * abs(np.interp(w0, om, sphere["excitation_force"].values[:, 0, HEAVE]))
    c = float(sphere["hydrostatic_stiffness"].values[HEAVE, HEAVE]) + 2 * stiffness
    amp = f / abs(c - w0 ** 2 * (mass + a) - 1j * w0 * b)
    last = t > t[-1] - 2 * period                  # least-squares sinusoid at w0 over two periods
    basis = np.column_stack([np.cos(w0 * t[last]), np.sin(w0 * t[last]), np.ones(last.sum())])
    got = float(np.hypot(*np.linalg.lstsq(basis, z[last], rcond=None)[0][:2]))
    print(f"stiffness {stiffness:g}: heave amplitude {got:.6g} m, frequency domain {amp:.6g} m")
    assert got == pytest.approx(amp, rel=0.01)


# ------------------------------------------------------------------ IRF length

def test_irf_from_zero_to_200_s(sphere, a33, c33, tmp_path):
    """irf_duration = 0 (no memory: an undamped oscillator at 2π√((m+A∞)/C)); 200 s on the HDB
    grid is refused (past pi/dω = 62.8 s the IRF mirrors its start); 200 s resampled with
    irf_domega = 0.01 runs and agrees with the 20 s memory."""
    mass = 261.724e3
    _, ds, _ = simulate(scene_text(mass, irf=0.0, duration=10.0), sphere, tmp_path / "off.nc")
    ref = cummins(mass + a33, c33, np.zeros(1), 0.5, 0.01, 1000)
    assert np.abs(heave(ds) - ref).max() < 1e-6
    with pytest.raises(RuntimeError, match=r"hydro\.irf_duration.*pi/d_omega = 62\.8 s.*irf_domega <= 0\.0157"):
        simulate(scene_text(mass, irf=200.0, duration=2.0), sphere, tmp_path / "long.nc")
    _, ds, _ = simulate(scene_text(mass, irf=200.0, duration=10.0, hydro={"irf_domega": 0.01}), sphere,
                        tmp_path / "long.nc")
    ref = decay_reference(sphere, mass, a33, c33, 0.01, 10.0, 20.0)
    assert np.abs(heave(ds) - ref).max() < 0.01 * 0.5


def test_badly_sampled_hdb(sphere, tmp_path):
    """Every 8th frequency (dω = 0.4 rad/s, pi/dω = 7.9 s): a 20 s memory is refused naming
    hydro.irf_duration and irf_domega; 7 s runs."""
    coarse = sphere.isel(omega=slice(7, None, 8))
    mass = 261.724e3
    with pytest.raises(RuntimeError, match=r"hydro\.irf_duration.*20 s reaches past the aliasing time "
                                           r"pi/d_omega = 7\.8\d s.*set hydro\.irf_duration <= 7\.8"):
        simulate(scene_text(mass, irf=20.0), coarse, tmp_path / "c.nc")
    summary, ds, _ = simulate(scene_text(mass, irf=7.0), coarse, tmp_path / "c7.nc")
    assert np.isfinite(heave(ds)).all() and summary.status == "complete"


# ------------------------------------------------------------------ waves up to breaking

def test_waves_up_to_the_breaking_limit(sphere, tmp_path):
    """Deep water, T = 4 s: λ = 24.98 m. H/λ = 1/6 is refused naming waves.height; 1/8 runs with a
    warning (over half the limit); the response stays linear in H."""
    mass, period = 261.724e3, 4.0
    lam = 9.81 * period ** 2 / (2 * np.pi)   # depth 200 m is deep at 4 s
    with pytest.raises(RuntimeError, match=r"waves\.height.*breaking limit.*> 1/7.*waves\.height <= 3\.569"):
        simulate(scene_text(mass, x0=0.0, waves=regular_waves(lam / 6, period)), sphere, tmp_path / "b.nc")
    summary, ds, _ = simulate(scene_text(mass, x0=0.0, duration=20.0, waves=regular_waves(lam / 8, period, ramp=4.0)),
                              sphere, tmp_path / "s.nc")
    assert any("breaking limit" in w for w in summary.warnings)
    _, small, _ = simulate(scene_text(mass, x0=0.0, duration=20.0, waves=regular_waves(0.1, period, ramp=4.0)),
                           sphere, tmp_path / "l.nc")
    assert np.allclose(heave(ds), heave(small) * (lam / 8) / 0.1, atol=1e-9 * lam)


# ------------------------------------------------------------------ unstable state-space fit

def test_forced_unstable_state_space_fit_is_refused():
    """B(ω) of a slowly growing mode (pole +0.05 + 2i) fitted at order 4 without stabilisation: the
    scene is refused naming hydro.radiation and ss_enforce_stability; with it (default) it runs."""
    import analytic_hdb as an
    w = np.linspace(0.02, 8, 400)
    s, p, c = 1j * w, 0.05 + 2.0j, 1.0 - 0.5j
    hd = an.make_body_hdb(omega=w)
    hd["radiation_damping"].values[:, HEAVE, HEAVE] = 1e5 * (c / (s - p) + np.conj(c) / (s - np.conj(p))).real
    def scene(**hydro) -> Scene:
        return parse_scene(scene_toml(
            dt=0.05, duration=10, hydro={"irf_duration": 40.0, "radiation": "state-space", "ss_order": 4, **hydro},
            bodies=[body("float", hdb="x.nc", mass=3e5, center_of_mass=[0, 0, 0], inertia=[1e6, 1e6, 1e6],
                         dofs=["heave"])]))

    with pytest.raises(ModelError, match=r"hydro\.radiation.*unstable pole.*ss_enforce_stability = true"):
        HydroModel(scene(ss_enforce_stability=False), {"float": hd})
    HydroModel(scene(), {"float": hd})
