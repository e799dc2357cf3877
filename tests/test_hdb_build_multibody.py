"""Multi-body `hdb build` ([[bodies]], compound bodies) and the device specs in examples/.

Independent references (none computed by the code under test):
* Reciprocity (Newman 1977, Marine Hydrodynamics, sec. 6.17): A_ij = A_ji and B_ij = B_ji for the
  coupled 6N x 6N matrices, so the body-to-body blocks satisfy A_ab = A_ba^T. A constant-panel
  collocation BEM satisfies it only to discretisation accuracy: measured on the R = 1 m pair 4 m
  apart, the worst entry (heave of one body - surge of the other) is off by 2.8 % of the block's
  largest entry at panel R/4, 2.3 % at R/8, with or without lids (slow O(h) convergence at the
  bottom edge); the tests allow 4 %.
* Energy: the radiated power for any real motion amplitude u is (w^2/2) u^T B u >= 0, so B(w) is
  positive semi-definite.
* Haskind relation for the coupled system, deep water: B_ij = w^3/(4 pi rho g^3) x
  int_0^2pi X_i(b) conj(X_j(b)) db (k = w^2/g, c_g = g/(2w) in k/(8 pi rho g c_g)). The integrand
  is smooth and periodic: the trapezoid rule over 24 headings is spectrally accurate.
* Far-field interaction of two identical heaving axisymmetric bodies a distance d apart: heave
  radiates isotropic waves, and with body 2's excitation X_2(b) = X_1(b) exp(-i k d cos b) the
  Haskind integral gives B_12 = B_11 J0(k d) (isolated-body X; multiple scattering neglected, good
  when k d >> 1 and the bodies are small). Measured at d = 200 m: B_ab/B_aa = 0.2097, 0.0655, 0.0658
  against J0(kd) = 0.2101, 0.0533, 0.0399 (kd = 13, 46, 127): within 2.7 % of B_aa; the rest is
  the BEM's far-field accuracy, allowed 4 %.
* Hydrostatics of boxes and cylinders: V, centre of buoyancy and C33 = rho g (waterplane area).
"""

from __future__ import annotations

import json
import math
import re
from pathlib import Path

import numpy as np
import pytest
from scipy.special import j0

from hydrolink.server.hdb.build.builder import SpecError, body_hydrostatics, build_hdb, load_spec, parse_spec

# One pytest-xdist worker runs this whole module (pyproject: --dist loadgroup): its module fixtures (two
# multibody Capytaine builds) cost ~6 s, paid once per worker otherwise.
pytestmark = pytest.mark.xdist_group("hdb_build_multibody")

RHO, G = 1025.0, 9.81
EXAMPLES = Path(__file__).resolve().parents[1] / "examples"
OMEGAS = [0.8, 1.5, 2.5]


def _cyl(name: str, x: float, y: float = 0.0, panel: float = 0.25) -> str:
    return (f'[[bodies]]\nname = "{name}"\nshape = "vertical_cylinder"\nradius = 1.0\ndraft = 1.0\n'
            f"center = [{x}, {y}, 0.0]\nreference_point = [{x}, {y}, -0.5]\npanel_size = {panel}\n")


def _grid(omegas=OMEGAS, directions=(0.0,)) -> str:
    return (f"[frequencies]\nvalues = {list(map(float, omegas))}\n[water]\ndensity = {RHO}\ngravity = {G}\n"
            f"[waves]\ndirections = {list(map(float, directions))}\n")


def _build(tmp_path: Path, name: str, text: str):
    path = tmp_path / name
    path.write_text(text)
    return build_hdb(path, cache_dir=tmp_path / "cache", progress=False)


@pytest.fixture(scope="module")
def pair(tmp_path_factory):
    """Two R = 1 m, T = 1 m cylinders 4 m apart on the x axis, 24 headings at one frequency."""
    tmp = tmp_path_factory.mktemp("pair")
    return _build(tmp, "pair.toml", _cyl("a", 0.0) + _cyl("b", 4.0) + _grid([1.5, 2.5], np.arange(0, 360, 15)))


