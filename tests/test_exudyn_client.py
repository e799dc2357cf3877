"""Exudyn client + real force server + real model on the IEA Task-10 floating sphere (heave).

Every physics check compares against a reference computed here from the HDB itself:
the frequency-domain RAO, a monolithic Cummins-equation integration, 2π√((m+A∞)/C) and the
rigid-body mass matrix moved to the reference point by hand.
"""

from __future__ import annotations

import os
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from conftest import EXIT_S, REPLY_S
from conftest import SPHERE_WATER, needs_python_sigint, regular_waves, scene_toml, sphere_body, write_scene

from hydrolink.clients.lockstep.connection import ServerConnection
from hydrolink.clients.exudyn.client import RunInterrupted, SimulationDiverged, build_model, run
from hydrolink.clients.lockstep.results import ResultWriter
from hydrolink.protocol.scene import SceneError, parse_scene
from hydrolink.server.hdb.io import load_hdb
from hydrolink.server.service.force_server import serve_in_thread

MASS = 261.724e3         # kg: rho V of the Task 10 sphere HDB (floats at equilibrium: no net buoyancy)
HEAVE = 2
REPORT: dict[str, str] = {}


# ------------------------------------------------------------------------------------ fixtures


def sphere_scene(hdb_path: Path, *, dt: float, duration: float, waves: dict | None = None, dofs=("heave",),
                 displacement=(0.0,) * 6, irf: float = 40.0, cog=(0.0, 0.0, -2.0),
                 inertia=(2.6e6, 2.6e6, 2.6e6)) -> str:
    """Scene TOML for the sphere (rho and depth as in its HDB so nothing is rescaled)."""
    return scene_toml(dt=dt, duration=duration, water={**SPHERE_WATER, "gravity": 9.81}, waves=waves,
                      hydro={"irf_duration": irf},
                      bodies=[sphere_body(str(hdb_path), mass=MASS, center_of_mass=list(cog), inertia=list(inertia),
                                          dofs=list(dofs), initial_displacement=list(displacement))])


def simulate(address: str, text: str, hdb, out: Path, timeout: float = 30.0, **kw):
    """One full run through the real server; returns (summary, results dataset)."""
    scene = parse_scene(text)
    with ServerConnection(address, timeout=timeout) as conn:
        setup = conn.hello(text, {scene.bodies[0].hdb: hdb})
        with ResultWriter(out, scene=scene, scene_text=text, setup=setup) as writer:
            summary = run(scene, text, conn, setup, writer, progress=False, **kw)
        conn.bye()
    return summary, xr.load_dataset(out)


def heave(ds: xr.Dataset) -> tuple[np.ndarray, np.ndarray]:
    """Time and heave displacement from equilibrium."""
    z = ds["position"].values[:, 0, HEAVE] - ds["equilibrium_position"].values[0, HEAVE]
    return ds["time"].values, z


def extrema(t: np.ndarray, x: np.ndarray, count: int) -> np.ndarray:
    """First ``count`` local extrema after t = 0 as (time, value), refined by a parabola."""
    out = []
    dx = np.diff(x)
    for i in np.flatnonzero(dx[:-1] * dx[1:] < 0) + 1:
        y0, y1, y2 = x[i - 1], x[i], x[i + 1]
        s = 0.5 * (y0 - y2) / (y0 - 2 * y1 + y2)
        out.append((t[i] + s * (t[1] - t[0]), y1 - 0.25 * (y0 - y2) * s))
        if len(out) == count:
            break
    assert len(out) == count, f"only {len(out)} extrema found"
    return np.array(out)


def radiation_irf(hdb, t: np.ndarray) -> np.ndarray:
    """Heave K(t) = (2/π) ∫ B(ω) cos(ωt) dω by the trapezoid rule on the HDB grid (B(0) = 0)."""
    w = np.r_[0.0, hdb["omega"].values]
    b = np.r_[0.0, hdb["radiation_damping"].values[:, HEAVE, HEAVE]]
    return np.array([2 / np.pi * np.trapezoid(b * np.cos(w * ti), w) for ti in t])


