"""Bodies held to ground by a fixed joint, left out of Exudyn's system (clients/exudyn/mechanism.py,
"Held bodies"): the flap of the OSWEC case (F3OF's base held, flap 1 on its hinge) against the
frequency-domain response of the flap's one DOF, and against the full form (``[client] reduce =
false``: the base integrated under its fixed joint); a dry held base's reaction against statics; the
scenes the rule leaves in the system.

Frequency-domain reference: the flap's body DOFs (surge, heave, pitch at its CoG = the HDB's reference
point, 5.5 m below the hinge) are u = t p, t = (-5.5, 0, 1), p the hinge angle, so

    p = t'X a / t'[-w^2 (M + A_eff) - i w B_eff + C] t        (exp(-iwt), a the wave amplitude)

over the flap's own 3 x 3 blocks of the HDB (the base does not move: its coupling blocks multiply
zero), A_eff, B_eff what the truncated, sampled convolution realises (tests/test_f3of.py
``body_system``: its 40 s of memory, as the scenes here).
"""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

from conftest import body, joint, linear_pto, regular_waves, scene_toml

from hydrolink.clients.exudyn.client import build_model, result_bodies, run
from hydrolink.clients.exudyn.mechanism import held_bodies
from hydrolink.clients.lockstep.results import ResultWriter
from hydrolink.clients.run import run_scene_file
from hydrolink.protocol.scene import parse_scene

sys.path.insert(0, str(Path(__file__).parent))
from test_f3of import AMPLITUDE as F3OF_AMPLITUDE, IRF, SPEC, body_system, hdb  # noqa: E402,F401 - its HDB fixture

G = 9.81
M_FLAP, I_FLAP = 179250.0, 1.3e6          # tests/test_f3of.py's flap
HINGE_DEPTH = 5.5            # CoG below the hinge
AMPLITUDE = 0.5
FULL = {"type": "exudyn", "reduce": False}


def oswec(tmp_path: Path, name: str, *, period: float, dt: float, duration: float, full: bool = False,
          friction: dict | None = None) -> Path:
    """bench/bench_suite.py's OSWEC (F3OF's base held, flap 1 on a hinge about y) at these times;
    ``friction`` on the hinge."""
    hdb_path = SPEC.as_posix()
    text = scene_toml(dt=dt, duration=duration, progress=False, water={"density": 1025.0, "depth": "inf"},
                      waves=regular_waves(2 * AMPLITUDE, period, ramp=40.0), hydro={"irf_duration": IRF},
                      bodies=[body("base", mass=1089825.0, center_of_mass=[0.0, 0.0, -9.0],
                                   inertia=[7.63e7, 7.63e7, 2.0e7], hdb=hdb_path),
                              body("flap1", mass=M_FLAP, center_of_mass=[-12.5, 0.0, -5.5],
                                   inertia=[5.85e6, I_FLAP, 4.58e6], hdb=hdb_path)],
                      joints=[joint("revolute", "base", "flap1", [-12.5, 0.0, 0.0], name="hinge", axis=[0.0, 1.0, 0.0],
                                    **({"friction": friction} if friction else {})),
                              joint("fixed", "ground", "base", [0.0, 0.0, -9.0], name="hold")],
                      client=FULL if full else None)
    path = tmp_path / f"{name}.toml"
    path.write_text(text)
    return path


def flap_response(hdb, w: float, dt: float) -> complex:
    """The hinge angle's complex amplitude (module docstring): the flap's block of
    tests/test_f3of.py's nine-DOF system (its effective A and B at ``dt``, its wave amplitude)."""
    z, x = body_system(hdb, w, dt)
    tm = np.array([-HINGE_DEPTH, 0.0, 1.0])
    flap = slice(3, 6)
    return complex(tm @ x[flap] * (AMPLITUDE / F3OF_AMPLITUDE) / (tm @ z[flap, flap] @ tm))


