"""The joints' results arithmetic of :class:`~hydrolink.clients.exudyn.mechanism.JointOutputs` in one
compiled call (numba; imported only by ``JointOutputs.compiled``, which the compiled exchange
takes, on first use).

Python still reads each ``ObjectJointGeneric``'s four outputs (``ForceLocal``, ``TorqueLocal``,
``DisplacementLocal``, ``Rotation``), its friction connector's (one, where it has friction) and,
where marker 0 moves, its frame, into arrays made once; :func:`joint_rows` then does what
``JointOutputs.__call__`` does with numpy — the loads in the global frame (the moment from the
rotation multipliers and the friction's share by clients/exudyn/kernels/joint_moments.py, compiled
here), the violations on the locked axes, a held body's fixed-joint reaction (one product
over its stacked loads) — straight into the results row's slots. Each product and sum is an
``np.dot`` (BLAS, as the numpy path's ``ndarray.dot``) over the same operands in the same order, so
the values are the numpy path's bits (tests/test_compiled_exchange.py, tests/test_held_bodies.py).
"""

from __future__ import annotations

import math

import numpy as np

from hydrolink.clients.exudyn.kernels.joint_moments import add_friction, local_moment
from hydrolink.server import compiler

numba = compiler.load()

_jit = numba.njit(cache=True, nogil=True, error_model="numpy")
_local_moment = _jit(local_moment)
_add_friction = _jit(add_friction)

#: where a held reaction's stacked entry comes from (``kind``): the client's load, a, q, the wrenches
LOAD, ACC, POS, WRENCH = 0, 1, 2, 3


@_jit
def joint_rows(raw, frames, rows, locked, pairs, friction, held, offset, transfer, start, width, kind, index, load,
               q, a, wrench, gap, rot):
    """``raw`` (G, 5, 3): each generic joint's ForceLocal, TorqueLocal, DisplacementLocal, Rotation
    and its friction connector's output ``friction`` (G,) names (joint_moments.add_friction's
    ``which``); ``frames`` (G, 3, 3) its marker-0 frame; ``rows`` (G,) its joint; ``locked`` (G, 6)
    its locked axes; ``pairs`` (G, 3, 2) its rotation constraints' axes (joint_moments.rotation_pairs).
    ``held`` (H,): each held body's fixed joint, ``offset`` (H, 6), its transfer matrix (6 ×
    ``width[h]``) at ``transfer[start[h]:]`` (flat), its stacked entries' source ``kind`` and
    ``index`` (H, max width). Fills ``wrench`` (J, 6), ``gap`` and ``rot`` (J,)."""
    wrench[:] = 0.0
    gap[:] = 0.0
    rot[:] = 0.0
    m, force = np.empty(3), np.empty(3)
    for g in range(rows.size):
        k = rows[g]
        _local_moment(raw[g, 1], raw[g, 3], pairs[g], m)
        force[:] = raw[g, 0]
        _add_friction(friction[g], raw[g, 4], force, m)
        f = np.dot(frames[g], force)
        t = np.dot(frames[g], m)
        for i in range(3):
            wrench[k, i] = -f[i]
            wrench[k, 3 + i] = -t[i]
        d = np.empty(int(locked[g, :3].sum()))
        r = np.empty(int(locked[g, 3:].sum()))
        nd = nr = 0
        for i in range(3):
            if locked[g, i]:
                d[nd] = raw[g, 2, i]
                nd += 1
            if locked[g, 3 + i]:
                r[nr] = raw[g, 3, i]
                nr += 1
        gap[k] = math.sqrt(np.dot(d, d))
        rot[k] = math.sqrt(np.dot(r, r))
    flat = wrench.reshape(-1)
    for h in range(held.size):
        w = width[h]
        x = np.empty(w)
        for e in range(w):
            c, j = kind[h, e], index[h, e]
            x[e] = load[j] if c == LOAD else a[j] if c == ACC else q[j] if c == POS else flat[j]
        k = held[h]
        if w == 0:       # nothing on it but its constant load (+ 0.0: the numpy path's empty product)
            for i in range(6):
                wrench[k, i] = offset[h, i] + 0.0
            continue
        y = np.dot(transfer[start[h]:start[h] + 6 * w].reshape(6, w), x)
        for i in range(6):
            wrench[k, i] = offset[h, i] + y[i]
