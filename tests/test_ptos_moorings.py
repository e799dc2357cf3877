"""PTOs and moorings in Exudyn against closed-form references (real Exudyn, dry mechanisms)."""

from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr

import exudyn as exu
from scipy.optimize import brentq

from conftest import (SPHERE_WATER, body, joint, linear_pto, regular_waves, scene_toml, sphere_body,
                      write_scene)

from hydrolink.clients.exudyn.mechanism import build_mechanism
from hydrolink.clients.exudyn.moorings import SEABED_PENETRATION, build_moorings, rope_properties
from hydrolink.clients.exudyn.ptos import build_ptos
from hydrolink.protocol.scene import parse_scene

RHO, G = 1025.0, 9.81


def _system(**sections):
    """Mechanism + PTOs + moorings of a dry scene (``sections`` as scene_toml takes them; weights
    cancelled by buoyancy in the scenes)."""
    scene = parse_scene(scene_toml(dt=0.01, duration=1.0, progress=False, **sections))
    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    mech = build_mechanism(mbs, scene, {})
    ptos = build_ptos(mbs, scene.ptos, mech.handles)
    moorings = build_moorings(mbs, scene.moorings, mech.handles, scene.water)
    mbs.Assemble()
    return sc, mbs, mech, ptos, moorings


def _settings(dt: float = 0.01) -> exu.SimulationSettings:
    ss = exu.SimulationSettings()
    ss.solution.file.write = False
    ss.solution.sensors.active = False
    ss.timeIntegration.verboseMode = 0
    ss.staticSolver.verboseMode = 0
    ss.staticSolver.newton.relativeTolerance = 1e-7
    ss.staticSolver.newton.absoluteTolerance = 1e-4     # round-off floor of EA ~ 1e9 N
    ss.timeIntegration.adaptiveStep = False
    ss.timeIntegration.numberOfSteps = 1
    ss.timeIntegration.endTime = dt
    ss.timeIntegration.generalizedAlpha.spectralRadius = 1.0
    return ss


def _run(mbs, n_steps: int, dt: float, sample, spectral_radius: float = 1.0):
    """Step the system by hand (as the client does) and call ``sample(t)`` after every step."""
    ss = _settings(dt)
    ss.timeIntegration.generalizedAlpha.spectralRadius = spectral_radius
    solver = exu.MainSolverImplicitSecondOrder()
    solver.InitializeSolver(mbs, ss)
    rows = [sample(0.0)]
    for k in range(1, n_steps + 1):
        solver.it.startTime, solver.it.endTime = (k - 1) * dt, k * dt
        assert solver.SolveSteps(mbs, ss)
        rows.append(sample(k * dt))
    solver.FinalizeSolver(mbs, ss)
    return rows


def _dry_body(name="b", mass=100.0, com=(0.0, 0.0, 0.0), inertia=(10.0, 20.0, 30.0), dofs=None,
              x0=None, v0=None) -> dict:
    """A dry body whose buoyancy cancels its weight."""
    keys = {k: v for k, v in (("dofs", dofs), ("initial_displacement", x0), ("initial_velocity", v0)) if v is not None}
    return body(name, mass=mass, center_of_mass=com, inertia=inertia, buoyancy_volume=mass / RHO, **keys)


def _node_state(mbs, mech, name="b"):
    node = mech.handles[name].node
    return (np.asarray(mbs.GetNodeOutput(node, exu.OutputVariableType.Coordinates)),
            np.asarray(mbs.GetNodeOutput(node, exu.OutputVariableType.Coordinates_t)))


# -- linear PTO ------------------------------------------------------------------------------------
M, K, C = 100.0, 400.0, 40.0          # ω0 = 2 rad/s, ζ = 0.1


def linear_oscillator(**pto_keys) -> dict:
    """Sections of a surge oscillator: spring K (a linear mooring) and damper C (a PTO to ground)."""
    return dict(bodies=[_dry_body(mass=M, dofs=["surge"], x0=[0.1, 0, 0, 0, 0, 0])],
                moorings=[{"type": "linear", "name": "spring", "body": "b", "point": [0, 0, 0],
                           "stiffness": [K, 0, 0, 0, 0, 0]}],
                ptos=[linear_pto("damper", "b", [0, 0, 0], "ground", [-5, 0, 0], damping=C, **pto_keys)])


