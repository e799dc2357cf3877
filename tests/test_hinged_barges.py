"""Hinged two-barge device (examples/hinged_barges, issue 3 device 3): the time-domain steady-state
heave of barge 2 in regular waves against a frequency-domain solution of the same linear model,
written here.

Frequency domain (exp(-iwt)), planar coordinates of both barges about their reference points
(the HDB's, = the waterplane centres (0, 0, 0) and (2.26, 0, 0)): q = (x1, z1, th1, x2, z2, th2)
(surge, heave, pitch), complex amplitudes per unit wave amplitude times 0.06 m:

    Z(w) = -w^2 (M + A) - i w (B + B_pto) + C + K_moor,      N^T Z N p = N^T X a,   q = N p

- M: each barge's rigid-body mass matrix moved to its reference point by hand:
  [[m, 0, m dz], [0, m, -m dx], [m dz, -m dx, I_yy + m (dx^2 + dz^2)]], d = CoG - reference.
- C: the HDB's hydrostatic stiffness (planar block, both barges) plus the gravity terms
  -m g (z_G - z_ref) on each barge's pitch diagonal.
- K_moor: 3.5e4 N/m on barge 1's surge (the mooring point is barge 1's reference point).
- Hinge: the displacement of the hinge point H = (0.78, 0, 0) is the same on both barges,
  u_i(H) = (x_i + th_i (H_z - r_iz), z_i - th_i (H_x - r_ix)); the 2 x 6 constraint matrix J has the
  null space N (6 x 4, scipy): the device has 4 DOFs (surge, heave, pitch of barge 1 and the
  relative rotation). Reactions do no work on N, so the projected equations N^T Z N are exact.
- PTO: a damper c = 850 N s/m on the extension rate of the line P1 = (0.35, 0, 0.1) (barge 1) ->
  P2 = (1.71, 0, 0.1) (barge 2), unit vector e = +x: extension = g q with
  g = e . (u_2(P2) - u_1(P1)), B_pto = c g^T g.
- X: the HDB's excitation at heading 0, A, B: see below. Re/im interpolated linearly in w (as the
  server does).

Which A(w), B(w): the assertions use the **effective** coefficients of the truncated, sampled
convolution the co-simulation actually performs,

    A_eff = A_inf - (1/w) sum_j w_j K(t_j) sin(w t_j) dt,   B_eff = sum_j w_j K(t_j) cos(w t_j) dt,

over t_j = 0 .. irf_duration (10 s) in steps of the run's dt (trapezoid weights w_j), with
K(t) = (2/pi) int_0^wmax B(w) cos(wt) dw integrated here by the trapezoid rule over the HDB's grid
(B(0) = 0 prepended) and A_inf the HDB's. That is the model the co-simulation realises, so the
comparison measures the co-simulation (server convolution, Exudyn hinge/PTO/mooring, coupling,
integration) and not the BEM grid. The HDB's own A(w), B(w) are a second reference, printed
(pytest -s) but not asserted: here the IRF truncation dominates at the top of the band. Barge 2's
damping is still ~18 % of its peak at the grid's 10.8 rad/s, and every radiation coefficient has a
narrow resonance at 9.0 rad/s (three grid points, e.g. barge 1 surge B = 1072 against ~300 around
it) that makes the trapezoid-rule K(t) ring beyond the 10 s memory. Body-2 heave is small there
(RAO 0.01-0.03: a near-cancellation), so the effective reference is 17 % above the HDB one at
7.85 rad/s and 0.2-1.3 % off it at 2.6-6.8 rad/s; the time domain follows the effective one to
< 0.3 % (examples/hinged_barges/README.md decomposes the difference).

Time domain: the example scene with its HDB replaced by the session's built file, dt = T/100,
a 30 s cosine ramp (barge 1 heaves on a damping plate: its heave-pitch modes near 1.4 and 2.1 rad/s
have almost no radiation damping and ring for minutes if the start excites them; the long ramp
keeps them < 0.05 %), 65 s in all; the steady state is fitted over the last ten periods
(a0 + a cos wt + b sin wt).
"""

from __future__ import annotations

import re
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg as sla
import xarray as xr

from hydrolink.protocol.scene import load_scene


REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "hinged_barges"
SPEC = EXAMPLE / "hinged_barges_hdb.toml"

AMPLITUDE = 0.06                            # m
OMEGAS = np.linspace(2.61, 7.85, 6)         # rad/s: 2.61, 3.658, 4.706, 5.754, 6.802, 7.85
STEPS_PER_PERIOD = 100
RAMP, DURATION, FIT_PERIODS = 30.0, 65.0, 10
IRF = 10.0                                  # s, the example's hydro.irf_duration

