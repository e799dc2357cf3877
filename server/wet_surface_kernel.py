"""The pressure integral over a hull cut by the free surface, compiled (issue 26; numba, optional).

It does what server/nonlinear_hydro.py's numpy path does with
:func:`~hydrolink.server.wetted_surface.clip_wet`, :func:`~hydrolink.server.wetted_surface.interpolate`
and :func:`~hydrolink.server.wetted_surface.corner_loads`: every wet vertex adds its pressures times
the fixed corner loads of all its triangles (summed per vertex at set-up), which is the wholly wet
triangles' integral once the cut triangles' wet corners are taken off again; a triangle the surface
cuts is clipped where the signed height d = 0 (linear along its edges; the same sub-triangles and
orientation as ``clip_wet``) and each piece adds its corner pressures times its own corner loads
(F = -S sum p_i / 3, M = -sum_i p_i (r_i + sum_j r_j) x S / 12, S the area vector); a dry one
adds nothing.

Two pressures at once, per unit rho g: the hydrostatic one -z and the Froude–Krylov one (given at
the wet vertices; on the free surface equal to the height there, z = eta). The wet vertices' part
is one matrix product of their two pressures with their load sums, the pieces' loads add up in
local variables (no store and reload of the result per term): 53 µs instead of 108 on the
8,260-triangle sphere.
"""

from __future__ import annotations

import numpy as np
from hydrolink.server.incident_kernels import AVAILABLE

__all__ = ["AVAILABLE", "cut_hull_loads", "warm_up"]


def _cut_hull_loads(local, tris, d, z, p, loads, vertex_loads, out):
    w = np.zeros((2, d.size))   # each wet vertex's two pressures, to weigh its triangles' corner loads ...
    wet = np.empty(d.size, np.int64)
    for v in range(d.size):
        wet[v] = 1 if d[v] <= 0.0 else 0
        if wet[v]:
            w[0, v], w[1, v] = -z[v], p[v]
    r = np.empty((2, 3, 3))     # up to two pieces of a cut triangle: corners, then their pressures
    ph, pf = np.empty((2, 3)), np.empty((2, 3))
    ab, ac = np.empty(3), np.empty(3)      # the cut points on edges a-b and a-c
    h0 = h1 = h2 = h3 = h4 = h5 = f0 = f1 = f2 = f3 = f4 = f5 = 0.0    # the pieces' loads, per pressure
    for t in range(tris.shape[0]):
        n = wet[tris[t, 0]] + wet[tris[t, 1]] + wet[tris[t, 2]]
        if n == 0 or n == 3:
            continue
        for c in range(3):      # ... less those of the cut triangles, which are clipped instead
            v = tris[t, c]
            if wet[v]:
                for k in range(6):
                    out[0, k] += z[v] * loads[t, c, k]
                    out[1, k] -= p[v] * loads[t, c, k]
        a = 0                   # the odd corner: the wet one of one, the dry one of two
        for c in range(3):
            if (wet[tris[t, c]] == 1) == (n == 1):
                a = c
        ia, ib, ic = tris[t, a], tris[t, (a + 1) % 3], tris[t, (a + 2) % 3]
        s_ab = d[ib] / (d[ib] - d[ia])     # the weight of a
        s_ac = d[ic] / (d[ic] - d[ia])
        z_ab = s_ab * z[ia] + (1.0 - s_ab) * z[ib]
        z_ac = s_ac * z[ia] + (1.0 - s_ac) * z[ic]
        # on the free surface (s < 1) p_FK = z; at a corner (s = 1) the corner's own value
        f_ab = z_ab if s_ab < 1.0 else s_ab * p[ia] + (1.0 - s_ab) * p[ib]
        f_ac = z_ac if s_ac < 1.0 else s_ac * p[ia] + (1.0 - s_ac) * p[ic]
        for k in range(3):
            ab[k] = s_ab * local[ia, k] + (1.0 - s_ab) * local[ib, k]
            ac[k] = s_ac * local[ia, k] + (1.0 - s_ac) * local[ic, k]
        if n == 1:              # (a, ab, ac)
            for k in range(3):
                r[0, 0, k], r[0, 1, k], r[0, 2, k] = local[ia, k], ab[k], ac[k]
            ph[0, 0], ph[0, 1], ph[0, 2] = -z[ia], -z_ab, -z_ac
            pf[0, 0], pf[0, 1], pf[0, 2] = p[ia], f_ab, f_ac
        else:                   # (b, c, ca) and (b, ca, ab)
            for k in range(3):
                r[0, 0, k], r[0, 1, k], r[0, 2, k] = local[ib, k], local[ic, k], ac[k]
                r[1, 0, k], r[1, 1, k], r[1, 2, k] = local[ib, k], ac[k], ab[k]
            ph[0, 0], ph[0, 1], ph[0, 2] = -z[ib], -z[ic], -z_ac
            pf[0, 0], pf[0, 1], pf[0, 2] = p[ib], p[ic], f_ac
            ph[1, 0], ph[1, 1], ph[1, 2] = -z[ib], -z_ac, -z_ab
            pf[1, 0], pf[1, 1], pf[1, 2] = p[ib], f_ac, f_ab
        for q in range(n):      # each piece (one of one wet corner, two of two): F = -S sum p / 3, M = -sum p_i (r_i + R) x S / 12
            e1x, e1y, e1z = r[q, 1, 0] - r[q, 0, 0], r[q, 1, 1] - r[q, 0, 1], r[q, 1, 2] - r[q, 0, 2]
            e2x, e2y, e2z = r[q, 2, 0] - r[q, 0, 0], r[q, 2, 1] - r[q, 0, 1], r[q, 2, 2] - r[q, 0, 2]
            sx, sy, sz = 0.5 * (e1y * e2z - e1z * e2y), 0.5 * (e1z * e2x - e1x * e2z), 0.5 * (e1x * e2y - e1y * e2x)
            rx = r[q, 0, 0] + r[q, 1, 0] + r[q, 2, 0]
            ry = r[q, 0, 1] + r[q, 1, 1] + r[q, 2, 1]
            rz = r[q, 0, 2] + r[q, 1, 2] + r[q, 2, 2]
            for i in range(3):
                qx, qy, qz = r[q, i, 0] + rx, r[q, i, 1] + ry, r[q, i, 2] + rz
                mx, my, mz = qy * sz - qz * sy, qz * sx - qx * sz, qx * sy - qy * sx
                wh, wf = ph[q, i], pf[q, i]
                h0, h1, h2, h3, h4, h5 = h0 - wh * sx, h1 - wh * sy, h2 - wh * sz, h3 - wh * mx, h4 - wh * my, h5 - wh * mz
                f0, f1, f2, f3, f4, f5 = f0 - wf * sx, f1 - wf * sy, f2 - wf * sz, f3 - wf * mx, f4 - wf * my, f5 - wf * mz
    out += w @ vertex_loads     # every wet vertex with all its triangles' corner loads
    pieces = ((h0, h1, h2, h3, h4, h5), (f0, f1, f2, f3, f4, f5))
    for row in range(2):
        for k in range(6):
            out[row, k] += pieces[row][k] / (3.0 if k < 3 else 12.0)


