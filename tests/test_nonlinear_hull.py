"""server/terms/nonlinear/hull.py: closed hulls, cutting at the free surface, the pressure integral.

References written here, independent of the module: the spherical cap's volume; Capytaine's own
clipping (``Mesh.immersed_part``) and volume of the same polyhedron; the prism of a polygonal
cylinder; a box at large pitch angles against a 2-D polygon clip (Sutherland-Hodgman) of its
rotated cross-section, whose area and centroid give the buoyancy and its moment exactly."""

from __future__ import annotations

import numpy as np
import pytest

from hydrolink.server.terms.hulls import MeshError, closed_hull
from hydrolink.server.terms.nonlinear.hull import clip_wet, pressure_load, rotation_xyz

cpt = pytest.importorskip("capytaine")


def _plain(mesh):
    return mesh.merged() if hasattr(mesh, "merged") else mesh


def _buoyancy(hull, offset=(0.0, 0.0, 0.0), rotation=np.eye(3)):
    """(6,) buoyancy / (rho g) and its moment about the moved reference point, still water."""
    offset = np.asarray(offset, float)
    corners = hull.vertices[hull.triangles] @ rotation.T + offset
    pts, _ = clip_wet(corners, corners[..., 2])
    return pressure_load(pts - offset, -pts[..., 2])


SPHERE = _plain(cpt.mesh_sphere(radius=1.0, resolution=(40, 80)))


@pytest.mark.parametrize("centre_z", [0.7, 0.25, 0.0, -0.4, -1.5])
def test_sphere_buoyancy_is_the_immersed_volume(centre_z):
    hull = closed_hull(SPHERE.vertices, SPHERE.faces)
    f = _buoyancy(hull, (0.0, 0.0, centre_z))
    # the polyhedron exactly: Capytaine clips the same mesh and measures the part below z = 0
    clipped = SPHERE.translated((0.0, 0.0, centre_z)).immersed_part()
    assert f[2] == pytest.approx(clipped.volume, rel=1e-10)
    # the sphere: cap of height h = 1 - z_c. The mesh is inscribed in the sphere, so its part below
    # the plane misses less than the whole mesh misses (0.26 % of 4/3 pi)
    h = min(max(1.0 - centre_z, 0.0), 2.0)
    cap = np.pi * h * h * (3.0 - h) / 3.0
    deficit = 4 / 3 * np.pi - hull.volume
    assert deficit / (4 / 3 * np.pi) == pytest.approx(0.00257, abs=1e-4)
    assert 0.0 <= cap - f[2] <= deficit
    assert np.abs(f[[0, 1, 3, 4, 5]]).max() < 1e-10


def test_vertical_cylinder_buoyancy_is_a_prism():
    n, r = 48, 1.5
    mesh = _plain(cpt.mesh_vertical_cylinder(length=4.0, radius=r, center=(0, 0, -1.0), resolution=(3, n, 8)))
    hull = closed_hull(mesh.vertices, mesh.faces)
    polygon = 0.5 * n * r * r * np.sin(2 * np.pi / n)    # the mesh's cross-section
    for heave in (-0.9, 0.0, 0.45, 2.5):
        draft = min(max(3.0 - heave, 0.0), 4.0)       # bottom at -3 + heave, top at 1 + heave
        f = _buoyancy(hull, (0.0, 0.0, heave))
        assert f[2] == pytest.approx(polygon * draft, rel=1e-10)
        assert f[2] == pytest.approx(np.pi * r * r * draft, rel=3e-3)


def _clip_polygon(poly: np.ndarray) -> np.ndarray:
    """Sutherland-Hodgman: the part of a closed polygon (x, z) with z <= 0."""
    out = []
    for a, b in zip(poly, np.roll(poly, -1, axis=0)):
        if a[1] <= 0:
            out.append(a)
        if (a[1] <= 0) != (b[1] <= 0):
            s = a[1] / (a[1] - b[1])
            out.append(a + s * (b - a))
    return np.array(out)


def _area_centroid(poly: np.ndarray) -> tuple[float, np.ndarray]:
    x, z = poly[:, 0], poly[:, 1]
    cross = x * np.roll(z, -1) - np.roll(x, -1) * z
    area = cross.sum() / 2
    cx = ((x + np.roll(x, -1)) * cross).sum() / (6 * area)
    cz = ((z + np.roll(z, -1)) * cross).sum() / (6 * area)
    return area, np.array([cx, cz])


