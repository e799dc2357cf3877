"""The native FMU (clients/fmu/native.py, C binary in clients/fmu/native_c/): FMI 2.0 and 3.0,
exported from the Task-10 sphere in heave and imported with fmpy against a separately started
`hydrolink serve`.

- It passes fmpy's validation, its binary depends on the C library alone (no Python, no libzmq),
  and its model description tells the truth (fixed step, dependencies, units, A_inf).
- An iterating master written here (Newmark, fixed point on the force, A_inf from the FMU in its
  mass) that also rejects and redoes steps with Get/SetFMUState: heave RAO against the frequency
  domain of the same HDB (0.5 %), and the same run without rejections bit for bit.
- Errors reach the importer as an FMI status with a logged message: no server, a wrong step."""

from __future__ import annotations

import shutil
import subprocess
import zipfile
from pathlib import Path

import numpy as np
import pytest
from conftest import (SPHERE_WATER, regular_waves, rm3_float, rm3_spar, scene_toml, serve_process, sphere_body,
                      write_scene)

# One pytest-xdist worker runs this whole module (pyproject: --dist loadgroup): its module fixtures (a server
# process, the native FMUs compiled, a straight run) cost ~12 s, paid once per worker otherwise.
pytestmark = pytest.mark.xdist_group("fmu_native")

DT, DURATION, FIT_FROM = 0.02, 60.0, 35.0


def _needs_compiler():
    if shutil.which("cc") is None and shutil.which("gcc") is None:
        pytest.skip("needs a C compiler (Debian package gcc)")


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    with serve_process("--store", str(tmp_path_factory.mktemp("store"))) as address:
        yield address


@pytest.fixture(scope="module")
def omega(sphere) -> float:
    return float(sphere["omega"].values[23])      # 1.2 rad/s, an HDB frequency


@pytest.fixture(scope="module")
def fmus(tmp_path_factory, sphere_path, sphere, omega) -> dict[int, Path]:
    _needs_compiler()
    from hydrolink.clients.fmu.native import export_native_fmu
    folder = tmp_path_factory.mktemp("native_fmu")
    shutil.copy(sphere_path, folder / "sphere.h5")
    mass = 1000.0 * float(sphere["displaced_volume"].values[0])
    write_scene(folder, scene_toml(dt=DT, duration=DURATION, water=SPHERE_WATER,
                                   waves=regular_waves(1.0, 2 * np.pi / omega, ramp=10.0), hydro={"irf_duration": 15.0},
                                   bodies=[sphere_body("sphere.h5", mass=mass, dofs=["heave"])]))
    return {fmi: export_native_fmu(folder / "scene.toml", folder / f"sphere{fmi}.fmu", fmi=fmi, progress=False)[0]
            for fmi in (2, 3)}


