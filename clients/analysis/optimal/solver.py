"""Solve the optimal-control QP (clients/analysis/optimal/problem.py).

Measured choice (docs/optimal-control.md "Solver"): with linear limits on a fine grid the problem is a
convex QP with a dense constraint matrix (every fine-grid row reads every node), solved by DAQP's dual
active-set method, exact at its active set. OSQP (operator splitting + polishing) reaches the same
optimum but needs thousands of iterations when the force limit holds most of the period: 140 s against
DAQP's 4.9 s for the WaveBot's irregular sea (267 nodes, 2136 rows; both at load 12-15), and
scipy's SLSQP took 4.4 s against OSQP's 0.29 s on RM3 at order 10. The optional
no-reactive-power rule (u(t) v(t) >= 0 at every fine-grid instant) and the PTO efficiency rule (mean of
the electrical power eta p when p = u v >= 0, p / eta when the PTO feeds power back) are not convex: they
are solved by SLSQP from the QP's optimum, on a grid 8x finer than the limits' (a sampled product lets
the force lead the velocity by about pi / samples, which is worth a first-order power gain). The
efficiency's |p| is smoothed, sqrt(p^2 + e^2), with e shrunk from 1e-2 to 1e-4 of the peak power, the
result's electrical power then sampled exactly. Without limits the optimum is the complex-conjugate
bound of the collocated model, H u = -q (least squares: the mean force does no work).
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
    power: float                # W, mean absorbed (mechanical)
    unconstrained_u: np.ndarray
    unconstrained_power: float  # W: the complex-conjugate bound of the same model
    solver: str
    status: str
    iterations: int
    solve_seconds: float
    utilisation: dict[str, float]   # label -> max |value| / bound on the fine grid
    active: list[str]               # labels with utilisation >= 0.999
    electrical_power: float         # W: mean of eta p+ - p- / eta (= power when the efficiency is 1)


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
    """The constrained optimum (DAQP; SLSQP for the no-reactive-power and efficiency rules)."""
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
        x, its, status = _active_set(prob, Hs, qs, A, lo, hi, tolerance)
        name = "daqp"
    else:
        x, its, name, status = x_cc, 0, "lstsq", "solved"
    dense = _DensePower(prob, scale) if (not prob.reactive or prob.efficiency < 1) else None
    if dense is not None:
        x, its, status = _nonconvex(prob, dense, Hs, qs, A, lo, hi, x, p_cc)
        name = "daqp+slsqp" if binding else "slsqp"
    u = x * scale
    util = {lim.label: float(np.abs(lim.rows @ u + lim.offset).max() / lim.bound) for lim in prob.limits}
    return OptimalSolution(u, prob.power(u), u_cc, p_cc, name, status, its, _time.perf_counter() - t0, util,
                           [k for k, v in util.items() if v >= 0.999],
                           prob.power(u) if dense is None else dense.electrical(x, prob.efficiency))


# DAQP's exit flags (https://darnstrom.github.io/daqp/parameters)
_DAQP_EXIT = {1: "solved", 2: "solved (soft constraints)", -1: "infeasible", -2: "cycling", -3: "unbounded",
              -4: "iteration limit", -5: "non-convex", -6: "overdetermined initial active set"}


def _active_set(prob: OptimalProblem, Hs, qs, A, lo, hi, tolerance: float) -> tuple[np.ndarray, int, str]:
    """The QP by DAQP's dual active-set method (dense; the Hessian's null direction, a constant force
    that does no work, regularised)."""
    import daqp

    n = Hs.shape[0]
    reg = 1e-6 * float(np.abs(np.diag(Hs)).max())   # the null direction (a mean force, no work) held at 0; power ~1e-6
    x, _, flag, info = daqp.solve(np.ascontiguousarray(Hs + reg * np.eye(n)), np.ascontiguousarray(qs),
                                  np.ascontiguousarray(A), np.ascontiguousarray(hi), np.ascontiguousarray(lo),
                                  np.zeros(A.shape[0], dtype=np.int32), primal_tol=tolerance, iter_limit=100000)
    status = _DAQP_EXIT.get(int(flag), f"exit flag {flag}")
    if flag == -1:
        keys = ", ".join(sorted({lim.key for lim in prob.limits}))
        raise OptimizeError("optimize.limits", f"the limits admit no periodic motion ({keys}): the PTO forces "
                                               "cannot hold the motion within them; relax one")
    if flag != 1 or not np.all(np.isfinite(x)):
        raise OptimizeError("optimize", f"DAQP did not solve the QP ({status})")
    return np.asarray(x, float), int(info["iterations"]), status


class _DensePower:
    """The PTOs' instantaneous power on a dense grid, 8x the limits' (the product u v holds twice the
    harmonics, and a sampled u v >= 0 lets u lead v by up to about pi / samples, a first-order power
    gain): p = scale (Rk x) (V x + v0) for the scaled force nodes x, PTO-major rows."""

    def __init__(self, prob: OptimalProblem, scale: float):
        from hydrolink.clients.analysis.steady import fourier_matrices

        m = prob.n_pto
        self.samples = 8 * prob.t_fine.size
        k = np.arange(-prob.order, prob.order + 1)
        t = np.arange(self.samples) * 2 * np.pi / prob.omega0 / self.samples
        R = np.real(np.exp(1j * np.outer(prob.omega0 * t, k)) @ fourier_matrices(prob.order, prob.omega0)[2])
        self.Rk = np.kron(np.eye(m), R)                                   # force nodes -> dense grid
        self.V = self.Rk @ prob.velocity_rows() * scale                   # scaled force -> dense-grid rates
        self.v0 = self.Rk @ np.kron(np.eye(m), prob.D1) @ prob.s0
        self.scale = scale

    def power(self, x: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """(p (W) at the dense instants, dp/dx)."""
        f, v = self.Rk @ x, self.V @ x + self.v0
        return self.scale * f * v, self.scale * (v[:, None] * self.Rk + f[:, None] * self.V)

    def electrical(self, x: np.ndarray, efficiency: float) -> float:
        """Mean electrical power (W): eta p where p >= 0, p / eta where p < 0, summed over the PTOs."""
        p = self.power(x)[0]
        return float(np.where(p >= 0, efficiency * p, p / efficiency).sum() / self.samples)


def _nonconvex(prob: OptimalProblem, dense: _DensePower, Hs, qs, A, lo, hi, x0, p_cc: float) -> tuple[np.ndarray, int, str]:
    """SLSQP from ``x0`` under the limits, with u(t) v(t) >= 0 on the dense grid when ``reactive`` is
    false, maximising the electrical power a p - b |p| (a = (eta + 1/eta) / 2, b = (1/eta - eta) / 2,
    |p| smoothed) when the efficiency eta < 1, else the QP's mechanical power."""
    from scipy.optimize import minimize

    p_x0 = dense.power(x0)[0]
    ps = max(float(np.abs(p_x0).max()), 1e-300)          # the constraint rows' scale
    cons = []
    if not prob.reactive:
        cons.append({"type": "ineq", "fun": lambda x: dense.power(x)[0] / ps, "jac": lambda x: dense.power(x)[1] / ps})
    if A.shape[0]:
        cons += [{"type": "ineq", "fun": lambda x: hi - A @ x, "jac": lambda x: -A},
                 {"type": "ineq", "fun": lambda x: A @ x - lo, "jac": lambda x: A}]
    # start from a passive law when the rule forbids reactive power: the QP's optimum if it feeds none
    x = x0 * (prob.reactive or p_x0.min() >= 0)
    eta = prob.efficiency
    a, b = 0.5 * (eta + 1 / eta), 0.5 * (1 / eta - eta)
    norm = dense.samples * p_cc                    # summed W -> the QP's units (power / the bound)
    iterations = 0
    for eps in ((1e-2, 1e-3, 1e-4) if eta < 1 else (None,)):
        if eps is None:
            fun = lambda x: (0.5 * x @ Hs @ x + qs @ x, Hs @ x + qs)     # noqa: E731
        else:
            def fun(x, e=eps * ps):
                p, dp = dense.power(x)
                r = np.sqrt(p * p + e * e)
                return -(a * p.sum() - b * r.sum()) / norm, -(a * dp.sum(axis=0) - b * (p / r) @ dp) / norm
        res = minimize(fun, x, jac=True, constraints=cons, method="SLSQP", options={"maxiter": 500, "ftol": 1e-12})
        x, iterations = np.asarray(res.x, float), iterations + int(res.nit)
        status = "solved" if res.success else f"slsqp: {res.message}"
    if not prob.reactive and dense.power(x)[0].min() / ps < -1e-6:
        raise OptimizeError("optimize.reactive", f"SLSQP found no force without reactive power ({status})")
    return x, iterations, status


