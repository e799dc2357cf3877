"""The polled server's own run's step path for a session with controllers
(server/service/controlled_step.py): the replies, relayed measurements and errors of a ``step``
message, bit for bit, without the message. The whole run against a separate server, variable by
variable, with a controller process: tests/test_controllers.py
``test_run_polls_its_own_server_and_equals_a_separate_one``."""

from __future__ import annotations

import numpy as np
import pytest
from analytic_hdb import make_body_hdb

from conftest import body, linear_pto, regular_waves, scene_toml

from hydrolink.clients.lockstep.connection import RemoteError, ServerConnection
from hydrolink.protocol.codec import ProtocolError
from hydrolink.server.service.force_server import ForceServer

DT = 0.05
# a controller every second step that never joins (absent after its 10 ms join timeout): every
# control step still carries the measurements of the step before, relayed to its slot
SCENE = scene_toml(dt=DT, duration=2.0, waves=regular_waves(1.0, 6.0), hydro={"irf_duration": 4.0},
                   bodies=[body("float", hdb="float.nc", mass=3.0e5, center_of_mass=[0.0, 0.0, -1.0],
                                inertia=[1.0e7, 1.0e7, 2.0e7])],
                   ptos=[linear_pto("pto", "float", [0, 0, -1], "ground", [0, 0, -20], damping=1e5)],
                   controllers=[{"name": "ctl", "ptos": ["pto"], "period": 2 * DT, "timeout": 0.01,
                                 "join_timeout": 0.01, "measurements": ["pto_velocity", "body_position"]}])
ENVELOPE = {"v", "type", "msg_id", "session", "parent"}


@pytest.fixture(scope="module")
def hdb():
    return make_body_hdb()


def _measured(k: int, rng: np.random.Generator) -> dict:
    """What the Exudyn client's measurements map holds at step k (clients/exudyn/pto_control.py)."""
    return {"step": k, "pto_displacement": rng.standard_normal(1), "pto_velocity": rng.standard_normal(1),
            "pto_force": 1e4 * rng.standard_normal(1), "body_position": 0.1 * rng.standard_normal((1, 6)),
            "body_velocity": rng.standard_normal((1, 6))}


def _open(hdb) -> tuple[ForceServer, ServerConnection]:
    srv = ForceServer("tcp://127.0.0.1:*", polled=True)
    conn = ServerConnection(srv)
    conn.hello(SCENE, {"float.nc": hdb})
    return srv, conn


def _close(*pairs) -> None:
    for srv, conn in pairs:
        conn.close()
        srv.close()


def test_controlled_step_answers_and_relays_as_a_step_message(hdb):
    """Two polled servers, one stepped by ``step`` messages with their measurements
    (ServerConnection.step), one through its ControlledStep, with the same states and
    measurements — new steps and replacing iterations — give the same reply fields bit for bit
    (compute_us aside; the absent controller's decisions included) and relay the same samples
    to the controller's slot."""
    (srv_m, by_msg), (srv_p, by_port) = pairs = _open(hdb), _open(hdb)
    try:
        port = by_port.controlled_step()
        assert port is not None and by_port.local_step() is None
        rng = np.random.default_rng(5)
        plan = [(seq, 0) for seq in range(9)] + [(8, 1), (8, 2), (9, 0), (10, 0)]
        relayed, decided = 0, set()
        for seq, it in plan:
            p, v = 0.1 * rng.standard_normal((1, 6)), 0.5 * rng.standard_normal((1, 6))
            meas = _measured(seq - 1, rng) if it == 0 and seq >= 1 and (seq - 1) % 2 == 0 else None
            want = by_msg.step(seq, seq * DT, p, v, it, measurements=meas)
            port.position[...], port.velocity[...] = p, v
            got = port(seq, it, meas)
            assert set(want) - set(got) <= ENVELOPE and set(got) - set(want) <= ENVELOPE
            for k in set(got) - ENVELOPE - {"compute_us"}:
                if isinstance(got[k], np.ndarray):
                    assert got[k].tobytes() == want[k].tobytes(), (seq, it, k)
                else:
                    assert got[k] == want[k], (seq, it, k)
            decided |= {d["status"] for d in got.get("control", {}).values()}
            slot_m, slot_p = (s._hubs[c.session].slots["ctl"] for s, c in pairs)
            assert slot_p.newest == slot_m.newest
            if meas is not None:
                relayed += 1
                assert slot_p.sample.keys() == slot_m.sample.keys()
                for k, a in slot_m.sample.items():
                    assert np.array_equal(slot_p.sample[k], a), (seq, k)
                assert np.array_equal(slot_p.sample["body_position"], meas["body_position"])
        assert relayed == 5 and decided == {"absent"}
        assert srv_p.sessions[by_port.session].steps == srv_m.sessions[by_msg.session].steps == len(plan)
    finally:
        _close(*pairs)