class Slave:
    """One FMU instance through fmpy, the same few calls for FMI 2 and 3; log lines collected."""

    def __init__(self, path: Path, fmi: int, tmp: Path, server: str, timeout: float = 120.0):
        """``timeout``: the FMU's wait for each server reply; the set-up's reply at load 8-10 (a
        loaded 2-core machine) took over the 30 s this used to be."""
        from fmpy import extract, read_model_description
        self.md = read_model_description(path)
        self.vr = {v.name: v.valueReference for v in self.md.modelVariables}
        self.fmi, self.log, self.statuses = fmi, [], []     # each message and its FMI status (1: warning)
        unzipped = extract(path, unzipdir=tmp / f"fmu{fmi}")
        if fmi == 2:
            from fmpy.fmi2 import FMU2Slave, fmi2CallbackFunctions, fmi2CallbackLoggerTYPE, fmi2CallbackAllocateMemoryTYPE, fmi2CallbackFreeMemoryTYPE
            from fmpy import calloc, free
            self.fmu = FMU2Slave(guid=self.md.guid, unzipDirectory=unzipped,
                                 modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName="hydro")
            cb = fmi2CallbackFunctions()
            cb.logger = fmi2CallbackLoggerTYPE(lambda env, name, status, cat, msg, *a: self._logged(status, msg))
            cb.allocateMemory = fmi2CallbackAllocateMemoryTYPE(calloc)
            cb.freeMemory = fmi2CallbackFreeMemoryTYPE(free)
            self._cb = cb
            self.fmu.instantiate(callbacks=cb)
            self.fmu.setupExperiment(startTime=0.0)
            self.fmu.setString([self.vr["server_address"]], [server])
            self.fmu.setReal([self.vr["timeout"]], [timeout])
            self.fmu.enterInitializationMode()
        else:
            from fmpy.fmi3 import FMU3Slave, fmi3LogMessageCallback
            self.fmu = FMU3Slave(guid=self.md.instantiationToken, unzipDirectory=unzipped,
                                 modelIdentifier=self.md.coSimulation.modelIdentifier, instanceName="hydro")
            self._cb = fmi3LogMessageCallback(lambda env, status, cat, msg: self._logged(status, msg))
            self.fmu.instantiate(logMessage=self._cb)
            self.fmu.setString([self.vr["server_address"]], [server])
            self.fmu.setFloat64([self.vr["timeout"]], [timeout])
            self.fmu.enterInitializationMode()

    def _logged(self, status: int, message: bytes) -> None:
        self.log.append(message.decode())
        self.statuses.append(int(status))

    def start(self) -> None:
        """Leave initialization (the FMU's hello to the server); a failure carries the FMU's log."""
        from fmpy.fmi1 import FMICallException
        try:
            self.fmu.exitInitializationMode()
        except FMICallException as exc:
            exc.add_note(f"the FMU logged: {self.log}")
            raise

    def set(self, names, values) -> None:
        (self.fmu.setReal if self.fmi == 2 else self.fmu.setFloat64)([self.vr[n] for n in names], list(values))

    def get(self, names) -> list[float]:
        return (self.fmu.getReal if self.fmi == 2 else self.fmu.getFloat64)([self.vr[n] for n in names])

    def step(self, t: float, h: float) -> None:
        self.fmu.doStep(t, h) if self.fmi == 2 else self.fmu.doStep(t, h)

    def save(self):
        return self.fmu.getFMUstate() if self.fmi == 2 else self.fmu.getFMUState()

    def restore(self, state) -> None:
        self.fmu.setFMUstate(state) if self.fmi == 2 else self.fmu.setFMUState(state)

    def release(self, state) -> None:
        self.fmu.freeFMUstate(state) if self.fmi == 2 else self.fmu.freeFMUState(state)

    def close(self) -> None:
        self.fmu.terminate()
        self.fmu.freeInstance()


def master(slave: Slave, mass: float, reject_every: int = 0, steps: int | None = None
           ) -> tuple[np.ndarray, np.ndarray, int]:
    """Newmark (average acceleration), M = mass + A_inf (read from the FMU): at every step the
    force at t_k+1 is iterated to a fixed point (inputs set again at the same point). With
    ``reject_every``, every such step is first taken with a poor guess and one pass, then rejected:
    the FMU state saved at t_k is restored and the step is taken again."""
    a_inf = slave.get(["A_inf.sphere.heave.sphere.heave"])[0]
    big_m = mass + a_inf
    names_in = ["sphere.heave.displacement", "sphere.heave.velocity"]
    u = v = 0.0
    slave.set(names_in, [u, v])
    f, eta = slave.get(["sphere.heave.force", "wave_elevation"])
    a = f / big_m
    n = round(DURATION / DT) if steps is None else steps
    zs, etas, redos = [u], [eta], 0
    for k in range(n):
        t = k * DT
        state = slave.save()
        if reject_every and k % reject_every == 3:
            slave.step(t, DT)
            slave.set(names_in, [0.0, 0.0])          # a poor first try, then rejected
            slave.get(["sphere.heave.force"])
            slave.restore(state)
            redos += 1
        slave.step(t, DT)
        a_new = a
        for _ in range(30):
            u1 = u + DT * v + 0.25 * DT * DT * (a + a_new)
            v1 = v + 0.5 * DT * (a + a_new)
            slave.set(names_in, [u1, v1])
            f, eta = slave.get(["sphere.heave.force", "wave_elevation"])
            a_next = f / big_m
            done = abs(a_next - a_new) <= 1e-12 * max(1.0, abs(a_next))
            a_new = a_next
            if done:
                break
        slave.release(state)
        u, v, a = u + DT * v + 0.25 * DT * DT * (a + a_new), v + 0.5 * DT * (a + a_new), a_new
        zs.append(u)
        etas.append(eta)
    return np.array(zs), np.array(etas), redos


