"""``hydrolink steady`` (clients/analysis/steady.py): pseudo-spectral periodic steady state on RM3.

References, all independent of the collocation code:
- the two-body frequency-domain solution written in tests/test_rm3.py (HDB A(w), B(w), excitation,
  hand-built mass and PTO matrices): a linear scene at order 1 must reproduce it to solver precision;
- ``hydrolink run`` (Exudyn client + force server, time stepping) fitted over its last periods: the
  linear scene and a force-limited PTO (Newton on the clipped force);
- the system matrices against an assembly by hand from the scene (rigid-body mass about the
  reference point, A_inf, hydrostatics) and the PTO lines against Exudyn's own linearisation of
  its connectors.
"""

from __future__ import annotations

import numpy as np
import pytest

from hydrolink.protocol.scene import parse_scene
from test_rm3 import (C_PTO, H, HEAVE, MASS, PERIOD, W, frequency_domain, hdb_radiation,
                      scene_text, steady_state)

# One pytest-xdist worker runs this whole module (pyproject: --dist loadgroup): its module fixture (an RM3
# time-domain run) costs ~4 s, paid once per worker otherwise.
pytestmark = pytest.mark.xdist_group("steady")

LIMIT = 2.0e5   # N: the linear PTO's peak force is ~3.3e5 N


@pytest.fixture(scope="module")
def rm3(reference_data):
    from hydrolink.server.hdb.io import load_hdb
    return load_hdb(reference_data / "rm3_wamit" / "rm3.1")


def _system(text: str, rm3):
    from hydrolink.clients.analysis.steady import hydro_model, linearize
    scene = parse_scene(text)
    model = hydro_model(scene, {b.hdb: rm3 for b in scene.bodies})
    return scene, linearize(scene, model, model.setup_info())


def _heave(sol, k: int = 1) -> np.ndarray:
    """Complex heave amplitudes (float, spar) of harmonic k, exp(-i k w t)."""
    s = sol.system
    return sol.harmonic(sol.q[s.body_index])[[2, 8]] if k == 1 else sol.harmonic(sol.q[s.body_index], k)[[2, 8]]


def _limited(text: str) -> str:
    return text.replace("damping = 1.2e6", f"damping = 1.2e6\nforce_limit = {LIMIT}")


@pytest.mark.parametrize("interaction", ["full", "none"])
def test_order_one_reproduces_frequency_domain(rm3, interaction):
    from hydrolink.clients.analysis.steady import solve
    _, lin = _system(scene_text(interaction, __import__("pathlib").Path("rm3.1")), rm3)
    x_fd, p_fd = frequency_domain(rm3, *hdb_radiation(rm3), interaction)
    for form in ("dae", "ode"):
        sol = solve(lin, 1, form)
        assert sol.iterations == 1 and sol.residual < 1e-12
        x = _heave(sol)
        print(f"{interaction} {form}: {np.abs(x)} vs FD {np.abs(x_fd)}, rel {np.abs(x / x_fd - 1).max():.1e}")
        np.testing.assert_allclose(x, x_fd, rtol=1e-9)          # amplitude and phase
        # higher orders: the linear response has no other harmonic and the first one is unchanged
        sol5 = solve(lin, 5, form)
        np.testing.assert_allclose(_heave(sol5), x_fd, rtol=1e-9)
        assert np.abs(sol5.harmonic(sol5.q, 3)).max() < 1e-9 * np.abs(x_fd).max()
    # the PTO's mean absorbed power from the sampled results
    from hydrolink.clients.analysis.steady import sample
    t = np.linspace(0, PERIOD, 400, endpoint=False)
    assert sample(sol5, t)["pto_power"].mean() == pytest.approx(p_fd, rel=1e-9)


