"""The in-process client's step path (server/service/local_step.py): the replies and errors of a
``step`` message, bit for bit, without the message."""

from __future__ import annotations

import numpy as np
import pytest
from analytic_hdb import make_body_hdb

from conftest import body, regular_waves, scene_toml

from hydrolink.clients.lockstep.connection import ServerConnection
from hydrolink.protocol.codec import ProtocolError
from hydrolink.server.service.force_server import ForceServer

DT = 0.05
SCENE = scene_toml(dt=DT, duration=2.0, waves=regular_waves(1.0, 6.0), hydro={"irf_duration": 4.0},
                   bodies=[body("float", hdb="float.nc", mass=3.0e5, center_of_mass=[0.0, 0.0, -1.0],
                                inertia=[1.0e7, 1.0e7, 2.0e7])])
FORCES = ("excitation", "radiation", "hydrostatic")


@pytest.fixture(scope="module")
def hdb():
    return make_body_hdb()


def _states(n: int) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(3)
    return [(0.1 * rng.standard_normal((1, 6)), 0.5 * rng.standard_normal((1, 6))) for _ in range(n)]


def test_local_step_answers_as_a_step_message(hdb):
    """Two sessions of one scene, one stepped by messages (ServerConnection.step), one through its
    LocalStep, with the same states — new steps and a replacing iteration — get the same reply
    fields bit for bit (compute_us aside), the arrays read-only as a message's."""
    srv = ForceServer(None)
    with ServerConnection(srv) as by_msg, ServerConnection(srv) as by_port:
        by_msg.hello(SCENE, {"float.nc": hdb})
        by_port.hello(SCENE, {"float.nc": hdb})
        port = by_port.local_step()
        assert port is not None and by_msg.local_step() is not None
        plan = [(seq, 0) for seq in range(12)] + [(11, 1), (11, 2), (12, 0)]
        for (seq, it), (p, v) in zip(plan, _states(len(plan))):
            want = by_msg.step(seq, seq * DT, p, v, it)
            port.position[...], port.velocity[...] = p, v
            got = port(seq, it)
            assert set(want) - set(got) == {"v", "type", "msg_id", "session", "parent"}
            for k in got:
                if k in FORCES:
                    assert not got[k].flags.writeable and got[k].tobytes() == want[k].tobytes(), (seq, it, k)
                elif k != "compute_us":
                    assert got[k] == want[k], (seq, it, k)
        assert srv.sessions[by_port.session].steps == srv.sessions[by_msg.session].steps == len(plan)


@pytest.mark.parametrize("bad", ["nan-position", "far-position", "fast-velocity", "past-end", "out-of-order"])
def test_local_step_refuses_as_a_step_message(hdb, bad):
    """A state out of the wire's bounds, a seq past the run's end or out of order: the ProtocolError
    (code, field, message) the same ``step`` message gets; the session unchanged (seq 0 then
    steps)."""
    srv = ForceServer(None)
    with ServerConnection(srv) as c:
        c.hello(SCENE, {"float.nc": hdb})
        port = c.local_step()
        p, v = np.zeros((1, 6)), np.zeros((1, 6))
        seq = {"past-end": 41, "out-of-order": 3}.get(bad, 0)
        if bad == "nan-position":
            p[0, 2] = np.nan
        elif bad == "far-position":
            p[0, 0] = 2e5
        elif bad == "fast-velocity":
            v[0, 5] = -2e4
        msg = srv.step_map(c.session, "t-1", {"seq": seq, "time": seq * DT, "iteration": 0, "position": p,
                                              "velocity": v})
        assert msg["type"] == "error"
        port.position[...], port.velocity[...] = p, v
        with pytest.raises(ProtocolError) as err:
            port(seq, 0)
        assert (err.value.code, err.value.field, err.value.message) == (msg["code"], msg["field"], msg["message"])
        port.position[...], port.velocity[...] = 0.0, 0.0
        assert port(0, 0)["seq"] == 0


def test_local_step_only_for_the_socketless_servers_unpaced_session(hdb):
    """A paced session (hello.realtime) takes the message path: no LocalStep."""
    srv = ForceServer(None)
    with ServerConnection(srv) as c:
        c.hello(SCENE, {"float.nc": hdb}, realtime=1.0)
        assert c.local_step() is None


def test_compiled_kernel_steps_as_a_step_message(hdb):
    """LocalStep.compiled's kernel, called as the compiled exchange calls it (absolute state, no
    outside excitation, then ``advanced``), gives a message's forces bit for bit; the session counts
    the steps; a retry of such a step is refused (nothing kept to compare it with), a replacing
    iteration by message is answered as the other session answers it."""
    from hydrolink.clients.lockstep.connection import RemoteError
    from hydrolink.protocol.codec import Code
    from hydrolink.server.fused import kernel_numba

    srv = ForceServer(None)
    with ServerConnection(srv) as by_msg, ServerConnection(srv) as by_kernel:
        by_msg.hello(SCENE, {"float.nc": hdb})
        by_kernel.hello(SCENE, {"float.nc": hdb})
        port = by_kernel.local_step()
        compiled = port.compiled()
        assert compiled is not None and compiled.dt == DT and compiled.last_seq == 40
        out, f_ext = np.zeros((3, 6)), np.zeros(6)
        states = _states(9)
        for seq, (p, v) in enumerate(states[:8]):
            want = by_msg.step(seq, seq * DT, p, v, 0)
            eta = kernel_numba.step(compiled.kernel, seq * DT, p.reshape(-1), v.reshape(-1), False, f_ext, 0.0, out)
            port.advanced(seq, 1e-6)
            assert eta == want["wave_elevation"]
            for row, k in enumerate(FORCES):
                assert out[row].tobytes() == want[k].reshape(-1).tobytes(), (seq, k)
        session = srv.sessions[by_kernel.session]
        assert (session.steps, session.last_seq, session.last_iteration) == (8, 7, 0)
        p, v = states[7]
        with pytest.raises(RemoteError) as err:
            by_kernel.step(7, 7 * DT, p, v, 0)
        assert (err.value.code, err.value.field) == (Code.OUT_OF_ORDER, "iteration")
        p, v = states[8]
        want, got = by_msg.step(7, 7 * DT, p, v, 1), by_kernel.step(7, 7 * DT, p, v, 1)
        for k in FORCES:
            assert got[k].tobytes() == want[k].tobytes(), k
