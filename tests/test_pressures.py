"""The panel pressures of a run (server/loads/pressures.py, ``bodies[i].pressure_output``): a free box
barge in a small irregular sea from 30 deg, radiation by convolution. The dynamic pressure on every panel,
integrated over the hull as the force on each rigid DOF (-sum p (V . n) dS, the rigid motions written
here), must be the linear force the run applied: its recorded excitation, its recorded radiation memory
less A-infinity times the acceleration, and the hydrostatic change -C x of the HDB less the buoyancy's
turning with the body (the pressure is in the body's axes) — the last to the panels' one-point rule,
whose error on the box is the test's own rho g sum A h^2 / 12."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from conftest import body, box_build_spec, irregular_waves, scene_toml, unit_rigid_motions
from hydrolink.clients.run import run_scene_file
from hydrolink.server.hdb.build.builder import build_hdb

RHO, G = 1025.0, 9.81
L, B, T, H = 20.0, 6.0, 2.0, 1.0          # H the panels' size
MASS = RHO * L * B * T
INERTIA = [MASS * (B ** 2 + T ** 2) / 12, MASS * (L ** 2 + T ** 2) / 12, MASS * (L ** 2 + B ** 2) / 12]
SPEC = box_build_spec(name="barge", length=L, width=B, draft=T, panel_size=H, density=RHO,
                      frequencies="omega_min = 0.3\nomega_max = 1.8\nn = 8")




def test_panel_pressures_integrate_to_the_force_the_run_applied(tmp_path: Path, monkeypatch):
    monkeypatch.setenv("HYDROLINK_CACHE", str(tmp_path / "cache"))
    spec = tmp_path / "barge_hdb.toml"
    spec.write_text(SPEC)
    scene = tmp_path / "barge.toml"
    scene.write_text(scene_toml(
        dt=0.1, duration=40.0, water={"density": RHO}, waves=irregular_waves(0.1, 7.0, direction=30.0, ramp=10.0, seed=2),
        hydro={"radiation": "convolution", "irf_duration": 10.0},
        bodies=[body("barge", hdb=str(spec), mass=MASS, center_of_mass=[0.0, 0.0, -0.5], inertia=INERTIA,
                     pressure_output=True)]))
    run_scene_file(scene, tmp_path / "out.nc", progress=False)
    run = xr.load_dataset(tmp_path / "out.nc")
    ds = xr.load_dataset(tmp_path / "out.pressures.nc")
    assert "section_force" not in run and set(ds["panel_body"].values) == {"barge"}
    hdb = build_hdb(spec, progress=False)                                  # from the cache
    c, n, area = ds["center"].values, ds["normal"].values, ds["area"].values
    vn = np.einsum("mpk,pk->mp", unit_rigid_motions(c), n) * area                     # (6, P)
    force = -ds["pressure"].values @ vn.T                                   # (T, 6) the pressures' generalized force
    t = run["time"].values
    x = run["position"].values[:, 0] - run["equilibrium_position"].values[0]
    acc = np.gradient(run["velocity"].values[:, 0], t, axis=0, edge_order=2)
    buoyancy = RHO * G * L * B * T
    cb = hdb["center_of_buoyancy"].values.reshape(3)
    turn = np.c_[np.cross(x[:, 3:], [0.0, 0.0, buoyancy]), np.cross(x[:, 3:], np.cross(cb, [0.0, 0.0, buoyancy]))]
    applied = run["excitation_force"].values[:, 0] + run["radiation_force"].values[:, 0] \
        - acc @ hdb["added_mass_inf"].values.T - x @ hdb["hydrostatic_stiffness"].values.T - turn
    error = np.abs(force - applied)[t > 10.0].max(axis=0)
    # the one-point rule on the hull's flat panels misses rho g sum A h^2/12 of the roll and pitch stiffness
    rule = RHO * G * L * B * H ** 2 / 12 * np.abs(x[t > 10.0, 3:5]).max(axis=0)
    scale = np.abs(run["excitation_force"].values[t > 10.0, 0]).max(axis=0)
    print("error / excitation", np.round(error / scale, 5), "one-point rule / excitation", np.round(rule / scale[3:5], 5))
    assert (error[:3] < 0.01 * scale[:3]).all() and error[5] < 0.01 * scale[5]
    assert (error[3:5] < rule + 0.01 * scale[3:5]).all()
    assert ds["pressure"].shape == (t.size, c.shape[0]) and np.all(ds["still_pressure"].values >= 0)
