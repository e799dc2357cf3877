"""The pressure integral over a closed hull's instantaneous wetted surface (issue 10, nonlinear
hydrostatics and Froude–Krylov; server/terms/nonlinear/term.py uses it).

A :class:`~hydrolink.server.terms.hulls.Hull` (server/terms/hulls.py) is a closed, outward-oriented triangle mesh in the global frame at equilibrium,
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

from typing import NamedTuple

import numpy as np

from hydrolink.server.terms.hulls import _area_vectors, _cross

__all__ = ["Cut", "clip_wet", "corner_loads", "interpolate", "pressure_load", "rotation_xyz"]


def rotation_xyz(angles: np.ndarray) -> np.ndarray:
    """The rotation matrix of Tait–Bryan angles (rx, ry, rz): Rx(rx) Ry(ry) Rz(rz) (Exudyn's Rxyz
    node, the angles a client sends in ``position``)."""
    a, b, c = (float(v) for v in angles)
    ca, sa, cb, sb, cc, sc = np.cos(a), np.sin(a), np.cos(b), np.sin(b), np.cos(c), np.sin(c)
    rx = np.array([[1, 0, 0], [0, ca, -sa], [0, sa, ca]])
    ry = np.array([[cb, 0, sb], [0, 1, 0], [-sb, 0, cb]])
    rz = np.array([[cc, -sc, 0], [sc, cc, 0], [0, 0, 1]])
    return rx @ ry @ rz


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
