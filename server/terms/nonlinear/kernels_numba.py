"""The compiled kernels of server/terms/nonlinear/kernels.py (numba; this module is imported only from
there, on first use, so that numba is imported only by a scene that needs it).

Each sum is a loop over the components (or orders) outside and over a block of points inside,
vectorised by the compiler, the block's running values in the first-level cache. Floating-point
contraction (a fused multiply-add for a product and a sum) is the only liberty taken with the
arithmetic; the cosines, sines and exponentials of many values at once are server/terms/nonlinear/vector_math.py's
(vectorised, not a C library call a value). :func:`hull_pressure` is one body's whole incident wave
for one step: the pieces below composed, with no Python between them; :func:`hull_step` with
:func:`hull_loads` its whole step, the fixed inputs held in a :class:`HullState`.
"""

from __future__ import annotations

import math

import numpy as np
from hydrolink.server import compiler
from hydrolink.server.terms.nonlinear import vector_math
from hydrolink.server.terms.nonlinear.rows import reply_rows as _reply_rows
from hydrolink.server.terms.nonlinear.cut_hull_loop import cut_hull_loads as _cut_hull_loads

numba = compiler.load()      # numba with 512-bit vectors where the CPU has them (server/compiler.py)
from numba.core import types  # (after numba's set-up above)
from numba.experimental import structref

_jit = numba.njit(cache=True, nogil=True, error_model="numpy", fastmath={"contract"})
_BLOCK = 128   # points per pass over a block

cut_hull_loads = _jit(_cut_hull_loads)   # server/terms/nonlinear/cut_hull_loop.py, callable from the kernels here
reply_rows = _jit(_reply_rows)           # server/terms/nonlinear/rows.py's
sincos = _jit(vector_math.sincos)        # server/terms/nonlinear/vector_math.py's: vectorised, not one C library call a value
exp = _jit(vector_math.exp)


@_jit
def _blocks(n):
    """(n, _BLOCK): a block's running values, each row starting on a 64-byte boundary (numba's
    arrays start on 32: a 512-bit load of an unaligned row spans two cache lines; measured 12 %
    slower in deep_pressure)."""
    raw = np.empty(n * _BLOCK + 8)
    o = ((-raw.ctypes.data) % 64) // 8
    return raw[o:o + n * _BLOCK].reshape((n, _BLOCK))


@_jit
def deep_pressure(xi, z, ar, ai, tail, k0, dk, d2, out):
    """out += sum_c Re(a_c e^{k_c (z + i xi)}), k_c = k0 + c dk + c (c - 1) d2 / 2 (incident_kernels).
    Each block of points stops at the component past which the rest add at most 2^-53 sum |a_c|
    at its highest point (faster where the points come sorted by height); ``tail`` sum_{c' >= c}
    |a_c'| to any common scale (the amplitudes' at set-up)."""
    p_n, n_c = xi.size, ar.size
    tol = 2.0 ** -53 * tail[0] if n_c else 0.0
    b = _blocks(7)
    ur, ui, rr, ri, qr, qi, acc = b[0], b[1], b[2], b[3], b[4], b[5], b[6]
    arg, mag = np.empty((2, 3 * _BLOCK)), np.empty(3 * _BLOCK)      # the three powers' phases, heights; e^...
    cs = np.empty((2, 3 * _BLOCK))
    for s in range(0, p_n, _BLOCK):
        m = min(_BLOCK, p_n - s)
        top = -math.inf
        for p in range(m):
            x, h = xi[s + p], z[s + p]
            top = max(top, h)
            arg[0, p], arg[0, m + p], arg[0, 2 * m + p] = k0 * x, dk * x, d2 * x
            arg[1, p], arg[1, m + p], arg[1, 2 * m + p] = k0 * h, dk * h, d2 * h
            acc[p] = 0.0
        sincos(arg[0, :3 * m], cs[0, :3 * m], cs[1, :3 * m])
        exp(arg[1, :3 * m], mag[:3 * m])
        for p in range(m):
            ur[p], ui[p] = mag[p] * cs[0, p], mag[p] * cs[1, p]
            rr[p], ri[p] = mag[m + p] * cs[0, m + p], mag[m + p] * cs[1, m + p]
            qr[p], qi[p] = mag[2 * m + p] * cs[0, 2 * m + p], mag[2 * m + p] * cs[1, 2 * m + p]
        lo, hi = 0, n_c                 # the fewest components c_n whose rest, tail[c_n] e^{k_c_n top}, is below tol
        while lo < hi:
            mid = (lo + hi) // 2
            if tail[mid] * math.exp((k0 + mid * dk + 0.5 * mid * (mid - 1.0) * d2) * top) <= tol:
                hi = mid
            else:
                lo = mid + 1
        n_b = lo
        c = 0
        while c + 2 <= n_b:     # two components per pass over the block: half the loads and stores
            a0r, a0i, a1r, a1i = ar[c], ai[c], ar[c + 1], ai[c + 1]
            for p in range(m):
                xr, xs, yr, ys, zr, zs = ur[p], ui[p], rr[p], ri[p], qr[p], qi[p]
                t = a0r * xr - a0i * xs
                xr, xs = xr * yr - xs * ys, xr * ys + xs * yr
                yr, ys = yr * zr - ys * zs, yr * zs + ys * zr
                acc[p] += t + (a1r * xr - a1i * xs)
                ur[p], ui[p] = xr * yr - xs * ys, xr * ys + xs * yr
                rr[p], ri[p] = yr * zr - ys * zs, yr * zs + ys * zr
            c += 2
        if c < n_b:
            for p in range(m):
                acc[p] += ar[c] * ur[p] - ai[c] * ui[p]
        for p in range(m):
            out[s + p] += acc[p]


