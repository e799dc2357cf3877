"""Viscous damping on wet bodies (server/terms/viscous.py, issue 10): F = -B_lin v - B_quad v|v|.
The Task-10 sphere in heave, run through the whole co-simulation (server reply field ``viscous``,
Exudyn client), against a monolithic integration written here of
(m + A) x'' + (B + B_lin) x' + B_quad x'|x'| + C x = F_ex(t), with A, B, C and F_ex from the HDB."""

from __future__ import annotations

import math

import numpy as np
import pytest
import xarray as xr
from scipy.integrate import solve_ivp

from conftest import SPHERE_WATER, regular_waves, scene_toml, sphere_body, write_scene
from hydrolink.clients.run import run_scene_file
from hydrolink.protocol.scene import SceneError, parse_scene
from hydrolink.server.hdb.io import load_hdb

MASS, HEAVE = 261.724e3, 2
B_LIN, B_QUAD = 2.0e4, 8.0e4


def _hdb_heave(sphere_path, omega: float | None):
    hdb = load_hdb(sphere_path)
    c = float(hdb["hydrostatic_stiffness"].values[HEAVE, HEAVE])
    if omega is None:
        return hdb, c
    i = int(np.argmin(np.abs(hdb["omega"].values - omega)))
    return (hdb, c, float(hdb["omega"].values[i]), float(hdb["added_mass"].values[i, HEAVE, HEAVE]),
            float(hdb["radiation_damping"].values[i, HEAVE, HEAVE]), complex(hdb["excitation_force"].values[i, 0, HEAVE]))


def _run(tmp_path, sphere_path, name: str, **scene) -> xr.Dataset:
    path = write_scene(tmp_path, scene_toml(progress=False, water={**SPHERE_WATER, "gravity": 9.81}, **scene), name)
    run_scene_file(path, tmp_path / f"{name}.nc", progress=False)
    return xr.load_dataset(tmp_path / f"{name}.nc")