def cummins_decay(mass: float, a_inf: float, c: float, kernel_of, x0: float, duration: float,
                  h: float) -> tuple[np.ndarray, np.ndarray]:
    """(m + A∞) ẍ + ∫₀ᵗ K(τ) ẋ(t−τ) dτ + C x = 0, x(0) = x0, ẋ(0) = 0: average-acceleration
    Newmark with the convolution by the trapezoid rule, solved implicitly for each new step."""
    n = int(round(duration / h))
    k = kernel_of(np.arange(n + 1) * h)
    x, v, a = np.zeros(n + 1), np.zeros(n + 1), np.zeros(n + 1)
    m = mass + a_inf
    x[0], a[0] = x0, -c * x0 / m
    for i in range(n):
        memory = h * np.dot(k[1:i + 1], v[i:0:-1]) + 0.5 * h * k[i + 1] * v[0]
        vb, xb = v[i] + 0.5 * h * a[i], x[i] + h * v[i] + 0.25 * h * h * a[i]
        a[i + 1] = -(0.5 * h * k[0] * vb + memory + c * xb) / (m + 0.25 * h * h * (k[0] + c))
        v[i + 1] = vb + 0.5 * h * a[i + 1]
        x[i + 1] = xb + 0.25 * h * h * a[i + 1]
    return np.arange(n + 1) * h, x


# ------------------------------------------------------------------------------------ physics

RAO_OMEGAS = (0.85, 1.15, 1.45, 1.75, 2.25)   # rad/s, on the HDB grid; heave resonance ≈ 1.45


@pytest.mark.parametrize("omega", RAO_OMEGAS)
def test_heave_rao_matches_frequency_domain(server, sphere, sphere_path, tmp_path, omega):
    i = int(np.argmin(np.abs(sphere["omega"].values - omega)))
    w = float(sphere["omega"].values[i])
    a = sphere["added_mass"].values[i, HEAVE, HEAVE]
    b = sphere["radiation_damping"].values[i, HEAVE, HEAVE]
    x = sphere["excitation_force"].values[i, 0, HEAVE]
    c = sphere["hydrostatic_stiffness"].values[HEAVE, HEAVE]
    rao = x / (-w ** 2 * (MASS + a) - 1j * w * b + c)          # exp(-iωt) convention

    period, n_periods = 2 * np.pi / w, 20
    text = sphere_scene(sphere_path, dt=period / 100, duration=n_periods * period,
                        waves=regular_waves(1.0, period, ramp=2 * period))
    summary, ds = simulate(server, text, sphere, tmp_path / "rao.nc")
    t, z = heave(ds)
    eta = ds["wave_elevation"].values
    fit = t >= t[-1] - 4 * period - 1e-9                          # last 4 periods: steady state
    basis = np.c_[np.cos(w * t[fit]), np.sin(w * t[fit]), np.ones(fit.sum())]
    cz = np.linalg.lstsq(basis, z[fit], rcond=None)[0]
    ce = np.linalg.lstsq(basis, eta[fit], rcond=None)[0]
    measured = complex(cz[0], cz[1]) / complex(ce[0], ce[1])     # Re{Z e^{-iωt}} = Zr cos + Zi sin
    amp_err = abs(measured) / abs(rao) - 1
    phase_err = np.degrees(np.angle(measured / rao))
    REPORT[f"rao w={w:.2f}"] = (f"|RAO| {abs(rao):.4f} m/m, amplitude error {amp_err:+.2e}, phase error "
                                f"{phase_err:+.3f} deg, client {summary.client_us_per_step:.0f} us/step, "
                                f"round trip {summary.round_trip_us_per_step:.0f} us/step")
    print(REPORT[f"rao w={w:.2f}"])
    assert abs(ce[0] + 1j * ce[1]) == pytest.approx(0.5, rel=1e-6)   # the wave the body felt
    assert abs(amp_err) < 0.01
    assert abs(phase_err) < 1.0


