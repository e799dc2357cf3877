"""FMU master against the real force server on the Task-10 sphere in heave, with test FMUs built
here from tests/fmu_src: a C FMI 2.0 FMU (A∞ and hydrostatic stiffness as parameters), a
pythonfmu FMI 2.0 FMU and its pythonfmu3 FMI 3.0 twin (no A∞ parameter: iterative coupling with
rollback).

References: the frequency-domain heave RAO with the PTO damping, computed here from the HDB, and
the Exudyn client on the same scene with a linear PTO to ground.
"""

from __future__ import annotations

from pathlib import Path
from typing import NamedTuple

import numpy as np
import pytest
import xarray as xr
from fmpy.validation import validate_fmu

from conftest import REPLY_S, SPHERE_WATER, linear_pto, regular_waves, scene_toml, sphere_body, write_scene
from fmu_build import build_c_fmu, build_python3_fmu, build_python_fmu
from hydrolink.clients.fmu import master as fmu_client
from hydrolink.clients.lockstep.connection import ServerConnection
from hydrolink.clients.exudyn.client import SimulationDiverged
from hydrolink.clients.lockstep.results import ResultWriter
from hydrolink.protocol.scene import SceneError, parse_scene

HEAVE = 2
C_PTO = 2.0e5            # N s/m
REPORT: dict[str, str] = {}


@pytest.fixture(scope="module")
def rho_v(sphere) -> float:
    """The sphere's displaced mass: floating at equilibrium with no net buoyancy."""
    return float(1000.0 * sphere["displaced_volume"].values[0])


@pytest.fixture(scope="module")
def fmus(tmp_path_factory) -> dict[str, Path]:
    root = tmp_path_factory.mktemp("fmus")
    return {"c": build_c_fmu(root), "py": build_python_fmu(root), "py3": build_python3_fmu(root),
            "py-nostate": build_python_fmu(root, handle_state=False)}


def base_scene(hdb: Path, mass: float, period: float, *, dt_per_period: int = 100, periods: int = 20,
               height: float = 1.0, still: bool = False, client: dict | None = None, ptos: list[dict] | None = None,
               coupling: dict | None = None, **body_keys) -> str:
    """The sphere in heave in regular waves of ``period`` (or still water), run by ``client`` with
    ``coupling`` as the scene's [coupling]."""
    waves = regular_waves(height, period, ramp=2 * period) if not still else {"type": "still"}
    return scene_toml(dt=period / dt_per_period, duration=periods * period, water=SPHERE_WATER, waves=waves,
                      bodies=[sphere_body(str(hdb), mass=mass, dofs=["heave"], **body_keys)], client=client, ptos=ptos,
                      coupling=coupling)


def fmu_section(fmu: Path, mass: float, *, a_inf: bool, c_pto: float = C_PTO,
                parameters: dict | None = None, variables: dict | None = None, **keys) -> dict:
    """[client] for a test FMU of tests/fmu_src: m and c_pto as parameters, heave z, v in and F out;
    with ``a_inf`` A∞ and the hydrostatic stiffness go to its parameters too. ``variables``
    replaces entries of the sphere's variable map."""
    sphere = {"position": {"heave": "z"}, "velocity": {"heave": "v"}, "force": {"heave": "F"}}
    if a_inf:
        sphere.update(added_mass={"heave": "a_inf"}, hydrostatic_stiffness={"heave": "k_hs"})
    return {"type": "fmu", "fmu": str(fmu), **keys, "parameters": {"m": mass, "c_pto": c_pto, **(parameters or {})},
            "bodies": {"sphere": {**sphere, **(variables or {})}}}


def run_fmu(address: str, text: str, hdb, out: Path, **kw) -> tuple[dict, xr.Dataset]:
    scene = parse_scene(text)
    with ServerConnection(address, timeout=REPLY_S) as conn:
        setup = conn.hello(text, {scene.bodies[0].hdb: hdb})
        with ResultWriter(out, scene=scene, scene_text=text, setup=setup) as writer:
            summary = fmu_client.run(scene, text, conn, setup, writer, progress=False, **kw)
        conn.bye()
    return summary, xr.load_dataset(out)


