"""The embedded exchange's glue compiled (numba; imported only from clients/exudyn/compiled_exchange.py,
on first use).

Two calls a step on one :class:`ExchangeState` made once per run (numba's dispatch types each
array argument on every call: the arrays live in the structure, a call passes it and the step's
own values):

- :func:`predict`: from Exudyn's state (the rows q, v, a of every ODE2 coordinate, held in
  ``qva``), the wet DOFs' predicted state (x + H v + H²/2 a, v + H a, the arithmetic of
  clients/lockstep/coupling_schemes.py ``Predictor`` in its order), the absolute position and
  velocity checked against the wire's bounds, the server's compiled linear step
  (server/fused/kernel_numba.py ``step``) into ``out``, and the load excitation + radiation at
  the hydro object's coordinates (``force``); a run with controllers calls its two halves,
  :func:`prepare` (the prediction and the bounds) and :func:`forces` (the step and the load),
  relaying the measurements between them, before the model steps (server/service/controlled_step.py);
- :func:`settle`: Exudyn's state after the step (read through ``q``, ``v``, ``a``: views of Exudyn's
  own current-state vectors, ``GetODE2Coordinates(copy=False)``, so no getter is called a step)
  into ``qva``, the results row (every body's position and velocity, the forces, the hydrostatic
  force −C q) and the sum of squares of q and v (the divergence watch's bound).

No ``fastmath`` here: each sum and product in numpy's order (−C q by BLAS's gemv, as numpy's ``dot``), so the results are numpy's bits
(tests/test_compiled_exchange.py).
"""

from __future__ import annotations

import math

import numpy as np

from hydrolink.server import compiler
from hydrolink.server.fused import kernel_numba

numba = compiler.load()
from numba.experimental import structref  # (after numba's set-up above)

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")
_step = kernel_numba.step

FIELDS = ["lin", "qva", "q", "v", "a", "wet_take", "eq", "pos", "vel", "out", "load", "f_ext", "force_index", "force", "body_take", "ref",
          "wet_of", "k_hs", "hs", "x_wet", "h", "bounds", "status", "damp", "active", "v_act", "dv", "visc"]

#: predict's outcomes (``status[0]``): the step taken; the state refused by the wire's bounds (no step taken);
#: the server's forces not finite (the step taken)
TAKEN, REFUSED, NON_FINITE = 0, 1, 2


@structref.register
class _ExchangeStateType(kernel_numba.UnliteralStructRef):
    """numba's type of an :class:`ExchangeState`."""


class ExchangeState(structref.StructRefProxy):
    """The embedded exchange's arrays (clients/exudyn/compiled_exchange.py ``CompiledExchange``)."""


structref.define_proxy(ExchangeState, _ExchangeStateType, FIELDS)


@_jit
def exchange_state(lin, qva, q, v, a, wet_take, eq, pos, vel, out, load, f_ext, force_index, force, body_take, ref,
                   wet_of, k_hs, hs, x_wet, h, bounds, status, damp, active, v_act, dv, visc):
    """The :class:`ExchangeState` of these arrays (held, not copied); ``wet_of``: each body row's
    wet body (its block of the wet DOFs), -1 for a dry body; ``damp`` (na, na) the server's linear
    viscous damping over its active DOFs ``active`` (their positions in the wet DOFs; (0, 0): none),
    ``visc`` the wet DOFs' viscous force it gives (zero on the others), ``v_act`` and ``dv`` scratch."""
    return ExchangeState(lin, qva, q, v, a, wet_take, eq, pos, vel, out, load, f_ext, force_index, force, body_take,
                         ref, wet_of, k_hs, hs, x_wet, h, bounds, status, damp, active, v_act, dv, visc)


@_jit
def prepare(g):
    """The wet DOFs' state predicted from ``g.qva`` into ``g.pos`` and ``g.vel`` (module docstring),
    checked against the wire's bounds; returns the outcome (TAKEN: within them, or REFUSED), also
    in ``g.status[0]``."""
    flat = g.qva.reshape(-1)
    take, eq, pos, vel = g.wet_take, g.eq, g.pos, g.vel
    n = eq.size
    h = g.h
    c = 0.5 * h * h
    max_x, max_v = g.bounds[0], g.bounds[1]
    ok = True
    for i in range(n):
        x, v, a = flat[take[i]], flat[take[n + i]], flat[take[2 * n + i]]
        p = eq[i] + (x + h * v + c * a)
        u = v + h * a
        pos[i], vel[i] = p, u
        ok = ok and abs(p) <= max_x and abs(u) <= max_v
    g.status[0] = TAKEN if ok else REFUSED
    return g.status[0]


