"""State-space radiation: a rational fit per DOF pair of the radiation transfer function, realised
as complex modal states and stepped with an exact first-order-hold discretisation.

Fit. For every DOF pair (i, j) the transfer function of the IRF the convolution would use,

    H(w) = int_0^T K(t) exp(-i w t) dt = B_K(w) + i w (A_K(w) - A_inf)      (irf.irf_transfer)

is fitted on s = i w over [0, w_max] by vector fitting (iterative pole relocation, Gustavsen and
Semlyen's formulation, written here from the method's description) with m complex-conjugate pole
pairs (order 2 m) and a real direct term D:

    H(s) ~ D + sum_r [ c_r / (s - p_r) + conj(c_r) / (s - conj(p_r)) ]
    K(t) ~ D delta(t) + sum_r 2 Re(c_r exp(p_r t))

Poles that the relocation puts in the right half plane are reflected (Re p -> -Re p) at every
iteration (``enforce_stability``), so the result is stable by construction; the realisation checks
Re p < 0 for every pole anyway and refuses an unstable one with a message naming the DOF pair.

Order. Either fixed (``order``) or the smallest even order <= ``max_order`` whose error

    e_ij = max_w |H_fit - H| / s_ij,   s_ij = sqrt(max_w |H_ii| max_w |H_jj|)

(relative to the diagonal scales, so small coupling terms are not chased to relative precision)
is <= ``tolerance``. Pairs that do not reach it keep their best fit and are reported.

Discretisation (exact for a velocity that is linear over each step: first-order hold, the same
assumption as the trapezoidal convolution). With z_r(t) = int_0^t exp(p_r (t - s)) v_j(s) ds,

    z_r(k+1) = phi z_r(k) + g0 v_j(k) + g1 v_j(k+1),   phi = exp(p h),
    g0 = phi/p - (phi - 1)/(h p^2),   g1 = -1/p + (phi - 1)/(h p^2),
    F_i(k+1) = -[ sum_r 2 Re(c_r z_r(k+1)) + D v_j(k+1) ]

so a step costs O(order) per DOF pair: a few element-wise operations over all states and one
scatter-add to the force rows. ``replace_last`` recomputes the newest step from the kept previous
state (iterative coupling).
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from hydrolink.server.fused.step import FusedRadiation


ITER = 6  # pole relocation iterations
FIT_RECIPE_VERSION = 1  # bump when fit_pairs' results change: invalidates cached fits (state_space_cache)
CHUNK = 64  # DOF pairs fitted together (each pair's fit is independent of the others)


class StateSpaceError(ValueError):
    """An unusable realisation (unstable pole); the message says which pair and what to change."""


# ----------------------------------------------------------------------------------------- fitting

def _basis(s: np.ndarray, poles: np.ndarray) -> np.ndarray:
    """Real-coefficient partial-fraction basis: (P, K, 2m) complex, columns
    1/(s-p) + 1/(s-p*) and i/(s-p) - i/(s-p*) per pole pair."""
    a = 1.0 / (s[None, :, None] - poles[:, None, :])
    b = 1.0 / (s[None, :, None] - np.conj(poles)[:, None, :])
    out = np.empty((*a.shape[:2], 2 * poles.shape[1]), complex)
    out[..., 0::2] = a + b
    out[..., 1::2] = 1j * (a - b)
    return out


def _lstsq(a: np.ndarray, rhs: np.ndarray) -> np.ndarray:
    """Batched least squares (P, R, n) x = (P, R) by column-scaled QR."""
    norm = np.linalg.norm(a, axis=1)
    norm[norm == 0] = 1.0
    q, r = np.linalg.qr(a / norm[:, None, :])
    y = np.einsum("prn,pr->pn", q, rhs)
    diag = np.abs(np.diagonal(r, axis1=1, axis2=2))
    bad = diag < 1e-13 * np.maximum(diag.max(axis=1, keepdims=True), 1e-300)
    r = r + np.where(bad, 1.0, 0.0)[:, :, None] * np.eye(r.shape[1])[None]  # rank-deficient columns -> 0
    y = np.where(bad, 0.0, y)
    return np.linalg.solve(r, y[..., None])[..., 0] / norm


def _stack(x: np.ndarray) -> np.ndarray:
    """Complex (P, K, n) -> real rows (P, 2K, n)."""
    return np.concatenate([x.real, x.imag], axis=1)


def _relocate(s, h, poles, w, enforce):
    """One pole relocation: zeros of the weighting function sigma(s) become the new poles.

    Least squares for [c, d, ct] in  (phi c + d - h phi ct) w = h w  (real and imaginary rows) by
    column-scaled normal equations (the relocation only needs an approximate answer; a tiny ridge
    keeps rank-deficient systems solvable). One product X^T X of the rows with the right-hand side
    appended gives the Gram matrix, the column norms (its diagonal) and X^T rhs at once."""
    P, m = poles.shape
    K, n = s.size, 4 * m + 1
    phi = _basis(s, poles) * w[None, :, None]                # (P, K, 2m)
    hphi = -h[:, :, None] * phi
    hw = h * w[None, :]
    x = np.empty((P, 2 * K, n + 1))
    for part, rows in ((np.real, slice(0, K)), (np.imag, slice(K, 2 * K))):
        x[:, rows, :2 * m] = part(phi)
        x[:, rows, 2 * m + 1:n] = part(hphi)
        x[:, rows, n] = part(hw)
    x[:, :K, 2 * m] = w
    x[:, K:, 2 * m] = 0.0
    g = np.matmul(x.transpose(0, 2, 1), x)                  # (P, n + 1, n + 1)
    norm = np.sqrt(np.diagonal(g, axis1=1, axis2=2)[:, :n])
    norm = np.where(norm == 0, 1.0, norm)
    gs = g[:, :n, :n] / (norm[:, :, None] * norm[:, None, :])
    gs += 1e-12 * np.eye(n)[None]
    ct = (np.linalg.solve(gs, (g[:, :n, n] / norm)[..., None])[..., 0] / norm)[:, 2 * m + 1:]  # sigma's residues
    # real realisation of sigma: blocks [[sr, si], [-si, sr]] minus b ct^T with b = [2, 0, 2, 0, ...]
    e = 2 * np.arange(m)
    a = np.zeros((P, 2 * m, 2 * m))
    a[:, e, e] = a[:, e + 1, e + 1] = poles.real
    a[:, e, e + 1] = poles.imag
    a[:, e + 1, e] = -poles.imag
    a[:, e, :] -= 2.0 * ct[:, None, :]
    return _pair_up(np.linalg.eigvals(a), enforce)


def _pair_up(z: np.ndarray, enforce: bool) -> np.ndarray:
    """Eigenvalues (P, 2m) -> m upper-half-plane pole representatives per row. Real eigenvalues
    (which come in an even number) are merged pairwise into a lightly oscillating complex pair."""
    P, n = z.shape
    m = n // 2
    tol = 1e-9 * np.maximum(np.abs(z).max(axis=1, keepdims=True), 1e-300)
    srt = np.take_along_axis(z, np.argsort(-z.imag, axis=1), axis=1)
    out = srt[:, :m].copy()
    for p in np.flatnonzero(np.any(out.imag <= tol, axis=1)):  # rows with real eigenvalues
        zp = z[p]
        cpx = zp[zp.imag > tol[p, 0]]
        real = np.sort(zp[np.abs(zp.imag) <= tol[p, 0]].real)
        merged = [complex(0.5 * (real[i] + real[i + 1]),
                          max(0.5 * abs(real[i + 1] - real[i]), 1e-6 * abs(real[i]) + 1e-9))
                  for i in range(0, real.size - 1, 2)]
        poles = np.concatenate([cpx, np.array(merged, complex)])[:m]
        if poles.size < m:  # cannot happen for a real matrix; keep the shape anyway
            poles = np.concatenate([poles, np.full(m - poles.size, -1.0 + 1j)])
        out[p] = poles
    if enforce:
        re = out.real
        scale = np.maximum(np.abs(out), 1e-12)
        re = np.where(re > 0, -re, re)
        re = np.where(re > -1e-8 * scale, -1e-8 * scale, re)  # never exactly on the axis
        out = re + 1j * out.imag
    return out


def _residues(s, h, poles, w):
    """Residues (P, m) complex and D (P,) for fixed poles (weighted least squares)."""
    P, m = poles.shape
    phi = _basis(s, poles)
    ones = np.broadcast_to(np.ones_like(s)[None, :, None], (P, s.size, 1))
    a = np.concatenate([phi, ones], axis=2) * w[None, :, None]
    x = _lstsq(_stack(a), _stack((h * w[None, :])[..., None])[..., 0])
    return x[:, 0:2 * m:2] + 1j * x[:, 1:2 * m:2], x[:, 2 * m]


def evaluate(s: np.ndarray, poles: np.ndarray, residues: np.ndarray, d: np.ndarray) -> np.ndarray:
    """H(s) (P, K) of fitted pairs."""
    return (np.einsum("pkr,pr->pk", 1.0 / (s[None, :, None] - poles[:, None, :]), residues)
            + np.einsum("pkr,pr->pk", 1.0 / (s[None, :, None] - np.conj(poles)[:, None, :]), np.conj(residues))
            + d[:, None])


def impulse_response(t: np.ndarray, poles: np.ndarray, residues: np.ndarray) -> np.ndarray:
    """K(t) (P, n_t) without the D delta: sum_r 2 Re(c_r exp(p_r t))."""
    return 2.0 * np.einsum("pr,ptr->pt", residues, np.exp(poles[:, None, :] * np.asarray(t, float)[None, :, None])).real


def vector_fit(omega: np.ndarray, h: np.ndarray, order: int, *, iterations: int | None = None,
               enforce_stability: bool = True, weight: np.ndarray | None = None):
    """Fit each row of h (P, K) on s = i omega with ``order`` (even) poles; returns poles (P, m),
    residues (P, m), D (P,)."""
    omega = np.asarray(omega, float)
    s = 1j * omega
    h = np.asarray(h, complex)
    P = h.shape[0]
    m = order // 2
    w = np.ones(omega.size) if weight is None else np.asarray(weight, float)
    top = omega.max()
    beta = top * (np.arange(m) + 0.5) / m
    poles = np.tile(-beta / 100.0 + 1j * beta, (P, 1))
    res, d = np.empty((P, m), complex), np.empty(P)
    for lo in range(0, P, CHUNK):  # pairs are independent: blocks small enough to stay in cache
        part = slice(lo, lo + CHUNK)
        for _ in range(iterations or ITER):
            poles[part] = _relocate(s, h[part], poles[part], w, enforce_stability)
        res[part], d[part] = _residues(s, h[part], poles[part], w)
    return poles, res, d


@dataclass
class PairFits:
    """Fitted DOF pairs: output row, input column, poles/residues (per pair, ragged), D, error."""
    rows: np.ndarray
    cols: np.ndarray
    poles: list[np.ndarray] = field(default_factory=list)
    residues: list[np.ndarray] = field(default_factory=list)
    d: np.ndarray | None = None
    error: np.ndarray | None = None
    repaired: int = 0
    fitted: int = 0  # distinct pair fits computed to get these (0: taken from a cache)

    @property
    def orders(self) -> np.ndarray:
        return np.array([2 * p.size for p in self.poles], int)


def distinct_rows(h: np.ndarray, scale: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Exact duplicates among the pairs: (first, inverse) with h[first] the distinct rows (same
    samples and scale, byte for byte) and h[first][inverse] == h. Identical kernels (an array of
    identical bodies, the far-apart blocks of one HDB) are thus fitted once."""
    seen: dict[bytes, int] = {}
    inverse = np.array([seen.setdefault(h[p].tobytes() + scale[p].tobytes(), len(seen)) for p in range(h.shape[0])],
                       int)
    return np.unique(inverse, return_index=True)[1], inverse


