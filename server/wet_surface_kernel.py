"""The pressure integral over a hull cut by the free surface, compiled (issue 26; numba, optional).

One pass over the hull's triangles does what server/nonlinear_hydro.py's numpy path does with
:func:`~hydrolink.server.wetted_surface.clip_wet`, :func:`~hydrolink.server.wetted_surface.interpolate`
and :func:`~hydrolink.server.wetted_surface.corner_loads`: a wholly wet triangle adds its corner
pressures times its fixed corner loads; a triangle the surface cuts is clipped where the signed
height d = 0 (linear along its edges; the same sub-triangles and orientation as ``clip_wet``) and
each piece adds its corner pressures times its own corner loads (F = -S sum p_i / 3,
M = -sum_i p_i (r_i + sum_j r_j) x S / 12, S the area vector); a dry one adds nothing.

Two pressures at once, per unit rho g: the hydrostatic one -z and the Froude–Krylov one (given at
the wet vertices; on the free surface equal to the height there, z = eta).
"""

from __future__ import annotations

import numpy as np

from hydrolink.server.incident_kernels import AVAILABLE

__all__ = ["AVAILABLE", "cut_hull_loads", "warm_up"]


def _add_piece(r, ph, pf, out):
    """A triangle's corners r (3, 3) with pressures ph, pf (3,) added to out (2, 6)."""
    e1x, e1y, e1z = r[1, 0] - r[0, 0], r[1, 1] - r[0, 1], r[1, 2] - r[0, 2]
    e2x, e2y, e2z = r[2, 0] - r[0, 0], r[2, 1] - r[0, 1], r[2, 2] - r[0, 2]
    sx, sy, sz = 0.5 * (e1y * e2z - e1z * e2y), 0.5 * (e1z * e2x - e1x * e2z), 0.5 * (e1x * e2y - e1y * e2x)
    rx, ry, rz = r[0, 0] + r[1, 0] + r[2, 0], r[0, 1] + r[1, 1] + r[2, 1], r[0, 2] + r[1, 2] + r[2, 2]
    for i in range(3):
        qx, qy, qz = r[i, 0] + rx, r[i, 1] + ry, r[i, 2] + rz
        mx, my, mz = qy * sz - qz * sy, qz * sx - qx * sz, qx * sy - qy * sx
        for row in range(2):
            q = ph[i] if row == 0 else pf[i]
            out[row, 0] -= q * sx / 3.0
            out[row, 1] -= q * sy / 3.0
            out[row, 2] -= q * sz / 3.0
            out[row, 3] -= q * mx / 12.0
            out[row, 4] -= q * my / 12.0
            out[row, 5] -= q * mz / 12.0


def _cut_hull_loads(local, tris, d, z, p, loads, out):
    r = np.empty((3, 3))
    ph, pf = np.empty(3), np.empty(3)
    pos = np.empty((4, 3))      # the odd corner a, then b, c; the cut points ab, ac (weights of a)
    for t in range(tris.shape[0]):
        n = 0
        for c in range(3):
            if d[tris[t, c]] <= 0.0:
                n += 1
        if n == 0:
            continue
        if n == 3:
            for c in range(3):
                v = tris[t, c]
                for k in range(6):
                    out[0, k] -= z[v] * loads[t, c, k]
                    out[1, k] += p[v] * loads[t, c, k]
            continue
        a = 0                   # the odd corner: the wet one of one, the dry one of two
        for c in range(3):
            if (d[tris[t, c]] <= 0.0) == (n == 1):
                a = c
        ia, ib, ic = tris[t, a], tris[t, (a + 1) % 3], tris[t, (a + 2) % 3]
        s_ab = d[ib] / (d[ib] - d[ia])
        s_ac = d[ic] / (d[ic] - d[ia])
        z_ab = s_ab * z[ia] + (1.0 - s_ab) * z[ib]
        z_ac = s_ac * z[ia] + (1.0 - s_ac) * z[ic]
        # on the free surface (s < 1) p_FK = z; at a corner (s = 1) the corner's own value
        f_ab = z_ab if s_ab < 1.0 else s_ab * p[ia] + (1.0 - s_ab) * p[ib]
        f_ac = z_ac if s_ac < 1.0 else s_ac * p[ia] + (1.0 - s_ac) * p[ic]
        for k in range(3):
            pos[0, k] = s_ab * local[ia, k] + (1.0 - s_ab) * local[ib, k]
            pos[1, k] = s_ac * local[ia, k] + (1.0 - s_ac) * local[ic, k]
        if n == 1:              # (a, ab, ac)
            for k in range(3):
                r[0, k], r[1, k], r[2, k] = local[ia, k], pos[0, k], pos[1, k]
            ph[0], ph[1], ph[2] = -z[ia], -z_ab, -z_ac
            pf[0], pf[1], pf[2] = p[ia], f_ab, f_ac
            _add_piece(r, ph, pf, out)
            continue
        for k in range(3):      # (b, c, ca) and (b, ca, ab)
            r[0, k], r[1, k], r[2, k] = local[ib, k], local[ic, k], pos[1, k]
        ph[0], ph[1], ph[2] = -z[ib], -z[ic], -z_ac
        pf[0], pf[1], pf[2] = p[ib], p[ic], f_ac
        _add_piece(r, ph, pf, out)
        for k in range(3):
            r[0, k], r[1, k], r[2, k] = local[ib, k], pos[1, k], pos[0, k]
        ph[0], ph[1], ph[2] = -z[ib], -z_ac, -z_ab
        pf[0], pf[1], pf[2] = p[ib], f_ac, f_ab
        _add_piece(r, ph, pf, out)


if AVAILABLE:
    import numba
    _jit = numba.njit(cache=True, nogil=True, error_model="numpy")
    _add_piece = _jit(_add_piece)
    _cut_hull_loads = _jit(_cut_hull_loads)


def cut_hull_loads(local: np.ndarray, triangles: np.ndarray, d: np.ndarray, z: np.ndarray, p: np.ndarray,
                   loads: np.ndarray) -> np.ndarray:
    """(2, 6): the load (force, moment about the reference point, in the body's frame) per unit
    rho g of the hydrostatic pressure -z and of the Froude–Krylov pressure ``p`` over the part of
    the hull below the free surface (module docstring). ``local`` (V, 3) vertices relative to the
    reference point in the body's frame, ``triangles`` (T, 3), ``d`` (V,) signed heights above the
    free surface, ``z`` (V,) global heights, ``p`` (V,) the Froude–Krylov pressure / (rho g) at the
    wet vertices, ``loads`` (T, 3, 6) the triangles' corner loads (corner_loads of ``local``)."""
    out = np.zeros((2, 6))
    f, c = np.float64, np.ascontiguousarray     # one compiled signature: contiguous float64 and int64
    _cut_hull_loads(c(local, f), c(triangles, np.int64), c(d, f), c(z, f), c(p, f), c(loads, f), out)
    return out


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernel now, at set-up, not in a run's first step."""
    local = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]])
    cut_hull_loads(local, np.array([[0, 1, 2]]), local[:, 2], local[:, 2], np.zeros(3), np.zeros((1, 3, 6)))
