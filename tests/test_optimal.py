"""``hydrolink optimize`` (clients/analysis/optimal/) on RM3 (regular wave H = 2.5 m, T = 8 s) against
closed forms written here from the HDB's frequency domain (tests/test_rm3.py's two-body heave model).

One PTO between the float and the spar: with v = Y (F_ex - g f) (Y the 2x2 velocity admittance,
g = (1, -1) the PTO's line), the PTO's rate is v_p = v_oc - y f with v_oc = g^T Y F_ex, y = g^T Y g
(a one-port). The mean power of f = Re(F e^{-iwt}) is 1/2 Re(conj(F) v_p); over F's phase at |F| = r
it is 1/2 r |v_oc| - 1/2 r^2 Re y, hence

- unconstrained (complex-conjugate): P* = |v_oc|^2 / (8 Re y), at r* = |v_oc| / (2 Re y);
- force limit F_max < r* with a sinusoidal force (order 1): P = 1/2 F_max |v_oc| - 1/2 F_max^2 Re y;
- stroke limit S (|v_p| <= w S): in v_p, P = 1/2 V |v_oc| / |y| - 1/2 V^2 Re y / |y|^2 at V = w S.
With more harmonics the force-limited optimum gains (a squarer force has a larger fundamental), up to P*.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hydrolink.protocol.scene import parse_scene
from test_rm3 import HEAVE, H, MASS, W, _at_w, hdb_radiation, scene_text

pytestmark = pytest.mark.xdist_group("steady")


@pytest.fixture(scope="module")
def rm3(reference_data):
    from hydrolink.server.hdb.io import load_hdb
    return load_hdb(reference_data / "rm3_wamit" / "rm3.1")


@pytest.fixture(scope="module")
def one_port(rm3) -> tuple[complex, complex]:
    """(v_oc, y) of the PTO's line from the HDB's heave blocks at w (velocity, exp(-iwt))."""
    a, b = hdb_radiation(rm3)
    c_hs = rm3["hydrostatic_stiffness"].values[np.ix_(HEAVE, HEAVE)]
    z = -W ** 2 * (np.diag(MASS) + a) - 1j * W * b + c_hs          # z x = F
    Y = -1j * W * np.linalg.inv(z)                                 # v = Y F
    f_ex = _at_w(rm3, rm3["excitation_force"].values[:, 0, HEAVE]) * H / 2
    g = np.array([1.0, -1.0])
    return complex(g @ Y @ f_ex), complex(g @ Y @ g)


def _optimum(rm3, extra: str):
    from hydrolink.clients.analysis.optimal.run import optimize_scene
    scene = parse_scene(scene_text("full", Path("rm3.1")) + extra)
    prob, sol, _ = optimize_scene(scene, {b.hdb: rm3 for b in scene.bodies})
    return prob, sol


def _fine(prob, values: np.ndarray, n: int = 4000, derivative: int = 0) -> np.ndarray:
    """Nodal values (P,) interpolated on ``n`` instants of the period (independent of the solver's grid)."""
    k = np.arange(-prob.order, prob.order + 1)
    c = np.fft.fftshift(np.fft.fft(values)) / values.size * (1j * k * prob.omega0) ** derivative
    t = np.arange(n) * 2 * np.pi / prob.omega0 / n
    return np.real(np.exp(1j * np.outer(t, k * prob.omega0)) @ c)


def test_unconstrained_is_the_complex_conjugate_bound(rm3, one_port):
    v_oc, y = one_port
    p_cc = abs(v_oc) ** 2 / (8 * y.real)
    prob, sol = _optimum(rm3, "\n[optimize]\norder = 4\n")
    print(f"optimum {sol.power:.6g} W, unconstrained {sol.unconstrained_power:.6g} W, closed form {p_cc:.6g} W")
    assert sol.unconstrained_power == pytest.approx(p_cc, rel=1e-6)
    assert sol.power == pytest.approx(p_cc, rel=1e-6) and not sol.active
    # its force amplitude is r* and only the first harmonic moves
    f = _fine(prob, sol.u)
    assert np.abs(f).max() == pytest.approx(abs(v_oc) / (2 * y.real), rel=1e-6)


def test_force_limit_sinusoid_closed_form_and_harmonics_gain(rm3, one_port):
    v_oc, y = one_port
    r_star = abs(v_oc) / (2 * y.real)
    f_max = 0.5 * r_star
    closed = 0.5 * f_max * abs(v_oc) - 0.5 * f_max ** 2 * y.real
    limit = f"\n[[optimize.limits]]\npto = \"pto\"\nforce = {f_max!r}\n"
    prob1, sol1 = _optimum(rm3, "\n[optimize]\norder = 1\n" + limit)
    prob10, sol10 = _optimum(rm3, "\n[optimize]\norder = 10\n" + limit)
    print(f"F_max {f_max:.4g} N: order 1 {sol1.power:.6g} W vs closed form {closed:.6g} W; order 10 {sol10.power:.6g} W; "
          f"bound {sol10.unconstrained_power:.6g} W")
    assert sol1.power == pytest.approx(closed, rel=1e-3)
    assert sol1.active == ["pto.force"] and sol10.active == ["pto.force"]
    assert closed * 1.01 < sol10.power < sol10.unconstrained_power
    for prob, sol in ((prob1, sol1), (prob10, sol10)):     # held between the nodes too
        assert np.abs(_fine(prob, sol.u)).max() <= f_max * 1.005


def test_stroke_limit_closed_form(rm3, one_port):
    v_oc, y = one_port
    v_star = abs(v_oc) / 2                  # |v_p| at the conjugate optimum (v_p = v_oc / 2)
    stroke = 0.6 * v_star / W
    V = W * stroke
    closed = 0.5 * V * abs(v_oc) / abs(y) - 0.5 * V ** 2 * y.real / abs(y) ** 2
    prob, sol = _optimum(rm3, f"\n[optimize]\norder = 1\n[[optimize.limits]]\npto = \"pto\"\nstroke = {stroke!r}\n")
    print(f"stroke {stroke:.4g} m: {sol.power:.6g} W vs closed form {closed:.6g} W")
    assert sol.power == pytest.approx(closed, rel=1e-3) and sol.active == ["pto.stroke"]
    ext = (prob.s0 + prob.Ts @ sol.u)
    assert np.abs(_fine(prob, ext)).max() <= stroke * 1.005


def test_reactive_spring_damper_reaches_the_bound_in_steady(rm3, one_port):
    """A negative PTO stiffness is a scene a controller may command: steady with the conjugate
    tuning (f = c v_p + k x_p = conj(1/y) v_p) absorbs the complex-conjugate power."""
    from hydrolink.clients.analysis.steady import hydro_model, linearize, sample, solve
    v_oc, y = one_port
    z_p = np.conj(1 / y)                    # f = z_p v_p; x_p = v_p / (-iw): f = (c + i k / w) v_p
    c, k = float(z_p.real), float(z_p.imag * W)
    assert k < 0
    text = scene_text("full", Path("rm3.1")).replace("damping = 1.2e6", f"damping = {c!r}\nstiffness = {k!r}")
    scene = parse_scene(text)
    model = hydro_model(scene, {b.hdb: rm3 for b in scene.bodies})
    sol = solve(linearize(scene, model, model.setup_info()), 1, "ode")
    p = sample(sol, np.linspace(0, 2 * np.pi / W, 200, endpoint=False))["pto_power"].mean()
    assert p == pytest.approx(abs(v_oc) ** 2 / (8 * y.real), rel=1e-6)


def test_bad_limits_are_refused(rm3):
    from hydrolink.clients.analysis.optimal.problem import OptimizeError
    # names the scene does not have: refused when the scene is read (also by `hydrolink run`, before it runs)
    with pytest.raises(ValueError, match=r"optimize.limits\[0\].pto: no PTO named 'ptoo'"):
        _optimum(rm3, "\n[[optimize.limits]]\npto = \"ptoo\"\nforce = 1e5\n")
    with pytest.raises(ValueError, match=r"optimize.limits\[1\].body: no body named 'flot'"):
        _optimum(rm3, "\n[[optimize.limits]]\npto = \"pto\"\nforce = 1e5\n"
                      "[[optimize.limits]]\nbody = \"flot\"\ndof = \"heave\"\ndisplacement = 1.0\n")
    # the float's heave held within 1 mm by a PTO force of at most 1 kN against a 2.5 m wave
    with pytest.raises(OptimizeError, match="admit no periodic motion"):
        _optimum(rm3, "\n[optimize]\norder = 2\n[[optimize.limits]]\npto = \"pto\"\nforce = 1e3\n"
                      "[[optimize.limits]]\nbody = \"float\"\ndof = \"heave\"\ndisplacement = 1e-3\n")
    with pytest.raises(ValueError, match="no limit given"):
        parse_scene(scene_text("full", Path("rm3.1")) + "\n[[optimize.limits]]\npto = \"pto\"\n")


def test_no_reactive_power_order_one_is_the_best_damper(rm3, one_port):
    """``reactive = false``: u(t) v(t) >= 0 with sinusoids forces u in phase with v: a damper u = c v_p; the best c by a
    scalar search over the one-port's P(c) = 1/2 c |v_oc / (1 + y c)|^2."""
    from scipy.optimize import minimize_scalar
    v_oc, y = one_port
    best = minimize_scalar(lambda lc: -0.5 * np.exp(lc) * abs(v_oc / (1 + y * np.exp(lc))) ** 2,
                           bounds=(np.log(1e4), np.log(1e8)), method="bounded")
    prob, sol = _optimum(rm3, "\n[optimize]\norder = 1\nreactive = false\n")
    print(f"no reactive power: {sol.power:.6g} W vs best damper {-best.fun:.6g} W (c = {np.exp(best.x):.4g} N s/m)")
    # the rule is sampled (1024 instants a period): the force may lead v by ~pi/1024, +0.4 % here
    assert 0 <= sol.power / -best.fun - 1 < 0.01 and sol.solver == "slsqp"


def test_efficiency_order_one_closed_form(rm3, one_port):
    """``efficiency = eta``: the electrical power is eta p while the PTO absorbs, p / eta while it feeds
    power back. With sinusoids (order 1) f = Re(F e^{-iwt}), v_p = Re(V e^{-iwt}), V = v_oc - y F, the
    power p(t) = 1/2 |F||V| (c + cos theta(t)) with c = cos(angle(F, V)), so mean p = 1/2 |F||V| c and
    mean |p| = 1/2 |F||V| (2/pi) (sqrt(1 - c^2) + c asin c); the electrical mean is a mean p - b mean |p|,
    a = (eta + 1/eta) / 2, b = (1/eta - eta) / 2, maximised here over the complex F (Nelder-Mead)."""
    from scipy.optimize import minimize
    v_oc, y = one_port
    eta = 0.7
    a, b = 0.5 * (eta + 1 / eta), 0.5 * (1 / eta - eta)
    f_star = v_oc / (2 * y.real)

    def electrical(z):
        f = complex(z[0], z[1]) * abs(f_star)
        v = v_oc - y * f
        half = 0.5 * abs(f) * abs(v)
        c = float(np.clip(np.real(np.conj(f) * v) / max(abs(f) * abs(v), 1e-300), -1, 1))
        return a * half * c - b * half * 2 / np.pi * (np.sqrt(1 - c * c) + c * np.arcsin(c))

    starts = [f_star / abs(f_star) * s for s in (1.0, 0.5, 0.5j, -0.3 + 0.3j)]
    best = max((minimize(lambda z: -electrical(z), [s.real, s.imag], method="Nelder-Mead",
                         options={"xatol": 1e-10, "fatol": 1e-6, "maxiter": 4000}) for s in starts), key=lambda r: -r.fun)
    closed = -best.fun
    prob, sol = _optimum(rm3, f"\n[optimize]\norder = 1\nefficiency = {eta!r}\n")
    print(f"efficiency {eta}: electrical {sol.electrical_power:.6g} W vs closed form {closed:.6g} W "
          f"(mechanical {sol.power:.6g} W; lossless bound x eta {eta * sol.unconstrained_power:.6g} W)")
    assert sol.electrical_power == pytest.approx(closed, rel=2e-3)
    assert sol.electrical_power < eta * sol.unconstrained_power and sol.solver == "slsqp"
    # the MPC's convex stand-in (a force penalty) gains on the conjugate force, short of the optimum
    from hydrolink.clients.analysis.optimal.solver import loss_penalty
    conjugate = electrical([f_star.real / abs(f_star), f_star.imag / abs(f_star)])
    rho, penalised = loss_penalty(prob, eta)
    print(f"conjugate force {conjugate:.6g} W electrical; force penalty {rho:.3g} W/N^2: {penalised:.6g} W")
    assert conjugate < penalised <= closed * 1.001


def test_wavebot_single_dof_force_limit_closed_form():
    """One DOF, the WaveBot's heave in its regular wave (a = 0.0625 m, w = 2 pi 0.3 Hz, on the HDB's
    grid): from the HDB, (B - i w (m + A) + i K / w) v = F_ex - f, so v_p = v_oc - y f with
    v_oc = F_ex / Z, y = 1 / Z. Unconstrained: |F_ex|^2 / (8 B); a force limit F_max below the conjugate
    force with a sinusoidal force (order 1): 1/2 F_max |v_oc| - 1/2 F_max^2 Re y. With 7 harmonics the
    force may be squarer: more power, still below the bound, and within the limit between the nodes."""
    import math

    from hydrolink.clients.analysis.optimal.run import optimize_scene
    from hydrolink.server.hdb.io import load_hdb

    scene_file = Path(__file__).resolve().parents[1] / "examples" / "optimal_control" / "wavebot.toml"
    hdb = load_hdb(scene_file.parent.parent / "data" / "wavebot" / "wavebot.nc")
    w, a, m, f_max = 2 * math.pi * 0.3, 0.0625, 876.104, 2000.0
    i = int(np.argmin(np.abs(hdb["omega"].values - w)))
    assert hdb["omega"].values[i] == pytest.approx(w, rel=1e-9)
    A, B = hdb["added_mass"].values[i, 2, 2], hdb["radiation_damping"].values[i, 2, 2]
    K = hdb["hydrostatic_stiffness"].values[2, 2]
    f_ex = hdb["excitation_force"].values[i, 0, 2] * a
    Z = B - 1j * w * (m + A) + 1j * K / w
    v_oc, y = f_ex / Z, 1 / Z
    bound = abs(f_ex) ** 2 / (8 * B)
    closed = 0.5 * f_max * abs(v_oc) - 0.5 * f_max ** 2 * y.real
    assert f_max < abs(v_oc) / (2 * y.real)                          # the limit binds
    text = scene_file.read_text().replace('"../data/', f'"{(scene_file.parent.parent / "data").as_posix()}/')
    powers = {}
    for order in (1, 7):
        scene = parse_scene(text.replace("\norder = 7 ", f"\norder = {order} "))
        prob, sol, _ = optimize_scene(scene, {b.hdb: hdb for b in scene.bodies})
        powers[order] = sol.power
        assert sol.unconstrained_power == pytest.approx(bound, rel=1e-6) and sol.active == ["pto.force"]
        assert np.abs(_fine(prob, sol.u, n=40 * sol.u.size)).max() <= f_max * 1.005
    print(f"WaveBot F <= {f_max:g} N: order 1 {powers[1]:.4f} W vs closed form {closed:.4f} W; order 7 {powers[7]:.4f} W; "
          f"bound {bound:.4f} W")
    assert powers[1] == pytest.approx(closed, rel=1e-4)
    assert closed < powers[7] < bound


def test_irregular_sea_repeat_period():
    """A sea whose components sit at odd multiples of dw/2 (omega_range from a multiple of dw) repeats
    after 4 pi / dw; any other band is refused naming waves.omega_range; too low an order is refused."""
    from hydrolink.clients.analysis.optimal.problem import OptimizeError, harmonic_grid
    from hydrolink.server.sea.waves import wave_components
    dw = 2 * np.pi / 40.0

    def sea(lo: float, extra: str = ""):
        text = scene_text("full", Path("rm3.1")).replace(
            'type = "regular"\nheight = 2.5             # m\nperiod = 8.0             # s',
            f'type = "irregular"\nspectrum = "jonswap"\nhs = 2.5\ntp = 8.0\ncomponents = 30\n'
            f'omega_range = [{lo!r}, {lo + 30 * dw!r}]')
        scene = parse_scene(text + extra)
        return scene, wave_components(scene.waves, 0.02, 20.0).omega

    scene, omega = sea(5 * dw)
    w0, harmonics, order = harmonic_grid(scene, omega)
    assert 2 * np.pi / w0 == pytest.approx(80.0) and order == 2 * 34 + 1
    np.testing.assert_array_equal(harmonics, 2 * np.arange(5, 35) + 1)
    with pytest.raises(OptimizeError, match="waves.omega_range: the sea's components are not harmonics"):
        harmonic_grid(*sea(5.3 * dw))
    with pytest.raises(OptimizeError, match="optimize.order: 20 harmonics of the repeat period 80 s"):
        harmonic_grid(*sea(5 * dw, "\n[optimize]\norder = 20\n"))


def test_a_run_with_a_force_limit_carries_its_metrics(reference_data, tmp_path):
    """`hydrolink run` of a scene with a PTO force limit writes the WECCCOMP metrics into the
    results and its summary: mean power against the frequency-domain ½ c ω² |X|² of the sphere's
    heave damper, utilisation against c ω |X| / limit (the limit above the force: never reached)."""
    import math

    from conftest import SPHERE_WATER, linear_pto, regular_waves, scene_toml, sphere_body, write_scene
    from hydrolink.clients.run import run_scene_file
    from hydrolink.server.hdb.io import load_hdb

    path = reference_data / "sphere_task10" / "sphere.h5"
    hdb = load_hdb(path)
    mass, heave, c_pto, height = 261.724e3, 2, 2.0e5, 1.0
    i = int(np.argmin(np.abs(hdb["omega"].values - 1.15)))
    w = float(hdb["omega"].values[i])
    a, b = hdb["added_mass"].values[i, heave, heave], hdb["radiation_damping"].values[i, heave, heave]
    f, c = hdb["excitation_force"].values[i, 0, heave], hdb["hydrostatic_stiffness"].values[heave, heave]
    x = abs(f * height / 2 / (-w ** 2 * (mass + a) - 1j * w * (b + c_pto) + c))
    limit = 2.0 * c_pto * w * x
    period = 2 * math.pi / w
    scene = write_scene(tmp_path, scene_toml(
        dt=period / 100, duration=24 * period, progress=False, water={**SPHERE_WATER, "gravity": 9.81},
        waves=regular_waves(height, period, ramp=6 * period),
        bodies=[sphere_body(str(path), mass=mass, dofs=["heave"])],
        ptos=[linear_pto("damper", "sphere", [0, 0, 0], "ground", [0, 0, -50], damping=c_pto,
                         force_limit=limit)]), "sphere.toml")
    summary = run_scene_file(scene, tmp_path / "sphere.nc", progress=False)
    import xarray as xr
    attrs = xr.open_dataset(tmp_path / "sphere.nc").attrs
    assert summary.metrics is not None
    assert attrs["wecccomp_mean_power"] == pytest.approx(summary.metrics.mean_power)
    assert summary.metrics.mean_power == pytest.approx(0.5 * c_pto * w ** 2 * x ** 2, rel=0.05)
    (use,) = summary.metrics.limits
    assert use.label == "damper.force" and use.violations == 0
    assert use.utilisation == pytest.approx(0.5, rel=0.06)


@pytest.mark.parametrize("dt,rows,why", [("0.1", 80, ""), ("100", 0, "longer than the period"),
                                         ("1e-300", 0, "greater than or equal to 1e-06"), ("nan", 0, "finite")])
def test_cli_writes_one_period_every_dt_or_refuses_it(reference_data, tmp_path, dt, rows, why):
    """``hydrolink optimize --dt``: one period of the wave (T = 8 s) every dt, the sampled power's mean
    the optimum's (the rectangle rule on 80 points is exact for the power's harmonics, up to 8);
    a --dt that is not a time step (nan and 1e-300 ended in a traceback) or exceeds the period: one
    line naming --dt, nothing written."""
    import xarray as xr
    from click.testing import CliRunner

    from hydrolink.clients.cli import cli
    scene = tmp_path / "rm3.toml"
    scene.write_text(scene_text("full", reference_data / "rm3_wamit" / "rm3.1") + "\n[optimize]\norder = 4\n")
    res = CliRunner().invoke(cli, ["optimize", str(scene), "-o", str(tmp_path / "o.nc"), "--dt", dt, "--no-progress"])
    if not rows:
        assert res.exit_code == 1 and "--dt" in res.output and why in res.output, res.output
        assert not (tmp_path / "o.nc").exists()
        return
    assert res.exit_code == 0, res.output
    ds = xr.load_dataset(tmp_path / "o.nc")
    assert ds.sizes["time"] == rows and np.allclose(np.diff(ds["time"].values), 0.1)
    assert float(ds["total_pto_power"].mean()) == pytest.approx(float(ds.attrs["optimize_power"]), rel=1e-6)
