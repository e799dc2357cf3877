"""Generalized modes (issue 38): the build's beam and table modes (server/hdb/build/modes.py), their
hydrostatic stiffness against the potential energy's Hessian written here, the stored flexible
barge HDB (examples/data/flexible_barge) and the bad-input errors. No BEM solve here: the stored
HDB was built by ``hydrolink hdb build examples/flexible_barge/barge_hdb.toml``."""

from __future__ import annotations

import math
from pathlib import Path

import numpy as np
import pytest
from scipy.optimize import brentq

from conftest import body, scene_toml, write_gdf
from hydrolink.protocol.hdb.layout import HDBError, hdb_warnings
from hydrolink.protocol.hdb.schema import hdb_dofs
from hydrolink.protocol.scene import parse_scene
from hydrolink.server.hdb.build.builder import body_hydrostatics, load_spec, parse_spec
from hydrolink.server.hdb.build.modes import beam_roots, bending_shape
from hydrolink.server.hdb.build.spec import SpecError
from hydrolink.server.hdb.io import load_hdb
from hydrolink.server.model import HydroModel, ModelError

ROOT = Path(__file__).resolve().parents[1]
BARGE = ROOT / "examples" / "data" / "flexible_barge" / "flexible_barge.nc"
RHO, G = 1025.0, 9.81
SPEC = """
[body]
name = "barge"
shape = "box"
length = 40.0
width = 8.0
draft = 2.0
freeboard = 1.0
panel_size = 1.0
{modes}
[frequencies]
omega_min = 0.3
omega_max = 1.0
n = 2
[water]
density = 1025.0
"""
BENDING = '[[body.modes]]\nkind = "bending"\ndeflection = "z"\ncount = 2\n'


