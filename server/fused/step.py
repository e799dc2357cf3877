"""The linear core of a session's step in one compiled call (issue 36; numba, optional).

:class:`FusedLinearStep` does what :meth:`HydroModel.step <hydrolink.server.model.HydroModel.step>`'s
numpy path does for the excitation (the components' sum, or one computed outside by convolution),
the radiation force of one group over every active DOF (convolution, dense or sparse; constant
damping; state space) and the hydrostatic restoring force, in one call of server/fused/loops.py's
loops compiled by server/fused/kernel_numba.py, into preallocated buffers and the reply's arrays.
Same results as the numpy path to round-off (tests/test_fused_step.py). Where numba is not
installed (``compiler.AVAILABLE``) or does not import (``compiler.imports()``), or the radiation has
several groups, the model takes its numpy path.
"""

from __future__ import annotations

import functools
from dataclasses import dataclass, field

import numpy as np

from hydrolink.server.fused.loops import RADIATION_KINDS

__all__ = ["FusedLinearStep", "FusedRadiation"]

_F, _I = np.float64, np.int64


def _empty(*shape: int, dtype=_F) -> np.ndarray:
    return np.zeros(shape, dtype)


@dataclass(frozen=True)
class FusedRadiation:
    """A radiation force over n DOFs as the fused step takes it (server/radiation's ``fused()``):
    ``kind`` one of loops.RADIATION_KINDS; a convolution's pre-weighted kernel over ``length``
    samples, dense ``k`` (n, length nc) or CSR (``data``, ``indices``, ``indptr``) over the columns
    ``live`` convolved (positions among the n DOFs; None: all, nc = n — a held body's columns
    are left out, its velocity being zero); a state space's per-state ``phi``, ``g0``, ``g1``, ``c2`` (complex), output ``rows`` and input
    ``cols``, and feedthrough ``d`` (n, n; empty when zero)."""

    kind: str
    length: int = 1
    live: np.ndarray | None = None
    k: np.ndarray = field(default_factory=lambda: _empty(0, 0))
    data: np.ndarray = field(default_factory=lambda: _empty(0))
    indices: np.ndarray = field(default_factory=lambda: _empty(0, dtype=_I))
    indptr: np.ndarray = field(default_factory=lambda: _empty(0, dtype=_I))
    phi: np.ndarray = field(default_factory=lambda: _empty(0, dtype=complex))
    g0: np.ndarray = field(default_factory=lambda: _empty(0, dtype=complex))
    g1: np.ndarray = field(default_factory=lambda: _empty(0, dtype=complex))
    c2: np.ndarray = field(default_factory=lambda: _empty(0, dtype=complex))
    rows: np.ndarray = field(default_factory=lambda: _empty(0, dtype=_I))
    cols: np.ndarray = field(default_factory=lambda: _empty(0, dtype=_I))
    d: np.ndarray = field(default_factory=lambda: _empty(0, 0))


@functools.cache
def _compiled():
    """server/fused/kernel_numba.py, imported (numba with it) on first use."""
    from hydrolink.server.fused import kernel_numba
    return kernel_numba


