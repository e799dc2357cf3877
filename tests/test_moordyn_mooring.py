"""MoorDyn moorings (clients/exudyn/moordyn_mooring.py) against independent references written here: the
elastic catenary with seabed contact (static), and a monolithic integration of a moored body with
constant added mass and damping that calls MoorDyn directly (dynamic)."""

from __future__ import annotations

import json
import math
import os
from contextlib import contextmanager
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from scipy.optimize import fsolve

from conftest import body, regular_waves, scene_toml, write_scene

from hydrolink.protocol.scene import SceneError, parse_scene
from hydrolink.protocol.hdb.schema import make_hdb

moordyn = pytest.importorskip("moordyn")

RHO, G, DEPTH = 1025.0, 9.81, 200.0
# chain: diameter, mass per metre, EA; 480 m lines from anchors 400 m out on the seabed
D, MU, EA, LENGTH, SPAN0 = 0.1, 60.0, 1.0e8, 480.0, 400.0
W = (MU - RHO * math.pi * D * D / 4) * G                  # submerged weight per metre
Z0 = -2.0                                                  # the body's reference point
FAIRLEAD_R = 10.0                                          # fairlead radius on the body


# -- MoorDyn input files -----------------------------------------------------------------------------
def moordyn_file(path: Path, headings_deg, *, coupled: str = "body", origin=(0.0, 0.0, Z0), segments: int = 40,
                 dtm: float = 2e-3) -> Path:
    """A MoorDyn v2 input file: one chain line per heading, from an anchor on the seabed SPAN0 out to a
    fairlead FAIRLEAD_R out on a coupled body at ``origin`` (``coupled="body"``), or to coupled points
    at the same places (``coupled="points"``)."""
    anchors, fairleads, rows_lines = [], [], []
    n = len(headings_deg)
    for k, h in enumerate(np.radians(headings_deg)):
        c, s = math.cos(h), math.sin(h)
        anchors.append(f"{k + 1} Fixed {SPAN0 * c:.9g} {SPAN0 * s:.9g} {-DEPTH} 0 0 0 0")
        if coupled == "body":
            fairleads.append(f"{n + k + 1} Body1 {FAIRLEAD_R * c:.9g} {FAIRLEAD_R * s:.9g} 0 0 0 0 0")
        else:
            fairleads.append(f"{n + k + 1} Coupled {origin[0] + FAIRLEAD_R * c:.9g} {origin[1] + FAIRLEAD_R * s:.9g} "
                             f"{origin[2]} 0 0 0 0")
        rows_lines.append(f"{k + 1} chain {k + 1} {n + k + 1} {LENGTH} {segments} -")
    rows_points = anchors + fairleads
    bodies = ("---------------------- BODIES ----------------------\n"
              "ID Attachment X0 Y0 Z0 r0 p0 y0 Mass CG* I* Volume CdA* Ca*\n"
              "(#) (word) (m) (m) (m) (deg) (deg) (deg) (kg) (m) (kg-m^2) (m^3) (m^2) (-)\n"
              f"1 Coupled {origin[0]} {origin[1]} {origin[2]} 0 0 0 0 0 0 0 0 0\n") if coupled == "body" else ""
    text = (
        "--------------------- MoorDyn Input File -----------------------\n"
        "test mooring written by tests/test_moordyn_mooring.py\n"
        "---------------------- LINE TYPES ----------------------\n"
        "TypeName Diam Mass/m EA BA/-zeta EI Cd Ca CdAx CaAx\n"
        "(name) (m) (kg/m) (N) (N-s/-) (N-m^2) (-) (-) (-) (-)\n"
        f"chain {D} {MU} {EA} -1.0 0 1.2 1.0 0.2 0.0\n"
        + bodies +
        "---------------------- POINTS ----------------------\n"
        "ID Attachment X Y Z Mass Volume CdA Ca\n"
        "(#) (word/ID) (m) (m) (m) (kg) (m^3) (m^2) (-)\n"
        + "\n".join(rows_points) + "\n"
        "---------------------- LINES ----------------------\n"
        "ID LineType AttachA AttachB UnstrLen NumSegs LineOutputs\n"
        "(#) (name) (#) (#) (m) (-) (-)\n"
        + "\n".join(rows_lines) + "\n"
        "---------------------- OPTIONS ----------------------\n"
        f"{dtm} dtM\n{DEPTH} WtrDpth\n{RHO} WtrDnsty\n{G} g\n"
        "1.0 dtIC\n100 TmaxIC\n4.0 CdScaleIC\n1e-5 threshIC\n"
        "---------------------- OUTPUTS ----------------------\n"
        "END\n---------------------- need this line ----------------------\n")
    path.write_text(text)
    return path


