"""A real ForceServer on a free loopback port with a real HydroModel and an analytic HDB."""

from __future__ import annotations

import time
from pathlib import Path

import msgpack
import numpy as np
import pytest
import zmq
from analytic_hdb import make_body_hdb

from conftest import EXIT_S, IDLE_S, REPLY_S, rm3_short_text
from conftest import SPHERE_WATER, body, dealer, linear_pto, regular_waves, scene_toml, serve_process, stopped

from hydrolink.clients.lockstep.connection import RemoteError, ServerConnection
from hydrolink.protocol import codec
from hydrolink.protocol.hdb.wire import to_wire
from hydrolink.server.service.force_server import serve_in_thread

REPO = Path(__file__).resolve().parents[1]
DT = 0.05


def float_scene(*, name: str = "float", hdb: str = "float.nc", mass: float = 3.0e5, water: dict | None = None,
                dt: float = DT, duration: float = 10.0, irf_duration: float = 4.0, **body_keys) -> str:
    """The analytic float in regular waves; ``body_keys`` add to the body's keys."""
    return scene_toml(dt=dt, duration=duration, water=water, waves=regular_waves(1.0, 6.0),
                      hydro={"irf_duration": irf_duration},
                      bodies=[body(name, hdb=hdb, mass=mass, center_of_mass=[0.0, 0.0, -1.0],
                                   inertia=[1.0e7, 1.0e7, 2.0e7], **body_keys)])


SCENE = float_scene()
RECV_MS = 5000


@pytest.fixture(scope="module")
def hdb():
    return make_body_hdb()


@pytest.fixture(scope="module")
def server():
    srv, thread = serve_in_thread(session_timeout=IDLE_S)
    yield srv
    srv.stop()
    thread.join(timeout=5)
    assert not thread.is_alive()


@pytest.fixture
def conn(server, hdb):
    with ServerConnection(server.address, timeout=REPLY_S) as c:
        c.hello(SCENE, {"float.nc": hdb})
        yield c


def states(n: int, seed: int = 0) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    return [(0.1 * rng.standard_normal((1, 6)), 0.5 * rng.standard_normal((1, 6))) for _ in range(n)]


def raw(address: str, frame: bytes, socket_type: int = zmq.DEALER) -> dict:
    """Send one raw frame and return the decoded reply (bounded wait)."""
    ctx = zmq.Context.instance()
    sock = ctx.socket(socket_type)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVTIMEO, RECV_MS)
    try:
        sock.connect(address)
        sock.send(frame)
        return codec.unpack(sock.recv())
    finally:
        sock.close(0)


def request(address: str, **fields) -> dict:
    return raw(address, codec.pack({"v": 1, "msg_id": "t-1", **fields}))


def expect_error(call, code: int, field: str | None = None) -> RemoteError:
    with pytest.raises(RemoteError) as err:
        call()
    assert err.value.code == code, err.value
    if field is not None:
        assert err.value.field == field, err.value
    return err.value


# ------------------------------------------------------------------ envelope-level errors

def test_malformed_bytes_and_not_a_map(server):
    for frame in (b"\x00\xc1 not msgpack", msgpack.packb([1, 2])):
        reply = raw(server.address, frame)
        assert (reply["type"], reply["code"], reply["name"], reply["parent"]) == ("error", 1, "malformed", None)


@pytest.mark.parametrize("fields, code, field", [
    ({"type": "ping", "v": 7}, 2, "v"),
    ({"type": "fly"}, 3, "type"),
    ({"type": "step", "session": None}, 4, "session"),
    ({"type": "hello", "role": "multibody", "hdbs": {}}, 4, "scene"),
    ({"type": "hello", "role": "monitor", "scene": "", "hdbs": {}}, 12, "role"),
    ({"type": "step", "session": "0" * 32}, 7, "session"),
])
def test_envelope_errors_name_the_field(server, fields, code, field):
    reply = request(server.address, **fields)
    assert (reply["type"], reply["code"], reply["field"], reply["parent"]) == ("error", code, field, "t-1")
    assert reply["name"] == codec.code_name(code) and reply["message"]


def test_ping_and_req_socket(server):
    reply = raw(server.address, codec.pack(codec.message("ping", 5, None)), zmq.REQ)
    assert reply["type"] == "pong" and reply["parent"] == 5 and reply["sessions"] >= 0


def test_size_limit_covers_every_frame_and_nothing_is_echoed():
    """SPEC §1: the size limit counts all frames of a message, routing frames included, and the
    routing frames are at most 8 of at most 255 bytes. A message over a limit is answered with
    error 1 to the sender's identity alone (its own frames are not echoed) and the server goes on."""
    srv, thread = serve_in_thread(session_timeout=IDLE_S, max_message_bytes=2**20)
    ctx = zmq.Context.instance()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVTIMEO, RECV_MS)
    try:
        sock.connect(srv.address)
        ping = codec.pack(codec.message("ping", 1, None))
        cases = [([b"r" * 600_000, b"s" * 600_000, ping], "over all its frames; at most 1048576"),
                 ([b"x" * 300, ping], "routing frame 1 is 300 bytes; at most 255"),
                 ([b""] * 8 + [ping], "9 routing frames before the message; at most 8")]
        for frames, why in cases:
            sock.send_multipart(frames)
            reply = sock.recv_multipart()
            assert len(reply) == 1, [len(f) for f in reply]          # nothing the sender added comes back
            msg = codec.unpack(reply[0])
            assert (msg["type"], msg["code"], msg["field"]) == ("error", 1, None) and why in msg["message"], msg
        sock.send_multipart([b"", ping])                            # a REQ-like delimiter is fine
        assert codec.unpack(sock.recv_multipart()[-1])["type"] == "pong"
    finally:
        sock.close(0)
        srv.stop()
        thread.join(timeout=5)