def fit_pairs(omega: np.ndarray, h: np.ndarray, rows: np.ndarray, cols: np.ndarray, scale: np.ndarray, *,
              tolerance: float = 0.01, order: int | None = None, max_order: int = 24,
              enforce_stability: bool = True) -> PairFits:
    """Fit h (P, K) of pairs (rows, cols) with per-pair error scale (P,): fixed ``order``, or the
    smallest even order meeting ``tolerance`` (see module docstring). Identical pairs are fitted
    once (:func:`distinct_rows`); every pair's fit is independent of the others."""
    h = np.asarray(h, complex)
    scale = np.asarray(scale, float)
    first, inverse = distinct_rows(h, scale)
    h, scale = h[first], scale[first]
    P = h.shape[0]
    poles_, res_, d_, err_ = [None] * P, [None] * P, np.zeros(P), np.full(P, np.inf)
    s = 1j * np.asarray(omega, float)
    todo = np.arange(P)
    orders = [order] if order else list(range(2, max_order + 1, 2))
    for n in orders:
        if not todo.size:
            break
        poles, res, d = vector_fit(omega, h[todo], n, enforce_stability=enforce_stability)
        err = np.max(np.abs(evaluate(s, poles, res, d) - h[todo]), axis=1) / scale[todo]
        better = err < err_[todo]
        for k in np.flatnonzero(better):
            p = todo[k]
            poles_[p], res_[p], d_[p], err_[p] = poles[k], res[k], d[k], err[k]
        todo = todo[err_[todo] > tolerance]
    return PairFits(np.asarray(rows, int), np.asarray(cols, int), [poles_[i] for i in inverse],
                    [res_[i] for i in inverse], d_[inverse], err_[inverse], fitted=P)


