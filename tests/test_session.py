"""server/service/session.py: a hello's scene and HDBs become the model (errors naming the field), and the
step sequencing rules of SPEC §5.3 — new step, replace (higher iteration, the radiation memory
rolled back), retry (the cached reply) and the refusals that leave the session as it was. Messages
go through the real codec (pack/unpack), as over the wire."""

from __future__ import annotations

import numpy as np
import pytest

from analytic_hdb import DOF_PARAMS, irf, make_body_hdb
from conftest import body, scene_toml
from hydrolink.protocol import codec
from hydrolink.protocol.codec import Code, ProtocolError
from hydrolink.protocol.hdb.wire import to_wire
from hydrolink.server.service.session import Session, build_model

DT, RHO = 0.05, 1025.0
HEAVE = 2


@pytest.fixture(scope="module")
def hdb():
    return make_body_hdb()


def wire(**fields) -> dict:
    """A message map as the server receives it (msgpack round trip)."""
    return codec.unpack(codec.pack(fields))


def hello(hdb, *, hdbs: dict | None = None, **body_keys) -> dict:
    """A hello for the analytic float (HDB float.nc) in still water, plus a dry body "frame"."""
    text = scene_toml(dt=DT, duration=10.0, hydro={"irf_duration": 4.0},
                      bodies=[body("float", **{"hdb": "float.nc", "mass": 3.0e5, "center_of_mass": [0, 0, -1],
                                               "inertia": [1e7, 1e7, 2e7], **body_keys}),
                              body("frame", mass=10.0, center_of_mass=[0, 0, 5], inertia=[1, 1, 1])])
    return wire(scene=text, hdbs={"float.nc": to_wire(hdb)} if hdbs is None else hdbs)


def step(seq: int, position: np.ndarray, velocity: np.ndarray, iteration: int = 0, time: float | None = None) -> dict:
    return wire(seq=seq, iteration=iteration, time=seq * DT if time is None else time,
                position=np.ascontiguousarray(position), velocity=np.ascontiguousarray(velocity))


def refused(fn, code: int, field: str) -> ProtocolError:
    with pytest.raises(ProtocolError) as info:
        fn()
    assert (info.value.code, info.value.field) == (code, field), info.value
    return info.value


@pytest.fixture()
def session(hdb) -> Session:
    return Session("s" * 32, build_model(hello(hdb)))


def test_hello_builds_the_model_of_the_wet_bodies_in_the_scene_water(session):
    """The dry body needs no HDB; the heave stiffness is the analytic C33 rescaled to rho = 1025 and
    the hydrostatic force of a 0.1 m heave offset is -C33 * 0.1."""
    setup = session.model.setup_info()
    assert setup.bodies == ("float",) and session.n_bodies == 1 and session.dt == DT
    c33 = 7.7e5 * RHO / 1000
    assert setup.hydrostatic_stiffness[HEAVE, HEAVE] == pytest.approx(c33, rel=1e-12)
    pos = setup.equilibrium_position.copy()
    pos[0, HEAVE] += 0.1
    out = session.step(step(0, pos, np.zeros((1, 6))))
    assert out["hydrostatic"][0, HEAVE] == pytest.approx(-0.1 * c33, rel=1e-12)
    assert (out["seq"], out["iteration"], out["time"]) == (0, 0, 0.0) and out["compute_us"] > 0


def test_hello_errors_name_the_field(hdb):
    refused(lambda: build_model(hello(hdb, mass=-1.0)), Code.BAD_SCENE, "scene.bodies[0].mass")
    refused(lambda: build_model(hello(hdb, hdb_body="buoy")), Code.BAD_SCENE, "scene.bodies[0].hdb_body")
    refused(lambda: build_model(hello(hdb, hdbs={})), Code.BAD_HDB, 'hdbs["float.nc"]')
    bad = to_wire(hdb)
    bad["omega"] = bad["omega"].copy()
    bad["omega"][2] = np.nan
    refused(lambda: build_model(hello(hdb, hdbs={"float.nc": bad})), Code.BAD_HDB, 'hdbs["float.nc"].omega')
    refused(lambda: build_model(wire(scene="[simulation\n", hdbs={})), Code.BAD_SCENE, "scene")


