"""Radiation memory by direct convolution of the IRF with the velocity history.

    F_r(t_n) = -dt sum_{j=0}^{M} w_j K(j dt) v(t_n - j dt),   w_0 = w_M = 1/2, else 1

The current step's velocity is included (trapezoid end point); v = 0 before t0. The M+1 newest
velocity samples live in a ring buffer stored twice (rows p and p + M + 1), so the window newest ->
oldest is always the contiguous slice buf[p : p + M + 1] and the sum is a single BLAS matvec with
the pre-weighted kernel. ``replace_last`` overwrites the newest sample (the same step re-sent while
iterating) without touching the history.

M = 0 (irf_duration = 0) means radiation memory off: the force is zero. The lone trapezoid term
-dt/2 K(0) v would only be a dt-dependent artefact, not a physical damping.
"""

from __future__ import annotations

import numpy as np

from hydrolink.server.fused.step import FusedRadiation


class RadiationMemory:
    """Convolution state for n coupled DOFs."""

    def __init__(self, kernel: np.ndarray, dt: float, keep: np.ndarray | None = None):
        """kernel: K(j dt) for j = 0..M, shape (M+1, n, n). ``keep`` (n, n) bool: the DOF pairs in
        use (pruned pairs are zero); when at most half are kept the kernel is stored sparse (CSR),
        so a step costs O(kept pairs x M) instead of O(n^2 M)."""
        kernel = np.asarray(kernel, float)
        L, n, _ = kernel.shape
        self.n, self.samples, self.dt = n, L, float(dt)
        self.enabled = L > 1 and n > 0
        w = np.ones(L)
        w[0] = w[-1] = 0.5
        if keep is not None:
            kernel = kernel * np.asarray(keep, bool)[None]
        # kflat[i, j*n + k] = -dt w_j K_ik(j dt): contracts with the (L, n) window raveled row-major
        self._k = np.ascontiguousarray((-self.dt * w[:, None, None] * kernel).transpose(1, 0, 2).reshape(n, L * n))
        self.sparse = keep is not None and n > 0 and np.count_nonzero(keep) <= 0.5 * n * n
        if self.sparse:
            from scipy.sparse import csr_matrix
            self._k = csr_matrix(self._k)
        self._buf = np.zeros((2 * L, n))
        self._p = 0
        self._count = 0

    def reset(self) -> None:
        self._buf[:] = 0.0
        self._p = 0
        self._count = 0

    @property
    def count(self) -> int:
        """Samples pushed so far (replacements not counted)."""
        return self._count

    def state(self) -> tuple:
        """What push() changes, copied (a session rolled back restores it: :meth:`set_state`)."""
        return self._buf[self._p:self._p + self.samples].copy(), self._p, self._count

    def set_state(self, state: tuple) -> None:
        window, self._p, self._count = state
        L = self.samples
        # the ring holds each sample twice: row j of the window sits at (p + j) mod L and at that + L
        rows = (self._p + np.arange(L)) % L
        self._buf[rows] = window
        self._buf[rows + L] = window

    def push(self, v: np.ndarray, replace_last: bool = False) -> np.ndarray:
        """Add the velocity at the new step (or replace the newest one) and return F_r (n,)."""
        if not self.enabled:
            return np.zeros(self.n)
        L = self.samples
        if not (replace_last and self._count):
            self._p = (self._p - 1) % L
            self._count += 1
        p = self._p
        self._buf[p] = v
        self._buf[p + L] = v
        return self._k @ self._buf[p:p + L].reshape(-1)

    def feedthrough(self) -> np.ndarray:
        """dF/dv of the newest sample (n, n): -dt/2 K(0) on the kept pairs (zero when memory is off)."""
        if not self.enabled:
            return np.zeros((self.n, self.n))
        first = self._k[:, :self.n]
        return first.toarray() if self.sparse else first.copy()

    def fused(self, still: np.ndarray | None = None) -> FusedRadiation:
        """This force as the fused step takes it (server/fused/step.py): the pre-weighted kernel;
        ``still`` (n,) bool: the DOFs whose velocity is zero at every step (a held body's), whose
        columns are left out of it (they contribute nothing; None: none)."""
        if not self.enabled:
            return FusedRadiation("none")
        live = None
        k = self._k
        if still is not None and np.any(still):
            live = np.flatnonzero(~np.asarray(still, bool))
            dense = k.toarray() if self.sparse else k
            k = np.ascontiguousarray(dense.reshape(self.n, self.samples, self.n)[:, :, live]
                                     .reshape(self.n, self.samples * live.size))
            if self.sparse:
                from scipy.sparse import csr_matrix
                k = csr_matrix(k)
        if self.sparse:
            return FusedRadiation("sparse", self.samples, live, data=k.data, indices=k.indices, indptr=k.indptr)
        return FusedRadiation("dense", self.samples, live, k=k)

    def window(self) -> np.ndarray:
        """The velocity window, newest first (L, n) (a copy; for tests and diagnostics)."""
        return self._buf[self._p:self._p + self.samples].copy()