def catenary(span: float, height: float, *, length: float = LENGTH, w: float = W, ea: float = EA
             ) -> tuple[float, float]:
    """Elastic catenary with a frictionless seabed (anchor on the bed): horizontal and vertical
    fairlead force (H, V) of a ``length`` line (default LENGTH), submerged weight ``w`` per metre
    (W), stiffness ``ea`` (EA), for a fairlead ``span`` from the anchor horizontally and ``height``
    above it."""
    LENGTH, W, EA = length, w, ea   # noqa: N806 - the formulas below in the module's names
    def eqs(p):
        h, v = math.exp(p[0]), p[1]
        if v < W * LENGTH:      # part of the line on the seabed
            x = LENGTH - v / W + h / W * math.asinh(v / h) + h * LENGTH / EA
            z = h / W * (math.sqrt(1 + (v / h) ** 2) - 1) + v * v / (2 * EA * W)
        else:
            vb = v - W * LENGTH
            x = h / W * (math.asinh(v / h) - math.asinh(vb / h)) + h * LENGTH / EA
            z = h / W * (math.sqrt(1 + (v / h) ** 2) - math.sqrt(1 + (vb / h) ** 2)) + (v * LENGTH - W * LENGTH ** 2 / 2) / EA
        return [x - span, z - height]
    sol = fsolve(eqs, [math.log(W * LENGTH / 4), W * height], xtol=1e-13)
    return math.exp(sol[0]), float(sol[1])


def dry_float(**keys) -> dict:
    """A dry 2e5 kg body whose buoyancy cancels its weight, reference point at (0, 0, Z0)."""
    return body("float", mass=2.0e5, center_of_mass=[0.0, 0.0, Z0], inertia=[1e7, 1e7, 1e7],
                buoyancy_volume=2.0e5 / RHO, **keys)


def mooring(**keys) -> dict:
    return {"type": "moordyn", "name": "spread", "file": "lines.dat", "bodies": ["float"], **keys}


def _model(tmp_path: Path, scene_text: str, layouts=None):
    """Scene file -> its MoorDyn layouts (or ``layouts``) -> the Exudyn model (MoorDyn started at the
    initial pose)."""
    from hydrolink.clients.exudyn.client import build_model
    from hydrolink.clients.exudyn.moordyn_mooring import load_moordyn_files
    path = write_scene(tmp_path, scene_text)
    scene = parse_scene(scene_text, path)
    return build_model(scene, None, moordyn_files=layouts or load_moordyn_files(scene, path))


# -- static: the elastic catenary -----------------------------------------------------------------------
def _catenary_loads(headings_deg, dx: float) -> tuple[np.ndarray, np.ndarray]:
    """Force and moment about the reference point on the body (6,) and fairlead tensions (lines,)
    with the body moved ``dx`` in surge."""
    load, tension = np.zeros(6), []
    for h in np.radians(headings_deg):
        e = np.array([math.cos(h), math.sin(h)])
        fair, anchor = np.array([dx, 0.0]) + FAIRLEAD_R * e, SPAN0 * e
        span = float(np.linalg.norm(anchor - fair))
        hf, vf = catenary(span, Z0 + DEPTH)
        f = np.r_[hf * (anchor - fair) / span, -vf]
        load += np.r_[f, np.cross(np.r_[FAIRLEAD_R * e, 0.0], f)]
        tension.append(math.hypot(hf, vf))
    return load, np.array(tension)


def _segment_tensions(headings_deg, dx: float, segments: int) -> np.ndarray:
    """The elastic catenary's tension at the middle of each line's end segment (half a segment's
    submerged weight below the fairlead): what MoorDyn reports as the fairlead tension."""
    out = []
    for h in np.radians(headings_deg):
        e = np.array([math.cos(h), math.sin(h)])
        span = float(np.linalg.norm(SPAN0 * e - (np.array([dx, 0.0]) + FAIRLEAD_R * e)))
        hf, vf = catenary(span, Z0 + DEPTH)
        out.append(math.hypot(hf, vf - W * LENGTH / segments / 2))
    return np.array(out)