def test_linear_pto_damped_oscillator_and_power():
    sc, mbs, mech, ptos, moorings = _system(**linear_oscillator())
    dt, n = 0.005, 1200
    rows = _run(mbs, n, dt, lambda t: (t, *_node_state(mbs, mech), ptos.sample(mbs), moorings.sample(mbs)))
    t = np.array([r[0] for r in rows])
    x = np.array([r[1][0] for r in rows])
    v = np.array([r[2][0] for r in rows])
    w0, zeta = math.sqrt(K / M), C / (2 * math.sqrt(K * M))
    wd = w0 * math.sqrt(1 - zeta ** 2)
    exact = 0.1 * np.exp(-zeta * w0 * t) * (np.cos(wd * t) + zeta / math.sqrt(1 - zeta ** 2) * np.sin(wd * t))
    assert np.abs(x - exact).max() < 2e-6 / 0.1 * 0.1 * 100     # trapezoidal rule at ω dt = 0.01
    # decay per period and period from the zero crossings
    up = np.flatnonzero((x[:-1] < 0) & (x[1:] >= 0))
    tz = t[up] - x[up] * dt / (x[up + 1] - x[up])
    assert np.diff(tz).mean() == pytest.approx(2 * math.pi / wd, rel=1e-4)
    # PTO outputs: the line runs from point1 (body) to point2 (ground, at -x): e = -ex, so the
    # extension rate is (0 - v)·e = v; the force on body1 along e is c v; absorbed power c v²
    force = np.array([r[3].force[0] for r in rows])
    vel = np.array([r[3].velocity[0] for r in rows])
    power = np.array([r[3].power[0] for r in rows])
    assert ptos.names == ["damper"]
    np.testing.assert_allclose(vel, v, atol=1e-12)
    np.testing.assert_allclose(force, C * vel, atol=1e-9)
    np.testing.assert_allclose(power, C * v ** 2, atol=1e-9)
    assert (power >= 0).all()
    # energy: absorbed work = initial spring energy - remaining energy
    work = np.sum(0.5 * (power[1:] + power[:-1])) * dt
    remaining = 0.5 * K * x[-1] ** 2 + 0.5 * M * v[-1] ** 2
    assert work == pytest.approx(0.5 * K * 0.1 ** 2 - remaining, rel=2e-3)
    # mooring force on the body: -K x (surge), nothing else
    mf = np.array([r[4][0] for r in rows])
    np.testing.assert_allclose(mf[:, 0], -K * x, atol=1e-9)
    assert np.abs(mf[:, 1:]).max() < 1e-9


def test_linear_pto_force_limit_saturates():
    limit = 1.0
    sc, mbs, mech, ptos, moorings = _system(**linear_oscillator(force_limit=limit))
    obj = ptos.objects[0]
    rows = _run(mbs, 400, 0.005, lambda t: (ptos.sample(mbs), np.asarray(
        mbs.GetObjectOutput(obj, exu.OutputVariableType.Force)), _node_state(mbs, mech)[1][0]))
    force = np.array([r[0].force[0] for r in rows])
    v = np.array([r[2] for r in rows])
    exudyn_force = np.array([r[1][0] for r in rows])   # connector force vector (x component)
    assert np.abs(force).max() == pytest.approx(limit, rel=1e-12)
    assert (np.abs(force) >= limit * (1 - 1e-12)).sum() > 50          # saturated for a while
    assert np.abs(C * v).max() > 4 * limit                               # would be 4× more unlimited
    # the sampler agrees with the force Exudyn applies (the line points along -x)
    np.testing.assert_allclose(-exudyn_force, force, atol=1e-9)
    # slower decay than the unlimited damper: the energy is removed at most at limit·|v|
    assert np.all(np.array([r[0].power[0] for r in rows]) <= limit * np.abs(v) + 1e-12)