def test_hello_meshes_errors_name_the_field(hdb):
    """hello.meshes (SPEC §5.1): each malformed hull is refused naming meshes.<body> or its array."""
    cube = np.array([[x, y, z] for x in (-1.0, 1.0) for y in (-1.0, 1.0) for z in (-2.0, 1.0)])
    faces = np.array([[0, 1, 3, 2], [4, 6, 7, 5], [0, 4, 5, 1], [2, 3, 7, 6], [0, 2, 6, 4], [1, 5, 7, 3]])

    def with_mesh(meshes):
        return wire(**hello(hdb, nonlinear="hydrostatic"), meshes=meshes)
    assert [t.name for t in build_model(with_mesh({"float": {"vertices": cube, "faces": faces}})).terms] \
        == ["nonlinear_hydrostatics"]
    refused(lambda: build_model(with_mesh([1, 2])), Code.BAD_VALUE, "meshes")
    refused(lambda: build_model(with_mesh({"float": 3})), Code.BAD_VALUE, "meshes.float")
    refused(lambda: build_model(with_mesh({"float": {"faces": faces}})), Code.MISSING_FIELD, "meshes.float.vertices")
    refused(lambda: build_model(with_mesh({"float": {"vertices": cube, "faces": faces + 0.5}})), Code.BAD_VALUE,
            "meshes.float.faces")
    err = refused(lambda: build_model(with_mesh({"float": {"vertices": cube, "faces": faces[:5]}})), Code.BAD_VALUE,
                  "meshes.float")
    assert "not closed: 4 edges belong to one panel only" in err.message
    refused(lambda: build_model(with_mesh({"float": {"vertices": cube[:, :2], "faces": faces}})), Code.BAD_VALUE,
            "meshes.float")
    refused(lambda: build_model(hello(hdb, nonlinear="hydrostatic")), Code.BAD_SCENE, "scene.bodies[0].mesh")


def test_replace_rolls_the_radiation_memory_back(hdb):
    """Step 1 sent with one velocity and replaced (iteration 1) with another gives exactly the
    forces of a session that only ever saw the second; step 2 then convolves the second. With a
    unit heave velocity at t = 0 only, the memory at t_n (inside the IRF window, weight 1 of the
    fixed-window trapezoid) is -dt K(t_n), K in closed form."""
    a, b = (Session(n * 32, build_model(hello(hdb))) for n in "ab")
    eq = a.model.setup_info().equilibrium_position
    v0, v1, v1_final = np.zeros((1, 6)), np.zeros((1, 6)), np.zeros((1, 6))
    v0[0, HEAVE], v1[0, HEAVE], v1_final[0, HEAVE] = 1.0, 0.7, -0.3
    for s in (a, b):
        s.step(step(0, eq, v0))
    a.step(step(1, eq, v1))
    replaced = a.step(step(1, eq, v1_final, iteration=1))
    direct = b.step(step(1, eq, v1_final))
    for key in ("excitation", "radiation", "hydrostatic"):
        np.testing.assert_array_equal(replaced[key], direct[key])
    zero = np.zeros((1, 6))
    np.testing.assert_array_equal(a.step(step(2, eq, zero))["radiation"], b.step(step(2, eq, zero))["radiation"])
    # the memory itself: a fresh session, an impulse of heave velocity at t = 0
    c = Session("c" * 32, build_model(hello(hdb)))
    f = [c.step(step(k, eq, v0 if k == 0 else zero))["radiation"][0, HEAVE] for k in range(40)]
    _, b0, w0 = DOF_PARAMS[HEAVE]
    t = np.arange(1, 40) * DT
    expected = -DT * irf(t, b0 * RHO / 1000, w0)
    assert np.abs(np.array(f[1:]) - expected).max() < 1e-3 * np.abs(expected).max()


def test_retry_returns_the_cached_reply_and_changes_nothing(session):
    eq = session.model.setup_info().equilibrium_position
    v = np.zeros((1, 6))
    v[0, HEAVE] = 0.5
    first = session.step(step(0, eq, v))
    again = session.step(step(0, eq, v))
    assert again["compute_us"] == 0.0 and session.steps == 1
    for key in ("excitation", "radiation", "hydrostatic"):
        np.testing.assert_array_equal(again[key], first[key])
    refused(lambda: session.step(step(0, eq, 2 * v)), Code.OUT_OF_ORDER, "iteration")


def test_refused_steps_leave_the_session_as_it_was(session):
    eq = session.model.setup_info().equilibrium_position
    zero = np.zeros((1, 6))
    assert session.state == "ready"
    refused(lambda: session.step(step(1, eq, zero)), Code.OUT_OF_ORDER, "seq")             # must start at 0
    refused(lambda: session.step(step(0, eq, zero, time=0.01)), Code.BAD_VALUE, "time")    # time = seq dt
    refused(lambda: session.step(step(0, np.zeros((2, 6)), np.zeros((2, 6)))), Code.BAD_VALUE, "position")
    assert session.state == "ready" and session.steps == 0
    session.step(step(0, eq, zero))
    session.step(step(1, eq, zero, iteration=2))
    refused(lambda: session.step(step(1, eq, zero, iteration=1)), Code.OUT_OF_ORDER, "iteration")  # older
    refused(lambda: session.step(step(3, eq, zero)), Code.OUT_OF_ORDER, "seq")                      # a gap
    refused(lambda: session.step(step(0, eq, zero)), Code.OUT_OF_ORDER, "seq")                      # the past
    assert (session.state, session.last_seq, session.last_iteration, session.steps) == ("running", 1, 2, 2)
    assert session.step(step(2, eq, zero))["seq"] == 2