@pytest.mark.parametrize("headings", [[0.0], [0.0, 120.0, 240.0]], ids=["one-line", "three-lines"])
def test_static_tension_and_restoring_force_against_the_elastic_catenary(tmp_path, headings):
    """MoorDyn's initial-condition solve with the body held at a few surge offsets: fairlead tensions
    and the force on the body within 1 % of the elastic catenary with seabed contact."""
    from hydrolink.clients.exudyn.moordyn_mooring import read_layout
    layouts = {0: read_layout(moordyn_file(tmp_path / "lines.dat", headings))}
    for dx in (6.0, -9.0) if len(headings) > 1 else (0.0, 6.0, -9.0):
        model = _model(tmp_path, scene_toml(dt=0.01, duration=0.01, progress=False,
                                            moorings=[mooring(static_offset=False, workers=0)],   # its own instance
                                            bodies=[dry_float(dofs=["surge"], initial_displacement=[dx, 0, 0, 0, 0, 0])]),
                       layouts)
        try:
            load = model.moorings.sample(model.mbs)[0]
            system = model.moorings.moordyn[0]
            tension, end_force = system.tensions(), system.end_forces()
            own = np.array([moordyn.GetLineFairTen(moordyn.GetLine(system.instance, k))
                            for k in range(1, len(headings) + 1)])
        finally:
            model.close()
        force, tension_ref = _catenary_loads(headings, dx)
        # the end node's pull on the fairlead: the catenary's tension at the fairlead point
        np.testing.assert_allclose(end_force, tension_ref, rtol=0.01)
        # line_tension: MoorDyn's own number (GetLineFairTen), the catenary's tension half a
        # segment below the fairlead (the end segment's), not the end node's pull
        np.testing.assert_allclose(tension, own, rtol=1e-12)
        np.testing.assert_allclose(tension, _segment_tensions(headings, dx, 40), rtol=0.01)
        assert (end_force > tension).all()
        assert load[0] == pytest.approx(force[0], rel=0.01)      # the (net) horizontal restoring force
        assert load[2] == pytest.approx(force[2], rel=0.01)
        # moments about the reference point: the fairleads' vertical pull FAIRLEAD_R off it
        np.testing.assert_allclose(load[3:], force[3:], rtol=0, atol=0.01 * abs(force[2]) * FAIRLEAD_R)


# -- dynamic: surge decay against a monolithic integration -------------------------------------------------
MASS, A11, B11, X0 = 2.0e4, 1.0e4, 2.0e3, 5.0      # kg, kg, N s/m, m


def constant_hdb(name: str = "float"):
    """One body with frequency-independent added mass and damping (A∞ = A) and no excitation."""
    omega = np.linspace(0.05, 4.0, 80)
    a = np.tile(np.diag([A11, A11, 2 * A11, 1e6, 1e6, 1e6]), (omega.size, 1, 1))
    b = np.tile(np.diag([B11, B11, B11, 1e4, 1e4, 1e4]), (omega.size, 1, 1))
    return make_hdb(bodies=[name], omega=omega, wave_direction=np.zeros(1), added_mass=a, radiation_damping=b,
                    excitation_force=np.zeros((omega.size, 1, 6), complex),
                    hydrostatic_stiffness=np.diag([0.0, 0.0, 3e5, 1e7, 1e7, 0.0]),
                    reference_point=np.array([[0.0, 0.0, Z0]]), rho=RHO, g=G, water_depth=DEPTH, source="analytic",
                    added_mass_inf=a[0])


@contextmanager
def silenced():
    """MoorDyn's stdout/stderr (banner, "t = ..." every step) to /dev/null."""
    saved = os.dup(1), os.dup(2)
    with open(os.devnull, "wb") as null:
        os.dup2(null.fileno(), 1)
        os.dup2(null.fileno(), 2)
        try:
            yield
        finally:
            os.dup2(saved[0], 1)
            os.dup2(saved[1], 2)
            os.close(saved[0])
            os.close(saved[1])