# ------------------------------------------------------------------ hello errors

def test_bad_scene_names_the_key(server, hdb):
    with ServerConnection(server.address, timeout=REPLY_S) as c:
        err = expect_error(lambda: c.hello(float_scene(mass=-1.0), {"float.nc": hdb}),
                           8, "scene.bodies[0].mass")
        assert err.name == "bad_scene"
        expect_error(lambda: c.hello("[simulation\n", {"float.nc": hdb}), 8, "scene")
        expect_error(lambda: c.hello(float_scene(hdb_body="buoy"),
                                     {"float.nc": hdb}), 8, "scene.bodies[0].hdb_body")
        assert c.session is None


@pytest.mark.parametrize("old,new,field", [
    ("duration = 10.0", "duration = 1e300", "scene.simulation.duration"),   # killed the server (issue 22)
    ("dt = 0.05", "dt = 1e-300", "scene.simulation.dt"),
    ("period = 6.0", "period = 1e300", "scene.waves.period"),
    ("irf_duration = 4.0", "irf_duration = 1e300", "scene.hydro.irf_duration"),
    ("[waves]", "[water]\ngravity = 1e-308\n[waves]", "scene.water.gravity"),
])
def test_extreme_scene_values_are_named_and_the_served_server_serves_on(server, hdb, old, new, field):
    """Over the socket, as `hydrolink serve` answers: each was error 99 or ended the server."""
    assert old in SCENE
    with ServerConnection(server.address, timeout=REPLY_S) as c:
        expect_error(lambda: c.hello(SCENE.replace(old, new), {"float.nc": hdb}), 8, field)
        c.hello(SCENE, {"float.nc": hdb})
        pos, vel = states(1)[0]
        assert c.step(0, 0.0, pos, vel)["seq"] == 0


def test_bad_hdb_names_the_field(server, hdb):
    with ServerConnection(server.address, timeout=REPLY_S) as c:
        wire = to_wire(hdb)
        wire["omega"] = wire["omega"].copy()
        wire["omega"][3] = np.nan
        err = expect_error(lambda: c.request("hello", role="multibody", scene=SCENE, hdbs={"float.nc": wire}),
                           9, 'hdbs["float.nc"].omega')
        assert err.name == "bad_hdb" and "float.nc" in err.message
        del wire["added_mass"]
        expect_error(lambda: c.request("hello", role="multibody", scene=SCENE, hdbs={"float.nc": wire}),
                     9, 'hdbs["float.nc"].added_mass')
        expect_error(lambda: c.hello(SCENE, {"other.nc": hdb}), 9, 'hdbs["float.nc"]')


# ------------------------------------------------------------------ steps

def test_welcome_carries_setup(server, hdb):
    with ServerConnection(server.address, timeout=REPLY_S) as c:
        setup = c.hello(SCENE, {"float.nc": hdb})
        session = c.session
        assert c.protocol == 1 and len(session) == 32 and setup.bodies == ("float",)
        assert setup.active.shape == (1, 6) and setup.active.dtype == bool
        assert setup.added_mass_inf.shape == (6, 6) and setup.dt == DT
        assert setup.equilibrium_position.shape == (1, 6)
        f = c.step(0, 0.0, *states(1)[0])
        assert {"excitation", "radiation", "hydrostatic"} <= set(f) and f["excitation"].shape == (1, 6)
        assert f["compute_us"] > 0 and np.isfinite(f["wave_elevation"])
        bye = c.bye()
        assert bye["steps"] == 1 and bye["compute_s"] > 0 and c.session is None
        reply = request(server.address, type="bye", session=session)
        assert reply["code"] == 7 and "closed by bye" in reply["message"]


def test_bad_steps_leave_the_session_usable(conn):
    (p0, v0), (p1, v1) = states(2)
    conn.step(0, 0.0, p0, v0)
    bad = p1.copy()
    bad[0, 2] = np.nan
    expect_error(lambda: conn.step(1, DT, bad, v1), 5, "position")
    expect_error(lambda: conn.step(1, DT, p1, np.zeros((2, 6))), 5, "velocity")
    expect_error(lambda: conn.step(1, DT, p1, v1.tolist()[0]), 5, "velocity")
    expect_error(lambda: conn.request("step", seq=1, time=DT, velocity=v1), 4, "position")
    expect_error(lambda: conn.step(1, DT * 1.001, p1, v1), 5, "time")
    expect_error(lambda: conn.step(3, 3 * DT, p1, v1), 6, "seq")
    expect_error(lambda: conn.step(-1, -DT, p1, v1), 5, "seq")
    f = conn.step(1, DT, p1, v1.tolist())  # nested lists are fine too
    assert f["seq"] == 1 and np.all(np.isfinite(f["radiation"]))


