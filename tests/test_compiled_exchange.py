"""clients/exudyn/compiled_exchange.py: an embedded run's exchange in two compiled calls gives the
reference path's results bit for bit — the reference being the same scene run against a server in
a thread over loopback TCP (messages: ForceLink, Session.step, HydroModel.step, the Exudyn client's
Python rows) — and stops where the reference path stops, with its error."""

from __future__ import annotations

import json
import secrets
import socket
from pathlib import Path

import netCDF4
import numpy as np
import pytest
import xarray as xr

from conftest import (REPLY_S, SPHERE_WATER, body, controller_process, joint, linear_pto, regular_waves, rm3_float,
                      rm3_short_text, rm3_spar, scene_toml, sphere_body)

from hydrolink.clients.exudyn import compiled_exchange
from hydrolink.clients.lockstep.driver import SimulationDiverged
from hydrolink.clients.run import run_scene_file
from hydrolink.server.service.force_server import serve_in_thread
from hydrolink.server.service.local_step import LocalStep

MASS = 261.8e3   # the Task-10 sphere floating (rho V)
TOKEN = secrets.token_urlsafe(32)   # the controlled runs' join token (SPEC §5.7.2)
REACTIVE = Path(__file__).resolve().parents[1] / "examples" / "controllers" / "reactive.py"
# an impedance controller whose damping follows the PTO velocity's sign: commands that change every few steps
SWITCHING = """
from hydrolink.clients.control import Controller

class Switching(Controller):
    def on_start(self, info):
        self.c, self.k = float(info["parameters"]["damping"]), float(info["parameters"]["stiffness"])

    def on_step(self, t, m):
        c = self.c * (1.5 if m["pto_velocity"][0] > 0.0 else 1.0)
        return {p: {"damping": c, "stiffness": self.k} for p in self.ptos}
"""
# a reactive force controller (plus a term of the wave elevation at its probe) whose every seventh
# command is refused (NaN: "invalid"), so that the scene's passive fallback acts on those steps
# (its parameters: damping, stiffness, the elevation's gain and the scene's step)
FAULTY = """
import math

from hydrolink.clients.control import Controller

class Faulty(Controller):
    def on_start(self, info):
        p = info["parameters"]
        self.c, self.k = float(p["damping"]), float(p["stiffness"])
        self.gain, self.dt = float(p.get("eta_gain", 1.0e4)), float(p.get("dt", 0.08))

    def on_step(self, t, m):
        if round(t / self.dt) % 7 == 6:
            return {p: math.nan for p in self.ptos}
        v, x, eta = m["pto_velocity"].tolist(), m["pto_displacement"].tolist(), float(m["wave_elevation"][0])
        return {p: self.c * v[i] + self.k * x[i] + self.gain * eta for i, p in enumerate(self.ptos)}

    def on_error(self, error):
        pass
"""
#: the hinged scene's friction on the hinge: the float's pitch swing 0.32 -> 0.23 rad, 76 of 121 rows in the tanh zone
HINGE_FRICTION = {"force": 1.0e6, "velocity": 1.0e-2}
#: results variables that are wall time, not the run's physics
WALL_CLOCK = {"controller_latency", "step_latency", "step_time", "overrun"}


def rm3_scene(reference_data: Path, tmp_path: Path, extra: str = "") -> Path:
    """RM3 (two reduced bodies, convolution, the PTO's outputs) at dt 0.08 for 16 s."""
    path = tmp_path / "rm3.toml"
    path.write_text(rm3_short_text(reference_data) + extra)
    return path


def sphere_scene(sphere_path: Path, tmp_path: Path) -> Path:
    """The sphere in all six DOFs (no reduced body), state-space radiation, a heave offset."""
    path = tmp_path / "sphere.toml"
    path.write_text(scene_toml(dt=0.05, duration=10.0, progress=False, water=SPHERE_WATER,
                               waves=regular_waves(1.0, 6.0, ramp=3.0),
                               hydro={"irf_duration": 20.0, "radiation": "state-space"},
                               bodies=[sphere_body(str(sphere_path), mass=MASS,
                                                   initial_displacement=[0.1, 0.05, 0.5, 0.01, 0.02, 0.0])]))
    return path