G = 9.81
M1, ZG1, IYY1 = 331.65, -0.511, 196.9       # barge 1 (+ plate): rho V, CoG z, pitch inertia at CoG
M2, ZG2, IYY2 = 128.0, -0.02, 66.82         # barge 2: rho V, uniform box
REF2 = np.array([2.26, 0.0, 0.0])           # barge 2's reference point (barge 1's is the origin)
HINGE = np.array([0.78, 0.0, 0.0])
P1, P2 = np.array([0.35, 0.0, 0.1]), np.array([1.71, 0.0, 0.1])
C_PTO, K_MOOR = 850.0, 3.5e4
PLANAR = [0, 2, 4, 6, 8, 10]                # surge, heave, pitch of both barges in the 12-DOF HDB


@pytest.fixture(scope="session")
def barges_hdb(tmp_path_factory):
    """The HDB built from the example's spec once per session (Capytaine, disk cache: ~20 s the
    first time), and a NetCDF copy the scenes point to."""
    from hydrolink.server.hdb.build.builder import build_hdb
    from hydrolink.protocol.hdb.schema import to_netcdf
    ds = build_hdb(SPEC, progress=False)
    path = tmp_path_factory.mktemp("hinged_barges") / "hinged_barges_hdb.nc"
    to_netcdf(ds, path)
    return ds, path


# -- frequency domain ----------------------------------------------------------------------------

def _at(hdb, w: float, values: np.ndarray) -> np.ndarray:
    """Linear interpolation in w of an (n_w, ...) array (complex: re and im separately)."""
    om = hdb["omega"].values
    flat = values.reshape(om.size, -1)
    out = [np.interp(w, om, flat[:, k].real) + 1j * np.interp(w, om, flat[:, k].imag)
           for k in range(flat.shape[1])]
    return np.array(out).reshape(values.shape[1:])


def hdb_radiation(hdb, w: float) -> tuple[np.ndarray, np.ndarray]:
    """The HDB's A(w), B(w) (planar 6 x 6)."""
    sel = np.ix_(range(hdb.sizes["omega"]), PLANAR, PLANAR)
    return _at(hdb, w, hdb["added_mass"].values[sel]).real, _at(hdb, w, hdb["radiation_damping"].values[sel]).real


def effective_radiation(hdb, w: float, irf: float, dt: float) -> tuple[np.ndarray, np.ndarray]:
    """A_eff, B_eff (planar 6 x 6) of the trapezoid convolution over [0, irf] with step dt."""
    om = np.r_[0.0, hdb["omega"].values]
    b = hdb["radiation_damping"].values[:, PLANAR][:, :, PLANAR]
    b = np.concatenate([np.zeros((1, 6, 6)), b])
    t = np.arange(int(round(irf / dt)) + 1) * dt
    k = np.array([2 / np.pi * np.trapezoid(b * np.cos(om * ti)[:, None, None], om, axis=0) for ti in t])
    wt = np.full(t.size, dt)
    wt[[0, -1]] *= 0.5
    a_inf = hdb["added_mass_inf"].values[np.ix_(PLANAR, PLANAR)]
    return (a_inf - np.tensordot(wt * np.sin(w * t), k, axes=(0, 0)) / w,
            np.tensordot(wt * np.cos(w * t), k, axes=(0, 0)))


def _rigid_mass(m: float, d: np.ndarray, iyy: float) -> np.ndarray:
    """Planar (surge, heave, pitch) mass matrix about a reference point, CoG at reference + d."""
    dx, _, dz = d
    return np.array([[m, 0.0, m * dz], [0.0, m, -m * dx], [m * dz, -m * dx, iyy + m * (dx * dx + dz * dz)]])


def _point_map(point: np.ndarray, ref: np.ndarray) -> np.ndarray:
    """(2 x 3) planar displacement (x, z) of a body-fixed point from (surge, heave, pitch) about ref:
    a pitch th about +y moves r = point - ref by th * (r_z, -r_x)."""
    rx, _, rz = point - ref
    return np.array([[1.0, 0.0, rz], [0.0, 1.0, -rx]])


