"""External controllers over TCP (SPEC §5.7) on the RM3 two-body device: real processes, free ports.

Frequency-domain reference (written here, exp(-iwt)): the 2x2 heave impedance of the float and spar
without PTO, Z = B(w) - i w (M + A(w)) + i C / w, from the WAMIT HDB. The PTO sees the relative
velocity u = v_f - v_s = e^T v (e = [1, -1]) and its tension T acts as -e T, so u = u0 - Y T with
Y = e^T Z^-1 e and u0 = e^T Z^-1 F_ex: a Thevenin source F = u0 / Y with impedance Z_th = 1 / Y
(R = Re Z_th). Mean absorbed power:

- optimum over all linear PTOs (complex-conjugate control, T = Z_th* u): |F|^2 / (8 R);
- best passive damper (c = |Z_th|): |F|^2 / (4 (|Z_th| + R)).

A spring-damper T = c u + k x (x the extension, u = -i w x) has impedance c + i k / w, so the
conjugate match is c = R, k = -w Im Z_th. At T = 4 s (off resonance: RM3's relative-heave
resonance is near 5 s) k > 0 and the optimum is 1.72 x the best passive damper.
"""

from __future__ import annotations

import json
import math
import os
import secrets
import subprocess
import sys
import threading
import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import xarray as xr
import zmq
from conftest import IDLE_S, REPLY_S, finished, rm3_example_text, stopped
from conftest import build_zmq_msgpack_program

from hydrolink.clients.run import run_scene_file
from hydrolink.clients.analysis.plant import build_plant
from hydrolink.server.service.force_server import serve_in_thread

REPO = Path(__file__).resolve().parents[1]
EXAMPLES = REPO / "examples" / "controllers"
PERIOD, H = 4.0, 2.5
W = 2 * np.pi / PERIOD
DT = PERIOD / 100
MASS = np.diag([725833.0, 886687.0])
HEAVE = [2, 8]


# ---------------------------------------------------------------- reference

@pytest.fixture(scope="module")
def thevenin(reference_data):
    from hydrolink.server.hdb.io import load_hdb
    th = _thevenin_port(load_hdb(reference_data / "rm3_wamit" / "rm3.1"))
    f2 = abs(th["G"] * H / 2) ** 2
    return {**th, "absZ": abs(th["R"] + 1j * th["X"]), "passive": f2 / (4 * (abs(th["R"] + 1j * th["X"]) + th["R"]))}


# ---------------------------------------------------------------- helpers

def scene_text(reference_data: Path, duration: float, controller: str) -> str:
    text = rm3_example_text("rm3.toml")
    hdb = (reference_data / "rm3_wamit" / "rm3.1").as_posix()
    for a, b in (('"../data/rm3_wamit/rm3.1"', f'"{hdb}"'), ("duration = 400.0", f"duration = {duration}"),
                 ("period = 8.0", f"period = {PERIOD}"), ("dt = 0.08", f"dt = {DT}"), ("ramp = 40.0", "ramp = 20.0"),
                 ("damping = 1.2e6          # N s/m", "damping = 0.0")):
        assert a in text
        text = text.replace(a, b)
    return text + "\n[[controllers]]\n" + controller


# the join token every run of this module hands its controllers (SPEC §5.7.2)
TOKEN = secrets.token_urlsafe(32)


def c_controller(tmp_path_factory) -> Path:
    return build_zmq_msgpack_program(EXAMPLES / "c" / "reactive.c", tmp_path_factory.mktemp("cctl") / "reactive",
                                     "-O2", "-Wall", "-Werror", "-ffp-contract=off")


@pytest.fixture()
def server():
    srv, thread = serve_in_thread("tcp://127.0.0.1:*", session_timeout=IDLE_S, plant_builder=build_plant)
    yield srv
    srv.stop()
    thread.join(5)


def run_with(tmp_path: Path, name: str, text: str, server: str, proc_args: list | None) -> tuple[xr.Dataset, dict, tuple]:
    """Run the scene against ``server`` with one controller process; (results, summary, (rc, stderr))."""
    scene = tmp_path / f"{name}.toml"
    scene.write_text(text)
    proc = subprocess.Popen(proc_args, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True) if proc_args else None
    try:
        summary = run_scene_file(scene, tmp_path / f"{name}.nc", server=server, progress=False, timeout=REPLY_S,
                                 control_token=TOKEN)
    finally:
        if proc is not None:
            _, err = finished(proc, REPLY_S)
    return xr.load_dataset(tmp_path / f"{name}.nc"), summary, ((proc.returncode, err) if proc else (None, ""))


def free_address() -> str:
    """A loopback TCP endpoint on a port free now (for a run's own server)."""
    import socket
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{sock.getsockname()[1]}"