def hinged_scene(reference_data: Path, tmp_path: Path, full: bool = False, friction: dict | None = None) -> Path:
    """RM3's spar held to ground by a fixed joint and its float on a hinge about y to it (two wet
    bodies, every DOF, joints, the held DOFs' radiation columns left out), convolution; ``full``:
    the spar integrated under its joint (``[client] reduce = false``: the hinge's marker-0 frame
    moves with it); ``friction`` on the hinge (its torque in the hinge's load and the hold's), the hold
    then listed first (the hinge's results row is not its place among the Exudyn joints)."""
    path = tmp_path / "hinged.toml"
    hdb = (reference_data / "rm3_wamit" / "rm3.1").as_posix()
    joints = [joint("revolute", "spar", "float", [0.0, 0.0, 0.0], axis=[0.0, 1.0, 0.0],
                    **({"friction": friction} if friction else {})),
              joint("fixed", "ground", "spar", [0.0, 0.0, -21.29])]
    path.write_text(scene_toml(dt=0.1, duration=12.0, progress=False, water={"density": 1000.0},
                               waves=regular_waves(2.0, 7.0, ramp=3.0), hydro={"irf_duration": 10.0},
                               bodies=[rm3_float(hdb), rm3_spar(hdb)],
                               joints=joints[::-1] if friction else joints,
                               client={"type": "exudyn", "reduce": False} if full else None))
    return path


def counted(monkeypatch) -> list[int]:
    """The exchanges the compiled kernel took (a spy on LocalStep.advanced, which only the compiled
    exchange calls: each call goes on to the real one), as exchange indices."""
    calls: list[int] = []
    real = LocalStep.advanced

    def spy(self, seq, seconds):
        calls.append(seq - 1)
        return real(self, seq, seconds)
    monkeypatch.setattr(LocalStep, "advanced", spy)
    return calls


def socket_run(scene: Path, out: Path):
    srv, thread = serve_in_thread()
    try:
        return run_scene_file(scene, out, server=srv.address, progress=False, timeout=REPLY_S)
    finally:
        srv.stop()
        thread.join(5)


@pytest.mark.parametrize("case", ["rm3", "sphere", "hinged", "hinged-full", "hinged-friction", "float_on_arm"])
def test_compiled_exchange_equals_reference_bit_for_bit(case, reference_data, sphere_path, tmp_path, monkeypatch):
    """Every variable of the results file (position, velocity, the forces, the elevation, the
    PTO's outputs, the joints' reactions; float_on_arm: a dry body, joints and a PTO together, the
    viscous force and power) is the reference path's to the bit, over every row."""
    scene = {"rm3": lambda: rm3_scene(reference_data, tmp_path), "sphere": lambda: sphere_scene(sphere_path, tmp_path),
             "hinged": lambda: hinged_scene(reference_data, tmp_path),
             "hinged-full": lambda: hinged_scene(reference_data, tmp_path, full=True),
             "hinged-friction": lambda: hinged_scene(reference_data, tmp_path, friction=HINGE_FRICTION),
             "float_on_arm": lambda: float_on_dry_arm_scene(tmp_path, 0.01, controlled=False)}[case]()
    calls = counted(monkeypatch)
    embedded = run_scene_file(scene, tmp_path / "embedded.nc", progress=False)
    remote = socket_run(scene, tmp_path / "socket.nc")
    assert embedded.status == remote.status == "complete"
    assert calls == list(range(embedded.steps))      # every exchange compiled in the embedded run, none in the other
    assert embedded.round_trip_us_per_step > 0.0      # the kernel's time counted as the server's
    with netCDF4.Dataset(tmp_path / "embedded.nc") as a, netCDF4.Dataset(tmp_path / "socket.nc") as b:
        names = [n for n, v in a.variables.items() if v.dtype is not str and v.dtype.kind == "f"
                 and "time" in v.dimensions]
        assert {"position", "velocity", "excitation_force", "radiation_force", "hydrostatic_force",
                "wave_elevation"} <= set(names)
        if case == "rm3":
            assert {"pto_force", "pto_power"} <= set(names)
        if case.startswith("hinged") or case == "float_on_arm":
            assert {"joint_force", "joint_violation"} <= set(names)
        if case == "float_on_arm":
            assert {"pto_force", "viscous_force", "viscous_power"} <= set(names)
        for name in names:
            x, y = a[name][:].filled(np.nan), b[name][:].filled(np.nan)
            assert x.shape == y.shape and x.tobytes() == y.tobytes(), name
        moved = np.abs(a["position"][:] - a["position"][0]).max()
        assert moved > (0.01 if case == "float_on_arm" else 0.05)   # the body moved: not a comparison of rest states


