"""`hydrolink fmu export`: the exported FMU imported with fmpy as the master and coupled to a
mass–spring model written here (Newmark average acceleration, iterated at each communication
point), against the native run of the same scene (Exudyn client) and the frequency domain."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner
from fmpy import extract, read_model_description
from fmpy.fmi2 import FMU2Slave
from fmpy.validation import validate_fmu

from hydrolink.clients.cli import cli
from hydrolink.clients.run import run_scene_file
from hydrolink.server.service.force_server import serve_in_thread
from test_fmu_master import base_scene, reference

HEAVE = 2


@pytest.fixture(scope="module")
def setting(sphere, sphere_path, tmp_path_factory):
    """A regular-wave sphere scene (rho V, heave) and its FMU exported through the CLI."""
    rho_v = float(1000.0 * sphere["displaced_volume"].values[0])
    w = float(sphere["omega"].values[np.argmin(np.abs(sphere["omega"].values - 1.15))])
    folder = tmp_path_factory.mktemp("export")
    scene = folder / "scene.toml"
    scene.write_text(base_scene(sphere_path, rho_v, 2 * np.pi / w, periods=16))
    fmu = folder / "hydro.fmu"
    result = CliRunner().invoke(cli, ["fmu", "export", str(scene), "-o", str(fmu), "--python"])
    assert result.exit_code == 0, result.output
    assert f"wrote {fmu}" in result.output
    return {"scene": scene, "fmu": fmu, "mass": rho_v, "omega": w}


def mass_spring_master(fmu: Path, mass: float, spring: float, dt: float, duration: float,
                       server: str = "") -> tuple[np.ndarray, np.ndarray]:
    """(M + A∞) x'' + k x = F(x, x', t), F from the FMU; returns time and heave displacement."""
    md = read_model_description(str(fmu))
    vr = {v.name: v.valueReference for v in md.modelVariables}
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu)),
                      modelIdentifier=md.coSimulation.modelIdentifier, instanceName="hydro")
    xs, fs = [vr["sphere.heave.displacement"], vr["sphere.heave.velocity"]], [vr["sphere.heave.force"]]
    slave.instantiate()
    slave.setupExperiment(startTime=0.0)
    slave.setString([vr["server_address"]], [server])
    slave.enterInitializationMode()
    slave.setReal(xs, [0.0, 0.0])
    slave.exitInitializationMode()
    m = mass + slave.getReal([vr["A_inf.sphere.heave.sphere.heave"]])[0]

    def force(x: float, v: float) -> float:
        slave.setReal(xs, [x, v])
        return slave.getReal(fs)[0]

    n = int(round(duration / dt))
    x, v = 0.0, 0.0
    a = (force(x, v) - spring * x) / m
    out = [x]
    try:
        for k in range(n):
            slave.doStep(k * dt, dt)
            a1 = a
            for _ in range(4):   # fixed point on the end-of-step force (A∞ is in m: contracts fast)
                x1 = x + dt * v + 0.25 * dt * dt * (a + a1)
                v1 = v + 0.5 * dt * (a + a1)
                a1 = (force(x1, v1) - spring * x1) / m
            x, v, a = x + dt * v + 0.25 * dt * dt * (a + a1), v + 0.5 * dt * (a + a1), a1
            force(x, v)          # the server's sample for this step is the final state
            out.append(x)
    finally:
        slave.terminate()
        slave.freeInstance()
    return np.arange(n + 1) * dt, np.array(out)


def heave_amplitude(t: np.ndarray, z: np.ndarray, omega: float, periods: int = 4) -> complex:
    fit = t >= t[-1] - periods * 2 * np.pi / omega - 1e-9
    basis = np.c_[np.cos(omega * t[fit]), np.sin(omega * t[fit]), np.ones(fit.sum())]
    c = np.linalg.lstsq(basis, z[fit], rcond=None)[0]
    return complex(c[0], c[1])


def test_exported_fmu_validates(setting):
    assert validate_fmu(str(setting["fmu"])) == []
    md = read_model_description(str(setting["fmu"]))
    names = {v.name: v.causality for v in md.modelVariables}
    assert names["sphere.heave.displacement"] == names["sphere.heave.velocity"] == "input"
    assert names["sphere.heave.force"] == "output" and names["server_address"] == "parameter"


def test_exported_fmu_with_mass_matches_native_run(setting, tmp_path):
    """Embedded server (server_address empty); the native run is `hydrolink run` (Exudyn)."""
    summary = run_scene_file(setting["scene"], tmp_path / "native.nc", progress=False)
    ds = xr.load_dataset(tmp_path / "native.nc")
    tn = ds["time"].values
    zn = ds["position"].values[:, 0, HEAVE] - ds["equilibrium_position"].values[0, HEAVE]
    dt = float(tn[1] - tn[0])
    t, z = mass_spring_master(setting["fmu"], setting["mass"], 0.0, dt, float(tn[-1]))
    w = setting["omega"]
    native, imported = heave_amplitude(tn, zn, w), heave_amplitude(t, z, w)
    err = abs(imported) / abs(native) - 1
    print(f"export vs native: amplitude {abs(imported):.5f} vs {abs(native):.5f} m ({err:+.2e}), phase "
          f"{np.degrees(np.angle(imported / native)):+.3f} deg; native {summary.steps} steps")
    assert abs(err) < 0.005
    assert abs(np.degrees(np.angle(imported / native))) < 0.5


