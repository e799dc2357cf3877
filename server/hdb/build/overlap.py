"""Whether two bodies' immersed hulls overlap, told from the meshes themselves.

Bounding boxes are not enough: a flap between the pontoons of a frame sits inside the frame's box
though the hulls are apart. Two closed surfaces overlap when (a) they cross: an edge of one passes
through a triangle of the other (Moller-Trumbore, on the pairs a k-d tree finds within reach), or
(b) one holds the other: a vertex of one of its connected pieces is inside the other (generalised
winding number; an immersed hull is open at z = 0, so it is closed with its mirror image above the
water first; surfaces that do not cross leave each piece wholly in or out), or
(c) they touch: vertices of both closer than TOUCH of the bodies' size (coincident panels, which
a BEM solve cannot take). Otherwise they are apart, at any distance.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy.sparse import coo_matrix
from scipy.sparse.csgraph import connected_components
from scipy.spatial import cKDTree

TOUCH = 1e-6          # vertices closer than this fraction of the larger body's size: touching
_CHUNK = 200_000      # (point, triangle) or (edge, triangle) pairs per vectorised batch


@dataclass(frozen=True)
class Hull:
    """A body's immersed hull as triangles (T, 3, 3), its vertices (V, 3) and one vertex of each of
    its connected pieces (C, 3), global frame."""

    triangles: np.ndarray
    vertices: np.ndarray
    pieces: np.ndarray

    @classmethod
    def from_mesh(cls, vertices: np.ndarray, faces: np.ndarray) -> "Hull":
        """From Capytaine's vertices and quadrilateral faces (a triangle repeats its last vertex);
        vertices that coincide (a panel file lists each panel's own) are merged first."""
        v, f = np.asarray(vertices, float), np.asarray(faces, int)
        scale = float(np.abs(v).max()) or 1.0
        _, first, index = np.unique(np.round(v / (1e-9 * scale)), axis=0, return_index=True, return_inverse=True)
        v, f = v[first], index.ravel()[f]
        used = np.unique(f)
        tris = np.concatenate([v[f[:, [0, 1, 2]]], v[f[:, [0, 2, 3]]]])
        area2 = np.linalg.norm(np.cross(tris[:, 1] - tris[:, 0], tris[:, 2] - tris[:, 0]), axis=1)
        ring = np.concatenate([f[:, [0, 1]], f[:, [1, 2]], f[:, [2, 3]], f[:, [3, 0]]])
        graph = coo_matrix((np.ones(len(ring)), (ring[:, 0], ring[:, 1])), shape=(len(v), len(v)))
        _, label = connected_components(graph, directed=False)
        _, one = np.unique(label[used], return_index=True)
        return cls(tris[area2 > 0], v[used], v[used[one]])

    @property
    def low(self) -> np.ndarray:
        return self.vertices.min(axis=0)

    @property
    def high(self) -> np.ndarray:
        return self.vertices.max(axis=0)

    def closed(self) -> np.ndarray:
        """The triangles with their mirror image about z = 0 (orientation kept): a closed surface
        for a hull clipped at the free surface; a submerged hull's mirror lies wholly above it."""
        mirror = self.triangles[:, ::-1].copy()
        mirror[..., 2] *= -1.0
        return np.concatenate([self.triangles, mirror])

    def edges(self) -> np.ndarray:
        """Each triangle's three edges as segments (3T, 2, 3)."""
        t = self.triangles
        return np.concatenate([t[:, [0, 1]], t[:, [1, 2]], t[:, [2, 0]]])


def winding_numbers(points: np.ndarray, triangles: np.ndarray) -> np.ndarray:
    """Generalised winding number of each point about a closed triangulated surface (1 inside,
    0 outside; Van Oosterom and Strackee's solid angle per triangle)."""
    out = np.zeros(len(points))
    step = max(1, _CHUNK // max(len(triangles), 1))
    for s in range(0, len(points), step):
        r = triangles[None, :, :, :] - points[s:s + step, None, None, :]      # (P, T, 3, 3)
        n = np.linalg.norm(r, axis=-1)
        a, b, c = r[..., 0, :], r[..., 1, :], r[..., 2, :]
        det = np.einsum("ptk,ptk->pt", a, np.cross(b, c))
        den = (n[..., 0] * n[..., 1] * n[..., 2] + np.einsum("ptk,ptk->pt", a, b) * n[..., 2]
               + np.einsum("ptk,ptk->pt", b, c) * n[..., 0] + np.einsum("ptk,ptk->pt", c, a) * n[..., 1])
        out[s:s + step] = np.arctan2(det, den).sum(axis=1) / (2 * np.pi)
    return out


def _crossings(segments: np.ndarray, triangles: np.ndarray, eps: float = 1e-12) -> bool:
    """Whether any segment i passes through triangle i (paired arrays; Moller-Trumbore)."""
    for s in range(0, len(segments), _CHUNK):
        p, q = segments[s:s + _CHUNK, 0], segments[s:s + _CHUNK, 1]
        t = triangles[s:s + _CHUNK]
        d = q - p
        e1, e2 = t[:, 1] - t[:, 0], t[:, 2] - t[:, 0]
        h = np.cross(d, e2)
        det = np.einsum("ij,ij->i", e1, h)
        ok = np.abs(det) > eps * np.linalg.norm(e1, axis=1) * np.linalg.norm(e2, axis=1) * np.linalg.norm(d, axis=1)
        inv = np.where(ok, 1.0 / np.where(ok, det, 1.0), 0.0)
        sv = p - t[:, 0]
        u = np.einsum("ij,ij->i", sv, h) * inv
        qv = np.cross(sv, e1)
        v = np.einsum("ij,ij->i", d, qv) * inv
        w = np.einsum("ij,ij->i", e2, qv) * inv
        if np.any(ok & (u >= 0) & (v >= 0) & (u + v <= 1) & (w >= 0) & (w <= 1)):
            return True
    return False


def _edges_cross(a: Hull, b: Hull) -> bool:
    """Whether an edge of ``b`` passes through a triangle of ``a``."""
    edges = b.edges()
    centroids = a.triangles.mean(axis=1)
    reach = (np.linalg.norm(a.triangles - centroids[:, None], axis=-1).max()
             + 0.5 * np.linalg.norm(edges[:, 1] - edges[:, 0], axis=-1).max())
    pairs = cKDTree(edges.mean(axis=1)).sparse_distance_matrix(cKDTree(centroids), reach, output_type="ndarray")
    return bool(len(pairs)) and _crossings(edges[pairs["i"]], a.triangles[pairs["j"]])


def _inside(points: np.ndarray, hull: Hull) -> bool:
    """Whether any of ``points`` is inside ``hull`` (only those within its bounding box are tried).
    Called once the surfaces are known not to cross: one point per connected piece decides."""
    near = points[np.all((points > hull.low) & (points < hull.high), axis=1)]
    return bool(len(near)) and bool(np.any(np.abs(winding_numbers(near, hull.closed())) > 0.5))


@dataclass(frozen=True)
class Overlap:
    """How two hulls overlap (``how``: "intersect", "contains", "touch"), or None when apart."""

    how: str | None
    detail: str


def overlap(a: Hull, b: Hull) -> Overlap:
    """Whether hulls ``a`` and ``b`` intersect, one holds the other, or they touch (module docstring)."""
    if np.any(a.low > b.high) or np.any(b.low > a.high):
        return Overlap(None, "bounding boxes apart")
    gap = float(cKDTree(a.vertices).query(b.vertices)[0].min())
    size = float(max(np.linalg.norm(a.high - a.low), np.linalg.norm(b.high - b.low)))
    if _edges_cross(a, b) or _edges_cross(b, a):
        return Overlap("intersect", "their surfaces cross")
    if _inside(b.pieces, a) or _inside(a.pieces, b):
        return Overlap("contains", "one is inside the other")
    if gap < TOUCH * size:
        return Overlap("touch", f"vertices {gap:.3g} m apart")
    return Overlap(None, f"closest vertices {gap:.3g} m apart")
