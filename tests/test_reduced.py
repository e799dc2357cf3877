"""Reduced bodies (clients/exudyn/mechanism.py, "Reduced bodies"): a body built with its active coordinates
only, against analytic motions (dry scenes, no server) and against the full form — a 6-DOF rigid
body whose locked DOFs are coordinate constraints (``[client] reduce = false``) — on wet scenes
(real server, real HDBs). The full form is the independent model here: rigid-body node, constraints
and hydrodynamic object over the node's six coordinates; the two must agree to round-off.

The wet bodies themselves are checked against independent references elsewhere with the default
(reduced) build: tests/test_exudyn_client.py (heave-only sphere: Cummins free decay, RAO) and
tests/test_rm3.py (float + spar heave with the PTO: frequency-domain solution).
"""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
import xarray as xr

import exudyn as exu

from conftest import REPLY_S, rm3_example_text
from conftest import (SPHERE_WATER, body, joint, linear_pto, regular_waves, scene_toml, sphere_body,
                      toml_document)

from hydrolink.clients.lockstep.connection import ServerConnection
from hydrolink.clients.exudyn.client import build_model, result_bodies, run
from hydrolink.clients.exudyn.mechanism import build_mechanism, marker_at
from hydrolink.clients.lockstep.results import ResultWriter
from hydrolink.protocol.scene import DOF_NAMES, SceneError, parse_scene

REPO = Path(__file__).resolve().parents[1]
G, RHO = 9.81, 1000.0
AGREE = 1e-10        # reduced vs full: relative to each variable's largest magnitude


def run_scene(text: str, out: Path, address: str | None = None, hdbs: dict | None = None) -> tuple[dict, xr.Dataset]:
    """One run through the Exudyn client (the real server at ``address`` when a body is wet)."""
    scene = parse_scene(text)
    if address is None:
        names, ref = result_bodies(scene, None)
        with ResultWriter(out, scene=scene, scene_text=text, dt=scene.simulation.dt, bodies=names,
                          equilibrium_position=ref) as writer:
            summary = run(scene, text, None, None, writer, progress=False)
        return summary, xr.load_dataset(out)
    with ServerConnection(address, timeout=REPLY_S) as conn:
        setup = conn.hello(text, hdbs)
        with ResultWriter(out, scene=scene, scene_text=text, setup=setup) as writer:
            summary = run(scene, text, conn, setup, writer, progress=False)
        conn.bye()
    return summary, xr.load_dataset(out)


def both_forms(scene: dict | str, tmp_path: Path, **kw) -> tuple[dict, xr.Dataset, dict, xr.Dataset]:
    """The scene (``scene_toml`` sections, or scene text without [client]) run reduced and full:
    (summary, results) of each."""
    runs = []
    for reduce in (True, False):
        client = {"type": "exudyn", "reduce": reduce}
        text = (scene + toml_document({"client": client}) if isinstance(scene, str)
                else scene_toml(**scene, client=client))
        runs += run_scene(text, tmp_path / f"reduce_{reduce}.nc", **kw)
    return tuple(runs)


def disagreement(a: xr.Dataset, b: xr.Dataset) -> dict[str, float]:
    """max |a - b| / max |b| of every floating-point result variable (positions from equilibrium)."""
    out = {}
    for name, var in b.data_vars.items():
        if var.dtype.kind != "f":
            continue
        x, y = a[name].values, var.values
        if name == "position":
            x, y = x - a["equilibrium_position"].values, y - b["equilibrium_position"].values
        scale = float(np.abs(y).max(initial=0.0))
        out[name] = float(np.abs(x - y).max(initial=0.0)) / (scale if scale > 0 else 1.0)
    return out


def assert_agree(red: xr.Dataset, full: xr.Dataset) -> None:
    assert red.attrs["status"] == full.attrs["status"] == "complete"
    assert set(red.data_vars) == set(full.data_vars)
    worst = disagreement(red, full)
    top = max(worst, key=worst.get)
    print(f"reduced vs full: worst {top} {worst[top]:.2e} (relative to its largest magnitude)")
    assert worst[top] < AGREE, worst


# ------------------------------------------------------------------ dry scenes: analytic motions

def dry_scene(bodies: list[dict], *, dt: float = 0.01, duration: float = 0.1, **sections) -> dict:
    return dict(dt=dt, duration=duration, progress=False, water={"density": RHO, "gravity": G}, bodies=bodies,
                **sections)