def complex_amplitude(t, y, w):
    basis = np.column_stack([np.cos(w * t), np.sin(w * t), np.ones_like(t)])
    coef = np.linalg.lstsq(basis, y, rcond=None)[0]
    return complex(coef[0], coef[1])


def rao_error(t, z, eta, sphere, omega: float, mass: float, label: str) -> tuple[float, float]:
    """(|RAO| / |RAO_FD| - 1, phase difference in degrees) of the heave z against the elevation,
    fitted after FIT_FROM, against X / (C - w^2 (m + A) - i w B) at the HDB frequency ``omega``."""
    late = t >= FIT_FROM
    rao = complex_amplitude(t[late], z[late], omega) / complex_amplitude(t[late], eta[late], omega)
    k = int(np.flatnonzero(sphere["omega"].values == omega)[0])
    a, b = sphere["added_mass"].values[k, 2, 2], sphere["radiation_damping"].values[k, 2, 2]
    ref = sphere["excitation_force"].values[k, 0, 2] / (
        sphere["hydrostatic_stiffness"].values[2, 2] - omega ** 2 * (mass + a) - 1j * omega * b)
    err, phase = abs(rao) / abs(ref) - 1, float(np.angle(rao / ref, deg=True))
    print(f"{label}: |RAO| {abs(rao):.5f} against {abs(ref):.5f} ({err:+.2e}), phase {phase:+.3f} deg")
    return err, phase


def test_validates_links_no_python_and_tells_the_truth(fmus, sphere):
    from fmpy import read_model_description
    from fmpy.validation import validate_fmu
    for fmi, path in fmus.items():
        assert validate_fmu(str(path)) == [], fmi
        with zipfile.ZipFile(path) as z:
            binary = next(n for n in z.namelist() if n.startswith("binaries/") and n.endswith(".so"))
            so = path.parent / f"check{fmi}.so"
            so.write_bytes(z.read(binary))
        libs = subprocess.run(["ldd", str(so)], capture_output=True, text=True).stdout
        needed = {line.split()[0] for line in libs.splitlines() if "=>" in line}
        assert needed <= {"libc.so.6", "libm.so.6"}, libs
        md = read_model_description(path)
        cs = md.coSimulation
        assert not cs.canHandleVariableCommunicationStepSize
        assert cs.canGetAndSetFMUstate          # fmpy reads FMI 3's canGetAndSetFMUState into the same field
        by_name = {v.name: v for v in md.modelVariables}
        for v in md.modelVariables:
            assert v.description, v.name
            if v.type in ("Real", "Float64"):
                assert v.unit, v.name
        assert by_name["sphere.heave.force"].unit == "N" and by_name["sphere.heave.displacement"].unit == "m"
        a_inf = by_name["A_inf.sphere.heave.sphere.heave"]   # outputs: what masters can connect
        assert (a_inf.causality, a_inf.variability, a_inf.unit) == ("output", "constant", "kg")
        assert float(a_inf.start) == float(sphere["added_mass_inf"].values[2, 2])
        k_hs, net = by_name["K_hs.sphere.heave.sphere.heave"], by_name["sphere.heave.net_buoyancy"]
        assert (k_hs.causality, k_hs.unit, net.causality, net.unit) == ("output", "N/m", "output", "N")
        assert float(k_hs.start) == float(sphere["hydrostatic_stiffness"].values[2, 2])
        deps = {u.variable.name: sorted(d.name for d in u.dependencies) for u in md.outputs}
        assert deps["sphere.heave.force"] == ["sphere.heave.displacement", "sphere.heave.velocity"]
        assert deps["sphere.heave.hydrostatic"] == ["sphere.heave.displacement"]
        assert deps["sphere.heave.radiation"] == ["sphere.heave.velocity"]
        assert deps["sphere.heave.dynamic"] == ["sphere.heave.velocity"]
        assert deps["sphere.heave.excitation"] == [] and deps["wave_elevation"] == []
        assert md.defaultExperiment.stepSize == str(DT) or float(md.defaultExperiment.stepSize) == DT