def test_a_viscous_term_beyond_linear_damping_keeps_the_reference_path(tmp_path, monkeypatch):
    """Quadratic damping (a viscous term the compiled exchange does not compute) leaves the run to
    the reference path: no exchange compiled, the run complete with its viscous force."""
    calls = counted(monkeypatch)
    scene = float_on_dry_arm_scene(tmp_path, 0.01, damping="quadratic_damping", controlled=False)
    summary = run_scene_file(scene, tmp_path / "embedded.nc", progress=False)
    assert summary.status == "complete" and summary.steps == 400 and calls == []
    with netCDF4.Dataset(tmp_path / "embedded.nc") as a:
        assert np.abs(a["viscous_force"][:]).max() > 0.0


def test_compiled_exchange_stops_where_the_reference_path_does(reference_data, tmp_path, monkeypatch):
    """A state past the divergence bound (a run's blow-up limit set below RM3's heave) stops the
    compiled run at the step, with the message, and with the rows the reference path keeps."""
    from hydrolink.clients.exudyn import client

    real = client.run

    def low_limit(*args, **kw):
        return real(*args, **{**kw, "blow_up_limit": 0.05})
    monkeypatch.setattr(client, "run", low_limit)
    scene = rm3_scene(reference_data, tmp_path)
    calls = counted(monkeypatch)
    with pytest.raises(SimulationDiverged) as embedded:
        run_scene_file(scene, tmp_path / "embedded.nc", progress=False)
    assert calls
    with pytest.raises(SimulationDiverged) as remote:
        socket_run(scene, tmp_path / "socket.nc")
    assert embedded.value.step == remote.value.step > 1
    assert str(embedded.value) == str(remote.value)
    with netCDF4.Dataset(tmp_path / "embedded.nc") as a, netCDF4.Dataset(tmp_path / "socket.nc") as b:
        assert a.dimensions["time"].size == b.dimensions["time"].size == embedded.value.rows
        assert a["position"][:].tobytes() == b["position"][:].tobytes()


def test_steps_the_compiled_check_refuses_go_to_the_reference_path(sphere_path, tmp_path, monkeypatch):
    """A state the compiled bounds refuse (here a velocity bound of 0.3 m/s in place of the wire's,
    which the reference path's check then passes) ends Exudyn's step loop before that step; the
    reference path takes the exchange and a new loop goes on: the results are still the socket
    run's bit for bit, and both paths took steps."""
    import dataclasses

    from hydrolink.protocol.scene_bounds import MAX_COORDINATE

    real = LocalStep.compiled

    def tight(self):
        step = real(self)
        return None if step is None else dataclasses.replace(step, bounds=(MAX_COORDINATE, 0.3))
    monkeypatch.setattr(LocalStep, "compiled", tight)
    scene = sphere_scene(sphere_path, tmp_path)
    calls = counted(monkeypatch)
    embedded = run_scene_file(scene, tmp_path / "embedded.nc", progress=False)
    remote = socket_run(scene, tmp_path / "socket.nc")
    assert embedded.status == remote.status == "complete"
    compiled = set(calls)
    assert compiled and len(compiled) < embedded.steps          # some exchanges compiled, some handed off
    with netCDF4.Dataset(tmp_path / "embedded.nc") as a, netCDF4.Dataset(tmp_path / "socket.nc") as b:
        v = a["velocity"][:]
        assert np.abs(v).max() > 0.3                              # the bound was passed
        for name in ("position", "velocity", "excitation_force", "radiation_force", "hydrostatic_force"):
            assert a[name][:].tobytes() == b[name][:].tobytes(), name