def loss_penalty(prob: OptimalProblem, efficiency: float) -> tuple[float, float]:
    """(rho W/N^2, its electrical power W): the force penalty rho whose convex QP optimum (maximise the
    mechanical power minus rho mean(u^2), under the limits) has the highest electrical power at
    ``efficiency`` — the convex stand-in for the efficiency rule an MPC can solve each step
    (examples/controllers/mpc.py ``force_penalty``). A bounded scalar search over log rho around
    the bound's power / mean(u*^2)."""
    from scipy.optimize import minimize_scalar

    u_cc = unconstrained(prob)
    p_cc = prob.power(u_cc)
    scale = max(float(np.abs(u_cc).max()), 1e-12)
    rho0 = p_cc / max(float(np.mean(u_cc ** 2)), 1e-300)
    A, lo, hi = _stacked(prob, scale)
    dense = _DensePower(prob, scale)
    n = prob.q.size

    def electrical(log_rho: float) -> float:
        H = (prob.H + 2 * rho0 * 10 ** log_rho / prob.points * np.eye(n)) * scale ** 2 / p_cc
        qs = prob.q * scale / p_cc
        x = _active_set(prob, H, qs, A, lo, hi, 1e-6)[0] if A.shape[0] else np.linalg.solve(H, -qs)
        return dense.electrical(x, efficiency)

    best = minimize_scalar(lambda s: -electrical(s), bounds=(-3.0, 1.0), method="bounded", options={"xatol": 0.01})
    return rho0 * 10 ** float(best.x), -float(best.fun)
