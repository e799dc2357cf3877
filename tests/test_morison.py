"""Morison elements (server/terms/morison.py): a fixed vertical surface-piercing cylinder in regular
waves, its inline force against the closed-form Morison integrals over depth written here
(inertia and drag parts separately); the member's added mass in the body's mass matrix; bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.optimize import brentq

from conftest import SPHERE_WATER, regular_waves, scene_toml, sphere_body
from hydrolink.server import compiler
from hydrolink.protocol.scene import SceneError, parse_scene
from hydrolink.server.hdb.io import load_hdb
from hydrolink.server.model import HydroModel

RHO, G, DEPTH = 1000.0, 9.81, 200.0     # the Task-10 sphere's water (deep for these waves: k h > 20)


def model(sphere_path, *, cd: float, ca: float, diameter: float = 2.0, draft: float = 20.0, segments: int = 400,
          period: float = 7.0, height: float = 2.0) -> HydroModel:
    """The sphere (a carrier: its HDB forces are not looked at) with a vertical member from 5 m above
    the water to ``draft`` below, 30 m beside its centre."""
    scene = parse_scene(scene_toml(dt=0.05, duration=100.0, water={**SPHERE_WATER, "gravity": G},
                                   waves=regular_waves(height, period),
                                   bodies=[sphere_body(str(sphere_path), mass=261.8e3)],
                                   morison=[{"body": "sphere", "point_a": [30.0, 0.0, 5.0],
                                             "point_b": [30.0, 0.0, -draft], "diameter": diameter, "cd": cd,
                                             "ca": ca, "segments": segments}]))
    return HydroModel(scene, {"sphere": load_hdb(sphere_path)})


@pytest.mark.parametrize("part", ["inertia", "drag"])
def test_fixed_vertical_cylinder_against_the_morison_integral(sphere_path, part):
    """Deep water, eta = a cos(k x - w t), u = a w e^{kz} cos, du/dt = a w^2 e^{kz} sin over z in
    [-d, 0]: inertia F = rho Cm (pi D^2/4) a w^2 (1 - e^{-kd}) / k sin(kx - wt); drag
    F = 1/2 rho Cd D (a w)^2 (1 - e^{-2kd}) / (2k) |cos| cos. The moment about the reference point
    is the same integrals weighted by the lever arm (checked through the pitch moment)."""
    cd, ca = (0.0, 1.0) if part == "inertia" else (1.2, 0.0)
    period, height, diameter, draft = 7.0, 2.0, 2.0, 20.0
    m = model(sphere_path, cd=cd, ca=ca, diameter=diameter, draft=draft, period=period, height=height)
    w, a = 2 * math.pi / period, height / 2
    k = w ** 2 / G
    pos = m.setup_info().equilibrium_position
    for step in range(140):
        t = step * 0.05
        f = m.step(t, pos, np.zeros_like(pos))["morison"][0]
        if step % 7:
            continue
        theta = k * 30.0 - w * t
        inertia = RHO * (1 + ca) * math.pi * diameter ** 2 / 4 * a * w ** 2 * (1 - math.exp(-k * draft)) / k * math.sin(theta)
        drag = 0.5 * RHO * cd * diameter * (a * w) ** 2 * (1 - math.exp(-2 * k * draft)) / (2 * k) \
            * abs(math.cos(theta)) * math.cos(theta)
        # the drag part: what the member gets beyond the Froude-Krylov inertia (Cm = 1 at ca = 0)
        got, expect = (f[0], inertia) if part == "inertia" else (f[0] - inertia, drag)
        scale = RHO * math.pi * diameter ** 2 / 4 * a * w ** 2 / k if part == "inertia" else 0.5 * RHO * cd * diameter * (a * w) ** 2 / (2 * k)
        assert got == pytest.approx(expect, abs=2e-3 * scale), (t, got, expect)
        assert abs(f[1]) < 1e-9 * scale and abs(f[2]) < 1e-9 * scale   # no vertical force on a vertical member


def test_the_members_added_mass_is_in_the_mass_matrix(sphere_path):
    """rho ca V of the wetted length on the surge and sway (normal) directions, with its lever arm
    into the rotations (surge-pitch coupling rho ca A int z dz about the reference point)."""
    base = model(sphere_path, cd=0.0, ca=0.0).setup_info().added_mass
    with_ca = model(sphere_path, cd=0.0, ca=1.0).setup_info().added_mass
    d = with_ca - base
    area, draft = math.pi * 2.0 ** 2 / 4, 20.0
    assert d[0, 0] == pytest.approx(RHO * area * draft, rel=1e-9)
    assert d[1, 1] == pytest.approx(RHO * area * draft, rel=1e-9)
    assert abs(d[2, 2]) < 1e-6                                             # not along the axis
    zref = float(model(sphere_path, cd=0.0, ca=0.0).setup_info().equilibrium_position[0, 2])
    # surge-pitch: f = -m a, moment about y of a force along x at height z: (z - zref) f_x
    assert d[4, 0] == pytest.approx(RHO * area * (-draft ** 2 / 2 - zref * draft), rel=1e-6)


@pytest.mark.parametrize("compiled", [False, pytest.param(True, marks=pytest.mark.skipif(
    not compiler.AVAILABLE, reason="numba not installed"))])
def test_a_slanted_member_on_a_moving_body_against_the_strip_sum(sphere_path, compiled):
    """A member slanted in x, y and z through the water line, on the sphere moving in all six DOFs
    (displaced and with velocity and angular velocity), by numpy and by the compiled kernel
    (server/terms/morison_kernel.py): the reply against Morison's equation
    evaluated here segment by segment, Airy kinematics in 200 m of water (dispersion solved with
    brentq) at each segment's centre (at rest:
    the segments' mean positions), the normal parts by (I - t t^T), the segment's velocity
    v + omega x r, wet while the displaced centre is below z = 0 (heave, roll, pitch), and the
    moments about the reference point."""
    cd, ca, diameter, n = 0.9, 0.8, 1.5, 23
    a_pt, b_pt = np.array([3.0, -4.0, 2.0]), np.array([12.0, 5.0, -9.0])
    height, period = 2.0, 7.0
    scene = parse_scene(scene_toml(dt=0.05, duration=100.0, water={**SPHERE_WATER, "gravity": G},
                                   waves=regular_waves(height, period, phase=40.0),
                                   bodies=[sphere_body(str(sphere_path), mass=261.8e3)],
                                   morison=[{"body": "sphere", "point_a": a_pt.tolist(), "point_b": b_pt.tolist(),
                                             "diameter": diameter, "cd": cd, "ca": ca, "segments": n}]))
    m = HydroModel(scene, {"sphere": load_hdb(sphere_path)})
    next(t for t in m.terms if t.name == "morison").members.compiled = compiled
    eq = m.setup_info().equilibrium_position
    ref = eq[0, :3]
    w, amp, phi, depth = 2 * math.pi / period, height / 2, math.radians(40.0), SPHERE_WATER["depth"]
    k = brentq(lambda k: G * k * math.tanh(k * depth) - w ** 2, 1e-6, 10.0)
    axis = (b_pt - a_pt) / np.linalg.norm(b_pt - a_pt)
    normal = np.eye(3) - np.outer(axis, axis)
    length = np.linalg.norm(b_pt - a_pt) / n
    vol = math.pi * diameter ** 2 / 4 * length
    rng = np.random.default_rng(3)
    for step in range(60):
        t = step * 0.05
        x = rng.normal(size=6) * [0.5, 0.5, 0.8, 0.05, 0.05, 0.1]
        v = rng.normal(size=6) * [0.5, 0.5, 0.5, 0.1, 0.1, 0.1]
        got = m.step(t, eq + x, v[None, :])["morison"][0]
        expect = np.zeros(6)
        for s in range(n):
            c = a_pt + (s + 0.5) / n * (b_pt - a_pt)
            r = c - ref
            if c[2] + x[2] + x[3] * r[1] - x[4] * r[0] > 0.0:
                continue
            theta = k * c[0] - w * t + phi
            zc = min(c[2], 0.0)
            ch, sh = (math.cosh(k * (zc + depth)) / math.sinh(k * depth), math.sinh(k * (zc + depth)) / math.sinh(k * depth))
            u = amp * w * np.array([ch * math.cos(theta), 0.0, sh * math.sin(theta)])
            du = amp * w * w * np.array([ch * math.sin(theta), 0.0, -sh * math.cos(theta)])
            rel = normal @ (u - v[:3] - np.cross(v[3:], r))
            f = RHO * (1 + ca) * vol * (normal @ du) + 0.5 * RHO * cd * diameter * length * np.linalg.norm(rel) * rel
            expect += np.concatenate([f, np.cross(r, f)])
        scale = np.abs(expect).max()
        np.testing.assert_allclose(got, expect, rtol=0, atol=1e-12 * scale)


def test_bad_members_are_named():
    def parse(**member):
        return parse_scene(scene_toml(dt=0.1, duration=1.0, bodies=[sphere_body("s.h5", mass=1.0)],
                                      morison=[{"body": "sphere", "point_a": [0, 0, -1], "point_b": [0, 0, -5],
                                                "diameter": 1.0, "cd": 1.0, **member}]))
    with pytest.raises(SceneError, match=r"morison\[0\]\.cd: Input should be greater than or equal to 0"):
        parse(cd=-1.0)
    with pytest.raises(SceneError, match=r"morison\[0\]: the member lies above the still water line"):
        parse(point_a=[0, 0, 1.0], point_b=[0, 0, 3.0])
    with pytest.raises(SceneError, match=r"morison\[0\]\.body: no body named 'hull'"):
        parse(body="hull")
    with pytest.raises(SceneError, match=r"morison\[0\]\.point_b: must differ from point_a"):
        parse(point_b=[0, 0, -1])


def test_a_run_with_a_horizontal_member_against_a_monolithic_integration(sphere_path, tmp_path):
    """The sphere in heave with a horizontal member (10 m long, D 1 m, 5 m deep, ca 1, cd 0) in a
    regular wave: the co-simulation (member force in the reply, its added mass in the client's mass)
    against (m + A + rho ca V) z'' + B z' + C z = F_ex + rho (1 + ca) V <a_z> written here, <a_z> the
    fluid's vertical acceleration averaged over the member: -a w^2 e^{kz} (2 sin(kL/2) / (k L))."""
    import xarray as xr
    from scipy.integrate import solve_ivp

    from conftest import write_scene
    from hydrolink.clients.run import run_scene_file
    mass, height, length, diameter, depth_m = 261.724e3, 1.0, 10.0, 1.0, -5.0
    hdb = load_hdb(sphere_path)
    i = int(np.argmin(np.abs(hdb["omega"].values - 1.0)))
    w = float(hdb["omega"].values[i])
    a_33, b_33 = float(hdb["added_mass"].values[i, 2, 2]), float(hdb["radiation_damping"].values[i, 2, 2])
    x_exc, c = complex(hdb["excitation_force"].values[i, 0, 2]), float(hdb["hydrostatic_stiffness"].values[2, 2])
    period = 2 * math.pi / w
    k = w ** 2 / G
    vol = math.pi * diameter ** 2 / 4 * length
    path = write_scene(tmp_path, scene_toml(
        dt=period / 200, duration=20 * period, progress=False, water={**SPHERE_WATER, "gravity": G},
        waves=regular_waves(height, period, ramp=2 * period), hydro={"radiation": "constant"},
        bodies=[sphere_body(str(sphere_path), mass=mass, dofs=["heave"])],
        morison=[{"body": "sphere", "point_a": [-length / 2, 0.0, depth_m], "point_b": [length / 2, 0.0, depth_m],
                  "diameter": diameter, "cd": 0.0, "ca": 1.0, "segments": 100}]), "s.toml")
    run_scene_file(path, tmp_path / "s.nc", progress=False)
    ds = xr.load_dataset(tmp_path / "s.nc")
    a = height / 2
    f_mor = RHO * 2.0 * vol * (-a * w ** 2 * math.exp(k * depth_m) * 2 * math.sin(k * length / 2) / (k * length))
    ramp = 2 * period

    def rhs(t, y):
        r = 1.0 if t >= ramp else 0.5 * (1 - math.cos(math.pi * t / ramp))
        f = r * ((x_exc * a + f_mor) * np.exp(-1j * w * t)).real
        return [y[1], (f - b_33 * y[1] - c * y[0]) / (mass + a_33 + RHO * 1.0 * vol)]
    t = ds["time"].values
    ref = solve_ivp(rhs, (0, t[-1]), [0.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12, max_step=period / 200)
    z = ds["position"].sel(body="sphere", dof="heave").values
    z = z - z[0]
    last = t > t[-1] - 4 * period
    assert 0.5 * np.ptp(z[last]) == pytest.approx(0.5 * np.ptp(ref.y[0][last]), rel=5e-3)
    fz = ds["morison_force"].sel(body="sphere", dof="heave").values
    assert np.abs(fz[last]).max() == pytest.approx(abs(f_mor), rel=5e-3)


def test_a_morison_only_body_without_an_hdb(tmp_path):
    """A neutrally buoyant horizontal pontoon with no HDB (a dry body carrying a member: L 12 m,
    D 1.2 m along y, 6 m deep, Cd 1.2, Ca 1), held by a linear mooring in surge and heave, in a
    regular wave travelling along x (every segment sees the same wave): the co-simulation against
    the monolithic 2-DOF integration written here,
    (m + rho Ca V) x'' = -K x + rho (1 + Ca) V a(t) + 1/2 rho Cd D L |w| w,  w = u(t) - x'
    in the (x, z) plane normal to the member, u and a the Airy particle velocity and acceleration
    at the member (deep water: e^{kz}). The pontoon's weight and buoyancy are the client's, as for
    any dry body; the server serves it with Morison forces only."""
    import xarray as xr
    from scipy.integrate import solve_ivp

    from conftest import body, write_scene
    from hydrolink.clients.run import run_scene_file
    length, diameter, depth_m, cd, ca = 12.0, 1.2, -6.0, 1.2, 1.0
    vol = math.pi * diameter ** 2 / 4 * length
    mass, k_x, k_z = RHO * vol, 4.0e4, 6.0e4
    period, height = 6.0, 2.0
    w, a = 2 * math.pi / period, height / 2
    k = w ** 2 / G
    ramp = 2 * period
    pontoon = body("pontoon", mass=mass, center_of_mass=[0.0, 0.0, depth_m], inertia=[1e4, 1e4, 1e4],
                   dofs=["surge", "heave"], buoyancy_volume=vol)
    path = write_scene(tmp_path, scene_toml(
        dt=period / 200, duration=12 * period, progress=False, water={**SPHERE_WATER, "gravity": G},
        waves=regular_waves(height, period, ramp=ramp), bodies=[pontoon],
        moorings=[{"type": "linear", "body": "pontoon", "point": [0.0, 0.0, depth_m],
                   "stiffness": [k_x, 0.0, k_z, 0.0, 0.0, 0.0]}],
        morison=[{"body": "pontoon", "point_a": [0.0, -length / 2, depth_m], "point_b": [0.0, length / 2, depth_m],
                  "diameter": diameter, "cd": cd, "ca": ca, "segments": 24}]), "pontoon.toml")
    run_scene_file(path, tmp_path / "pontoon.nc", progress=False)
    ds = xr.load_dataset(tmp_path / "pontoon.nc")
    decay = math.exp(k * depth_m)

    def rhs(t, y):
        r = 1.0 if t >= ramp else 0.5 * (1 - math.cos(math.pi * t / ramp))
        u = r * a * w * decay * np.array([math.cos(w * t), -math.sin(w * t)])
        acc = r * a * w * w * decay * np.array([-math.sin(w * t), -math.cos(w * t)])
        rel = u - y[2:]
        f = RHO * (1 + ca) * vol * acc + 0.5 * RHO * cd * diameter * length * np.hypot(*rel) * rel
        f -= np.array([k_x, k_z]) * y[:2]
        return [y[2], y[3], *(f / (mass + RHO * ca * vol))]
    t = ds["time"].values
    ref = solve_ivp(rhs, (0, t[-1]), [0.0, 0.0, 0.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12, max_step=period / 200)
    last = t > t[-1] - 4 * period
    for j, dof in enumerate(("surge", "heave")):
        x = (ds["position"] - ds["equilibrium_position"]).sel(body="pontoon", dof=dof).values
        assert 0.5 * np.ptp(x[last]) == pytest.approx(0.5 * np.ptp(ref.y[j][last]), rel=5e-3)
        assert np.abs(x - ref.y[j]).max() < 0.01 * np.ptp(ref.y[j][last])
    assert np.abs(ds["morison_force"].sel(body="pontoon", dof="heave").values).max() > 0.1 * mass
    # no HDB: nothing else from the server
    assert np.abs(ds["excitation_force"].sel(body="pontoon").values).max() == 0.0
    assert np.abs(ds["radiation_force"].sel(body="pontoon").values).max() == 0.0
    # hydrolink steady on the same scene: its members' loads are all the forcing there is
    from hydrolink.clients.analysis.steady import steady_scene_file
    steady_scene_file(path, tmp_path / "steady.nc", progress=False)
    st = xr.load_dataset(tmp_path / "steady.nc")
    for j, dof in enumerate(("surge", "heave")):
        x = (st["position"] - st["equilibrium_position"]).sel(body="pontoon", dof=dof).values
        assert 0.5 * np.ptp(x) == pytest.approx(0.5 * np.ptp(ref.y[j][last]), rel=5e-3)