def coupled_run(path: Path, fmi: int, server: str, sphere, folder: Path, reject_every: int,
                steps: int | None = None):
    """The iterating master's run of the sphere with the FMU at ``path`` (``steps``: of DT, default
    the whole DURATION)."""
    slave = Slave(path, fmi, folder, server)
    slave.start()
    try:
        assert slave.get(["A_inf.sphere.heave.sphere.heave"])[0] == pytest.approx(
            float(sphere["added_mass_inf"].values[2, 2]), rel=1e-12)
        return master(slave, 1000.0 * float(sphere["displaced_volume"].values[0]), reject_every, steps)
    finally:
        slave.close()


@pytest.fixture(scope="module")
def straight_run(fmus, server, sphere, tmp_path_factory):
    """The FMI 2 FMU under the iterating master, no step rejected."""
    return coupled_run(fmus[2], 2, server, sphere, tmp_path_factory.mktemp("straight"), 0)


@pytest.mark.parametrize("fmi", [2, 3])
def test_iterating_master_with_rollback_against_the_frequency_domain(fmi, fmus, server, sphere, omega, tmp_path,
                                                                     straight_run):
    """FMI 2: the whole run with every 7th step rejected and redone equals the straight run bit
    for bit, and its RAO the frequency domain's. FMI 3 (its own Get/SetFMUState code, twice as slow
    under fmpy): the first 20 s with rejections equal the FMI 2 straight run bit for bit."""
    steps = None if fmi == 2 else round(20.0 / DT)
    z, eta, redos = coupled_run(fmus[fmi], fmi, server, sphere, tmp_path, 7, steps)
    assert redos == len(range(3, steps or round(DURATION / DT), 7))
    assert np.array_equal(z, straight_run[0][:z.size]) and np.array_equal(eta, straight_run[1][:eta.size])
    if fmi == 3:
        return
    mass = 1000.0 * float(sphere["displaced_volume"].values[0])
    err, phase = rao_error(np.arange(z.size) * DT, z, eta, sphere, omega, mass,
                           f"FMI {fmi}, {redos} steps rejected and redone")
    assert abs(err) <= 0.005 and abs(phase) <= 0.5


@pytest.mark.parametrize("fmi", [2, 3])
def test_errors_are_fmi_statuses_with_a_logged_message(fmi, fmus, server, tmp_path):
    from fmpy.fmi1 import FMICallException
    nobody = "tcp://127.0.0.1:9"                       # the discard port: nothing listens
    slave = Slave(fmus[fmi], fmi, tmp_path / "none", nobody, timeout=1.0)
    with pytest.raises(FMICallException):
        slave.start()
    assert any("no hydrolink server answered at tcp://127.0.0.1:9" in line for line in slave.log), slave.log
    slave.fmu.freeInstance()
    slave = Slave(fmus[fmi], fmi, tmp_path / "step", server)
    slave.start()
    with pytest.raises(FMICallException):
        slave.step(0.0, 2 * DT)
    assert any("this FMU takes only its scene's dt" in line for line in slave.log), slave.log
    slave.close()


def test_simulate_fmu_against_a_separate_server(fmus, server, tmp_path):
    """fmpy's own master (simulate_fmu), the FMU alone with its inputs at rest: its excitation is
    the server's, bit for bit, as the Python client gets it for the same states."""
    from fmpy import simulate_fmu
    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.server.hdb.io import load_hdb
    for fmi, path in fmus.items():
        out = simulate_fmu(str(path), start_values={"server_address": server}, stop_time=2.0, step_size=DT,
                           output=["sphere.heave.excitation", "sphere.heave.force", "wave_elevation"])
        assert out["time"][-1] == pytest.approx(2.0)
        scene = (path.parent / "scene.toml").read_text()
        with ServerConnection(server) as conn:
            setup = conn.hello(scene, {"sphere.h5": load_hdb(path.parent / "sphere.h5")})
            rest = setup.equilibrium_position
            for k, t in enumerate(out["time"]):
                r = conn.step(k, k * DT, rest, np.zeros_like(rest))
                assert r["excitation"][0, 2] == out["sphere.heave.excitation"][k], (fmi, k)
        assert np.abs(out["sphere.heave.excitation"]).max() > 1e3