def test_exported_fmu_with_spring_matches_frequency_domain(setting, sphere, tmp_path):
    """A mooring-like spring in the master (remote server via server_address), against the frequency
    domain and against the native run of the same scene with the spring as a linear mooring."""
    srv, thread = serve_in_thread("tcp://127.0.0.1:*")
    try:
        k = 3.0e5
        w, _, _ = reference(sphere, setting["mass"], setting["omega"], c_pto=0.0)
        i = int(np.argmin(np.abs(sphere["omega"].values - w)))
        a, b = (sphere[v].values[i, HEAVE, HEAVE] for v in ("added_mass", "radiation_damping"))
        x = sphere["excitation_force"].values[i, 0, HEAVE]
        c = sphere["hydrostatic_stiffness"].values[HEAVE, HEAVE]
        rao = x / (-w ** 2 * (setting["mass"] + a) - 1j * w * b + c + k)
        period = 2 * np.pi / w
        t, z = mass_spring_master(setting["fmu"], setting["mass"], k, period / 100, 16 * period, srv.address)
    finally:
        srv.stop()
        thread.join(5.0)
    got = heave_amplitude(t, z, w) / 0.5            # wave amplitude 0.5 m, phase 0 at the origin
    err = abs(got) / abs(rao) - 1
    print(f"export + spring vs frequency domain: |RAO| {abs(got):.5f} vs {abs(rao):.5f} ({err:+.2e})")
    assert abs(err) < 0.01

    native_scene = tmp_path / "native_spring.toml"
    native_scene.write_text(setting["scene"].read_text() + textwrap.dedent(f"""\
        [[moorings]]
        type = "linear"
        body = "sphere"
        point = [0.0, 0.0, -2.0]
        stiffness = [0.0, 0.0, {k!r}, 0.0, 0.0, 0.0]
        """))
    run_scene_file(native_scene, tmp_path / "native_spring.nc", progress=False)
    ds = xr.load_dataset(tmp_path / "native_spring.nc")
    zn = ds["position"].values[:, 0, HEAVE] - ds["equilibrium_position"].values[0, HEAVE]
    native = heave_amplitude(ds["time"].values, zn, w) / 0.5
    err_native = abs(got) / abs(native) - 1
    print(f"export + spring vs native run with a linear mooring: {abs(got):.5f} vs {abs(native):.5f} "
          f"({err_native:+.2e}), phase {np.degrees(np.angle(got / native)):+.3f} deg")
    assert abs(err_native) < 0.005
    assert abs(np.degrees(np.angle(got / native))) < 0.5


def test_exported_added_mass_is_what_the_mass_matrix_takes(sphere, sphere_path, tmp_path):
    """With [hydro] radiation = "constant" the importer's mass matrix takes A(ω0), not A∞ (SPEC §5.1
    `added_mass`): the FMU's A_inf output must equal the HDB's A33 at the wave frequency (a grid
    frequency here, so no interpolation), which on the Task-10 sphere at T ≈ 5 s is ~7 % below A∞."""
    rho_v = float(1000.0 * sphere["displaced_volume"].values[0])
    om = sphere["omega"].values
    i = int(np.argmin(np.abs(om - 2 * np.pi / 5.0)))
    scene = tmp_path / "constant.toml"
    scene.write_text(base_scene(sphere_path, rho_v, 2 * np.pi / float(om[i]), periods=2)
                     + '[hydro]\nradiation = "constant"\n')
    fmu = tmp_path / "constant.fmu"
    result = CliRunner().invoke(cli, ["fmu", "export", str(scene), "-o", str(fmu), "--python"])
    assert result.exit_code == 0, result.output
    md = read_model_description(str(fmu))
    exported = float(next(v.start for v in md.modelVariables if v.name == "A_inf.sphere.heave.sphere.heave"))
    a_w0 = float(sphere["added_mass"].values[i, HEAVE, HEAVE])
    a_inf = float(sphere["added_mass_inf"].values[HEAVE, HEAVE])
    print(f"exported {exported:.6g}, A(w0) {a_w0:.6g}, A_inf {a_inf:.6g} ({a_inf / a_w0 - 1:+.1%})")
    assert abs(a_inf / a_w0 - 1) > 0.03        # the two differ enough for the check to mean something
    assert exported == pytest.approx(a_w0, rel=1e-9)