def monolithic_decay(path: Path, dt: float, n: int) -> np.ndarray:
    """(m + A) x'' + B x' = F_moordyn: Newmark's trapezoidal rule (as the implicit scheme integrates),
    each step's mooring force from MoorDyn moving the body linearly from x_k to x_k+1, iterated to
    the fixed point with MoorDyn's state restored (Serialize/Deserialize); MoorDyn called directly."""
    pose = lambda x: [x, 0.0, Z0, 0.0, 0.0, 0.0]              # noqa: E731
    rate = lambda v: [v, 0.0, 0.0, 0.0, 0.0, 0.0]             # noqa: E731
    m = moordyn.Create(str(path))
    moordyn.Init(m, pose(X0), rate(0.0))
    x, v = X0, 0.0
    a = moordyn.Step(m, pose(x), rate(0.0), 0.0, 0.0)[0] / (MASS + A11)
    out = [x]
    for k in range(n):
        state = moordyn.Serialize(m)
        x1 = x + dt * v + dt * dt / 2 * a
        for _ in range(100):
            moordyn.Deserialize(m, state)
            f = moordyn.Step(m, pose(x), rate((x1 - x) / dt), k * dt, dt)[0]
            a1 = (f - B11 * (v + dt / 2 * a)) / (MASS + A11 + B11 * dt / 2)
            x_new = x + dt * v + dt * dt / 4 * (a + a1)
            done = abs(x_new - x1) <= 1e-13 * X0
            x1 = x_new
            if done:
                break
        v, a, x = v + dt / 2 * (a + a1), a1, x1
        out.append(x)
    moordyn.Close(m)
    return np.array(out)


def _decay_scene(tmp_path: Path, dt: float, duration: float, scheme: str, **mooring_keys) -> Path:
    return write_scene(tmp_path, scene_toml(
        dt=dt, duration=duration, progress=False, water={"density": RHO, "depth": DEPTH},
        waves=regular_waves(0.0, 8.0), hydro={"radiation": "constant"},
        coupling={"scheme": scheme, "tolerance": 1e-10, "max_iterations": 100} if scheme == "implicit" else {"scheme": scheme},
        bodies=[body("float", hdb="float.nc", mass=MASS, center_of_mass=[0, 0, Z0], inertia=[1e6] * 3, dofs=["surge"],
                     initial_displacement=[X0, 0, 0, 0, 0, 0])],
        moorings=[mooring(**{"static_offset": False, **mooring_keys})]), f"decay_{scheme}.toml")


def test_surge_decay_equals_a_monolithic_integration_with_moordyn(tmp_path):
    """A moored body with constant A and B released from a 5 m surge offset: hydrolink's implicit
    scheme (rolling MoorDyn back on every redo) equals the monolithic integration to 1e-6 of the
    offset; the default scheme (MoorDyn driven towards the predicted pose) is second-order close."""
    from hydrolink.clients.run import run_scene_file
    dt, duration = 0.05, 20.0
    n = int(round(duration / dt))
    moordyn_file(tmp_path / "lines.dat", [0.0, 120.0, 240.0], segments=24)
    with silenced():
        reference = monolithic_decay(tmp_path / "lines.dat", dt, n)
    assert reference.min() < -0.1 * X0 and np.abs(reference[-100:]).max() < 0.1 * X0    # swings back, decays
    hdbs = {"float.nc": constant_hdb()}
    results = {}
    for scheme in ("implicit", "mass-matrix"):
        summary = run_scene_file(_decay_scene(tmp_path, dt, duration, scheme), tmp_path / f"{scheme}.nc",
                                 progress=False, hdbs=hdbs)
        assert summary.status == "complete" and not summary.warnings
        with xr.open_dataset(tmp_path / f"{scheme}.nc") as ds:
            results[scheme] = ds["position"].values[:, 0, 0].copy()
            if scheme == "implicit":
                iterations = summary.coupling.iterations_mean
    x_imp = results["implicit"]
    assert iterations > 2                                   # every step was redone (MoorDyn rolled back)
    err = np.abs(x_imp - reference).max() / X0
    assert err <= 1e-6, err
    err_mm = np.abs(results["mass-matrix"] - reference).max() / X0
    assert err_mm <= 5e-3, err_mm


