"""A body's closed hull as a hello carries it (SPEC §5.1 ``hulls``): a closed, outward-oriented
triangle mesh in the global frame at equilibrium, checked once (:func:`closed_hull`); the terms
that integrate pressures over it (server/terms/nonlinear/) read it from their TermContext."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

__all__ = ["Hull", "MeshError", "closed_hull"]


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