def test_free_decay_matches_cummins(server, sphere, sphere_path, tmp_path):
    x0, dt = 1.0, 0.04
    text = sphere_scene(sphere_path, dt=dt, duration=15.0, displacement=(0, 0, x0, 0, 0, 0))
    _, ds = simulate(server, text, sphere, tmp_path / "decay.nc")
    t, z = heave(ds)

    a_inf = float(sphere["added_mass_inf"].values[HEAVE, HEAVE])
    c = float(sphere["hydrostatic_stiffness"].values[HEAVE, HEAVE])
    tr, zr = cummins_decay(MASS, a_inf, c, lambda s: radiation_irf(sphere, s), x0, 15.0, 0.005)

    got, ref = extrema(t, z, 6), extrema(tr, zr, 6)      # 3 troughs and 3 crests
    period_err = (got[5, 0] - got[1, 0]) / (ref[5, 0] - ref[1, 0]) - 1   # two full periods
    peak_err = got[:, 1] / ref[:, 1] - 1
    REPORT["decay"] = (f"period error {period_err:+.2e}; extrema errors "
                       + ", ".join(f"{e:+.2e}" for e in peak_err))
    print(REPORT["decay"])
    assert abs(period_err) < 0.01
    assert np.all(np.abs(peak_err) < 0.01)
    assert np.all(np.abs(got[:, 0] / ref[:, 0] - 1) < 0.01)


def test_mass_matrix_holds_rigid_body_plus_added_mass(server, sphere, sphere_path):
    cog = np.array([0.3, -0.2, -2.5])
    inertia = np.array([[3.1e6, 0.1e6, 0.0], [0.1e6, 2.9e6, 0.05e6], [0.0, 0.05e6, 2.7e6]])
    text = sphere_scene(sphere_path, dt=0.05, duration=1.0, dofs=("surge", "sway", "heave", "roll",
                        "pitch", "yaw"), cog=tuple(map(float, cog)), irf=0.0, inertia=inertia.tolist())
    scene = parse_scene(text)
    with ServerConnection(server, timeout=REPLY_S) as conn:
        setup = conn.hello(text, {scene.bodies[0].hdb: sphere})
    model = build_model(scene, setup)
    try:
        got = model.mass_matrix()
    finally:
        model.finalize()
    # rigid body about the reference point R: v_G = v_R + ω × d, d = G − R
    d = cog - sphere["reference_point"].values[0]
    skew = np.array([[0, -d[2], d[1]], [d[2], 0, -d[0]], [-d[1], d[0], 0]])
    rigid = np.block([[MASS * np.eye(3), -MASS * skew],
                      [MASS * skew, inertia + MASS * skew.T @ skew]])
    expected = rigid + sphere["added_mass_inf"].values
    np.testing.assert_allclose(got, expected, rtol=1e-12, atol=1e-9 * np.abs(expected).max())


def test_undamped_heave_period_uses_added_mass_inf(server, sphere, sphere_path, tmp_path):
    a_inf = float(sphere["added_mass_inf"].values[HEAVE, HEAVE])
    c = float(sphere["hydrostatic_stiffness"].values[HEAVE, HEAVE])
    period = 2 * np.pi * np.sqrt((MASS + a_inf) / c)     # ≈ 4.49 s; with m alone it would be 3.65 s
    text = sphere_scene(sphere_path, dt=period / 200, duration=3.2 * period, irf=0.0,
                        displacement=(0, 0, 0.5, 0, 0, 0))
    _, ds = simulate(server, text, sphere, tmp_path / "undamped.nc")
    t, z = heave(ds)
    ext = extrema(t, z, 6)
    measured = (ext[5, 0] - ext[1, 0]) / 2
    REPORT["undamped"] = f"period {measured:.5f} s vs 2π√((m+A∞)/C) = {period:.5f} s ({measured / period - 1:+.1e})"
    print(REPORT["undamped"])
    assert measured == pytest.approx(period, rel=2e-4)
    np.testing.assert_allclose(np.abs(ext[:, 1]), 0.5, rtol=1e-3)   # trapezoidal rule: no decay