def test_duplicate_seq_resends_the_cached_reply(conn):
    (p0, v0), (p1, v1) = states(2)
    conn.step(0, 0.0, p0, v0)
    first = conn.step(1, DT, p1, v1)
    again = conn.step(1, DT, p1, v1)
    assert again["compute_us"] == 0.0
    for k in ("excitation", "radiation", "hydrostatic"):
        np.testing.assert_array_equal(first[k], again[k])
    assert (again["seq"], again["iteration"], again["time"], again["wave_elevation"]) == \
        (first["seq"], first["iteration"], first["time"], first["wave_elevation"])
    expect_error(lambda: conn.step(1, DT, p1 + 0.01, v1), 6, "iteration")
    expect_error(lambda: conn.step(0, 0.0, p0, v0), 6, "seq")


def run(conn: ServerConnection, seq_states, replace_at: int | None = None, replacement=None) -> list[dict]:
    out = []
    for k, (p, v) in enumerate(seq_states):
        out.append(conn.step(k, k * DT, p, v))
        if k == replace_at:
            out[-1] = conn.step(k, k * DT, *replacement, iteration=1)
    return out


def test_iteration_replaces_the_newest_sample(server, hdb, conn):
    seq_states = states(8, seed=1)
    new_state = (seq_states[5][0] + 0.2, seq_states[5][1] - 0.3)
    replaced = run(conn, seq_states, replace_at=5, replacement=new_state)
    with ServerConnection(server.address, timeout=REPLY_S) as ref_conn:
        ref_conn.hello(SCENE, {"float.nc": hdb})
        reference = run(ref_conn, seq_states[:5] + [new_state] + seq_states[6:])
    assert replaced[5]["iteration"] == 1
    for a, b in zip(replaced, reference):
        for k in ("excitation", "radiation", "hydrostatic"):
            np.testing.assert_allclose(a[k], b[k], rtol=1e-12, atol=1e-9)
    assert np.any(reference[7]["radiation"] != 0)
    expect_error(lambda: conn.step(5, 5 * DT, *new_state, iteration=2), 6, "seq")  # only the newest
    conn.step(7, 7 * DT, *new_state, iteration=3)
    expect_error(lambda: conn.step(7, 7 * DT, *seq_states[7], iteration=2), 6, "iteration")


def test_concurrent_sessions_do_not_interfere(server, hdb):
    a_states, b_states = states(30, seed=2), states(30, seed=3)
    with ServerConnection(server.address, timeout=REPLY_S) as a, ServerConnection(server.address, timeout=REPLY_S) as b:
        a.hello(SCENE, {"float.nc": hdb})
        b.hello(SCENE, {"float.nc": hdb})
        interleaved_a, interleaved_b = [], []
        for k in range(30):
            interleaved_a.append(a.step(k, k * DT, *a_states[k]))
            interleaved_b.append(b.step(k, k * DT, *b_states[k]))
    for seq_states, interleaved in ((a_states, interleaved_a), (b_states, interleaved_b)):
        with ServerConnection(server.address, timeout=REPLY_S) as alone:
            alone.hello(SCENE, {"float.nc": hdb})
            separate = run(alone, seq_states)
        for x, y in zip(interleaved, separate):
            for k in ("excitation", "radiation", "hydrostatic"):
                np.testing.assert_array_equal(x[k], y[k])


@pytest.mark.timing
def test_vanished_client_expires_while_others_keep_running(hdb):
    srv, thread = serve_in_thread(session_timeout=0.4)
    try:
        ghost = ServerConnection(srv.address, timeout=REPLY_S)
        ghost.hello(SCENE, {"float.nc": hdb})
        ghost.step(0, 0.0, *states(1)[0])
        ghost_id = ghost.session
        ghost.close()  # vanishes without bye
        with ServerConnection(srv.address, timeout=REPLY_S) as live:
            live.hello(SCENE, {"float.nc": hdb})
            t0, k = time.monotonic(), 0
            while time.monotonic() - t0 < 1.2:  # keeps stepping while the ghost expires
                live.step(k, k * DT, *states(1, seed=k)[0])
                k += 1
                time.sleep(0.01)
            assert ghost_id not in srv.sessions and live.session in srv.sessions
            reply = request(srv.address, type="step", session=ghost_id, seq=1, time=DT)
            assert reply["code"] == 7 and "expired" in reply["message"]
    finally:
        srv.stop()
        thread.join(timeout=5)


def test_signed_server_rejects_unsigned_and_wrong_key(hdb):
    key = b"0123456789abcdef0123456789abcdef"
    srv, thread = serve_in_thread(key=key)
    try:
        with ServerConnection(srv.address, timeout=REPLY_S) as plain:
            expect_error(plain.ping, 11, "sig")  # the error reply is signed; a keyless client still reads it
        with ServerConnection(srv.address, timeout=REPLY_S, key=b"wrong") as wrong:
            with pytest.raises(ConnectionError, match="signature"):
                wrong.ping()  # the server's reply fails *our* check too
        with ServerConnection(srv.address, timeout=REPLY_S, key=key) as good:
            good.hello(SCENE, {"float.nc": hdb})
            assert good.step(0, 0.0, *states(1)[0])["seq"] == 0
    finally:
        srv.stop()
        thread.join(timeout=5)