# ---------------------------------------------------------------- rollback (SPEC §5.9)

def rollback_session(hdb, radiation: str) -> Session:
    """The analytic float in regular waves with quadratic damping and relative drag (every term
    that depends on the state sent), radiation by ``radiation``."""
    text = scene_toml(dt=DT, duration=10.0, waves={"type": "regular", "height": 1.0, "period": 6.0},
                      hydro={"irf_duration": 4.0, "radiation": radiation},
                      bodies=[body("float", hdb="float.nc", mass=3.0e5, center_of_mass=[0, 0, -1],
                                   inertia=[1e7, 1e7, 2e7], quadratic_damping=[1e4] * 6,
                                   drag={"cd": [1.0] * 6, "area": [20.0] * 6, "relative": True})])
    return Session("r" * 32, build_model(wire(scene=text, hdbs={"float.nc": to_wire(hdb)})))


def states(n: int, seed: int) -> list[tuple[np.ndarray, np.ndarray]]:
    rng = np.random.default_rng(seed)
    eq = np.array([[0.0, 0.0, 0.0, 0.0, 0.0, 0.0]])
    return [(eq + 0.1 * rng.standard_normal((1, 6)), 0.5 * rng.standard_normal((1, 6))) for _ in range(n)]


FIELDS = ("excitation", "radiation", "hydrostatic", "viscous")


@pytest.mark.parametrize("radiation", ["convolution", "state-space", "constant", "off"])
def test_a_restored_session_answers_as_if_the_steps_after_its_save_never_happened(hdb, radiation):
    """Reference: 120 steps, step 40 replaced once (iteration 1). Rolled back: at step 60 the
    state is saved, 30 other steps are sent (other states, one replaced), the state is restored and
    the reference's steps 61.. are sent: every reply equals the reference's, bit for bit; restored
    twice, the same again; a state saved before any step replays the whole run."""
    good = states(120, 1)
    other = states(120, 2)

    def run(s: Session, seqs, sts, replace_at=None) -> dict[int, dict]:
        out = {}
        for k in seqs:
            out[k] = s.step(step(k, *sts[k]))
            if k == replace_at:
                out[k] = s.step(step(k, sts[k][0] * 1.5, sts[k][1] * 0.5, iteration=1))
        return out

    ref = run(rollback_session(hdb, radiation), range(120), good, replace_at=40)
    s = rollback_session(hdb, radiation)
    at_start = s.save()
    assert at_start["seq"] == -1
    run(s, range(61), good, replace_at=40)
    saved = s.save()
    assert (saved["seq"], saved["iteration"]) == (60, 0)
    for attempt in range(2):
        run(s, range(61, 91), other, replace_at=70)
        assert s.restore(wire(state=saved["state"]))["seq"] == 60
        refused(lambda: s.step(step(62, *good[62])), Code.OUT_OF_ORDER, "seq")
        again = run(s, range(61, 120), good)
        for k, reply in again.items():
            for f in FIELDS:
                assert np.array_equal(reply[f], ref[k][f]), (attempt, k, f)
        s.restore(wire(state=saved["state"]))
    s.restore(wire(state=at_start["state"]))
    whole = run(s, range(120), good, replace_at=40)
    for k in (0, 40, 119):
        for f in FIELDS:
            assert np.array_equal(whole[k][f], ref[k][f]), (k, f)


def test_a_restored_step_can_be_replaced_and_retried(hdb):
    """Right after a restore the saved step is the newest: a retry gets its cached reply, a higher
    iteration replaces it exactly as it would have before the save."""
    sts = states(12, 3)
    ref = rollback_session(hdb, "convolution")
    for k in range(10):
        ref.step(step(k, *sts[k]))
    replaced = ref.step(step(9, sts[11][0], sts[11][1], iteration=1))
    s = rollback_session(hdb, "convolution")
    for k in range(10):
        first9 = s.step(step(k, *sts[k]))
    state = s.save()["state"]
    s.step(step(10, *sts[10]))
    s.restore(wire(state=state))
    assert s.step(step(9, *sts[9]))["compute_us"] == 0.0           # the retry: from the cache
    assert np.array_equal(s.step(step(9, *sts[9]))["radiation"], first9["radiation"])
    again = s.step(step(9, sts[11][0], sts[11][1], iteration=1))
    for f in FIELDS:
        assert np.array_equal(again[f], replaced[f]), f


def test_unknown_and_released_states_are_named(hdb):
    s = rollback_session(hdb, "convolution")
    refused(lambda: s.restore(wire(state=7)), Code.BAD_VALUE, "state")
    refused(lambda: s.restore(wire(state=0)), Code.BAD_VALUE, "state")
    refused(lambda: s.restore(wire()), Code.MISSING_FIELD, "state")
    state = s.save()["state"]
    assert s.release(wire(state=state))["kept"] == 0
    err = refused(lambda: s.restore(wire(state=state)), Code.BAD_VALUE, "state")
    assert "none" in err.message