def test_matrices_against_scene_assembly_and_exudyn_ptos(rm3):
    """M = rigid-body mass about the reference point + A_inf, K = hydrostatics (setup), G locks all
    but heave; the PTO lines g (k g g^T, c g g^T) equal Exudyn's linearisation of its connectors."""
    import exudyn as exu

    from hydrolink.clients.exudyn.client import build_model
    from hydrolink.clients.analysis.steady import hydro_model, linearize

    text = scene_text("full", __import__("pathlib").Path("rm3.1"))
    text = text.replace('dofs = ["heave"]         # the other five DOFs are locked to ground', "")
    text = text.replace('dofs = ["heave"]         # heave-only constraint to ground: the other five DOFs are locked', "")
    text = text.replace("point1 = [0.0, 0.0, -0.72]", "point1 = [1.0, 0.5, -0.3]")
    text = text.replace("point2 = [0.0, 0.0, -21.29]", "point2 = [2.0, -1.0, -21.0]\nstiffness = 3.0e5")
    text += """
[[ptos]]
name = "knee"
type = "rotary"
body1 = "float"
body2 = "spar"
point = [0.0, 0.0, -5.0]
axes = ["roll", "pitch"]
frame = [[0.8, 0.6, 0.0], [-0.6, 0.8, 0.0], [0.0, 0.0, 1.0]]
stiffness = [1.0e6, 2.0e6]
damping = [3.0e5, 4.0e5]
"""
    scene, lin = _system(text, rm3)
    info = hydro_model(scene, {b.hdb: rm3 for b in scene.bodies}).setup_info()
    m_hand = np.zeros((12, 12))
    for i, b in enumerate(scene.bodies):
        c = np.asarray(b.center_of_mass) - info.equilibrium_position[i, :3]
        cx = np.array([[0, -c[2], c[1]], [c[2], 0, -c[0]], [-c[1], c[0], 0]])
        blk = np.zeros((6, 6))
        blk[:3, :3] = b.mass * np.eye(3)
        blk[:3, 3:], blk[3:, :3] = -b.mass * cx, b.mass * cx
        blk[3:, 3:] = b.inertia_matrix + b.mass * (c @ c * np.eye(3) - np.outer(c, c))
        m_hand[6 * i:6 * i + 6, 6 * i:6 * i + 6] = blk
    w = lin.wet_index
    np.testing.assert_allclose(lin.M[np.ix_(w, w)], m_hand + info.added_mass_inf, rtol=1e-12, atol=1e-6)
    np.testing.assert_allclose(lin.K[np.ix_(w, w)], info.hydrostatic_stiffness, rtol=1e-12, atol=1e-6)
    assert not lin.D.any() and lin.G.shape[0] == 0      # all six DOFs free, no joint
    # PTO lines against Exudyn's linearisation with the PTOs built in
    ex = build_model(scene, info)
    ss = exu.SimulationSettings()
    ss.solution.file.write = False
    m2, k2, d2 = (np.asarray(a) for a in ex.mbs.ComputeLinearizedSystem(ss)[:3])
    ex.finalize()
    k_pto = sum(p.stiffness * np.outer(p.g, p.g) for p in lin.ptos)
    d_pto = sum(p.damping * np.outer(p.g, p.g) for p in lin.ptos)
    assert [p.name for p in lin.ptos] == ["pto", "knee.roll", "knee.pitch"]
    np.testing.assert_allclose(m2, lin.M, rtol=1e-12)
    np.testing.assert_allclose(k2 - lin.K, k_pto, atol=1e-6 * np.abs(k_pto).max())
    np.testing.assert_allclose(d2 - lin.D, d_pto, atol=1e-6 * np.abs(d_pto).max())


@pytest.fixture(scope="module")
def time_domain(rm3, reference_data, tmp_path_factory):
    """``hydrolink run`` of the linear and the force-limited RM3 (240 s, dt = T/100)."""
    import xarray as xr

    from hydrolink.clients.run import run_scene_file
    out = {}
    tmp = tmp_path_factory.mktemp("steady_td")
    for kind in ("linear", "limited"):
        text = scene_text("full", reference_data / "rm3_wamit" / "rm3.1", duration=240.0)
        (tmp / f"{kind}.toml").write_text(_limited(text) if kind == "limited" else text)
        run_scene_file(tmp / f"{kind}.toml", tmp / f"{kind}.nc", progress=False)
        ds = xr.load_dataset(tmp / f"{kind}.nc")
        t = ds["time"].values
        z = (ds["position"] - ds["equilibrium_position"]).sel(dof="heave").values
        sel = t > t[-1] - 5 * PERIOD + 1e-9
        basis = np.c_[np.ones(sel.sum()), np.cos(W * t[sel]), np.sin(W * t[sel])]
        fit = np.linalg.lstsq(basis, z[sel], rcond=None)[0]
        out[kind] = (fit[1] + 1j * fit[2], float(ds["pto_power"].values[sel].mean()))
    return out


