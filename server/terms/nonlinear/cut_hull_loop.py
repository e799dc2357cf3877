"""The cut-hull pressure integral as plain loops (server/terms/nonlinear/hull_kernel.py's docstring
says what it computes): compiled by server/terms/nonlinear/kernels_numba.py; no Python calls, so
that the compiled form has none."""

from __future__ import annotations

import numpy as np

__all__ = ["cut_hull_loads"]


def cut_hull_loads(local, tris, d, z, p, loads, vertex_loads, out):
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
