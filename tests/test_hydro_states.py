"""Variable hydrodynamics (server/hydro_states.py, ``bodies[i].hydro_states``, ``[[hydro_switches]]``).

References, all independent of the code: a heaving body with two analytic HDB states (tests/
analytic_hdb.py: B(w) and its closed-form IRF K(t) and A(w)). A scene whose states never switch runs
bit for bit as the same scene without states (model and Exudyn run). A run switching at t_s equals,
after the switch, the monolithic integration of (m + A∞_s) q'' = F_ex,s(t) − ∫K(t − τ) v dτ − C_s q
+ ρ g V_s − m g written here with the analytic kernel (trapezoidal rule at a quarter of the step), and
once the state is held, its frequency-domain response X a / (C − ω²(m + A(ω)) − iωB(ω)) (1 %).
The radiation memory across a switch equals the convolution integral written out here — the new
state's kernel over the whole history ("current-kernel") or each sample's own state's kernel
("kernel-at-emission"). Bad input gets errors naming the key.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from analytic_hdb import added_mass, damping, irf, make_body_hdb
from conftest import REPLY_S, body, regular_waves, scene_toml, write_scene

from hydrolink.protocol.hdb.schema import to_netcdf
from hydrolink.protocol.scene import SceneError, parse_scene
from hydrolink.server.errors import ModelError
from hydrolink.server.hdb.io import load_hdb
from hydrolink.server.hydro_states import SwitchingModel
from hydrolink.server.model import HydroModel

RHO, G = 1000.0, 9.81
MASS = 2.5e5
TOKEN = "hydro-states-test-token-0123456789abcdef"   # a session's join token (32+ characters)
#: heave (A_inf, b0, w0), stiffness C, displaced volume V, excitation (amplitude, decay, phase, slope) and
#: the reference point's height: in "deep" the body rests 0.2 m lower (its HDB refers to the same point
#: of the body, there)
STATES = {
    "shallow": ((3.0e5, 8.0e4, 1.0), 7.7e5, MASS / RHO, (3.0e5, 0.3, 0.4, 0.8), 0.0),
    "deep": ((4.6e5, 4.0e5, 0.8), 9.1e5, MASS / RHO + 20.0, (4.2e5, 0.2, 0.1, 0.5), -0.2),
}


def _exc(amp, decay, phase, slope):
    def exc(w, beta):
        x = np.zeros((w.size, 6), complex)
        x[:, 2] = amp * np.exp(-decay * w ** 2) * np.exp(1j * (phase + slope * w))
        return x
    return exc


def state_hdb(name: str, *, body_name: str = "float") -> xr.Dataset:
    (ainf, b0, w0), c, volume, exc, zref = STATES[name]
    ref = (0.0, 0.0, zref)
    ds = make_body_hdb(params={2: (ainf, b0, w0)}, hydrostatics=np.diag([0, 0, c, 0, 0, 0.0]), exc=_exc(*exc),
                       name=body_name, ref=ref, rho=RHO, g=G)
    return ds.assign(displaced_volume=("body", [volume]))


@pytest.fixture(scope="module")
def hdb_files(tmp_path_factory) -> Path:
    folder = tmp_path_factory.mktemp("states")
    for name in STATES:
        to_netcdf(state_hdb(name), folder / f"{name}.nc")
    return folder


def scene_text(folder: Path, *, switches=(), states: bool = True, memory: str | None = None,
               waves=None, duration: float = 30.0, dt: float = 0.025, coupling=None, radiation: str | None = None,
               ptos=None, controllers=None, **keys) -> str:
    extra = {"hydro_state": "shallow", "hydro_states": [{"name": "deep", "hdb": str(folder / "deep.nc")}]} \
        if states else {}
    if memory is not None:
        extra["hydro_memory"] = memory
    extra = {k: v for k, v in {**extra, **keys}.items() if v is not None}
    bodies = [body("float", hdb=str(folder / "shallow.nc"), mass=MASS, center_of_mass=None, inertia=None,
                   dofs=["heave"], **extra)]
    return scene_toml(dt=dt, duration=duration, water={"density": RHO, "gravity": G, "depth": "inf"},
                      waves=regular_waves(1.0, 8.0) if waves is None else waves, bodies=bodies,
                      hydro={"irf_duration": 20.0, **({"radiation": radiation} if radiation else {})},
                      hydro_switches=list(switches), coupling=coupling, ptos=ptos, controllers=controllers,
                      progress=False)


def _models(folder: Path, **kw) -> tuple[SwitchingModel, dict[str, xr.Dataset]]:
    scene = parse_scene(scene_text(folder, **kw))
    hdbs = {"float": load_hdb(folder / "shallow.nc")}
    return SwitchingModel(scene, hdbs, {"float": {"deep": load_hdb(folder / "deep.nc")}}), hdbs


# ---------------------------------------------------------------------------------- one state

@pytest.mark.parametrize("compiled", [False, None])
def test_states_that_never_switch_are_the_single_hdb_model_bit_for_bit(hdb_files, compiled):
    rule = {"body": "float", "state": "deep", "dof": "heave", "below": -50.0}   # never reached
    scene = parse_scene(scene_text(hdb_files, switches=[rule]))
    hdbs = {"float": load_hdb(hdb_files / "shallow.nc")}
    switching = SwitchingModel(scene, hdbs, {"float": {"deep": load_hdb(hdb_files / "deep.nc")}},
                               compiled=compiled)
    plain = HydroModel(parse_scene(scene_text(hdb_files, states=False)), hdbs, compiled=compiled)
    assert switching.setup_info().hydro_state == {"float": "shallow"}
    rng = np.random.default_rng(3)
    for k in range(200):
        x, v = np.zeros((1, 6)), np.zeros((1, 6))
        x[0, 2], v[0, 2] = rng.normal(0, 0.5), rng.normal(0, 0.5)
        a, b = switching.step(k * plain.dt, x, v), plain.step(k * plain.dt, x, v)
        assert "hydro_state" not in a
        for f in ("excitation", "radiation", "hydrostatic"):
            np.testing.assert_array_equal(a[f], b[f])
        assert a["wave_elevation"] == b["wave_elevation"]


def test_a_run_that_never_switches_is_the_run_without_states_bit_for_bit(hdb_files, tmp_path):
    from hydrolink.clients.run import run_scene_file
    rule = {"body": "float", "state": "deep", "dof": "heave", "below": -50.0}
    out = {}
    for name, text in (("states", scene_text(hdb_files, switches=[rule], duration=10.0)),
                       ("plain", scene_text(hdb_files, states=False, duration=10.0))):
        run_scene_file(write_scene(tmp_path, text, f"{name}.toml"), tmp_path / f"{name}.nc", progress=False)
        out[name] = xr.load_dataset(tmp_path / f"{name}.nc")
    for var in ("position", "velocity", "excitation_force", "radiation_force"):
        np.testing.assert_array_equal(out["states"][var].values, out["plain"][var].values)


# ---------------------------------------------------------------------------------- the memory

def _integral(kernels: list[tuple[float, float]], states: np.ndarray, v: np.ndarray, dt: float, n: int,
              emission: bool) -> float:
    """-dt sum_j w_j K(t_n - t_j) v_j (trapezoid weights) with the analytic kernel of the state at
    t_n ("current-kernel") or of the state sample j was sent in ("kernel-at-emission")."""
    lag = (n - np.arange(n + 1)) * dt
    k = np.array([irf(lag, *kernels[s]) for s in (0, 1)])                  # (2, n + 1)
    pick = states[:n + 1] if emission else np.full(n + 1, states[n])
    w = np.ones(n + 1)
    w[0] = w[-1] = 0.5
    return -dt * float(np.sum(w * k[pick, np.arange(n + 1)] * v[:n + 1]))


@pytest.mark.parametrize("radiation,tol", [("convolution", 300.0), ("state-space", 300.0)])
@pytest.mark.parametrize("memory", ["current-kernel", "kernel-at-emission"])
def test_radiation_memory_across_a_switch_is_the_integral_written_out(hdb_files, memory, radiation, tol):
    """A prescribed heave velocity through a switch at 6 s and back at 12 s: the radiation force of
    each step against the convolution written here (the analytic kernels), by convolution and by the
    state-space fits (whose states are driven the same way: nothing mapped at a switch); ``tol`` in N
    beside forces up to 7e4 N (measured: 38 N by convolution, 123-196 N by the state-space fits; the
    other method's integral is 4.3e4 N away after the switch)."""
    rules = [{"body": "float", "state": "deep", "time": 6.0}, {"body": "float", "state": "shallow", "time": 12.0}]
    model, _ = _models(hdb_files, switches=rules, memory=memory, waves={"type": "still"}, dt=0.02, duration=20.0,
                       radiation=radiation)
    dt, n = model.dt, 900
    t = np.arange(n) * dt
    v = 0.4 * np.sin(0.9 * t) + 0.2 * np.sin(2.3 * t + 1.0)
    states = ((t >= 6.0 - 1e-9) & (t < 12.0 - 1e-9)).astype(int)
    kernels = [STATES[s][0][1:] for s in ("shallow", "deep")]
    got, other, switched = np.zeros(n), np.zeros(n), []
    for k in range(n):
        vel = np.zeros((1, 6))
        vel[0, 2] = v[k]
        reply = model.step(k * dt, np.zeros((1, 6)), vel)
        if "hydro_state" in reply:
            switched.append((k, reply["hydro_state"]["state"]))
        got[k] = reply["radiation"][0, 2]
        other[k] = _integral(kernels, states, v, dt, k, memory != "kernel-at-emission")
        want = _integral(kernels, states, v, dt, k, memory == "kernel-at-emission")
        assert abs(got[k] - want) <= tol, (k, got[k], want)
    assert switched == [(300, "deep"), (600, "shallow")]
    # the two methods differ after each switch by far more than the tolerance: the test tells them apart
    assert np.abs(got - other)[300:400].max() > 10 * tol


# ---------------------------------------------------------------------------------- a run

def _monolithic(dt: float, n: int, t_s: float, emission: bool, sub: int = 4) -> tuple[np.ndarray, np.ndarray]:
    """The heaving body switching from "shallow" to "deep" at t_s, integrated here by the trapezoidal
    rule at dt / sub with the analytic kernels: (m + A∞_s) a = F_ex,s(t) - R(t) - C_s (q - z_s) + rho g V_s - m g
    (z_s: the state's rest height of the reference point),
    velocity continuous across the switch; q at t = k dt."""
    h, steps = dt / sub, n * sub
    t = np.arange(steps + 1) * h
    st = (t >= t_s - 1e-9).astype(int)
    par = [STATES[s] for s in ("shallow", "deep")]
    w_wave, amp = 2 * np.pi / 8.0, 0.5
    fex = np.zeros((2, steps + 1))
    for s, (_, _, _, (xa, dec, ph, sl), _) in enumerate(par):
        x = xa * np.exp(-dec * w_wave ** 2) * np.exp(1j * (ph + sl * w_wave))
        fex[s] = np.real(amp * x * np.exp(-1j * w_wave * t))
    kern = np.array([irf(t, *p[0][1:]) for p in par])                     # (2, steps + 1) K_s(lag)
    q, v, a = np.zeros(steps + 1), np.zeros(steps + 1), np.zeros(steps + 1)

    def accel(j: int, vj: float, qj: float, hist: float) -> float:
        s = st[j]
        (ainf, *_), c, vol, _, zref = par[s]
        r = hist + 0.5 * h * kern[s, 0] * vj
        return (fex[s, j] - r - c * (qj - zref) + RHO * G * vol - MASS * G) / (MASS + ainf)

    for j in range(steps + 1):
        s = st[j]
        lags = j - np.arange(j)                                          # samples 0..j-1
        which = st[:j] if emission else np.full(j, s)
        wts = np.ones(j)
        if j:
            wts[0] = 0.5
        hist = h * float(np.sum(wts * kern[which, lags] * v[:j]))
        if j == 0:
            a[0] = accel(0, 0.0, 0.0, 0.0)
            continue
        (ainf, *_), c, vol, _, zref = par[s]
        m = MASS + ainf
        # trapezoid: v_j = v + h/2 (a + a_j), q_j = q + h/2 (v + v_j); a_j linear in v_j
        rhs = v[j - 1] + 0.5 * h * a[j - 1] + 0.5 * h / m * (
            fex[s, j] - hist - c * (q[j - 1] + 0.5 * h * v[j - 1] - zref) + RHO * G * vol - MASS * G)
        v[j] = rhs / (1 + 0.5 * h / m * (0.5 * h * kern[s, 0] + 0.5 * h * c))
        q[j] = q[j - 1] + 0.5 * h * (v[j - 1] + v[j])
        a[j] = accel(j, v[j], q[j], hist)
    return q[::sub], t[::sub]


@pytest.mark.parametrize("memory", ["current-kernel", "kernel-at-emission"])
def test_a_run_switching_at_ts_is_the_monolithic_integration_after_it(hdb_files, tmp_path, memory):
    from hydrolink.clients.run import run_scene_file
    t_s, dt, duration = 12.0, 0.025, 30.0
    text = scene_text(hdb_files, switches=[{"body": "float", "state": "deep", "time": t_s}], memory=memory,
                      dt=dt, duration=duration)
    run_scene_file(write_scene(tmp_path, text), tmp_path / "run.nc", progress=False)
    ds = xr.load_dataset(tmp_path / "run.nc")
    z = ds["position"].values[:, 0, 2]
    n = int(round(duration / dt))
    q, t = _monolithic(dt, n, t_s, memory == "kernel-at-emission")
    np.testing.assert_allclose(ds["time"].values, t, rtol=0, atol=1e-9)
    after = t > t_s
    scale = np.abs(q[after]).max()
    err = np.abs(z - q)[after].max()      # measured: 0.19-0.27 % of the motion (the other method's reference: 9 %)
    assert err <= 0.005 * scale, (err, scale)
    # the results' hydrostatic force is the deep state's -C (z - z_deep) about its own rest height
    hs = ds["hydrostatic_force"].values[:, 0, 2]
    np.testing.assert_allclose(hs[after], -STATES["deep"][1] * (z[after] - STATES["deep"][4]), rtol=1e-12, atol=1e-6)
    q_other, _ = _monolithic(dt, n, t_s, memory != "kernel-at-emission")
    assert np.abs(q_other - q)[after].max() > 2 * 0.005 * scale      # the reference tells the methods apart


def test_a_held_state_reaches_its_own_frequency_domain_response(hdb_files, tmp_path):
    """Switched at 10 s and held: from 60 s on the heave is the deep state's steady response to the
    8 s wave, X a / (C - w^2 (m + A(w)) - i w B(w)) with the analytic A, B, about the state's rest height
    z_s + rho g dV / C (1 %)."""
    from hydrolink.clients.run import run_scene_file
    text = scene_text(hdb_files, switches=[{"body": "float", "state": "deep", "time": 10.0}], duration=80.0)
    run_scene_file(write_scene(tmp_path, text), tmp_path / "held.nc", progress=False)
    ds = xr.load_dataset(tmp_path / "held.nc")
    t, z = ds["time"].values, ds["position"].values[:, 0, 2]
    (ainf, b0, w0), c, volume, (xa, dec, ph, sl), zref = STATES["deep"]
    w = 2 * np.pi / 8.0
    x = xa * np.exp(-dec * w ** 2) * np.exp(1j * (ph + sl * w))
    h = x / (c - w ** 2 * (MASS + float(added_mass(w, ainf, b0, w0))) - 1j * w * float(damping(w, b0, w0)))
    want = 0.5 * h                                      # complex heave amplitude, exp(-i w t)
    last = t >= 64.0                                    # two periods
    basis = np.column_stack([np.cos(w * t[last]), np.sin(w * t[last]), np.ones(last.sum())])
    (cc, ss, mean), *_ = np.linalg.lstsq(basis, z[last], rcond=None)
    got = cc + 1j * ss                                  # z = Re(got e^{-i w t}) + mean
    assert abs(got - want) <= 0.01 * abs(want), (got, want)
    rest = zref + RHO * G * (volume - MASS / RHO) / c
    assert abs(mean - rest) <= 0.01 * abs(want)
    assert int(ds["hydro_state"].values[-1]) == 1 and int(ds["hydro_state"].values[0]) == 0


# ---------------------------------------------------------------------------------- bad input

def _parse_error(text: str) -> SceneError:
    with pytest.raises(SceneError) as err:
        parse_scene(text)
    return err.value


def test_rules_naming_unknown_states_or_bodies_are_refused_with_their_key(hdb_files):
    err = _parse_error(scene_text(hdb_files, switches=[{"body": "float", "state": "flooded", "time": 3.0}]))
    assert err.key == "hydro_switches[0].state" and "flooded" in str(err) and "deep" in str(err)
    err = _parse_error(scene_text(hdb_files, switches=[{"body": "buoy", "state": "deep", "time": 3.0}]))
    assert err.key == "hydro_switches[0].body"
    err = _parse_error(scene_text(hdb_files, switches=[{"body": "float", "state": "deep", "dof": "surge",
                                                        "below": 1.0}]))
    assert err.key == "hydro_switches[0].dof"
    err = _parse_error(scene_text(hdb_files, switches=[{"body": "float", "state": "deep", "time": 3.0,
                                                        "dof": "heave", "below": 1.0}]))
    assert err.key.startswith("hydro_switches[0]")
    err = _parse_error(scene_text(hdb_files, hydro_state=None))
    assert err.key == "bodies[0].hydro_state"
    err = _parse_error(scene_text(hdb_files, states=False, hydro_memory="kernel-at-emission"))
    assert err.key == "bodies[0].hydro_memory"
    err = _parse_error(scene_text(hdb_files, coupling={"scheme": "implicit"}))
    assert err.key == "coupling.scheme"


@pytest.mark.parametrize("case", ["body", "modes"])
def test_a_state_hdb_that_does_not_hold_the_body_alike_is_refused_naming_it(hdb_files, case):
    scene = parse_scene(scene_text(hdb_files))
    hdbs = {"float": load_hdb(hdb_files / "shallow.nc")}
    if case == "body":
        deep = state_hdb("deep", body_name="other")
    else:   # the state's HDB gives the body a generalized mode (7 DOFs where the other state has 6)
        from hydrolink.protocol.hdb.schema import make_hdb
        base = state_hdb("deep")
        n = base["omega"].size

        def grow(a, axes):
            out = np.zeros([s + 1 if i in axes else s for i, s in enumerate(a.shape)], a.dtype)
            out[tuple(slice(0, s) for s in a.shape)] = a
            return out
        deep = make_hdb(bodies=["float"], omega=base["omega"].values, wave_direction=base["wave_direction"].values,
                        added_mass=grow(base["added_mass"].values, (1, 2)) + np.eye(7)[None] * 1e3,
                        radiation_damping=grow(base["radiation_damping"].values, (1, 2)),
                        excitation_force=grow(base["excitation_force"].values, (2,)),
                        hydrostatic_stiffness=grow(base["hydrostatic_stiffness"].values[0], (0, 1)) + np.eye(7) * 1e3,
                        reference_point=base["reference_point"].values, rho=RHO, g=G, water_depth=np.inf,
                        source="analytic", modes={"float": ["bend"]})
        assert deep["added_mass"].shape[0] == n
    with pytest.raises(ModelError) as err:
        SwitchingModel(scene, hdbs, {"float": {"deep": deep}})
    assert err.value.key == "bodies[0].hydro_states[0].hdb", err.value
    assert "deep" in str(err.value)


def test_two_switching_bodies_are_refused_naming_the_second(hdb_files):
    states = {"hydro_state": "a", "hydro_states": [{"name": "b", "hdb": str(hdb_files / "deep.nc")}]}
    bodies = [body(n, hdb=str(hdb_files / "shallow.nc"), mass=MASS, center_of_mass=None, inertia=None,
                   dofs=["heave"], hdb_body="float", **states) for n in ("one", "two")]
    err = _parse_error(scene_toml(dt=0.1, duration=1.0, bodies=bodies, hydro={"interaction": "none"}))
    assert err.key == "bodies[1].hydro_states"


def test_threshold_rules_switch_on_the_position_sent_with_hysteresis_and_roll_back(hdb_files):
    """Two rules make a band: below -0.3 m -> deep, above -0.1 m -> shallow. A sub-iteration keeps the
    state of its step; a rollback (SPEC §5.9) repeats the switches bit for bit."""
    rules = [{"body": "float", "state": "deep", "dof": "heave", "below": -0.3},
             {"body": "float", "state": "shallow", "dof": "heave", "above": -0.1}]
    model, _ = _models(hdb_files, switches=rules, waves={"type": "still"}, dt=0.1, duration=10.0)
    z = np.array([0.0, -0.2, -0.35, -0.2, -0.05, -0.5, -0.2])
    want = [None, None, "deep", None, "shallow", "deep", None]
    x, v = np.zeros((1, 6)), np.zeros((1, 6))
    states, replies = [], []
    for k, zk in enumerate(z):
        x[0, 2] = zk
        if k == 3:
            saved = model.state()
        replies.append(model.step(k * model.dt, x, v))
        states.append(replies[-1].get("hydro_state", {}).get("state"))
        if k == 2:     # an iteration of the switching step, back above the threshold: still deep, still the switch
            x[0, 2] = 0.0
            again = model.step(k * model.dt, x, v, replace_last=True)
            assert again["hydro_state"]["state"] == "deep" and model.hydro_state == "deep"
    assert states == want
    model.set_state(saved)
    for k in range(3, z.size):
        x[0, 2] = z[k]
        redo = model.step(k * model.dt, x, v)
        assert redo.get("hydro_state", {}).get("state") == states[k]
        np.testing.assert_array_equal(redo["radiation"], replies[k]["radiation"])
        np.testing.assert_array_equal(redo["hydrostatic"], replies[k]["hydrostatic"])
    # the switch's matrices are the deep state's HDB values
    change = replies[2]["hydro_state"]
    assert change["added_mass"][2, 2] == STATES["deep"][0][0]
    assert change["hydrostatic_stiffness"][2, 2] == pytest.approx(STATES["deep"][1], rel=1e-12)
    assert change["net_buoyancy"][0] == pytest.approx(RHO * G * 20.0, rel=1e-9)
    assert change["equilibrium_position"][0, 2] == STATES["deep"][4]


def test_a_switching_run_through_a_served_server_is_the_in_process_run_bit_for_bit(hdb_files, tmp_path, server):
    """The states' HDBs go as file sets (SPEC §5.1), the switch's matrices come back as binary arrays
    (SPEC §2.1), and the run is the same."""
    from hydrolink.clients.run import run_scene_file
    text = scene_text(hdb_files, switches=[{"body": "float", "state": "deep", "time": 2.0}], duration=5.0)
    path = write_scene(tmp_path, text)
    run_scene_file(path, tmp_path / "local.nc", progress=False)
    run_scene_file(path, tmp_path / "served.nc", server=server, progress=False, hdb_files=True, timeout=REPLY_S)   # sent by hash
    local, served = xr.load_dataset(tmp_path / "local.nc"), xr.load_dataset(tmp_path / "served.nc")
    for var in ("position", "velocity", "excitation_force", "radiation_force", "hydro_state"):
        np.testing.assert_array_equal(local[var].values, served[var].values)
    assert served["hydro_state"].values[-1] == 1



BALLAST = '''
from hydrolink.clients.control import Controller

class Ballast(Controller):
    def on_step(self, t, m):
        if abs(t - 2.0) < 1e-9:          # the measurements of t = 2 s: sink
            self.switch_hydro_state("float", "deep")
        if abs(t - 3.0) < 1e-9:          # a state the body does not have: refused, the step falls back
            self.switch_hydro_state("float", "flooded")
        return {p: 0.0 for p in self.ptos}
'''


def test_a_controller_command_switches_the_state_a_step_after_its_decision(hdb_files, tmp_path):
    """A controller commands "deep" from the measurements of t = 2 s (latency 1: due at 2.025 s): the
    model enters it at 2.05 s, and the run equals the run whose time rule switches at 2.05 s, bit for
    bit; a command of a state the body lacks is refused (decision "invalid", the run goes on)."""
    import json
    import socket
    from conftest import controller_process, linear_pto
    from hydrolink.clients.run import run_scene_file
    pto = [linear_pto("pto", "float", [0.0, 0.0, 0.0], "ground", [0.0, 0.0, -10.0], damping=0.0, stiffness=0.0)]
    ctl = [{"name": "ctl", "ptos": ["pto"], "hydro_states": ["float"], "timeout": 20.0}]
    commanded = scene_text(hdb_files, duration=4.0, ptos=pto, controllers=ctl)
    ruled = scene_text(hdb_files, duration=4.0, ptos=pto, switches=[{"body": "float", "state": "deep", "time": 2.05}])
    (tmp_path / "ballast.py").write_text(BALLAST)
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{sock.getsockname()[1]}"
    with controller_process(tmp_path / "ballast.py", address, TOKEN) as ended:
        run_scene_file(write_scene(tmp_path, commanded, "commanded.toml"), tmp_path / "commanded.nc", progress=False,
                       listen=address, control_token=TOKEN, timeout=REPLY_S)
    assert ended.returncode == 0, ended.stderr
    run_scene_file(write_scene(tmp_path, ruled, "ruled.toml"), tmp_path / "ruled.nc", progress=False)
    a, b = xr.load_dataset(tmp_path / "commanded.nc"), xr.load_dataset(tmp_path / "ruled.nc")
    state = a["hydro_state"].values
    assert state[81] == 0 and state[82] == 1 and state[-1] == 1          # t = 2.025 s, 2.05 s
    for var in ("position", "velocity", "excitation_force", "radiation_force", "hydro_state"):
        np.testing.assert_array_equal(a[var].values, b[var].values)
    assert json.loads(a.attrs["controller_events"])["ctl"]["invalid"] == 1