# -- results ----------------------------------------------------------------------------------------------
def test_results_line_tension_mooring_force_and_nodes_with_coupled_points(tmp_path):
    """The same spread coupled as three points on the body and as a coupled body: the same motion;
    line_tension (time, line), mooring_force of the body and line_node_position (time, line, node,
    xyz) in the results, the fairlead nodes on the body's points."""
    from hydrolink.clients.run import run_scene_file
    headings = [0.0, 120.0, 240.0]
    (tmp_path / "points").mkdir()
    moordyn_file(tmp_path / "lines.dat", headings, segments=24)
    moordyn_file(tmp_path / "points" / "lines.dat", headings, coupled="points", segments=24)
    hdbs = {"float.nc": constant_hdb()}
    runs = {}
    for name, folder, keys in (("body", tmp_path, {}),
                               ("points", tmp_path / "points", {"bodies": [], "points": ["float"] * 3,
                                                                 "record_nodes": True})):
        scene = _decay_scene(folder, 0.05, 3.0, "mass-matrix", **keys)
        summary = run_scene_file(scene, folder / "out.nc", progress=False, hdbs=hdbs)
        runs[name] = ds = xr.load_dataset(folder / "out.nc")
        assert ds.attrs["status"] == "complete" and summary.moordyn[0]["lines"] == 3
    a, b = runs["body"], runs["points"]
    x = a["position"].values[:, 0, 0]
    assert x[0] == X0 and x[-1] < X0 - 0.01                                    # it moves
    np.testing.assert_allclose(b["position"].values[:, 0, 0], x, rtol=0, atol=1e-4 * X0)
    assert list(a["line"].values) == ["spread:1", "spread:2", "spread:3"]
    assert a["line_tension"].dims == ("time", "line") and "line_node_position" not in a
    np.testing.assert_allclose(b["line_tension"].values, a["line_tension"].values, rtol=2e-3)
    tension0 = a["line_end_force"].values[0]
    h0, v0 = catenary(math.hypot(SPAN0 * math.cos(0) - X0 - FAIRLEAD_R, 0.0), Z0 + DEPTH)
    assert tension0[0] == pytest.approx(math.hypot(h0, v0), rel=0.01)
    # line_tension is MoorDyn's own fairlead tension: the end segment's (24 segments), and the same as
    # MoorDyn's initial report of GetLineFairTen in the run's attribute
    assert a["line_tension"].values[0, 0] == pytest.approx(math.hypot(h0, v0 - W * LENGTH / 24 / 2), rel=0.01)
    report = json.loads(a.attrs["moordyn"])[0]
    np.testing.assert_allclose(a["line_tension"].values[0], report["initial_line_tension"], rtol=1e-12)
    np.testing.assert_allclose(a["line_end_force"].values[0], report["initial_line_end_force"], rtol=1e-12)
    assert (a["line_end_force"].values > a["line_tension"].values).all()
    # the mooring force on the body: MoorDyn's coupled force (points: their forces moved to the
    # reference point), the same both ways
    fa, fb = a["mooring_force"].values[:, 0], b["mooring_force"].values[:, 0]
    np.testing.assert_allclose(fb[:, :3], fa[:, :3], rtol=0, atol=2e-3 * np.abs(fa[:, 2]).max())
    # nodes: anchors fixed on the seabed, fairleads on the body's points
    nodes = b["line_node_position"].values                     # (time, line, node, xyz)
    assert nodes.shape == (x.size, 3, 25, 3)
    for k, h in enumerate(np.radians(headings)):
        np.testing.assert_allclose(nodes[:, k, 0], np.tile([SPAN0 * math.cos(h), SPAN0 * math.sin(h), -DEPTH], (x.size, 1)),
                                   atol=1e-9)
        fair = np.column_stack([b["position"].values[:, 0, 0] + FAIRLEAD_R * math.cos(h),
                                np.full(x.size, FAIRLEAD_R * math.sin(h)), np.full(x.size, Z0)])
        # (MoorDyn's fairlead ends each step at the predicted pose: O(dt³) from where the body ends)
        np.testing.assert_allclose(nodes[:, k, -1], fair, atol=1e-4)