def test_heave_slider_on_a_pto_spring_oscillates_about_its_buoyant_equilibrium(tmp_path):
    """A dry heave-only body (centre of mass off its reference point) hangs on a vertical linear PTO
    spring to ground, with buoyancy: z(t) about z_eq = (rho g V - m g)/k at omega = sqrt(k/m)."""
    m, k, vol, z0, v0 = 50.0, 8.0e3, 0.02, 0.01, -0.05
    buoy = body("buoy", mass=m, center_of_mass=[0.4, -0.3, -0.5], reference_point=[0.0, 0.0, 0.0],
                inertia=[2.0, 3.0, 4.0], dofs=["heave"], buoyancy_volume=vol, center_of_buoyancy=[0.1, 0.2, -0.2],
                initial_displacement=[0, 0, z0, 0, 0, 0], initial_velocity=[0, 0, v0, 0, 0, 0])
    spring = linear_pto("spring", "buoy", [0.3, 0.1, -0.4], "ground", [0.3, 0.1, -2.4], stiffness=k, damping=0.0)
    s_red, red, s_full, full = both_forms(dry_scene([buoy], dt=1e-3, duration=2.0, ptos=[spring]), tmp_path)
    assert_agree(red, full)
    assert any("'buoy' (heave)" in n for n in s_red.mechanism_notes)
    assert not any("reduced bodies" in n for n in s_full.mechanism_notes)
    t = red["time"].values
    w, z_eq = math.sqrt(k / m), (RHO * G * vol - m * G) / k
    z_ref = z_eq + (z0 - z_eq) * np.cos(w * t) + v0 / w * np.sin(w * t)
    pos = red["position"].values[:, 0] - red["equilibrium_position"].values[0]
    amp, h = math.hypot(z0 - z_eq, v0 / w), 1e-3
    phase = w * t[-1] * (w * h) ** 2 / 12          # the trapezoidal rule's period stretch, accumulated
    np.testing.assert_allclose(pos[:, 2], z_ref, atol=1.2 * amp * phase)
    locked = [0, 1, 3, 4, 5]
    assert not pos[:, locked].any() and not red["velocity"].values[:, 0, locked].any()   # exactly zero
    # the PTO's outputs: the line runs from the body down to ground, so its extension is the heave z and
    # the tension k z pulls the body down (the restoring force above)
    np.testing.assert_allclose(red["pto_force"].values[:, 0], k * pos[:, 2], rtol=1e-9, atol=1e-9 * k)


def test_reduced_translations_rotation_and_velocity_constraint_move_as_free_body(tmp_path):
    """A dry body with surge, heave, pitch active (centre of mass on the pitch axis through the
    reference point: the reduced form is exact) and a velocity constraint on surge: surge at the
    constraint's rate, heave falling at g - rho g V / m, pitch at its initial rate (no moment)."""
    m, vol, w0 = 20.0, 0.005, 0.7
    b = body("b", mass=m, center_of_mass=[1.0, 0.6, 2.0], reference_point=[1.0, 0.0, 2.0],
             inertia=[[2.0, 0.1, 0.2], [0.1, 3.0, 0.3], [0.2, 0.3, 4.0]], dofs=["surge", "heave", "pitch"],
             buoyancy_volume=vol, initial_velocity=[0, 0, 0.2, 0, w0, 0])
    surge_rate = {"body": "b", "dof": "surge", "type": "velocity", "value": 0.3}
    s_red, red, _, full = both_forms(dry_scene([b], duration=1.0, constraints=[surge_rate]), tmp_path)
    assert_agree(red, full)
    assert any("'b' (surge+heave+pitch)" in n for n in s_red.mechanism_notes)
    t = red["time"].values
    pos = red["position"].values[:, 0] - red["equilibrium_position"].values[0]
    a = RHO * G * vol / m - G
    np.testing.assert_allclose(pos[:, 0], 0.3 * t, atol=1e-12)
    np.testing.assert_allclose(pos[:, 2], 0.2 * t + 0.5 * a * t * t, atol=1e-12)   # exact for the trapezoidal rule
    np.testing.assert_allclose(pos[:, 4], w0 * t, atol=1e-12)
    assert not pos[:, [1, 3, 5]].any()


def dry_body(name: str = "b", dofs=("heave",), com=(0.0, 0.0, 0.0)) -> dict:
    return body(name, mass=10.0, center_of_mass=list(com), reference_point=[0.0, 0.0, 0.0], inertia=[1.0, 1.0, 1.0],
                dofs=list(dofs))