def _compiled():
    """The kernel compiled (or loaded from numba's cache) on first use, with server/incident_numba.py's
    kernels: numba is imported only by a scene that needs it (its import costs about half a second)."""
    from hydrolink.server import incident_numba
    return incident_numba.cut_hull_loads


def cut_hull_loads(local: np.ndarray, triangles: np.ndarray, d: np.ndarray, z: np.ndarray, p: np.ndarray,
                   loads: np.ndarray, vertex_loads: np.ndarray) -> np.ndarray:
    """(2, 6): the load (force, moment about the reference point, in the body's frame) per unit
    rho g of the hydrostatic pressure -z and of the Froude–Krylov pressure ``p`` over the part of
    the hull below the free surface (module docstring). ``local`` (V, 3) vertices relative to the
    reference point in the body's frame, ``triangles`` (T, 3), ``d`` (V,) signed heights above the
    free surface, ``z`` (V,) global heights, ``p`` (V,) the Froude–Krylov pressure / (rho g) at the
    wet vertices, ``loads`` (T, 3, 6) the triangles' corner loads (corner_loads of ``local``) and
    ``vertex_loads`` (V, 6) their sums over each vertex's triangles."""
    out = np.zeros((2, 6))
    f, c = np.float64, np.ascontiguousarray     # one compiled signature: contiguous float64 and int64
    _compiled()(c(local, f), c(triangles, np.int64), c(d, f), c(z, f), c(p, f), c(loads, f), c(vertex_loads, f), out)
    return out


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernel now, at set-up, not in a run's first step."""
    local = np.array([[0.0, 0.0, -1.0], [1.0, 0.0, 1.0], [0.0, 1.0, 1.0]])
    cut_hull_loads(local, np.array([[0, 1, 2]]), local[:, 2], local[:, 2], np.zeros(3), np.zeros((1, 3, 6)),
                   np.zeros((3, 6)))
