"""A Morison step after the wave's trig row, compiled (issue 26; numba, optional).

One call does what :meth:`~hydrolink.server.terms.morison.MorisonSet.force`'s numpy path does in about
eight (each about 1 µs on a loaded machine, more than their arithmetic): the velocities and
accelerations [w; a] = flow @ [cos, sin, v, 1] (BLAS's matrix-vector product, as numpy's: a loop
compiled here was no faster, the product is bound by reading its matrix), each segment's wet test (its centre's height change
from equilibrium at most -z0), |w| w and a on the wet segments, and the bodies' loads. Same results
as the numpy path to round-off (tests/test_morison.py runs both).
"""

from __future__ import annotations

import functools
import math

import numpy as np

__all__ = ["morison_loads", "warm_up"]


def _morison_loads(flow, rhs, heave, x, below, loads):
    n_seg, n_dof = heave.shape
    wa = np.dot(flow, rhs)                  # w (2S) then a (2S), plane-major (BLAS, as numpy's)
    f = np.zeros(wa.size)                   # |w| w and a on the wet segments
    for s in range(n_seg):
        dz = 0.0
        for i in range(n_dof):
            dz += heave[s, i] * x[i]
        if dz <= below[s]:
            w0, w1 = wa[s], wa[n_seg + s]
            speed = math.hypot(w0, w1)
            f[s], f[n_seg + s] = w0 * speed, w1 * speed
            f[2 * n_seg + s], f[3 * n_seg + s] = wa[2 * n_seg + s], wa[3 * n_seg + s]
    out = np.empty(n_dof)
    for i in range(n_dof):
        acc = 0.0
        for c in range(f.size):
            acc += loads[i, c] * f[c]
        out[i] = acc
    return out


@functools.cache
def _compiled():
    """The kernel compiled (or loaded from numba's cache) on first use (numba as server/compiler.py
    imports it)."""
    from hydrolink.server import compiler
    return compiler.load().njit(cache=True, nogil=True, error_model="numpy")(_morison_loads)


def morison_loads(flow: np.ndarray, rhs: np.ndarray, heave: np.ndarray, x: np.ndarray, below: np.ndarray,
                  loads: np.ndarray) -> np.ndarray:
    """(6N,) force and moment on the bodies: ``flow`` (4S, K) maps the row ``rhs`` (K,) [cos wt,
    sin wt, v, 1] to w then a along the members' two normal directions (plane-major); ``heave``
    (S, 6N) maps the displacements ``x`` (6N,) to the segments' height changes, wet while at most
    ``below`` (S,) (= -z0), and ``loads`` (6N, 4S) maps |w| w and a to the loads (all writable C
    contiguous float64, as MorisonSet keeps them: one compiled signature)."""
    return _compiled()(flow, rhs, heave, x, below, loads)


def warm_up() -> None:
    """Compile (or load from numba's cache) the kernel now, at set-up, not in a run's first step."""
    morison_loads(np.ones((4, 3)), np.ones(3), np.ones((1, 6)), np.zeros(6), np.zeros(1), np.ones((6, 4)))