@pytest.mark.parametrize("sections, why", [
    (dry_scene([dry_body(), dry_body("c", dofs=DOF_NAMES)], joints=[joint("spherical", "b", "c", [0, 0, 0])]),
     "joints[0] needs its pose"),
    (dry_scene([dry_body()], moorings=[{"type": "linear", "body": "b", "point": [0, 0, 0],
                                        "stiffness": [0, 0, 100, 0, 0, 0]}]), "moorings[0] needs its pose"),
    (dry_scene([dry_body(dofs=("heave", "pitch"))], ptos=[linear_pto("p", "b", [0, 0, 0], "ground", [0, 0, -1],
                                                                     stiffness=10.0)]), "ptos[0] needs its pose"),
    (dry_scene([dry_body(dofs=("roll", "pitch"))]), "roll and pitch are active"),
    (dry_scene([dry_body(dofs=("surge", "pitch"), com=(0.0, 0.0, -0.5))]), "centre of mass is 0.5 m off the pitch axis"),
    (dry_scene([dry_body(dofs=("pitch",), com=(0.2, 0.0, 0.0))]), "the gravity moment depends on the angle"),
    (dry_scene([dry_body(dofs=DOF_NAMES)]), None),
])
def test_what_needs_a_full_rigid_body(sections, why):
    scene = parse_scene(scene_toml(**sections))
    mbs = exu.SystemContainer().AddSystem()
    mech = build_mechanism(mbs, scene, {}, reduce=True)
    assert mech.handles["b"].kind == "rigid" and mech.handles["b"].dofs is None
    assert not mech.reductions
    if why is None:
        assert mech.full_bodies == {}
    else:
        assert why in mech.full_bodies["b"]


def test_reduced_bodies_take_no_marker_frame():
    text = scene_toml(**dry_scene([dry_body("s"), dry_body("r", dofs=("surge", "heave"))]))
    mbs = exu.SystemContainer().AddSystem()
    mech = build_mechanism(mbs, parse_scene(text), {}, reduce=True)
    assert (mech.handles["s"].kind, mech.handles["s"].dofs) == ("slider", (2,))
    assert (mech.handles["r"].kind, mech.handles["r"].dofs) == ("reduced", (0, 2))
    marker_at(mbs, mech.handles["s"], [1.0, 2.0, 3.0])          # a position marker is fine
    with pytest.raises(ValueError, match="'s' is built with its active coordinates only"):
        marker_at(mbs, mech.handles["s"], [0.0, 0.0, 0.0], np.eye(3))
    with pytest.raises(ValueError, match="'r' is built with its active coordinates only"):
        marker_at(mbs, mech.handles["r"], [0.0, 0.0, 0.0])


def test_reduce_must_be_a_boolean():
    with pytest.raises(SceneError, match="client.reduce"):
        parse_scene(scene_toml(**dry_scene([dry_body()], client={"type": "exudyn", "reduce": "sometimes"})))


# ------------------------------------------------------------------ wet scenes: reduced vs full

def sphere_scene(path: Path, dofs, cog, coupling: str = "mass-matrix") -> dict:
    sphere = sphere_body(str(path), mass=250000.0,            # not rho V: a net buoyancy force on the body
                         center_of_mass=list(cog), inertia=[[2.6e6, 0.1e6, 0.0], [0.1e6, 2.9e6, 0.05e6],
                                                            [0.0, 0.05e6, 2.7e6]], dofs=list(dofs),
                         initial_displacement=[0.1 if d in dofs else 0.0 for d in DOF_NAMES[:3]] + [0.0] * 3,
                         initial_velocity=[0.0] * 4 + [0.02 if "pitch" in dofs else 0.0, 0.0])
    return dict(dt=0.05, duration=8.0, water={**SPHERE_WATER, "gravity": 9.81}, waves=regular_waves(1.0, 6.0, ramp=2.0),
                hydro={"irf_duration": 10.0}, coupling={"scheme": coupling}, bodies=[sphere])


@pytest.mark.parametrize("dofs, cog, coupling", [
    (("heave",), (0.3, -0.2, -2.5), "mass-matrix"),          # slider, centre of mass off the reference point
    (("heave",), (0.3, -0.2, -2.5), "implicit"),             # A∞ fed back, rollback of the reduced state
    (("surge", "heave"), (0.3, -0.2, -2.5), "mass-matrix"),  # GenericODE2 node, two translations
    (("pitch",), (0.3, -0.2, -2.5), "mass-matrix"),          # one rotation alone: any centre of mass
    (("surge", "heave", "pitch"), (0.0, 0.4, -2.0), "mass-matrix"),   # centre of mass on the pitch axis
])
def test_wet_sphere_reduced_matches_full_form(server, sphere, sphere_path, tmp_path, dofs, cog, coupling):
    s_red, red, s_full, full = both_forms(sphere_scene(sphere_path, dofs, cog, coupling), tmp_path, address=server,
                                          hdbs={str(sphere_path): sphere})
    assert any("reduced bodies" in n for n in s_red.mechanism_notes)
    assert_agree(red, full)
    locked = [j for j, d in enumerate(DOF_NAMES) if d not in dofs]
    assert red["position"].dims == ("time", "body", "dof")
    assert not (red["position"].values - red["equilibrium_position"].values)[:, 0, locked].any()
    assert not red["velocity"].values[:, 0, locked].any()