class FusedLinearStep:
    """The linear core of one session's step (module docstring) over the active DOFs ``idx`` of the
    6N vector: ``exc`` (na + 1, 2 n_c) the excitation then elevation rows over [cos wt; sin wt] of
    the components ``omega`` (ramped over ``ramp`` s; n_c = 0: none), ``k_hs`` (na, na) and
    ``x_eq`` (na,) the restoring force's stiffness and equilibrium, ``radiation`` the one radiation
    force over all na DOFs, ``yaw`` the passive-yaw bodies' tables, headings (held, not copied: the
    caller fills it before each call), rows and their bodies (server/sea/passive_yaw.py
    ``PassiveYaw.fused_inputs``; None: no such body)."""

    def __init__(self, idx: np.ndarray, exc: np.ndarray, omega: np.ndarray, ramp: float, k_hs: np.ndarray,
                 x_eq: np.ndarray, radiation: FusedRadiation,
                 yaw: tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray] | None = None):
        c = np.ascontiguousarray
        na, r = idx.size, radiation
        # passive-yaw bodies (server/sea/passive_yaw.py PassiveYaw.fused_inputs): none by default
        tables, headings, yaw_rows, owner = yaw if yaw is not None else (_empty(0, 1, 1, 0), _empty(0),
                                                                          _empty(0, dtype=_I), _empty(0, dtype=_I))
        s = r.phi.size
        live = np.arange(na) if r.live is None else r.live
        self._buf = np.zeros((2 * r.length, live.size))
        self._counters = np.array([0, 0, r.length], _I)        # ring position, pushes, ring length
        self._z, self._z_prev = np.zeros(s, complex), np.zeros(s, complex)
        self._v_prev, self._v_last = np.zeros(na), np.zeros(na)
        self._f_ext = np.zeros(na)                            # no excitation computed outside
        self._state = _compiled().linear_state(
            c(idx, _I), c(exc, _F), c(omega, _F), float(ramp), np.zeros(2 * omega.size), c(k_hs, _F), c(x_eq, _F),
            RADIATION_KINDS[r.kind], c(r.k, _F), c(r.data, _F), c(r.indices, _I), c(r.indptr, _I), c(live, _I), self._buf,
            self._counters, c(r.phi, complex), c(r.g0, complex), c(r.g1, complex), c(r.c2, complex),
            c(r.rows, _I), c(r.cols, _I), c(r.d, _F), self._z, self._z_prev, self._v_prev, self._v_last,
            np.zeros(na), np.zeros(na), c(tables, _F), headings, c(yaw_rows, _I), c(owner, _I))
        self._step = _compiled().step

    def __call__(self, t: float, x: np.ndarray, v: np.ndarray, replace_last: bool, out: np.ndarray,
                 f_ext: np.ndarray | None = None, eta_ext: float = 0.0) -> float:
        """Writes the excitation, radiation and hydrostatic rows of ``out`` (3, 6N; C contiguous) at
        the active DOFs for the state ``x``, ``v`` (6N,) at time ``t``; ``f_ext`` (na,) and
        ``eta_ext`` an excitation and elevation computed outside (by convolution). Returns the
        wave elevation."""
        return self._step(self._state, t, x, v, replace_last, self._f_ext if f_ext is None else f_ext, eta_ext, out)

    @property
    def kernel_state(self):
        """The compiled kernel's :class:`~hydrolink.server.fused.kernel_numba.LinearState`: what a
        caller's own compiled code passes to ``kernel_numba.step`` (with ``t``, ``x``, ``v``,
        ``replace``, ``f_ext``, ``eta_ext`` and ``out`` as :meth:`__call__` does)."""
        return self._state

    def state(self) -> tuple:
        """What a call changes, copied (for a session rolled back, SPEC §5.9)."""
        return tuple(a.copy() for a in (self._buf, self._counters, self._z, self._z_prev, self._v_prev, self._v_last))

    def set_state(self, state: tuple) -> None:
        """Back to a :meth:`state` (copied into the arrays the compiled code holds)."""
        for mine, saved in zip((self._buf, self._counters, self._z, self._z_prev, self._v_prev, self._v_last), state):
            np.copyto(mine, saved)

    def warm_up(self, n: int) -> None:
        """Compile (or load from numba's cache) now, at set-up, not in a run's first step: for a
        writable and a read-only state of ``n`` (= 6N) values (a frame's arrays are read-only);
        the steps taken are then forgotten."""
        saved = self.state()
        x = np.zeros(n)
        frozen = x.copy()
        frozen.flags.writeable = False
        for state in (x, frozen):
            self(0.0, state, state, False, np.zeros((3, n)))
        self.set_state(saved)