@pytest.mark.parametrize("kind", ["linear", "limited"])
def test_against_time_domain(rm3, time_domain, kind):
    """Heave amplitude (both bodies) and mean PTO power within 0.5 % of the time-domain steady state;
    the force-limited PTO needs Newton (several iterations) and higher harmonics."""
    from hydrolink.clients.analysis.steady import sample, solve
    text = scene_text("full", __import__("pathlib").Path("rm3.1"))
    _, lin = _system(_limited(text) if kind == "limited" else text, rm3)
    x_td, p_td = time_domain[kind]
    t = np.linspace(0, PERIOD, 1000, endpoint=False)
    sols = [solve(lin, 10, form) for form in ("dae", "ode")]
    for sol in sols:
        x = _heave(sol)
        p = sample(sol, t)["pto_power"].mean()
        err = np.r_[np.abs(x_td) / np.abs(x) - 1, p_td / p - 1]
        print(f"{kind} {sol.formulation}: |x| {np.abs(x)} TD {np.abs(x_td)}, P {p:.1f} TD {p_td:.1f} W, "
              f"errors {err}, {sol.iterations} Newton")
        assert np.all(np.abs(err) < 5e-3)
        assert abs(np.angle(x_td[0] / x[0])) < np.radians(0.5)
    np.testing.assert_allclose(sols[0].q, sols[1].q, atol=1e-9 * np.abs(sols[0].q).max())
    if kind == "limited":
        f = sample(sols[0], t)["pto_force"]
        assert np.abs(f).max() == pytest.approx(LIMIT) and sols[0].iterations > 1
        assert np.abs(_heave(sols[0], 3)).max() > 1e-4      # the clipped force excites odd harmonics


def test_cli_one_period_in_the_run_layout(rm3, reference_data, tmp_path):
    import xarray as xr
    from click.testing import CliRunner

    from hydrolink.clients.cli import cli
    scene = tmp_path / "rm3.toml"
    scene.write_text(scene_text("full", reference_data / "rm3_wamit" / "rm3.1") + "\n[steady]\norder = 3\n")
    res = CliRunner().invoke(cli, ["steady", str(scene), "-o", str(tmp_path / "s.nc"), "--formulation", "ode",
                                   "--no-progress"])
    assert res.exit_code == 0, res.output
    ds = xr.load_dataset(tmp_path / "s.nc")
    assert ds.attrs["status"] == "complete" and ds.attrs["steady_order"] == 3
    assert ds.attrs["steady_formulation"] == "ode" and "[[ptos]]" in ds.attrs["scene"]
    assert ds.sizes["time"] == 100 and np.allclose(np.diff(ds["time"].values), PERIOD / 100)
    for name in ("position", "velocity", "excitation_force", "radiation_force", "hydrostatic_force",
                 "wave_elevation", "pto_force", "pto_velocity", "pto_power", "total_pto_power"):
        assert np.isfinite(ds[name].values).all(), name
    z = (ds["position"] - ds["equilibrium_position"]).sel(body="float", dof="heave").values
    assert z.max() == pytest.approx(1.019, abs=1e-3)
    assert ds["pto_power"].values.mean() == pytest.approx(286e3, rel=2e-3)
    # hydrostatic force = -C z in heave (the HDB's 2x2 heave block; rho = 1000 as the WAMIT run)
    zz = (ds["position"] - ds["equilibrium_position"]).sel(dof="heave").values
    c_hs = rm3["hydrostatic_stiffness"].values[np.ix_(HEAVE, HEAVE)]
    np.testing.assert_allclose(ds["hydrostatic_force"].sel(dof="heave").values, -zz @ c_hs.T,
                               rtol=1e-9, atol=1e-6 * np.abs(zz @ c_hs.T).max())


@pytest.mark.parametrize("dt,why", [("nan", "finite"), ("inf", "finite"), ("1e300", "less than or equal to 3600"),
                                     ("1e-300", "greater than or equal to 1e-06"), ("100", "longer than the period")])
def test_cli_sampling_out_of_range_is_refused(reference_data, tmp_path, dt, why):
    """``--dt`` not a scene's time step (1 µs to 1 h: nan and 1e-300 ended in a traceback, inf and 1e300
    wrote a file of no row) or longer than the period: one line naming --dt, nothing written."""
    from click.testing import CliRunner

    from hydrolink.clients.cli import cli
    scene = tmp_path / "rm3.toml"
    scene.write_text(scene_text("full", reference_data / "rm3_wamit" / "rm3.1"))
    res = CliRunner().invoke(cli, ["steady", str(scene), "-o", str(tmp_path / "s.nc"), "--dt", dt, "--no-progress"])
    assert res.exit_code == 1 and "--dt" in res.output and why in res.output, res.output
    assert isinstance(res.exception, SystemExit) and not (tmp_path / "s.nc").exists()