def frequency_domain(hdb, w: float, a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Complex amplitudes q = (x1, z1, th1, x2, z2, th2) in the 0.06 m wave (see module docstring)."""
    mass = sla.block_diag(_rigid_mass(M1, np.array([0.0, 0.0, ZG1]), IYY1),
                          _rigid_mass(M2, np.array([0.0, 0.0, ZG2]), IYY2))
    c = hdb["hydrostatic_stiffness"].values[np.ix_(PLANAR, PLANAR)].copy()
    c[2, 2] -= M1 * G * ZG1
    c[5, 5] -= M2 * G * ZG2
    c[0, 0] += K_MOOR
    ref1 = np.zeros(3)
    jac = np.hstack([_point_map(HINGE, ref1), -_point_map(HINGE, REF2)])       # (2, 6)
    null = sla.null_space(jac)                                                  # (6, 4)
    e = (P2 - P1) / np.linalg.norm(P2 - P1)
    g = np.hstack([-e[[0, 2]] @ _point_map(P1, ref1), e[[0, 2]] @ _point_map(P2, REF2)])
    b_pto = C_PTO * np.outer(g, g)
    x_ex = _at(hdb, w, hdb["excitation_force"].values[:, 0, PLANAR])
    z = -w ** 2 * (mass + a) - 1j * w * (b + b_pto) + c
    p = np.linalg.solve(null.T @ z @ null, null.T @ x_ex * AMPLITUDE)
    return null @ p


# -- time domain ---------------------------------------------------------------------------------

def scene_text(hdb_path: Path, w: float) -> str:
    """The example scene at frequency w: dt = T/100, the test's ramp and duration, the built HDB."""
    period = 2 * np.pi / w
    text = (EXAMPLE / "scene.toml").read_text()
    subs = {"dt": period / STEPS_PER_PERIOD, "duration": DURATION, "period": period, "ramp": RAMP}
    for key, value in subs.items():
        text, n = re.subn(rf"(?m)^{key} = [0-9.eE+-]+", f"{key} = {float(value)!r}", text)
        assert n == 1, key
    text = text.replace("progress = true", "progress = false")
    assert text.count('"hinged_barges_hdb.toml"') == 2
    return text.replace('"hinged_barges_hdb.toml"', f'"{hdb_path.as_posix()}"')


def fit_harmonic(t: np.ndarray, z: np.ndarray, w: float, periods: int) -> complex:
    """Complex amplitude (exp(-iwt) convention) fitted over the last ``periods`` periods."""
    sel = t > t[-1] - periods * 2 * np.pi / w + 1e-9
    basis = np.c_[np.cos(w * t[sel]), np.sin(w * t[sel]), np.ones(sel.sum())]
    a, b, _ = np.linalg.lstsq(basis, z[sel], rcond=None)[0]
    return complex(a, b)


def test_example_scene_is_the_device(barges_hdb):
    """The example scene holds the device the reference above is written for."""
    hdb, _ = barges_hdb
    scene, _ = load_scene(EXAMPLE / "scene.toml")
    assert scene.water.density == hdb.attrs["rho"] == 1000.0 and scene.hydro.irf_duration == IRF
    assert scene.waves.height == pytest.approx(2 * AMPLITUDE)
    h = scene.hydro   # the plain truncated convolution the effective reference describes
    assert (h.interaction, h.radiation, h.irf_taper, h.irf_domega, h.irf_tail, h.coupling_tolerance) == (
        "full", "convolution", 0.0, None, "none", 0.0)
    b1, b2 = scene.bodies
    vol = hdb["displaced_volume"].sel(body=["barge1", "barge2"]).values
    assert [b1.mass, b2.mass] == pytest.approx(1000.0 * vol, rel=1e-4)   # rho V: floats at rest
    assert (b1.mass, b1.center_of_mass, b1.inertia[1]) == (M1, [0.0, 0.0, ZG1], IYY1)
    assert (b2.mass, b2.center_of_mass, b2.inertia[1]) == (M2, [REF2[0], 0.0, ZG2], IYY2)
    cob = hdb["center_of_buoyancy"].values                                # CoG above/below the CoB
    assert cob[:, 0] == pytest.approx([0.0, REF2[0]], abs=1e-9)
    assert hdb["reference_point"].values == pytest.approx(np.array([np.zeros(3), REF2]))
    assert b1.dofs == ["surge", "heave", "pitch"] and len(b2.dofs) == 6   # the hinge holds barge 2
    (joint,) = scene.joints
    assert (joint.type, joint.body1, joint.body2, joint.point, joint.axis) == (
        "revolute", "barge1", "barge2", list(HINGE), [0.0, 1.0, 0.0])
    (pto,) = scene.ptos
    assert (pto.type, pto.body1, pto.point1, pto.body2, pto.point2, pto.damping, pto.stiffness) == (
        "linear", "barge1", list(P1), "barge2", list(P2), C_PTO, 0.0)
    (moor,) = scene.moorings
    assert (moor.type, moor.body, moor.point, moor.stiffness) == (
        "linear", "barge1", [0.0, 0.0, 0.0], [K_MOOR, 0, 0, 0, 0, 0])


@pytest.mark.parametrize("w", [pytest.param(w, id=f"w={w:.3f}") for w in OMEGAS])
def test_body2_heave_matches_frequency_domain(barges_hdb, tmp_path, w):
    """hydrolink run (Exudyn client: hinge, PTO, mooring; embedded server) against the 4-DOF
    frequency-domain solution: barge 2 heave amplitude within 1 % and phase within 1 deg of the
    effective reference; the hinge holds (violation < 1e-9 m, barge 2 stays in the plane); the
    client's PTO power is c v^2 of the line's extension rate."""
    from hydrolink.clients.run import run_scene_file

    hdb, hdb_path = barges_hdb
    period = 2 * np.pi / w
    scene = tmp_path / "scene.toml"
    scene.write_text(scene_text(hdb_path, w))
    run_scene_file(scene, tmp_path / "out.nc", progress=False)
    ds = xr.load_dataset(tmp_path / "out.nc")
    assert ds.attrs["status"] == "complete"
    t = ds["time"].values
    disp = (ds["position"] - ds["equilibrium_position"]).sel(body=["barge1", "barge2"])
    q_td = np.array([fit_harmonic(t, disp.sel(body=b, dof=d).values, w, FIT_PERIODS)
                     for b in ("barge1", "barge2") for d in ("surge", "heave", "pitch")])

    q_eff = frequency_domain(hdb, w, *effective_radiation(hdb, w, IRF, period / STEPS_PER_PERIOD))
    q_hdb = frequency_domain(hdb, w, *hdb_radiation(hdb, w))
    z_td, z_eff, z_hdb = q_td[4], q_eff[4], q_hdb[4]
    err_eff, err_hdb = abs(z_td) / abs(z_eff) - 1, abs(z_td) / abs(z_hdb) - 1
    phase = float(np.degrees(np.angle(z_td / z_eff)))
    print(f"\nw = {w:.3f} rad/s: barge 2 heave TD {abs(z_td) * 1e3:.4f} mm (RAO {abs(z_td) / AMPLITUDE:.4f}); "
          f"FD effective {abs(z_eff) * 1e3:.4f} mm ({err_eff:+.2e}, phase {phase:+.2f} deg); "
          f"FD HDB {abs(z_hdb) * 1e3:.4f} mm ({err_hdb:+.2e}); HDB/effective {abs(z_hdb) / abs(z_eff) - 1:+.2e}")
    assert abs(err_eff) < 0.01
    assert abs(phase) < 1.0
    for k, name in enumerate(("x1", "z1", "th1", "x2", "z2", "th2")):
        print(f"  {name}: TD {abs(q_td[k]):.5g}, FD effective {abs(q_eff[k]):.5g} ({abs(q_td[k] / q_eff[k]) - 1:+.2e}), "
              f"HDB {abs(q_hdb[k]):.5g}")

    # the hinge: no violation, barge 2 held in the plane by barge 1 (whose sway/roll/yaw are locked)
    assert float(np.abs(ds["joint_violation"].values).max()) < 1e-9
    assert float(np.abs(disp.sel(body="barge2", dof=["sway", "roll", "yaw"]).values).max()) < 1e-9
    # PTO: the client's output is the damper's c v^2 on the extension rate; its mean against the
    # frequency domain's 1/2 c w^2 |extension|^2 (extension = 0.1 m x relative pitch, linearised)
    sel = t > t[-1] - FIT_PERIODS * period + 1e-9
    v = ds["pto_velocity"].sel(pto="pto").values
    power = ds["pto_power"].sel(pto="pto").values
    assert power[sel] == pytest.approx(C_PTO * v[sel] ** 2, rel=1e-9, abs=1e-15)
    p_fd = 0.5 * C_PTO * w ** 2 * abs((P1[2] - HINGE[2]) * (q_eff[5] - q_eff[2])) ** 2
    print(f"  mean PTO power TD {power[sel].mean() * 1e3:.4f} mW, FD effective {p_fd * 1e3:.4f} mW "
          f"({power[sel].mean() / p_fd - 1:+.2e})")
    assert power[sel].mean() == pytest.approx(p_fd, rel=0.02)


def test_plot_script(barges_hdb, tmp_path, monkeypatch):
    """examples/hinged_barges/plot.py on a two-frequency sweep (the full sweep is its default), run
    as its ``__main__`` in this process (runpy, its own argv): a child process would spend ~3 s of CPU
    importing what this one has loaded; the script, its options and its files are the same."""
    import runpy

    import matplotlib.pyplot as plt

    _, hdb_path = barges_hdb
    out = tmp_path / "rao.png"
    monkeypatch.setattr("sys.argv", [str(EXAMPLE / "plot.py"), "--omegas", "2.61,7.85", "--hdb", str(hdb_path),
                                     "-o", str(out), "--csv", str(tmp_path / "rao.csv")])
    try:
        runpy.run_path(str(EXAMPLE / "plot.py"), run_name="__main__")
    finally:
        plt.close("all")
    assert out.stat().st_size > 10_000
    rows = np.loadtxt(tmp_path / "rao.csv", delimiter=",", skiprows=1)
    assert rows.shape == (2, 4)
    assert rows[:, 1] == pytest.approx(rows[:, 2], rel=0.01)   # TD vs FD (effective) in the script