def test_two_bodies_layout_and_hydrostatics(pair):
    ds = pair
    assert list(ds["body"].values) == ["a", "b"] and ds.sizes["influenced_dof"] == 12
    assert ds["influenced_dof"].values[6] == "b.surge" and "added_mass_inf" in ds
    assert ds.attrs["xoz_symmetry"] == 1
    panels = json.loads(ds.attrs["panels_per_body"])
    assert panels["a"] == panels["b"] and ds.attrs["n_panels"] == 2 * panels["a"]["hull"]
    np.testing.assert_allclose(ds["displaced_volume"].values, [math.pi, math.pi], rtol=1e-9)
    np.testing.assert_allclose(ds["center_of_buoyancy"].values, [[0, 0, -0.5], [4, 0, -0.5]], atol=1e-9)
    np.testing.assert_allclose(ds["reference_point"].values, [[0, 0, -0.5], [4, 0, -0.5]])
    C = ds["hydrostatic_stiffness"].values
    assert C[2, 2] == pytest.approx(RHO * G * math.pi, rel=1e-9) and C[8, 8] == pytest.approx(C[2, 2])
    assert np.abs(C[:6, 6:]).max() == 0 and np.abs(C[6:, :6]).max() == 0  # no hydrostatic coupling


def test_reciprocity_and_positive_damping(pair):
    ds = pair
    for name in ("added_mass", "radiation_damping"):
        M = ds[name].values
        ab, ba = M[:, :6, 6:], M[:, 6:, :6]
        scale = np.abs(ab).max(axis=(1, 2))[:, None, None]
        assert np.all(np.abs(ab - ba.transpose(0, 2, 1)) <= 0.04 * scale), name
        assert np.abs(ab).max() > 1e-3 * np.abs(M).max()  # the coupling is really there
    a_inf = ds["added_mass_inf"].values
    assert np.abs(a_inf[:6, 6:] - a_inf[6:, :6].T).max() <= 0.04 * np.abs(a_inf[:6, 6:]).max()
    for B in ds["radiation_damping"].values:
        sym = (B + B.T) / 2
        assert np.linalg.eigvalsh(sym).min() >= -0.01 * np.abs(sym).max()


def test_haskind_on_the_coupled_system(pair):
    ds = pair
    w = ds["omega"].values
    beta = ds["wave_direction"].values
    assert beta.size == 24 and np.allclose(np.diff(beta), 2 * np.pi / 24)
    X = ds["excitation_force"].values  # (omega, heading, dof)
    for i, om in enumerate(w):
        haskind = om ** 3 / (4 * np.pi * RHO * G ** 3) * (2 * np.pi / 24) * np.einsum(
            "bi,bj->ij", X[i], X[i].conj()).real
        B = ds["radiation_damping"].values[i]
        big = np.abs(B).max()
        # translational-translational and heave-pitch blocks of both bodies, incl. the cross ones
        idx = [0, 2, 4, 6, 8, 10]
        np.testing.assert_allclose(B[np.ix_(idx, idx)], haskind[np.ix_(idx, idx)], atol=0.03 * big)
        assert abs(B[2, 8] - haskind[2, 8]) <= 0.04 * B[2, 2]  # heave a <-> heave b