@_jit
def binned_chebyshev_sum(u, c, out):
    """out += sum_n c[j, n] T_n(v), j the bin of u among len(c) equal bins of [-1, 1], v its
    coordinate in the bin (incident_kernels.binned_chebyshev_sum)."""
    n_b, n = c.shape
    p_n = u.size
    which = np.empty(p_n, np.int64)
    for p in range(p_n):
        which[p] = min(max(int((u[p] + 1.0) * 0.5 * n_b), 0), n_b - 1)
    order, first = _grouped(which, n_b)
    b = _blocks(4)
    v, w, b1, b2 = b[0], b[1], b[2], b[3]
    for j in range(n_b):
        centre = -1.0 + (2.0 * j + 1.0) / n_b
        for s in range(first[j], first[j + 1], _BLOCK):
            m = min(_BLOCK, first[j + 1] - s)
            for q in range(m):
                x = min(max((u[order[s + q]] - centre) * n_b, -1.0), 1.0)
                v[q], w[q], b1[q], b2[q] = x, 2.0 * x, 0.0, 0.0
            k = n - 1
            while k >= 2:       # Clenshaw, two orders per pass over the block
                ca, cb = c[j, k], c[j, k - 1]
                for q in range(m):
                    t = w[q] * b1[q] - b2[q] + ca
                    b2[q] = t
                    b1[q] = w[q] * t - b1[q] + cb
                k -= 2
            if k == 1:
                ca = c[j, 1]
                for q in range(m):
                    t = w[q] * b1[q] - b2[q] + ca
                    b2[q] = b1[q]
                    b1[q] = t
            c0 = c[j, 0]
            for q in range(m):
                out[order[s + q]] += v[q] * b1[q] - b2[q] + c0


@_jit
def bin_coefficients(even, odd, tr, ti, sr, si, out):
    """out[j, n]: the bins' Jacobi–Anger coefficients (server/terms/nonlinear/elevation_series.py's _Bins): the
    phasors at bin j's centre, Re times the even orders' weights and Im times the odd ones', as
    two matrix products (BLAS: a third of the time of a loop over each component's orders)."""
    n_b, n_c = sr.shape
    yr, yi = np.empty((n_b, n_c)), np.empty((n_b, n_c))
    for j in range(n_b):
        for c in range(n_c):
            yr[j, c] = tr[c] * sr[j, c] - ti[c] * si[j, c]
            yi[j, c] = tr[c] * si[j, c] + ti[c] * sr[j, c]
    e, o = yr @ even, yi @ odd
    for j in range(n_b):
        for m in range(e.shape[1]):
            out[j, 2 * m] = e[j, m]
        for m in range(o.shape[1]):
            out[j, 2 * m + 1] = o[j, m]


@_jit
def _gather(cols, x_re, x_im, out_re, out_im):
    """out = x[cols]."""
    for i in range(cols.size):
        out_re[i], out_im[i] = x_re[cols[i]], x_im[cols[i]]


@_jit
def _along(ox, oy, dx, dy, scale, clip, out):
    """out = (ox dx + oy dy) * scale, held within [-1, 1] where ``clip`` (a series' coordinate)."""
    for p in range(ox.size):
        x = (ox[p] * dx + oy[p] * dy) * scale
        out[p] = min(max(x, -1.0), 1.0) if clip else x