def test_build_model_maps_the_hydrodynamics_onto_active_coordinates(server, sphere, sphere_path):
    """The hydro object of a reduced surge+heave sphere holds the active rows/columns of A∞ and the
    hydrostatic stiffness; the mass matrix rows of locked DOFs read zero, the active block m I + A∞."""
    text = scene_toml(**sphere_scene(sphere_path, ("surge", "heave"), (0.3, -0.2, -2.5)))
    scene = parse_scene(text)
    with ServerConnection(server, timeout=REPLY_S) as conn:
        setup = conn.hello(text, {str(sphere_path): sphere})
        conn.bye()
    model = build_model(scene, setup)
    try:
        got = model.mass_matrix()
        a = setup.added_mass
        act = [0, 2]
        np.testing.assert_allclose(got[np.ix_(act, act)], 250000.0 * np.eye(2) + a[np.ix_(act, act)], rtol=1e-14)
        assert not np.delete(np.delete(got, act, 0), act, 1).any() and not got[np.ix_(act, [1, 3, 4, 5])].any()
        k = setup.hydrostatic_stiffness
        hydro_k = model.mbs.GetObjectParameter(model.hydro_object, "stiffnessMatrix").GetPythonObject()
        np.testing.assert_array_equal(np.asarray(hydro_k, float), k[np.ix_(act, act)])
        q, v, acc = model.state()
        assert q.size == v.size == acc.size == 3 and q[-1] == v[-1] == acc[-1] == 0.0   # 2 + the zero slot
        assert list(model.wet_index) == [0, 2, 1, 2, 2, 2]
    finally:
        model.finalize()


@pytest.mark.parametrize("example", ["rm3.toml", "rm3_none.toml"])
def test_rm3_examples_reduced_match_full_form(server, reference_data, tmp_path, example):
    """RM3 (float + spar heave, the linear PTO on their relative heave): 20 s of the example, both forms."""
    from hydrolink.server.hdb.io import load_hdb
    text = rm3_example_text(example)
    hdb = reference_data / "rm3_wamit" / "rm3.1"
    text = text.replace('"../data/rm3_wamit/rm3.1"', f'"{hdb.as_posix()}"')
    text = text.replace("duration = 400.0", "duration = 20.0")
    s_red, red, s_full, full = both_forms(text, tmp_path, address=server, hdbs={hdb.as_posix(): load_hdb(hdb)})
    assert any("'float' (heave), 'spar' (heave): 2 coordinates instead of 12 and 10 constraints" in n
               for n in s_red.mechanism_notes)
    assert_agree(red, full)


def test_bench_accuracy_measures_reduced_against_full(tmp_path, reference_data):
    """``hydrolink bench accuracy --reduce true,false``: the full form is an option against the
    (reduced) reference — no error beyond round-off, its own per-step cost."""
    import csv

    from click.testing import CliRunner

    from hydrolink.clients.cli import cli
    text = rm3_example_text("rm3.toml")
    text = text.replace("../data/rm3_wamit/rm3.1", str(reference_data / "rm3_wamit" / "rm3.1"))
    scene = tmp_path / "rm3.toml"
    scene.write_text(text.replace("ramp = 40.0", "ramp = 5.0"))
    out = tmp_path / "acc"
    r = CliRunner().invoke(cli, ["bench", "accuracy", str(scene), "--reduce", "true,false", "--duration", "16",
                                 "-o", str(out)], catch_exceptions=False)
    assert r.exit_code == 0, r.output
    rows = {row["label"]: row for row in csv.DictReader(open(out / "accuracy.csv"))}
    assert list(rows) == ["reference", "reduce=False"]
    assert float(rows["reduce=False"]["rms_error"]) < AGREE and float(rows["reduce=False"]["max_error"]) < AGREE
    assert all(float(row["us_per_step"]) > 0 for row in rows.values())