@pytest.mark.parametrize("period", [7.0, 10.0])
def test_flap_pitch_matches_the_frequency_domain(hdb, tmp_path, period):
    """The held-base run's steady hinge angle: amplitude within 1 %, phase within 1 deg of the
    one-DOF frequency-domain response (measured: 0.39 % / -0.16 deg at T = 7 s, 0.34 % / 0.06 deg at
    10 s; 0.06 % with 30 s of memory, inside the HDB grid's alias-free 31 s); the base does not
    move at all."""
    dt = period / 100
    scene = oswec(tmp_path, "flap", period=period, dt=dt, duration=250.0)
    summary = run_scene_file(scene, tmp_path / "flap.nc", progress=False)
    assert any("held to ground" in note for note in summary.mechanism_notes)
    ds = xr.load_dataset(tmp_path / "flap.nc")
    w = 2 * np.pi / period
    t = ds["time"].values
    sel = t > t[-1] - 10 * period + 1e-9
    d = (ds["position"] - ds["equilibrium_position"])
    p = d.sel(body="flap1", dof="pitch").values[sel]
    basis = np.c_[np.cos(w * t[sel]), np.sin(w * t[sel]), np.ones(sel.sum())]
    c = np.linalg.lstsq(basis, p, rcond=None)[0]
    td, fd = c[0] + 1j * c[1], flap_response(hdb, w, dt)
    print(f"T = {period:g} s: hinge angle {np.degrees(abs(td)):.4f} deg, frequency domain {np.degrees(abs(fd)):.4f}; "
          f"phase {np.degrees(np.angle(td / fd)):.3f} deg")
    assert abs(abs(td) / abs(fd) - 1) < 0.01
    assert abs(np.degrees(np.angle(td / fd))) < 1.0
    assert np.abs(d.sel(body="base").values).max() == 0.0
    # the hinge keeps the CoG on its circle (surge -5.5 sin p, heave 5.5 (1 - cos p)) to Newton's tolerance
    pa = d.sel(body="flap1", dof="pitch").values
    np.testing.assert_allclose(d.sel(body="flap1", dof="surge").values, -HINGE_DEPTH * np.sin(pa), atol=1e-7)
    np.testing.assert_allclose(d.sel(body="flap1", dof="heave").values, HINGE_DEPTH * (1 - np.cos(pa)), atol=1e-7)


@pytest.mark.parametrize("friction", [None, {"force": 2.0e5, "velocity": 1.0e-2}], ids=["free", "friction"])
def test_held_base_equals_the_full_form(hdb, tmp_path, friction):
    """Against the full form (the base integrated under its fixed joint, Exudyn's Lagrange
    multipliers for both joints): the motion and forces to round-off, the reactions' forces and the
    hold's moments to 1e-3 of their largest value (the full form's multipliers carry a step-to-step alternation of the
    undamped trapezoidal rule on its 11 constraints, growing to ~1e-4 in 20 s). With friction on the
    hinge the held base's reaction takes the friction torque with the hinge's load (``joint_force``:
    the constraint's reaction plus the friction), as the full form's multipliers do."""
    runs = {}
    for full in (False, True):
        name = "full" if full else "held"
        scene = oswec(tmp_path, name, period=8.0, dt=0.03, duration=20.0, full=full, friction=friction)
        summary = run_scene_file(scene, tmp_path / f"{name}.nc", progress=False)
        assert any("held to ground" in note for note in summary.mechanism_notes) != full
        runs[name] = xr.load_dataset(tmp_path / f"{name}.nc")
    a, b = runs["held"], runs["full"]
    for v in ("position", "velocity", "radiation_force", "hydrostatic_force", "excitation_force"):
        scale = float(np.abs(b[v]).max())
        assert float(np.abs(a[v] - b[v]).max()) <= 1e-8 * scale, v
    fa, fb = a["joint_force"].values, b["joint_force"].values
    forces = np.abs(fb[:, :, :3]).max()
    assert np.abs(fa[:, :, :3] - fb[:, :, :3]).max() <= 1e-3 * forces
    assert np.abs(fa[:, 0, 3:] - fb[:, 0, 3:]).max() <= 1e-3 * forces     # the hinge's moments (about x, z: ~0)
    moments = np.abs(fb[:, 1, 3:]).max()                                     # the hold's (about y: ~1e6 N m)
    assert np.abs(fa[:, 1, 3:] - fb[:, 1, 3:]).max() <= 1e-3 * moments
    assert float(a["joint_violation"].sel(joint="hold").max()) == 0.0


def dry_scene(tmp_path: Path, client: dict | None, bob: list[float]) -> xr.Dataset:
    """A dry base (5 kg, CoG (0.3, 0, -0.5)) held at the origin and a 2 kg bob (CoG ``bob``) hanging
    from a hinge about y at (1, 0, 0): at rest."""
    text = scene_toml(dt=0.002, duration=0.02, progress=False, client=client,
                      bodies=[body("base", mass=5.0, center_of_mass=[0.3, 0.0, -0.5], inertia=[1.0, 1.0, 1.0]),
                              body("bob", mass=2.0, center_of_mass=bob, inertia=[0.02, 0.02, 0.02])],
                      joints=[joint("fixed", "ground", "base", [0.0, 0.0, 0.0], name="hold"),
                              joint("revolute", "base", "bob", [1.0, 0.0, 0.0], name="hinge", axis=[0.0, 1.0, 0.0])])
    scene = parse_scene(text)
    names, ref = result_bodies(scene, None)
    out = tmp_path / f"dry{client is not None}.nc"
    with ResultWriter(out, scene=scene, scene_text=text, dt=0.002, bodies=names, equilibrium_position=ref) as writer:
        run(scene, text, None, None, writer, progress=False)
    return xr.load_dataset(out)