def controlled_scene(reference_data: Path, tmp_path: Path, command: str) -> Path:
    """RM3 at dt 0.08 for 8 s, no passive damping, one controller driving its PTO every step
    (``command``: "force" or "impedance"; its fallback passive, 2e5 N s/m), measuring the PTO, the
    bodies and the wave elevation 5 m up-wave."""
    path = rm3_scene(reference_data, tmp_path, (
        "\n[[controllers]]\nname = \"ctl\"\nptos = [\"pto\"]\n"
        f"command = \"{command}\"\ntimeout = 10.0\nfallback = \"passive\"\nfallback_damping = 2.0e5\n"
        "measurements = [\"pto_displacement\", \"pto_velocity\", \"pto_force\", \"body_position\", \"body_velocity\",\n"
        "                \"wave_elevation\"]\nwave_points = [[5.0, 0.0]]\n"
        "parameters = { damping = 3.9e5, stiffness = 1.36e6 }\n"))
    text = path.read_text()
    assert "damping = 1.2e6 " in text
    path.write_text(text.replace("damping = 1.2e6 ", "damping = 0.0 ", 1))
    return path


def own_run(scene: Path, out: Path, controller: Path, realtime: float | None):
    """``hydrolink run`` of ``scene`` on its own polled server (listening on a free loopback port)
    with ``controller`` in its own process; the summary (the controller ended cleanly)."""
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        address = f"tcp://127.0.0.1:{sock.getsockname()[1]}"
    with controller_process(controller, address, TOKEN) as ended:
        summary = run_scene_file(scene, out, progress=False, listen=address, control_token=TOKEN, realtime=realtime,
                                 timeout=REPLY_S)
    assert ended.returncode == 0, ended.stderr
    return summary


def velocity_bound(monkeypatch, bound: float) -> None:
    """The compiled check's velocity bound ``bound`` in place of the wire's (LocalStep.compiled's
    bounds), which the reference path's check then passes: exchanges go to it mid-run and back."""
    import dataclasses

    from hydrolink.protocol.scene_bounds import MAX_COORDINATE

    real = LocalStep.compiled
    monkeypatch.setattr(LocalStep, "compiled",
                        lambda self: dataclasses.replace(real(self), bounds=(MAX_COORDINATE, bound)))


def compiled_and_reference(scene: Path, controller: Path, realtime: float | None, tmp_path: Path, monkeypatch,
                           refused: bool):
    """``scene`` run twice on its own polled server with ``controller`` (:func:`own_run`): with the
    compiled exchange, then with it switched off (the reference path); every results variable but
    the wall-clock ones equal bytes, the same decisions (every seventh refused where ``refused``).
    (The compiled run's summary, the exchanges its kernel took, its results.)"""
    from hydrolink.clients.exudyn.client import ExudynMultibody

    calls = counted(monkeypatch)
    compiled = own_run(scene, tmp_path / "compiled.nc", controller, realtime)
    taken = set(calls)
    monkeypatch.setattr(ExudynMultibody, "compiled_exchange", lambda *args: None)
    reference = own_run(scene, tmp_path / "reference.nc", controller, realtime)
    assert compiled.status == reference.status == "complete" and len(calls) == len(taken)
    a, b = xr.load_dataset(tmp_path / "compiled.nc"), xr.load_dataset(tmp_path / "reference.nc")
    assert set(a.data_vars) == set(b.data_vars) >= {"pto_command_force", "pto_damping", "controller_status"}
    for name in set(a.data_vars) - WALL_CLOCK:
        assert a[name].values.tobytes() == b[name].values.tobytes(), name
    counts = [{k: v for k, v in json.loads(ds.attrs["controller_events"])["ctl"].items() if "latency" not in k}
              for ds in (a, b)]
    n_refused = compiled.steps // 7 if refused else 0
    assert counts[0] == counts[1] == {"ok": compiled.steps - n_refused, "invalid": n_refused, "timeout": 0,
                                      "absent": 0}
    return compiled, taken, a


