"""``hydrolink linearize`` (clients/analysis/plant.py): the device as a linear state-space plant.

References, independent of the plant's assembly (reduced coordinates, state-space realisation):
- RM3's two-body frequency-domain model written here from the HDB (A(w), B(w), hydrostatics at its
  frequencies), the scene's masses and the PTO damper, exp(-i w t) convention;
- ``hydrolink run`` of the same linear scene (Exudyn client + force server), its recorded excitation
  fed to the plant by scipy.signal.lsim (written here).
"""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest

from hydrolink.protocol.scene import parse_scene
from test_rm3 import C_PTO, HEAVE, MASS, scene_text

from conftest import IDLE_S, REPLY_S


@pytest.fixture(scope="module")
def rm3(reference_data):
    from hydrolink.server.hdb.io import load_hdb
    return load_hdb(reference_data / "rm3_wamit" / "rm3.1")


def _plant(text: str, rm3):
    from hydrolink.clients.analysis.plant import build_plant
    scene = parse_scene(text)
    return build_plant(scene, {b.hdb: rm3 for b in scene.bodies})


def _frequency_domain(rm3, omega_index: np.ndarray, force: np.ndarray, extra_damping: np.ndarray | None = None
                      ) -> np.ndarray:
    """Heave responses (n_w, 2) of RM3 to generalised heave forces ``force`` (2,) or (n_w, 2):
    [-w^2 (M + A(w)) - i w (B(w) + B_pto) + C] X = F at the HDB's own frequencies."""
    w = rm3["omega"].values[omega_index]
    a = rm3["added_mass"].values[omega_index][:, HEAVE][:, :, HEAVE]
    b = rm3["radiation_damping"].values[omega_index][:, HEAVE][:, :, HEAVE]
    c = rm3["hydrostatic_stiffness"].values[np.ix_(HEAVE, HEAVE)]
    b_pto = C_PTO * np.array([[1.0, -1.0], [-1.0, 1.0]])
    b_pto = b_pto + (0.0 if extra_damping is None else extra_damping)
    z = -w[:, None, None] ** 2 * (np.diag(MASS) + a) - 1j * w[:, None, None] * (b + b_pto) + c
    return np.linalg.solve(z, np.broadcast_to(force, (w.size, 2))[..., None])[..., 0]


def test_rm3_plant_layout(rm3):
    p = _plant(scene_text("full", Path("rm3.1")), rm3)
    assert p.states[:4] == ("float.heave.position", "spar.heave.position", "float.heave.velocity",
                            "spar.heave.velocity")
    assert all(s.startswith("radiation:") for s in p.states[4:]) and len(p.states) > 4
    assert p.inputs == ("pto:pto", "excitation:float.heave", "excitation:spar.heave")
    assert p.outputs == ("float.heave.position", "spar.heave.position", "float.heave.velocity",
                         "spar.heave.velocity", "pto:pto.displacement", "pto:pto.velocity")
    # the PTO line runs float -> spar, vertical: its extension is z_float - z_spar
    out = {name: p.C[i] for i, name in enumerate(p.outputs)}
    np.testing.assert_allclose(out["pto:pto.displacement"], out["float.heave.position"] - out["spar.heave.position"],
                               atol=1e-12)
    assert np.linalg.eigvals(p.A).real.max() < 0          # damped: every mode decays
    assert p.A.shape == (len(p.states),) * 2 and p.B.shape == (len(p.states), 3) and p.C.shape == (6, len(p.states))


def test_frequency_response_against_frequency_domain(rm3):
    """excitation -> position and PTO force -> PTO velocity equal the FD model within the state-space
    fit's tolerance over the wave band (0.3..2 rad/s)."""
    p = _plant(scene_text("full", Path("rm3.1")), rm3)
    w_all = rm3["omega"].values
    idx = np.flatnonzero((w_all >= 0.3) & (w_all <= 2.0))
    w = w_all[idx]
    h = np.conj(p.frequency_response(w))                   # -> exp(-i w t) phasors
    pos = [p.outputs.index("float.heave.position"), p.outputs.index("spar.heave.position")]
    worst = 0.0
    for k, name in enumerate(("excitation:float.heave", "excitation:spar.heave")):
        x = _frequency_domain(rm3, idx, np.eye(2)[k])
        got = h[:, pos, p.inputs.index(name)]
        err = np.abs(got - x).max(axis=1) / np.abs(x).max(axis=1)
        worst = max(worst, float(err.max()))
        print(f"{name} -> heave positions: max relative error {err.max():.2e} at w = {w[err.argmax()]:.3f}")
    # PTO added tension u: -u on the float's heave, +u on the spar's; PTO velocity = v_f - v_s
    x = _frequency_domain(rm3, idx, np.array([-1.0, 1.0]))
    v_pto = -1j * w * (x[:, 0] - x[:, 1])
    got = h[:, p.outputs.index("pto:pto.velocity"), p.inputs.index("pto:pto")]
    err = np.abs(got - v_pto) / np.abs(v_pto)
    print(f"pto force -> pto velocity: max relative error {err.max():.2e}; fit error {p.radiation_fit_error:.2e}")
    worst = max(worst, float(err.max()))
    assert worst < 3 * max(p.radiation_fit_error, 0.01)    # hydro.ss_tolerance = 0.01 (default)