def steady_heave(ds: xr.Dataset, omega: float, periods: int = 4) -> complex:
    """Complex heave amplitude per unit wave amplitude over the last ``periods`` periods."""
    t = ds["time"].values
    z = ds["position"].values[:, 0, HEAVE] - ds["equilibrium_position"].values[0, HEAVE]
    fit = t >= t[-1] - periods * 2 * np.pi / omega - 1e-9
    basis = np.c_[np.cos(omega * t[fit]), np.sin(omega * t[fit]), np.ones(fit.sum())]
    cz = np.linalg.lstsq(basis, z[fit], rcond=None)[0]
    ce = np.linalg.lstsq(basis, ds["wave_elevation"].values[fit], rcond=None)[0]
    return complex(cz[0], cz[1]) / complex(ce[0], ce[1])


def mean_power(t: np.ndarray, energy: np.ndarray, omega: float, periods: int = 4) -> float:
    """Mean PTO power over whole periods at the end, from the FMU's absorbed-energy output."""
    i0 = int(np.argmax(t >= t[-1] - periods * 2 * np.pi / omega - 1e-9))
    return float((energy[-1] - energy[i0]) / (t[-1] - t[i0]))


def reference(sphere, mass: float, omega_target: float, c_pto: float = C_PTO, height: float = 1.0):
    """(omega, heave RAO, mean PTO power) in the frequency domain, at an HDB frequency."""
    i = int(np.argmin(np.abs(sphere["omega"].values - omega_target)))
    w = float(sphere["omega"].values[i])
    a = sphere["added_mass"].values[i, HEAVE, HEAVE]
    b = sphere["radiation_damping"].values[i, HEAVE, HEAVE]
    x = sphere["excitation_force"].values[i, 0, HEAVE]
    c = sphere["hydrostatic_stiffness"].values[HEAVE, HEAVE]
    rao = x / (-w ** 2 * (mass + a) - 1j * w * (b + c_pto) + c)
    return w, rao, 0.5 * c_pto * (w * abs(rao) * height / 2) ** 2


# ------------------------------------------------------------------------------------ the FMUs

def test_test_fmus_pass_fmpy_validation(fmus):
    from fmpy import read_model_description
    for name, path in fmus.items():
        assert validate_fmu(str(path)) == [], name
    mds = {k: read_model_description(str(p)) for k, p in fmus.items()}
    assert {k: md.coSimulation.canGetAndSetFMUstate for k, md in mds.items()} == {
        "c": True, "py": True, "py3": True, "py-nostate": False}
    assert {k: md.fmiVersion for k, md in mds.items()} == {"c": "2.0", "py": "2.0", "py3": "3.0", "py-nostate": "2.0"}


# ------------------------------------------------------------------------------------ physics

@pytest.mark.parametrize("which", ["c", "py", "py3"])
def test_fmu_heave_and_pto_power_match_frequency_domain(server, sphere, sphere_path, rho_v, fmus, tmp_path,
                                                        which):
    w, rao, power = reference(sphere, rho_v, 1.45)
    period = 2 * np.pi / w
    text = base_scene(sphere_path, rho_v, period, client=fmu_section(fmus[which], rho_v, a_inf=which == "c"))
    summary, ds = run_fmu(server, text, sphere, tmp_path / "run.nc", record=["E_pto"])
    got = steady_heave(ds, w)
    p = mean_power(ds["time"].values, summary.recorded["E_pto"], w)
    amp_err, p_err = abs(got) / abs(rao) - 1, p / power - 1
    REPORT[f"fd {which}"] = (f"{which}: mode {summary.coupling.scheme}, |RAO| {abs(rao):.4f}, amplitude error "
                             f"{amp_err:+.2e}, power {p:.0f} W vs {power:.0f} W ({p_err:+.2e}), "
                             f"iterations/step {summary.coupling.iterations_mean:.2f} (max {summary.coupling.iterations_max}), "
                             f"client {summary.client_us_per_step:.0f} us/step (FMU {summary.fmu_us_per_step:.0f}), "
                             f"round trip {summary.round_trip_us_per_step:.0f} us/step")
    print(REPORT[f"fd {which}"])
    assert summary.coupling.scheme == ("mass-matrix" if which == "c" else "implicit")
    assert summary.fmi_version == ("3.0" if which == "py3" else "2.0")
    assert abs(amp_err) < 0.01 and abs(p_err) < 0.01
    assert abs(np.degrees(np.angle(got / rao))) < 1.0


# ------------------------------------------------------------------------------------ light body

LIGHT = 0.2      # mass / (rho V): A∞/m = 2.5