@_jit
def forces(g, t):
    """The server's forces at time ``t`` for the state :func:`prepare` left in ``g.pos``, ``g.vel``
    (with linear viscous damping its force ``g.visc`` = 0 - B_lin v, as server/terms/viscous.py's
    ``f -= B_lin @ v`` on zeros) and the load (excitation + radiation, + the viscous force: the
    order of clients/lockstep/driver.py ``Sample.of``) at the hydro object's coordinates; returns
    the wave elevation, ``g.status[0]`` the outcome (TAKEN, NON_FINITE)."""
    out = g.out
    eta = _step(g.lin, t, g.pos, g.vel, False, g.f_ext, 0.0, out)
    damped = g.damp.shape[0] > 0
    if damped:
        active, v_act, dv, visc, vel = g.active, g.v_act, g.dv, g.visc, g.vel
        for k in range(active.size):
            v_act[k] = vel[active[k]]
        np.dot(g.damp, v_act, dv)   # BLAS's gemv, as numpy's matmul
        for k in range(active.size):
            visc[active[k]] = 0.0 - dv[k]
    load = g.load
    total = eta
    for i in range(load.size):
        load[i] = out[0, i] + out[1, i]
        if damped:
            load[i] = load[i] + g.visc[i]
        total += load[i] + out[2, i]
    for j in range(g.force_index.size):
        g.force[j] = load[g.force_index[j]]
    g.status[0] = TAKEN if math.isfinite(total) else NON_FINITE
    return eta


@_jit
def predict(g, t):
    """:func:`prepare` then, within the bounds, :func:`forces` (one call); returns the wave
    elevation (NaN when refused), ``g.status[0]`` the outcome (TAKEN, REFUSED, NON_FINITE)."""
    if prepare(g) == REFUSED:
        return math.nan
    return forces(g, t)


@_jit
def settle(g, row):
    """Exudyn's state after a step (``g.q``, ``g.v``, ``g.a``: its ODE2 coordinates) into ``g.qva``,
    the results row (5, B, 6) filled from it and ``g.out`` (a dry body's forces zero, as the
    reference path's rows); returns the sum of squares of q and v."""
    st, q, v, a = g.qva, g.q, g.v, g.a
    nq = q.size
    ss = 0.0
    for i in range(nq):
        st[0, i], st[1, i], st[2, i] = q[i], v[i], a[i]
        ss += q[i] * q[i] + v[i] * v[i]
    flat = st.reshape(-1)
    take, ref = g.body_take, g.ref
    nb = ref.size // 6
    m = nb * 6
    for b in range(nb):
        for d in range(6):
            j = 6 * b + d
            row[0, b, d] = ref[j] + flat[take[j]]
            row[1, b, d] = flat[take[m + j]]
    out, k_hs, hs, wet = g.out, g.k_hs, g.hs, g.wet_take
    n = hs.size
    x = g.x_wet
    for j in range(n):
        x[j] = flat[wet[j]]
    np.dot(k_hs, x, hs)   # BLAS's gemv, as the reference path's np.dot (its sums' order from 12 DOFs up)
    wet_of = g.wet_of
    for b in range(nb):
        w = wet_of[b]
        for d in range(6):
            if w < 0:
                row[2, b, d] = row[3, b, d] = row[4, b, d] = 0.0
            else:
                j = 6 * w + d
                row[2, b, d] = out[0, j]
                row[3, b, d] = out[1, j]
                row[4, b, d] = -hs[j]
    return ss


@_jit
def linear_ptos(table, dw, force, velocity, power, total, meas):
    """The linear PTOs' outputs as clients/exudyn/ptos.py ``PTOSet.sample`` computes them, into the
    results row's slots (1, n) and (1,), and each PTO's extension, velocity and force into the
    rows of ``meas`` (3, rows: a controller's measurements, clients/exudyn/pto_control.py):
    ``table`` (rows, 6) entry, stiffness, damping, added force, rest length, limit; ``dw`` (rows,
    2, 3) each connector's displacement (point2 − point1) and velocity."""
    for r in range(table.shape[0]):
        e = int(table[r, 0])
        dx, dy, dz = dw[r, 0, 0], dw[r, 0, 1], dw[r, 0, 2]
        vx, vy, vz = dw[r, 1, 0], dw[r, 1, 1], dw[r, 1, 2]
        length = math.sqrt(dx * dx + dy * dy + dz * dz)
        rate = (vx * dx + vy * dy + vz * dz) / length if length > 0 else 0.0
        f = table[r, 1] * (length - table[r, 4]) + table[r, 2] * rate + table[r, 3]
        limit = table[r, 5]
        f = min(max(f, -limit), limit)
        force[0, e], velocity[0, e] = f, rate
        meas[0, r], meas[1, r], meas[2, r] = length - table[r, 4], rate, f
    acc = 0.0
    for e in range(force.shape[1]):
        p = force[0, e] * velocity[0, e]
        power[0, e] = p
        acc += p
    total[0] = acc