# ------------------------------------------------------------------------------------ results file

def test_results_file_layout(server, sphere, sphere_path, tmp_path):
    dt = 0.05
    text = sphere_scene(sphere_path, dt=dt, duration=2.0, waves=regular_waves(1.0, 5.0, ramp=1.0))
    summary, ds = simulate(server, text, sphere, tmp_path / "layout.nc")
    assert summary.steps == 40 and summary.rows == 41
    assert dict(ds.sizes) == {"time": 41, "body": 1, "dof": 6}
    assert list(ds["body"].values) == ["sphere"]
    assert list(ds["dof"].values) == ["surge", "sway", "heave", "roll", "pitch", "yaw"]
    np.testing.assert_allclose(ds["time"].values, dt * np.arange(41), rtol=0, atol=1e-12)
    for name in ("position", "velocity", "excitation_force", "radiation_force", "hydrostatic_force"):
        assert ds[name].dims == ("time", "body", "dof"), name
        assert ds[name].attrs["units"] and ds[name].attrs["long_name"], name
        assert np.all(np.isfinite(ds[name].values)), name
    assert ds["wave_elevation"].dims == ("time",) and ds["wave_elevation"].attrs["units"] == "m"
    assert ds["equilibrium_position"].dims == ("body", "dof")
    np.testing.assert_allclose(ds["equilibrium_position"].values[0], [0, 0, -2, 0, 0, 0])
    # inactive DOFs stay at equilibrium and get no force; the restoring force is -C (z - z_eq)
    pos = ds["position"].values[:, 0, :]
    np.testing.assert_array_equal(pos[:, [0, 1, 3, 4, 5]], 0.0)
    c = float(sphere["hydrostatic_stiffness"].values[HEAVE, HEAVE])
    np.testing.assert_allclose(ds["hydrostatic_force"].values[:, 0, HEAVE], -c * (pos[:, HEAVE] + 2.0),
                               rtol=1e-9, atol=1e-6)
    attrs = ds.attrs
    assert attrs["status"] == "complete"
    assert attrs["scene"] == text
    for pkg in ("hydrolink", "exudyn", "numpy", "capytaine", "xarray"):
        assert attrs[f"{pkg}_version"], pkg
    assert "T" in attrs["created"]


KILLED_RUN = """
import sys, time
from hydrolink.clients.lockstep.connection import ServerConnection
from hydrolink.clients.exudyn.client import run
from hydrolink.clients.lockstep.results import ResultWriter
from hydrolink.protocol.scene import SceneError, parse_scene
from hydrolink.server.hdb.io import load_hdb
from hydrolink.server.service.force_server import serve_in_thread
text, out = open(sys.argv[1]).read(), sys.argv[2]
scene = parse_scene(text)
srv, _ = serve_in_thread("tcp://127.0.0.1:*")
with ServerConnection(srv.address, timeout=120.0) as conn:
    setup = conn.hello(text, {scene.bodies[0].hdb: load_hdb(scene.bodies[0].hdb)})
    with ResultWriter(out, scene=scene, scene_text=text, setup=setup, flush_seconds=0.2) as writer:
        print("running", flush=True)
        run(scene, text, conn, setup, writer, progress=False)
"""