def test_light_body_explicit_is_refused_and_would_blow_up(server, sphere, sphere_path, rho_v, fmus, tmp_path):
    mass = LIGHT * rho_v
    period = 2 * np.pi / 1.45
    text = base_scene(sphere_path, mass, period, periods=4,
                      client=fmu_section(fmus["py"], mass, a_inf=False), coupling={"scheme": "explicit-predictor"})
    with pytest.raises(SceneError, match=r"coupling.scheme: refused: explicit .* ratio .* is 2.5\d* > "):
        run_fmu(server, text, sphere, tmp_path / "refused.nc")
    # forced past the refusal, the lagged -A∞·a feedback grows by ~A∞/m per step and blows up
    with pytest.raises(SimulationDiverged, match='coupling.scheme = "explicit-predictor"') as err:
        run_fmu(server, text, sphere, tmp_path / "blown.nc", allow_unstable=True)
    REPORT["explicit blow-up"] = f"explicit at A∞/m = 2.5 diverged at step {err.value.step}"
    print(REPORT["explicit blow-up"])
    assert err.value.step < 100


def test_no_rollback_and_no_added_mass_parameter_is_refused(server, sphere, sphere_path, rho_v, fmus, tmp_path):
    mass = LIGHT * rho_v
    text = base_scene(sphere_path, mass, 4.0, periods=1, client=fmu_section(fmus["py-nostate"], mass, a_inf=False))
    with pytest.raises(SceneError, match=r"refused to run: A∞ is not passed .* cannot roll back "
                                         r"\(canGetAndSetFMUstate is false\), and explicit"):
        run_fmu(server, text, sphere, tmp_path / "refused.nc")
    text = base_scene(sphere_path, mass, 4.0, periods=1,
                      client=fmu_section(fmus["py-nostate"], mass, a_inf=False), coupling={"scheme": "implicit"})
    with pytest.raises(SceneError, match="implicit coupling needs rollback"):
        run_fmu(server, text, sphere, tmp_path / "refused.nc")


def test_explicit_at_a_small_ratio_is_stable_but_lagged(server, sphere, sphere_path, rho_v, fmus, tmp_path):
    """Ratio A∞/m = 0.5 (≤ explicit_limit 0.6): explicit runs and stays bounded, but the lagged −A∞·a
    damps the response by ≈ A∞·dt·ω² — which is why `auto` never picks it."""
    w, rao, _ = reference(sphere, rho_v, 1.45)
    client = fmu_section(fmus["c"], rho_v, a_inf=False)
    summary, ds = run_fmu(server, base_scene(sphere_path, rho_v, 2 * np.pi / w, client=client, coupling={
                              "scheme": "explicit-predictor", "explicit_limit": 0.6}), sphere,
                          tmp_path / "explicit.nc")
    err = abs(steady_heave(ds, w)) / abs(rao) - 1
    REPORT["explicit 0.5"] = f"explicit at A∞/m = {summary.coupling.added_mass_ratio:.2f}: amplitude error {err:+.2e}"
    print(REPORT["explicit 0.5"])
    assert summary.coupling.scheme == "explicit-predictor"
    assert -0.08 < err < -0.01
    heavier = 1.001 * rho_v     # ratio just under 0.5: `auto` still refuses, naming the explicit option
    with pytest.raises(SceneError, match=r'scheme = "explicit-predictor" would be stable here \(ratio 0.5\d* ≤ 0.5\) '
                                         r'but lags'):
        run_fmu(server, base_scene(sphere_path, heavier, 4.0, periods=1, coupling={"explicit_limit": 0.5},
                                   client=fmu_section(fmus["py-nostate"], heavier, a_inf=False)),
                sphere, tmp_path / "refused.nc")


def test_light_body_iterative_is_stable_and_accurate(server, sphere, sphere_path, rho_v, fmus, tmp_path):
    mass = LIGHT * rho_v
    a_inf = float(sphere["added_mass_inf"].values[HEAVE, HEAVE])
    assert a_inf / mass >= 2
    w, rao, power = reference(sphere, mass, 1.45)
    period = 2 * np.pi / w
    text = base_scene(sphere_path, mass, period, client=fmu_section(fmus["py"], mass, a_inf=False))
    summary, ds = run_fmu(server, text, sphere, tmp_path / "light.nc", record=["E_pto"])
    got = steady_heave(ds, w)
    p = mean_power(ds["time"].values, summary.recorded["E_pto"], w)
    its = summary.coupling.iterations
    REPORT["light iterative"] = (f"A∞/m = {a_inf / mass:.2f}: mode {summary.coupling.scheme}, iterations/step mean "
                                 f"{its.mean():.2f}, median {np.median(its):.0f}, max {its.max()}; amplitude error "
                                 f"{abs(got) / abs(rao) - 1:+.2e}, power error {p / power - 1:+.2e}")
    print(REPORT["light iterative"])
    assert summary.coupling.scheme == "implicit"
    assert abs(abs(got) / abs(rao) - 1) < 0.01 and abs(p / power - 1) < 0.01
    assert its.mean() <= 3.5 and its.max() <= 10