# -- rotary PTO on a spherical joint ---------------------------------------------------------------
def test_rotary_pto_torsional_period_and_free_axes():
    iyy, k, theta0, roll_rate = 20.0, 80.0, 0.05, 0.02
    sc, mbs, mech, ptos, _ = _system(
        bodies=[_dry_body(inertia=(10.0, iyy, 30.0), x0=[0, 0, 0, 0, theta0, 0], v0=[0, 0, 0, roll_rate, 0, 0])],
        joints=[joint("spherical", "ground", "b", [0, 0, 0])],
        ptos=[{"name": "hinge", "type": "rotary", "body1": "ground", "body2": "b", "point": [0, 0, 0],
               "axes": ["pitch"], "stiffness": k}])
    dt = 0.002
    rows = _run(mbs, 2000, dt, lambda t: (t, *_node_state(mbs, mech), ptos.sample(mbs)))
    t = np.array([r[0] for r in rows])
    q = np.array([r[1] for r in rows])
    s = [r[3] for r in rows]
    pitch = q[:, 4]
    cross = np.flatnonzero(np.sign(pitch[:-1]) != np.sign(pitch[1:]))
    tz = t[cross] - pitch[cross] * dt / (pitch[cross + 1] - pitch[cross])
    assert len(tz) >= 3
    assert 2 * np.diff(tz).mean() == pytest.approx(2 * math.pi * math.sqrt(iyy / k), rel=1e-3)
    # roll and yaw feel no stiffness: the roll rate stays (coupling is second order in the angles)
    assert q[-1, 3] == pytest.approx(roll_rate * t[-1], rel=2e-2)
    assert ptos.names == ["hinge.pitch"]
    # torque on body1 (ground) about +y is k θ (θ of body2 relative to body1), power = k θ ω
    f = np.array([x.force[0] for x in s])
    assert np.abs(f - k * pitch).max() < 2e-3 * k * theta0
    assert np.abs(np.array([x.power[0] for x in s])
                  - f * np.array([x.velocity[0] for x in s])).max() < 1e-12


def test_rotary_pto_frame_and_several_axes_match_exudyn_outputs():
    sc, mbs, mech, ptos, _ = _system(
        bodies=[_dry_body(x0=[0, 0, 0, 0.03, -0.02, 0.04], v0=[0, 0, 0, 0.1, 0.2, -0.1])],
        joints=[joint("spherical", "ground", "b", [0, 0, 0])],
        ptos=[{"name": "r", "type": "rotary", "body1": "ground", "body2": "b", "point": [0, 0, 0],
               "axes": ["yaw", "roll"], "stiffness": [5.0, 7.0], "damping": [1.0, 2.0],
               "frame": [[0, 1, 0], [-1, 0, 0], [0, 0, 1]], "torque_limit": 0.25}])
    rows = _run(mbs, 50, 0.01, lambda t: (ptos.sample(mbs), np.asarray(
        mbs.GetObjectOutput(ptos.objects[0], exu.OutputVariableType.Rotation)), np.asarray(
        mbs.GetObjectOutput(ptos.objects[0], exu.OutputVariableType.AngularVelocityLocal))))
    assert ptos.names == ["r.yaw", "r.roll"]
    for s, rot, omega in rows:
        expect = np.clip([5.0 * rot[2] + 1.0 * omega[2], 7.0 * rot[0] + 2.0 * omega[0]], -0.25, 0.25)
        np.testing.assert_allclose(s.force, expect, atol=1e-12)
        np.testing.assert_allclose(s.velocity, [omega[2], omega[0]], atol=1e-12)
    assert max(abs(r[0].force).max() for r in rows) == pytest.approx(0.25)