@pytest.mark.timing
def test_receive_times_out_naming_the_address():
    ctx = zmq.Context.instance()
    with ctx.socket(zmq.ROUTER) as silent:  # accepts connections, never answers
        silent.setsockopt(zmq.LINGER, 0)
        port = silent.bind_to_random_port("tcp://127.0.0.1")
        address = f"tcp://127.0.0.1:{port}"
        with ServerConnection(address, timeout=0.2) as c:
            t0 = time.monotonic()
            with pytest.raises(TimeoutError, match=address):
                c.ping()
            assert time.monotonic() - t0 < 2.0


def test_close_without_serving_is_idempotent():
    from hydrolink.server.service.force_server import ForceServer
    srv = ForceServer("tcp://127.0.0.1:*")
    assert srv.address.startswith("tcp://127.0.0.1:") and not srv.address.endswith("*")
    srv.close()
    srv.close()


def test_real_hdb_file_over_the_wire(server, reference_data):
    """The shared WEC-Sim sphere (BEMIO .h5) travels in hello; heave hydrostatics come back."""
    from hydrolink.server.hdb.io import load_hdb
    ds = load_hdb(reference_data / "sphere_task10" / "sphere.h5")
    scene = float_scene(name="sphere", hdb="sphere.h5", water=SPHERE_WATER)
    with ServerConnection(server.address, timeout=REPLY_S) as c:
        setup = c.hello(scene, {"sphere.h5": ds})
        assert setup.bodies == ("sphere",) and setup.added_mass_inf[2, 2] > 0
        eq = setup.equilibrium_position
        dz = np.zeros((1, 6))
        dz[0, 2] = 0.1
        f = c.step(0, 0.0, eq + dz, np.zeros((1, 6)))
        k33 = setup.hydrostatic_stiffness[2, 2]
        assert k33 > 0 and f["hydrostatic"][0, 2] == pytest.approx(-0.1 * k33, rel=1e-9)


# ------------------------------------------------------------------ in-process maps = frames

RM3_COMPARED = ("time", "position", "velocity", "excitation_force", "radiation_force", "hydrostatic_force",
                "wave_elevation", "pto_force", "pto_velocity", "pto_power", "total_pto_power")


@pytest.mark.parametrize("scheme", ["mass-matrix", "implicit"])
def test_embedded_run_equals_socket_run_bit_for_bit(reference_data, tmp_path, scheme):
    """RM3 (two bodies, PTO) run embedded — step requests handed to the in-process server as maps,
    no msgpack — and over loopback TCP (frames): every results value is the same bit for bit
    (the implicit scheme also exercises the iteration/replace requests)."""
    import netCDF4

    from hydrolink.clients.run import run_scene_file

    text = rm3_short_text(reference_data)
    scene = tmp_path / "rm3.toml"
    scene.write_text(text + f'\n[coupling]\nscheme = "{scheme}"\n')
    embedded = run_scene_file(scene, tmp_path / "embedded.nc", progress=False)
    srv, thread = serve_in_thread()
    try:
        remote = run_scene_file(scene, tmp_path / "socket.nc", server=srv.address, progress=False, timeout=REPLY_S)
    finally:
        srv.stop()
        thread.join(5)
    assert embedded.status == remote.status == "complete"
    assert embedded.server == "in-process" and remote.server.startswith("tcp://")
    with netCDF4.Dataset(tmp_path / "embedded.nc") as a, netCDF4.Dataset(tmp_path / "socket.nc") as b:
        assert a.dimensions["time"].size == b.dimensions["time"].size == 201
        for name in RM3_COMPARED:
            x, y = a[name][:].filled(np.nan), b[name][:].filled(np.nan)
            assert x.shape == y.shape and x.tobytes() == y.tobytes(), name
        assert float(np.abs(a["pto_power"][:]).max()) > 1e3   # the device moved


def _step_map(sid: str, **fields) -> dict:
    base = {"seq": 0, "time": 0.0, "iteration": 0, "position": np.zeros((1, 6)), "velocity": np.zeros((1, 6))}
    msg = codec.message("step", "t-1", sid, **base)
    msg.update(fields)   # envelope fields too
    return msg


@pytest.mark.parametrize("fields", [
    {"position": np.full((1, 6), np.nan)}, {"velocity": np.zeros((2, 6))},
    {"position": [["a"] * 6]}, {"position": None}, {"seq": 1.0}, {"seq": -1}, {"time": 0.5}, {"time": "0"},
    {"iteration": True}, {"v": 2}, {"type": "stepp"}, {"msg_id": 1.5}, {"session": 7}])