# ------------------------------------------------------------------------------------ errors

def test_mapping_errors_name_the_key(server, sphere, sphere_path, rho_v, fmus, tmp_path):
    def scene(**body_keys) -> str:
        return base_scene(sphere_path, rho_v, 4.0, periods=1, **body_keys)

    bad = fmu_section(fmus["c"], rho_v, a_inf=True, variables={"velocity": {"heave": "w"}})
    with pytest.raises(SceneError, match=r"client.bodies.sphere.velocity.heave: the FMU heave_body.fmu has no "
                                         r"variable 'w'"):
        run_fmu(server, scene(client=bad), sphere, tmp_path / "e.nc")
    bad = fmu_section(fmus["c"], rho_v, a_inf=True, variables={"force": {"heave": "z"}})
    with pytest.raises(SceneError, match=r"force.heave: FMU variable 'z' has causality 'output', expected input"):
        run_fmu(server, scene(client=bad), sphere, tmp_path / "e.nc")
    moved = scene(client=fmu_section(fmus["c"], rho_v, a_inf=True), initial_displacement=[0, 0, 0.5, 0, 0, 0])
    with pytest.raises(SceneError, match=r"bodies\[0\].initial_displacement: the FMU starts at heave = 0 but "
                                         r"the scene says 0.5"):
        run_fmu(server, moved, sphere, tmp_path / "e.nc")
    step = fmu_section(fmus["c"], rho_v, a_inf=True, communication_step=0.015)
    with pytest.raises(SceneError, match="client.communication_step: must divide simulation.dt"):
        run_fmu(server, scene(client=step), sphere, tmp_path / "e.nc")


def test_initial_displacement_via_parameters_and_substeps(server, sphere, sphere_path, rho_v, fmus, tmp_path):
    """A decay from z0 = 0.5 m with the C FMU (z0 set as a parameter), communication step dt/4: the
    period of the free decay is 2π√((m + A∞)/C) within the memory effect (≈ 1 %)."""
    period = 4.0
    client = fmu_section(fmus["c"], rho_v, a_inf=True, c_pto=0.0, communication_step=period / 400,
                         parameters={"z0": 0.5})
    text = base_scene(sphere_path, rho_v, period, periods=3, still=True, client=client,
                      initial_displacement=[0, 0, 0.5, 0, 0, 0])
    summary, ds = run_fmu(server, text, sphere, tmp_path / "decay.nc")
    t = ds["time"].values
    z = ds["position"].values[:, 0, HEAVE] - ds["equilibrium_position"].values[0, HEAVE]
    assert z[0] == pytest.approx(0.5)
    crossings = t[1:][(z[:-1] > 0) & (z[1:] <= 0)]
    a_inf = float(sphere["added_mass_inf"].values[HEAVE, HEAVE])
    c = float(sphere["hydrostatic_stiffness"].values[HEAVE, HEAVE])
    t_n = 2 * np.pi * np.sqrt((rho_v + a_inf) / c)
    assert (crossings[1] - crossings[0]) == pytest.approx(t_n, rel=0.05)
    assert summary.coupling.scheme == "mass-matrix"