@pytest.mark.parametrize("bob", [[1.0, 0.0, -1.0], [1.0, 0.5, -1.0]], ids=["below", "off-axis"])
def test_held_dry_base_reaction_is_statics(tmp_path, bob):
    """The held base's reaction carries both weights, and their moment about the joint point, the
    hinge the bob's weight and its moment (about x where the bob's CoG is off along the axis: the
    held reaction adds the hinge's reported moment); forces and moments equal the full form's
    (Exudyn's multipliers)."""
    held, full = dry_scene(tmp_path, None, bob), dry_scene(tmp_path, FULL, bob)
    f = held["joint_force"].sel(joint="hold").values[-1]
    w_base, w_bob = 5.0 * G, 2.0 * G
    np.testing.assert_allclose(f[:3], [0.0, 0.0, w_base + w_bob], atol=1e-9)
    moment = np.cross([0.3, 0.0, -0.5], [0.0, 0.0, -w_base]) + np.cross(bob, [0.0, 0.0, -w_bob])
    np.testing.assert_allclose(f[3:], -moment, atol=1e-9)          # on the base from ground: balances the weights'
    hinge = -np.cross(np.subtract(bob, [1.0, 0.0, 0.0]), [0.0, 0.0, -w_bob])
    np.testing.assert_allclose(held["joint_force"].sel(joint="hinge").values[-1], [0, 0, w_bob, *hinge], atol=1e-9)
    np.testing.assert_allclose(full["joint_force"].values, held["joint_force"].values, atol=1e-9)


HOLD = joint("fixed", "ground", "base", [0.0, 0.0, 0.0])
HINGE = joint("revolute", "base", "bob", [1.0, 0.0, 0.0], axis=[0.0, 1.0, 0.0])


@pytest.mark.parametrize("joints, ptos, held, kinds", [
    ([HOLD, HINGE], [], {"base": 0}, ("held", "rigid")),
    ([HOLD, {**HINGE, "friction": {"force": 1.0}}], [], {"base": 0}, ("held", "rigid")),   # friction: in the hinge's load
    ([HOLD, joint("fixed", "base", "bob", [1.0, 0.0, 0.0])], [], {"base": 0}, ("held", "rigid")),  # bob: not to ground
    ([HOLD, HINGE], [linear_pto("p", "base", [0.0, 0.0, 0.0], "bob", [1.0, 0.0, -1.0], damping=1.0)], {},
     ("rigid", "rigid")),                                              # a PTO's load on the base: kept
    ([HOLD, HINGE, joint("spherical", "ground", "base", [0.0, 0.0, 0.0])], [], {}, None),   # redundant: kept
])
def test_which_bodies_are_held(joints, ptos, held, kinds):
    """A body held by one fixed joint to ground is left out (with friction on a joint to it too); one
    a PTO acts on, or held redundantly (the full form reports it), is kept; a fixed joint between two bodies holds neither."""
    text = scene_toml(dt=0.01, duration=0.1, progress=False, joints=joints, ptos=ptos or None,
                      bodies=[body("base", mass=5.0, center_of_mass=[0.3, 0.0, -0.5], inertia=[1.0, 1.0, 1.0]),
                              body("bob", mass=2.0, center_of_mass=[1.0, 0.0, -1.0], inertia=[0.02, 0.02, 0.02])])
    scene = parse_scene(text)
    assert held_bodies(scene) == held
    if kinds is not None:
        model = build_model(scene, None)
        assert tuple(model.mechanism.handles[n].kind for n in ("base", "bob")) == kinds
        model.close()


def test_a_held_body_with_nothing_else_on_it(tmp_path):
    """A held base that no other joint touches: its reaction is its own weight and that weight's
    moment about the joint point (the bob beside it falls freely)."""
    text = scene_toml(dt=0.002, duration=0.01, progress=False, joints=[HOLD],
                      bodies=[body("base", mass=5.0, center_of_mass=[0.3, 0.0, -0.5], inertia=[1.0, 1.0, 1.0]),
                              body("bob", mass=2.0, center_of_mass=[1.0, 0.0, -1.0], inertia=[0.02, 0.02, 0.02])])
    scene = parse_scene(text)
    names, ref = result_bodies(scene, None)
    with ResultWriter(tmp_path / "lone.nc", scene=scene, scene_text=text, dt=0.002, bodies=names,
                      equilibrium_position=ref) as writer:
        run(scene, text, None, None, writer, progress=False)
    f = xr.load_dataset(tmp_path / "lone.nc")["joint_force"].values[:, 0]
    w = 5.0 * G
    np.testing.assert_allclose(f, np.tile([0.0, 0.0, w, 0.0, -0.3 * w, 0.0], (len(f), 1)), atol=1e-12)
