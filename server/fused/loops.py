"""The loops of the fused linear step (server/fused/step.py), plain Python over arrays: compiled by
server/fused/kernel_numba.py (which composes them into one step), never run as they stand (the reference they are tested against is
the model's numpy path, server/model.py ``HydroModel.step`` with ``compiled=False``).

One call does what the numpy path does in a dozen array calls: the wave components' trig row and
the excitation sum (with its ramp), the radiation force (a convolution ring buffer, dense or
sparse, or the state-space recursion), and the hydrostatic restoring force, each written straight
into the reply's rows of the active DOFs. Every product is a loop here, never BLAS: a step takes
no thread pool, whatever the process's BLAS threading (BLAS's own matrix-vector product called from
here ran on two threads outside the lockstep loop, 8 ms a step for F3OF's 18 x 27,018 kernel on a
loaded machine; the loop is 1.3-1.7x BLAS's single-threaded time for RM3's 2 x 8,002 kernel).
"""

from __future__ import annotations

import math

import numpy as np

__all__ = ["RADIATION_KINDS", "convolution", "excitation", "gather", "hydrostatic", "state_space", "yaw_excitation"]

#: radiation force kinds of the fused step: none, convolution (dense kernel), convolution (CSR kernel), state space
RADIATION_KINDS = {"none": 0, "dense": 1, "sparse": 2, "state-space": 3}


def excitation(idx, exc, omega, ramp_t, trig, t, f_ext, out):
    """out[idx] = ramp(t) (exc @ [cos wt; sin wt])[:n] + f_ext; returns the elevation row's value."""
    n_c, na = omega.size, idx.size
    if n_c == 0:
        for i in range(na):
            out[idx[i]] = f_ext[i]
        return 0.0
    ramp = 1.0
    if ramp_t > 0.0 and t < ramp_t:
        ramp = 0.5 * (1.0 - math.cos(math.pi * max(t, 0.0) / ramp_t))
    for c in range(n_c):
        wt = omega[c] * t
        trig[c] = math.cos(wt)
        trig[n_c + c] = math.sin(wt)
    eta = 0.0
    for i in range(na + 1):
        acc = 0.0
        for j in range(2 * n_c):
            acc += exc[i, j] * trig[j]
        if i < na:
            out[idx[i]] = acc * ramp + f_ext[i]
        else:
            eta = acc * ramp
    return eta


def yaw_excitation(tables, headings, rows, owner, idx, ramp_t, trig, t, f_ext, out):
    """The passive-yaw bodies' excitation rows (server/sea/passive_yaw.py), after :func:`excitation`
    filled ``trig``: for passive row r of body b = owner[r], forcing row i = rows[r], the sums of
    tables[b, j0, i] and tables[b, j1, i] over [cos wt; sin wt] at the tabulated yaws j0, j1 around
    headings[b], blended linearly, times the ramp: out[idx[i]] = that + f_ext[i] (the same loop as
    :func:`excitation`'s, so the table at yaw 0, the fixed-heading matrix, gives its bits)."""
    if rows.size == 0:
        return
    points = tables.shape[1]
    width = tables.shape[3]
    ramp = 1.0
    if ramp_t > 0.0 and t < ramp_t:
        ramp = 0.5 * (1.0 - math.cos(math.pi * max(t, 0.0) / ramp_t))
    for r in range(rows.size):
        b, i = owner[r], rows[r]
        u = (headings[b] * (points / (2.0 * math.pi))) % points
        j0 = int(u)
        s = u - j0
        if j0 >= points:     # a tiny negative angle rounds to a whole turn
            j0, s = 0, 0.0
        j1 = j0 + 1 if j0 + 1 < points else 0
        acc0 = 0.0
        for j in range(width):
            acc0 += tables[b, j0, i, j] * trig[j]
        acc1 = 0.0
        for j in range(width):
            acc1 += tables[b, j1, i, j] * trig[j]
        out[idx[i]] = ((1.0 - s) * acc0 + s * acc1) * ramp + f_ext[i]


def convolution(k, data, indices, indptr, buf, counters, vs, replace, idx, live, out):
    """The newest velocity of the convolved columns ``live`` (positions in ``vs``; a held body's
    DOFs left out: their velocity is zero) into the ring ``buf`` (nc wide, stored twice: rows p and
    p + L; counters: p, pushes, L), then out[idx] = K (window newest first, raveled): dense ``k``
    (na, L nc) or CSR (data, indices, indptr)."""
    na, nc, length = idx.size, live.size, counters[2]
    if not (replace and counters[1]):
        counters[0] = (counters[0] - 1) % length
        counters[1] += 1
    p = counters[0]
    for c in range(nc):
        buf[p, c] = vs[live[c]]
        buf[p + length, c] = vs[live[c]]
    flat = buf.reshape(-1)   # the window newest first is flat[p nc : (p + L) nc]
    start = p * nc
    if indptr.size:
        for i in range(na):
            acc = 0.0
            for e in range(indptr[i], indptr[i + 1]):
                acc += data[e] * flat[start + indices[e]]
            out[idx[i]] = acc
    else:   # row by row, offsets rather than slices: the sums vectorise (kernel_numba.py)
        for i in range(na):
            row = k[i]
            acc = 0.0
            for m in range(length * nc):
                acc += row[m] * flat[start + m]
            out[idx[i]] = acc


def state_space(phi, g0, g1, c2, rows, cols, d, z, z_prev, v_prev, v_last, counters, vs, replace, f, idx, out):
    """The first-order-hold recursion of server/radiation/state_space.py's StateSpaceRadiation.push."""
    na = idx.size
    if not (replace and counters[1]):
        for s in range(z.size):
            z_prev[s] = z[s]
        for i in range(na):
            v_prev[i] = v_last[i]
        counters[1] += 1
    for i in range(na):
        v_last[i] = vs[i]
        f[i] = 0.0
    for s in range(z.size):
        zs = phi[s] * z_prev[s] + g0[s] * v_prev[cols[s]] + g1[s] * vs[cols[s]]
        z[s] = zs
        f[rows[s]] += (c2[s] * zs).real
    if d.size:
        for i in range(na):
            acc = f[i]
            for j in range(na):
                acc += d[i, j] * vs[j]
            f[i] = acc
    for i in range(na):
        out[idx[i]] = -f[i]


def hydrostatic(k_hs, x_eq, idx, x, out):
    """out[idx] = K_hs (x_eq - x[idx])."""
    na = idx.size
    for i in range(na):
        acc = 0.0
        for j in range(na):
            acc += k_hs[i, j] * (x_eq[j] - x[idx[j]])
        out[idx[i]] = acc


def gather(v, idx, vs):
    """vs = v[idx]."""
    for i in range(idx.size):
        vs[i] = v[idx[i]]