def test_in_process_map_gets_the_checks_a_frame_gets(hdb, fields):
    """A bad step handed over as a map is refused exactly as the same message as a frame: same
    error code, name, field and message; the session stays usable. A good one gets the same
    values, its arrays read-only (as a frame's)."""
    from hydrolink.server.service.force_server import ForceServer

    srv = ForceServer(None)
    with ServerConnection(srv) as c:
        c.hello(SCENE, {"float.nc": hdb})
        msg = _step_map(c.session, **fields)
        by_map, by_frame = srv.respond_map(msg), codec.unpack(srv.respond(codec.pack(msg)))
        assert by_map["type"] == by_frame["type"] == "error"
        keys = ("code", "name", "field", "message", "parent", "session")
        assert {k: by_map[k] for k in keys} == {k: by_frame[k] for k in keys}
        p, v = states(1)[0]
        good = _step_map(c.session, position=p, velocity=v)
        f_map = srv.respond_map(good)
        f_frame = codec.unpack(srv.respond(codec.pack(dict(good, seq=0, iteration=0))))  # the retry: cached
        for k in ("excitation", "radiation", "hydrostatic"):
            assert not f_map[k].flags.writeable
            assert f_map[k].tobytes() == codec.require_array(f_frame, k, (1, 6)).tobytes()
        assert f_map["wave_elevation"] == f_frame["wave_elevation"]


@pytest.mark.parametrize("fields", [
    {"position": np.full((1, 6), np.nan)}, {"velocity": np.zeros((2, 6))}, {"position": [["a"] * 6]},
    {"position": None}, {"seq": 1.0}, {"seq": -1}, {"time": 0.5}, {"time": "0"}, {"iteration": True}])
def test_in_process_step_path_answers_as_the_map_path(hdb, fields):
    """ForceServer.step_map (ServerConnection.step's path to an in-process server: the envelope is
    the connection's own) refuses a bad step exactly as respond_map does (code, name, field,
    message, parent, session) and answers a good one with the same map: the same keys, envelope
    included, the same values bit for bit; the session stays usable."""
    from hydrolink.server.service.force_server import ForceServer

    srv = ForceServer(None)
    with ServerConnection(srv) as c:
        c.hello(SCENE, {"float.nc": hdb})
        msg = _step_map(c.session, **fields)
        body = {k: msg[k] for k in ("seq", "time", "iteration", "position", "velocity") if k in msg}
        fast, by_map = srv.step_map(c.session, "t-1", body), srv.respond_map(msg)
        assert fast["type"] == by_map["type"] == "error"
        keys = ("code", "name", "field", "message", "parent", "session")
        assert {k: fast[k] for k in keys} == {k: by_map[k] for k in keys}
        p, v = states(1)[0]
        good = _step_map(c.session, position=p, velocity=v)
        fast = srv.step_map(c.session, "t-1", {k: good[k] for k in ("seq", "time", "iteration", "position", "velocity")})
        again = srv.respond_map(good)   # the retry: the cached reply of the same step
        assert list(fast) == list(again) and fast["parent"] == again["parent"] == "t-1"
        for k in ("excitation", "radiation", "hydrostatic"):
            assert fast[k].tobytes() == again[k].tobytes()
        assert (fast["wave_elevation"], fast["seq"], fast["time"]) == (again["wave_elevation"], 0, 0.0)


def test_save_restore_release_over_the_wire(server, hdb, conn):
    """SPEC §5.9 through the socket: a restored session answers the steps after its save as
    before; release forgets; a session with controllers refuses to be rolled back (error 12)."""
    sts = states(30, seed=5)
    for k in range(20):
        conn.step(k, k * DT, *sts[k])
    state = conn.save()
    for k in range(20, 30):
        conn.step(k, k * DT, *states(1, seed=k)[0])
    assert conn.restore(state) == 19
    with pytest.raises(RemoteError) as err:
        conn.step(21, 21 * DT, *sts[21])
    assert err.value.code == 6
    replayed = conn.step(20, 20 * DT, *sts[20])
    with ServerConnection(server.address) as ref:
        ref.hello(SCENE, {"float.nc": hdb})
        for k in range(21):
            expect = ref.step(k, k * DT, *sts[k])
        assert np.array_equal(expect["radiation"], replayed["radiation"])
    conn.release(state)
    with pytest.raises(RemoteError) as err:
        conn.restore(state)
    assert (err.value.code, err.value.field) == (5, "state")
    controlled = float_scene().replace("[[bodies]]", '[[ptos]]\nname = "pto"\ntype = "linear"\nbody1 = "float"\n'
                                       'point1 = [0.0, 0.0, -1.0]\nbody2 = "ground"\npoint2 = [0.0, 0.0, -20.0]\n'
                                       'damping = 1e5\n\n[[controllers]]\nname = "ctl"\nptos = ["pto"]\n\n[[bodies]]', 1)
    with ServerConnection(server.address) as other:
        other.hello(controlled, {"float.nc": hdb})
        with pytest.raises(RemoteError) as err:
            other.save()
        assert (err.value.code, err.value.field) == (12, "type")


# ------------------------------------------------------------------ set-up off the step path

