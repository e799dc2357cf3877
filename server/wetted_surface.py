"""A body's closed hull and the pressure integral over its instantaneous wetted surface (issue 10,
nonlinear hydrostatics and Froude–Krylov; server/nonlinear_hydro.py uses it).

A :class:`Hull` is a closed, outward-oriented triangle mesh in the global frame at equilibrium,
stored relative to the body's reference point. Each step :func:`clip_wet` cuts its triangles, in
their current pose, where the signed height above the free surface ``d = z - eta(x, y)`` changes
sign (linear interpolation along the edges), and keeps the wet side (d <= 0) as triangles.
:func:`pressure_load` integrates a pressure given at those triangles' corners, linearly
interpolated over each triangle: exactly (no quadrature error) for a pressure linear in position,
such as the hydrostatic -rho g z, so buoyancy and its moment are exact for the polyhedron:

    F = -sum_T (p1 + p2 + p3)/3 S_T,     M = -sum_T (1/12)(sum_i p_i r_i + (sum_i p_i)(sum_i r_i)) x S_T

with S_T the triangle's area vector (outward normal times area) and r_i its corners relative to the
reference point (the integral of p r over a triangle with p, r linear is A/12 (sum p_i r_i +
sum p_i sum r_i)).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Hull", "MeshError", "clip_wet", "closed_hull", "interpolate", "pressure_load", "rotation_xyz"]


class MeshError(ValueError):
    """A hull the nonlinear forces cannot use; ``why`` says what is wrong with it."""

    def __init__(self, why: str):
        super().__init__(why)
        self.why = why


@dataclass(frozen=True)
class Hull:
    """A closed triangle mesh with outward triangles."""
    vertices: np.ndarray     # (V, 3) global frame at equilibrium, or relative to a body's reference point
    triangles: np.ndarray    # (T, 3) vertex indices, counter-clockwise seen from outside
    volume: float            # enclosed volume [m^3]

    @property
    def n_triangles(self) -> int:
        return len(self.triangles)


def rotation_xyz(angles: np.ndarray) -> np.ndarray:
    """The rotation matrix of Tait–Bryan angles (rx, ry, rz): Rx(rx) Ry(ry) Rz(rz) (Exudyn's Rxyz
    node, the angles a client sends in ``position``)."""
    a, b, c = (float(v) for v in angles)
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return rx @ ry @ rz


def _area_vectors(corners: np.ndarray) -> np.ndarray:
    """(T, 3) area vectors of triangles given as (T, 3, 3) corners."""
    return 0.5 * np.cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])


def closed_hull(vertices: np.ndarray, faces: np.ndarray) -> Hull:
    """A :class:`Hull` from a panel mesh (triangles, or quads whose repeated corner makes a
    triangle) in the global frame at equilibrium.

    Coincident vertices (closer than 1e-6 of the mesh's size) are merged and degenerate triangles
    dropped. The mesh must be closed: every edge shared by exactly two triangles, traversed in
    opposite directions (MeshError naming how many edges are open or inconsistent, and where).
    Inward-facing meshes (negative volume) are turned outward."""
    v = np.asarray(vertices, float)
    f = np.asarray(faces)
    if v.ndim != 2 or v.shape[1] != 3 or not len(v):
        raise MeshError(f"vertices must be (V, 3), got {v.shape}")
    if not np.all(np.isfinite(v)):
        raise MeshError("vertices hold non-finite values")
    if f.ndim != 2 or f.shape[1] not in (3, 4) or not len(f) or not np.issubdtype(f.dtype, np.integer):
        raise MeshError(f"faces must be integer (F, 3) or (F, 4) vertex indices, got {f.dtype} {f.shape}")
    if f.min() < 0 or f.max() >= len(v):
        raise MeshError(f"faces index vertices {int(f.min())}..{int(f.max())} but there are {len(v)}")
    size = float(np.ptp(v, axis=0).max()) or 1.0
    key = np.round(v / (1e-6 * size)).astype(np.int64)
    _, first, inverse = np.unique(key, axis=0, return_index=True, return_inverse=True)
    inverse = inverse.reshape(-1)
    verts = v[first]
    f = inverse[f]
    tris = f[:, :3] if f.shape[1] == 3 else np.vstack([f[:, [0, 1, 2]], f[:, [0, 2, 3]]])
    tris = tris[(tris[:, 0] != tris[:, 1]) & (tris[:, 1] != tris[:, 2]) & (tris[:, 2] != tris[:, 0])]
    areas = np.linalg.norm(_area_vectors(verts[tris]), axis=1)
    tris = tris[areas > 1e-12 * size * size]
    if not len(tris):
        raise MeshError("no triangle of non-zero area")
    edges = np.concatenate([tris[:, [0, 1]], tris[:, [1, 2]], tris[:, [2, 0]]])
    directed, counts = np.unique(edges, axis=0, return_counts=True)
    undirected, u_counts = np.unique(np.sort(edges, axis=1), axis=0, return_counts=True)
    open_edges = undirected[u_counts == 1]
    if len(open_edges):
        mid = 0.5 * (verts[open_edges[:, 0]] + verts[open_edges[:, 1]])
        z = mid[:, 2]
        raise MeshError(f"the mesh is not closed: {len(open_edges)} edges belong to one panel only (z from "
                        f"{z.min():.4g} to {z.max():.4g} m, e.g. at {np.round(mid[0], 4).tolist()}); nonlinear "
                        "hydrostatics need the whole hull, freeboard and deck included (a BEM mesh of the immersed "
                        "part, open at the waterline, will not do)")
    if np.any(u_counts > 2) or np.any(counts > 1):
        bad = int(np.sum(u_counts > 2) + np.sum(counts > 1))
        raise MeshError(f"the mesh is not a consistent closed surface: {bad} edges are shared by more than two "
                        "panels or traversed twice in one direction (panels with mixed orientation)")
    corners = verts[tris]
    volume = float(np.sum(np.einsum("ti,ti->t", corners[:, 0], np.cross(corners[:, 1], corners[:, 2])))) / 6.0
    if volume < 0:
        tris, volume = tris[:, ::-1].copy(), -volume
    if volume <= 1e-12 * size ** 3:
        raise MeshError(f"the mesh encloses no volume ({volume:.3g} m^3)")
    return Hull(verts, np.ascontiguousarray(tris), volume)


def clip_wet(corners: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The wet part (d <= 0) of triangles with corners (T, 3, 3) and signed heights d (T, 3) above
    the free surface, as triangles.

    Returns their corners (W, 3, 3), the source triangle of each (W,) and, per corner, the weight
    of the first of the two original corners it lies between together with those corners' local
    indices: (W, 3, 3) as (i, j, s) with the point = s c_i + (1 - s) c_j (s = 1, i = j for an
    original corner). A caller interpolates any per-corner quantity with the same weights."""
    wet = d <= 0.0
    n_wet = wet.sum(axis=1)
    t_all = np.flatnonzero(n_wet == 3)
    t_one = np.flatnonzero(n_wet == 1)
    t_two = np.flatnonzero(n_wet == 2)
    # the odd corner (the wet one of one-wet triangles, the dry one of two-wet ones) first, keeping
    # the orientation: (a, b, c) with a odd
    odd_one = np.argmax(wet[t_one], axis=1)
    odd_two = np.argmin(wet[t_two], axis=1)

    def cut(tri, a, b):
        """Weight s of corner a on the edge a-b where d = 0 (point = s c_a + (1 - s) c_b)."""
        da, db = d[tri, a], d[tri, b]
        return db / (db - da)

    specs = []   # (triangles, (i, j, s) for three corners)
    ones = np.ones(len(t_all))
    specs.append((t_all, [(np.zeros(len(t_all), int), np.zeros(len(t_all), int), ones),
                          (np.ones(len(t_all), int), np.ones(len(t_all), int), ones),
                          (np.full(len(t_all), 2), np.full(len(t_all), 2), ones)]))
    a, b, c = odd_one, (odd_one + 1) % 3, (odd_one + 2) % 3
    one = np.ones(len(t_one))
    specs.append((t_one, [(a, a, one), (a, b, cut(t_one, a, b)), (a, c, cut(t_one, a, c))]))
    a, b, c = odd_two, (odd_two + 1) % 3, (odd_two + 2) % 3
    one = np.ones(len(t_two))
    s_ab, s_ac = cut(t_two, b, a), cut(t_two, c, a)     # weights of the wet corners b, c
    specs.append((t_two, [(b, b, one), (c, c, one), (c, a, s_ac)]))
    specs.append((t_two, [(b, b, one), (c, a, s_ac), (b, a, s_ab)]))
    src = np.concatenate([t for t, _ in specs])
    w = np.zeros((len(src), 3, 3))
    k = 0
    for tri, cs in specs:
        n = len(tri)
        for m, (i, j, s) in enumerate(cs):
            w[k:k + n, m, 0], w[k:k + n, m, 1], w[k:k + n, m, 2] = i, j, s
        k += n
    i, j, s = w[..., 0].astype(int), w[..., 1].astype(int), w[..., 2]
    c_src = corners[src]
    rows = np.arange(len(src))[:, None]
    pts = s[..., None] * c_src[rows, i] + (1 - s)[..., None] * c_src[rows, j]
    return pts, src, w


def interpolate(values: np.ndarray, src: np.ndarray, w: np.ndarray) -> np.ndarray:
    """A per-corner quantity (T, 3, ...) of the source triangles at the clipped triangles' corners
    (:func:`clip_wet`'s ``src`` and weights)."""
    i, j, s = w[..., 0].astype(int), w[..., 1].astype(int), w[..., 2]
    v = values[src]
    rows = np.arange(len(src))[:, None]
    s = s.reshape(s.shape + (1,) * (v.ndim - 2))
    return s * v[rows, i] + (1 - s) * v[rows, j]


def pressure_load(corners: np.ndarray, pressure: np.ndarray) -> np.ndarray:
    """(6, ...) force and moment about the origin of the pressure (W, 3, ...) at the corners
    (W, 3, 3) (relative to the reference point) of wet triangles, pushing on the body (-p n);
    exact for a pressure linear over each triangle (module docstring). Trailing pressure
    dimensions (e.g. one per wave component) are kept."""
    s = _area_vectors(corners)
    p_sum = pressure.sum(axis=1)                                          # (W, ...)
    force = -np.einsum("w...,wi->i...", p_sum, s) / 3.0
    lever = np.einsum("wk...,wki->wi...", pressure, corners) + np.einsum("w...,wi->wi...", p_sum, corners.sum(axis=1))
    sx, sy, sz = (s[:, i].reshape((-1,) + (1,) * (pressure.ndim - 2)) for i in range(3))
    lx, ly, lz = lever[:, 0], lever[:, 1], lever[:, 2]
    moment = -np.stack([(ly * sz - lz * sy).sum(axis=0), (lz * sx - lx * sz).sum(axis=0),
                        (lx * sy - ly * sx).sum(axis=0)]) / 12.0
    return np.concatenate([force, moment])
