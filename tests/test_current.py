"""The steady current (protocol/current.py, issue 23) against references written here: the profile
formulas; a fixed vertical Morison cylinder in current + regular waves against the strip integral
over depth (scipy quad; time mean and first harmonic); relative drag on a body; the mean offset of
``hydrolink steady`` against the current's drag over a surge spring; bad input."""

from __future__ import annotations

import math

import numpy as np
import pytest
from scipy.integrate import quad

from conftest import SPHERE_WATER, regular_waves, scene_toml, sphere_body
from hydrolink.protocol.current import Current
from hydrolink.protocol.scene import SceneError, parse_scene
from hydrolink.server.hdb.io import load_hdb
from hydrolink.server.model import HydroModel

RHO, G = 1000.0, 9.81


def profile(kind: str, u0: float, d: float | None, z: float) -> float:
    """The current's speed at height z, written from the definitions (issue 23, WEC-Sim's profiles)."""
    z = min(z, 0.0)
    if kind == "uniform":
        return u0
    if z < -d:
        return 0.0
    return u0 * (1 + z / d) ** (1 / 7) if kind == "power" else u0 * (1 + z / d)


@pytest.mark.parametrize("kind,depth", [("uniform", None), ("power", 30.0), ("linear", 15.0)])
def test_profile_values(kind, depth):
    c = Current(speed=1.5, direction=30.0, profile=kind, depth=depth)
    z = np.array([2.0, 0.0, -1.0, -7.5, -14.9, -15.0, -29.0, -30.0, -60.0])
    v = c.velocity(z)
    speed = np.array([profile(kind, 1.5, depth, float(zi)) for zi in z])
    np.testing.assert_allclose(v[:, 0], speed * math.cos(math.radians(30.0)), rtol=1e-14, atol=1e-15)
    np.testing.assert_allclose(v[:, 1], speed * math.sin(math.radians(30.0)), rtol=1e-14, atol=1e-15)
    assert np.all(v[:, 2] == 0.0)


def _model(sphere_path, current: dict | None, *, cd: float = 1.2, height: float = 2.0, period: float = 7.0,
           draft: float = 20.0, diameter: float = 2.0, drag: dict | None = None, dt: float = 0.05) -> HydroModel:
    """The Task-10 sphere as a carrier of a vertical member from 5 m above the water to ``draft``
    below, 30 m beside its centre (its own HDB forces are not looked at)."""
    body = sphere_body("x", mass=261.8e3) if drag is None else sphere_body("x", mass=261.8e3, drag=drag)
    body["hdb"] = str(sphere_path)
    scene = parse_scene(scene_toml(dt=dt, duration=100.0, water={**SPHERE_WATER, "gravity": G},
                                   waves=regular_waves(height, period), current=current, bodies=[body],
                                   morison=[{"body": "sphere", "point_a": [30.0, 0.0, 5.0],
                                             "point_b": [30.0, 0.0, -draft], "diameter": diameter, "cd": cd,
                                             "ca": 0.0, "segments": 500}]))
    return HydroModel(scene, {"sphere": load_hdb(sphere_path)})


@pytest.mark.parametrize("kind,depth,direction", [("uniform", None, 0.0), ("power", 30.0, 0.0),
                                                  ("linear", 15.0, 60.0)])