@pytest.mark.parametrize("degrees", [5.0, 20.0, 35.0, 60.0])
def test_box_pitch_restoring_at_large_angles_matches_the_wedge_geometry(degrees):
    length, width, draft, freeboard = 4.0, 2.0, 1.0, 0.8
    mesh = _plain(cpt.mesh_parallelepiped(size=(length, width, draft + freeboard),
                                          center=(0, 0, (freeboard - draft) / 2), resolution=(8, 4, 6)))
    hull = closed_hull(mesh.vertices, mesh.faces)
    theta = np.deg2rad(degrees)
    f = _buoyancy(hull, rotation=rotation_xyz([0.0, theta, 0.0]))
    # the cross-section (x, z) rotated by the pitch (x -> x cos + z sin, z -> -x sin + z cos), then cut
    c, s = np.cos(theta), np.sin(theta)
    corners = np.array([[-length / 2, -draft], [length / 2, -draft], [length / 2, freeboard], [-length / 2, freeboard]])
    rotated = corners @ np.array([[c, -s], [s, c]])
    area, (xb, zb) = _area_centroid(_clip_polygon(rotated))
    volume = area * width
    assert f[2] == pytest.approx(volume, rel=1e-10)
    assert f[0] == pytest.approx(0.0, abs=1e-10) and f[1] == pytest.approx(0.0, abs=1e-10)
    # moment about the reference point (origin) of the upward force V at the centre of buoyancy
    assert f[4] == pytest.approx(-xb * volume, rel=1e-9, abs=1e-12)
    assert abs(f[3]) < 1e-10 and abs(f[5]) < 1e-10
    if degrees == 5.0:   # small angle: the linear restoring rho g (I_wp + V z_B) theta (per rho g)
        linear = (width * length ** 3 / 12 + volume * -draft / 2) * theta
        assert -f[4] == pytest.approx(linear, rel=0.01)


def test_pressure_load_keeps_trailing_dimensions():
    hull = closed_hull(SPHERE.vertices, SPHERE.faces)
    corners = hull.vertices[hull.triangles][:50]
    rng = np.random.default_rng(1)
    p = rng.normal(size=(50, 3, 4))
    stacked = pressure_load(corners, p)
    assert stacked.shape == (6, 4)
    for j in range(4):
        assert np.allclose(stacked[:, j], pressure_load(corners, p[:, :, j]), rtol=1e-13, atol=1e-13)


def test_clipping_keeps_orientation_and_area():
    """The wet part of a tilted unit square cut by z = 0: its area vector stays outward."""
    square = np.array([[[0, 0, -1.0], [1, 0, 1.0], [1, 1, 1.0]], [[0, 0, -1.0], [1, 1, 1.0], [0, 1, -1.0]]])
    pts, cut = clip_wet(square, square[..., 2])
    s = 0.5 * np.cross(pts[:, 1] - pts[:, 0], pts[:, 2] - pts[:, 0]).sum(axis=0)
    full = 0.5 * np.cross(square[:, 1] - square[:, 0], square[:, 2] - square[:, 0]).sum(axis=0)
    assert np.allclose(s, full / 2)     # half the square is below z = 0, same direction
    assert set(cut.src.tolist()) == {0, 1}


def test_hull_checks_name_what_is_wrong():
    immersed = _plain(cpt.mesh_vertical_cylinder(length=2.0, radius=1.0, center=(0, 0, 0), resolution=(2, 24, 4))
                      .immersed_part())
    with pytest.raises(MeshError, match=r"not closed: \d+ edges belong to one panel only \(z from 0 to 0 m"):
        closed_hull(immersed.vertices, immersed.faces)
    faces = SPHERE.faces.copy()
    faces[0] = faces[0][::-1]
    with pytest.raises(MeshError, match="mixed orientation"):
        closed_hull(SPHERE.vertices, faces)
    with pytest.raises(MeshError, match="index vertices"):
        closed_hull(SPHERE.vertices, SPHERE.faces + len(SPHERE.vertices))
    with pytest.raises(MeshError, match="non-finite"):
        closed_hull(np.full((3, 3), np.nan), np.array([[0, 1, 2]]))
    inward = closed_hull(SPHERE.vertices, SPHERE.faces[:, ::-1])
    assert inward.volume == pytest.approx(closed_hull(SPHERE.vertices, SPHERE.faces).volume, rel=1e-12)