def test_steps_of_another_session_are_answered_while_a_hello_is_set_up(server, hdb):
    """A hello whose set-up takes long (dt = 2e-4 s: an IRF of 2e4 samples over 400 frequencies, ~2 s
    of CPU; a step takes well under a millisecond) is answered when its set-up is done; meanwhile the loop answers another session's steps (before
    the set-up moved to a worker thread, they waited for it: 0 or 1 step got through)."""
    slow = float_scene(dt=2e-4, duration=0.01)
    conn = ServerConnection(server.address, timeout=REPLY_S)
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    try:
        conn.hello(float_scene(duration=1.0e5), {"float.nc": hdb})
        sock.connect(server.address)
        sock.send(codec.pack(codec.message("hello", "slow-1", None, role="multibody", scene=slow,
                                           hdbs={"float.nc": to_wire(hdb)})))
        answered, seq = 0, 0
        sts = states(1)
        deadline = time.monotonic() + 600
        while not sock.poll(5):       # a step every 5 ms at most: a busy loop would take the set-up's core
            assert time.monotonic() < deadline, "the slow hello got no reply"
            conn.step(seq, seq * DT, *sts[0])
            seq, answered = seq + 1, answered + 1
        welcome = codec.unpack(sock.recv())
        assert welcome["type"] == "welcome" and welcome["parent"] == "slow-1", welcome
        assert welcome["setup"]["dt"] == 2e-4 and welcome["setup"]["irf_samples"] == 20_000
        assert answered >= 10, f"only {answered} steps of the other session were answered during the set-up"
        conn.step(seq, seq * DT, *sts[0])
    finally:
        sock.close(0)
        conn.close()


def test_irf_work_over_the_setup_bound_is_refused_naming_the_key(server, hdb):
    """An IRF of 6e6 samples (irf_duration 60 s at dt 1e-5) over 400 frequencies is 2.4e9
    sample-frequency products per transform, over MAX_IRF_PRODUCTS: error 8 naming the key,
    before any transform; the server serves on. Heave only: K(t) itself (6e6 x 1 pair, 48 MB) is
    within the set-up allocation bound, only the work is not."""
    text = float_scene(dt=1e-5, duration=0.01, irf_duration=60.0, dofs=["heave"])
    with ServerConnection(server.address, timeout=REPLY_S) as c:
        t0 = time.perf_counter()
        err = expect_error(lambda: c.hello(text, {"float.nc": hdb}), 8, "scene.hydro.irf_duration")
        assert "6000001 samples" in err.message and "2.41e+09" in err.message and "hydro.irf_domega" in err.message
        assert time.perf_counter() - t0 < 30.0
        c.hello(SCENE, {"float.nc": hdb})
        assert c.step(0, 0.0, *states(1)[0])["seq"] == 0


def test_a_frame_over_the_limit_is_refused_before_it_is_buffered(tmp_path):
    """SPEC §1: ``hydrolink serve --max-message-mib 1`` refuses a 200 MiB frame from its header
    without buffering it (dropped as it arrives), answering error 1 naming the limit on the same
    connection: the server's peak RSS grows by far less than the frame (before, a frame under the
    256 MiB limit cost twice its size; up to SPEC 1.8 such a frame dropped its connection); the
    server serves on."""
    import re
    import subprocess
    import sys

    proc = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "serve", "--bind", "tcp://127.0.0.1:*",
                             "--max-message-mib", "1", "--store", str(tmp_path)], stderr=subprocess.PIPE, text=True)
    socks = []

    def peak_mib() -> float:
        return int(re.search(r"VmHWM:\s+(\d+) kB", Path(f"/proc/{proc.pid}/status").read_text()).group(1)) / 1024

    def tracked() -> zmq.Socket:   # closed at the end of the test
        sock = dealer(address)
        socks.append(sock)
        return sock

    try:
        address = re.search(r"listening on (tcp://\S+)", proc.stderr.readline()).group(1)
        ping = codec.pack(codec.message("ping", 1, None))
        first = tracked()
        first.send(ping)
        assert first.poll(RECV_MS) and codec.unpack(first.recv())["type"] == "pong"
        before = peak_mib()
        big = tracked()
        big.send(bytes(200 * 2**20))
        assert big.poll(30_000), "no reply to a frame over the limit"
        reply = codec.unpack(big.recv())
        assert (reply["code"], reply["limit"], reply["maximum"]) == (1, "message_bytes", 2**20), reply
        grown = peak_mib() - before
        assert grown < 50, f"the server's peak RSS grew by {grown:.0f} MiB for a refused 200 MiB frame"
        under = tracked()   # a message just under the limit is still read
        under.send(codec.pack(codec.message("upload", 2, None, sha256="0" * 64, data=bytes(2**20 - 200))))
        assert under.poll(RECV_MS) and codec.unpack(under.recv())["field"] == "sha256"
        first.send(ping)
        assert first.poll(RECV_MS) and codec.unpack(first.recv())["type"] == "pong"
    finally:
        for sock in socks:
            sock.close(0)
        stopped(proc)


def test_a_reply_the_wire_cannot_carry_is_an_error_and_the_server_serves_on():
    """The one place replies are packed: a reply holding an int past 64 bits (a server fault: scene
    bounds keep every sent value in range) becomes error 99 naming the field, and the next request
    is answered (issue 22: TypeError in the server loop ended the server)."""
    from hydrolink.server.service.force_server import ForceServer
    srv = ForceServer(None)
    ping = codec.pack(codec.message("ping", "p1", None))
    srv._handlers["ping"] = lambda msg, msg_id, session: ("pong", {"time": 2 ** 70}, session)
    reply = codec.unpack(srv.respond(ping))
    assert (reply["type"], reply["code"], reply["field"], reply["parent"]) == ("error", 99, "time", "p1"), reply
    srv._handlers["ping"] = srv._ping
    assert codec.unpack(srv.respond(ping))["type"] == "pong"
    srv.close()


# ------------------------------------------------------------------ bounds on hellos (SPEC §4.2, error 14)


