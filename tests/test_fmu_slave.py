"""clients/fmu/slave.py, the model class of an exported FMU, through fmpy: its variables (inputs,
outputs, the A∞ constants), direct feedthrough (set the state at t, read F(t)), an iterating
master replacing the step's sample, and the communication step it accepts. References: the
sphere HDB's own C33, A∞ and displaced volume, and a second FMU instance that saw one state only."""

from __future__ import annotations

import subprocess
import sys
from pathlib import Path

import numpy as np
import pytest

pytest.importorskip("pythonfmu", reason="hydrolink fmu export needs pythonfmu")
from click.testing import CliRunner  # noqa: E402
from fmpy import extract, read_model_description  # noqa: E402
from fmpy.fmi2 import FMU2Slave  # noqa: E402

from conftest import EXIT_S, SPHERE_WATER, scene_toml, sphere_body, write_scene  # noqa: E402
from hydrolink.clients.cli import cli  # noqa: E402

DT, HEAVE, MASS_RATIO = 0.05, 2, 0.9


@pytest.fixture(scope="module")
def exported(sphere, sphere_path, tmp_path_factory) -> dict:
    """The sphere in still water, heave only, 10 % lighter than its displacement, exported."""
    rho_v = 1000.0 * float(sphere["displaced_volume"].values[0])
    folder = tmp_path_factory.mktemp("slave")
    scene = write_scene(folder, scene_toml(dt=DT, duration=10.0, water=SPHERE_WATER, hydro={"irf_duration": 10.0},
                                           bodies=[sphere_body(str(sphere_path), mass=MASS_RATIO * rho_v,
                                                               dofs=["heave"])]))
    fmu = folder / "hydro.fmu"
    result = CliRunner().invoke(cli, ["fmu", "export", str(scene), "-o", str(fmu), "--python"])
    assert result.exit_code == 0, result.output
    return {"fmu": fmu, "mass": MASS_RATIO * rho_v, "unzipped": extract(str(fmu))}


class Slave:
    """An initialised instance of the exported FMU (embedded server) with named access."""

    def __init__(self, fmu: Path, unzipped: str, name: str):
        self.md = read_model_description(str(fmu))
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=unzipped,
                             modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName=name)
        self.fmu.instantiate()
        self.fmu.setupExperiment(startTime=0.0)
        self.fmu.enterInitializationMode()
        self.fmu.exitInitializationMode()

    def set(self, **values: float) -> None:
        names = [f"sphere.heave.{k}" for k in values]
        self.fmu.setReal([self.vr[n] for n in names], list(values.values()))

    def get(self, *names: str) -> list[float]:
        return self.fmu.getReal([self.vr[n] for n in names])

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()


@pytest.fixture()
def slave(exported):
    s = Slave(exported["fmu"], exported["unzipped"], "a")
    yield s
    s.close()


def test_variables_and_a_inf_constant(exported, sphere):
    md = read_model_description(str(exported["fmu"]))
    causality = {v.name: v.causality for v in md.modelVariables}
    assert causality["sphere.heave.displacement"] == causality["sphere.heave.velocity"] == "input"
    for part in ("force", "excitation", "radiation", "hydrostatic"):
        assert causality[f"sphere.heave.{part}"] == "output"
    assert causality["wave_elevation"] == "output" and causality["server_address"] == "parameter"
    assert not any(name.startswith("sphere.surge") for name in causality)          # inactive DOFs: none
    a_inf = next(v for v in md.modelVariables if v.name == "A_inf.sphere.heave.sphere.heave")
    assert (a_inf.causality, a_inf.variability) == ("output", "constant")
    assert float(a_inf.start) == pytest.approx(float(sphere["added_mass_inf"].values[HEAVE, HEAVE]), rel=1e-12)


def test_hydrostatic_output_is_stiffness_plus_net_buoyancy(slave, exported, sphere):
    """Still water: F = -C33 x + (rho g V - m g), the parts sum to the force; read at once after set."""
    c33 = float(sphere["hydrostatic_stiffness"].values[HEAVE, HEAVE])
    net = 1000.0 * 9.81 * float(sphere["displaced_volume"].values[0]) - exported["mass"] * 9.81
    for x in (0.0, 0.1, -0.25):
        slave.set(displacement=x, velocity=0.0)
        force, exc, rad, hs, eta = slave.get("sphere.heave.force", "sphere.heave.excitation",
                                             "sphere.heave.radiation", "sphere.heave.hydrostatic", "wave_elevation")
        assert hs == pytest.approx(-c33 * x + net, rel=1e-9)
        assert exc == 0.0 and eta == 0.0 and rad == pytest.approx(0.0, abs=1e-6)
        assert force == pytest.approx(exc + rad + hs, rel=1e-12)
    assert net == pytest.approx(0.1 * exported["mass"] / MASS_RATIO * 9.81, rel=1e-12)


def test_iterating_master_replaces_the_step_sample(exported):
    """Two velocities set at t = 0 (an iterating master), then a step: the radiation memory at
    t = dt is that of the last velocity only — equal to an instance that only ever saw it — and
    opposes it (positive K(dt) of the sphere)."""
    a, b = (Slave(exported["fmu"], exported["unzipped"], n) for n in "ab")
    try:
        a.set(displacement=0.0, velocity=0.8)
        a.get("sphere.heave.force")
        a.set(velocity=-0.5)
        b.set(displacement=0.0, velocity=-0.5)
        assert a.get("sphere.heave.force") == b.get("sphere.heave.force")
        for s in (a, b):
            s.fmu.doStep(0.0, DT)
            s.set(displacement=0.0, velocity=0.0)
        (ra,), (rb,) = a.get("sphere.heave.radiation"), b.get("sphere.heave.radiation")
        assert ra == rb and ra > 0.0          # -dt K(dt) (-0.5) > 0
    finally:
        a.close()
        b.close()