def test_refuses_irregular_waves(reference_data, tmp_path):
    from hydrolink.clients.analysis.steady import SteadyError, steady_scene_file
    scene = tmp_path / "rm3.toml"
    text = scene_text("full", reference_data / "rm3_wamit" / "rm3.1")
    text = text.replace('type = "regular"', 'type = "irregular"\nspectrum = "jonswap"\nhs = 2.0\ntp = 8.0')
    text = text.replace("height = 2.5             # m", "").replace("period = 8.0             # s", "")
    scene.write_text(text)
    with pytest.raises(SteadyError, match="waves.type: hydrolink steady needs regular waves"):
        steady_scene_file(scene, tmp_path / "x.nc", progress=False)


def test_viscous_damping_pointwise_against_time_integration_and_lorentz(sphere_path, tmp_path):
    """The Task-10 sphere in heave with linear and quadratic damping in a regular wave: the steady
    solution (viscous force evaluated at every collocation node, Newton with its exact Jacobian)
    against a monolithic time integration written here with A(w), B(w) of the HDB, and its first
    harmonic against the Lorentz-linearised frequency domain B_eq = 8/(3 pi) B_quad w |X| iterated
    to convergence."""
    import math

    import xarray as xr
    from scipy.integrate import solve_ivp

    from conftest import SPHERE_WATER, regular_waves, scene_toml, sphere_body, write_scene
    from hydrolink.clients.analysis.steady import steady_scene_file
    from hydrolink.server.hdb.io import load_hdb

    mass, b_lin, b_quad, height = 261.724e3, 1.0e4, 6.0e5, 2.0
    hdb = load_hdb(sphere_path)
    i = int(np.argmin(np.abs(hdb["omega"].values - 1.0)))
    w = float(hdb["omega"].values[i])
    a, b = float(hdb["added_mass"].values[i, 2, 2]), float(hdb["radiation_damping"].values[i, 2, 2])
    x_exc, c = complex(hdb["excitation_force"].values[i, 0, 2]), float(hdb["hydrostatic_stiffness"].values[2, 2])
    period = 2 * math.pi / w
    path = write_scene(tmp_path, scene_toml(
        dt=period / 64, duration=10 * period, progress=False, water={**SPHERE_WATER, "gravity": 9.81},
        waves=regular_waves(height, period, ramp=period), steady={"order": 7},
        bodies=[sphere_body(str(sphere_path), mass=mass, dofs=["heave"], linear_damping=[0, 0, b_lin, 0, 0, 0],
                            quadratic_damping=[0, 0, b_quad, 0, 0, 0])]), "s.toml")
    steady_scene_file(path, tmp_path / "s.nc", progress=False)
    ds = xr.load_dataset(tmp_path / "s.nc")
    z = ds["position"].sel(body="sphere", dof="heave").values
    z = z - z.mean()
    # monolithic, constant A and B at w (the harmonics' own A(kw), B(kw) differ: the third harmonic
    # is small), run to a periodic state
    f = x_exc * height / 2

    def rhs(t, y):
        return [y[1], ((f * np.exp(-1j * w * t)).real - (b + b_lin) * y[1] - b_quad * y[1] * abs(y[1]) - c * y[0])
                / (mass + a)]
    ref = solve_ivp(rhs, (0, 40 * period), [0.0, 0.0], rtol=1e-10, atol=1e-12, dense_output=True)
    tt = np.linspace(39 * period, 40 * period, 400, endpoint=False)
    amp_ref = 0.5 * np.ptp(ref.sol(tt)[0])
    assert 0.5 * np.ptp(z) == pytest.approx(amp_ref, rel=5e-3)
    # Lorentz: the first harmonic of v|v| for v = V sin is (8 / 3 pi) V v
    x = f / (-w ** 2 * (mass + a) - 1j * w * (b + b_lin) + c)
    for _ in range(200):
        b_eq = 8 / (3 * math.pi) * b_quad * w * abs(x)
        x = f / (-w ** 2 * (mass + a) - 1j * w * (b + b_lin + b_eq) + c)
    first = 2 * abs(np.fft.rfft(z)[1]) / z.size
    # Lorentz keeps only the first harmonic of the dissipation: measured 1.3 % here (the drag takes
    # a quarter off the amplitude)
    assert first == pytest.approx(abs(x), rel=2e-2)
    assert abs(x) < 0.8 * abs(f / (-w ** 2 * (mass + a) - 1j * w * (b + b_lin) + c))   # the drag matters