def test_fixed_vertical_cylinder_in_current_and_waves_against_the_strip_integral(sphere_path, kind, depth,
                                                                                  direction):
    """Deep water, u = a w e^{kz} cos(kx - wt) along x, the current U(z) (cos b, sin b): the drag per
    metre 1/2 rho Cd D |w| w with w = u + U over z in [-d, 0] (the member is fixed), integrated here
    with quad at 64 instants of a period; the model's force less its Froude-Krylov inertia (Cm = 1 at
    ca = 0, independent of the current) against it: time mean and first harmonic, surge and sway."""
    cd, period, height, diameter, draft, u0 = 1.2, 7.0, 2.0, 2.0, 20.0, 0.8
    current = {"speed": u0, "direction": direction, "profile": kind, **({"depth": depth} if depth else {})}
    n = 64
    same = dict(height=height, period=period, draft=draft, diameter=diameter, dt=period / n)
    m, still = _model(sphere_path, current, cd=cd, **same), _model(sphere_path, current, cd=0.0, **same)
    w, a = 2 * math.pi / period, height / 2
    k = w ** 2 / G
    b = math.radians(direction)
    pos = m.setup_info().equilibrium_position
    times = np.arange(n) * period / n
    got = np.array([m.step(t, pos, np.zeros_like(pos))["morison"][0, :3]
                    - still.step(t, pos, np.zeros_like(pos))["morison"][0, :3] for t in times])

    def strip(t: float, axis: int) -> float:
        def per_metre(z: float) -> float:
            u = a * w * math.exp(k * z) * math.cos(k * 30.0 - w * t)
            cur = profile(kind, u0, depth, z)
            wx, wy = u + cur * math.cos(b), cur * math.sin(b)
            return 0.5 * RHO * cd * diameter * math.hypot(wx, wy) * (wx, wy)[axis]
        return quad(per_metre, -draft, 0.0, points=[-depth] if depth and depth < draft else None,
                    epsabs=1e-9, epsrel=1e-11, limit=200)[0]

    ref = np.array([[strip(t, 0), strip(t, 1)] for t in times])
    scale = 0.5 * RHO * cd * diameter * (a * w + u0) ** 2 / k
    for axis in (0, 1):
        mean_ref, mean_got = ref[:, axis].mean(), got[:, axis].mean()
        h_ref, h_got = np.fft.rfft(ref[:, axis])[1] * 2 / n, np.fft.rfft(got[:, axis])[1] * 2 / n
        # measured: within 5e-7 of the scale (uniform: mean 18192.108 N against 18192.115 N)
        assert mean_got == pytest.approx(mean_ref, abs=1e-5 * scale), (axis, mean_got, mean_ref)
        assert abs(h_got - h_ref) < 1e-5 * scale, (axis, h_got, h_ref)
    assert abs(ref[:, 0].mean()) > 0.05 * scale            # the current makes a mean load
    assert np.abs(got[:, 2]).max() < 1e-9 * scale          # none along the member


def test_no_current_and_a_still_current_change_nothing(sphere_path):
    """Without [current], and with a current of speed 0, the Morison force is the same, bit for bit."""
    bare = _model(sphere_path, None)
    zero = _model(sphere_path, {"speed": 0.0, "profile": "power", "depth": 30.0})
    pos = bare.setup_info().equilibrium_position
    for t in np.arange(40) * 0.05:
        a = bare.step(t, pos, np.zeros_like(pos))["morison"]
        b = zero.step(t, pos, np.zeros_like(pos))["morison"]
        assert np.array_equal(a, b)


@pytest.mark.parametrize("relative", [True, False])
def test_body_drag_feels_the_current_only_when_relative(sphere_path, relative):
    """Still water, the body moving at v: F_i = -1/2 rho cd_i A_i |v_i - U_i| (v_i - U_i) with U the
    current at the reference point's depth when relative, else |v_i| v_i."""
    cd, area = [1.0, 0.8, 0.0, 0.0, 0.0, 0.0], [50.0, 40.0, 0.0, 0.0, 0.0, 0.0]
    u0, b = 1.1, math.radians(-40.0)
    body = sphere_body(str(sphere_path), mass=261.8e3, drag={"cd": cd, "area": area, "relative": relative})
    scene = parse_scene(scene_toml(dt=0.05, duration=10.0, water={**SPHERE_WATER, "gravity": G},
                                   current={"speed": u0, "direction": -40.0, "profile": "power", "depth": 50.0},
                                   bodies=[body]))
    m = HydroModel(scene, {"sphere": load_hdb(sphere_path)})
    pos = m.setup_info().equilibrium_position
    u0 = profile("power", u0, 50.0, float(pos[0, 2]))
    assert pos[0, 2] < -1.0 and u0 < 1.1                  # below the surface: less than U0
    vel = np.array([[0.3, -0.2, 0.0, 0.0, 0.0, 0.0]])
    f = m.step(0.0, pos, vel)["viscous"][0]
    u = np.array([u0 * math.cos(b), u0 * math.sin(b)]) if relative else np.zeros(2)
    rel = vel[0, :2] - u
    expect = -0.5 * RHO * np.array(cd[:2]) * np.array(area[:2]) * np.abs(rel) * rel
    np.testing.assert_allclose(f[:2], expect, rtol=1e-12)