@pytest.fixture(scope="module")
def far_apart(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("far")
    single = _build(tmp, "one.toml", _cyl("a", 0.0).replace("[[bodies]]", "[body]") + _grid())
    two = _build(tmp, "two.toml", _cyl("a", 0.0) + _cyl("b", 200.0) + _grid())
    return single, two


def test_far_apart_bodies_tend_to_the_isolated_body(far_apart):
    single, two = far_apart
    for name in ("added_mass", "radiation_damping"):
        iso = single[name].values
        scale = np.abs(iso).max(axis=(1, 2))[:, None, None]
        for blk in (slice(0, 6), slice(6, 12)):
            diag = two[name].values[:, blk, blk]
            assert np.all(np.abs(diag - iso) <= 0.02 * scale), name
        assert np.abs(two[name].values[:, :6, 6:]).max() < 0.3 * np.abs(iso).max()
    iso = single["added_mass_inf"].values
    assert np.abs(two["added_mass_inf"].values[:6, :6] - iso).max() <= 0.01 * np.abs(iso).max()
    assert np.abs(two["added_mass_inf"].values[:6, 6:]).max() < 1e-3 * np.abs(iso).max()
    # far-field interaction: B_ab(heave, heave) = J0(k d) B_aa(heave) of the isolated body
    k = np.asarray(OMEGAS) ** 2 / G
    b33 = single["radiation_damping"].values[:, 2, 2]
    assert np.all(np.abs(two["radiation_damping"].values[:, 2, 8] - j0(k * 200.0) * b33) <= 0.04 * b33)


def test_mirror_symmetry_gives_the_same_answer(tmp_path):
    """The same pair solved as one xOz-symmetric problem and, moved off the plane, without."""
    sym = _build(tmp_path, "s.toml", _cyl("a", 0.0, panel=0.4) + _cyl("b", 3.0, panel=0.4) + _grid([1.0, 2.0]))
    off = _build(tmp_path, "o.toml", _cyl("a", 0.0, 1.0, 0.4) + _cyl("b", 3.0, 1.0, 0.4) + _grid([1.0, 2.0]))
    assert sym.attrs["xoz_symmetry"] == 1 and off.attrs["xoz_symmetry"] == 0
    for name in ("added_mass", "radiation_damping", "excitation_force"):
        np.testing.assert_allclose(off[name].values, sym[name].values, rtol=1e-6,
                                   atol=1e-6 * np.abs(sym[name].values).max())


BARGE_WITH_PLATE = """
[[bodies]]
name = "raft"
shape = "compound"
center = [1.0, 0.0, 0.0]
reference_point = [1.0, 0.0, 0.0]
panel_size = 0.25
[[bodies.parts]]
shape = "box"
length = 2.0
width = 1.0
draft = 0.5
height = 0.8
[[bodies.parts]]
shape = "box"
length = 3.0
width = 2.0
draft = 2.05
freeboard = -1.95
panel_size = 0.4
[[bodies]]
name = "float"
shape = "vertical_cylinder"
radius = 0.5
draft = 0.4
center = [4.0, 0.0, 0.0]
panel_size = 0.2
"""


def test_compound_body_with_a_damping_plate(tmp_path):
    ds = _build(tmp_path, "raft.toml", BARGE_WITH_PLATE + _grid([1.0, 2.0]))
    v_box, v_plate = 2.0 * 1.0 * 0.5, 3.0 * 2.0 * 0.1
    assert ds["displaced_volume"].values[0] == pytest.approx(v_box + v_plate, rel=1e-9)
    cob_z = (v_box * -0.25 + v_plate * -2.0) / (v_box + v_plate)
    np.testing.assert_allclose(ds["center_of_buoyancy"].values[0], [1.0, 0.0, cob_z], atol=1e-9)
    C = ds["hydrostatic_stiffness"].values
    assert C[2, 2] == pytest.approx(RHO * G * 2.0, rel=1e-9)  # only the barge cuts the surface
    panels = json.loads(ds.attrs["panels_per_body"])
    assert panels["raft"]["lid"] == 8 * 4  # the barge's waterplane only (2 x 1 m at 0.25 m)
    a_inf = ds["added_mass_inf"].values
    # the plate dominates the raft's heave added mass: a thin rectangular plate a x b = 3 x 2 m in
    # infinite fluid has C rho pi/4 b^2 a with C = 0.705 for a/b = 1.5 (DNV-RP-H103, Table D-2):
    # 6.8 t; the barge above it and the 0.1 m thickness add to it, the free surface takes off a little
    plate = 0.705 * RHO * math.pi / 4 * 2.0 ** 2 * 3.0
    assert 0.8 * plate < a_inf[2, 2] < 1.4 * plate
    # reciprocity of the (small) raft-float coupling, relative to the float's own heave A_inf
    assert np.abs(a_inf[:6, 6:] - a_inf[6:, :6].T).max() <= 0.05 * a_inf[8, 8]


def test_mesh_file_body_in_a_multibody_build(tmp_path):
    from test_hdb_build import _gdf_box
    _gdf_box(tmp_path / "box.gdf", 2.0, 1.0, 0.5, 4)
    text = ('[[bodies]]\nname = "box"\nshape = "mesh"\nmesh = "box.gdf"\ncenter = [-3.0, 0.0, 0.0]\n'
            + _cyl("c", 1.0, panel=0.4) + _grid([1.0, 2.0]))
    ds = _build(tmp_path, "m.toml", text)
    assert ds["displaced_volume"].values == pytest.approx([1.0, math.pi], rel=1e-6)
    assert ds["center_of_buoyancy"].values[0] == pytest.approx([-3.0, 0.0, -0.25], abs=1e-9)
    assert np.abs(ds["added_mass"].values[:, :6, 6:]).max() > 0  # coupled


BAD = [
    ('[body]\nname = "a"\nshape = "sphere"\nradius = 1.0\n' + _cyl("b", 5.0), "body", "not both"),
    (_cyl("a", 0.0) + _cyl("a", 5.0), "bodies[1].name", "used by bodies[0]"),
    (_cyl("a", 0.0) + _cyl("b", 1.5), "bodies[1].center", "overlaps"),
    ('[[bodies]]\nname = "r"\nshape = "compound"\n[[bodies.parts]]\nshape = "box"\nlength = 1.0\nwidth = 1.0\n',
     "bodies[0].parts[0].draft", "required"),
    ('[[bodies]]\nname = "r"\nshape = "compound"\n[[bodies.parts]]\nshape = "box"\nlength = 1.0\nwidth = 1.0\n'
     'draft = 1.0\n[[bodies.parts]]\nshape = "vertical_cylinder"\nradius = 0.2\ndraft = 2.0\n',
     "bodies[0].parts[1].center", "overlaps"),
    ('[[bodies]]\nname = "r"\nshape = "compound"\nradius = 1.0\n[[bodies.parts]]\nshape = "sphere"\n'
     'radius = 1.0\n', "bodies[0].radius", "not used"),
    ('[[bodies]]\nname = "r"\nshape = "compound"\n[[bodies.parts]]\nshape = "mesh"\nmesh = "x.gdf"\n',
     "bodies[0].parts[0].shape", ""),
    (_cyl("a", 0.0) + '[[bodies]]\nname = "b"\nshape = "vertical_cylinder"\nradius = 1.0\ndraft = 40.0\n'
     'center = [5.0, 0.0, 0.0]\n' + "[water]\ndepth = 30.0\n", "water.depth", "bodies[1] ('b')"),
]


@pytest.mark.parametrize("text, key, why", BAD)
def test_bad_multibody_specs_name_the_key(tmp_path, text, key, why):
    if "[water]" not in text:
        text += "[frequencies]\nvalues = [0.5, 1.0]\n"
    else:
        text = text.replace("[water]", "[frequencies]\nvalues = [0.5, 1.0]\n[water]")
    path = tmp_path / "bad.toml"
    path.write_text(text)
    with pytest.raises(SpecError) as err:
        load_spec(path)
    assert err.value.key == key and why in err.value.why, str(err.value)


# --- device specs ---------------------------------------------------------------------------------

# {body: (mass kg, centre of gravity (z None: not specified), z of the centre of buoyancy)}: masses,
# CoGs and buoyancy as documented in the examples' README files (F3OF: the paper's masses and CoGs,
# flaps with their buoyancy 0.5 m above the CoG; the scale models: rho V of the documented geometry)
NODE = 1000.0 * math.pi * 0.25 ** 2 * 0.6
V_BARGE1 = 1.1 * 0.67 * 0.37 + 2.2 * 1.34 * 0.02
DEVICES = {
    "f3of": {"base": (1_089_825.0, (0.0, 0.0, -9.0), -9.0), "flap1": (179_250.0, (-12.5, 0.0, -5.5), -5.0),
             "flap2": (179_250.0, (12.5, 0.0, -5.5), -5.0)},
    "hinged_barges": {
        "barge1": (1000.0 * V_BARGE1, (0.0, 0.0, None), (1.1 * 0.67 * 0.37 * -0.185 + 2.2 * 1.34 * 0.02 * -1.47) / V_BARGE1),
        "barge2": (1000.0 * 2.5 * 0.64 * 0.08, (2.26, 0.0, None), -0.04)},
    "node_4n3la": {n: (NODE, xy + (-0.3,), -0.3) for n, xy in
                   {"S3": (0.0, 0.0), "C1": (0.7, -1.21), "S1": (0.0, -2.42), "S2": (2.1, -1.21)}.items()},
    "node_9n9la": None,
}


@pytest.mark.parametrize("device", sorted(DEVICES))
def test_device_spec_masses_and_buoyancy(device):
    path = EXAMPLES / device / f"{device}_hdb.toml"
    assert load_spec(path).multibody
    # the same geometry on a coarse mesh (3x the panel size): volumes stay exact (boxes, equal-area
    # cylinder polygons), meshing takes a fraction of the time
    coarse = re.sub(r"panel_size = ([0-9.]+)", lambda m: f"panel_size = {3 * float(m.group(1))}", path.read_text())
    spec = parse_spec(coarse, path)
    hydro = body_hydrostatics(spec, path)
    expected = DEVICES[device] or {b.name: (NODE, (b.ref_point[0], b.ref_point[1], -0.3), -0.3)
                                   for b in spec.all_bodies}
    assert list(hydro) == list(expected)
    for name, (mass, cog, cob_z) in expected.items():
        h = hydro[name]
        assert h["mass"] == pytest.approx(mass, rel=0.01), name
        cob = h["center_of_buoyancy"]
        assert cob == pytest.approx([cog[0], cog[1], cob_z], abs=1e-6), name  # on the CoG's vertical
        if cog[2] is not None:
            assert cob[2] >= cog[2] - 1e-9, name  # buoyancy at or above the CoG: upright
        assert h["stiffness"][2, 2] > 0
    assert spec.frequencies.infinite


def test_device_layouts():
    barges = {b.name: b for b in load_spec(EXAMPLES / "hinged_barges" / "hinged_barges_hdb.toml").all_bodies}
    hinge = 0.78
    assert hinge - barges["barge1"].center[0] == pytest.approx(0.78)
    assert barges["barge2"].center[0] - hinge == pytest.approx(1.48)
    plate = barges["barge1"].parts[1]
    assert (plate.top - plate.draft) / 2 == pytest.approx(-1.47) and plate.draft + plate.top == pytest.approx(0.02)
    assert (plate.length, plate.width) == (2.2, 1.34)
    # 9N9LA: nine link arms of 1.4 m (hexagonal ring R0..R5 and O0-R0, O2-R2, O4-R4)
    nodes = {b.name: np.asarray(b.center[:2]) for b in
             load_spec(EXAMPLES / "node_9n9la" / "node_9n9la_hdb.toml").all_bodies}
    arms = [(f"R{i}", f"R{(i + 1) % 6}") for i in range(6)] + [(f"O{i}", f"R{i}") for i in (0, 2, 4)]
    assert len(nodes) == 9 and len(arms) == 9
    for a, b in arms:
        assert np.linalg.norm(nodes[a] - nodes[b]) == pytest.approx(1.4, abs=1e-5), (a, b)
    n4 = {b.name: np.asarray(b.center[:2]) for b in
          load_spec(EXAMPLES / "node_4n3la" / "node_4n3la_hdb.toml").all_bodies}
    for leaf in ("S1", "S2", "S3"):
        assert np.linalg.norm(n4[leaf] - n4["C1"]) == pytest.approx(1.4, abs=0.005)


def _gdf_boxes(path: Path, centers, size=(1.0, 1.0, 1.0)) -> None:
    """One WAMIT .gdf holding closed boxes (``size`` = length, width, draft; their freeboard is half
    the draft) at the given (x, y) centres: a frame of separate pontoons when there are several."""
    from test_hdb_build import _gdf_box
    panels = []
    for cx, cy in centers:
        one = path.with_suffix(".one.gdf")
        _gdf_box(one, size[0], size[1], size[2], 3)       # -L/2..L/2 x -W/2..W/2 x -T..T/2
        rows = one.read_text().splitlines()
        pts = np.array([[float(c) for c in r.split()] for r in rows[4:]]) + [cx, cy, 0.0]
        panels.append(pts)
        one.unlink()
    pts = np.concatenate(panels)
    path.write_text("\n".join(["frame", f"1.0 {9.81}", "0 0", str(len(pts) // 4)]
                              + [" ".join(f"{c:.9g}" for c in p) for p in pts]) + "\n")


def _frame_and_flap(tmp_path: Path, flap_x: float, flap_size: tuple) -> Path:
    """A frame of two 1 x 1 m pontoons, 1 m draft, at x = -2 and 2 (one mesh file: its bounding box
    spans -2.5..2.5) and a flap (a box of flap_size) at flap_x, each in its own mesh file."""
    _gdf_boxes(tmp_path / "frame.gdf", [(-2.0, 0.0), (2.0, 0.0)])
    _gdf_boxes(tmp_path / "flap.gdf", [(0.0, 0.0)], size=flap_size)
    path = tmp_path / "f.toml"
    path.write_text('[[bodies]]\nname = "frame"\nshape = "mesh"\nmesh = "frame.gdf"\n'
                    f'[[bodies]]\nname = "flap"\nshape = "mesh"\nmesh = "flap.gdf"\ncenter = [{flap_x}, 0.0, 0.0]\n'
                    "[frequencies]\nvalues = [1.0, 2.0]\n")
    return path


def test_a_flap_inside_the_frames_box_but_apart_builds(tmp_path):
    """The flap sits inside the frame's bounding box, 0.47 m from each pontoon: built (the check
    compares the meshes, not their boxes), with both bodies' displaced volumes (1 m^3 per box
    metre of length) and their hydrodynamic coupling."""
    ds = build_hdb(_frame_and_flap(tmp_path, 0.0, (2.06, 1.0, 1.0)), cache_dir=tmp_path / "cache", progress=False)
    assert ds["displaced_volume"].values == pytest.approx([2.0, 2.06], rel=1e-6)
    assert np.abs(ds["added_mass"].values[:, :6, 6:]).max() > 0


@pytest.mark.parametrize("flap_x, flap_size, how", [(0.6, (2.06, 1.0, 1.0), "intersects"),    # into a pontoon
                                                      (2.0, (0.4, 0.4, 0.5), "is inside or holds")])  # within it
def test_hulls_that_overlap_are_refused_naming_both(tmp_path, flap_x, flap_size, how):
    """A flap that cuts into a pontoon, or floats within one: refused, naming both bodies."""
    with pytest.raises(SpecError, match=rf"bodies\[1\]\.center: the immersed hull of 'flap' {how} that of "
                                        rf"bodies\[0\] \('frame'\)"):
        build_hdb(_frame_and_flap(tmp_path, flap_x, flap_size), cache_dir=tmp_path / "cache", progress=False)