def test_libcosim_couples_it_to_a_body_fmu(fmus, server, sphere, omega, tmp_path):
    """libcosim (libcosimpy, a C++ master nobody here wrote) with its fixed-step algorithm: the
    native FMU's `dynamic` force (excitation + radiation) into tests/fmu_src's heave body FMU, whose
    added mass, hydrostatic stiffness and net buoyancy are the hydro FMU's constant outputs, wired
    by libcosim itself (the body's own a_inf and k_hs are 0); the body's state back. Every
    connection is accepted (status 0; A_inf as a calculated parameter was refused with -1 and a
    user who missed it ran with no added mass: RAO -33.7 %). An explicit master reads the forces
    before it sets the new state: the radiation lags a step; the heave RAO is within 0.5 % of the
    frequency-domain RAO X / (C - w^2 (m + A) - i w B) of the HDB (measured -0.40 %)."""
    pytest.importorskip("libcosimpy", reason="needs libcosimpy (pip install libcosimpy; in the test extras)")
    from libcosimpy.CosimExecution import CosimExecution
    from libcosimpy.CosimEnums import CosimVariableType
    from libcosimpy.CosimObserver import CosimObserver
    from libcosimpy.CosimSlave import CosimLocalSlave
    from fmpy import read_model_description
    from fmu_build import build_c_fmu
    body_fmu = build_c_fmu(tmp_path / "body")
    mass = 1000.0 * float(sphere["displaced_volume"].values[0])
    hydro_vr = {v.name: v.valueReference for v in read_model_description(fmus[2]).modelVariables}
    body_vr = {v.name: v.valueReference for v in read_model_description(body_fmu).modelVariables}
    ex = CosimExecution.from_step_size(step_size=int(round(DT * 1e9)))
    hydro = ex.add_local_slave(CosimLocalSlave(fmu_path=str(fmus[2]), instance_name="hydro"))
    body = ex.add_local_slave(CosimLocalSlave(fmu_path=str(body_fmu), instance_name="body"))
    assert ex.string_initial_value(hydro, hydro_vr["server_address"], server)
    for name, value in (("m", mass), ("a_inf", 0.0), ("k_hs", 0.0), ("c_pto", 0.0), ("z0", 0.0), ("v0", 0.0)):
        assert ex.real_initial_value(body, body_vr[name], value)
    for source, target in (("sphere.heave.dynamic", "F"), ("A_inf.sphere.heave.sphere.heave", "a_in"),
                           ("K_hs.sphere.heave.sphere.heave", "k_in"), ("sphere.heave.net_buoyancy", "F0")):
        assert ex.connect_real_variables(hydro, hydro_vr[source], body, body_vr[target]) == 0, source  # C API status
    assert ex.connect_real_variables(body, body_vr["z"], hydro, hydro_vr["sphere.heave.displacement"]) == 0
    assert ex.connect_real_variables(body, body_vr["v"], hydro, hydro_vr["sphere.heave.velocity"]) == 0
    observer = CosimObserver.create_time_series(buffer_size=round(DURATION / DT) + 10)
    ex.add_observer(observer)
    for slave, vr in ((body, body_vr["z"]), (hydro, hydro_vr["wave_elevation"]), (body, body_vr["a_in"]),
                      (body, body_vr["k_in"])):
        assert observer.start_time_series(slave, value_reference=vr, variable_type=CosimVariableType.REAL)
    assert ex.simulate_until(target_time=int(round(DURATION * 1e9)))
    n = round(DURATION / DT) + 1

    def series(slave, vr):
        return observer.time_series_real_samples(slave, value_reference=vr, from_step=0, sample_count=n)

    times, _, z = series(body, body_vr["z"])
    _, _, eta = series(hydro, hydro_vr["wave_elevation"])
    a_in, k_in = series(body, body_vr["a_in"])[2], series(body, body_vr["k_in"])[2]
    assert a_in[-1] == float(sphere["added_mass_inf"].values[2, 2])         # the hydro FMU's, through libcosim
    assert k_in[-1] == float(sphere["hydrostatic_stiffness"].values[2, 2])
    m = min(len(times), len(z), len(eta))
    t, z, eta = np.array(times[:m]) * 1e-9, np.array(z[:m]), np.array(eta[:m])
    assert t[-1] >= DURATION - 2 * DT
    err, _ = rao_error(t, z, eta, sphere, omega, mass, "libcosim (explicit), added mass from the hydro FMU")
    assert abs(err) <= 0.005