def _broken(bad: str, rng: np.random.Generator) -> dict | None:
    meas = _measured(2, rng)
    if bad == "missing":
        return None
    if bad == "wrong-step":
        meas["step"] = 3
    elif bad == "shape":
        meas["pto_force"] = np.zeros(2)
    elif bad == "nan":
        meas["body_velocity"][0, 4] = np.nan
    elif bad == "inf":
        meas["pto_velocity"][0] = -np.inf
    return meas


@pytest.mark.parametrize("bad", ["missing", "wrong-step", "shape", "nan", "inf", "far-position"])
def test_controlled_step_refuses_as_a_step_message(hdb, bad):
    """Measurements missing at a control step, of another step, of a wrong shape, with NaN or inf,
    or a state out of the wire's bounds: the error (code, field, message) the same ``step``
    message gets; the session unchanged (the step then taken with good values is answered)."""
    (srv_m, by_msg), (srv_p, by_port) = pairs = _open(hdb), _open(hdb)
    try:
        port = by_port.controlled_step()
        p, v = np.zeros((1, 6)), np.zeros((1, 6))
        for seq in range(3):
            meas = _measured(seq - 1, np.random.default_rng(seq)) if seq == 1 else None
            by_msg.step(seq, seq * DT, p, v, measurements=meas)
            port(seq, 0, meas)
        bad_p = p.copy()
        if bad == "far-position":
            bad_p[0, 2] = 1e9
        meas = _broken(bad, np.random.default_rng(9))
        with pytest.raises(RemoteError) as by_message:
            by_msg.step(3, 3 * DT, bad_p, v, measurements=meas)
        port.position[...], port.velocity[...] = bad_p, v
        with pytest.raises(ProtocolError) as by_path:
            port(3, 0, meas)
        e, g = by_message.value, by_path.value
        assert (g.code, g.field, g.message) == (e.code, e.field, e.message)
        s = srv_p.sessions[by_port.session]
        assert (s.last_seq, s.steps) == (2, 3)
        port.position[...] = p
        good = _measured(2, np.random.default_rng(9))
        assert port(3, 0, good)["seq"] == 3 and s.last_seq == 3
    finally:
        _close(*pairs)


def test_compiled_kernel_between_relayed_and_decided_steps_as_a_step_message(hdb):
    """A run that takes the model's compiled kernel itself (clients/exudyn/compiled_exchange.py):
    ``relayed``, the kernel (server/fused/kernel_numba.py ``step``, as the compiled exchange calls
    it), then ``decided``, step by step, give a ``step`` message's forces and elevation bit for
    bit, its decisions, the same relayed samples and the session's counters; measurements a
    message would have refused raise its error from ``relayed``, before the model steps."""
    from hydrolink.server.fused import kernel_numba

    (srv_m, by_msg), (srv_p, by_port) = pairs = _open(hdb), _open(hdb)
    try:
        port = by_port.controlled_step()
        compiled = port.compiled()
        assert compiled is not None and compiled.last_seq == 40
        session = srv_p.sessions[by_port.session]
        rng = np.random.default_rng(7)
        out, f_ext = np.zeros((3, 6)), np.zeros(6)
        for seq in range(9):
            p, v = 0.1 * rng.standard_normal((1, 6)), 0.5 * rng.standard_normal((1, 6))
            meas = _measured(seq - 1, rng) if seq >= 1 and (seq - 1) % 2 == 0 else None
            want = by_msg.step(seq, seq * DT, p, v, measurements=meas)
            port.relayed(seq, meas)
            assert session.last_seq == seq - 1                  # relayed before the model steps
            eta = kernel_numba.step(compiled.kernel, seq * DT, p.reshape(-1), v.reshape(-1), False, f_ext, 0.0, out)
            got = port.decided(seq, 1e-6)
            assert eta == want["wave_elevation"] and got.get("control") == want.get("control"), seq
            for row, k in enumerate(("excitation", "radiation", "hydrostatic")):
                assert out[row].tobytes() == want[k].reshape(-1).tobytes(), (seq, k)
            slot_m, slot_p = (s._hubs[c.session].slots["ctl"] for s, c in pairs)
            assert slot_p.newest == slot_m.newest == (seq - 1 if meas is not None else slot_m.newest)
            if meas is not None:
                assert slot_p.sample.keys() == slot_m.sample.keys()
                for k, a in slot_m.sample.items():
                    assert np.array_equal(slot_p.sample[k], a), (seq, k)
        assert (session.last_seq, session.steps) == (8, srv_m.sessions[by_msg.session].steps)
        bad = _broken("nan", np.random.default_rng(9))
        bad["step"] = 8
        with pytest.raises(RemoteError) as by_message:
            by_msg.step(9, 9 * DT, np.zeros((1, 6)), np.zeros((1, 6)), measurements=bad)
        with pytest.raises(ProtocolError) as by_path:
            port.relayed(9, bad)
        e, g = by_message.value, by_path.value
        assert (g.code, g.field, g.message) == (e.code, e.field, e.message) and session.last_seq == 8
    finally:
        _close(*pairs)