def free_free(xi: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The test's own k-th free-free mode (textbook form, scaled to 1 at the end) and its two
    derivatives in xi, its beta L a root of cos x cosh x = 1 found here."""
    bl = brentq(lambda x: math.cos(x) * math.cosh(x) - 1.0, (k + 0.5) * math.pi - 0.5, (k + 0.5) * math.pi + 0.5,
                xtol=1e-14)
    s = (math.cosh(bl) - math.cos(bl)) / (math.sinh(bl) - math.sin(bl))
    x = bl * xi
    return ((np.cosh(x) + np.cos(x) - s * (np.sinh(x) + np.sin(x))) / 2,
            bl * (np.sinh(x) - np.sin(x) - s * (np.cosh(x) + np.cos(x))) / 2,
            bl ** 2 * (np.cosh(x) - np.cos(x) - s * (np.sinh(x) - np.sin(x))) / 2)


def trapezoid(n: int = 20001) -> tuple[np.ndarray, np.ndarray]:
    xi = np.linspace(0.0, 1.0, n)
    w = np.full(n, 1.0 / (n - 1))
    w[[0, -1]] /= 2
    return xi, w


def test_free_free_beam_modes_give_the_analytic_natural_frequencies_in_vacuum():
    """A uniform beam (EI, m per metre, L) in the build's mode shapes: Rayleigh's quotient
    EI int phi''^2 / (m int phi^2) equals (beta_n L)^4 EI / (m L^4) (the textbook roots 4.7300,
    7.8532, 10.9956, 14.1372); the modes are orthogonal to heave and pitch (int phi = int x phi = 0)."""
    assert beam_roots(4) == pytest.approx((4.730040745, 7.853204624, 10.995607838, 14.137165491), abs=1e-8)
    ei, m, length = 2.0e9, 8.0e3, 40.0
    xi, w = trapezoid()
    for k, bl in enumerate(beam_roots(4), start=1):
        phi, d1, d2 = bending_shape(xi, k)
        ref_phi, ref_d1, ref_d2 = free_free(xi, k)
        np.testing.assert_allclose(np.c_[phi, d1, d2], np.c_[ref_phi, ref_d1, ref_d2], atol=1e-9 * bl ** 2)
        stiffness = ei / length ** 3 * np.sum(w * d2 ** 2)
        mass = m * length * np.sum(w * phi ** 2)
        assert math.sqrt(stiffness / mass) == pytest.approx(bl ** 2 * math.sqrt(ei / (m * length ** 4)), rel=1e-6)
        assert abs(np.sum(w * phi)) < 1e-8 and abs(np.sum(w * (xi - 0.5) * phi)) < 1e-8
        assert phi[0] == pytest.approx(1.0) and abs(phi[-1]) == pytest.approx(1.0)


@pytest.mark.slow   # 3-6 s: the box's hydrostatics at 1 m panels (Capytaine's quadrature, most of it the rigid part)
def test_mode_hydrostatics_equal_the_hessian_of_the_buoyancy_potential(tmp_path):
    """The box's heave and vertical bending rows of the built stiffness against the Hessian of
    E(q) = -rho g int over the immersed volume of z dV, the box moved by x = X + sum q V(X)
    (Euler-Bernoulli: V = (-Z phi'/L, 0, phi)), integrated in Z analytically per section here:
    C_ij = rho g B int [phi_i phi_j - d^2 (phi_i phi_j'' + phi_j phi_i'') / (2 L^2) + d^2 phi_i' phi_j' / L^2] dX.
    Within 0.5 % of the diagonal (panels of 1 m; 0.06 % at 0.5 m); a surging box loads no mode."""
    path = tmp_path / "box.toml"
    path.write_text(SPEC.format(modes=BENDING))
    hydro = body_hydrostatics(load_spec(path), path)["barge"]
    assert hydro["modes"] == ("bend_z1", "bend_z2")
    built = hydro["stiffness"][np.ix_([2, 6, 7], [2, 6, 7])]
    length, width, draft = 40.0, 8.0, 2.0
    xi, w = trapezoid()
    shapes = [(np.ones_like(xi), 0 * xi, 0 * xi), free_free(xi, 1), free_free(xi, 2)]
    ref = np.array([[RHO * G * width * length * np.sum(w * (p * q - draft ** 2 * (p * q2 + q * p2) / (2 * length ** 2)
                                                             + draft ** 2 * p1 * q1 / length ** 2))
                     for q, q1, q2 in shapes] for p, p1, p2 in shapes])
    scale = np.sqrt(np.outer(np.diag(ref), np.diag(ref)))
    assert np.max(np.abs(built - ref) / scale) < 5e-3, (built, ref)
    assert ref[0, 1] < -0.01 * scale[0, 1]          # the end sections' tilt: a real heave-bending coupling
    k = hydro["stiffness"]
    assert np.max(np.abs(k[6:, 0])) < 1e-6 * k[6, 6] and np.max(np.abs(k[6:, 1])) < 1e-6 * k[6, 6]   # clipping round-off


def test_the_stored_flexible_barge_hdb_is_read_with_its_modes():
    """The example HDB: 6 rigid + 2 bending + 1 torsion DOFs; A symmetric over all 9 DOFs
    (reciprocity, within 2.5 % of each pair's scale on these 2 m panels: the rigid pairs' spread
    is 2.1 %), B's diagonal >= 0; a head sea (0 deg) excites the symmetric bending mode 1 and not
    the torsion (antisymmetric in y), the 30 deg sea does."""
    ds = load_hdb(BARGE)
    dofs = hdb_dofs(ds)
    assert dofs.bodies == ("barge",) and dofs.of("barge") == ("bend_z1", "bend_z2", "twist1")
    assert dofs.counts == (9,) and ds.sizes["influenced_dof"] == 9
    a = ds["added_mass"].values
    scale = np.sqrt(np.abs(np.einsum("wii,wjj->wij", a, a))) + 1e-9 * np.abs(a).max()
    assert np.max(np.abs(a - a.transpose(0, 2, 1)) / scale) < 0.025
    assert np.all(np.diagonal(ds["radiation_damping"].values, axis1=1, axis2=2) >= -1e-6 * ds["radiation_damping"].values.max())
    f = np.abs(ds["excitation_force"].values)            # (omega, heading, dof)
    assert np.all(f[:, 0, 8] < 1e-6 * f[:, 0, 6].max()) and f[:, 1, 8].max() > 0.01 * f[:, 1, 6].max()
    assert f[:, 0, 6].max() > 0.01 * f[:, 0, 2].max()


def test_a_scene_with_the_modal_hdb_and_no_structure_is_refused_naming_its_modes_key():
    """A scene that gives the modal HDB to a body without its modes' structure is refused by name,
    never run on the rigid block alone (which would drop the modes' coupling silently); simulating
    them: tests/test_modes.py."""
    scene = parse_scene(scene_toml(dt=0.05, duration=1.0, bodies=[
        body("barge", hdb=str(BARGE), mass=RHO * 640.0, center_of_mass=[0, 0, -0.5], inertia=[4e6, 9e7, 9e7])],
        water={"density": RHO}))
    with pytest.raises(ModelError, match=r"bodies\[0\]\.modes: body 'barge'.* has 3 generalized mode\(s\) "
                                         r"\['bend_z1', 'bend_z2', 'twist1'\].*no modal mass"):
        HydroModel(scene, {"barge": load_hdb(BARGE)})


def test_bad_mode_input_is_an_error_naming_the_key(tmp_path):
    with pytest.raises(SpecError, match=r"body\.modes\.0\.bending\.deflection|body\.modes\[0\].*deflection"):
        parse_spec(SPEC.format(modes='[[body.modes]]\nkind = "bending"\ncount = 2\n'), "box.toml")
    with pytest.raises(SpecError, match=r"deflection"):
        parse_spec(SPEC.format(modes='[[body.modes]]\nkind = "torsion"\ncount = 1\ndeflection = "z"\n'), "box.toml")
    path = tmp_path / "box.toml"
    path.write_text(SPEC.format(modes=BENDING + BENDING))
    with pytest.raises(SpecError, match=r"box\.toml: body\.modes: two modes are named 'bend_z1'"):
        body_hydrostatics(load_spec(path), path)
    path.write_text(SPEC.format(modes='[[body.modes]]\nkind = "table"\nname = "sag"\nfile = "sag.csv"\n'))
    with pytest.raises(SpecError, match=r"body\.modes\[0\]\.kind: a displacement table needs a mesh-file body"):
        body_hydrostatics(load_spec(path), path)


def test_a_displacement_table_mode_reads_per_vertex_and_a_wrong_length_is_an_error(tmp_path):
    """A mesh-file box with a table mode moving every vertex up by 1 m (heave's field): its
    stiffness equals the rigid heave's C33 (rho g A_wp), with the warning that a table's row is
    Newman's formula alone; a table with one row too few is an error naming the file and key."""
    import capytaine as cpt

    box = cpt.mesh_parallelepiped(size=(10.0, 4.0, 3.0), center=(0.0, 0.0, -0.5), resolution=(10, 4, 3))
    write_gdf(tmp_path / "box.gdf", box.vertices, box.faces)
    n_vertices = cpt.load_mesh(str(tmp_path / "box.gdf")).nb_vertices
    np.savetxt(tmp_path / "up.csv", np.tile([0.0, 0.0, 1.0], (n_vertices, 1)), delimiter=",")
    spec = tmp_path / "mesh.toml"
    spec.write_text('[body]\nname = "box"\nshape = "mesh"\nmesh = "box.gdf"\n'
                    '[[body.modes]]\nkind = "table"\nname = "up"\nfile = "up.csv"\n'
                    '[frequencies]\nomega_min = 0.5\nomega_max = 1.0\nn = 2\n[water]\ndensity = 1025.0\n')
    with pytest.warns(UserWarning, match=r"box: mode 'up' is a displacement table"):
        k = body_hydrostatics(load_spec(spec), spec)["box"]["stiffness"]
    assert k.shape == (7, 7)
    assert k[6, 6] == pytest.approx(RHO * G * 40.0, rel=1e-9) and k[6, 6] == pytest.approx(k[2, 2], rel=1e-9)
    np.savetxt(tmp_path / "up.csv", np.tile([0.0, 0.0, 1.0], (n_vertices - 1, 1)), delimiter=",")
    with pytest.raises(SpecError, match=rf"mesh\.toml: body\.modes\[0\]\.file: up\.csv: {n_vertices - 1} rows of 3 "
                                        rf"columns; the mesh box\.gdf has {n_vertices} vertices"):
        body_hydrostatics(load_spec(spec), spec)


def test_an_hdb_with_modes_crosses_the_wire_with_its_mode_names():
    """SPEC 1.11: the HDB map carries ``modes``; the map read back equals the HDB, labels and all;
    a ``modes`` field naming an unknown body is an error naming it."""
    from hydrolink.protocol.hdb.wire import from_wire, to_wire

    ds = load_hdb(BARGE)
    data = to_wire(ds)
    assert data["modes"] == {"barge": ["bend_z1", "bend_z2", "twist1"]}
    back = from_wire(data, "hello.hdbs[0]")
    assert list(back["influenced_dof"].values) == list(ds["influenced_dof"].values)
    for name in ("added_mass", "radiation_damping", "excitation_force", "hydrostatic_stiffness", "added_mass_inf"):
        np.testing.assert_array_equal(back[name].values, ds[name].values)
    with pytest.raises(HDBError, match=r"hello\.hdbs\[0\]: modes: bodies \['hull'\] are not among"):
        from_wire({**data, "modes": {"hull": ["bend_z1"]}}, "hello.hdbs[0]")


def test_modes_with_second_order_or_a_free_surface_are_refused_naming_the_key():
    """The far-field drift and the free-surface solution are built for rigid DOFs only."""
    with pytest.raises(SpecError, match=r"second_order\.mean_drift: not with generalized modes \(body\.modes\)"):
        parse_spec(SPEC.format(modes=BENDING) + '[second_order]\nmean_drift = "far-field"\n', "box.toml")
    with pytest.raises(SpecError, match=r"free_surface: not with generalized modes \(body\.modes\)"):
        parse_spec(SPEC.format(modes=BENDING) + '[free_surface]\nomega = [1.0]\nextent = [-50, 50, -50, 50]\n'
                   'cells = [10, 10]\n', "box.toml")


def test_hdb_info_shows_the_modes():
    """``hdb info``: the body's modes with A_inf and the hydrostatic diagonal read from the HDB, the
    largest rigid-mode coupling (C(pitch, bend_z2): the antisymmetric mode and pitch), and --dofs
    taking a mode's name."""
    from hydrolink.server.hdb.info import _select_dofs, hdb_summary

    ds = load_hdb(BARGE)
    text = hdb_summary(ds)
    a_inf = ds["added_mass_inf"].sel(influenced_dof="barge.twist1", radiating_dof="barge.twist1").item()
    c = ds["hydrostatic_stiffness"].sel(influenced_dof="barge.bend_z1", radiating_dof="barge.bend_z1").item()
    assert "generalized modes (3, after the six rigid DOFs): bend_z1, bend_z2, twist1" in text
    assert f"twist1 {a_inf:.4g}" in text and f"bend_z1 {c:.5g}" in text
    assert "largest rigid-mode stiffness coupling: C(pitch, bend_z2)" in text
    assert "barge.twist1: B(w) re-transformed" in text           # the IRF check runs over the modes too
    assert _select_dofs(ds, ["heave", "twist1"]) == ["barge.heave", "barge.twist1"]    # --dofs takes a mode


def test_the_example_s_structure_gives_the_analytic_dry_frequencies_and_wet_ones_from_the_hdb():
    """examples/flexible_barge/responses.py: its uniform beam's modes in vacuum at the analytic
    free-free frequencies (beta_n L)^2 sqrt(EI / (m L^4)) and pi sqrt(GJ / (I_p L^2)) for the
    torsion, and bend_z1 in water where w^2 (M + A(w)) = K_s + C with the HDB's A and C; its RAOs
    solve the frequency-domain equations (residual at round-off)."""
    import importlib.util

    spec = importlib.util.spec_from_file_location("responses", ROOT / "examples" / "flexible_barge" / "responses.py")
    ex = importlib.util.module_from_spec(spec)
    spec.loader.exec_module(ex)
    ds = load_hdb(BARGE)
    m, k, names = ex.structure(ds)
    per_metre = RHO * float(ds["displaced_volume"].values[0]) / ex.LENGTH
    polar = per_metre * (ex.WIDTH ** 2 + ex.HEIGHT ** 2) / 12
    freqs = {name: (dry, wet) for name, dry, wet in ex.natural_frequencies(ds, m, k, names)}
    for n, bl in enumerate(beam_roots(2), start=1):
        assert freqs[f"bend_z{n}"][0] == pytest.approx(bl ** 2 * math.sqrt(ex.EI / (per_metre * ex.LENGTH ** 4)),
                                                       rel=1e-4)
    assert freqs["twist1"][0] == pytest.approx(math.pi * math.sqrt(ex.GJ / (polar * ex.LENGTH ** 2)), rel=1e-4)
    wet = freqs["bend_z1"][1]
    a = np.interp(wet, ds["omega"].values, ds["added_mass"].values[:, 6, 6])
    assert wet ** 2 * (m[6, 6] + a) == pytest.approx(k[6, 6] + ds["hydrostatic_stiffness"].values[6, 6], rel=1e-9)
    x = ex.responses(ds, m, k)
    i = 5
    w = ds["omega"].values[i]
    z = -w ** 2 * (m + ds["added_mass"].values[i]) - 1j * w * ds["radiation_damping"].values[i] \
        + ds["hydrostatic_stiffness"].values + k
    f = ds["excitation_force"].values[i, 1]
    assert np.max(np.abs(z @ x[i, 1] - f)) < 1e-9 * np.max(np.abs(f))