def test_constant_radiation_publishes_the_added_mass_at_omega0_by_that_name(sphere, sphere_path, tmp_path):
    """radiation = "constant": the mass-matrix output carries A(omega0) (the HDB's A33 at the wave
    frequency, a grid frequency) and is named and described so, not as A_inf; the stiffness and
    net buoyancy (rho g V - m g, the body 10 % lighter than its displacement) are published."""
    _needs_compiler()
    from fmpy import read_model_description
    from hydrolink.clients.fmu.native import export_native_fmu
    shutil.copy(sphere_path, tmp_path / "sphere.h5")
    om = sphere["omega"].values
    i = int(np.argmin(np.abs(om - 2 * np.pi / 5.0)))
    rho_v = 1000.0 * float(sphere["displaced_volume"].values[0])
    write_scene(tmp_path, scene_toml(dt=DT, duration=10.0, water=SPHERE_WATER,
                                     waves=regular_waves(1.0, 2 * np.pi / float(om[i]), ramp=5.0),
                                     hydro={"radiation": "constant"},
                                     bodies=[sphere_body("sphere.h5", mass=0.9 * rho_v, dofs=["heave"])]))
    fmu, _ = export_native_fmu(tmp_path / "scene.toml", tmp_path / "constant.fmu", fmi=2, progress=False)
    by_name = {v.name: v for v in read_model_description(fmu).modelVariables}
    assert not any(name.startswith("A_inf.") for name in by_name)
    a = by_name["A_omega0.sphere.heave.sphere.heave"]
    assert float(a.start) == pytest.approx(float(sphere["added_mass"].values[i, 2, 2]), rel=1e-9)
    assert abs(float(sphere["added_mass_inf"].values[2, 2]) / float(a.start) - 1) > 0.03   # they differ
    assert "A(omega0)" in a.description and f"omega0 = {float(om[i]):.6g} rad/s" in a.description
    net = float(by_name["sphere.heave.net_buoyancy"].start)
    assert net == pytest.approx(0.1 * rho_v * 9.81, rel=1e-9)