def test_linear_damping_is_in_the_plant(rm3):
    """bodies[0].linear_damping (a linear force term of the server) enters as a damping: the float's
    response equals the frequency-domain model with B + diag(b_lin, 0)."""
    text = scene_text("full", Path("rm3.1")).replace(
        "mass = 725833.0", "mass = 725833.0\nlinear_damping = [0, 0, 4e5, 0, 0, 0]")
    p = _plant(text, rm3)
    idx = np.flatnonzero((rm3["omega"].values >= 0.3) & (rm3["omega"].values <= 2.0))
    h = np.conj(p.frequency_response(rm3["omega"].values[idx]))[:, p.outputs.index("float.heave.position"),
                                                                  p.inputs.index("excitation:float.heave")]
    x = _frequency_domain(rm3, idx, np.array([1.0, 0.0]), np.diag([4e5, 0.0]))[:, 0]
    x0 = _frequency_domain(rm3, idx, np.array([1.0, 0.0]))[:, 0]
    err = np.abs(h - x) / np.abs(x)
    print(f"linear damping: max relative error {err.max():.2e}; the damping changes |x| by up to "
          f"{np.abs(np.abs(x) / np.abs(x0) - 1).max():.1%}")
    assert err.max() < 0.03 and np.abs(np.abs(x) / np.abs(x0) - 1).max() > 0.1


def test_time_simulation_against_hydrolink_run(rm3, reference_data, tmp_path):
    """lsim of the plant fed with the run's recorded excitation equals ``hydrolink run`` of the same
    scene (radiation = "state-space": the same fits) within 0.5 % of the motion's amplitude."""
    import xarray as xr
    from scipy.signal import lsim

    from hydrolink.clients.run import run_scene_file
    text = scene_text("full", reference_data / "rm3_wamit" / "rm3.1", duration=120.0)
    text = text.replace('interaction = "full"', 'interaction = "full"\nradiation = "state-space"')
    (tmp_path / "rm3.toml").write_text(text)
    run_scene_file(tmp_path / "rm3.toml", tmp_path / "rm3.nc", progress=False)
    ds = xr.load_dataset(tmp_path / "rm3.nc")
    t = ds["time"].values
    run_z = (ds["position"] - ds["equilibrium_position"]).sel(dof="heave").values       # (T, 2)
    exc = ds["excitation_force"].sel(dof="heave").values
    p = _plant(text, rm3)
    u = np.zeros((t.size, len(p.inputs)))
    u[:, p.inputs.index("excitation:float.heave")] = exc[:, 0]
    u[:, p.inputs.index("excitation:spar.heave")] = exc[:, 1]
    _, y, _ = lsim((p.A, p.B, p.C, p.D), u, t)
    pos = [p.outputs.index("float.heave.position"), p.outputs.index("spar.heave.position")]
    err = np.abs(y[:, pos] - run_z).max(axis=0) / np.abs(run_z).max(axis=0)
    vel = (y[:, p.outputs.index("pto:pto.velocity")], ds["pto_velocity"].values[:, 0])
    err_v = np.abs(vel[0] - vel[1]).max() / np.abs(vel[1]).max()
    print(f"plant vs hydrolink run: float {err[0]:.2e}, spar {err[1]:.2e}, pto velocity {err_v:.2e} "
          f"(of the peak); amplitudes {np.abs(run_z).max(axis=0)}")
    assert np.all(err < 5e-3) and err_v < 5e-3


