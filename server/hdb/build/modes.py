"""Generalized modes for ``hdb build`` (issue 38): each mode's displacement field on a body's hull
panels, for Capytaine's generalized DOFs, and its divergence, for the modes' hydrostatic stiffness.

Two kinds (``[[body.modes]]`` in the build spec, :mod:`.spec`):

* **Free-free beam modes** of a slender body along an axis (``kind = "bending"``: deflection
  along ``deflection``; ``kind = "torsion"``: twist about the axis). Euler-Bernoulli kinematics,
  plane sections staying normal to the neutral axis through the reference point r::

      bending   V_d = phi(s),  V_a = -(p_d - r_d) phi'(s)        div V = -(p_d - r_d) phi''(s)
      torsion   V = theta(s) e_a x (p - r)                      div V = 0

  with s the coordinate along the axis a, phi_n the n-th free-free bending mode
  ``cosh + cos - sigma_n (sinh + sin)`` of beta_n (s - s0) (cos(beta L) cosh(beta L) = 1), scaled
  to 1 at the beam's ends, theta_n = cos(n pi (s - s0) / L). Both are orthogonal to the rigid
  motions for a uniform beam.
* **A displacement table**: one row (dx, dy, dz) per vertex of a mesh-file body's mesh, in the
  file's vertex order; a panel moves with the mean of its vertices.
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path

import numpy as np

from hydrolink.server.hdb.build.spec import BodySpec, SpecError

AXES = "xyz"


@lru_cache(maxsize=None)
def beam_roots(n: int) -> tuple[float, ...]:
    """beta_k L of the first ``n`` free-free (elastic) bending modes: roots of cos x cosh x = 1."""
    from scipy.optimize import brentq

    f = lambda x: math.cos(x) * math.cosh(x) - 1.0   # noqa: E731
    return tuple(brentq(f, (k + 0.5) * math.pi - 0.5, (k + 0.5) * math.pi + 0.5, xtol=1e-14)
                 for k in range(1, n + 1))


def bending_shape(xi: np.ndarray, k: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The k-th (1-based) free-free bending mode at xi = (s - s0) / L in [0, 1], scaled to 1 at
    xi = 0: phi, d phi / d xi, d2 phi / d xi2."""
    bl = beam_roots(k)[-1]
    sigma = (math.cosh(bl) - math.cos(bl)) / (math.sinh(bl) - math.sin(bl))
    x = bl * np.asarray(xi, float)
    phi = np.cosh(x) + np.cos(x) - sigma * (np.sinh(x) + np.sin(x))
    d1 = bl * (np.sinh(x) - np.sin(x) - sigma * (np.cosh(x) + np.cos(x)))
    d2 = bl ** 2 * (np.cosh(x) - np.cos(x) - sigma * (np.sinh(x) - np.sin(x)))
    return phi / 2, d1 / 2, d2 / 2


@dataclass(frozen=True)
class ModeField:
    """One generalized mode on a hull's panels: displacement (F, 3) at the panel centres, its
    divergence (F,) and its gradient (F, 3, 3), ``gradient[f, i, k]`` = d V_i / d x_k (None: not
    known, a displacement table)."""
    name: str
    motion: np.ndarray
    divergence: np.ndarray
    gradient: np.ndarray | None


def _beam_field(mode, k: int, points: np.ndarray, ref: np.ndarray, ends: tuple[float, float]) -> ModeField:
    a = AXES.index(mode.axis)
    s0, s1 = ends
    length = s1 - s0
    xi = (points[:, a] - s0) / length
    motion, grad = np.zeros_like(points), np.zeros((len(points), 3, 3))
    if mode.kind == "torsion":
        theta, dtheta = np.cos(k * math.pi * xi), -k * math.pi / length * np.sin(k * math.pi * xi)
        axis = np.eye(3)[a]
        arm = np.cross(axis, points - ref)                    # e_a x (p - r)
        motion = theta[:, None] * arm
        grad[:] = np.cross(axis, np.eye(3)).T                 # d(e_a x p)_i / d x_k
        grad *= theta[:, None, None]
        grad[:, :, a] += arm * dtheta[:, None]
        return ModeField(f"{mode.prefix}{k}", motion, np.zeros(len(points)), grad)
    d = AXES.index(mode.deflection)
    phi, d1, d2 = bending_shape(xi, k)
    lever = points[:, d] - ref[d]
    motion[:, d] = phi
    motion[:, a] = -lever * d1 / length
    grad[:, d, a] = d1 / length
    grad[:, a, a] = -lever * d2 / length ** 2
    grad[:, a, d] = -d1 / length
    return ModeField(f"{mode.prefix}{k}", motion, -lever * d2 / length ** 2, grad)


def beam_ends(mode, hull) -> tuple[float, float]:
    """The beam's ends along its axis: the mode's ``ends``, else the hull's extent."""
    if mode.ends is not None:
        return float(mode.ends[0]), float(mode.ends[1])
    a = AXES.index(mode.axis)
    v = np.asarray(hull.vertices, float)[:, a]
    return float(v.min()), float(v.max())