def test_killed_run_keeps_what_was_computed(server, sphere, sphere_path, tmp_path):
    dt = 0.04
    text = sphere_scene(sphere_path, dt=dt, duration=4000.0, waves=regular_waves(1.0, 4.3, ramp=4.0),
                        displacement=(0, 0, 0.2, 0, 0, 0))
    write_scene(tmp_path, text)
    out = tmp_path / "killed.nc"
    proc = subprocess.Popen([sys.executable, "-c", KILLED_RUN, str(tmp_path / "scene.toml"), str(out)],
                            stdout=subprocess.PIPE, text=True)
    try:
        assert proc.stdout.readline().strip() == "running"
        time.sleep(1.5)
    finally:
        proc.send_signal(signal.SIGKILL)
        proc.wait(EXIT_S)
    with xr.open_dataset(out) as ds:
        ds = ds.load()
    n = ds.sizes["time"]
    assert ds.attrs["status"] == "running"
    assert 10 < n < 100_000            # part way: some rows, not the whole run
    np.testing.assert_allclose(ds["time"].values, dt * np.arange(n), rtol=0, atol=1e-9)
    assert np.all(np.isfinite(ds["position"].values))
    # the saved rows are those of an uninterrupted run of the same length (to round-off: BLAS
    # kernels may differ with memory alignment between processes)
    _, full = simulate(server, text.replace("duration = 4000.0", f"duration = {dt * (n - 1)!r}"),
                       sphere, tmp_path / "reference.nc")
    for name in ("position", "velocity", "excitation_force", "radiation_force", "wave_elevation"):
        np.testing.assert_allclose(ds[name].values, full[name].values, rtol=1e-7, atol=1e-6, err_msg=name)


def test_ctrl_c_flushes_and_reraises(server, sphere, sphere_path, tmp_path):
    needs_python_sigint()
    dt = 0.04
    text = sphere_scene(sphere_path, dt=dt, duration=4000.0, waves=regular_waves(1.0, 4.3, ramp=4.0))
    scene = parse_scene(text)
    done = threading.Event()
    with ServerConnection(server, timeout=REPLY_S) as conn:
        setup = conn.hello(text, {scene.bodies[0].hdb: sphere})
        with ResultWriter(tmp_path / "ctrl_c.nc", scene=scene, scene_text=text, setup=setup) as writer:
            def interrupt_mid_run() -> None:   # once the run has stepped (not on a clock: holds under load)
                deadline = time.monotonic() + 120.0
                while not done.is_set() and writer.rows < 20 and time.monotonic() < deadline:
                    time.sleep(0.01)
                if not done.is_set():
                    os.kill(os.getpid(), signal.SIGINT)

            watcher = threading.Thread(target=interrupt_mid_run, daemon=True)
            watcher.start()
            try:
                with pytest.raises(KeyboardInterrupt, match=r"interrupted at step \d+ \(t = [\d.]+ s\)"):
                    run(scene, text, conn, setup, writer, progress=False)
            finally:
                done.set()
                watcher.join(5.0)
    with xr.open_dataset(tmp_path / "ctrl_c.nc") as ds:
        assert ds.attrs["status"].startswith("interrupted: KeyboardInterrupt at step")
        n = ds.sizes["time"]
        assert n > 1 and np.all(np.isfinite(ds["position"].values))
        np.testing.assert_allclose(ds["time"].values, dt * np.arange(n), rtol=0, atol=1e-9)


