"""Sessions stepping in worker processes (server/service/step_worker.py, issue 35 item 4): results
equal to the same session stepped in-process, a worker that dies or hangs ends its session with
error 16 and the server serves the next hello, every worker reaped; the controllers' wave preview
computed along the run (equal to the closed-form elevation) and not at all when no controller
joined. Latency figures are bench/bench_attacks.py's (isolation), not asserted here."""

from __future__ import annotations

import math
import os
import signal

import numpy as np
import pytest
from analytic_hdb import make_body_hdb

from conftest import REPLY_S, body, irregular_waves, linear_pto, regular_waves, scene_toml
from hydrolink.clients.lockstep.connection import RemoteError, ServerConnection
from hydrolink.protocol.scene import parse_scene
from hydrolink.server.model import HydroModel
from hydrolink.server.sea.probes import PreviewGrid, WaveProbes
from hydrolink.server.service.force_server import ForceServer, serve_in_thread
from hydrolink.server.service.step_worker import WorkerSession

DT = 0.05
WAIT = REPLY_S   # a reply expected (a worker starts in well under it)


def _scene(n_bodies: int, waves: dict, **sections) -> str:
    return scene_toml(dt=DT, duration=1e3, waves=waves, hydro={"irf_duration": 2.0},
                      bodies=[body(f"b{i}", hdb="float.nc", hdb_body="float", mass=3.0e5,
                                   center_of_mass=[40.0 * i, 0, -1], inertia=[1e7, 1e7, 2e7])
                              for i in range(n_bodies)], **sections)


LIGHT = _scene(1, regular_waves(1.0, 6.0))
HEAVY = _scene(6, irregular_waves(2.0, 8.0, components=30000, seed=3))   # a step of a millisecond or more
CONTROLLED = _scene(1, irregular_waves(2.0, 8.0, components=50, seed=4),
                    ptos=[linear_pto("pto", "b0", [0, 0, -1], "ground", [0, 0, -20], damping=1e5)],
                    controllers=[{"name": "ctl", "ptos": ["pto"], "timeout": 0.05, "join_timeout": 0.2,
                                  "period": 2 * DT, "measurements": ["wave_elevation"], "preview": 1.0,
                                  "preview_step": 3 * DT}])


@pytest.fixture(scope="module")
def hdbs():
    return {"float.nc": make_body_hdb(omega=np.linspace(0.2, 4.0, 12), name="float")}