def test_hydrolink_run_dispatches_to_the_fmu_client(sphere, sphere_path, rho_v, fmus, tmp_path):
    """`hydrolink run` on a scene file with [client] type = "fmu" and an FMU path relative to it."""
    from click.testing import CliRunner
    from hydrolink.clients.cli import cli

    import shutil
    shutil.copy2(fmus["c"], tmp_path / "body.fmu")
    period = 2 * np.pi / 1.45
    scene = write_scene(tmp_path, base_scene(sphere_path, rho_v, period, periods=2,
                                             client=fmu_section(Path("body.fmu"), rho_v, a_inf=True)))
    result = CliRunner().invoke(cli, ["run", str(scene), "-o", str(tmp_path / "out.nc"), "--no-progress"])
    assert result.exit_code == 0, result.output
    ds = xr.load_dataset(tmp_path / "out.nc")
    assert ds.attrs["status"] == "complete" and ds.sizes["time"] == 201
    assert np.abs(ds["position"].values[:, 0, HEAVE] - ds["equilibrium_position"].values[0, HEAVE]).max() > 0.05
    write_scene(tmp_path, base_scene(sphere_path, rho_v, period, periods=2,
                                     client=fmu_section(Path("missing.fmu"), rho_v, a_inf=True),
                                     coupling={"scheme": "implicit"}))
    result = CliRunner().invoke(cli, ["run", str(scene), "-o", str(tmp_path / "out2.nc"), "--no-progress"])
    assert result.exit_code == 1 and "FMU not found" in result.output and "missing.fmu" in result.output


PTO_TO_GROUND = linear_pto("pto", "sphere", [0.0, 0.0, -2.0], "ground", [0.0, 0.0, -50.0], damping=C_PTO)


class NativeRun(NamedTuple):
    """What the FMU runs are compared with: the wave frequency (rad/s), the mean PTO power (W) over
    the last 4 periods, the steady heave (complex amplitude, m) and the wall time per step (s)."""
    omega: float
    power: float
    heave: complex
    step_time: float


@pytest.fixture(scope="module")
def native_run(sphere, sphere_path, rho_v, tmp_path_factory) -> NativeRun:
    """The scene of test_fmu_matches_exudyn_client_on_the_same_scene run natively (Exudyn, the PTO
    a `[[ptos]] type = "linear"` damper to ground), once for the three FMUs compared with it."""
    from hydrolink.clients.run import run_scene_file

    w = float(sphere["omega"].values[np.argmin(np.abs(sphere["omega"].values - 1.45))])
    period = 2 * np.pi / w
    folder = tmp_path_factory.mktemp("native")
    write_scene(folder, base_scene(sphere_path, rho_v, period, ptos=[PTO_TO_GROUND]), "native.toml")
    native = run_scene_file(folder / "native.toml", folder / "native.nc", progress=False)
    ds = xr.load_dataset(folder / "native.nc")
    t = ds["time"].values
    last = t >= t[-1] - 4 * period - 1e-9
    p_native = float(np.trapezoid(ds["total_pto_power"].values[last], t[last]) / (t[last][-1] - t[last][0]))
    return NativeRun(w, p_native, steady_heave(ds, w), native.wall_time / native.steps)


@pytest.mark.parametrize("which", ["c", "py", "py3"])
def test_fmu_matches_exudyn_client_on_the_same_scene(server, sphere, sphere_path, rho_v, fmus, native_run, tmp_path,
                                                     which):
    """The same scene — sphere, regular waves near heave resonance, PTO damper to ground — run
    natively (Exudyn, `[[ptos]] type = "linear"`; once, ``native_run``) and with the FMU client (the
    PTO inside the FMU): heave amplitude and mean PTO power agree within 0.5 %."""
    w, p_native, z_native, native_step = native_run
    period = 2 * np.pi / w
    text = base_scene(sphere_path, rho_v, period, client=fmu_section(fmus[which], rho_v, a_inf=which == "c"))
    summary, dsf = run_fmu(server, text, sphere, tmp_path / "fmu.nc", record=["E_pto"])
    p_fmu = mean_power(dsf["time"].values, summary.recorded["E_pto"], w)
    z_fmu = steady_heave(dsf, w)
    amp_err, p_err = abs(z_fmu) / abs(z_native) - 1, p_fmu / p_native - 1
    REPORT[f"exudyn {which}"] = (f"{which} ({summary.coupling.scheme}) vs Exudyn: |RAO| {abs(z_fmu):.5f} vs "
                                 f"{abs(z_native):.5f} ({amp_err:+.2e}), PTO power {p_fmu:.0f} vs {p_native:.0f} W "
                                 f"({p_err:+.2e}); wall {summary.wall_time / summary.steps * 1e6:.0f} vs "
                                 f"{native_step * 1e6:.0f} us/step")
    print(REPORT[f"exudyn {which}"])
    assert abs(amp_err) < 0.005 and abs(p_err) < 0.005
    assert abs(np.degrees(np.angle(z_fmu / z_native))) < 0.5