def _table_motion(body: BodySpec, key: str, mode, spec_path, depth: float, centers: np.ndarray) -> np.ndarray:
    """A displacement table's motion at the final hull's panel centres (the clipped mesh's panels
    found by their centres: symmetry may have reordered them); ``key``: the mode's table."""
    from scipy.spatial import cKDTree

    from hydrolink.server.hdb.build.mesh import read_mesh_file

    full = read_mesh_file(body, key.split(".modes")[0], spec_path)
    rows = _table_rows(body, key, mode, spec_path, full.nb_vertices)
    per_face = rows[np.asarray(full.faces)].mean(axis=1)
    clipped = full.with_metadata(origin_panel=np.arange(full.nb_faces)).immersed_part(water_depth=depth)
    clipped, ids = clipped.pop_metadata("origin_panel")
    dist, at = cKDTree(np.asarray(clipped.faces_centers)).query(centers)
    scale = max(1.0, float(np.abs(centers).max()))
    if np.any(dist > 1e-6 * scale):
        raise SpecError(spec_path, f"{key}.file", "the solved hull's panels do not match the mesh file's "
                                                        "immersed panels (cannot place the table)")
    return per_face[np.asarray(ids)[at]]


def _table_rows(body: BodySpec, key: str, mode, spec_path, n_vertices: int) -> np.ndarray:
    """A displacement table's rows (n_vertices, 3); SpecError naming ``key``.file when it cannot be
    read, has another length than the mesh's vertices or holds NaN or inf."""
    table = table_path(mode, spec_path)
    try:
        rows = np.loadtxt(table, delimiter=",", ndmin=2, comments="#")
    except (OSError, ValueError) as exc:
        raise SpecError(spec_path, f"{key}.file", f"cannot read the displacement table {table}: {exc}") from None
    if rows.shape != (n_vertices, 3):
        raise SpecError(spec_path, f"{key}.file",
                        f"{table.name}: {rows.shape[0]} rows of {rows.shape[1]} columns; the mesh {body.mesh} has "
                        f"{n_vertices} vertices: one row (dx, dy, dz) per vertex, in the file's order")
    if not np.all(np.isfinite(rows)):
        raise SpecError(spec_path, f"{key}.file", f"{table.name}: NaN or inf in the table")
    return rows


def vertex_shapes(body: BodySpec, key: str, vertices: np.ndarray, spec_path) -> dict[str, np.ndarray]:
    """Each of the body's modes' displacement (V, 3) at its closed hull's ``vertices`` (global frame
    at rest, :func:`~hydrolink.server.hdb.build.mesh.closed_hull`: what ``hydrolink view`` deforms),
    in spec order: a beam mode's field there (its ends: the mode's ``ends``, else the extent of the
    vertices under the still water — the solved hull's for a wall-sided body), a displacement
    table's rows (a mesh body's vertices are its file's, in its order)."""
    ref = np.asarray(body.ref_point, float)
    wet = vertices[vertices[:, 2] <= 1e-9]
    out: dict[str, np.ndarray] = {}
    for j, mode in enumerate(body.modes or []):
        if mode.kind == "table":
            out[mode.name] = _table_rows(body, f"{key}.modes[{j}]", mode, spec_path, len(vertices))
            continue
        a = AXES.index(mode.axis)
        ends = ((float(mode.ends[0]), float(mode.ends[1])) if mode.ends is not None
                else (float(wet[:, a].min()), float(wet[:, a].max())))
        out.update((f.name, f.motion) for f in (_beam_field(mode, k, vertices, ref, ends)
                                                 for k in range(1, mode.count + 1)))
    return out


def table_path(mode, spec_path) -> Path:
    p = Path(mode.file).expanduser()
    return p if p.is_absolute() else Path(spec_path).resolve().parent / p


def mode_fields(body: BodySpec, key: str, hull, spec_path, depth: float) -> list[ModeField]:
    """The body's generalized modes on ``hull``'s panels (the mesh the BEM solves), in spec order."""
    centers = np.asarray(hull.faces_centers, float)
    ref = np.asarray(body.ref_point, float)
    out: list[ModeField] = []
    for j, mode in enumerate(body.modes or []):
        if mode.kind == "table":
            if body.shape != "mesh":
                raise SpecError(spec_path, f"{key}.modes[{j}].kind",
                                "a displacement table needs a mesh-file body (its rows are the file's vertices)")
            motion = _table_motion(body, f"{key}.modes[{j}]", mode, spec_path, depth, centers)
            out.append(ModeField(mode.name, motion, np.zeros(len(centers)), None))
            continue
        ends = beam_ends(mode, hull)
        if ends[1] - ends[0] <= 0:
            raise SpecError(spec_path, f"{key}.modes[{j}].ends", f"the beam's ends {ends} must be increasing")
        out += [_beam_field(mode, k, centers, ref, ends) for k in range(1, mode.count + 1)]
    names = [f.name for f in out]
    for i, name in enumerate(names):
        if name in names[:i]:
            raise SpecError(spec_path, f"{key}.modes", f"two modes are named {name!r}: give each its own name")
    return out


__all__ = ["ModeField", "beam_ends", "beam_roots", "bending_shape", "mode_fields", "vertex_shapes"]