# ----------------------------------------------------------------------------------- realisation

def check_stable(poles: np.ndarray, where: str) -> None:
    """Refuse a pole with Re >= 0 (the realisation would grow without bound)."""
    poles = np.asarray(poles)
    bad = poles.real >= 0
    if np.any(bad):
        p = poles[bad][np.argmax(poles[bad].real)]
        raise StateSpaceError(
            f"the state-space fit of {where} has an unstable pole p = {p.real:+.4g} {p.imag:+.4g}i "
            f"(Re p >= 0: its response grows without bound); keep hydro.ss_enforce_stability = true "
            f"(poles are reflected into the left half plane), lower hydro.ss_order, or use "
            f"radiation = \"convolution\"")


def foh_coefficients(poles: np.ndarray, h: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """phi, g0, g1 of the exact first-order-hold step (module docstring); series near p h -> 0."""
    p = np.asarray(poles, complex)
    x = p * h
    phi = np.exp(x)
    small = np.abs(x) < 1e-4
    xs = np.where(small, 1.0, x)
    e1 = np.where(small, 1 + x / 2 + x * x / 6, (phi - 1) / xs)          # (phi - 1)/x
    e2 = np.where(small, 0.5 + x / 6 + x * x / 24, (phi - 1 - xs) / xs ** 2)  # (phi - 1 - x)/x^2
    g1 = h * e2                      # = -1/p + (phi - 1)/(h p^2)
    g0 = h * e1 - g1                 # = (phi - 1)/p - g1
    return phi, g0, g1


@dataclass(frozen=True)
class Realization:
    """A radiation force as a continuous-time linear system of the velocities v of its DOFs:
    x' = a x + b v, F = c x + d v; ``rows``/``cols``: the DOF pair (output, input) of every state."""
    a: np.ndarray
    b: np.ndarray
    c: np.ndarray
    d: np.ndarray
    rows: np.ndarray
    cols: np.ndarray


class StateSpaceRadiation:
    """Radiation force of n DOFs from fitted pairs; the same push() interface as RadiationMemory."""

    def __init__(self, n: int, fits: PairFits, dt: float, labels: list[str] | None = None):
        self.n, self.dt = n, float(dt)
        rows, cols = [], []
        poles, res = [], []
        for k, (i, j) in enumerate(zip(fits.rows, fits.cols)):
            p = fits.poles[k]
            if p is None:
                continue
            where = (f"DOF pair ({labels[i]}, {labels[j]})" if labels else f"DOF pair ({i}, {j})")
            check_stable(p, where)
            rows.append(np.full(p.size, i))
            cols.append(np.full(p.size, j))
            poles.append(p)
            res.append(fits.residues[k])
        cat = (lambda a, t: np.concatenate(a).astype(t)) if poles else (lambda a, t: np.zeros(0, t))
        self._rows, self._cols = cat(rows, int), cat(cols, int)
        self.poles, self._c2 = cat(poles, complex), 2.0 * cat(res, complex)
        order = np.argsort(self._rows, kind="stable")   # states grouped by output row
        self._rows, self._cols = self._rows[order], self._cols[order]
        self.poles, self._c2 = self.poles[order], self._c2[order]
        self._phi, self._g0, self._g1 = foh_coefficients(self.poles, self.dt)
        self.d = np.zeros((n, n))
        for k, (i, j) in enumerate(zip(fits.rows, fits.cols)):
            if fits.poles[k] is not None:
                self.d[i, j] = fits.d[k]
        self._has_d = bool(np.any(self.d))
        self.states = 2 * self.poles.size  # real states (order) in all
        self._z = np.zeros(self.poles.size, complex)
        self._z_prev = self._z.copy()
        self._v_prev = np.zeros(n)
        self._v_last = np.zeros(n)
        self._count = 0
        starts = np.searchsorted(self._rows, np.arange(n))
        self._present = np.unique(self._rows)
        self._starts = starts[self._present] if self._present.size else starts[:0]

    @property
    def count(self) -> int:
        return self._count

    def state(self) -> tuple:
        """What push() changes, copied (a session rolled back restores it: :meth:`set_state`)."""
        return self._z.copy(), self._z_prev.copy(), self._v_prev.copy(), self._v_last.copy(), self._count

    def set_state(self, state: tuple) -> None:
        z, z_prev, v_prev, v_last, self._count = state
        self._z, self._z_prev, self._v_prev, self._v_last = z.copy(), z_prev.copy(), v_prev.copy(), v_last.copy()

    def reset(self) -> None:
        self._z[:] = 0
        self._z_prev[:] = 0
        self._v_prev[:] = 0
        self._v_last[:] = 0
        self._count = 0

    def realization(self) -> "Realization":
        """The continuous-time model of this force, F = C x + D v, x' = A x + B v, in real states:
        each complex state z_r (z' = p z + v_j) as (Re z, Im z), F_i -= 2 Re(c_r z_r) + D_ij v_j."""
        s = self.poles.size
        a, b, c = np.zeros((2 * s, 2 * s)), np.zeros((2 * s, self.n)), np.zeros((self.n, 2 * s))
        re, im = 2 * np.arange(s), 2 * np.arange(s) + 1
        a[re, re] = a[im, im] = self.poles.real
        a[re, im] = -self.poles.imag
        a[im, re] = self.poles.imag
        b[re, self._cols] = 1.0
        c[self._rows, re] = -self._c2.real
        c[self._rows, im] = self._c2.imag
        return Realization(a, b, c, -self.d, np.repeat(self._rows, 2), np.repeat(self._cols, 2))

    def feedthrough(self) -> np.ndarray:
        """dF/dv of the newest sample (n, n): the first-order hold's direct term of every state
        (Re 2 c g1) plus D, negated like the force."""
        out = self.d.copy()
        np.add.at(out, (self._rows, self._cols), (self._c2 * self._g1).real)
        return -out

    def fused(self) -> FusedRadiation:
        """This force as the fused step takes it (server/fused/step.py): the recursion's coefficients."""
        return FusedRadiation("state-space", phi=self._phi, g0=self._g0, g1=self._g1, c2=self._c2, rows=self._rows,
                              cols=self._cols, d=self.d if self._has_d else np.zeros((0, 0)))

    def push(self, v: np.ndarray, replace_last: bool = False) -> np.ndarray:
        v = np.asarray(v, float)
        if not (replace_last and self._count):
            self._z_prev, self._z = self._z, self._z_prev   # keep the state before this step
            self._v_prev = self._v_last.copy()
            self._count += 1
        self._v_last = v.copy()
        z = self._z
        np.multiply(self._phi, self._z_prev, out=z)
        z += self._g0 * self._v_prev[self._cols]
        z += self._g1 * v[self._cols]
        out = np.zeros(self.n)
        if self._present.size:
            out[self._present] = np.add.reduceat((self._c2 * z).real, self._starts)
        if self._has_d:
            out += self.d @ v
        return -out
