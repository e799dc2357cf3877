"""The loads along a body over a run (clients/lockstep/section_results.py on server/loads/sections.py):
a free rigid box barge in regular head waves, radiation "constant" (A and B at the wave's frequency:
the frequency-domain solution is then the exact reference). The reference is written here: Capytaine
solves the box's radiation and diffraction at that frequency (pressures kept), the test's own
equation of motion gives the RAO, and the complex amplitude of each station's load sums, panel by
panel over the part beyond it, the incident, diffracted, radiated and hydrostatic pressure of that
motion, the weight turning with the body and the mass line's inertia. The run's steady amplitude and
phase at each station must match; the loads at both free ends must vanish to the discretization."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from conftest import body, box_build_spec, regular_waves, scene_toml, unit_rigid_motions
from hydrolink.clients.run import run_scene_file
from hydrolink.server.errors import ModelError
from hydrolink.server.hdb.build.builder import build_hdb, load_spec, make_meshes

RHO, G = 1025.0, 9.81
L, B, T = 20.0, 6.0, 2.0
MASS = RHO * L * B * T
PER_M = MASS / L
OWN = [PER_M * (B ** 2 + T ** 2) / 12, PER_M * T ** 2 / 12, PER_M * B ** 2 / 12]   # kg m^2/m about x, y, z
INERTIA = [OWN[0] * L, MASS * L ** 2 / 12 + OWN[1] * L, MASS * L ** 2 / 12 + OWN[2] * L]
Z_G = -0.5
W0 = 0.8
STATIONS = [-10.0, -6.0, -2.0, 0.0, 4.0, 8.0, 10.0]
SPEC = box_build_spec(name="barge", length=L, width=B, draft=T, panel_size=1.0, density=RHO,
                      frequencies=f"values = [0.6, {W0}, 1.0]")




def gauss_points(mesh) -> tuple[np.ndarray, np.ndarray]:
    """(P, 4, 3) the 2 x 2 Gauss points of each (bilinear) quadrilateral panel and (P, 4) their weights
    (the panel's area element): exact for a pressure linear in r on flat panels."""
    merged = mesh.merged() if hasattr(mesh, "merged") else mesh                # (a symmetric mesh as one)
    v = np.asarray(merged.vertices)[np.asarray(merged.faces)]                  # (P, 4, 3)
    g = 1 / math.sqrt(3)
    points, weights = [], []
    for xi, eta in ((-g, -g), (g, -g), (g, g), (-g, g)):
        shape = np.array([(1 - xi) * (1 - eta), (1 + xi) * (1 - eta), (1 + xi) * (1 + eta), (1 - xi) * (1 + eta)]) / 4
        d_xi = np.array([-(1 - eta), 1 - eta, 1 + eta, -(1 + eta)]) / 4
        d_eta = np.array([-(1 - xi), -(1 + xi), 1 + xi, 1 - xi]) / 4
        points.append(np.einsum("k,pkj->pj", shape, v))
        weights.append(np.linalg.norm(np.cross(np.einsum("k,pkj->pj", d_xi, v), np.einsum("k,pkj->pj", d_eta, v)),
                                      axis=1))
    points, weights = np.stack(points, axis=1), np.stack(weights, axis=1)
    assert np.abs(np.einsum("pg,pgk->pk", weights, points) / weights.sum(axis=1)[:, None]
                  - mesh.faces_centers).max() < 1e-9                          # the panels' order is the solver's
    return points, weights


def reference(spec: Path, heading: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The test's frequency-domain solution at W0: the RAO (6,), each station's load amplitude (S, 6)
    and the largest inertia load of a part along the body (6,) (what the water's load nearly cancels),
    per metre of wave amplitude, exp(-iwt)."""
    import capytaine as cpt
    from capytaine.bem.airy_waves import airy_waves_pressure

    hull, lid = make_meshes(load_spec(spec), spec)
    fb = cpt.FloatingBody(mesh=hull, lid_mesh=lid, dofs=cpt.rigid_body_dofs(rotation_center=(0, 0, 0)))
    solver = cpt.BEMSolver()
    common = dict(body=fb, omega=W0, rho=RHO, g=G, water_depth=math.inf)
    rad = [solver.solve(cpt.RadiationProblem(radiating_dof=d, **common), keep_details=True) for d in fb.dofs]
    dif = solver.solve(cpt.DiffractionProblem(wave_direction=heading, **common), keep_details=True)
    mask = fb.hull_mask
    c, n, ds = hull.faces_centers, hull.faces_normals, hull.faces_areas
    # generalized forces -sum p (V . n) dS of the unit motions, as complex amplitudes
    modes = unit_rigid_motions(c)
    vn = np.einsum("mpk,pk->mp", modes, n) * ds
    p_rad = np.array([np.asarray(r.pressure)[mask] for r in rad])           # (6, P) per unit displacement
    p_exc = np.asarray(dif.pressure)[mask] + airy_waves_pressure(c, dif.problem)
    f_rad, f_exc = -(p_rad @ vn.T).T, -(vn @ p_exc)                          # (6, 6) [i, j], (6,)
    # hydrostatics and gravity about the origin, the test's own: rho g (A_wp, S, I) and m g z_G, rho g V z_B
    m = np.diag([MASS] * 3 + [INERTIA[0] + MASS * Z_G ** 2, INERTIA[1] + MASS * Z_G ** 2, INERTIA[2]])  # about the origin
    m[:3, 3:] = MASS * np.array([[0, Z_G, 0], [-Z_G, 0, 0], [0, 0, 0]])
    m[3:, :3] = m[:3, 3:].T
    c_mat = np.zeros((6, 6))
    c_mat[2, 2] = RHO * G * L * B
    c_mat[3, 3] = RHO * G * (L * B ** 3 / 12) + RHO * G * L * B * T * (-T / 2) - MASS * G * Z_G
    c_mat[4, 4] = RHO * G * (B * L ** 3 / 12) + RHO * G * L * B * T * (-T / 2) - MASS * G * Z_G
    z = -W0 ** 2 * m - f_rad + c_mat                                         # F_rad = f_rad X (unit displacement)
    rao = np.linalg.solve(z, f_exc)
    # each station: the load = m_P a_P - (water + weight) on the part beyond, panel by panel here
    x = rao
    p = p_exc + x @ p_rad                                        # the panels' wave pressure (constant per panel)
    gauss, area_el = gauss_points(hull)                          # the hydrostatic one is linear: 2 x 2 Gauss points
    p_hs = -RHO * G * (x[2] + x[3] * gauss[..., 1] - x[4] * gauss[..., 0])   # (P, 4)
    acc = -W0 ** 2 * x
    loads, terms = [], []
    for s in STATIONS:
        beyond = (c[:, 0] > s) | (np.isclose(c[:, 0], s) & (n[:, 0] < 0))
        point = np.array([s, 0.0, Z_G])
        f_w = -(p[beyond, None] * n[beyond] * ds[beyond, None]).sum(axis=0)
        m_w = -(p[beyond, None] * np.cross(c[beyond] - point, n[beyond]) * ds[beyond, None]).sum(axis=0)
        hs = (p_hs * area_el)[beyond]                                                # (P', 4)
        f_w -= np.einsum("pg,pk->k", hs, n[beyond])
        m_w -= np.einsum("pg,pgk->k", hs, np.cross(gauss[beyond] - point, n[beyond][:, None, :]))
        lo = max(s, -L / 2)
        m_p = PER_M * (L / 2 - lo)
        g_p = np.array([(lo + L / 2) / 2, 0.0, Z_G])
        lever = g_p - point
        weight = m_p * G * np.array([x[4], -x[3], 0.0])                       # m (g - theta x g), its change
        a_g = acc[:3] + np.cross(acc[3:], g_p)
        length = L / 2 - lo
        i_p = np.diag([OWN[0] * length, OWN[1] * length + m_p * length ** 2 / 12,
                       OWN[2] * length + m_p * length ** 2 / 12])
        force = m_p * a_g - f_w - weight
        moment = i_p @ acc[3:] + np.cross(lever, m_p * a_g) - m_w - np.cross(lever, weight)
        loads.append(np.r_[force, moment])
        terms.append(np.abs(np.r_[m_p * a_g, i_p @ acc[3:] + np.cross(lever, m_p * a_g)]))
    return rao, np.array(loads), np.array(terms).max(axis=0)


def scene(spec: Path, height: float, heading: float, **sections) -> str:
    period = 2 * math.pi / W0
    keys = {"stations": STATIONS, "mass_stations": [-L / 2, L / 2], "mass_per_length": [PER_M],
            "section_inertia": [OWN], **sections}
    return scene_toml(dt=period / 120, duration=14 * period, water={"density": RHO},
                      waves=regular_waves(height, period, ramp=3 * period, direction=heading),
                      hydro={"radiation": "constant"},
                      bodies=[body("barge", hdb=str(spec), mass=MASS, center_of_mass=[0.0, 0.0, Z_G],
                                   inertia=INERTIA, sections=keys)])


@pytest.fixture
def box_spec(tmp_path: Path, monkeypatch) -> Path:
    monkeypatch.setenv("HYDROLINK_CACHE", str(tmp_path / "cache"))
    spec = tmp_path / "barge_hdb.toml"
    spec.write_text(SPEC)
    return spec


def test_sectional_loads_in_regular_waves_match_the_frequency_domain(box_spec: Path, tmp_path: Path):
    heading = math.radians(30.0)
    rao, expected, terms = reference(box_spec, heading)
    path = tmp_path / "barge.toml"
    path.write_text(scene(box_spec, 0.02, 30.0))
    run_scene_file(path, tmp_path / "out.nc", progress=False)
    ds = xr.load_dataset(tmp_path / "out.nc")
    assert list(ds["section_station"].values) == STATIONS and set(ds["section_body"].values) == {"barge"}
    t = ds["time"].values
    period = 2 * math.pi / W0
    fit = t >= t[-1] - 4 * period - 1e-9
    basis = np.c_[np.cos(W0 * t[fit]), np.sin(W0 * t[fit]), np.ones(fit.sum()), t[fit]]
    loads = np.concatenate((ds["section_force"].values, ds["section_moment"].values), axis=2)  # (T, S, 6)
    dynamic = loads - np.concatenate((ds["section_still_force"].values, ds["section_still_moment"].values), axis=1)
    series = np.c_[dynamic[fit].reshape(fit.sum(), -1), ds["position"].values[fit, 0] - ds["equilibrium_position"].values[0],
                   ds["wave_elevation"].values[fit]]
    coef = np.linalg.lstsq(basis, series, rcond=None)[0]
    phasor = (coef[0] + 1j * coef[1]) / (coef[0, -1] + 1j * coef[1, -1])     # per metre of the recorded wave
    measured, motion = phasor[:-7].reshape(len(STATIONS), 6), phasor[-7:-1]
    live = np.abs(rao) > 1e-3 * np.abs(rao).max()
    print("RAO", np.round(np.abs(rao), 5), "error", np.round(np.abs(motion[live] / rao[live] - 1), 5))
    # a load is what is left of the part's inertia load against the water's (10-400 times larger here):
    # the run's motion, within 0.1 % of the RAO, leaves its error on that scale (the acceleration from the
    # recorded velocity and the integrator's phase: 3e-4 of it at dt = T/120). Second order in dt: at T/240
    # the worst error is 5.5e-4 of the inertia load (2.3e-3 at T/120), 1.6 % of the largest bending (6.1 %)
    scale = np.abs(expected).max(axis=0)                        # each component's largest amplitude along the body
    for s, mine, ref in zip(STATIONS, measured, expected):
        print(f"s {s:+5.1f} |F| {np.round(np.abs(ref), 1)}  error / largest {np.round(np.abs(mine - ref) / scale, 4)}"
              f"  / inertia {np.round(np.abs(mine - ref) / terms, 5)}")
    assert np.abs(motion[live] / rao[live] - 1).max() < 0.005
    assert (np.abs(measured - expected) < 3e-3 * terms).all()
    inner = [j for j, s in enumerate(STATIONS) if -L / 2 < s < L / 2]
    for k in (2, 4):                                          # the vertical shear and bending along the body
        assert np.abs(measured[inner, k] - expected[inner, k]).max() < 0.07 * scale[k], k
    # the ends: nothing beyond the far end (exactly), the whole free body at the near end
    assert np.abs(measured[-1]).max() == 0.0
    assert (np.abs(measured[0]) < 3e-3 * terms).all()
    # the run checks itself there: 12 % of the largest yaw moment (rms, the ramp included) is said, naming simulation.dt
    import json
    said = [w for w in json.loads(ds.attrs["warnings"]) if "sections" in w]
    assert len(said) == 1 and said[0].startswith("simulation.dt: bodies[0].sections") and "z moment" in said[0]


def test_an_hdb_without_panel_pressures_is_refused_by_name(box_spec: Path, tmp_path: Path):
    box_spec.write_text(SPEC.replace("panel_pressures = true", ""))
    path = tmp_path / "barge.toml"
    path.write_text(scene(box_spec, 0.02, 0.0))
    with pytest.raises(ModelError, match=r"bodies\[0\]\.sections.*panel"):
        run_scene_file(path, tmp_path / "out.nc", progress=False)
    assert not (tmp_path / "out.nc").exists()                  # refused before any step