@pytest.mark.parametrize("command, realtime, bound", [("faulty", None, None), ("impedance", 16.0, None),
                                                      ("force", None, 0.3)])
def test_controlled_compiled_exchange_equals_the_reference_path(command, realtime, bound, reference_data, tmp_path,
                                                               monkeypatch):
    """A run with a controller process (``hydrolink run``'s own polled server, the direct channel)
    takes the compiled exchange — unpaced inside one SolveSteps, paced an exchange a call — with
    the measurements from the kernels' arrays and the commands applied to the PTO between the
    steps: every variable of the results file but the wall-clock ones is the reference path's
    (the same run with the compiled exchange switched off) to the bit, with the same decisions.
    ``command`` "faulty": force commands, every seventh refused, the passive fallback applied on
    those steps. ``bound``: a velocity bound of the compiled check in place of the wire's, so
    that exchanges go to the reference path mid-run and back (their measurements then the
    reference path's)."""
    controller = REACTIVE
    if command != "force":
        controller = tmp_path / f"{command}.py"
        controller.write_text(SWITCHING if command == "impedance" else FAULTY)
    if bound is not None:
        velocity_bound(monkeypatch, bound)
    scene = controlled_scene(reference_data, tmp_path, "impedance" if command == "impedance" else "force")
    compiled, taken, a = compiled_and_reference(scene, controller, realtime, tmp_path, monkeypatch,
                                                refused=command == "faulty")
    if bound is None:
        assert taken == set(range(compiled.steps))   # every exchange compiled
    else:
        assert taken and len(taken) < compiled.steps   # some compiled, some handed to the reference path
    assert np.abs(a["position"].values - a["position"].values[0]).max() > 0.05
    if bound is not None:
        assert np.abs(a["velocity"].values).max() > bound
    if command != "impedance":
        assert np.abs(a["pto_command_force"].values).max() > 1e3
    if command != "force":   # the commands, or the fallback, changed the damping
        assert np.unique(a["pto_damping"].values[1:]).size == 2


WAVESTAR_HDB = Path(__file__).resolve().parents[1] / "examples" / "data" / "wavestar" / "wavestar.out"


def float_on_dry_arm_scene(tmp_path: Path, dt: float, damping: str = "linear_damping", controlled: bool = True) -> Path:
    """WECCCOMP's WaveStar (examples/wavestar/wavestar.toml) at ``dt`` for 4 s in regular waves: the
    wet float (its pitch's ``damping``, linear or quadratic: the server's viscous term) fixed to a
    dry arm, the arm on a revolute joint to ground, a linear PTO from the arm to ground driven
    (``controlled``) by one force controller (fallback passive, 400 N s/m) measuring the PTO, the
    bodies and the elevation at three up-wave points, else a 400 N s/m damper; convolution radiation."""
    control = [{"name": "ctl", "ptos": ["pto"], "command": "force", "timeout": 10.0, "fallback": "passive",
                "fallback_damping": 400.0,
                "measurements": ["pto_displacement", "pto_velocity", "pto_force", "body_position", "body_velocity",
                                 "wave_elevation"],
                "wave_points": [[-1.70, 0.0], [-1.50, 0.0], [-1.25, 0.0]],
                "parameters": {"damping": 400.0, "stiffness": 20.0, "eta_gain": 100.0, "dt": dt}}]
    path = tmp_path / "float_on_arm.toml"
    path.write_text(scene_toml(
        dt=dt, duration=4.0, progress=False, water={"density": 1000.0, "gravity": 9.80665, "depth": 0.65},
        waves=regular_waves(0.04, 1.4, ramp=1.0), hydro={"irf_duration": 2.0},
        bodies=[body("float", hdb=WAVESTAR_HDB.as_posix(), hdb_body="body1", mass=3.075,
                     center_of_mass=[0.001292, 0.0, 0.0533], inertia=[0.00145] * 3,
                     **{damping: [0.0, 0.0, 0.0, 0.0, 1.8, 0.0]}),
                body("arm", mass=1.157, center_of_mass=[-0.3301, 0.0, 0.2551], inertia=[0.0606] * 3)],
        joints=[joint("fixed", "arm", "float", [0.0, 0.0, 0.09]),
                joint("revolute", "ground", "arm", [-0.438, 0.0, 0.302], axis=[0.0, 1.0, 0.0])],
        ptos=[linear_pto("pto", "arm", [-0.6214398, 0.0, 0.3816858], "ground", [-0.438, 0.0, 0.714],
                         damping=0.0 if controlled else 400.0)],
        controllers=control if controlled else None))
    return path