def test_server_gone_mid_run_keeps_rows_and_names_the_step(sphere, sphere_path, tmp_path):
    srv, thread = serve_in_thread("tcp://127.0.0.1:*")
    dt = 0.04
    text = sphere_scene(sphere_path, dt=dt, duration=4000.0, waves=regular_waves(1.0, 4.3, ramp=4.0))
    done = threading.Event()

    def stop_mid_run() -> None:   # the server goes once the run has stepped (not on a clock: holds under load)
        deadline = time.monotonic() + 120.0
        while not done.is_set() and time.monotonic() < deadline:
            if any(session.steps >= 20 for session in list(srv.sessions.values())):
                break
            time.sleep(0.01)
        srv.stop()

    watcher = threading.Thread(target=stop_mid_run, daemon=True)
    watcher.start()
    try:
        with pytest.raises(RunInterrupted, match=r"force server error at step \d+ \(t = [\d.]+ s\)") as info:
            simulate(srv.address, text, sphere, tmp_path / "gone.nc", timeout=5.0)
    finally:
        done.set()
        watcher.join(5.0)
        srv.stop()
        thread.join(5.0)
    with xr.open_dataset(tmp_path / "gone.nc") as ds:
        assert ds.attrs["status"].startswith("interrupted: force server error")
        assert ds.sizes["time"] == info.value.step      # every step before the failed one
        assert np.all(np.isfinite(ds["position"].values))


def test_unstable_body_stops_with_a_clear_message(server, sphere, sphere_path, tmp_path):
    # centre of gravity 3 m above the sphere's centre: negative pitch stiffness, exponential growth
    text = sphere_scene(sphere_path, dt=0.05, duration=60.0, dofs=("pitch",), cog=(0.0, 0.0, 3.0),
                        displacement=(0, 0, 0, 0, 0.01, 0))
    with pytest.raises(SimulationDiverged, match=r"diverged at step \d+ \(t = [\d.]+ s\)") as info:
        simulate(server, text, sphere, tmp_path / "unstable.nc", blow_up_limit=1.0)
    with xr.open_dataset(tmp_path / "unstable.nc") as ds:
        assert ds.attrs["status"].startswith("interrupted: simulation diverged")
        assert ds.sizes["time"] == info.value.step
        pitch = ds["position"].values[:, 0, 4]
        assert np.all(np.isfinite(pitch)) and np.all(np.abs(pitch) < 1.0)
        assert np.all(np.diff(np.abs(pitch[ds.sizes["time"] // 2:])) > 0)   # growing, not oscillating


def test_initial_displacement_in_a_locked_dof_is_a_scene_error(server, sphere, sphere_path):
    text = sphere_scene(sphere_path, dt=0.05, duration=1.0, displacement=(0.5, 0, 0.1, 0, 0, 0))
    scene = parse_scene(text)
    with ServerConnection(server, timeout=REPLY_S) as conn:
        setup = conn.hello(text, {scene.bodies[0].hdb: sphere})
    with pytest.raises(SceneError, match=r"bodies\[0\]\.initial_displacement: .*\['surge'\]"):
        build_model(scene, setup)


@pytest.mark.parametrize("reduce", [True, False])
def test_a_heave_only_body_needs_no_inertia(tmp_path, sphere_path, reduce):
    """The same heave-only sphere run with an inertia and a centre of mass, and with neither (it
    then sits at its HDB reference point): the same motion, bit for bit (neither enters the motion
    of a body whose rotations are locked), reduced or as a full rigid body with its rotations
    constrained."""
    from hydrolink.clients.run import run_scene_file
    heave = []
    for inertia, com in (([2.6e6] * 3, [0.0, 0.0, -2.0]), (None, None)):
        text = scene_toml(dt=0.05, duration=10.0, progress=False, water=SPHERE_WATER,
                          waves=regular_waves(1.0, 6.0, ramp=2.0), hydro={"irf_duration": 8.0},
                          client={"type": "exudyn", "reduce": reduce},
                          bodies=[sphere_body(str(sphere_path), mass=261.8e3, dofs=["heave"], inertia=inertia,
                                              center_of_mass=com)])
        path = write_scene(tmp_path, text, f"s{len(heave)}.toml")
        run_scene_file(path, tmp_path / f"s{len(heave)}.nc", progress=False)
        with xr.open_dataset(tmp_path / f"s{len(heave)}.nc") as ds:
            heave.append(ds["position"].sel(dof="heave").values.copy())
    assert np.abs(heave[0]).max() > 0.1
    np.testing.assert_array_equal(heave[0], heave[1])