@pytest.mark.parametrize("dt,why", [("nan", "finite"), ("1e-300", "greater than or equal to 1e-06"),
                                     ("1e300", "less than or equal to 3600")])
def test_a_sampling_time_outside_a_time_steps_bounds_is_refused_before_the_build(reference_data, tmp_path, dt, why):
    """--dt as a scene's time step (1 µs to 1 h): 1e-300 made a zero-order hold whose A is the identity
    to the last bit and was written as a plant; NaN and 1e300 are refused too, naming --dt, nothing written."""
    from click.testing import CliRunner

    from hydrolink.clients.cli import cli
    (tmp_path / "rm3.toml").write_text(scene_text("full", reference_data / "rm3_wamit" / "rm3.1"))
    res = CliRunner().invoke(cli, ["linearize", str(tmp_path / "rm3.toml"), "-o", str(tmp_path / "p.npz"),
                                   "--no-progress", "--dt", dt])
    assert res.exit_code == 1 and "--dt" in res.output and why in res.output, res.output
    assert not (tmp_path / "p.npz").exists()


def test_files_and_discretisation(rm3, reference_data, tmp_path):
    """.npz/.mat/.nc hold the same matrices and names; --dt gives the zero-order hold: the discrete
    plant's step response equals the continuous one at the samples (scipy.signal.lsim of a step)."""
    import xarray as xr
    from click.testing import CliRunner
    from scipy.io import loadmat
    from scipy.signal import lsim

    from hydrolink.clients.cli import cli
    from hydrolink.clients.analysis.plant import load_plant
    text = scene_text("full", reference_data / "rm3_wamit" / "rm3.1")
    (tmp_path / "rm3.toml").write_text(text)
    for out, extra in (("p.npz", []), ("p.mat", []), ("pd.nc", ["--dt", "0.05"]), ("pd.npz", ["--dt", "0.05"])):
        res = CliRunner().invoke(cli, ["linearize", str(tmp_path / "rm3.toml"), "-o", str(tmp_path / out),
                                       "--no-progress", *extra])
        assert res.exit_code == 0, res.output
    p = load_plant(tmp_path / "p.npz")
    assert p.dt is None and p.inputs[0] == "pto:pto"
    m = loadmat(tmp_path / "p.mat")
    np.testing.assert_array_equal(m["A"], p.A)
    assert [str(x[0]) for x in m["outputs"].ravel()] == list(p.outputs)
    nc = xr.load_dataset(tmp_path / "pd.nc")
    pd = load_plant(tmp_path / "pd.npz")
    assert pd.dt == 0.05 and nc.attrs["dt"] == 0.05
    np.testing.assert_array_equal(nc["A"].values, pd.A)
    assert list(nc["input"].values) == list(p.inputs)
    # a held step on the PTO force: discrete recursion vs continuous integration at the samples
    t = np.arange(400) * 0.05
    u = np.zeros((t.size, 3))
    u[:, 0] = 1e5
    _, y, _ = lsim((p.A, p.B, p.C, p.D), u, t, interp=False)
    x, yd = np.zeros(pd.A.shape[0]), np.zeros((t.size, pd.C.shape[0]))
    for k in range(t.size):
        yd[k] = pd.C @ x + pd.D @ u[k]
        x = pd.A @ x + pd.B @ u[k]
    np.testing.assert_allclose(yd, y, atol=1e-8 * np.abs(y).max())


@pytest.mark.parametrize("edit, key", [
    (("mass = 725833.0", "mass = 725833.0\nquadratic_damping = [0, 0, 1e5, 0, 0, 0]"), "bodies[0].quadratic_damping"),
    (('interaction = "full"', 'interaction = "full"\nnonlinear = "hydrostatic"'), None),
])
def test_nonlinear_terms_refused_with_their_key(rm3, edit, key):
    from hydrolink.clients.analysis.plant import PlantError
    text = scene_text("full", Path("rm3.1")).replace(*edit)
    if key is None:   # nonlinear hydrostatics: parse may already ask for the hull
        try:
            scene = parse_scene(text)
        except Exception as exc:
            pytest.skip(f"scene refused before the plant: {exc}")
        key = scene.nonlinear_key()
    with pytest.raises(PlantError, match=key.replace("[", r"\[").replace("]", r"\]")):
        _plant(text, rm3)


