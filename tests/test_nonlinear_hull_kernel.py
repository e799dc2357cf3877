"""The compiled pressure integral over a cut hull (server/hull_kernel.py) against the numpy
one written from the clipping functions of server/terms/nonlinear/hull.py: a sphere hull cut by a
wavy surface at random poses, the hydrostatic pressure -z and a smooth pressure field."""

from __future__ import annotations

import numpy as np
import pytest
from hydrolink.server import compiler
from hydrolink.server.terms.nonlinear import hull_kernel
from hydrolink.server.terms.nonlinear.hull import clip_wet, corner_loads, interpolate, pressure_load, rotation_xyz
from hydrolink.server.terms.hulls import closed_hull

cpt = pytest.importorskip("capytaine")
pytestmark = pytest.mark.skipif(not compiler.AVAILABLE, reason="numba not installed")


def test_cut_hull_loads_equal_the_clipped_integral():
    mesh = cpt.mesh_sphere(radius=2.0, resolution=(14, 18))
    mesh = mesh.merged() if hasattr(mesh, "merged") else mesh
    hull = closed_hull(mesh.vertices, mesh.faces)
    loads = corner_loads(hull.vertices[hull.triangles])
    rng = np.random.default_rng(7)
    for _ in range(20):
        pose = np.concatenate([rng.uniform(-1.0, 1.0, 3), rng.uniform(-0.6, 0.6, 3)])
        verts = pose[:3] + hull.vertices @ rotation_xyz(pose[3:]).T
        eta = 0.4 * np.sin(1.3 * verts[:, 0] + 0.7 * verts[:, 1])
        d = verts[:, 2] - eta
        p = np.where(d <= 0.0, np.cos(verts[:, 0]) * np.exp(verts[:, 2]), 0.0)
        vertex_loads = np.zeros((len(hull.vertices), 6))
        np.add.at(vertex_loads, hull.triangles.reshape(-1), loads.reshape(-1, 6))
        got = hull_kernel.cut_hull_loads(hull.vertices, hull.triangles, d, verts[:, 2], p, loads, vertex_loads)
        # the reference: clip every triangle, interpolate both pressures, integrate (body frame)
        tris = hull.triangles
        pts, cut = clip_wet(hull.vertices[tris], d[tris])
        z_c = interpolate(verts[tris, 2], cut)
        p_c = interpolate(p[tris], cut)
        p_c[cut.s < 1.0] = z_c[cut.s < 1.0]
        want = np.stack([pressure_load(pts, -z_c), pressure_load(pts, p_c)])
        scale = np.abs(want).max(axis=1, keepdims=True)
        np.testing.assert_allclose(got, want, rtol=0, atol=1e-12 * scale.max())
