"""The constrained optimal-control problem as a QP on the collocation model of ``hydrolink steady``.

Over one period T = 2 pi / w0 of the wave (regular: w0 the wave's frequency; irregular: the repeat
period of components that are all harmonics of one w0) the body coordinates are the nodal values of a
truncated Fourier series, collocated at P = 2N + 1 instants with the operator L of
clients/analysis/steady.py (``_operators``: mass, stiffness, constraints by the null-space (ODE) form,
radiation per harmonic). The PTO forces u_i(t_j) are the decision variables instead of the PTOs'
spring-damper laws; every PTO acts as -g_i u_i, so the dynamics are linear in u::

    L z + sum_i (g_i (x) I) u_i = b        ->   z = z0 + S u,   s_i = (g_i (x) I) z = s0_i + T_i u

and the mean absorbed power, (1/P) sum_j u_j . (D s)_j (exact for the product of two order-N
series sampled at 2N + 1 points), is a quadratic form in u: maximising it is the QP
``min 1/2 u^T H u + q^T u`` (H positive semi-definite for a passive device, checked). Limits are
linear in u and enforced on a **fine grid** of ``oversampling`` points per collocation interval by
trigonometric interpolation (between the nodes an order-N series overshoots its nodal values: a
limit held only at the nodes lets the force exceed it by tens of percent).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

from hydrolink.clients.analysis.steady import (LinearizedSystem, SteadyError, _operators, _pin_free_modes,
                                               fourier_matrices)
from hydrolink.protocol.scene import DOF_NAMES, IrregularWave, RegularWave, Scene


class OptimizeError(SteadyError):
    """A scene or limit the optimiser cannot use; the message names the key and why."""


@dataclass(frozen=True)
class LimitRow:
    """One limited quantity, sampled on the fine grid: value(u) = rows @ u + offset, |value| <= bound."""
    label: str          # e.g. "pto.force", "float.heave.displacement"
    key: str            # the scene key that set it
    rows: np.ndarray    # (M, m P)
    offset: np.ndarray  # (M,)
    bound: float


@dataclass
class OptimalProblem:
    """The QP and the maps from the force nodes u (m P,) back to the motion."""
    system: LinearizedSystem
    omega0: float                 # fundamental, rad/s
    order: int
    harmonics: np.ndarray         # wave components' harmonic numbers (of omega0)
    t: np.ndarray                 # nodes (P,)
    t_fine: np.ndarray            # fine grid (M,)
    N: np.ndarray                 # (n_full, n) null-space basis: q = N z
    z0: np.ndarray                # (n P,) motion without PTO force
    S: np.ndarray                 # (n P, m P) dz/du
    s0: np.ndarray                # (m P,) PTO extensions without force
    Ts: np.ndarray                # (m P, m P) ds/du
    D1: np.ndarray                # (P, P) differentiation
    interp: np.ndarray            # (M, P) nodes -> fine grid
    H: np.ndarray                 # (m P, m P) PSD: -power = 1/2 u^T H u + q^T u
    q: np.ndarray                 # (m P,)
    limits: list[LimitRow] = field(default_factory=list)
    reactive: bool = True
    efficiency: float = 1.0
    excitation: tuple[np.ndarray, np.ndarray, np.ndarray] | None = None   # (omega_c, X_c (n_c, n_full), eta_c)
    warnings: list[str] = field(default_factory=list)

    @property
    def n_pto(self) -> int:
        return len(self.system.ptos)

    @property
    def points(self) -> int:
        return self.t.size

    def power(self, u: np.ndarray) -> float:
        """Mean absorbed power (W) of the force nodes u."""
        return -float(0.5 * u @ self.H @ u + self.q @ u)

    def velocity_rows(self) -> np.ndarray:
        """(m P, m P): PTO rates at the nodes = velocity_rows @ u + velocity_offset."""
        return np.kron(np.eye(self.n_pto), self.D1) @ self.Ts


def harmonic_grid(scene: Scene, omega: np.ndarray) -> tuple[float, np.ndarray, int]:
    """(w0, harmonic numbers of the components, order): regular waves: w0 = w, order from
    ``[optimize] order`` (default ``[steady] order``); irregular seas: w0 such that every component is a
    harmonic of it (the sea repeats after 2 pi / w0), order at least the highest harmonic."""
    if isinstance(scene.waves, RegularWave):
        return float(omega[0]), np.array([1]), scene.optimize.order or scene.steady.order
    if not isinstance(scene.waves, IrregularWave) or not omega.size:
        raise OptimizeError("waves.type", "hydrolink optimize needs regular or irregular waves (nothing to absorb "
                                          "in still water)")
    step = float(np.min(np.diff(np.sort(omega)))) if omega.size > 1 else float(omega[0])
    for w0 in (step, step / 2):
        h = omega / w0
        if np.all(np.abs(h - np.round(h)) < 1e-6):
            harmonics = np.round(h).astype(int)
            order = scene.optimize.order or int(harmonics.max())
            if order < harmonics.max():
                raise OptimizeError("optimize.order", f"{order} harmonics of the repeat period {2 * math.pi / w0:.4g} s "
                                                      f"do not reach the sea's highest component (harmonic "
                                                      f"{harmonics.max()}); give at least that, or leave it out")
            return w0, harmonics, order
    raise OptimizeError("waves.omega_range", "the sea's components are not harmonics of one repeat period (the "
                                             "components sit at the centres of equal bins from omega_range[0]): "
                                             "set omega_range = [j dw, ...] with dw = (high - low) / components, "
                                             "j an integer, so that the sea repeats")


def _bare(sys_: LinearizedSystem, omega0: float) -> LinearizedSystem:
    """The system with the PTOs' own spring-damper laws taken out (the optimiser commands their whole
    force) at the fundamental ``omega0``; the excitation is added per component by the caller."""
    ptos = [replace(p, stiffness=0.0, damping=0.0, preload=0.0, limit=math.inf) for p in sys_.ptos]
    return replace(sys_, omega=omega0, ptos=ptos, excitation=np.zeros_like(sys_.excitation))


def build_problem(scene: Scene, sys_: LinearizedSystem, excitation: tuple[np.ndarray, np.ndarray, np.ndarray]
                  ) -> OptimalProblem:
    """Assemble the QP of ``scene`` (limits from ``[optimize]`` and the PTOs' force limits) on the
    linearised system ``sys_``; ``excitation`` = (omega_c, X_c over the n coordinates, eta_c)."""
    from scipy.linalg import null_space

    if sys_.terms:
        raise OptimizeError("hydro", "hydrolink optimize solves a linear model; the force terms "
                                     f"{', '.join(t.name for t in sys_.terms)} are nonlinear (leave them out)")
    if not sys_.ptos:
        raise OptimizeError("ptos", "no PTO: there is no force to optimise")
    omega_c, x_c, _ = excitation
    w0, harmonics, order = harmonic_grid(scene, omega_c)
    bare = _bare(sys_, w0)
    N = null_space(bare.G) if bare.G.shape[0] else np.eye(bare.M.shape[0])
    L, b, gs, D1, t, n = _operators(bare, order, N)
    p = t.size
    warnings: list[str] = []
    pin = _pin_free_modes(bare, N, 0, p, warnings)
    A = L + pin if pin is not None else L
    fex = np.real(np.exp(-1j * np.outer(t, omega_c)) @ (x_c @ N)).T      # (n, P)
    b = b + fex.reshape(-1)
    B = np.hstack([np.kron(g[:, None], np.eye(p)) for g in gs])          # (n P, m P)
    lu = _factor(A)
    z0, S = lu(b), -lu(B)
    C = B.T
    s0, Ts = C @ z0, C @ S
    m = len(gs)
    Dk = np.kron(np.eye(m), D1)
    G = Dk @ Ts / p
    H = -(G + G.T)
    q = -(Dk @ s0) / p
    _check_passive(H)
    k = np.arange(-order, order + 1)
    _, _, E, _, _ = fourier_matrices(order, w0)
    fine = max(scene.optimize.oversampling * p, 128)
    t_fine = np.arange(fine) * (2 * math.pi / w0) / fine
    interp = np.real(np.exp(1j * np.outer(w0 * t_fine, k)) @ E)
    prob = OptimalProblem(sys_, w0, order, harmonics, t, t_fine, N, z0, S, s0, Ts, D1, interp, H, q,
                          reactive=scene.optimize.reactive, efficiency=scene.optimize.efficiency,
                          excitation=excitation, warnings=warnings)
    prob.limits = _limit_rows(scene, prob)
    return prob


def _factor(A: np.ndarray):
    """x = A^-1 y by one LU (the collocated operator; singular: the scene has a mode no force holds)."""
    from scipy.linalg import lu_factor, lu_solve

    lu = lu_factor(A, check_finite=True)
    if np.any(np.abs(np.diag(lu[0])) < 1e-13 * np.abs(np.diag(lu[0])).max()):
        raise OptimizeError("bodies", "the collocated equations are singular (a mode without stiffness or "
                                      "damping at a harmonic): no periodic motion is determined")
    return lambda y: lu_solve(lu, y)


def _check_passive(H: np.ndarray) -> None:
    """H must be positive semi-definite (a passive device cannot give power for ever)."""
    ev = np.linalg.eigvalsh(H)
    if ev.min() < -1e-6 * max(abs(ev).max(), 1e-300):     # beyond the round-off of the LU solves
        raise OptimizeError("bodies", "the absorbed power has no maximum (the linear model is not passive: "
                                      f"an eigenvalue {ev.min():.3g} of the power's quadratic form is negative)")


def _limit_rows(scene: Scene, prob: OptimalProblem) -> list[LimitRow]:
    """The fine-grid rows of every limit of the scene (metrics.scene_limits: ``[[optimize.limits]]``
    and the PTOs' force limits)."""
    from hydrolink.clients.analysis.optimal.metrics import scene_limits

    names, bodies = prob.system.pto_names, prob.system.body_names
    p, R = prob.points, prob.interp
    rows: list[LimitRow] = []
    for lim in scene_limits(scene):
        if lim.quantity in ("displacement", "body_velocity"):
            body, dof = lim.target.rsplit(".", 1)      # names checked by the scene (Scene._check_optimize_limits)
            idx = prob.system.body_index[6 * bodies.index(body) + DOF_NAMES.index(dof)]
            sel = np.kron(prob.N[idx][None, :], np.eye(p))          # (P, n P): the coordinate at the nodes
            op = (R if lim.quantity == "displacement" else R @ prob.D1) @ sel
            rows.append(LimitRow(lim.label, lim.key, op @ prob.S, op @ prob.z0, lim.bound))
            continue
        sel = np.kron(np.eye(len(names))[names.index(lim.target)], np.eye(p))     # (P, m P)
        if lim.quantity == "force":
            rows.append(LimitRow(lim.label, lim.key, R @ sel, np.zeros(R.shape[0]), lim.bound))
        else:
            op = (R if lim.quantity == "stroke" else R @ prob.D1) @ sel
            rows.append(LimitRow(lim.label, lim.key, op @ prob.Ts, op @ prob.s0, lim.bound))
    return rows
