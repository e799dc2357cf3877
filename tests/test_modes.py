"""Generalized modes simulated (issue 38 item 3): server/modes.py, clients/exudyn/modes.py.

The flexible barge (examples/data/flexible_barge: 6 rigid DOFs + two bending modes + one torsion
mode) run end to end through a real force server and the Exudyn client, against references written
here: the frequency-domain solution of the same HDB and structure, and the undamped eigenvalue
problem for a free decay.
"""

from __future__ import annotations

import json
from pathlib import Path

import numpy as np
import pytest
import scipy.linalg
import xarray as xr

from conftest import REPLY_S, body, linear_pto, regular_waves, scene_toml

from hydrolink.clients.exudyn.client import run
from hydrolink.clients.lockstep.connection import RemoteError, ServerConnection
from hydrolink.clients.lockstep.results import ResultWriter
from hydrolink.protocol.scene import SceneError, parse_scene
from hydrolink.server.errors import ModelError
from hydrolink.server.hdb.io import load_hdb
from hydrolink.server.model import HydroModel

HDB = Path(__file__).resolve().parents[1] / "examples" / "data" / "flexible_barge" / "flexible_barge.nc"
MODES = ["bend_z1", "bend_z2", "twist1"]
# the barge as a uniform beam (examples/flexible_barge/responses.py): rho V, its rigid inertia about
# the reference point (the centre of mass), and each mode's Rayleigh modal mass and stiffness
MASS, INERTIA = 656000.0, [3990666.7, 87466666.7, 87466666.7]
MODAL_MASS = [164000.0, 164000.0, 1995333.0]
MODAL_STIFFNESS = [39106.55, 297151.3, 6168503.0]
MODAL_DAMPING = [2000.0, 5000.0, 1.0e5]
# viscous damping of the rigid DOFs (a force term beside the modes): the lightly damped roll and the
# free surge, sway and yaw forget their start within the runs
RIGID_DAMPING = [5.0e4, 5.0e4, 0.0, 1.7e6, 0.0, 1.0e7]
PTO_DAMPING = [2.0e4, 0.0, 0.0]     # a PTO on the first bending mode (bodies[i].modes.pto_damping)


@pytest.fixture(scope="module")
def barge() -> xr.Dataset:
    return load_hdb(HDB)


STRUCTURE = {"names": MODES, "mass": MODAL_MASS, "stiffness": MODAL_STIFFNESS, "damping": MODAL_DAMPING}


def barge_scene(*, dt: float, duration: float, waves=None, hydro=None, modes: dict | None = STRUCTURE, **keys) -> str:
    """The flexible barge's scene (the HDB's water), structure as above unless ``modes`` says (None:
    no ``modes`` key)."""
    structure = {} if modes is None else {"modes": modes}
    return scene_toml(dt=dt, duration=duration, water={"density": 1025.0}, waves=waves, hydro=hydro,
                      bodies=[body("barge", hdb=str(HDB), mass=MASS, center_of_mass=[0.0, 0.0, 0.0],
                                   inertia=INERTIA, **structure, **keys)])


def simulate(address: str, text: str, hdb: xr.Dataset, out: Path) -> xr.Dataset:
    scene = parse_scene(text)
    with ServerConnection(address, timeout=REPLY_S) as conn:
        setup = conn.hello(text, {str(HDB): hdb})
        with ResultWriter(out, scene=scene, scene_text=text, setup=setup) as writer:
            run(scene, text, conn, setup, writer, progress=False)
        conn.bye()
    return xr.load_dataset(out)