def _master(code: str) -> subprocess.CompletedProcess:
    """Run a master's Python ``code`` in its own process, as a user runs it (a Python exception in
    a pythonfmu FMU is answered Fatal and corrupts the host's heap: the host must not be pytest)."""
    return subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, timeout=EXIT_S)


def test_communication_step_must_be_the_scene_dt(exported):
    """Declared (no variable communication step) and refused with an error status (Fatal: pythonfmu
    answers Discard, taken by masters for a normal end, or Fatal for an exception)."""
    from fmpy import read_model_description
    assert read_model_description(exported["fmu"]).coSimulation.canHandleVariableCommunicationStepSize is False
    done = _master("from fmpy import read_model_description\nfrom fmpy.fmi2 import FMU2Slave\n"
                   f"md = read_model_description({str(exported['fmu'])!r})\n"
                   f"f = FMU2Slave(guid=md.guid, unzipDirectory={str(exported['unzipped'])!r}, "
                   "modelIdentifier=md.coSimulation.modelIdentifier, instanceName='a')\n"
                   "f.instantiate(); f.setupExperiment(startTime=0.0); f.enterInitializationMode(); "
                   "f.exitInitializationMode()\n"
                   f"f.doStep(0.0, {DT / 2!r})\nprint('STEPPED')\n")
    assert "STEPPED" not in done.stdout and "fmi2DoStep" in done.stderr, done.stderr


def test_other_step_size_fails_loudly_in_fmpy(exported):
    """fmpy's simulate_fmu asked for another step than the scene's dt: the FMU answers an error
    status (fmpy raises, naming fmi2DoStep), never ends at t = 0 reporting success, and the message
    naming both steps is printed with fmpy's default logging (pythonfmu passes FMU log messages on
    only with debug logging)."""
    done = _master("from fmpy import simulate_fmu\n"
                   f"r = simulate_fmu({str(exported['fmu'])!r}, stop_time=1.0, step_size={DT / 2!r}, "
                   f"output_interval={DT / 2!r})\nprint('ENDED', len(r), r['time'][-1])\n")
    assert "ENDED" not in done.stdout, done.stdout
    assert done.returncode != 0
    assert "fmi2DoStep failed" in done.stderr
    assert f"communication step {DT / 2} s must equal the scene's dt {DT} s" in done.stderr


def test_setup_warnings_reach_the_importers_logger(reference_data, tmp_path, capfd):
    """SPEC §5.1: the FMU shows every setup warning — its HDB reader's (the RM3 Capytaine file records
    no rotation centre; the FMU carries it as hydrolink NetCDF with the warning kept) and the
    server's own (sea water against the file's 1000 kg/m³) — through the importer's logger at status
    warning, and on stderr (pythonfmu forwards log messages only with logging on)."""
    import shutil

    from fmpy.fmi2 import fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2CallbackAllocateMemoryTYPE, \
        fmi2CallbackFreeMemoryTYPE
    from fmpy import calloc, free
    from conftest import rm3_float, rm3_spar

    shutil.copy(reference_data / "rm3_capytaine" / "rm3_hydrodynamics.nc", tmp_path / "rm3.nc")
    scene = write_scene(tmp_path, scene_toml(dt=0.1, duration=1.0, hydro={"irf_duration": 10.0},
                                             bodies=[rm3_float("rm3.nc", dofs=["heave"]),
                                                     rm3_spar("rm3.nc", dofs=["heave"])]))
    fmu = tmp_path / "rm3.fmu"
    result = CliRunner().invoke(cli, ["fmu", "export", str(scene), "-o", str(fmu), "--python"])
    assert result.exit_code == 0, result.output
    reader, water = "rm3.nc: no rotation_center or center_of_mass recorded", "water: the scene's density 1025 kg/m^3"
    md = read_model_description(str(fmu))
    logged: list[tuple[int, str]] = []
    cb = fmi2CallbackFunctions()
    cb.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, cat, msg, *a: logged.append((int(status), msg.decode())))
    cb.allocateMemory, cb.freeMemory = fmi2CallbackAllocateMemoryTYPE(calloc), fmi2CallbackFreeMemoryTYPE(free)
    slave = FMU2Slave(guid=md.guid, unzipDirectory=extract(str(fmu)), modelIdentifier=md.coSimulation.modelIdentifier,
                      instanceName="rm3")
    slave.instantiate(callbacks=cb, loggingOn=True)
    try:
        slave.setupExperiment(startTime=0.0)
        slave.enterInitializationMode()
        capfd.readouterr()
        slave.exitInitializationMode()
        err = capfd.readouterr().err
    finally:
        slave.terminate()
        slave.freeInstance()
    warned = [m for status, m in logged if status == 1]   # fmi2Warning
    for text in (reader, water):
        assert sum(text in m for m in warned) == 1, logged
        assert sum(text in line for line in err.splitlines()) == 1, err