def _states(n_bodies: int, steps: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [(rng.normal(0, 0.1, (n_bodies, 6)), rng.normal(0, 0.1, (n_bodies, 6))) for _ in range(steps)]


def _forces(reply: dict) -> np.ndarray:
    return np.stack([reply[k] for k in ("excitation", "radiation", "hydrostatic")])


def _alone(scene: str, hdbs: dict, states) -> list[np.ndarray]:
    """The session stepped by the embedded in-process server (no worker, no trial step)."""
    with ServerConnection(ForceServer(None)) as conn:
        conn.hello(scene, hdbs)
        return [_forces(conn.step(k, k * DT, x, v)) for k, (x, v) in enumerate(states)]


def _worker_of(srv: ForceServer, session: str):
    s = srv.sessions[session]
    assert type(s) is WorkerSession
    return s.worker.process


def test_a_heavy_and_a_light_session_side_by_side_give_their_single_runs_results(served, hdbs):
    """The heavy session's step (a millisecond or more of CPU) passes the bound (0.2 ms): it steps
    in a worker; the light one on the loop (it may step in a worker too: the results are the same).
    Both equal, bit for bit, the same steps on the embedded server (no worker, no trial step)."""
    srv = served(isolate_step_s=0.2e-3)
    heavy_states, light_states = _states(6, 12, seed=1), _states(1, 12, seed=2)
    with ServerConnection(srv.address, timeout=WAIT) as heavy, ServerConnection(srv.address, timeout=WAIT) as light:
        heavy.hello(HEAVY, hdbs)
        light.hello(LIGHT, hdbs)
        process = _worker_of(srv, heavy.session)
        got_heavy, got_light = [], []
        for k in range(12):
            got_heavy.append(_forces(heavy.step(k, k * DT, *heavy_states[k])))
            got_light.append(_forces(light.step(k, k * DT, *light_states[k])))
        saved = heavy.request("save")["state"]   # save / restore in the worker as well
        again = heavy.step(12, 12 * DT, *heavy_states[0])
        assert heavy.request("restore", state=saved)["seq"] == 11
        assert np.array_equal(_forces(heavy.step(12, 12 * DT, *heavy_states[0])), _forces(again))
        heavy.bye()
    process.join(10)
    assert process.exitcode is not None   # reaped at bye
    for got, want in ((got_heavy, _alone(HEAVY, hdbs, heavy_states)), (got_light, _alone(LIGHT, hdbs, light_states))):
        for a, b in zip(got, want):
            assert np.array_equal(a, b)


@pytest.mark.parametrize("how", ["killed", "hung"])
def test_a_worker_that_dies_or_hangs_ends_its_session_with_error_16(served, hdbs, how):
    """SIGKILL: the worker is gone; SIGSTOP: it never answers and passes its time budget. Either
    way its step gets error 16 naming why, its next request error 7, the worker is reaped, and a
    new hello is served and steps."""
    srv = served(isolate_step_s=0.0, step_timeout=2.0)
    with ServerConnection(srv.address, timeout=WAIT) as conn:
        conn.hello(LIGHT, hdbs)
        process = _worker_of(srv, conn.session)
        x, v = _states(1, 1, seed=3)[0]
        conn.step(0, 0.0, x, v)
        os.kill(process.pid, signal.SIGKILL if how == "killed" else signal.SIGSTOP)
        with pytest.raises(RemoteError) as failed:
            conn.step(1, DT, x, v)
        assert failed.value.code == 16 and failed.value.name == "session_failed"
        assert ("died" if how == "killed" else "longer than 2 s") in failed.value.message
        with pytest.raises(RemoteError) as gone:
            conn.step(2, 2 * DT, x, v)
        assert gone.value.code == 7 and "ended" in gone.value.message
    process.join(10)
    assert process.exitcode == -signal.SIGKILL   # reaped (a stopped one killed first)
    with ServerConnection(srv.address, timeout=WAIT) as again:
        again.hello(LIGHT, hdbs)
        assert again.step(0, 0.0, x, v)["seq"] == 0
        again.bye()
    assert srv._worker_slots._held == 0


def test_workers_are_reaped_when_the_server_stops(hdbs):
    srv, thread = serve_in_thread(session_timeout=600.0, isolate_step_s=0.0)
    conn = ServerConnection(srv.address, timeout=WAIT)
    conn.hello(LIGHT, hdbs)
    process = _worker_of(srv, conn.session)
    srv.stop()
    thread.join(30)
    conn.close()
    assert not thread.is_alive() and process.exitcode is not None


def test_heavy_hellos_beyond_max_workers_are_refused_busy(served, hdbs):
    srv = served(isolate_step_s=0.0, max_workers=1)
    with ServerConnection(srv.address, timeout=WAIT) as one, ServerConnection(srv.address, timeout=WAIT) as two:
        one.hello(LIGHT, hdbs)
        with pytest.raises(RemoteError) as busy:
            two.hello(LIGHT, hdbs)
        assert (busy.value.code, busy.value.extra.get("limit"), busy.value.extra.get("maximum")) == (14, "workers", 1)
        one.bye()
        two.hello(LIGHT, hdbs)   # the worker given back at bye
        two.bye()


@pytest.mark.parametrize("isolate", [math.inf, 0.0])
def test_the_wave_preview_is_not_computed_when_no_controller_joined(served, hdbs, isolate):
    """A session declaring a controller with a wave preview, stepped for several control periods
    with no controller: the decisions are 'absent' and no probe of the sea was ever made (on the
    loop, or in the worker: its steps carry no probes)."""
    srv = served(isolate_step_s=isolate)
    with ServerConnection(srv.address, timeout=WAIT) as conn:
        conn.hello(CONTROLLED, hdbs)
        hub = srv._hubs[conn.session]
        x = np.zeros((1, 6))
        decisions = []
        for k in range(9):
            meas = {"step": k - 1, "pto_displacement": np.zeros(1), "pto_velocity": np.zeros(1),
                    "pto_force": np.zeros(1), "body_position": x, "body_velocity": x}
            reply = conn.step(k, k * DT, x, x, measurements=meas if k and (k - 1) % 2 == 0 else None)
            decisions += [reply["control"]["ctl"]["status"]] if "control" in reply else []
        assert len(decisions) >= 3 and set(decisions) == {"absent"}
        assert hub.slots["ctl"].sample is not None and "wave_preview" not in hub.slots["ctl"].sample
        s = srv.sessions[conn.session]
        if isolate == math.inf:
            assert s._probes == {}
        assert hub.previews_due({"step": 2}) == {}


def test_the_sliding_preview_equals_the_closed_form_elevation(hdbs):
    """WaveProbes.at_step (a window computed a column or two per control step, by phasor rotation)
    against WaveProbes.__call__ (every time from exp(-i w t)), over a run whose control period (4
    steps) is not a multiple of the preview step (3 steps), through the ramp, and after a jump back."""
    scene = parse_scene(_scene(1, irregular_waves(2.0, 8.0, components=400, seed=5, ramp=2.0)))
    model = HydroModel(scene, {"b0": hdbs["float.nc"]})
    grid = PreviewGrid(((0.0, 0.0), (25.0, -5.0)), DT, 3, 40)
    probes = WaveProbes.on_grid(model.waves, grid, 9.81, scene.water.depth_m)
    exact = WaveProbes(model.waves, np.array(grid.points), grid.offsets[1:], 9.81, scene.water.depth_m)
    scale = np.abs(model.waves.amplitude).sum()
    for k in [*range(0, 400, 4), 12, 16]:
        np.testing.assert_allclose(probes.at_step(k), exact(k * DT), rtol=0, atol=1e-12 * scale)
    distinct = {k + 3 * j for k in range(0, 400, 4) for j in range(41)}
    assert probes.computed == len(distinct) + 2 * 41   # each column once along the run; the jump back afresh