# -- linear mooring with pretension ----------------------------------------------------------------
def test_linear_mooring_pretension_static_offset():
    k = [1000.0, 2000.0, 3000.0, 400.0, 500.0, 600.0]
    pre = [50.0, -80.0, 30.0, 4.0, -5.0, 6.0]
    sections = dict(bodies=[_dry_body(com=(1.0, 2.0, -3.0))],
                    moorings=[{"type": "linear", "body": "b", "point": [1.0, 2.0, -3.0], "stiffness": k,
                               "damping": [10, 10, 10, 1, 1, 1], "pretension": pre}])
    sc, mbs, mech, _, moorings = _system(**sections)
    ss = _settings()
    mbs.SolveStatic(ss)
    q, _ = _node_state(mbs, mech)
    expected = np.array(pre) / np.array(k)
    np.testing.assert_allclose(q[:3], expected[:3], rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(q[3:], expected[3:], rtol=2e-3)    # Tait-Bryan vs small angles
    assert np.abs(moorings.sample(mbs)[0]).max() < 1e-6 * max(pre)   # in balance: K x = pretension
    # at zero displacement the mooring exerts exactly the pretension
    sc2, mbs2, _, _, moorings2 = _system(**sections)
    ss2 = _settings()
    solver = exu.MainSolverImplicitSecondOrder()
    solver.InitializeSolver(mbs2, ss2)
    np.testing.assert_allclose(moorings2.sample(mbs2)[0], pre, atol=1e-12)
    solver.FinalizeSolver(mbs2, ss2)


# -- ropes -----------------------------------------------------------------------------------------
def test_rope_catenary_shape_and_tension():
    mu, span, length, n = 10.0, 80.0, 100.0, 20
    w = mu * G
    sc, mbs, mech, _, moorings = _system(
        bodies=[_dry_body(com=(span, 0.0, -10.0), dofs=["surge"])],
        moorings=[{"type": "linear", "body": "b", "point": [span, 0, -10], "stiffness": [1e8, 0, 0, 0, 0, 0]},
                  {"type": "rope", "name": "line", "anchor": [0, 0, -10], "attach_to": "b", "point": [span, 0, -10],
                   "length": length, "axial_stiffness": 1e10, "mass_per_length": mu, "elements": n}])
    mbs.SolveStatic(_settings())
    c = brentq(lambda c: 2 * c * math.sinh(span / (2 * c)) - length, 1.0, 1e4)
    rope = moorings.ropes[1]
    pos = np.array([mbs.GetNodeOutput(nd, exu.OutputVariableType.Position) for nd in rope.nodes])
    z_exact = -10 + c * (np.cosh((pos[:, 0] - span / 2) / c) - math.cosh(span / (2 * c)))
    assert np.abs(pos[:, 2] - z_exact).max() < 2e-3
    f = -moorings.sample(mbs)[1]     # sampled after a static solve: Exudyn's static sign (see sample)
    assert moorings.names == ["moorings[0]", "line"]
    np.testing.assert_allclose(f[:3], [-w * c, 0.0, -w * length / 2], rtol=2e-4, atol=1e-6)
    np.testing.assert_allclose(f[3:], 0.0)


def test_rope_hanging_vertical_top_tension_and_taut_axial_stiffness():
    # weightless taut rope (buoyancy cancels its weight): small pull F gives F L / EA
    mu, ea, length = 5.0, 2.0e7, 50.0
    d = math.sqrt(4 * mu / (math.pi * RHO))
    pull = 4.0e4
    sc, mbs, mech, _, moorings = _system(
        bodies=[_dry_body(com=(length, 0.0, -10.0), dofs=["surge"])],
        moorings=[{"type": "linear", "body": "b", "point": [length, 0, -10], "pretension": [pull, 0, 0, 0, 0, 0]},
                  {"type": "rope", "anchor": [0, 0, -10], "attach_to": "b", "point": [length, 0, -10], "length": length,
                   "axial_stiffness": ea, "mass_per_length": mu, "diameter": d, "elements": 8}])
    mbs.SolveStatic(_settings())
    q, _ = _node_state(mbs, mech)
    assert q[0] == pytest.approx(pull * length / ea, rel=1e-6)
    # sampled after a static solve: Exudyn's static sign (see MooringSet.sample)
    np.testing.assert_allclose(-moorings.sample(mbs)[1][:3], [-pull, 0, 0], rtol=1e-6, atol=1e-3)
    # a vertical rope hanging from a fixed top anchor, a weight (heave-only body) at its lower end: the top
    # tension is w' L + m g (submerged weight of the rope + the weight it carries)
    mu2, m_pm, length2 = 20.0, 100.0, 30.0
    w_sub = (mu2 - RHO * math.pi * 0.05 ** 2 / 4) * G
    sc2, mbs2, mech2, _, moorings2 = _system(
        bodies=[_dry_body(mass=m_pm, com=(0.0, 0.0, -5.0 - length2), dofs=["heave"])],   # weight → pretension
        moorings=[{"type": "linear", "body": "b", "point": [0, 0, -5 - length2],
                   "pretension": [0, 0, -m_pm * G, 0, 0, 0]},
                  {"type": "rope", "anchor": [0, 0, -5], "attach_to": "b", "point": [0, 0, -5 - length2],
                   "length": length2, "axial_stiffness": 1e9, "mass_per_length": mu2, "diameter": 0.05,
                   "elements": 10}])
    mbs2.SolveStatic(_settings())
    top = np.asarray(mbs2.GetObjectOutput(moorings2.ropes[1].anchor_joint, exu.OutputVariableType.Force))
    assert abs(top[2]) == pytest.approx(w_sub * length2 + m_pm * G, rel=1e-6)
    np.testing.assert_allclose(-moorings2.sample(mbs2)[1][:3], [0, 0, m_pm * G], rtol=1e-6, atol=1e-6)
    stretch = (w_sub * length2 / 2 + m_pm * G) * length2 / 1e9      # mean tension · L / EA
    z_pm = mbs2.GetNodeOutput(mech2.handles["b"].node, exu.OutputVariableType.Position)[2]
    assert z_pm == pytest.approx(-5 - length2 - stretch, abs=1e-3 * stretch)


def test_rope_on_seabed_does_not_penetrate():
    depth = 20.0
    sections = dict(
        water={"depth": 20.0},
        bodies=[_dry_body(mass=2e4, com=(60.0, 0.0, -5.0), dofs=["surge", "heave"], v0=[0.05, 0, 0.1, 0, 0, 0])],
        moorings=[{"type": "linear", "body": "b", "point": [60, 0, -5], "stiffness": [2e5, 0, 2e5, 0, 0, 0]},
                  {"type": "rope", "anchor": [0, 0, -20], "attach_to": "b", "point": [60, 0, -5], "length": 70,
                   "axial_stiffness": 1e8, "mass_per_length": 50, "diameter": 0.05, "elements": 40}])
    scene = parse_scene(scene_toml(dt=0.01, duration=1.0, **sections))
    props = rope_properties(scene.moorings[1], scene.water)
    sc, mbs, mech, _, moorings = _system(**sections)
    rope = moorings.ropes[1]
    z = lambda: np.array([mbs.GetNodeOutput(nd, exu.OutputVariableType.Position)[2] for nd in rope.nodes])  # noqa: E731
    z0 = z()
    on_bed = z0 < -depth + 0.01
    assert on_bed.sum() >= 20                       # about 49 m of the 70 m lie on the bed
    assert z0.min() > -depth - 1.5 * SEABED_PENETRATION
    # dynamic: the body starts moving up and away, then springs back (ropes need some numerical
    # damping of their element-level modes: spectral radius 0.8)
    zmin = []
    rows = _run(mbs, 300, 0.01, lambda t: zmin.append(z().min()), spectral_radius=0.8)
    assert min(zmin) > -depth - 3 * SEABED_PENETRATION
    assert props["seabed_stiffness"] * SEABED_PENETRATION == pytest.approx(
        (50 - RHO * math.pi * 0.05 ** 2 / 4) * G * 70 / 40)
    assert len(rows) == 301


# -- wave-driven: heaving sphere with a PTO damper to ground ---------------------------------------
def test_sphere_pto_damper_mean_power_in_regular_waves(reference_data, tmp_path):
    """Mean absorbed power vs the frequency-domain ½ c ω² |X|², X = F_ex a / (−ω²(m+A) − iω(B+c) + C)."""
    import xarray as xr

    from hydrolink.clients.run import run_scene_file
    from hydrolink.server.hdb.io import load_hdb

    path = reference_data / "sphere_task10" / "sphere.h5"
    hdb = load_hdb(path)
    mass, heave, c_pto, height = 261.724e3, 2, 2.0e5, 1.0
    i = int(np.argmin(np.abs(hdb["omega"].values - 1.15)))
    w = float(hdb["omega"].values[i])
    a = hdb["added_mass"].values[i, heave, heave]
    b = hdb["radiation_damping"].values[i, heave, heave]
    f = hdb["excitation_force"].values[i, 0, heave]
    c = hdb["hydrostatic_stiffness"].values[heave, heave]
    x = f * height / 2 / (-w ** 2 * (mass + a) - 1j * w * (b + c_pto) + c)
    expected = 0.5 * c_pto * w ** 2 * abs(x) ** 2
    period = 2 * math.pi / w
    scene = write_scene(tmp_path, scene_toml(
        dt=period / 100, duration=20 * period, progress=False, water={**SPHERE_WATER, "gravity": 9.81},
        waves=regular_waves(height, period, ramp=2 * period),
        bodies=[sphere_body(str(path), mass=mass, dofs=["heave"])],
        ptos=[linear_pto("damper", "sphere", [0, 0, 0], "ground", [0, 0, -50], damping=c_pto)]), "sphere.toml")
    run_scene_file(scene, tmp_path / "sphere.nc", progress=False)
    ds = xr.load_dataset(tmp_path / "sphere.nc")
    assert ds.attrs["status"] == "complete"
    assert list(ds["pto"].values) == ["damper"]
    t = ds["time"].values
    sel = t > t[-1] - 4 * period + 1e-9                      # last 4 periods (steady state)
    power = ds["pto_power"].values[sel, 0]
    print(f"sphere PTO mean power {power.mean():.2f} W vs frequency domain {expected:.2f} W "
          f"({power.mean() / expected - 1:+.2e})")
    assert power.mean() == pytest.approx(expected, rel=0.02)
    v = ds["velocity"].sel(body="sphere", dof="heave").values
    np.testing.assert_allclose(ds["pto_power"].values[:, 0], c_pto * v ** 2, rtol=1e-9, atol=1e-9)
    np.testing.assert_allclose(ds["total_pto_power"].values, ds["pto_power"].values.sum(axis=1))
    # the damper acts on the body: with c = 0 the amplitude would be larger
    assert abs(x) < abs(f * height / 2 / (-w ** 2 * (mass + a) - 1j * w * b + c))


def test_rope_force_on_a_hanging_body_in_a_run_equals_its_weight(tmp_path):
    """mooring_force as `hydrolink run` records it (dynamic solver): a 100 kg body hanging from a
    5 m rope settles with the rope pulling it up by m g (rope weight carried by the anchor)."""
    from hydrolink.clients.run import run_scene_file
    scene = write_scene(tmp_path, scene_toml(
        dt=0.01, duration=6.0, progress=False, simulation={"spectral_radius": 0.8},
        water={"density": 1000.0, "depth": 50.0},
        bodies=[body("b", mass=100.0, center_of_mass=[0, 0, -10], inertia=[1, 1, 1], dofs=["heave"])],
        moorings=[{"type": "rope", "anchor": [0, 0, -5], "attach_to": "b", "point": [0, 0, -10], "length": 5.0,
                   "axial_stiffness": 1e6, "mass_per_length": 1.0, "seabed": False}]), "hang.toml")
    run_scene_file(scene, tmp_path / "hang.nc", progress=False)
    ds = xr.load_dataset(tmp_path / "hang.nc")
    fz = ds["mooring_force"].sel(mooring_component=ds["mooring_force"]["mooring_component"][2]).values[:, 0]
    settled = fz[ds["time"].values > 3.0]
    assert settled.min() > 0                                  # the rope pulls the body up
    assert settled.mean() == pytest.approx(100.0 * 9.81, rel=0.02)


@pytest.mark.parametrize("reduce", [True, False])
def test_pto_to_ground_by_direction(reference_data, tmp_path, reduce):
    """A heave PTO given by direction = [0, 0, -1] (no anchor point): mean power against the
    frequency-domain 1/2 c w^2 |X|^2 with its spring in the restoring term; the same run with an
    anchor 50 m below gives the same motion and PTO outputs (a vertical line stays vertical in
    heave); tension = k z + c w and extension rate = w (moving up, away from the ground below,
    stretches the line)."""
    from hydrolink.clients.run import run_scene_file
    from hydrolink.server.hdb.io import load_hdb

    path = reference_data / "sphere_task10" / "sphere.h5"
    hdb = load_hdb(path)
    mass, heave, c_pto, k_pto, height = 261.724e3, 2, 2.0e5, 1.0e5, 1.0
    i = int(np.argmin(np.abs(hdb["omega"].values - 1.15)))
    w = float(hdb["omega"].values[i])
    a, b = hdb["added_mass"].values[i, heave, heave], hdb["radiation_damping"].values[i, heave, heave]
    f, c = hdb["excitation_force"].values[i, 0, heave], hdb["hydrostatic_stiffness"].values[heave, heave]
    x = f * height / 2 / (-w ** 2 * (mass + a) - 1j * w * (b + c_pto) + c + k_pto)
    period = 2 * math.pi / w
    out = {}
    for kind, pto in (("direction", linear_pto("pto", "sphere", [0, 0, 0], "ground", None, direction=[0, 0, -1],
                                                damping=c_pto, stiffness=k_pto)),
                      ("anchor", linear_pto("pto", "sphere", [0, 0, 0], "ground", [0, 0, -50],
                                            damping=c_pto, stiffness=k_pto))):
        scene = write_scene(tmp_path, scene_toml(
            dt=period / 100, duration=20 * period, progress=False, water={**SPHERE_WATER, "gravity": 9.81},
            waves=regular_waves(height, period, ramp=2 * period), client={"type": "exudyn", "reduce": reduce},
            bodies=[sphere_body(str(path), mass=mass, dofs=["heave"], inertia=None)], ptos=[pto]), f"{kind}.toml")
        run_scene_file(scene, tmp_path / f"{kind}.nc", progress=False)
        out[kind] = xr.load_dataset(tmp_path / f"{kind}.nc")
    ds = out["direction"]
    t = ds["time"].values
    sel = t > t[-1] - 4 * period + 1e-9
    assert ds["pto_power"].values[sel, 0].mean() == pytest.approx(0.5 * c_pto * w ** 2 * abs(x) ** 2, rel=0.02)
    z = ds["position"].sel(body="sphere", dof="heave").values - ds["position"].sel(body="sphere", dof="heave").values[0]
    v = ds["velocity"].sel(body="sphere", dof="heave").values
    np.testing.assert_allclose(ds["pto_velocity"].values[:, 0], v, rtol=1e-9, atol=1e-12)
    np.testing.assert_allclose(ds["pto_force"].values[:, 0], k_pto * z + c_pto * v, rtol=1e-9, atol=1e-6)
    for name in ("position", "pto_force", "pto_velocity", "pto_power"):   # to round-off of the series' scale
        ref = out["anchor"][name].values   # (the 50 m line's length differences: 7e-9 N of a 1e5 N force seen)
        np.testing.assert_allclose(ds[name].values, ref, rtol=1e-9, atol=1e-12 * max(1.0, np.abs(ref).max()))


def test_pto_direction_errors_name_the_key():
    def bad(**keys) -> str:
        with pytest.raises(Exception) as err:
            parse_scene(scene_toml(dt=0.1, duration=1.0, bodies=[body("b", mass=1.0, center_of_mass=[0, 0, 0],
                                                                         inertia=[1, 1, 1])],
                                   ptos=[{"name": "p", "type": "linear", "body1": "b", "point1": [0, 0, 0], **keys}]))
        return str(err.value)
    assert "ptos[0]: point2 or direction: give one" in bad(body2="ground")
    assert "ptos[0].direction: only for a PTO to ground" in bad(body2="b", direction=[0, 0, -1])
    assert "ptos[0].direction: along a global axis" in bad(body2="ground", direction=[0, 1, -1])
    assert "ptos[0].rest_length: not with direction" in bad(body2="ground", direction=[0, 0, 1], rest_length=2.0)