def _reply(sock: zmq.Socket, timeout_s: float) -> dict:
    assert sock.poll(int(timeout_s * 1000)), f"no reply within {timeout_s} s"
    return codec.unpack(sock.recv())


def test_a_hello_beyond_the_setup_bound_is_refused_at_once_and_the_others_are_served(hdb):
    """max_setups = 2: two hellos with set-ups of seconds (dt = 5e-4 s: an IRF of 8e3
    samples) are being set up; a third is refused with error 14 at once — while both set-ups still
    run — naming the bound, its value and the option; the two are welcomed and step, the existing
    session steps throughout, and once the set-ups are done a new hello is welcomed."""
    srv, thread = serve_in_thread(session_timeout=IDLE_S, max_setups=2)
    slow = float_scene(dt=5e-4, duration=0.1)
    socks = [dealer(srv.address) for _ in range(2)]
    try:
        with ServerConnection(srv.address, timeout=REPLY_S) as live, \
                ServerConnection(srv.address, timeout=REPLY_S) as late:
            live.hello(float_scene(duration=1.0e5), {"float.nc": hdb})
            t_sent = time.perf_counter()
            for i, sock in enumerate(socks):   # the ping's pong: the hello before it was handled
                sock.send(codec.pack(codec.message("hello", f"slow-{i}", None, role="multibody", scene=slow,
                                                   hdbs={"float.nc": to_wire(hdb)})))
                sock.send(codec.pack(codec.message("ping", f"ping-{i}", None)))
                assert _reply(sock, REPLY_S)["type"] == "pong"
            t0 = time.perf_counter()
            err = expect_error(lambda: late.hello(SCENE, {"float.nc": hdb}), 14, None)
            refused_s = time.perf_counter() - t0
            still_running = [sock.poll(0) == 0 for sock in socks]
            assert err.name == "busy" and err.extra == {"limit": "setups", "maximum": 2, "current": 2}, err
            assert "2 hellos are being set up, at most 2" in err.message and "--max-setups" in err.message
            assert all(still_running), "the refusal came after a set-up was done: not at once"
            steps = 0
            while not all(sock.poll(0) for sock in socks):   # the live session is answered meanwhile
                assert time.perf_counter() - t_sent < EXIT_S, "the slow hellos got no reply"
                live.step(steps, steps * DT, *states(1, seed=steps)[0])
                steps += 1
            setup_s = time.perf_counter() - t_sent
            for i, sock in enumerate(socks):
                welcome = codec.unpack(sock.recv())
                assert welcome["type"] == "welcome" and welcome["parent"] == f"slow-{i}", welcome
                assert welcome["setup"]["irf_samples"] == 8_000
                sock.send(codec.pack(codec.message("step", f"step-{i}", welcome["session"], seq=0, time=0.0,
                                                   position=np.zeros((1, 6)), velocity=np.zeros((1, 6)))))
                forces = _reply(sock, REPLY_S)
                assert forces["type"] == "forces" and forces["seq"] == 0, forces
            print(f"busy after {refused_s * 1e3:.1f} ms; the two set-ups took {setup_s:.2f} s; "
                  f"{steps} steps of the live session answered meanwhile")
            # "at once" is `still_running` above (the refusal came while both set-ups ran), not a ratio of
            # wall times: at load 16 the refusal took 2.5 s of 9.3 s of set-up
            assert steps >= 10, (refused_s, setup_s, steps)
            late.hello(SCENE, {"float.nc": hdb})   # the set-ups are done: room again
            assert late.step(0, 0.0, *states(1)[0])["seq"] == 0
            assert live.step(steps, steps * DT, *states(1)[0])["seq"] == steps
    finally:
        for sock in socks:
            sock.close(0)
        srv.stop()
        thread.join(timeout=5)


def test_a_hello_beyond_the_session_bound_is_refused_until_a_bye_frees_one(hdb):
    """max_sessions = 2: the third hello is refused with error 14 naming the bound; the open
    sessions step on unchanged; after one says bye a hello is welcomed."""
    srv, thread = serve_in_thread(session_timeout=IDLE_S, max_sessions=2)
    try:
        with ServerConnection(srv.address, timeout=REPLY_S) as a, ServerConnection(srv.address, timeout=REPLY_S) as b, \
                ServerConnection(srv.address, timeout=REPLY_S) as c:
            a.hello(SCENE, {"float.nc": hdb})
            b.hello(SCENE, {"float.nc": hdb})
            sts = states(4, seed=5)
            before = a.step(0, 0.0, *sts[0])
            t0 = time.perf_counter()
            err = expect_error(lambda: c.hello(SCENE, {"float.nc": hdb}), 14, None)
            refused_s = time.perf_counter() - t0
            assert err.name == "busy" and err.extra == {"limit": "sessions", "maximum": 2, "current": 2}, err
            assert "2 sessions open and 0 being set up, at most 2" in err.message and "--max-sessions" in err.message
            assert c.session is None and len(srv.sessions) == 2
            print(f"busy after {refused_s * 1e3:.1f} ms")
            assert refused_s < 1.0
            repeat = a.step(0, 0.0, *sts[0])   # §5.3: the cached reply, the session as it was
            for k in ("excitation", "radiation", "hydrostatic"):
                np.testing.assert_array_equal(repeat[k], before[k])
            assert a.step(1, DT, *sts[1])["seq"] == 1 and b.step(0, 0.0, *sts[0])["seq"] == 0
            b.bye()
            c.hello(SCENE, {"float.nc": hdb})
            assert c.step(0, 0.0, *sts[0])["seq"] == 0 and a.step(2, 2 * DT, *sts[2])["seq"] == 2
    finally:
        srv.stop()
        thread.join(timeout=5)