def test_steady_mean_offset_is_the_current_drag_over_the_mooring_stiffness(sphere_path, tmp_path):
    """``hydrolink steady`` of the sphere in surge on a linear spring k, a vertical Morison member in
    a power-law current (waves of zero height): the body sits at F/k with F = 1/2 rho Cd D times the
    integral of U(z)^2 over the wetted length (quad here)."""
    import xarray as xr

    from conftest import write_scene
    from hydrolink.clients.analysis.steady import steady_scene_file

    cd, diameter, draft, u0, depth, k = 1.0, 3.0, 20.0, 1.5, 40.0, 2.0e4
    body = sphere_body(str(sphere_path), mass=261.8e3, dofs=["surge"])
    path = write_scene(tmp_path, scene_toml(
        dt=0.1, duration=10.0, progress=False, water={**SPHERE_WATER, "gravity": G},
        waves=regular_waves(0.0, 8.0), steady={"order": 3},
        current={"speed": u0, "profile": "power", "depth": depth}, bodies=[body],
        moorings=[{"type": "linear", "body": "sphere", "point": [0.0, 0.0, -2.0],
                   "stiffness": [k, 0, 0, 0, 0, 0]}],
        morison=[{"body": "sphere", "point_a": [0.0, 0.0, 5.0], "point_b": [0.0, 0.0, -draft],
                  "diameter": diameter, "cd": cd, "ca": 1.0, "segments": 500}]), "s.toml")
    steady_scene_file(path, tmp_path / "s.nc", progress=False)
    x = xr.load_dataset(tmp_path / "s.nc")["position"].sel(body="sphere", dof="surge").values
    force = 0.5 * RHO * cd * diameter * quad(lambda z: profile("power", u0, depth, z) ** 2, -draft, 0.0)[0]
    assert x.mean() == pytest.approx(force / k, rel=1e-6)       # measured 2.6e-8 (3.0966 m)
    assert np.ptp(x) < 1e-9 * force / k


def test_steady_refuses_a_current_on_an_unmoored_body(sphere_path, tmp_path):
    """Without the spring the current's drag has nothing to balance it: an error naming the key."""
    from conftest import write_scene
    from hydrolink.clients.analysis.steady import SteadyError, steady_scene_file

    path = write_scene(tmp_path, scene_toml(
        dt=0.1, duration=10.0, progress=False, water={**SPHERE_WATER, "gravity": G},
        waves=regular_waves(1.0, 8.0), steady={"order": 3}, current={"speed": 1.0},
        bodies=[sphere_body(str(sphere_path), mass=261.8e3, dofs=["surge"],
                            drag={"cd": [1.0, 0, 0, 0, 0, 0], "area": [50.0, 0, 0, 0, 0, 0]})]), "free.toml")
    with pytest.raises(SteadyError, match=r"bodies: a mean load of the force terms \(viscous: a current's drag"):
        steady_scene_file(path, tmp_path / "free.nc", progress=False)


def test_a_moordyn_file_with_its_own_water_kinematics_is_refused_with_a_current(tmp_path):
    """A MoorDyn file setting WaveKin (or Currents) with a scene [current]: which applies would be a
    guess; the error names the mooring's file key and the option."""
    pytest.importorskip("moordyn")
    from test_moordyn_mooring import moordyn_file

    from hydrolink.clients.exudyn.moordyn_mooring import load_moordyn_files

    text = moordyn_file(tmp_path / "lines.dat", [0.0], segments=10).read_text()
    (tmp_path / "lines.dat").write_text(text.replace("-- OPTIONS ----------------------\n",
                                                     "-- OPTIONS ----------------------\n2 Currents\n"))
    scene_text = scene_toml(dt=0.05, duration=1.0, current={"speed": 0.5},
                            bodies=[{"name": "float", "mass": 1e5, "center_of_mass": [0.0, 0.0, -2.0],
                                     "inertia": [1e6] * 3, "buoyancy_volume": 100.0}],
                            moorings=[{"type": "moordyn", "name": "m", "file": "lines.dat", "bodies": ["float"]}])
    path = tmp_path / "scene.toml"
    path.write_text(scene_text)
    with pytest.raises(SceneError, match=r"moorings\[0\]\.file.*sets its own water kinematics \(2 currents\)"):
        load_moordyn_files(parse_scene(scene_text, path), path)


def test_bad_current_is_named():
    def parse(current, water=None):
        return parse_scene(scene_toml(dt=0.1, duration=1.0, water=water, current=current,
                                      bodies=[sphere_body("s.h5", mass=1.0)]))
    for current, water, key in [({"speed": -1.0}, None, "current.speed"),
                                ({"speed": 1e300}, None, "current.speed"),
                                ({"speed": 1.0, "direction": 1e9}, None, "current.direction"),
                                ({"speed": 1.0, "profile": "power"}, None, "current.depth"),
                                ({"speed": 1.0, "depth": 10.0}, None, "current.depth"),
                                ({"speed": 1.0, "profile": "linear", "depth": 300.0}, {"depth": 200.0},
                                 "current.depth"),
                                ({"speed": 1.0, "profile": "log", "depth": 3.0}, None, "current.profile"),
                                ({"speed": 1.0, "doppler": [True]}, None, "current.doppler")]:
        with pytest.raises(SceneError, match=key.replace(".", r"\.")):
            parse(current, water)
    note = parse({"speed": 1.0}).notes
    assert note and note[0].startswith("current: nothing in this scene feels the current")