def run_own(tmp_path: Path, name: str, text: str, controller: Path, address: str, **kw) -> tuple[dict, tuple]:
    """Run the scene on the run's own server (``hydrolink run``: no --server, listening on
    ``address``) with one controller process; (summary, (rc, stderr))."""
    (tmp_path / f"{name}.toml").write_text(text)
    proc = subprocess.Popen(python_ctl(controller, address), stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        summary = run_scene_file(tmp_path / f"{name}.toml", tmp_path / f"{name}.nc", progress=False, listen=address,
                                 control_token=TOKEN, **{"timeout": 30.0, **kw})
    finally:
        _, err = finished(proc, REPLY_S)
    return summary, (proc.returncode, err)


def python_ctl(file: Path, server: str, *extra: str) -> list:
    return [sys.executable, "-m", "hydrolink.clients.cli", "control", str(file), "--server", server,
            "--token", TOKEN, "--join-wait", str(REPLY_S), *extra]


def mean_power(ds: xr.Dataset) -> float:
    """Mean of the sampled PTO power over the last five periods (the trapezoid's integration nodes)."""
    t = ds["time"].values
    sel = t > t[-1] - 5 * PERIOD + 1e-9
    return float(ds["pto_power"].sel(pto="pto").values[sel].mean())


def controller_block(command: str, c: float, k: float, **extra) -> str:
    lines = [f'name = "ctl"', 'ptos = ["pto"]', f'command = "{command}"', "timeout = 10.0",
             f"parameters = {{ damping = {float(c)!r}, stiffness = {float(k)!r} }}"]
    lines += [f"{key} = {json.dumps(v)}" for key, v in extra.items()]
    return "\n".join(lines) + "\n"


IMPEDANCE = '''
from hydrolink.clients.control import Controller

class Impedance(Controller):
    def on_start(self, info):
        self.c, self.k = float(info["parameters"]["damping"]), float(info["parameters"]["stiffness"])

    def on_step(self, t, m):
        return {p: {"damping": self.c, "stiffness": self.k} for p in self.ptos}
'''


# ---------------------------------------------------------------- power

@pytest.mark.parametrize("command", ["impedance", "force"])
def test_reactive_beats_passive_against_the_optimum(reference_data, thevenin, server, tmp_path, command):
    """RM3 at T = 4 s: the controller in its own process sets the best passive damper, then the
    conjugate-matched spring-damper. ``impedance``: setpoints of the connector (continuous in the
    integrator): both within 0.5 % of the frequency domain. ``force``: F = c u + k x from the
    measurements of step k applied from step k + 1 (examples/controllers/reactive.py, sample and
    hold at dt = T/100): the one-step lag costs the reactive controller < 2 % and shifts the
    passive one by a few %; reactive still ~1.6 x passive and never above the optimum."""
    file = EXAMPLES / "reactive.py"
    if command == "impedance":
        file = tmp_path / "impedance.py"
        file.write_text(IMPEDANCE)
    th = thevenin
    k_opt = -W * th["X"]
    assert k_opt > 0  # off resonance on the stiff side: a positive spring, a stable closed loop
    powers = {}
    for name, c, k in (("passive", th["absZ"], 0.0), ("reactive", th["R"], k_opt)):
        ds, summary, (rc, err) = run_with(tmp_path, name, scene_text(reference_data, 80.0, controller_block(command, c, k)),
                                          server.address, python_ctl(file, server.address))
        assert rc == 0, err
        ev = json.loads(ds.attrs["controller_events"])["ctl"]
        assert ev["ok"] == 2000 and ev["timeout"] == ev["absent"] == ev["invalid"] == 0
        powers[name] = mean_power(ds)
        print(f"{command:9s} {name:8s} P = {powers[name] / 1e3:8.2f} kW  (FD passive optimum {th['passive'] / 1e3:.2f}, "
              f"FD optimum {th['optimum'] / 1e3:.2f}); latency mean {1e3 * ev['mean_latency_s']:.2f} ms, "
              f"max {1e3 * ev['max_latency_s']:.2f} ms; {summary.wall_time:.2f} s wall")
    assert powers["reactive"] > 1.5 * powers["passive"]
    assert th["optimum"] / th["passive"] == pytest.approx(1.72, abs=0.01)
    if command == "impedance":
        assert powers["passive"] == pytest.approx(th["passive"], rel=5e-3)
        assert powers["reactive"] == pytest.approx(th["optimum"], rel=5e-3)
    else:
        assert powers["passive"] == pytest.approx(th["passive"], rel=0.06)
        assert powers["reactive"] == pytest.approx(th["optimum"], rel=0.02)
        assert powers["reactive"] < th["optimum"] * 1.002


# ---------------------------------------------------------------- C == Python

def test_c_controller_equals_python_bit_for_bit(reference_data, tmp_path, tmp_path_factory):
    """The same run with the Python reactive controller and with its C twin, both against one
    separate `hydrolink serve` process: identical results, bit for bit. (One server for both: a
    server in the test process runs BLAS with its default thread count, `hydrolink serve` with one,
    and OpenBLAS may sum in another order with more threads.)"""
    exe = c_controller(tmp_path_factory)
    text = scene_text(reference_data, 12.0, controller_block("force", 3.9e5, 1.36e6,
                                                          measurements=["pto_displacement", "pto_velocity"]))
    serve = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "serve", "--bind", "tcp://127.0.0.1:0"],
                             stderr=subprocess.PIPE, text=True)
    try:
        line = serve.stderr.readline()
        address = line.strip().rsplit(" ", 1)[-1]
        assert address.startswith("tcp://127.0.0.1:"), line
        ds_py, _, (rc, err) = run_with(tmp_path, "py", text, address, python_ctl(EXAMPLES / "reactive.py", address))
        assert rc == 0, err
        ds_c, _, (rc, err) = run_with(tmp_path, "c", text, address, [str(exe), address, TOKEN])
        assert rc == 0, err
    finally:
        stopped(serve)
    assert json.loads(ds_c.attrs["controller_events"])["ctl"]["ok"] == 300
    for v in ("position", "velocity", "pto_force", "pto_power", "pto_command_force", "excitation_force", "radiation_force"):
        assert np.array_equal(ds_py[v].values, ds_c[v].values), v
    assert np.abs(ds_c["pto_command_force"].values).max() > 1e4


# ---------------------------------------------------------------- joining

JOIN_LATE = """
import sys
from hydrolink.clients.control import load_controller, run_controller
print(run_controller(load_controller(sys.argv[1]), sys.argv[2], token=sys.argv[3], join_wait=float(sys.argv[4]),
                     timeout=float(sys.argv[5])), flush=True)
"""