def test_a_hello_beyond_the_memory_budget_is_refused_until_a_bye_frees_it(hdb):
    """Issue 35 item 5: the open sessions' models hold at most max_memory_bytes together. With room
    for one session's model (as measured: its IRF alone is at least samples x (6N)^2 doubles), the
    second hello is refused with error 14 naming the memory bound and the figures; the first steps
    on; after its bye the hello is welcomed."""
    srv, thread = serve_in_thread(session_timeout=IDLE_S)
    try:
        with ServerConnection(srv.address, timeout=REPLY_S) as a:
            a.hello(SCENE, {"float.nc": hdb})
            one = srv.held_bytes()
            irf = a.setup.irf_samples * 36 * 8
            assert one >= irf, (one, irf)
    finally:
        srv.stop()
        thread.join(timeout=5)
    srv, thread = serve_in_thread(session_timeout=IDLE_S, max_memory_bytes=int(1.5 * one))
    try:
        with ServerConnection(srv.address, timeout=REPLY_S) as a, ServerConnection(srv.address, timeout=REPLY_S) as b:
            a.hello(SCENE, {"float.nc": hdb})
            err = expect_error(lambda: b.hello(SCENE, {"float.nc": hdb}), 14, None)
            assert err.name == "busy" and err.extra["limit"] == "memory", err
            assert err.extra["maximum"] == int(1.5 * one) // 2**20 and "--max-memory-mib" in err.message
            assert b.session is None and len(srv.sessions) == 1
            sts = states(2, seed=3)
            assert a.step(0, 0.0, *sts[0])["seq"] == 0
            a.bye()
            b.hello(SCENE, {"float.nc": hdb})
            assert b.step(0, 0.0, *sts[0])["seq"] == 0
    finally:
        srv.stop()
        thread.join(timeout=5)


def test_a_controller_hello_is_not_counted_against_the_session_bound(hdb):
    """A controller joins an existing session: with max_sessions = 1 reached it is still welcomed,
    while a second multibody hello is refused (error 14)."""
    from hydrolink.server.service.force_server import ForceServer
    text = scene_toml(dt=DT, duration=10.0, waves=regular_waves(1.0, 6.0), hydro={"irf_duration": 2.0},
                      bodies=[body("float", hdb="float.nc", mass=3.0e5, center_of_mass=[0, 0, -1],
                                   inertia=[1e7, 1e7, 2e7])],
                      ptos=[linear_pto("pto", "float", [0, 0, -1], "ground", [0, 0, -20], damping=1e5)],
                      controllers=[{"name": "ctl", "ptos": ["pto"]}])
    srv = ForceServer("tcp://127.0.0.1:*", max_sessions=1)   # bound (controllers need one), not served
    try:
        hello = codec.message("hello", "h", None, role="multibody", scene=text, hdbs={"float.nc": to_wire(hdb)})
        welcome = srv.handle(codec.pack(hello), [b"c"])
        assert welcome["type"] == "welcome", welcome
        joined = srv.handle(codec.pack(codec.message("hello", "j", welcome["session"], role="controller",
                                                     controller="ctl", token=welcome["control_token"])), [b"k"])
        assert joined["type"] == "welcome" and joined["session"] not in (None, welcome["session"]), joined
        refused = srv.handle(codec.pack(hello), [b"d"])
        assert (refused["type"], refused["code"], refused["name"], refused["limit"]) == \
            ("error", 14, "busy", "sessions"), refused
    finally:
        srv.close()


@pytest.mark.parametrize("kw", [{"max_setups": 0}, {"max_sessions": -1}, {"max_sessions": 2.5}])
def test_a_bound_that_admits_nothing_is_refused_naming_the_argument(kw):
    from hydrolink.server.service.force_server import ForceServer
    with pytest.raises(ValueError, match=f"{next(iter(kw))} must be an int >= 1"):
        ForceServer(None, **kw)


def test_hydrolink_serve_takes_the_bounds_from_its_options(hdb, tmp_path):
    """`hydrolink serve --max-sessions 1`: the second hello is error 14 naming the option and 1."""
    # replies waited for up to 120 s: 30 s was too short for a set-up with three suite copies on 2 cores
    with serve_process("--max-setups", "1", "--max-sessions", "1", "--store", str(tmp_path)) as address, \
            ServerConnection(address, timeout=120.0) as a, ServerConnection(address, timeout=120.0) as b:
        a.hello(SCENE, {"float.nc": hdb})
        err = expect_error(lambda: b.hello(SCENE, {"float.nc": hdb}), 14, None)
        assert err.extra == {"limit": "sessions", "maximum": 1, "current": 1} and "--max-sessions" in err.message
        a.bye()
        b.hello(SCENE, {"float.nc": hdb})
        assert b.step(0, 0.0, *states(1)[0])["seq"] == 0