@_jit
def _grouped(key, n):
    """(order, first): the indices of ``key`` (values in [0, n)) grouped by value in increasing
    order, each group in index order (a counting sort); group v is order[first[v]:first[v + 1]]."""
    first = np.zeros(n + 1, np.int64)
    for p in range(key.size):
        first[key[p] + 1] += 1
    for v in range(n):
        first[v + 1] += first[v]
    order, fill = np.empty(key.size, np.int64), first[:n].copy()
    for p in range(key.size):
        order[fill[key[p]]] = p
        fill[key[p]] += 1
    return order, first


@_jit
def _by_height(z, floor):
    """The order of ``z`` (in [floor, 0]) from the highest, by 64 bands (a counting sort)."""
    band = np.empty(z.size, np.int64)
    for i in range(z.size):
        band[i] = min(max(int(z[i] / floor * 64.0), 0), 63) if floor < 0.0 else 0
    return _grouped(band, 64)[0]


@_jit
def elevation_sum(e, x_re, x_im, ox, oy, u, out):
    """out += the elevation at points with horizontal offsets ``ox``, ``oy`` from the reference
    point: each heading's Jacobi–Anger series by bins (``e`` an ElevationTable), the components'
    phasors at the reference point ``x``; ``u`` scratch, as long as the points."""
    for g in range(e.direction.shape[0]):
        cols = e.columns[e.start[g]:e.start[g + 1]]
        n_g, n_b, n_o = cols.size, e.bins[g], e.orders[g]
        tr, ti = np.empty(n_g), np.empty(n_g)
        _gather(cols, x_re, x_im, tr, ti)
        w0, n_e = e.weight_start[g], (n_o + 1) // 2
        even = e.weights[w0:w0 + n_g * n_e].reshape((n_g, n_e))
        odd = e.weights[w0 + n_g * n_e:w0 + n_g * n_o].reshape((n_g, n_o - n_e))
        s0 = e.shift_start[g]
        sr = e.shift_re[s0:s0 + n_b * n_g].reshape((n_b, n_g))
        si = e.shift_im[s0:s0 + n_b * n_g].reshape((n_b, n_g))
        coefficients = np.empty((n_b, n_o))
        bin_coefficients(even, odd, tr, ti, sr, si, coefficients)
        _along(ox, oy, e.direction[g, 0], e.direction[g, 1], 1.0 / e.radius, True, u)
        binned_chebyshev_sum(u, coefficients, out)