def test_two_bodies_from_wamit_files_give_the_servers_forces(tmp_path, reference_data, server):
    """RM3 (float and spar, heave and pitch active: 4 inputs of each kind), its HDB as the WAMIT
    run's five files: every output equals, bit for bit, what the Python client gets for the same
    states (force = excitation + radiation + hydrostatic + net buoyancy); the dependencies hold the
    float-spar coupling of the radiation feedthrough."""
    _needs_compiler()
    from fmpy import read_model_description
    from conftest import rm3_float, rm3_spar
    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.clients.fmu.native import export_native_fmu
    from hydrolink.server.hdb.io import load_hdb
    for name in ("rm3.1", "rm3.3", "rm3.hst", "rm3.out", "rm3.cfg"):
        shutil.copy(reference_data / "rm3_wamit" / name, tmp_path / name)
    dofs = ["heave", "pitch"]
    path = write_scene(tmp_path, scene_toml(dt=0.05, duration=20.0, waves=regular_waves(2.0, 8.0, ramp=5.0),
                                            hydro={"irf_duration": 20.0},
                                            bodies=[rm3_float("rm3.1", dofs=dofs), rm3_spar("rm3.1", dofs=dofs)]))
    fmu, _ = export_native_fmu(path, tmp_path / "rm3.fmu", fmi=3, progress=False)
    md = read_model_description(fmu)
    deps = {u.variable.name: sorted(d.name for d in u.dependencies) for u in md.outputs}
    assert "spar.heave.velocity" in deps["float.heave.radiation"]            # coupled through the HDB
    labels = [f"{b}.{d}" for b in ("float", "spar") for d in dofs]
    slave = Slave(fmu, 3, tmp_path, server)
    slave.start()
    rng = np.random.default_rng(3)
    scene_text = path.read_text()
    try:
        with ServerConnection(server) as conn:
            setup = conn.hello(scene_text, {"rm3.1": load_hdb(tmp_path / "rm3.1")})
            active = np.flatnonzero(setup.active.reshape(-1))
            net = np.where(active % 6 == 2, setup.net_buoyancy[active // 6], 0.0)
            for k in range(60):
                x, v = 0.05 * rng.standard_normal(4), 0.2 * rng.standard_normal(4)
                slave.set([f"{lab}.displacement" for lab in labels] + [f"{lab}.velocity" for lab in labels], [*x, *v])
                got = np.array(slave.get([f"{lab}.{q}" for q in ("force", "excitation", "radiation", "hydrostatic")
                                          for lab in labels])).reshape(4, 4)
                pos, vel = setup.equilibrium_position.copy().reshape(-1), np.zeros(12)
                pos[active] += x
                vel[active] = v
                r = conn.step(k, k * 0.05, pos.reshape(2, 6), vel.reshape(2, 6))
                parts = [np.asarray(r[f]).reshape(-1)[active] for f in ("excitation", "radiation", "hydrostatic")]
                parts[2] = parts[2] + net
                assert np.array_equal(got[1:], np.array(parts)), k
                assert np.array_equal(got[0], parts[0] + parts[1] + parts[2]), k
                slave.step(k * 0.05, 0.05)
    finally:
        slave.close()


@pytest.mark.parametrize("fmi", [2, 3])
def test_setup_warnings_reach_the_importers_logger(fmi, server, reference_data, tmp_path):
    """SPEC §5.1: a client shows every setup warning. The RM3 Capytaine file records no rotation
    centre (its reader's warning, raised in the server's child process that parses the files the FMU
    sends by hash) and the scene's sea water differs from its 1000 kg/m³ (the server's own): both
    reach the importer's logger once each, at FMI status warning (1 in FMI 2 and 3), without debug
    logging, and the export's notes say them too."""
    _needs_compiler()
    from hydrolink.clients.fmu.native import export_native_fmu
    shutil.copy(reference_data / "rm3_capytaine" / "rm3_hydrodynamics.nc", tmp_path / "rm3.nc")
    write_scene(tmp_path, scene_toml(dt=0.1, duration=1.0, hydro={"irf_duration": 10.0},
                                     bodies=[rm3_float("rm3.nc", dofs=["heave"]), rm3_spar("rm3.nc", dofs=["heave"])]))
    fmu, notes = export_native_fmu(tmp_path / "scene.toml", tmp_path / f"rm3_{fmi}.fmu", fmi=fmi, progress=False)
    reader, water = "rm3.nc: no rotation_center or center_of_mass recorded", "water: the scene's density 1025 kg/m^3"
    assert sum(reader in n for n in notes) == 1 and sum(water in n for n in notes) == 1, notes
    slave = Slave(fmu, fmi, tmp_path, server)
    try:
        slave.start()
        warned = [m for m, st in zip(slave.log, slave.statuses) if st == 1]
        assert sum(reader in m for m in warned) == 1 and sum(water in m for m in warned) == 1, slave.log
        assert not any("hydrolink-hdb-" in m for m in warned)      # named as sent, not by the server's folder
        assert 3 not in slave.statuses, slave.log                  # no error
    finally:
        slave.close()


def test_the_binary_is_compiled_once_and_a_changed_source_compiles_anew(tmp_path, monkeypatch):
    """compile_binary keeps the compiled library in the binary cache: a second export copies the same
    bytes without compiling (the cached file is not rewritten), and a changed source (here: a
    copy of the sources with one comment added) gets a binary of its own."""
    _needs_compiler()
    from hydrolink.clients.fmu import native

    monkeypatch.setenv("HYDROLINK_FMU_BINARIES", str(tmp_path / "cache"))
    native.compile_binary(2, tmp_path / "a.so")
    (cached,) = (tmp_path / "cache").iterdir()
    stamp = cached.stat().st_mtime_ns
    native.compile_binary(2, tmp_path / "b.so")
    assert (tmp_path / "a.so").read_bytes() == (tmp_path / "b.so").read_bytes() == cached.read_bytes()
    assert cached.stat().st_mtime_ns == stamp and len(list((tmp_path / "cache").iterdir())) == 1
    sources = tmp_path / "src"
    shutil.copytree(native.SOURCES, sources)
    (sources / "hydro_core.c").write_text((sources / "hydro_core.c").read_text() + "\n/* changed */\n")
    monkeypatch.setattr(native, "SOURCES", sources)
    native.compile_binary(2, tmp_path / "c.so")
    assert len(list((tmp_path / "cache").iterdir())) == 2