def structure_matrices() -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Mass, stiffness and damping of the structure over the 9 DOFs (rigid six, then the modes)."""
    m = np.diag([MASS] * 3 + INERTIA + MODAL_MASS)
    k = np.diag([0.0] * 6 + MODAL_STIFFNESS)
    c = np.diag([0.0] * 6 + MODAL_DAMPING)
    return m, k, c


# ------------------------------------------------------------------------------------ RAOs

@pytest.mark.parametrize("omega", [0.5, 0.9, 1.3, 1.6])
def test_every_rigid_and_modal_rao_matches_frequency_domain(server, barge, tmp_path, omega):
    """Regular waves from 30° (every DOF excited): each of the nine DOFs' steady amplitude and phase
    against (-w^2 (M + A(w)) - i w (B(w) + B_s + B_v) + C + K_s) X = F(w, 30°), solved here (B_v
    the rigid DOFs' linear_damping, B_s the modes' structural damping and their PTO's); the PTO's
    mean absorbed power 1/2 c w^2 |q|^2. Radiation
    "constant" (A and B at the wave's frequency, an HDB frequency) makes that the exact reference."""
    i = int(np.argmin(np.abs(barge["omega"].values - omega)))
    w = float(barge["omega"].values[i])
    m, k, c = structure_matrices()
    a, b = barge["added_mass"].values[i], barge["radiation_damping"].values[i]
    heading = int(np.argmin(np.abs(barge["wave_direction"].values - np.radians(30.0))))
    f = barge["excitation_force"].values[i, heading]
    c[:6, :6] += np.diag(RIGID_DAMPING)
    c[6:, 6:] += np.diag(PTO_DAMPING)
    z = -w ** 2 * (m + a) - 1j * w * (b + c) + barge["hydrostatic_stiffness"].values + k
    rao = np.linalg.solve(z, f)                   # per metre of amplitude, exp(-iwt)

    # a small wave (1 cm): the free yaw drifts from the start by the amplitude squared, and the
    # roll recorded about the global axes mixes with the pitch by that angle (5 % at 5 cm, 0.24 % at 1 cm)
    period = 2 * np.pi / w
    text = barge_scene(dt=period / 150, duration=30 * period, hydro={"radiation": "constant"},
                       waves=regular_waves(0.02, period, ramp=3 * period, direction=30.0),
                       linear_damping=RIGID_DAMPING, modes={**STRUCTURE, "pto_damping": PTO_DAMPING})
    ds = simulate(server, text, barge, tmp_path / "rao.nc")
    t = ds["time"].values
    motion = np.hstack([ds["position"].values[:, 0, :] - ds["equilibrium_position"].values[0],
                        ds["modal_position"].values])
    assert list(ds["mode"].values) == [f"barge.{n}" for n in MODES]
    fit = t >= t[-1] - 4 * period - 1e-9          # the last four periods
    # the free surge, sway and yaw may keep a slow drift from the start: a line in the fit
    basis = np.c_[np.cos(w * t[fit]), np.sin(w * t[fit]), np.ones(fit.sum()), t[fit]]
    coef = np.linalg.lstsq(basis, np.c_[motion[fit], ds["wave_elevation"].values[fit]], rcond=None)[0]
    phasor = coef[0] + 1j * coef[1]               # Re{X e^{-iwt}} = Xr cos + Xi sin
    measured = phasor[:9] / phasor[9]
    assert abs(phasor[9]) == pytest.approx(0.01, rel=1e-6)
    names = [str(d) for d in ds["dof"].values] + MODES
    live = np.abs(rao) > 1e-4 * np.abs(rao).max()   # a DOF the wave hardly moves has no phase to compare
    for j in np.flatnonzero(live):
        amp = abs(measured[j]) / abs(rao[j]) - 1
        phase = np.degrees(np.angle(measured[j] / rao[j]))
        print(f"w {w:.2f} {names[j]:8s} |RAO| {abs(rao[j]):.4e}  amplitude {amp:+.2e}  phase {phase:+.3f} deg")
        assert abs(amp) < 0.01, names[j]
        assert abs(phase) < 1.0, names[j]
    assert live[6:].all()                         # every mode takes part
    assert list(ds["pto"].values) == ["barge.bend_z1"]       # the modal PTO among the pto_* results
    power = ds["pto_power"].values[fit, 0].mean()
    expected = 0.5 * PTO_DAMPING[0] * w ** 2 * abs(rao[6] * 0.01) ** 2
    print(f"w {w:.2f} PTO on bend_z1: mean power {power:.4e} W, frequency domain {expected:.4e} W")
    assert power == pytest.approx(expected, rel=0.02)
    assert live.all() or w != 0.5                 # at 0.5 rad/s all nine DOFs are compared


def test_a_modal_pto_is_among_the_ptos_with_its_power_summed(server, barge, tmp_path):
    """A PTO on bend_z1 (spring and damper) and a line PTO on the heave: the results' dim ``pto``
    holds the line PTO then ``barge.bend_z1`` (attribute ``pto_modes`` naming the body and mode);
    the modal PTO's force, velocity and power equal k q + c q', q' and (k q + c q') q' computed here
    from the recorded modal coordinate and rate, every row; ``total_pto_power`` is the line PTO's
    power plus the mode's. Irregular waves, radiation off (the PTO law is what is checked)."""
    k_pto, c_pto = [5.0e3, 0.0, 0.0], [3.0e4, 0.0, 0.0]
    waves = {"type": "irregular", "spectrum": "jonswap", "hs": 1.0, "tp": 7.0, "direction": 30.0,
             "omega_range": [0.3, 1.8], "components": 40, "seed": 3, "ramp": 5.0}
    text = scene_toml(dt=0.05, duration=20.0, water={"density": 1025.0}, waves=waves, hydro={"radiation": "off"},
                      bodies=[body("barge", hdb=str(HDB), mass=MASS, center_of_mass=[0.0, 0.0, 0.0], inertia=INERTIA,
                                   dofs=["heave", "pitch"],
                                   modes={**STRUCTURE, "pto_stiffness": k_pto, "pto_damping": c_pto})],
                      ptos=[linear_pto("heave_pto", "barge", [0.0, 0.0, 0.0], "ground", [0.0, 0.0, -30.0],
                                       damping=2.0e5)])
    ds = simulate(server, text, barge, tmp_path / "pto.nc")
    assert list(ds["pto"].values) == ["heave_pto", "barge.bend_z1"]
    assert json.loads(ds.attrs["pto_modes"]) == {"barge.bend_z1": {"body": "barge", "mode": "bend_z1"}}
    q, rate = ds["modal_position"].values[:, 0], ds["modal_velocity"].values[:, 0]
    assert np.abs(rate).max() > 1e-3
    force = k_pto[0] * q + c_pto[0] * rate
    np.testing.assert_allclose(ds["pto_force"].values[:, 1], force, rtol=1e-12, atol=1e-12 * np.abs(force).max())
    np.testing.assert_array_equal(ds["pto_velocity"].values[:, 1], rate)
    np.testing.assert_allclose(ds["pto_power"].values[:, 1], force * rate, rtol=1e-12,
                               atol=1e-12 * np.abs(force * rate).max())
    line = ds["pto_power"].values[:, 0]
    assert np.abs(line).max() > 0
    np.testing.assert_allclose(ds["total_pto_power"].values, line + force * rate, rtol=1e-12,
                               atol=1e-12 * np.abs(line + force * rate).max())


def test_modal_free_decay_has_the_wet_natural_frequencies(server, barge, tmp_path):
    """Still water, radiation off, heave and pitch free, the modes displaced: each mode's motion is
    the sum of the undamped eigenmodes of (M + A∞, C + K) over heave, pitch and the modes, solved
    here; the wet first bending frequency is well below the dry sqrt(k/m)."""
    m, k, _ = structure_matrices()
    keep = [2, 4, 6, 7, 8]
    mass = (m + barge["added_mass_inf"].values)[np.ix_(keep, keep)]
    stiffness = (barge["hydrostatic_stiffness"].values + k)[np.ix_(keep, keep)]
    lam, vec = scipy.linalg.eig(stiffness, mass)
    wn = np.sqrt(lam.real)
    x0 = np.array([0.0, 0.0, 0.2, 0.0, 0.0])      # bend_z1 displaced 0.2
    amp = np.linalg.solve(vec.real, x0)           # x(t) = sum_k amp_k v_k cos(wn_k t)
    dt = 2 * np.pi / wn.max() / 80
    # the trapezoidal rule (the client's integrator) turns each mode at (2/h) atan(wn h / 2): exactly
    wd = 2 / dt * np.arctan(wn * dt / 2)
    text = barge_scene(dt=dt, duration=30.0, hydro={"radiation": "off"}, dofs=["heave", "pitch"],
                       modes={"names": MODES, "mass": MODAL_MASS, "stiffness": MODAL_STIFFNESS,
                              "initial_displacement": [0.2, 0.0, 0.0]})
    ds = simulate(server, text, barge, tmp_path / "decay.nc")
    t = ds["time"].values
    expected = (vec.real * amp) @ np.cos(np.outer(wd, t))
    got = np.vstack([ds["position"].values[:, 0, 2], ds["position"].values[:, 0, 4], ds["modal_position"].values.T])
    err = np.abs(got - expected).max(axis=1) / 0.2
    print("eigenfrequencies [rad/s]", np.round(np.sort(wn), 4), "error over 30 s / 0.2 (heave, pitch, modes)",
          err)
    assert np.abs(expected[0]).max() > 0.1 * 0.2          # heave takes part (its coupling to bend_z1)
    assert (err < 1e-4).all()
    j = int(np.argmax(np.abs(vec.real[2])))
    dry = np.sqrt(MODAL_STIFFNESS[0] / MODAL_MASS[0])
    assert wn[j] < 0.9 * dry or wn[j] > 1.1 * dry   # the water changes it (hydrostatics and added mass)


# ------------------------------------------------------------------------------------ the model

def test_a_rigid_body_keeps_six_dofs_and_no_modal_fields(barge):
    """A body whose HDB has six DOFs: no modes in the setup, no modal fields in the reply, and its
    forces equal the flexible body's rigid rows when the modes are at rest and uncoupled (the same
    HDB with the mode rows and columns dropped)."""
    rigid = barge.isel(influenced_dof=slice(0, 6), radiating_dof=slice(0, 6))
    rigid = rigid.assign_coords(influenced_dof=barge["influenced_dof"].values[:6],
                                radiating_dof=barge["radiating_dof"].values[:6])
    text = barge_scene(dt=0.1, duration=10.0, waves=regular_waves(1.0, 8.0, direction=30.0), modes=None)
    scene = parse_scene(text)
    model = HydroModel(scene, {"barge": rigid}, compiled=False)
    assert model.setup_info().modes is None and model.n == 6
    x = model.setup_info().equilibrium_position + 0.01
    reply = model.step(0.0, x, np.full((1, 6), 0.1))
    assert not any(k.startswith("modal_") for k in reply)
    assert reply["excitation"].shape == (1, 6)


@pytest.mark.parametrize("compiled", [False, True])
def test_modal_forces_are_the_hdb_rows(barge, compiled):
    """The model's step over 6 + 3 DOFs: the hydrostatic force of every row is -C (x - x_eq) with the
    HDB's full C (rigid-mode coupling), the excitation the HDB's at the wave's frequency; the
    compiled step and the numpy path agree."""
    period = 2 * np.pi / 0.8
    scene = parse_scene(barge_scene(dt=0.1, duration=10.0, waves=regular_waves(2.0, period, direction=30.0),
                                    hydro={"radiation": "off"}))
    model = HydroModel(scene, {"barge": barge}, compiled=compiled)
    if compiled:
        pytest.importorskip("numba")
        assert model._fused is not None
    x_eq = model.setup_info().equilibrium_position
    dx, q = np.array([[0.1, -0.2, 0.3, 0.01, -0.02, 0.03]]), np.array([0.05, -0.04, 0.02])
    reply = model.step(0.0, x_eq + dx, np.zeros((1, 6)), modal_position=q, modal_velocity=np.zeros(3))
    full = np.r_[dx.ravel(), q]
    c = barge["hydrostatic_stiffness"].values
    hs = np.r_[reply["hydrostatic"].ravel(), reply["modal_hydrostatic"]]
    np.testing.assert_allclose(hs, -c @ full, rtol=1e-12, atol=1e-9 * np.abs(c @ full).max())
    i = int(np.argmin(np.abs(barge["omega"].values - 0.8)))
    f = np.r_[reply["excitation"].ravel(), reply["modal_excitation"]]
    np.testing.assert_allclose(f, 1.0 * barge["excitation_force"].values[i, 1].real, rtol=1e-9,
                               atol=1e-9 * np.abs(f).max())


def test_bad_mode_input_names_the_key(barge):
    period = 8.0
    waves = regular_waves(1.0, period)
    no_structure = barge_scene(dt=0.1, duration=1.0, waves=waves, modes=None)
    with pytest.raises(ModelError) as e:
        HydroModel(parse_scene(no_structure), {"barge": barge}, compiled=False)
    assert e.value.key == "bodies[0].modes" and "modal mass" in str(e.value)
    wrong = {"names": ["bend_z1", "bend_z9", "twist1"], "mass": MODAL_MASS}
    with pytest.raises(ModelError) as e:
        HydroModel(parse_scene(barge_scene(dt=0.1, duration=1.0, waves=waves, modes=wrong)), {"barge": barge},
                   compiled=False)
    assert e.value.key == "bodies[0].modes.names" and "bend_z9" in str(e.value) and "bend_z2" in str(e.value)
    for modes, key in (({"names": MODES, "mass": [1.0, 0.0, 1.0]}, "bodies[0].modes.mass"),
                       ({"names": MODES, "mass": [[1.0, 1.0, 0.0], [1.0, 1.0, 0.0], [0.0, 0.0, 1.0]]},
                        "bodies[0].modes.mass"),
                       ({"names": MODES, "mass": [1.0, 1.0]}, "bodies[0].modes.mass"),
                       ({"names": MODES, "mass": MODAL_MASS, "stiffness": [1.0]}, "bodies[0].modes.stiffness"),
                       ({"names": MODES, "mass": MODAL_MASS, "pto_damping": [1.0, 0.0]}, "bodies[0].modes.pto_damping"),
                       ({"names": MODES, "mass": MODAL_MASS, "initial_displacement": [0.1]},
                        "bodies[0].modes.initial_displacement"),
                       ({"names": ["a", "a"], "mass": [1.0, 1.0]}, "bodies[0].modes.names")):
        with pytest.raises(SceneError) as e:
            parse_scene(barge_scene(dt=0.1, duration=1.0, waves=waves, modes=modes))
        assert key in str(e.value), (modes, str(e.value))


def test_a_step_without_the_modal_state_is_refused(served, barge):
    """The wire (SPEC §5.2, revision 1.15): a session with modes needs modal_position/velocity; a
    step sent again with another modal state is refused as a retry and taken as an iteration."""
    address = served()
    text = barge_scene(dt=0.1, duration=1.0, waves=regular_waves(1.0, 8.0))
    with ServerConnection(address, timeout=REPLY_S) as conn:
        setup = conn.hello(text, {str(HDB): barge})
        assert setup.modes == {"barge": MODES} and setup.n_dofs == 9
        assert setup.added_mass.shape == (9, 9)
        with pytest.raises(RemoteError) as e:
            conn.step(0, 0.0, setup.equilibrium_position, np.zeros((1, 6)))
        assert e.value.field == "modal_position"
        reply = conn.step(0, 0.0, setup.equilibrium_position, np.zeros((1, 6)), modal=(np.zeros(3), np.zeros(3)))
        assert reply["modal_excitation"].shape == (3,)
        # a retry of the same step with another modal state is not a retry (SPEC §5.3)
        with pytest.raises(RemoteError) as e:
            conn.step(0, 0.0, setup.equilibrium_position, np.zeros((1, 6)), modal=(np.full(3, 0.1), np.zeros(3)))
        assert e.value.field == "iteration"
        again = conn.step(0, 0.0, setup.equilibrium_position, np.zeros((1, 6)), iteration=1,
                          modal=(np.full(3, 0.1), np.zeros(3)))
        c = barge["hydrostatic_stiffness"].values[6:, 6:]
        np.testing.assert_allclose(again["modal_hydrostatic"], -c @ np.full(3, 0.1), rtol=1e-12)
        conn.bye()


# ------------------------------------------------------------------------------------ a WAMIT set

GBM = HDB.parents[1] / "wamit_gbm_barge"
# WEC-Sim's GBM barge (80 x 10 m, NEWMDS = 4): its .frc's external mass and stiffness (IALTFRC = 2),
# rigid and modal, as a scene gives them
GBM_MASS, GBM_INERTIA = 4.0e6, [6.666667e7, 2.166667e9, 2.166667e9]
GBM_MODES = {"names": ["mode1", "mode2", "mode3", "mode4"], "mass": [1.079216e6, 1.209976e6, 2.391821e6, 1.830601e6],
             "stiffness": [6.077064e6, 4.382532e7, 2.741026e8, 4.664370e8]}


def test_a_wamit_run_s_modes_simulate_to_the_frequency_domain_rao(server, tmp_path):
    """WEC-Sim's WAMIT barge (examples/data/wamit_gbm_barge: modes read as mode1..mode4 after the
    six) with its .frc structure, head seas at 0.59 rad/s (a period of the run), surge, heave, pitch
    and the four modes free, radiation "constant": each DOF's RAO against the frequency-domain
    solution of the same HDB within 1 % and 1°."""
    hdb = load_hdb(GBM / "barge.1", rho=1000.0, wamit={"iperout": 1})
    i = int(np.argmin(np.abs(hdb["omega"].values - 0.59)))
    w = float(hdb["omega"].values[i])
    free = [0, 2, 4, 6, 7, 8, 9]
    m = np.diag([GBM_MASS] * 3 + GBM_INERTIA + GBM_MODES["mass"])
    k = np.diag([0.0] * 6 + GBM_MODES["stiffness"])
    c = np.diag([2.0e5] + [0.0] * 9)                 # the free surge's viscous damping
    z = (-w ** 2 * (m + hdb["added_mass"].values[i]) - 1j * w * (hdb["radiation_damping"].values[i] + c)
         + hdb["hydrostatic_stiffness"].values + k)[np.ix_(free, free)]
    rao = np.linalg.solve(z, hdb["excitation_force"].values[i, 0, free])
    period = 2 * np.pi / w
    text = scene_toml(dt=period / 150, duration=30 * period, water={"density": 1000.0, "depth": "inf"},
                      waves=regular_waves(0.02, period, ramp=3 * period), hydro={"radiation": "constant"},
                      bodies=[body("barge", hdb=str(GBM / "barge.1"), mass=GBM_MASS, center_of_mass=[0.0, 0.0, 0.0],
                                   inertia=GBM_INERTIA, dofs=["surge", "heave", "pitch"], modes=GBM_MODES,
                                   linear_damping=[2.0e5, 0, 0, 0, 0, 0])])
    scene = parse_scene(text)
    with ServerConnection(server, timeout=REPLY_S) as conn:
        setup = conn.hello(text, {str(GBM / "barge.1"): hdb})
        with ResultWriter(tmp_path / "gbm.nc", scene=scene, scene_text=text, setup=setup) as writer:
            run(scene, text, conn, setup, writer, progress=False)
        conn.bye()
    ds = xr.load_dataset(tmp_path / "gbm.nc")
    t = ds["time"].values
    rigid = ds["position"].values[:, 0, :] - ds["equilibrium_position"].values[0]
    motion = np.hstack([rigid[:, [0, 2, 4]], ds["modal_position"].values])
    fit = t >= t[-1] - 4 * period - 1e-9
    basis = np.c_[np.cos(w * t[fit]), np.sin(w * t[fit]), np.ones(fit.sum()), t[fit]]
    coef = np.linalg.lstsq(basis, np.c_[motion[fit], ds["wave_elevation"].values[fit]], rcond=None)[0]
    phasor = coef[0] + 1j * coef[1]
    measured = phasor[:-1] / phasor[-1]
    for j, name in enumerate(["surge", "heave", "pitch", *GBM_MODES["names"]]):
        amp, phase = abs(measured[j]) / abs(rao[j]) - 1, np.degrees(np.angle(measured[j] / rao[j]))
        print(f"GBM w {w:.3f} {name:6s} |RAO| {abs(rao[j]):.3e}  amplitude {amp:+.2e}  phase {phase:+.3f} deg")
        assert abs(amp) < 0.01 and abs(phase) < 1.0, name


def test_two_flexible_bodies_keep_their_modes_apart(barge):
    """Two bodies of the same modal HDB (interaction "none"): the vector is both bodies' six, then
    b1's three modes, then b2's; each body's modal hydrostatic force follows its own modal state and
    its own rigid motion only (-C of its own block), and the setup names both bodies' modes."""
    bodies = [body(name, hdb=str(HDB), hdb_body="barge", mass=MASS, center_of_mass=[0.0, 0.0, 0.0], inertia=INERTIA,
                   modes=STRUCTURE) for name in ("b1", "b2")]
    scene = parse_scene(scene_toml(dt=0.1, duration=1.0, water={"density": 1025.0}, waves=regular_waves(1.0, 8.0),
                                   hydro={"radiation": "off", "interaction": "none"}, bodies=bodies))
    model = HydroModel(scene, {"b1": barge, "b2": barge}, compiled=False)
    setup = model.setup_info()
    assert setup.modes == {"b1": MODES, "b2": MODES} and setup.n_dofs == 18
    assert setup.mode_labels == tuple(f"{b}.{m}" for b in ("b1", "b2") for m in MODES)
    dx = np.array([[0.0, 0.0, 0.1, 0.0, 0.02, 0.0], [0.0, 0.0, -0.2, 0.0, 0.01, 0.0]])
    q = np.array([0.05, -0.04, 0.02, -0.03, 0.01, 0.06])
    reply = model.step(0.0, setup.equilibrium_position + dx, np.zeros((2, 6)), modal_position=q,
                       modal_velocity=np.zeros(6))
    c = barge["hydrostatic_stiffness"].values
    for k in range(2):
        own = -c @ np.r_[dx[k], q[3 * k:3 * k + 3]]
        np.testing.assert_allclose(reply["hydrostatic"][k], own[:6], atol=1e-9 * np.abs(own).max())
        np.testing.assert_allclose(reply["modal_hydrostatic"][3 * k:3 * k + 3], own[6:], rtol=1e-12)
