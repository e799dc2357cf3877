"""Solve the optimal-control QP (clients/analysis/optimal/problem.py).

Measured choice (docs/optimal-control.md "Solver"): with linear limits on a fine grid the problem is a
convex QP, solved by OSQP (operator splitting, then its solution polishing: the active set solved
exactly). scipy's SLSQP on the same QP reaches the same optimum (to 1e-13) but took 4.4 s against
OSQP's 0.29 s on RM3 at order 10 (21 force nodes, 168 limit rows), and 0.37 s against 0.23 s on the
WaveBot at order 7 (loaded 2-core VM). The optional
no-reactive-power rule (u(t) v(t) >= 0 at every fine-grid instant) is not convex: it is solved by
SLSQP from the QP's optimum, on a grid 8x finer than the limits' (a sampled product lets the force lead
the velocity by about pi / samples, which is worth a first-order power gain). Without limits the optimum is the
complex-conjugate bound of the collocated model, H u = -q (least squares: the mean force does no work).
"""

from __future__ import annotations

import time as _time
from dataclasses import dataclass

import numpy as np

from hydrolink.clients.analysis.optimal.problem import OptimalProblem, OptimizeError


@dataclass(frozen=True)
class OptimalSolution:
    """The optimum's force nodes and what limits it."""
    u: np.ndarray               # (m P,) PTO force at the nodes, PTO-major
    power: float                # W, mean absorbed
    unconstrained_u: np.ndarray
    unconstrained_power: float  # W: the complex-conjugate bound of the same model
    solver: str
    status: str
    iterations: int
    solve_seconds: float
    utilisation: dict[str, float]   # label -> max |value| / bound on the fine grid
    active: list[str]               # labels with utilisation >= 0.999


def unconstrained(prob: OptimalProblem) -> np.ndarray:
    """The complex-conjugate optimum of the collocated model (no limits)."""
    return np.linalg.lstsq(prob.H, -prob.q, rcond=1e-12)[0]


def _stacked(prob: OptimalProblem, scale: float) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """Constraint rows (in the scaled force) and their lower/upper bounds."""
    if not prob.limits:
        return np.zeros((0, prob.q.size)), np.zeros(0), np.zeros(0)
    A = np.vstack([lim.rows for lim in prob.limits]) * scale
    off = np.concatenate([lim.offset for lim in prob.limits])
    bnd = np.concatenate([np.full(lim.offset.size, lim.bound) for lim in prob.limits])
    return A, -bnd - off, bnd - off


def solve_optimal(prob: OptimalProblem, *, tolerance: float = 1e-6) -> OptimalSolution:
    """The constrained optimum (OSQP; SLSQP for the no-reactive-power rule)."""
    import osqp
    from scipy import sparse

    t0 = _time.perf_counter()
    u_cc = unconstrained(prob)
    p_cc = prob.power(u_cc)
    if not p_cc > 0:
        raise OptimizeError("waves", "the waves do no work on the PTOs (the excitation does not reach a PTO's "
                                     "motion): nothing to absorb")
    scale = max(float(np.abs(u_cc).max()), 1e-12)
    Hs, qs = prob.H * scale ** 2 / p_cc, prob.q * scale / p_cc
    A, lo, hi = _stacked(prob, scale)
    x_cc = u_cc / scale
    binding = A.shape[0] and not (np.all(A @ x_cc <= hi) and np.all(A @ x_cc >= lo))   # else the bound is the optimum
    if binding:
        solver = osqp.OSQP()
        solver.setup(P=sparse.triu(Hs + 1e-10 * np.eye(Hs.shape[0]), format="csc"), q=qs,
                     A=sparse.csc_matrix(A), l=lo, u=hi, eps_abs=tolerance, eps_rel=tolerance,
                     max_iter=400000, polishing=True, verbose=False)
        res = solver.solve(raise_error=False)
        status = str(res.info.status)
        if "infeasible" in status:
            keys = ", ".join(sorted({lim.key for lim in prob.limits}))
            raise OptimizeError("optimize.limits", f"the limits admit no periodic motion ({keys}): the PTO forces "
                                                   "cannot hold the motion within them; relax one")
        if res.x is None or not np.all(np.isfinite(res.x)) or status not in ("solved", "solved inaccurate"):
            raise OptimizeError("optimize", f"OSQP did not solve the QP (status {status!r})")
        x, its, name = np.asarray(res.x, float), int(res.info.iter), "osqp"
    else:
        x, its, name, status = x_cc, 0, "lstsq", "solved"
    if not prob.reactive:
        x, its, status = _no_reactive(prob, Hs, qs, A, lo, hi, x, scale)
        name = "osqp+slsqp" if A.shape[0] else "slsqp"
    u = x * scale
    util = {lim.label: float(np.abs(lim.rows @ u + lim.offset).max() / lim.bound) for lim in prob.limits}
    return OptimalSolution(u, prob.power(u), u_cc, p_cc, name, status, its, _time.perf_counter() - t0, util,
                           [k for k, v in util.items() if v >= 0.999])


def _no_reactive(prob: OptimalProblem, Hs, qs, A, lo, hi, x0, scale) -> tuple[np.ndarray, int, str]:
    """SLSQP with u(t) v(t) >= 0 on the fine grid (PTO power never negative), from ``x0``."""
    from scipy.optimize import minimize

    from hydrolink.clients.analysis.steady import fourier_matrices

    m = prob.n_pto
    # the product u v holds twice the harmonics, and a sampled u v >= 0 lets u lead v by up to about
    # pi / (samples per period), a first-order power gain: the rule is sampled 8x denser than the limits
    dense = 8 * prob.t_fine.size
    k = np.arange(-prob.order, prob.order + 1)
    t = np.arange(dense) * 2 * np.pi / prob.omega0 / dense
    R = np.real(np.exp(1j * np.outer(prob.omega0 * t, k)) @ fourier_matrices(prob.order, prob.omega0)[2])
    Rk = np.kron(np.eye(m), R)                               # force nodes -> fine grid
    V = Rk @ prob.velocity_rows() * scale                    # scaled force -> fine-grid rates
    v0 = Rk @ np.kron(np.eye(m), prob.D1) @ prob.s0
    vs = max(float(np.abs(V @ x0 + v0).max()), 1e-12)

    def power_rows(x):
        return (Rk @ x) * (V @ x + v0) / vs

    cons = [{"type": "ineq", "fun": power_rows,
             "jac": lambda x: ((V @ x + v0)[:, None] * Rk + (Rk @ x)[:, None] * V) / vs}]
    if A.shape[0]:
        cons += [{"type": "ineq", "fun": lambda x: hi - A @ x, "jac": lambda x: -A},
                 {"type": "ineq", "fun": lambda x: A @ x - lo, "jac": lambda x: A}]
    # start from a passive law: the QP optimum's force with its reactive part removed where it feeds power
    start = x0 * (power_rows(x0).min() >= 0)
    res = minimize(lambda x: 0.5 * x @ Hs @ x + qs @ x, start, jac=lambda x: Hs @ x + qs, constraints=cons,
                   method="SLSQP", options={"maxiter": 500, "ftol": 1e-12})
    if not res.success and power_rows(res.x).min() < -1e-6:
        raise OptimizeError("optimize.reactive", f"SLSQP found no force without reactive power ({res.message})")
    return np.asarray(res.x, float), int(res.nit), "solved" if res.success else f"slsqp: {res.message}"