def test_regular_wave_heave_with_linear_and_quadratic_damping(tmp_path, sphere_path):
    hdb, c, w, a, b, x_exc = _hdb_heave(sphere_path, 1.15)
    period, height, ramp = 2 * math.pi / w, 2.0, 2 * 2 * math.pi / w
    dt = period / 200
    ds = _run(tmp_path, sphere_path, "waves", dt=dt, duration=25 * period, waves=regular_waves(height, period, ramp=ramp),
              hydro={"radiation": "constant"},
              bodies=[sphere_body(str(sphere_path), mass=MASS, dofs=["heave"], linear_damping=[0, 0, B_LIN, 0, 0, 0],
                                  quadratic_damping=[0, 0, B_QUAD, 0, 0, 0])])

    def force(t):
        r = 1.0 if t >= ramp else 0.5 * (1 - math.cos(math.pi * t / ramp))
        return r * (x_exc * height / 2 * np.exp(-1j * w * t)).real

    def rhs(t, y):
        x, v = y
        return [v, (force(t) - (b + B_LIN) * v - B_QUAD * v * abs(v) - c * x) / (MASS + a)]
    t = ds["time"].values
    ref = solve_ivp(rhs, (0, t[-1]), [0.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12, max_step=dt)
    z = ds["position"].sel(body="sphere", dof="heave").values - ds["position"].sel(body="sphere", dof="heave").values[0]
    last = t > t[-1] - 4 * period
    amp, amp_ref = 0.5 * np.ptp(z[last]), 0.5 * np.ptp(ref.y[0][last])
    undamped = abs(x_exc * height / 2 / (-w ** 2 * (MASS + a) - 1j * w * b + c))
    assert amp < 0.9 * undamped                       # the damping acts
    assert amp == pytest.approx(amp_ref, rel=5e-3)
    v = ds["velocity"].sel(body="sphere", dof="heave").values
    f = ds["viscous_force"].sel(body="sphere", dof="heave").values
    np.testing.assert_allclose(f[10:], -(B_LIN * v + B_QUAD * v * np.abs(v))[10:], rtol=0.02,
                               atol=1e-3 * np.abs(f).max())
    assert np.all(ds["viscous_power"].values >= -1e-6 * np.abs(ds["viscous_power"].values).max())


def test_free_decay_with_quadratic_damping(tmp_path, sphere_path):
    """Heave decay from 1 m in still water with quadratic damping, radiation off (A_inf in the mass):
    the envelope against the monolithic integration."""
    hdb, c = _hdb_heave(sphere_path, None)
    a_inf = float(hdb["added_mass_inf"].values[HEAVE, HEAVE])
    period = 2 * math.pi * math.sqrt((MASS + a_inf) / c)
    dt = period / 200
    ds = _run(tmp_path, sphere_path, "decay", dt=dt, duration=6 * period, hydro={"radiation": "off"},
              bodies=[sphere_body(str(sphere_path), mass=MASS, dofs=["heave"], quadratic_damping=[0, 0, B_QUAD * 5, 0, 0, 0],
                                  initial_displacement=[0, 0, 1.0, 0, 0, 0])])
    t = ds["time"].values
    ref = solve_ivp(lambda t, y: [y[1], (-5 * B_QUAD * y[1] * abs(y[1]) - c * y[0]) / (MASS + a_inf)], (0, t[-1]),
                    [1.0, 0.0], t_eval=t, rtol=1e-10, atol=1e-12, max_step=dt)
    z = ds["position"].sel(body="sphere", dof="heave").values - (ds["position"].sel(body="sphere", dof="heave").values[0] - 1.0)
    assert np.abs(z - ref.y[0]).max() < 5e-3 * 1.0
    assert abs(z[-1]) < 0.5                            # it decays


def test_viscous_keys_are_checked():
    def parse(**keys):
        return parse_scene(scene_toml(dt=0.1, duration=1.0, bodies=[sphere_body("s.h5", mass=1.0, **keys)]))
    with pytest.raises(SceneError, match=r"bodies\[0\]\.quadratic_damping: the diagonal must be >= 0"):
        parse(quadratic_damping=[0, 0, -1.0, 0, 0, 0])
    with pytest.raises(SceneError, match=r"bodies\[0\]\.linear_damping"):
        parse(linear_damping=[1.0, 2.0])
    assert parse(linear_damping=[[float(i == j) for j in range(6)] for i in range(6)]).bodies[0].damping_matrix(
        "linear_damping").trace() == 6.0


def test_relative_drag_at_rest_is_the_drag_of_the_wave_particle_velocity(sphere_path):
    """A body held at rest in a regular wave: the drag is 1/2 rho cd A |u| u of the Airy particle
    velocity at its reference point (200 m, k h > 20: deep water, u = a w e^{kz} (cos wt, 0, -sin wt) at x = 0),
    written in the test; absolute drag gives nothing at rest."""
    from hydrolink.server.model import HydroModel
    rho, height, period = 1000.0, 1.0, 6.0
    w = 2 * math.pi / period
    k = w ** 2 / 9.81
    cd, area = [1.0, 0.0, 0.8, 0.0, 0.0, 0.0], [40.0, 0.0, 78.5, 0.0, 0.0, 0.0]
    for relative in (True, False):
        scene = parse_scene(scene_toml(dt=0.05, duration=60.0, water={"density": rho, "depth": 200.0, "gravity": 9.81},
                                       waves=regular_waves(height, period),
                                       bodies=[sphere_body(str(sphere_path), mass=MASS, dofs=["surge", "heave"],
                                                           drag={"cd": cd, "area": area, "relative": relative})]))
        m = HydroModel(scene, {"sphere": load_hdb(sphere_path)})
        pos = m.setup_info().equilibrium_position
        z = float(pos[0, 2])
        for step in range(200):
            t = step * 0.05
            f = m.step(t, pos, np.zeros_like(pos))["viscous"][0]
            ux = 0.5 * height * w * math.exp(k * z) * math.cos(w * t)
            uz = -0.5 * height * w * math.exp(k * z) * math.sin(w * t)
            if relative:
                expect = [0.5 * rho * cd[0] * area[0] * abs(ux) * ux, 0.5 * rho * cd[2] * area[2] * abs(uz) * uz]
                np.testing.assert_allclose([f[0], f[2]], expect, rtol=1e-9, atol=1e-9 * (1 + abs(expect[0]) + abs(expect[1])))
            else:
                assert not np.any(f)
    assert abs(expect[0]) + abs(expect[1]) > 1.0


def test_a_run_with_drag_only_records_it(tmp_path, sphere_path):
    """A scene whose only viscous term is drag (relative): the run applies and records it, and the
    recorded force is -1/2 rho cd A |u| u of the recorded velocity minus the Airy particle velocity."""
    period, height = 6.0, 1.0
    w, rho = 2 * math.pi / period, 1000.0
    ds = _run(tmp_path, sphere_path, "drag", dt=0.05, duration=30.0, waves=regular_waves(height, period, ramp=6.0),
              bodies=[sphere_body(str(sphere_path), mass=MASS, dofs=["heave"],
                                  drag={"cd": [0, 0, 1.0, 0, 0, 0], "area": [0, 0, 78.5, 0, 0, 0]})])
    t = ds["time"].values
    v = ds["velocity"].sel(body="sphere", dof="heave").values
    z = float(ds["position"].sel(body="sphere", dof="heave").values[0])
    k = w ** 2 / 9.81
    ramp = np.where(t >= 6.0, 1.0, 0.5 * (1 - np.cos(np.pi * np.clip(t, 0, 6.0) / 6.0)))
    uz = -ramp * 0.5 * height * w * np.exp(k * z) * np.sin(w * t)
    u = v - uz
    f = ds["viscous_force"].sel(body="sphere", dof="heave").values
    later = t > 10.0
    np.testing.assert_allclose(f[later], (-0.5 * rho * 78.5 * np.abs(u) * u)[later], rtol=0.05,
                               atol=0.02 * np.abs(f).max())
    assert np.abs(f).max() > 100.0


def test_rm3_float_drag_against_the_lorentz_frequency_domain(tmp_path, reference_data):
    """RM3 (float and spar in heave, the linear PTO between them) at T = 8.06 s, H = 2.5 m, with
    quadratic drag on the float's heave (Cd 1 on its 20 m disc, absolute velocity): the run's float
    amplitude and mean PTO power against the two-body frequency domain with the drag replaced by
    Lorentz's equivalent linear damping B_eq = (8 / 3 pi) 1/2 rho Cd A w |X_f|, iterated to a fixed
    point, from the HDB's A(w), B(w), C, X(w) at that frequency (a grid point). The drag lowers
    the power by more than the test's tolerance."""
    from conftest import linear_pto, rm3_float, rm3_spar
    hdb = load_hdb(reference_data / "rm3_wamit" / "rm3.1")
    k = int(np.argmin(np.abs(hdb["omega"].values - 0.78)))
    w = float(hdb["omega"].values[k])
    rho, height, c_pto, cd, area = 1000.0, 2.5, 1.2e6, 1.0, math.pi * 10.0 ** 2
    heave = [2, 8]
    mass = np.diag([725833.0, 886687.0])
    a = hdb["added_mass"].values[k][np.ix_(heave, heave)]
    b = hdb["radiation_damping"].values[k][np.ix_(heave, heave)]
    c = hdb["hydrostatic_stiffness"].values[np.ix_(heave, heave)]
    f = hdb["excitation_force"].values[k, 0, heave] * height / 2
    b_pto = c_pto * np.array([[1.0, -1.0], [-1.0, 1.0]])

    def frequency_domain(drag: bool) -> tuple[np.ndarray, float]:
        b_eq = 0.0
        for _ in range(200):
            z = c - w * w * (mass + a) - 1j * w * (b + b_pto + np.diag([b_eq, 0.0]))
            x = np.linalg.solve(z, f)
            new = (8 / (3 * math.pi)) * 0.5 * rho * cd * area * w * abs(x[0]) if drag else 0.0
            if abs(new - b_eq) <= 1e-12 * max(new, 1.0):
                break
            b_eq = new
        return x, 0.5 * c_pto * w * w * abs(x[0] - x[1]) ** 2

    period = 2 * math.pi / w
    results = {}
    for drag in (False, True):
        keys = {"drag": {"cd": [0, 0, cd, 0, 0, 0], "area": [0, 0, area, 0, 0, 0], "relative": False}} if drag else {}
        path = write_scene(tmp_path, scene_toml(
            dt=0.05, duration=300.0, progress=False, water={"density": rho, "gravity": 9.81},
            waves=regular_waves(height, period, ramp=20.0), hydro={"irf_duration": 40.0},
            bodies=[rm3_float(str(reference_data / "rm3_wamit" / "rm3.1"), dofs=["heave"], **keys),
                    rm3_spar(str(reference_data / "rm3_wamit" / "rm3.1"), dofs=["heave"])],
            ptos=[linear_pto("pto", "float", [0.0, 0.0, -0.72], "spar", [0.0, 0.0, -21.29], damping=c_pto)]),
            f"rm3_drag{int(drag)}.toml")
        run_scene_file(path, tmp_path / f"rm3_drag{int(drag)}.nc", progress=False)
        ds = xr.load_dataset(tmp_path / f"rm3_drag{int(drag)}.nc")
        t = ds["time"].values
        late = t > t[-1] - 10 * period + 1e-9
        z = (ds["position"] - ds["equilibrium_position"]).sel(body="float", dof="heave").values[late]
        basis = np.c_[np.ones(late.sum()), np.cos(w * t[late]), np.sin(w * t[late])]
        fit = np.linalg.lstsq(basis, z, rcond=None)[0]
        amp, power = math.hypot(fit[1], fit[2]), float(ds["pto_power"].sel(pto="pto").values[late].mean())
        x, p = frequency_domain(drag)
        print(f"drag {drag}: float {amp:.4f} m (FD {abs(x[0]):.4f}, {amp / abs(x[0]) - 1:+.2e}), "
              f"P {power / 1e3:.1f} kW (FD {p / 1e3:.1f}, {power / p - 1:+.2e})")
        assert amp == pytest.approx(abs(x[0]), rel=0.005) and power == pytest.approx(p, rel=0.005)
        results[drag] = power
    assert results[True] < 0.95 * results[False]