def test_force_limit_linearised_with_a_warning(rm3):
    text = scene_text("full", Path("rm3.1")).replace("damping = 1.2e6",
                                                                             "damping = 1.2e6\nforce_limit = 2e5")
    p = _plant(text, rm3)
    assert any(w.startswith("ptos[0].force_limit") for w in p.warnings)


def test_controller_gets_the_plant_at_join(reference_data, tmp_path):
    """SPEC §5.7.2: a controller's hello with ``plant`` gets the session's plant in welcome.control
    (continuous, or ZOH at plant.dt), equal to ``hydrolink linearize`` of the scene; a bad dt is
    error 5 naming plant.dt."""
    import zmq
    from test_controllers import controller_block
    from test_controllers import scene_text as controlled_scene

    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.clients.analysis.plant import Plant, build_plant
    from hydrolink.protocol import codec
    from hydrolink.server.service.force_server import serve_in_thread

    text = controlled_scene(reference_data, 4.0, controller_block("force", 1.0e6, 0.0, join_timeout=0.2))
    (tmp_path / "s.toml").write_text(text)
    scene = parse_scene(text)
    hdbs = load_scene_hdbs(scene, tmp_path / "s.toml", progress=False)
    expect = build_plant(scene, hdbs)
    srv, thread = serve_in_thread("tcp://127.0.0.1:*", session_timeout=IDLE_S, plant_builder=build_plant)
    ctx = zmq.Context()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(srv.address)

    def ask(**fields) -> dict:
        sock.send(codec.pack(codec.message("hello", "x", fields.pop("session"), **fields)))
        assert sock.poll(30000), "no reply"
        return codec.unpack(sock.recv())

    try:
        with ServerConnection(srv.address, timeout=REPLY_S) as conn:
            conn.hello(text, hdbs)
            r = ask(role="controller", controller="ctl", session=conn.session, token=conn.control_token, plant={"dt": None})
            got = Plant.from_wire(codec.decode_tree(r["control"])["plant"])
            assert got.states == expect.states and got.inputs == expect.inputs and got.dt is None
            np.testing.assert_allclose(got.A, expect.A, rtol=1e-12, atol=1e-12 * np.abs(expect.A).max())
            r = ask(role="controller", controller="ctl", session=conn.session, token=conn.control_token, plant={"dt": 0.04})
            got = Plant.from_wire(codec.decode_tree(r["control"])["plant"])
            np.testing.assert_allclose(got.B, expect.discretize(0.04).B, rtol=1e-9, atol=1e-15)
            for bad in (0.0, "x", 5e-324, 1e300, -1e300, 2**62):
                r = ask(role="controller", controller="ctl", session=conn.session, token=conn.control_token, plant={"dt": bad})
                assert (r["code"], r["field"]) == (5, "plant.dt")
    finally:
        sock.close(0)
        ctx.term()
        srv.stop()
        thread.join(5)


def test_constant_radiation_has_no_states_and_is_exact_at_its_frequency(rm3):
    """[hydro] radiation = "constant": A(w0) in the mass, B(w0) a damping, no radiation state; at w0
    the plant is the frequency-domain model exactly (HDB interpolated linearly at w0 here)."""
    text = scene_text("full", Path("rm3.1")).replace('interaction = "full"', 'interaction = "full"\nradiation = "constant"')
    p = _plant(text, rm3)
    assert not any(s.startswith("radiation:") for s in p.states) and len(p.states) == 4
    w0 = 2 * np.pi / 8.0
    om = rm3["omega"].values
    a = np.array([[np.interp(w0, om, rm3["added_mass"].values[:, i, j]) for j in HEAVE] for i in HEAVE])
    b = np.array([[np.interp(w0, om, rm3["radiation_damping"].values[:, i, j]) for j in HEAVE] for i in HEAVE])
    c = rm3["hydrostatic_stiffness"].values[np.ix_(HEAVE, HEAVE)]
    b_pto = C_PTO * np.array([[1.0, -1.0], [-1.0, 1.0]])
    x = np.linalg.solve(-w0 ** 2 * (np.diag(MASS) + a) - 1j * w0 * (b + b_pto) + c, np.eye(2))
    h = np.conj(p.frequency_response([w0])[0])
    rows = [p.outputs.index("float.heave.position"), p.outputs.index("spar.heave.position")]
    cols = [p.inputs.index("excitation:float.heave"), p.inputs.index("excitation:spar.heave")]
    np.testing.assert_allclose(h[np.ix_(rows, cols)], x, rtol=1e-9, atol=1e-9 * np.abs(x).max())