def test_morison_member_pointwise_against_the_time_domain(sphere_path, tmp_path):
    """The heaving sphere with a horizontal Morison member (fluid inertia, relative drag, its added
    mass): the steady solution against the co-simulated time domain of the same scene (constant
    radiation, T/200)."""
    import math

    import xarray as xr

    from conftest import SPHERE_WATER, regular_waves, scene_toml, sphere_body, write_scene
    from hydrolink.clients.run import run_scene_file
    from hydrolink.clients.analysis.steady import steady_scene_file

    w = 1.0
    period = 2 * math.pi / w
    text = scene_toml(dt=period / 200, duration=25 * period, progress=False, water={**SPHERE_WATER, "gravity": 9.81},
                      waves=regular_waves(2.0, period, ramp=2 * period), hydro={"radiation": "constant"},
                      steady={"order": 9, "radiation": "hdb"},
                      bodies=[sphere_body(str(sphere_path), mass=261.724e3, dofs=["heave"])],
                      morison=[{"body": "sphere", "point_a": [-10.0, 0.0, -3.0], "point_b": [10.0, 0.0, -3.0],
                                "diameter": 3.0, "cd": 2.0, "ca": 1.0, "segments": 40}])
    path = write_scene(tmp_path, text, "m.toml")
    steady_scene_file(path, tmp_path / "steady.nc", progress=False)
    run_scene_file(path, tmp_path / "run.nc", progress=False)
    st, td = xr.load_dataset(tmp_path / "steady.nc"), xr.load_dataset(tmp_path / "run.nc")
    zs = st["position"].sel(body="sphere", dof="heave").values
    zt = td["position"].sel(body="sphere", dof="heave").values
    t = td["time"].values
    last = t > t[-1] - 4 * period
    assert 0.5 * np.ptp(zs) == pytest.approx(0.5 * np.ptp(zt[last]), rel=1e-2)
    bare = write_scene(tmp_path, text.split("[[morison]]")[0], "bare.toml")
    steady_scene_file(bare, tmp_path / "bare.nc", progress=False)
    zb = xr.load_dataset(tmp_path / "bare.nc")["position"].sel(body="sphere", dof="heave").values
    assert abs(np.ptp(zs) / np.ptp(zb) - 1) > 0.05      # the member matters at this size


def test_convolution_radiation_is_sampled_at_the_exchange_step(rm3):
    """``[steady] radiation = "convolution"`` realises the time-domain run's radiation memory, whose IRF
    the server samples at its own step, one exchange ([coupling] exchange_every x simulation.dt; it
    took simulation.dt before): a scene exchanging every 2 steps of 0.2 s has the effective A(w), B(w)
    of one exchanging every step of 0.4 s to round-off, and not those of 0.2 s (RM3's IRF is smooth:
    the two steps' sums differ by ~5e-7 of B at T = 8 s, far above round-off and small in practice)."""
    from pathlib import Path

    from hydrolink.clients.analysis.steady import convolution_radiation, hydro_model
    base = scene_text("full", Path("rm3.1"))
    assert "dt = 0.08" in base

    def coefficients(dt: float, every: int):
        text = base.replace("dt = 0.08", f"dt = {dt}") + f"\n[coupling]\nexchange_every = {every}\n"
        scene = parse_scene(text)
        model = hydro_model(scene, {b.hdb: rm3 for b in scene.bodies})
        assert model.dt == pytest.approx(dt * every)
        return convolution_radiation(model, scene)(W)

    held = coefficients(0.2, 2)
    every_step = coefficients(0.4, 1)
    fine = coefficients(0.2, 1)
    for a, b in zip(held, every_step):
        np.testing.assert_allclose(a, b, rtol=1e-12, atol=1e-9 * np.abs(b).max())
    # the step matters: the 0.2 s sums differ from the 0.4 s ones by far more than round-off
    for a, b in zip(fine, every_step):
        assert np.abs(a - b).max() > 1e-9 * np.abs(b).max()