def test_moordyn_lines_in_current_against_standalone_moordyn_with_external_kinematics(tmp_path):
    """Three chain lines on a body held at rest, 60 s in a power-law current at 30 deg: hydrolink's
    MoorDyn system (its Currents grid file) against MoorDyn driven here directly with the same file
    set to external water kinematics (WaveKin = 1), given the profile written in this test at its
    nodes every step. Both start from MoorDyn's still-water initial-condition solve."""
    moordyn = pytest.importorskip("moordyn")
    from test_moordyn_mooring import DEPTH, RHO, Z0, moordyn_file, silenced

    from hydrolink.clients.exudyn.moordyn_mooring import MoorDynSystem, load_moordyn_files

    u0, direction, depth = 1.2, 30.0, 150.0
    b = math.radians(direction)
    moordyn_file(tmp_path / "lines.dat", [0.0, 120.0, 240.0], segments=24, dtm=2e-3)
    text = scene_toml(dt=0.05, duration=60.0, water={"density": RHO, "depth": DEPTH},
                      current={"speed": u0, "direction": direction, "profile": "power", "depth": depth},
                      bodies=[{"name": "float", "mass": 2.0e5, "center_of_mass": [0.0, 0.0, Z0],
                               "inertia": [1e7] * 3, "buoyancy_volume": 2.0e5 / RHO}],
                      moorings=[{"type": "moordyn", "name": "spread", "file": "lines.dat", "bodies": ["float"]}])
    path = tmp_path / "scene.toml"
    path.write_text(text)
    scene = parse_scene(text, path)
    pose = np.array([[0.0, 0.0, Z0, 0.0, 0.0, 0.0]])
    dt, n = 0.05, 1200

    def run(current) -> tuple[np.ndarray, np.ndarray]:
        system = MoorDynSystem(scene.moorings[0], load_moordyn_files(scene, path)[0], "moorings[0]", {"float": 0},
                               pose, current)
        system.start(pose)
        for k in range(n):
            loads = system.step(k * dt, dt, pose, pose)
        out = loads[0].copy(), np.r_[system.tensions(), system.end_forces()]
        system.close()
        return out

    loads, tensions = run(scene.current)
    still_loads, _ = run(None)

    # standalone: the same file with external kinematics, the current evaluated at the nodes
    ext = tmp_path / "ext"
    ext.mkdir()
    (ext / "lines.dat").write_text((tmp_path / "lines.dat").read_text().replace(
        "---------------------- OPTIONS ----------------------\n",
        "---------------------- OPTIONS ----------------------\n1 WaveKin\n"))
    x = [0.0, 0.0, Z0, 0.0, 0.0, 0.0]
    with silenced():
        m = moordyn.Create(str(ext / "lines.dat"))
        moordyn.Init(m, x, [0.0] * 6)
        moordyn.ExternalWaveKinInit(m)
        for k in range(n):
            r = np.asarray(moordyn.ExternalWaveKinGetCoordinates(m), float).reshape(-1, 3)
            speed = np.array([profile("power", u0, depth, z) for z in r[:, 2]])
            u = np.column_stack([speed * math.cos(b), speed * math.sin(b), np.zeros(len(r))])
            moordyn.ExternalWaveKinSet(m, u.tolist(), np.zeros_like(u).tolist(), k * dt)
            f = np.asarray(moordyn.Step(m, x, [0.0] * 6, k * dt, dt), float)
        lines = [moordyn.GetLine(m, i) for i in (1, 2, 3)]
        ref_tensions = np.array([math.hypot(*get(line, 24)) for get in (moordyn.GetLineNodeTen, moordyn.GetLineNodeForce)
                                 for line in lines])
        moordyn.Close(m)
    change = np.linalg.norm(f[:2] - still_loads[:2])
    assert change > 0.03 * np.linalg.norm(still_loads[:3])          # the current matters (4 %: 21 kN of 483 kN)
    # measured: horizontal load 18001.01 N vs 18001.15 N, fairlead tensions and end forces within 3e-7
    assert np.linalg.norm(loads[:2] - f[:2]) < 1e-3 * change, (loads[:3], f[:3], still_loads[:3])
    np.testing.assert_allclose(loads[2:], f[2:], rtol=1e-4, atol=1e-3 * change)
    np.testing.assert_allclose(tensions, ref_tensions, rtol=1e-5)
    # the mean horizontal load lies along the current
    dx = loads[:2] - still_loads[:2]
    assert math.degrees(math.atan2(dx[1], dx[0])) == pytest.approx(direction, abs=3.0)