def test_controller_waits_its_join_wait_for_a_server_that_answers_late(reference_data, tmp_path):
    """A controller whose hello is not answered within its reply timeout keeps waiting for its join
    wait: `hydrolink run`'s own server answers its socket only between the run's requests, so a
    hello waits through the run's set-up (its model, numba's compilation: 385 s at load 9 with a
    cold cache), and the controller gave up after its reply timeout (30 s) whatever its
    --join-wait; the run then went on without it (rt5: 5000 fallback decisions). Here the reply
    timeout is 0.5 s and nothing answers the hello for longer (a listener takes its connection and
    closes it: the hello stays queued), then the run's own server binds the port: the controller
    joins and decides every step."""
    import socket

    (tmp_path / "late.toml").write_text(scene_text(reference_data, 2.0, controller_block("force", 3.9e5, 1.36e6)))
    (tmp_path / "join_late.py").write_text(JOIN_LATE)
    listener = socket.create_server(("127.0.0.1", 0))
    listener.settimeout(REPLY_S)
    address = f"tcp://127.0.0.1:{listener.getsockname()[1]}"
    proc = subprocess.Popen([sys.executable, str(tmp_path / "join_late.py"), str(EXAMPLES / "reactive.py"), address,
                             TOKEN, str(REPLY_S), "0.5"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        with listener:
            listener.accept()[0].close()   # its hello is on its way: nothing answers it
        time.sleep(1.5)                    # three reply timeouts pass unanswered (time itself: no event to wait for)
        run_scene_file(tmp_path / "late.toml", tmp_path / "late.nc", progress=False, listen=address,
                       control_token=TOKEN, timeout=REPLY_S)
    finally:
        out, err = finished(proc, REPLY_S)
    assert proc.returncode == 0, err
    assert "'steps': 50" in out
    ev = json.loads(xr.load_dataset(tmp_path / "late.nc").attrs["controller_events"])["ctl"]
    assert ev["ok"] == 50 and ev["timeout"] + ev["absent"] + ev["invalid"] == 0, ev


def test_controller_waits_its_join_wait_for_the_first_measurements(reference_data, tmp_path):
    """The run's own server does not turn while the run's first step compiles (numba's cache
    cold: 14.5 s between steps 0 and 1 at load 2.7, measured, more when loaded), so a joined
    controller's first measure can go unanswered for longer than its reply timeout: it lost its
    direct channel, then gave up (rc 1) and the run went on absent. Until its first measurements
    it now waits for its join wait. Here the run stalls 4 s before its step 1 (its server not
    turning) and the controller's reply timeout is 0.5 s: it decides every step, on its direct
    channel."""
    from hydrolink.server.service import force_server

    (tmp_path / "stall.toml").write_text(scene_text(reference_data, 2.0, controller_block("force", 3.9e5, 1.36e6)))
    (tmp_path / "join_late.py").write_text(JOIN_LATE)
    address = free_address()
    serve_ready, calls = force_server.ForceServer.serve_ready, []

    def stalling(srv):   # before the run's step 1 (its 2nd request with the controller joined): a long compile
        calls.append(srv)
        if len(calls) == 2:
            time.sleep(4.0)
        return serve_ready(srv)
    proc = subprocess.Popen([sys.executable, str(tmp_path / "join_late.py"), str(EXAMPLES / "reactive.py"), address,
                             TOKEN, str(REPLY_S), "0.5"], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        force_server.ForceServer.serve_ready = stalling
        run_scene_file(tmp_path / "stall.toml", tmp_path / "stall.nc", progress=False, listen=address,
                       control_token=TOKEN, timeout=REPLY_S)
    finally:
        force_server.ForceServer.serve_ready = serve_ready
        out, err = finished(proc, REPLY_S)
    assert proc.returncode == 0 and "lost" not in err, err
    assert "'steps': 50" in out and "'direct': True" in out, out
    ev = json.loads(xr.load_dataset(tmp_path / "stall.nc").attrs["controller_events"])["ctl"]
    assert ev["ok"] == 50 and ev["timeout"] + ev["absent"] + ev["invalid"] == 0, ev


def test_a_controller_that_never_joins_is_reported_naming_the_keys(reference_data, tmp_path, caplog):
    """A run whose controller never joins goes on after its join_timeout on the fallback, and says
    so: the server's warning names the scene key (controllers[0].join_timeout), the run's that the
    controller decided no step and what to check (its join, --join-wait)."""
    text = scene_text(reference_data, 2.0, controller_block("force", 3.9e5, 1.36e6, join_timeout=0.2))
    (tmp_path / "alone.toml").write_text(text)
    with caplog.at_level("WARNING"):
        run_scene_file(tmp_path / "alone.toml", tmp_path / "alone.nc", progress=False, listen=free_address(),
                       control_token=TOKEN, timeout=REPLY_S)
    ev = json.loads(xr.load_dataset(tmp_path / "alone.nc").attrs["controller_events"])["ctl"]
    assert ev["absent"] == 50 and ev["ok"] == ev["timeout"] == ev["invalid"] == 0
    said = caplog.text
    assert "'ctl' did not join within its join_timeout (0.2 s, the scene's controllers[0].join_timeout" in said
    assert "50 fallback decision(s) (timeout 0, absent 50, invalid 0): it decided no step" in said
    assert "--join-wait" in said


# ---------------------------------------------------------------- timeouts, crashes, reconnects

SLOW = '''
import os, time
from hydrolink.clients.control import Controller

def wait_for(path):   # at most WAIT_S: a test gone wrong fails, it never hangs
    end = time.monotonic() + float(os.environ["WAIT_S"])
    while not os.path.exists(path) and time.monotonic() < end:
        time.sleep(0.002)

class Slow(Controller):
    def on_start(self, info):
        self.c = float(info["parameters"]["damping"])

    def on_step(self, t, m):
        if m["step"] == 20:
            wait_for(os.environ["RESUME"])   # misses the deadline: back once steps 20-25 were decided without it
        if m["step"] >= 750 and os.environ.get("CRASH"):   # the first measurements at 30 s or later
            open(os.environ["CRASH"], "w").close()
            os._exit(3)                       # dies without a word
        return {p: self.c * v for p, v in zip(self.ptos, m["pto_velocity"].tolist())}

    def on_error(self, error):
        print("ERROR", error["code"], error["field"], error["message"], flush=True)
'''

SUCCESSOR = '''
import os, sys, time
from hydrolink.clients.control import run_controller, load_controller
controller = load_controller(sys.argv[2])      # imports done before the crash: rejoins at once
marker, end = sys.argv[1], time.monotonic() + float(sys.argv[5])
while not os.path.exists(marker):
    if time.monotonic() > end:
        sys.exit("no crash to take over from")
    time.sleep(0.002)
print(run_controller(controller, sys.argv[3], token=sys.argv[4], join_wait=5.0), flush=True)
'''


@pytest.mark.timing
def test_slow_and_crashed_controller_fall_back_and_reconnect(reference_data, server, tmp_path):
    """A controller that misses one deadline and later crashes: the run never hangs; the passive
    fallback takes over (logged, counted, recorded) and, once a controller is known to be gone,
    costs no waiting ("absent"); the slow one's late command (step 20) is refused with error 6
    and it carries on; a new process rejoins after the crash and is accepted.

    Synchronised on the run's decisions, not on wall time: the slow controller sleeps through
    step 20 until the server has decided it (timeout) and steps 21-25 (absent) without it (the
    server's decisions watched as they are taken); it crashes at its first measurements at 30 s or
    later (simulated time: it keeps up from its return, the run waiting for it), whose decision the
    successor, started beforehand and waiting for the crash, takes over within the 3 s timeout.
    Before, it slept 0.8 s (timeout 0.5 s) and crashed at its 200th call, which the run, racing on
    absent decisions while it slept, sometimes ended before: the successor then waited forever."""
    from hydrolink.server.service import controllers

    file = tmp_path / "slow.py"
    file.write_text(SLOW)
    resume, marker = tmp_path / "resume", tmp_path / "crashed"
    succ = tmp_path / "successor.py"
    succ.write_text(SUCCESSOR)
    text = scene_text(reference_data, 60.0, controller_block("force", 1.0e6, 0.0, fallback="passive",
                                                           fallback_damping=7.0e5))
    text = text.replace("timeout = 10.0", "timeout = 3.0")
    decide, taken = controllers.ControlHub._decide, {}

    def deciding(hub, slot, k, status):   # the decisions as the server takes them
        decide(hub, slot, k, status)
        if slot.decided == k:
            taken.setdefault(k, status)
        if k == 25 and [taken.get(j) for j in range(20, 26)] == ["timeout"] + ["absent"] * 5:
            resume.touch()

    successor = subprocess.Popen([sys.executable, str(succ), str(marker), str(file), server.address, TOKEN,
                                  str(REPLY_S)], stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        controllers.ControlHub._decide = deciding
        os.environ.update(CRASH=str(marker), RESUME=str(resume), WAIT_S=str(REPLY_S))
        t0 = time.monotonic()
        ds, summary, (rc, err) = run_with(tmp_path, "slow", text, server.address, python_ctl(file, server.address))
        wall = time.monotonic() - t0
    finally:
        controllers.ControlHub._decide = decide
        for key in ("CRASH", "RESUME", "WAIT_S"):
            os.environ.pop(key, None)
        if not marker.exists():   # it never crashed: nothing starts the successor
            successor.kill()
        out, serr = finished(successor)
    assert rc == 3, err            # the first controller crashed ...
    assert "the decision for step 20 was already taken" in err   # ... after its late command was refused (error 6)
    assert successor.returncode == 0, serr
    status = ds["controller_status"].sel(controller="ctl").values
    ev = json.loads(ds.attrs["controller_events"])["ctl"]
    print("events", ev, "wall", round(wall, 2), "s; successor", out.strip())
    timeouts = np.flatnonzero(status == 1)
    # the slow step (a loaded machine may add a missed deadline: counted all the same)
    assert timeouts[0] == 21 and len(timeouts) == ev["timeout"] >= 1
    assert np.all(status[22:27] == 2)                  # absent (no waiting) until the slow one is back
    assert np.any(status[27:751] == 0)                 # ... and it is accepted again before it crashes
    # the successor joined as the first process crashed: it got the newest measurements at once
    assert "'steps': 0" not in out and status[-1] == 0
    assert ev["invalid"] == 0 and ev["ok"] + ev["timeout"] + ev["absent"] == 1500
    assert ds["controller_fallbacks"].values[-1, 0] == ev["timeout"] + ev["absent"]
    damping = ds["pto_damping"].sel(pto="pto").values
    assert damping[21] == 7.0e5 and damping[-1] == 0.0   # passive fallback, then the scene's damping again
    assert ds.attrs["status"] == "complete"


def test_a_command_for_a_step_decided_without_it_is_late_however_many_steps_since(reference_data):
    """SPEC §5.7.4: a command whose step's decision was already taken (its deadline passed: the
    fallback was used) is error 6 and counted late — also when later steps were decided since (the
    run races on while the controller is absent). Before, only the newest decided step was
    remembered: a command for an older one was taken as received, neither refused nor counted.
    Its return then makes it active: the newest measurements go to it (their decision taken
    absent: that command is late too) and the next step waits for its command, which decides it."""
    from hydrolink.protocol.codec import Code, ProtocolError
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.service.controllers import ControlHub

    text = scene_text(reference_data, 4.0, controller_block("force", 1.0e6, 0.0))
    sent = []
    hub = ControlHub(parse_scene(text), text, 1, "s", lambda route, mtype, parent, fields, own=None:
                     sent.append((mtype, parent, fields)), TOKEN)
    ident = {"controller": "ctl", "epoch": 1, "wait": 1.0}
    rng = np.random.default_rng(0)

    def step(seq: int) -> dict | None:   # the multibody's step seq: the measurements of seq - 1 relayed, decided
        meas = {"step": seq - 1, **{n: rng.standard_normal(shape) for n, shape in hub.mb_shapes}}
        return hub.after_step(seq, 0, True, meas, {"seq": seq}, ["mb"], f"m{seq}")

    hub.join("ctl")
    assert hub.after_step(0, 0, True, None, {"seq": 0}, ["mb"], "m0") == {"seq": 0}   # joined: no wait at t = 0
    assert hub.measure(ident, ["ctl"], "q0", "own") is None   # parked: no measurements yet
    assert step(1) is None and sent[-1][:2] == ("measurements", "q0") and sent[-1][2]["step"] == 0
    hub.poll(math.inf)   # the controller sleeps: step 0's deadline passes
    assert sent[-1][0] == "forces" and sent[-1][2]["control"]["ctl"]["status"] == "timeout"
    for seq in (2, 3, 4):   # absent: decided at once, no waiting
        assert step(seq)["control"]["ctl"]["status"] == "absent"
    for k in (0, 3):        # its command for step 0, then for the newest (3, delivered at its return)
        with pytest.raises(ProtocolError) as late:
            hub.command({**ident, "step": k, "commands": {"pto": {"force": 1.0}}}, ["ctl"], f"c{k}", "own")
        assert (late.value.code, late.value.field) == (Code.OUT_OF_ORDER, "step")
        assert f"the decision for step {k} was already taken" in late.value.message
        if k == 0:
            assert hub.measure(ident, ["ctl"], "q1", "own")[1]["step"] == 3
    assert hub.summary()["ctl"] == {"ok": 0, "timeout": 1, "absent": 3, "invalid": 0, "late": 2, "joins": 1}
    assert hub.measure(ident, ["ctl"], "q2", "own") is None   # active again: parked for the next measurements
    assert step(5) is None and sent[-1][:2] == ("measurements", "q2") and sent[-1][2]["step"] == 4
    assert hub.command({**ident, "step": 4, "commands": {"pto": {"force": 2.0}}}, ["ctl"], "c4", "own") is None
    assert sent[-1][0] == "forces" and sent[-1][2]["control"]["ctl"]["commands"] == {"pto": {"force": 2.0}}
    assert hub.summary()["ctl"]["ok"] == 1 and hub.summary()["ctl"]["late"] == 2


# ---------------------------------------------------------------- malformed commands, wrong session/version

BAD = '''
import math
from hydrolink.clients.control import Controller

class Bad(Controller):
    def on_start(self, info):
        self.errors = []

    def on_step(self, t, m):
        step = round(t / 0.04)
        if step == 5:
            return {"pto": math.nan}
        if step == 10:
            return {"nope": 1.0}
        if step == 15:
            return {"pto": 5.0e9}          # beyond max_force
        return {"pto": 1.0e6 * m["pto_velocity"][0]}

    def on_error(self, error):
        print("ERROR", error["code"], error["field"], "|", error["message"], flush=True)
'''


def test_malformed_commands_get_clear_errors_and_the_fallback(reference_data, server, tmp_path):
    file = tmp_path / "bad.py"
    file.write_text(BAD)
    text = scene_text(reference_data, 4.0, controller_block("force", 1.0e6, 0.0, max_force=1.0e7))
    ds, _, (rc, err) = run_with(tmp_path, "bad", text, server.address, python_ctl(file, server.address))
    assert rc == 0, err
    ev = json.loads(ds.attrs["controller_events"])["ctl"]
    assert ev == {**ev, "ok": 97, "invalid": 3, "timeout": 0, "absent": 0}
    status = ds["controller_status"].sel(controller="ctl").values
    assert [int(i) for i in np.flatnonzero(status == 3)] == [6, 11, 16]
    assert ds["controller_fallbacks"].values[-1, 0] == 3
    # hold: the command before each bad one stays in force
    f = ds["pto_command_force"].sel(pto="pto").values
    assert f[6] == f[5] and f[11] == f[10] and f[16] == f[15]


def test_wrong_session_version_and_name(reference_data, server, tmp_path):
    """Raw messages against a session with a controller: clear errors, the session unharmed."""
    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import parse_scene

    text = scene_text(reference_data, 4.0, controller_block("force", 1.0e6, 0.0, join_timeout=0.2))
    scene_path = tmp_path / "s.toml"
    scene_path.write_text(text)
    hdbs = load_scene_hdbs(parse_scene(text), scene_path)
    ctx = zmq.Context()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(server.address)

    def ask(**msg) -> dict:
        sock.send(msgpack.packb({"v": 1, "msg_id": "x", "session": None, **msg}))
        assert sock.poll(5000), "no reply"
        return msgpack.unpackb(sock.recv())

    try:
        with ServerConnection(server.address, timeout=REPLY_S) as conn:
            conn.hello(text, hdbs)
            token = conn.control_token     # drawn by the server, handed to the owner only
            assert isinstance(token, str) and len(token) >= 32
            r = ask(type="hello", role="controller", controller="ctl", session="0" * 32, token=token)
            assert (r["code"], r["name"], r["field"]) == (7, "unknown_session", "session")
            r = ask(type="hello", role="controller", controller="ctl", v=2, token=token)
            assert (r["code"], r["name"]) == (2, "version_mismatch") and "[1]" in r["message"]
            r = ask(type="hello", role="controller", controller="ctl")               # no token
            assert (r["code"], r["field"]) == (4, "token")
            r = ask(type="hello", role="controller", controller="ctl", token="x" * 32)   # a stranger's guess
            assert (r["code"], r["field"]) == (7, "token") and r.get("session") is None
            r = ask(type="hello", role="controller", controller="ctl", session=conn.session, token="x" * 32)
            assert (r["code"], r["name"], r["field"]) == (15, "unauthorized", "token")
            r = ask(type="hello", role="controller", controller="other", token=token)   # no such controller
            assert (r["code"], r["field"]) == (7, "token") and "'other'" in r["message"]
            r = ask(type="hello", role="controller", controller="other", session=conn.session, token=token)
            assert (r["code"], r["field"]) == (5, "controller") and "'ctl'" in r["message"]
            r = ask(type="hello", role="controller", controller="ctl", session=conn.session, token=token)
            assert r["type"] == "welcome" and r["epoch"] == 1
            own = r["session"]                  # the controller's own id, not the owner's
            assert own != conn.session
            ctl = r["control"]
            assert ctl["ptos"] == ["pto"] and ctl["steps_per_period"] == 1 and ctl["latency"] == 1
            r = ask(type="measure", session=own, controller="ctl", epoch=0)
            assert r["code"] == 5 and r["field"] == "epoch"
            r = ask(type="measure", session=conn.session, controller="ctl", epoch=1, wait=0.0)   # the owner's id
            assert (r["code"], r["field"]) == (7, "session")
            r = ask(type="hello", role="controller", controller="ctl", token=token)   # by token: a second process
            assert r["epoch"] == 2 and r["rejoined"] is True
            own2 = r["session"]
            r = ask(type="measure", session=own, controller="ctl", epoch=1, wait=0.0)
            assert (r["code"], r["name"]) == (10, "wrong_state") and "newer connection" in r["message"]
            r = ask(type="measure", session=own2, controller="ctl", epoch=2, wait=0.05)
            assert r["type"] == "idle" and r["session"] == own2
            r = ask(type="command", session=own2, controller="ctl", epoch=2, step=0, commands={})
            assert (r["code"], r["field"]) == (6, "step")
            # a controller's id can neither step, roll back nor end the owner's session
            for kind in ("step", "save", "restore", "release"):
                r = ask(type=kind, session=own2, seq=0, time=0.0)
                assert (r["code"], r["name"]) == (3, "unknown_type"), r
            # the multibody's step 1 must carry the measurements of step 0
            f0 = conn.step(0, 0.0, np.array(conn.setup.equilibrium_position), np.zeros((2, 6)))
            assert "control" not in f0
            with pytest.raises(Exception, match="measurements"):
                conn.step(1, DT, np.array(conn.setup.equilibrium_position), np.zeros((2, 6)))
            r = ask(type="bye", session=own2)   # the controller leaves; the session goes on
            assert r["type"] == "goodbye" and r["controller"] == "ctl"
            r = ask(type="measure", session=own2, controller="ctl", epoch=2, wait=0.0)
            assert (r["code"], r["field"]) == (7, "session")
            assert conn.request("ping")["type"] == "pong"   # the owner's session is still open
    finally:
        sock.close(0)
        ctx.term()


def test_in_process_server_refuses_controllers(reference_data, tmp_path):
    from hydrolink.clients.lockstep.connection import RemoteError, ServerConnection
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.service.force_server import ForceServer

    text = scene_text(reference_data, 4.0, controller_block("force", 1.0e6, 0.0))
    (tmp_path / "s.toml").write_text(text)
    hdbs = load_scene_hdbs(parse_scene(text), tmp_path / "s.toml")
    with ServerConnection(ForceServer(None)) as conn, pytest.raises(RemoteError, match="scene.controllers"):
        conn.hello(text, hdbs)


def test_run_polls_its_own_server_and_equals_a_separate_one(reference_data, server, tmp_path):
    """``hydrolink run`` of a scene with a controller and no --server polls its own server from the
    run's thread (ForceServer polled: no server thread, the run's steps in-process on its own
    arrays — server/service/controlled_step.py, every step of the run — the controller over its
    direct channel, SPEC §5.7.5, in binary frames, §5.7.6): the results equal, bit for bit and variable by variable, the same
    run against a server in a thread with the controller over ZeroMQ (--no-direct), whose steps are
    messages; no thread is left running; a second multibody hello to the run's socket is refused
    (one session: the run's)."""
    from hydrolink.protocol import codec
    from hydrolink.server.service import controlled_step, force_server

    text = scene_text(reference_data, 2.0, controller_block("force", 3.9e5, 1.36e6,
                                                         measurements=["pto_displacement", "pto_velocity"]))
    ds_remote, _, (rc, err) = run_with(tmp_path, "remote", text, server.address,
                                       python_ctl(EXAMPLES / "reactive.py", server.address, "--no-direct"))
    assert rc == 0 and "over ZeroMQ" in err, err   # kept on ZeroMQ (a server thread offers the channel too)
    address = free_address()
    threads = threading.active_count()
    ctx = zmq.Context()
    stranger = ctx.socket(zmq.DEALER)
    stranger.setsockopt(zmq.LINGER, 0)
    seen = {}
    port = controlled_step.ControlledStep
    serve_once, in_process, compiled = force_server.ForceServer.serve_once, port.__call__, port.decided
    steps = []

    def stepped(port, seq, *args):
        steps.append(seq)
        return in_process(port, seq, *args)

    def decided(port, seq, *args):   # a step the compiled exchange took (clients/exudyn/compiled_exchange.py)
        steps.append(seq)
        return compiled(port, seq, *args)

    def watched(srv):   # once the run's session is open: a stranger's multibody hello, answered by a later turn
        if "threads" not in seen and srv.sessions:
            seen["threads"] = threading.active_count()
            stranger.connect(address)
            stranger.send(codec.pack(codec.message("hello", "x1", None, role="multibody", scene=text, hdbs={})))
        serve_once(srv)
    try:
        force_server.ForceServer.serve_once = watched
        port.__call__, port.decided = stepped, decided
        summary, (rc, err) = run_own(tmp_path, "own", text, EXAMPLES / "reactive.py", address)
        assert stranger.poll(5000)
        refused = codec.unpack(stranger.recv())
    finally:
        force_server.ForceServer.serve_once = serve_once
        port.__call__, port.decided = in_process, compiled
        stranger.close(0)
        ctx.term()
    assert rc == 0 and "over the direct channel, binary frames" in err, err   # SPEC §5.7.6
    assert summary.server == address and (refused["code"], refused.get("limit")) == (14, "sessions")
    assert seen["threads"] <= threads + 1   # at most the results writer's thread: no server thread
    ds_own = xr.load_dataset(tmp_path / "own.nc")
    assert json.loads(ds_own.attrs["controller_events"])["ctl"]["ok"] == 50
    assert steps == list(range(ds_own.sizes["time"]))   # every step of the run on the in-process path
    assert set(ds_own.data_vars) == set(ds_remote.data_vars)
    for v in ds_own.data_vars:   # controller_latency is wall time: measured, not computed
        if v != "controller_latency":
            assert np.array_equal(ds_own[v].values, ds_remote[v].values, equal_nan=True), v
    assert np.abs(ds_own["pto_command_force"].values).max() > 1e3   # the ramp's first 2 s: commands of kN


def test_measurements_leave_before_the_model_steps(reference_data, tmp_path):
    """A controlled step relays its measurements before the session's model steps (ControlHub.relay
    from ForceServer._step), so the controller's round trip overlaps the model's step: the relay of
    step seq - 1's measurements comes before the model step of seq, for every seq >= 1; the run is
    decided by the controller throughout (its results equal a separate server's: the test above)."""
    from hydrolink.server.service import controllers, session as session_module

    text = scene_text(reference_data, 2.0, controller_block("force", 3.9e5, 1.36e6,
                                                         measurements=["pto_displacement", "pto_velocity"]))
    advance, advanced, relay = session_module.Session.advance, session_module.Session.advanced, controllers.ControlHub._relay
    order = []

    def advancing(s, seq, *args, **kw):
        order.append(("step", seq))
        return advance(s, seq, *args, **kw)

    def compiled(s, seq, *args):   # the step taken by the model's compiled kernel (clients/exudyn/compiled_exchange.py)
        order.append(("step", seq))
        return advanced(s, seq, *args)

    def relaying(hub, meas, *args):
        order.append(("relay", meas["step"]))
        return relay(hub, meas, *args)
    try:
        session_module.Session.advance, controllers.ControlHub._relay = advancing, relaying
        session_module.Session.advanced = compiled
        _, (rc, err) = run_own(tmp_path, "early", text, EXAMPLES / "reactive.py", free_address())
    finally:
        session_module.Session.advance, controllers.ControlHub._relay = advance, relay
        session_module.Session.advanced = advanced
    assert rc == 0 and "over the direct channel" in err, err
    ds = xr.load_dataset(tmp_path / "early.nc")
    assert json.loads(ds.attrs["controller_events"])["ctl"]["ok"] == 50
    assert order == [("step", 0)] + [e for seq in range(1, 51) for e in (("relay", seq - 1), ("step", seq))]


def test_controller_whose_direct_channel_breaks_goes_on_over_zeromq(reference_data, tmp_path):
    """The run's own server loses a controller's direct channel mid-run (SPEC §5.7.5), once while
    the controller computes a command and once while its request waits for the next measurements:
    the controller sends its request again over ZeroMQ and decides the rest of the run there; the
    measurements whose delivery went down with the channel are delivered again to its next
    request, so every decision is the controller's (0.5 s timeout)."""
    from hydrolink.server.service import force_server

    text = scene_text(reference_data, 2.0, controller_block("force", 3.9e5, 1.36e6,
                                                         measurements=["pto_displacement", "pto_velocity"])
                      .replace("timeout = 10.0", "timeout = 0.5"))
    wait_direct, serve_ready, cut = force_server.ForceServer._wait_direct, force_server.ForceServer._serve_ready, {}

    def breaking(where, plain):   # the 10th call with a direct link open: its socket closed under it
        def call(srv, *args):
            links = srv._direct.links if srv._direct is not None else []
            cut[where] = cut.get(where, 0) + bool(links)
            if links and cut[where] == 10:
                links[0].close()
            return plain(srv, *args)
        return call
    try:   # _wait_direct: the run waits for the command; _serve_ready: before the run's next step request
        force_server.ForceServer._wait_direct = breaking("waiting", wait_direct)
        _, (rc, err1) = run_own(tmp_path, "cut1", text, EXAMPLES / "reactive.py", free_address())
        force_server.ForceServer._wait_direct = wait_direct
        force_server.ForceServer._serve_ready = breaking("parked", serve_ready)
        _, (rc2, err2) = run_own(tmp_path, "cut2", text, EXAMPLES / "reactive.py", free_address())
    finally:
        force_server.ForceServer._wait_direct, force_server.ForceServer._serve_ready = wait_direct, serve_ready
    for name, code, err in (("cut1", rc, err1), ("cut2", rc2, err2)):
        assert code == 0 and "over ZeroMQ" in err, err
        ds = xr.load_dataset(tmp_path / f"{name}.nc")
        ev = json.loads(ds.attrs["controller_events"])["ctl"]
        assert ev["ok"] == 50 and ev["timeout"] + ev["absent"] + ev["invalid"] == 0, (name, ev)
    assert cut["waiting"] >= 10 and cut["parked"] >= 10


NAP = '''
import time
from hydrolink.clients.control import Controller

class Nap(Controller):
    def on_start(self, info):
        self.c = float(info["parameters"]["damping"])

    def on_step(self, t, m):
        if round(t / 0.04) == 10:
            time.sleep(1.0)            # misses the 0.3 s deadline: step 10 on the fallback
        return {p: self.c * v for p, v in zip(self.ptos, m["pto_velocity"].tolist())}
'''


@pytest.mark.timing
def test_polled_run_hears_a_controller_back_after_a_missed_deadline(reference_data, tmp_path):
    """The run's own polled server serves its socket at every step, not only while a step waits:
    a controller that missed a deadline (then absent: no step waits for it) is heard again with
    its next request and decides the rest of the run (paced: 3 s, the nap 1 s from 0.4 s)."""
    (tmp_path / "nap.py").write_text(NAP)
    text = scene_text(reference_data, 3.0, controller_block("force", 1.0e6, 0.0).replace("timeout = 10.0",
                                                                                       "timeout = 0.3"))
    _, (rc, err) = run_own(tmp_path, "nap", text, tmp_path / "nap.py", free_address(),
                           realtime=1.0)   # paced: the nap ends mid-run
    assert rc == 0, err
    ds = xr.load_dataset(tmp_path / "nap.nc")
    ev = json.loads(ds.attrs["controller_events"])["ctl"]
    status = ds["controller_status"].sel(controller="ctl").values
    assert ev["timeout"] == 1 and status[11] == 1 and ev["ok"] >= 40    # step 10's decision: row 11; ~25 absent
    assert np.all(status[-20:] == 0)                                   # back: the run's end decided by it


def test_wave_probes_match_the_model_and_travel(reference_data):
    """The server's elevation probes: at the origin exactly the model's wave_elevation; a probe
    downstream sees the same wave later by x / c (phase speed w / k, deep water k = w^2 / g)."""
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.sea.probes import WaveProbes
    from hydrolink.server.hdb.io import load_hdb
    from hydrolink.server.model import HydroModel

    scene = parse_scene(scene_text(reference_data, 4.0, controller_block("force", 1.0, 0.0)))
    rm3 = load_hdb(reference_data / "rm3_wamit" / "rm3.1")
    model = HydroModel(scene, {"float": rm3, "spar": rm3})
    k = W * W / 9.81
    lag = 10.0 / (W / k)
    probes = WaveProbes(model.waves, np.array([[0.0, 0.0], [10.0, 0.0]]), np.array([lag]), 9.81, np.inf)
    eq = model.setup_info().equilibrium_position
    for step in range(720):
        t = step * DT
        eta = probes(t)
        out = model.step(t, eq, np.zeros((2, 6)))
        if step < 100 and step % 10:
            continue          # the ramp too (every 10th step), then every step after the ramp
        assert eta[0, 0] == pytest.approx(out["wave_elevation"], abs=1e-12)
        assert eta[0, 1] == pytest.approx(probes(t + lag)[0, 0], abs=1e-12)  # the preview column
        if t - lag > 20.0:   # after the ramp (a function of time only)
            assert eta[1, 0] == pytest.approx(probes(t - lag)[0, 0], abs=1e-9)   # downstream = earlier at 0


def test_pseudospectral_preview_controller_reaches_the_optimum(reference_data, thevenin, server, tmp_path):
    """examples/controllers/pseudospectral.py: feedforward from the server's perfect wave preview
    (one Fourier component, 2 s of preview) plus velocity tracking; mean power near |F|^2/(8R)."""
    th = thevenin
    params = {"omega": W, "excitation_re": th["G"].real, "excitation_im": th["G"].imag,
              "impedance_re": th["R"], "impedance_im": th["X"], "feedback": th["R"]}
    block = controller_block("force", 0.0, 0.0, measurements=["pto_velocity", "wave_elevation"], preview=2.0)
    block = block.replace("parameters = { damping = 0.0, stiffness = 0.0 }",
                          "parameters = { " + ", ".join(f"{k} = {float(v)!r}" for k, v in params.items()) + " }")
    ds, _, (rc, err) = run_with(tmp_path, "ps", scene_text(reference_data, 80.0, block), server.address,
                                python_ctl(EXAMPLES / "pseudospectral.py", server.address))
    assert rc == 0, err
    p = mean_power(ds)
    print(f"pseudo-spectral P = {p / 1e3:.2f} kW (FD optimum {th['optimum'] / 1e3:.2f} kW)")
    assert p == pytest.approx(th["optimum"], rel=0.01) and p < th["optimum"]


@pytest.mark.parametrize("example", ["passive", "latching"])
def test_examples_run(reference_data, server, tmp_path, example):
    """The other examples drive the device: passive damping (force) and latching (impedance)."""
    if example == "passive":
        block = controller_block("force", 9.5e5, 0.0)
    else:
        block = controller_block("impedance", 0.0, 0.0).replace(
            "parameters = { damping = 0.0, stiffness = 0.0 }",
            "parameters = { damping = 9.5e5, latch_damping = 1.0e9, latch_time = 0.4 }")
    ds, _, (rc, err) = run_with(tmp_path, example, scene_text(reference_data, 40.0, block), server.address,
                                python_ctl(EXAMPLES / f"{example}.py", server.address))
    assert rc == 0, err
    assert json.loads(ds.attrs["controller_events"])["ctl"]["ok"] == 1000
    p = mean_power(ds)
    print(f"{example}: P = {p / 1e3:.2f} kW")
    assert p > 5e3   # latching pays off only in waves longer than the natural period (not at 4 s)
    if example == "latching":
        d = ds["pto_damping"].sel(pto="pto").values[1:]
        assert set(np.unique(d)) == {9.5e5, 1.0e9}


def _thevenin_port(rm3) -> dict:
    om = rm3["omega"].values

    def at(values):
        flat = values.reshape(om.size, -1)
        return np.array([np.interp(W, om, f.real) + 1j * np.interp(W, om, f.imag) for f in flat.T]).reshape(values.shape[1:])

    hv = np.ix_(range(om.size), HEAVE, HEAVE)
    a, b = at(rm3["added_mass"].values[hv]).real, at(rm3["radiation_damping"].values[hv]).real
    c = rm3["hydrostatic_stiffness"].values[np.ix_(HEAVE, HEAVE)]
    z = b - 1j * W * (MASS + a) + 1j * c / W
    e = np.array([1.0, -1.0])
    zi = np.linalg.inv(z)
    z_th = 1 / (e @ zi @ e)
    g = (e @ zi @ at(rm3["excitation_force"].values[:, 0, HEAVE])) * z_th   # per metre of amplitude
    r = z_th.real
    return {"R": r, "X": z_th.imag, "G": g, "optimum": abs(g * H / 2) ** 2 / (8 * r)}


def test_period_and_latency(reference_data, server, tmp_path):
    """period = 2 dt, latency = 2: the command from the measurements of step k (k even) is in force
    from step k + 2 until the next one, and equals c v_k + k x_k of the state at t_k."""
    c, k = 3.9e5, 1.36e6
    block = controller_block("force", c, k, period=2 * DT, latency=2)
    ds, _, (rc, err) = run_with(tmp_path, "lat", scene_text(reference_data, 4.0, block), server.address,
                                python_ctl(EXAMPLES / "reactive.py", server.address))
    assert rc == 0, err
    status = ds["controller_status"].sel(controller="ctl").values
    assert np.all(status[2::2] == 0) and np.all(np.isnan(status[1::2])) and np.isnan(status[0])
    f = ds["pto_command_force"].sel(pto="pto").values
    v = ds["pto_velocity"].sel(pto="pto").values
    x = ((ds["position"] - ds["equilibrium_position"]).sel(dof="heave").values @ np.array([1.0, -1.0]))
    for s in range(2, f.size):
        j = s - 2 - (s % 2)        # the newest measurement step whose command is due by step s
        assert f[s] == pytest.approx(c * v[j] + k * x[j], rel=1e-9, abs=1e-6)
    assert np.all(f[:2] == 0.0)


@pytest.mark.timing
def test_step_pipelined_behind_a_deferred_step_is_answered_in_order(reference_data, server, tmp_path):
    """SPEC §1 and §5.7: a client's requests are answered in order, and a step waiting for a
    command is deferred. A step pipelined behind it (sent before the deferred reply came) is held
    and handled after it: forces seq 1 (the command of step 0) then forces seq 2 (the command of
    step 1), each with its own decision. Before, seq 2 replaced the deferred reply and seq 1 was
    never answered. A ``measure`` with ``wait`` = nil is one without ``wait`` (SPEC §2)."""
    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol import codec
    from hydrolink.protocol.scene import parse_scene

    text = scene_text(reference_data, 4.0, controller_block("force", 1.0e6, 0.0))
    scene_path = tmp_path / "s.toml"
    scene_path.write_text(text)
    hdbs = load_scene_hdbs(parse_scene(text), scene_path)
    ctx = zmq.Context.instance()
    mb, ctl = ctx.socket(zmq.DEALER), ctx.socket(zmq.DEALER)
    for sock in (mb, ctl):
        sock.setsockopt(zmq.LINGER, 0)
        sock.connect(server.address)

    def recv(sock) -> dict:
        assert sock.poll(8000), "no reply within 8 s"
        return codec.unpack(sock.recv())

    try:
        with ServerConnection(server.address, timeout=REPLY_S) as conn:
            conn.hello(text, hdbs)
            sid = conn.session
            x = np.array(conn.setup.equilibrium_position, float)

            def step(seq: int) -> None:
                meas = None if seq == 0 else {
                    "step": seq - 1, "pto_displacement": np.zeros(1), "pto_velocity": np.full(1, 0.1 * seq),
                    "pto_force": np.zeros(1), "body_position": np.zeros((2, 6)), "body_velocity": np.zeros((2, 6))}
                mb.send(codec.pack(codec.message("step", f"mb-{seq}", sid, seq=seq, time=seq * DT, position=x,
                                                 velocity=np.zeros((2, 6)), measurements=meas)))

            ctl.send(codec.pack(codec.message("hello", "c-0", sid, role="controller", controller="ctl",
                                              token=conn.control_token)))
            welcome = recv(ctl)
            epoch, own = welcome["epoch"], welcome["session"]   # the controller's own session id
            ctl.send(codec.pack(codec.message("measure", "c-1", own, controller="ctl", epoch=epoch, wait=None)))
            step(0)
            assert recv(mb)["seq"] == 0
            step(1)                       # deferred: the command of step 0 is due at seq 1
            step(2)                       # pipelined behind it
            m0 = recv(ctl)
            assert (m0["type"], m0["parent"], m0["step"]) == ("measurements", "c-1", 0), m0
            assert not mb.poll(200), "a reply came before the command it waits for"
            ctl.send(codec.pack(codec.message("command", "c-2", own, controller="ctl", epoch=epoch, step=0,
                                              commands={"pto": {"force": 1000.0}})))
            f1 = recv(mb)
            assert (f1["type"], f1["parent"], f1["seq"]) == ("forces", "mb-1", 1), f1
            assert f1["control"]["ctl"]["status"] == "ok" and f1["control"]["ctl"]["commands"] == {"pto": {"force": 1000.0}}
            m1 = recv(ctl)                # the held step 2 relayed the measurements of step 1
            assert (m1["type"], m1["parent"], m1["step"]) == ("measurements", "c-2", 1), m1
            ctl.send(codec.pack(codec.message("command", "c-3", own, controller="ctl", epoch=epoch, step=1,
                                              commands={"pto": {"force": 2000.0}}, wait=0.05)))
            f2 = recv(mb)
            assert (f2["type"], f2["parent"], f2["seq"]) == ("forces", "mb-2", 2), f2
            assert f2["control"]["ctl"]["commands"] == {"pto": {"force": 2000.0}}
            assert recv(ctl)["type"] == "idle"
            ctl.send(codec.pack(codec.message("measure", "c-4", own, controller="ctl", epoch=epoch, wait=None)))
            t0 = time.monotonic()
            idle = recv(ctl)               # nil wait = the default 1 s, not an error
            assert idle["type"] == "idle" and 0.5 < time.monotonic() - t0 < 5.0, idle
    finally:
        mb.close(0)
        ctl.close(0)


def test_plant_pi_gains_from_the_plant_reach_the_optimum(reference_data, thevenin, server, tmp_path):
    """examples/controllers/plant_pi.py takes the linear plant at join (SPEC §5.7.2) and designs the
    conjugate spring-damper from the plant's own PTO response (no tuning parameter but the period):
    mean power at T = 4 s within 2 % of |F|^2/(8R) of the frequency domain written here, as the
    hand-tuned reactive controller (same one-step force lag)."""
    block = controller_block("force", 0.0, 0.0, measurements=["pto_displacement", "pto_velocity"])
    block = block.replace("parameters = { damping = 0.0, stiffness = 0.0 }", f"parameters = {{ peak_period = {PERIOD!r} }}")
    ds, _, (rc, err) = run_with(tmp_path, "plant_pi", scene_text(reference_data, 80.0, block), server.address,
                                python_ctl(EXAMPLES / "plant_pi.py", server.address))
    assert rc == 0, err
    assert json.loads(ds.attrs["controller_events"])["ctl"]["ok"] == 2000
    p = mean_power(ds)
    print(f"plant_pi P = {p / 1e3:.2f} kW (FD optimum {thevenin['optimum'] / 1e3:.2f} kW, best passive "
          f"{thevenin['passive'] / 1e3:.2f} kW)")
    assert p == pytest.approx(thevenin["optimum"], rel=0.02) and p < thevenin["optimum"] * 1.002