# -- errors -------------------------------------------------------------------------------------------------
def test_scene_errors_name_the_key():
    base = dict(dt=0.1, duration=1.0, bodies=[dry_float()])
    with pytest.raises(SceneError, match=r"moorings\[0\]\.bodies\[0\]: no body named 'buoy'"):
        parse_scene(scene_toml(**base, moorings=[mooring(bodies=["buoy"])]))
    with pytest.raises(SceneError, match=r"moorings\[0\].*at least one coupled scene body"):
        parse_scene(scene_toml(**base, moorings=[mooring(bodies=[])]))
    with pytest.raises(SceneError, match=r"moorings\[1\]\.name: duplicate mooring name 'spread'"):
        parse_scene(scene_toml(**base, moorings=[mooring(), mooring()]))


def test_file_errors_name_the_file_and_key(tmp_path):
    """Missing file, a file MoorDyn rejects, a coupled count that does not match the scene: one
    SceneError naming the scene, the key and the file. (A file that crashes MoorDyn's reader — an
    OUTPUTS section without a closing "---" line reads past the end of its buffer — crashes only
    sometimes, so it is not tested here; the child process turns a crash into the same SceneError.)"""
    from hydrolink.clients.exudyn.moordyn_mooring import load_moordyn_files
    text = scene_toml(dt=0.1, duration=1.0, bodies=[dry_float()], moorings=[mooring()])
    path = write_scene(tmp_path, text)
    scene = parse_scene(text, path)
    with pytest.raises(SceneError, match=r"scene\.toml: moorings\[0\]\.file: MoorDyn input file not found: .*lines\.dat"):
        load_moordyn_files(scene, path)
    f = moordyn_file(tmp_path / "lines.dat", [0.0])
    f.write_text(f.read_text().replace("1 chain 1 2", "1 chain 1 7"))
    with pytest.raises(SceneError, match=r"moorings\[0\]\.file: .*lines\.dat: MoorDyn could not read it: "):
        load_moordyn_files(scene, path)
    moordyn_file(tmp_path / "lines.dat", [0.0], coupled="points")
    with pytest.raises(SceneError, match=r"moorings\[0\]\.bodies: lines\.dat has 0 coupled bodies, moorings\[0\]\.bodies "
                                         r"lists 1 scene body \['float'\]"):
        load_moordyn_files(scene, path)


def test_moordyn_failure_mid_run_names_the_file_and_step_and_keeps_the_rows(tmp_path):
    """dtM too large for the line's axial stiffness: MoorDyn reports NaN node positions a few steps
    in; the run stops with one line naming the mooring, its file and the step; rows are kept."""
    from hydrolink.clients.lockstep.driver import RunInterrupted
    from hydrolink.clients.run import run_scene_file
    moordyn_file(tmp_path / "lines.dat", [0.0], dtm=0.01)
    with pytest.raises(RunInterrupted, match=r"^MoorDyn failed at step (\d+) \(t = [\d.]+ s\): moorings\[0\] \(.*lines\.dat\): "
                                             r".*NaN.*; the \1 rows before it are saved in .*out\.nc$") as info:
        run_scene_file(_decay_scene(tmp_path, 0.05, 5.0, "mass-matrix"), tmp_path / "out.nc", progress=False,
                       hdbs={"float.nc": constant_hdb()})
    ds = xr.load_dataset(tmp_path / "out.nc")
    assert ds.sizes["time"] == info.value.rows > 0 and ds.attrs["status"].startswith("interrupted: MoorDyn failed")


def test_steady_refuses_moordyn_moorings(tmp_path):
    from hydrolink.clients.analysis.steady import SteadyError, check_scene
    scene = parse_scene(scene_toml(dt=0.1, duration=1.0, bodies=[dry_float()], waves=regular_waves(1.0, 8.0),
                                   moorings=[mooring()]))
    with pytest.raises(SteadyError, match=r"moorings\[0\].*MoorDyn moorings are not supported by hydrolink steady"):
        check_scene(scene)