@_jit
def box_sum(b, x_re, x_im, wx, wy, zs, out):
    """out += the pressure per unit rho g of the components of ``b`` (a BoxTable: server/
    box_expansion.py) at points with horizontal offsets ``wx``, ``wy`` from the reference point
    and stretched heights ``zs`` in [floor, 0]: per heading, the points sorted by box (a counting
    sort); per row of boxes, its occupied boxes' coefficients B_n = sum_c m_cn (P_c + (-1)^n conj Q_c)
    to the row's order by four matrix products; Horner's scheme in zeta = ((z - z_b) + i (s - s_b))
    / rho at each point."""
    p_n = zs.size
    box = np.empty(p_n, np.int64)
    b4 = _blocks(4)
    zr, zi, br, bi = b4[0], b4[1], b4[2], b4[3]
    for g in range(b.direction.shape[0]):
        cols = b.columns[b.start[g]:b.start[g + 1]]
        n_g, n_s, n_z, n_o = cols.size, b.grid[g, 0], b.grid[g, 1], b.orders[g]
        n_box = n_s * n_z
        side_s, side_z = 2.0 * b.radius / n_s, -b.floor / n_z
        rho = 0.5 * math.sqrt(side_s * side_s + side_z * side_z)
        dx, dy = b.direction[g, 0], b.direction[g, 1]
        for p in range(p_n):      # box q = j n_s + i: row j (from the floor up), column i
            i = min(max(int((wx[p] * dx + wy[p] * dy + b.radius) / side_s), 0), n_s - 1)
            j = min(max(int((zs[p] - b.floor) / side_z), 0), n_z - 1)
            box[p] = j * n_s + i
        order, first = _grouped(box, n_box)
        xr, xi = np.empty(n_g), np.empty(n_g)
        _gather(cols, x_re, x_im, xr, xi)
        f0, w0, n_e = b.factor_start[g], b.weight_start[g], (n_o + 1) // 2
        pr = b.factor_re[f0:f0 + n_box * n_g].reshape((n_g, n_box))
        pi = b.factor_im[f0:f0 + n_box * n_g].reshape((n_g, n_box))
        n_m, m0 = b.mirror[g], b.mirror_start[g]     # the first n_m components feel the seabed
        qr = b.mirror_re[m0:m0 + n_m * n_box].reshape((n_m, n_box))
        qi = b.mirror_im[m0:m0 + n_m * n_box].reshape((n_m, n_box))
        even = b.weights[w0:w0 + n_e * n_g].reshape((n_e, n_g))
        odd = b.weights[w0 + n_e * n_g:w0 + n_o * n_g].reshape((n_o - n_e, n_g))
        ys = np.empty((2, n_g, 2 * n_s))    # per component: Re then Im of P + conj Q (even orders), of P - conj Q (odd)
        occ = np.empty(n_s, np.int64)       # a row's occupied boxes
        for j in range(n_z):
            n_j = b.row_orders[b.row_start[g] + j]
            n_occ = 0
            for i in range(n_s):
                if first[j * n_s + i + 1] > first[j * n_s + i]:
                    occ[n_occ] = j * n_s + i
                    n_occ += 1
            if n_occ == 0:
                continue
            for c in range(n_g):
                for o in range(n_occ):
                    q = occ[o]
                    ar = xr[c] * pr[c, q] - xi[c] * pi[c, q]
                    ai = xr[c] * pi[c, q] + xi[c] * pr[c, q]
                    ys[0, c, o], ys[0, c, n_occ + o], ys[1, c, o], ys[1, c, n_occ + o] = ar, ai, ar, ai
                if c < n_m:
                    for o in range(n_occ):
                        q = occ[o]
                        cr = xr[c] * qr[c, q] - xi[c] * qi[c, q]
                        ci = -(xr[c] * qi[c, q] + xi[c] * qr[c, q])
                        ys[0, c, o] += cr
                        ys[0, c, n_occ + o] += ci
                        ys[1, c, o] -= cr
                        ys[1, c, n_occ + o] -= ci
            y = np.ascontiguousarray(ys[:, :, :2 * n_occ])
            ce = even[:(n_j + 1) // 2] @ y[0]      # (orders, Re of the boxes then Im)
            co = odd[:n_j // 2] @ y[1]
            z_b = b.floor + (j + 0.5) * side_z
            for o in range(n_occ):
                q = occ[o]
                s_b = -b.radius + (q - j * n_s + 0.5) * side_s
                for st in range(first[q], first[q + 1], _BLOCK):
                    m = min(_BLOCK, first[q + 1] - st)
                    top = n_j - 1
                    hr, hi = (ce[top // 2, o], ce[top // 2, n_occ + o]) if top % 2 == 0 else \
                        (co[top // 2, o], co[top // 2, n_occ + o])
                    for t in range(m):
                        p = order[st + t]
                        zr[t] = (zs[p] - z_b) / rho
                        zi[t] = (wx[p] * dx + wy[p] * dy - s_b) / rho
                        br[t], bi[t] = hr, hi
                    for n in range(n_j - 2, -1, -1):
                        cr, ci = (ce[n // 2, o], ce[n // 2, n_occ + o]) if n % 2 == 0 else \
                            (co[n // 2, o], co[n // 2, n_occ + o])
                        for t in range(m):
                            ur, ui = br[t], bi[t]
                            br[t] = ur * zr[t] - ui * zi[t] + cr
                            bi[t] = ur * zi[t] + ui * zr[t] + ci
                    for t in range(m):
                        out[order[st + t]] += br[t]


@_jit
def hull_pressure(local, rot, pos, x_re, x_im, k, depth, elevation, recurrences, boxes, direct, direct_dir, z, d, p):
    """One body's incident wave for one step (incident_kernels.HullPass): the vertices' global
    heights ``z``, signed heights above the free surface ``d`` and the Froude–Krylov pressure per
    unit rho g at the wet ones ``p`` (V,), for the hull's vertices ``local`` (V, 3) in the pose
    (rotation ``rot``, reference point ``pos``), the components' phasors at the reference point
    ``x`` (ramp a_c e^{i (k_c s_ref + phi_c - w_c t)}) and wave numbers ``k``; the components
    ``direct`` one by one. False (p left zero) where a wet vertex's stretched height is below the
    tables' floor: the caller then sums the pressure directly."""
    v_n = local.shape[0]
    ox, oy = np.empty(v_n), np.empty(v_n)
    for v in range(v_n):
        ox[v] = rot[0, 0] * local[v, 0] + rot[0, 1] * local[v, 1] + rot[0, 2] * local[v, 2]
        oy[v] = rot[1, 0] * local[v, 0] + rot[1, 1] * local[v, 1] + rot[1, 2] * local[v, 2]
        z[v] = pos[2] + rot[2, 0] * local[v, 0] + rot[2, 1] * local[v, 1] + rot[2, 2] * local[v, 2]
        d[v] = 0.0
        p[v] = 0.0
    u = np.empty(v_n)
    elevation_sum(elevation, x_re, x_im, ox, oy, u, d)          # d holds the elevation for now
    wet_n = 0
    low = 0.0
    for v in range(v_n):
        eta = d[v]
        d[v] = z[v] - eta
        if d[v] <= 0.0:
            wet_n += 1
            # stretched, at most at the surface, at least at the seabed
            h = d[v] if math.isinf(depth) else depth * d[v] / (depth + eta)
            u[v] = min(max(h, -depth), 0.0)
            low = min(low, u[v])
    if wet_n == 0:
        return True
    if low < recurrences.floor:
        return False
    wet = np.empty(wet_n, np.int64)
    i = 0
    for v in range(v_n):
        if d[v] <= 0.0:
            wet[i] = v
            i += 1
    wet = wet[_by_height(u[wet], recurrences.floor)]      # from the surface down: the recurrences stop earlier
    zs, wx, wy = u[wet], ox[wet], oy[wet]
    out, xi = np.zeros(wet_n), np.empty(wet_n)
    r = recurrences
    for g in range(r.direction.shape[0]):   # the short waves: recurrences over evenly spaced components
        cols = r.columns[r.start[g]:r.start[g + 1]]
        ar, ai = np.empty(cols.size), np.empty(cols.size)
        _gather(cols, x_re, x_im, ar, ai)
        _along(wx, wy, r.direction[g, 0], r.direction[g, 1], 1.0, False, xi)
        deep_pressure(xi, zs, ar, ai, r.tail[r.start[g]:r.start[g + 1]], r.k0[g], r.dk[g], r.d2[g], out)
    box_sum(boxes, x_re, x_im, wx, wy, zs, out)
    for j in range(direct.size):            # the rest: one cosine and depth factor per point and component
        c = direct[j]
        kc = k[c]
        for i in range(wet_n):
            f = math.exp(kc * zs[i])
            if not math.isinf(depth):           # cosh(k (z + h)) / cosh(k h), overflow-safe
                f *= (1.0 + math.exp(-2.0 * kc * (zs[i] + depth))) / (1.0 + math.exp(-2.0 * kc * depth))
            theta = kc * (wx[i] * direct_dir[j, 0] + wy[i] * direct_dir[j, 1])
            out[i] += f * (x_re[c] * math.cos(theta) - x_im[c] * math.sin(theta))
    for i in range(wet_n):
        p[wet[i]] = out[i]
    return True


@_jit
def hull_loads(local, tris, loads, vertex_loads, pose, omega, amp_re, amp_im, t, ramp, k, heading, depth, elevation,
               recurrences, boxes, direct, direct_dir, fk_re, fk_im, rot, z, d, p, out):
    """One Froude–Krylov body's step (incident_kernels.HullPass): the rotation ``rot`` of the
    pose's angles, the components' phasors, the pressure at the vertices (:func:`hull_pressure`)
    and its integral over the wet part of the hull; ``out`` (3, 6): the hydrostatic and
    Froude–Krylov loads per unit rho g in the body's frame, and Re(fk_linear e^{-i w t}) ramp.
    False where :func:`hull_pressure` is (``out`` then incomplete)."""
    ca, sa = math.cos(pose[3]), math.sin(pose[3])
    cb, sb = math.cos(pose[4]), math.sin(pose[4])
    cc, sc = math.cos(pose[5]), math.sin(pose[5])
    rot[0, 0], rot[0, 1], rot[0, 2] = cb * cc, -cb * sc, sb          # Rx(a) Ry(b) Rz(c)
    rot[1, 0], rot[1, 1], rot[1, 2] = ca * sc + sa * sb * cc, ca * cc - sa * sb * sc, -sa * cb
    rot[2, 0], rot[2, 1], rot[2, 2] = sa * sc - ca * sb * cc, sa * cc + ca * sb * sc, ca * cb
    n_c = omega.size
    x_re, x_im = np.empty(n_c), np.empty(n_c)
    for r in range(3):
        for j in range(6):
            out[r, j] = 0.0
    arg, cs = np.empty(2 * n_c), np.empty((2, 2 * n_c))
    for c in range(n_c):        # w t, then the phase at the reference point
        arg[c] = omega[c] * t
        arg[n_c + c] = k[c] * (pose[0] * heading[c, 0] + pose[1] * heading[c, 1]) - omega[c] * t
    sincos(arg, cs[0], cs[1])
    f0 = f1 = f2 = f3 = f4 = f5 = 0.0      # Re(fk_linear e^{-i w t}), the sums in registers
    for c in range(n_c):
        co, si = cs[0, c], cs[1, c]
        f0 += fk_re[0, c] * co + fk_im[0, c] * si
        f1 += fk_re[1, c] * co + fk_im[1, c] * si
        f2 += fk_re[2, c] * co + fk_im[2, c] * si
        f3 += fk_re[3, c] * co + fk_im[3, c] * si
        f4 += fk_re[4, c] * co + fk_im[4, c] * si
        f5 += fk_re[5, c] * co + fk_im[5, c] * si
        tr, ti = ramp * cs[0, n_c + c], ramp * cs[1, n_c + c]
        x_re[c], x_im[c] = amp_re[c] * tr - amp_im[c] * ti, amp_re[c] * ti + amp_im[c] * tr
    out[2, 0], out[2, 1], out[2, 2], out[2, 3], out[2, 4], out[2, 5] = \
        ramp * f0, ramp * f1, ramp * f2, ramp * f3, ramp * f4, ramp * f5
    if not hull_pressure(local, rot, pose, x_re, x_im, k, depth, elevation, recurrences, boxes, direct,
                         direct_dir, z, d, p):
        return False
    cut_hull_loads(local, tris, d, z, p, loads, vertex_loads, out[:2])
    return True


@structref.register
class _HullStateType(types.StructRef):
    """numba's type of a :class:`HullState`: its fields' types as given (not literal)."""

    def preprocess_fields(self, fields):
        return tuple((name, types.unliteral(t)) for name, t in fields)


class HullState(structref.StructRefProxy):
    """One Froude–Krylov body's fixed inputs to :func:`hull_loads` (the hull, the sea, the tables:
    incident_kernels.HullPass), made once and held by the compiled code, so that a step's call
    passes one object: numba's dispatch of the sixty arrays, most in NamedTuples, cost 12 µs a
    call (measured on the 988-triangle hull; one object: 1 µs)."""


structref.define_proxy(HullState, _HullStateType, ["local", "tris", "loads", "vertex_loads", "omega", "amp_re", "amp_im",
                                                   "k", "heading", "depth", "elevation", "recurrences", "boxes",
                                                   "direct", "direct_dir", "fk_re", "fk_im", "body"])


@_jit
def hull_state(local, tris, loads, vertex_loads, omega, amp_re, amp_im, k, heading, depth, elevation, recurrences,
               boxes, direct, direct_dir, fk_re, fk_im, body):
    """The :class:`HullState` of these inputs (:func:`hull_loads`' own, and ``body`` the
    server/terms/nonlinear/rows.py BodyConstants of :func:`reply_rows`)."""
    return HullState(local, tris, loads, vertex_loads, omega, amp_re, amp_im, k, heading, depth, elevation, recurrences,
                     boxes, direct, direct_dir, fk_re, fk_im, body)


@_jit
def hull_step(st, pose, t, ramp, rot, v, out, hs, fk):
    """:func:`hull_loads` with the fixed inputs of ``st`` (a :class:`HullState`; ``v`` (3, V) the
    buffers z, d, p), then the body's reply rows ``hs`` and ``fk`` (6,) (:func:`reply_rows`).
    False where :func:`hull_loads` is (the rows then not written)."""
    if not hull_loads(st.local, st.tris, st.loads, st.vertex_loads, pose, st.omega, st.amp_re, st.amp_im, t, ramp,
                      st.k, st.heading, st.depth, st.elevation, st.recurrences, st.boxes, st.direct, st.direct_dir,
                      st.fk_re, st.fk_im, rot, v[0], v[1], v[2], out):
        return False
    reply_rows(out[:2], out[2], rot, pose, st.body, hs, fk)
    return True