@pytest.mark.parametrize("realtime, bound", [(None, None), (8.0, None), (None, 0.01)])
def test_dry_body_joints_and_pto_under_a_controller_compiled(realtime, bound, tmp_path, monkeypatch):
    """WaveStar's layout (a dry arm carrying the wet float, a fixed and a revolute joint, a linear
    PTO, the float's linear damping) under a force controller process whose every seventh command
    is refused, unpaced and paced: every exchange compiled, every results variable (the dry arm's
    rows, the joints' reactions, the PTO's outputs, the viscous force and power, the control's)
    the reference path's to the bit. ``bound``: a velocity bound of the compiled check in place of
    the wire's (exchanges handed to the reference path mid-run and back)."""
    if bound is not None:
        velocity_bound(monkeypatch, bound)
    controller = tmp_path / "faulty.py"
    controller.write_text(FAULTY)
    scene = float_on_dry_arm_scene(tmp_path, 0.01)
    compiled, taken, a = compiled_and_reference(scene, controller, realtime, tmp_path, monkeypatch, refused=True)
    if bound is None:
        assert taken == set(range(compiled.steps))
    else:
        assert taken and len(taken) < compiled.steps   # some compiled, some handed to the reference path
    assert {"joint_force", "pto_force", "pto_command_force", "viscous_force", "viscous_power"} <= set(a.data_vars)
    assert np.abs(a["viscous_force"].values).max() > 0.0
    arm = list(a["body"].values).index("arm")
    assert not a["excitation_force"].values[:, arm].any() and not a["hydrostatic_force"].values[:, arm].any()
    pitch = a["position"].values[:, arm, 4]
    assert np.abs(pitch - pitch[0]).max() > 0.01                  # the arm turned: not a rest state
    assert np.abs(a["pto_command_force"].values).max() > 0.1


def test_paced_compiled_exchange_equals_reference_bit_for_bit(reference_data, tmp_path, monkeypatch):
    """A paced embedded run (no controller) takes the compiled exchange an exchange a call
    (``CompiledExchange.exchange``): its results are the socket run's bit for bit but for the
    wall-clock variables of the pacing."""
    scene = rm3_scene(reference_data, tmp_path)
    calls = counted(monkeypatch)
    paced = run_scene_file(scene, tmp_path / "paced.nc", progress=False, realtime=64.0)
    remote = socket_run(scene, tmp_path / "socket.nc")
    assert paced.status == remote.status == "complete" and paced.realtime is not None
    assert calls == list(range(paced.steps))
    a, b = xr.load_dataset(tmp_path / "paced.nc"), xr.load_dataset(tmp_path / "socket.nc")
    assert set(a.data_vars) - set(b.data_vars) == WALL_CLOCK - {"controller_latency"}
    for name in set(b.data_vars):
        assert a[name].values.tobytes() == b[name].values.tobytes(), name