def test_static_offset_under_pretension_against_the_catenary(tmp_path):
    """A wet body (heave stiffness C33, surge free) on the three-line spread: the reported static
    offset is where C33 Δz balances the three lines' vertical pull at the lowered fairleads (the
    elastic catenary), and no surge offset (symmetric spread)."""
    from hydrolink.clients.run import run_scene_file
    from scipy.optimize import brentq
    headings = [0.0, 120.0, 240.0]
    moordyn_file(tmp_path / "lines.dat", headings, segments=24)
    scene = write_scene(tmp_path, scene_toml(
        dt=0.05, duration=0.1, progress=False, water={"density": RHO, "depth": DEPTH},
        waves=regular_waves(0.0, 8.0), hydro={"radiation": "constant"},
        bodies=[body("float", hdb="float.nc", mass=MASS, center_of_mass=[0, 0, Z0], inertia=[1e6] * 3,
                     dofs=["surge", "heave"])],
        moorings=[mooring()]))
    summary = run_scene_file(scene, tmp_path / "out.nc", progress=False, hdbs={"float.nc": constant_hdb()})
    report = summary.moordyn[0]
    offset = np.asarray(report["static_offset"])[0]
    c33 = 3e5                                                  # constant_hdb's heave stiffness
    dz = brentq(lambda z: c33 * z + len(headings) * catenary(SPAN0 - FAIRLEAD_R, Z0 + z + DEPTH)[1], -5.0, 0.0)
    assert dz < -0.3
    assert offset[2] == pytest.approx(dz, rel=0.01)
    assert abs(offset[0]) < 1e-3 and not np.any(offset[3:])
    assert report["static_offset_residual"] < 1e-3 * c33 * abs(dz)
    with xr.open_dataset(tmp_path / "out.nc") as ds:
        assert json.loads(ds.attrs["moordyn"])[0]["static_offset"] == report["static_offset"]


def test_a_step_that_is_not_a_multiple_of_dtm_is_a_warning(tmp_path):
    from hydrolink.clients.run import run_scene_file
    moordyn_file(tmp_path / "lines.dat", [0.0], segments=12, dtm=0.003)
    summary = run_scene_file(_decay_scene(tmp_path, 0.05, 0.1, "mass-matrix"), tmp_path / "out.nc", progress=False,
                             hdbs={"float.nc": constant_hdb()})
    assert summary.warnings == ["moorings[0]: simulation.dt = 0.05 s is not a multiple of dtM = 0.003 s in lines.dat: "
                                   "MoorDyn takes 17 substeps per step, the last one shorter; make dt a multiple of dtM"]


def test_static_offset_of_a_dry_body_with_spare_buoyancy(tmp_path):
    """A dry body whose buoyancy exceeds its weight by the three lines' vertical pull (elastic
    catenary) at 1 m above its reference: at the reported equilibrium MoorDyn, called directly,
    pulls down by that spare buoyancy (to 1 % of the change of pull over that metre), and the
    equilibrium is near 1 m (the lumped-mass lines' vertical stiffness is a difference of large
    pulls: 0.1 % on the pull moves the equilibrium by 10 %)."""
    from hydrolink.clients.exudyn.moordyn_mooring import read_layout
    headings = [0.0, 120.0, 240.0]
    lift = len(headings) * catenary(SPAN0 - FAIRLEAD_R, Z0 + 1.0 + DEPTH)[1]            # N, net upward
    path = moordyn_file(tmp_path / "lines.dat", headings, segments=24)
    float_ = body("float", mass=2.0e5, center_of_mass=[0.0, 0.0, Z0], inertia=[1e7, 1e7, 1e7],
                  buoyancy_volume=(2.0e5 * G + lift) / (RHO * G), dofs=["surge", "heave"])
    model = _model(tmp_path, scene_toml(dt=0.01, duration=0.01, bodies=[float_], moorings=[mooring()]),
                   {0: read_layout(path)})
    try:
        offset = model.moorings.moordyn[0].offset[0]
    finally:
        model.close()

    def pull(dz: float) -> float:
        with silenced():
            m = moordyn.Create(str(path))
            x = [0.0, 0.0, Z0 + dz, 0.0, 0.0, 0.0]
            moordyn.Init(m, x, [0.0] * 6)
            fz = moordyn.Step(m, x, [0.0] * 6, 0.0, 0.0)[2]
            moordyn.Close(m)
        return -fz

    change = lift - len(headings) * catenary(SPAN0 - FAIRLEAD_R, Z0 + DEPTH)[1]
    assert abs(pull(offset[2]) - lift) <= 0.01 * change
    assert offset[2] == pytest.approx(1.0, rel=0.15) and abs(offset[0]) < 1e-3
