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
from typing import NamedTuple

import numpy as np

__all__ = ["Cut", "Hull", "MeshError", "clip_wet", "closed_hull", "corner_loads", "interpolate", "pressure_load",
           "rotation_xyz"]


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


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """a x b over the last axis (broadcast; np.cross without its axis handling, for the hot path)."""
    a0, a1, a2 = a[..., 0], a[..., 1], a[..., 2]
    b0, b1, b2 = b[..., 0], b[..., 1], b[..., 2]
    return np.stack([a1 * b2 - a2 * b1, a2 * b0 - a0 * b2, a0 * b1 - a1 * b0], axis=-1)


def _area_vectors(corners: np.ndarray) -> np.ndarray:
    """(T, 3) area vectors of triangles given as (T, 3, 3) corners."""
    return 0.5 * _cross(corners[:, 1] - corners[:, 0], corners[:, 2] - corners[:, 0])


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


class Cut(NamedTuple):
    """Where each corner of :func:`clip_wet`'s triangles lies: point = s c_i + (1 - s) c_j with c_i,
    c_j corners (local indices 0..2) of its source triangle ``src`` (s = 1, i = j for an original
    corner; s < 1 on the free surface)."""
    src: np.ndarray     # (W,)
    i: np.ndarray       # (W, 3)
    j: np.ndarray       # (W, 3)
    s: np.ndarray       # (W, 3)


def clip_wet(corners: np.ndarray, d: np.ndarray) -> tuple[np.ndarray, Cut]:
    """The wet part (d <= 0) of triangles with corners (T, 3, 3) and signed heights d (T, 3) above
    the free surface, as triangles (W, 3, 3) with the same orientation, and where their corners
    come from (:class:`Cut`; :func:`interpolate` carries any per-corner quantity over).

    A triangle with one wet corner a (the corners rolled so that the odd one is first) keeps
    (a, ab, ac); with two wet corners b, c it becomes (b, c, ca) and (b, ca, ab), ab the point of
    the edge a-b where d = 0 (linear interpolation)."""
    wet = d <= 0.0
    n_wet = wet.sum(axis=1)
    full = np.flatnonzero(n_wet == 3)
    part = np.flatnonzero((n_wet == 1) | (n_wet == 2))
    two = n_wet[part] == 2
    a = np.where(two, np.argmin(wet[part], axis=1), np.argmax(wet[part], axis=1))   # the odd corner
    b, c = (a + 1) % 3, (a + 2) % 3
    dp = d[part]
    rows = np.arange(len(part))
    da, db, dc = dp[rows, a], dp[rows, b], dp[rows, c]
    s_ab, s_ac = db / (db - da), dc / (dc - da)          # weight of a on a-b and on a-c
    ones = np.ones(len(part))
    # (i, j, s) of the three corners of the new triangles: one wet corner, then two (two triangles)
    shapes = ((~two, ((a, a, ones), (a, b, s_ab), (a, c, s_ac))),
              (two, ((b, b, ones), (c, c, ones), (a, c, s_ac))),
              (two, ((b, b, ones), (a, c, s_ac), (a, b, s_ab))))
    n_full = len(full)
    src = np.concatenate([full] + [part[sel] for sel, _ in shapes])
    i = np.empty((len(src), 3), int)
    j = np.empty((len(src), 3), int)
    s = np.empty((len(src), 3))
    i[:n_full], j[:n_full], s[:n_full] = np.arange(3), np.arange(3), 1.0
    k = n_full
    for sel, corners_of in shapes:
        n = int(sel.sum())
        for m, (ii, jj, ss) in enumerate(corners_of):
            i[k:k + n, m], j[k:k + n, m], s[k:k + n, m] = ii[sel], jj[sel], ss[sel]
        k += n
    cut = Cut(src, i, j, s)
    return interpolate(corners, cut), cut


def interpolate(values: np.ndarray, cut: Cut) -> np.ndarray:
    """A per-corner quantity (T, 3, ...) of the source triangles at the clipped triangles' corners."""
    v = values[cut.src]
    rows = np.arange(len(cut.src))[:, None]
    s = cut.s.reshape(cut.s.shape + (1,) * (v.ndim - 2))
    return s * v[rows, cut.i] + (1 - s) * v[rows, cut.j]


def pressure_load(corners: np.ndarray, pressure: np.ndarray) -> np.ndarray:
    """(6, ...) force and moment about the origin of the pressure (W, 3, ...) at the corners
    (W, 3, 3) (relative to the reference point) of wet triangles, pushing on the body (-p n);
    exact for a pressure linear over each triangle (module docstring). Trailing pressure
    dimensions (e.g. one per wave component) are kept."""
    loads = corner_loads(corners).reshape(-1, 6)
    flat = pressure.reshape((loads.shape[0], -1))
    return (loads.T @ flat).reshape((6,) + pressure.shape[2:])


def corner_loads(corners: np.ndarray) -> np.ndarray:
    """(T, 3, 6): the load (force, moment about the origin) per unit pressure at each corner of
    triangles (T, 3, 3), so that :func:`pressure_load` of corner pressures p (T, 3) is
    ``einsum("tc,tck->k", p, corner_loads(corners))``: the integral is linear in the corner values
    (module docstring: F = -sum S (p1 + p2 + p3) / 3, M = -sum (1/12) sum_i p_i (r_i + sum_j r_j) x S).
    For a hull that moves rigidly, computed once in its own frame and rotated with the body."""
    s = _area_vectors(corners)[:, None, :]                               # (T, 1, 3)
    q = corners + corners.sum(axis=1, keepdims=True)                     # (T, 3, 3): r_i + sum_j r_j
    out = np.empty(corners.shape[:2] + (6,))
    out[..., :3] = -s / 3.0
    out[..., 3:] = -_cross(q, s) / 12.0
    return out
