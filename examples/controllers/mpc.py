"""Model-predictive control under limits: a receding-horizon QP (DAQP) on the plant the controller
receives at join, maximising the absorbed power over the next ``horizon`` seconds with the PTO force,
stroke and velocity limits, the wave excitation predicted from the server's preview (perfect) or from
an up-wave gauge (realistic).

Model: the discrete plant at the control period Ts (``plant = period``, zero-order hold, SPEC §5.7.2),
x+ = A x + B_u u + B_e e (u the force command, e the excitation forces). The command computed from the
measurements at t_k acts over [t_k+1, t_k+2] (the scene's ``latency`` must be one control period:
``latency = period / dt``). State estimate: the mechanical states are measured (``body_position``,
``body_velocity``); the radiation states are propagated by the plant from the previous estimate with
the command in force and the predicted excitation (they are driven by the measured velocities).

QP over the horizon (Np steps, the force held over ``blocks`` equal blocks): maximise
sum_i u_i (v_i + v_i+1) / 2 Ts (v the PTO rate, linear in u through the plant) — a quadratic form,
made strictly convex by a small force penalty where the sampled model is not exactly passive — with
|u| <= max_force, |stroke| <= stroke_limit and |v| <= velocity_limit at every step of the horizon.
The Hessian and the constraint matrix do not change (built once); each step solves the QP with the new
linear term and bounds by DAQP's dual active-set method (exact at its active set; measured on the
WaveBot's 40 force blocks: p50 0.11 ms against OSQP's 0.58 ms, load 15). A QP DAQP cannot solve
(infeasible limits, cycling, iteration cap) is logged and replaced by the previous plan's next command
(then 0). The MPC maximises the mechanical power: an efficiency rule (``[optimize] efficiency``, power
fed back costs 1/eta) would make the QP non-convex, so it takes a convex stand-in for the losses, a
force penalty rho sum_i u_i^2 Ts (parameter ``force_penalty``, W/N^2), which
clients/analysis/optimal/solver.py ``loss_penalty`` tunes on the collocation model (the rho whose
optimum has the highest electrical power); the run's WECCCOMP metrics report the electrical power.

Excitation prediction: the elevation is fitted with a Fourier basis at ``omega`` (rad/s) by least
squares (ridge-regularised) — over the past ``history`` s and the preview ([[controllers]] ``preview``)
at the device probe (``predictor = "preview"``: the server's preview is exact), or over the past
``history`` s at an up-wave probe ``gauge_distance`` m up-wave (``predictor = "gauge"``, probe at
(-gauge_distance, 0), waves towards +x, deep water: each component shifted by e^{i k L}) — and the
excitation forces at the horizon's mid-steps are Re sum_m X_m A_m e^{-i w_m tau}, X_m per metre
(parameters ``excitation_re``/``excitation_im``: omega-major, then the plant's excitation inputs).

Parameters ([[controllers]] parameters): omega, excitation_re, excitation_im, horizon (s), blocks,
history (s), predictor, gauge_distance (m), stroke_limit (m), velocity_limit (m/s), gravity,
force_penalty (W/N^2, default 0).
Force limit: the controller's ``max_force``. Solve times are kept in ``self.solve_times`` (s, wall
clock) and ``self.solve_cpu_times`` (s, the thread's CPU time).
"""

from __future__ import annotations

import logging
import math
import time

import daqp
import numpy as np

from hydrolink.clients.control import Controller

log = logging.getLogger("hydrolink.mpc")
# DAQP's exit flags (https://darnstrom.github.io/daqp/parameters)
_DAQP_EXIT = {1: "solved", -1: "infeasible", -2: "cycling", -3: "unbounded", -4: "iteration limit", -5: "non-convex"}


def prediction_matrices(A, Bu, Be, n: int):
    """Stacked x_1..x_n from x_0: X = Phi x0 + Gu U + Ge E (U, E: n inputs each, step-major).
    x_{j+1} = A^{j+1} x0 + sum_{i<=j} A^{j-i} (Bu u_i + Be e_i): block-Toeplitz, each block row a slice
    of the impulse blocks [A^{n-1} B ... A B, B] (n matrix products, not n^2: a 6 s horizon at 100 Hz
    is 600 steps, set up at join within the first step's timeout)."""
    nx = A.shape[0]
    Phi = np.zeros((n * nx, nx))
    P = np.eye(nx)
    impulses = []
    for j in range(n):
        impulses.append(P)
        P = A @ P
        Phi[j * nx:(j + 1) * nx] = P
    out = [Phi]
    for B in (Bu, Be):
        k = B.shape[1]
        seq = np.hstack([impulses[i] @ B for i in range(n - 1, -1, -1)])     # [A^{n-1} B, ..., B]
        G = np.zeros((n * nx, n * k))
        for j in range(n):
            G[j * nx:(j + 1) * nx, :(j + 1) * k] = seq[:, (n - 1 - j) * k:]
        out.append(G)
    return tuple(out)


def block_rows(C: np.ndarray, X: np.ndarray) -> np.ndarray:
    """kron(I_k, C) @ X for X of k stacked blocks of C.shape[1] rows, without the Kronecker product."""
    k = X.shape[0] // C.shape[1]
    return np.einsum("ij,kjl->kil", C, X.reshape(k, C.shape[1], -1)).reshape(k * C.shape[0], -1)


class WavePredictor:
    """Excitation forces at future times from elevation samples (module docstring)."""

    def __init__(self, omega, x_per_metre, history: float, shift=None, ridge: float = 1e-6):
        self.w = np.asarray(omega, float)
        self.x = np.asarray(x_per_metre, complex)        # (n_w, n_e)
        self.history = history
        self.shift = np.ones(self.w.size, complex) if shift is None else shift   # gauge -> device
        self.ridge = ridge
        self.t, self.eta = [], []

    def add(self, t: float, eta: float) -> None:
        self.t.append(t)
        self.eta.append(eta)
        while self.t[0] < t - self.history - 1e-9:
            self.t.pop(0)
            self.eta.pop(0)

    def excitation(self, t: float, times: np.ndarray, preview_tau=None, preview_eta=None) -> np.ndarray:
        """(len(times), n_e): forces at t + times."""
        tau = np.asarray(self.t) - t
        eta = np.asarray(self.eta)
        if preview_tau is not None:
            tau, eta = np.r_[tau, preview_tau], np.r_[eta, preview_eta]
        basis = np.hstack([np.cos(np.outer(tau, self.w)), np.sin(np.outer(tau, self.w))])
        lam = self.ridge * max(float(np.trace(basis.T @ basis)) / basis.shape[1], 1e-12)
        coef = np.linalg.solve(basis.T @ basis + lam * np.eye(basis.shape[1]), basis.T @ eta)
        amp = (coef[:self.w.size] + 1j * coef[self.w.size:]) * self.shift     # eta = Re sum A e^{-i w tau}
        return np.real(np.exp(-1j * np.outer(times, self.w)) @ (amp[:, None] * self.x))


class MPC(Controller):
    plant = "continuous"     # discretised at the control period in on_start

    def on_start(self, info):
        p = info["parameters"]
        dt, self.ts = float(info["dt"]), float(info["period"])
        if abs(info["latency"] * dt - self.ts) > 1e-9 * self.ts:
            raise ValueError(f"mpc: latency x dt = {info['latency'] * dt:g} s must be one control period "
                             f"({self.ts:g} s): set the controller's latency = period / dt")
        horizon = float(p.get("horizon", 4.0))
        self.n = int(round(horizon / self.ts))
        if self.n < 2:
            raise ValueError(f"mpc: horizon {horizon:g} s is shorter than two control periods ({self.ts:g} s)")
        plant = info["plant"]
        if plant.dt is None or abs(plant.dt - self.ts) > 1e-9:
            plant = plant.discretize(self.ts)
        blocks = min(int(p.get("blocks", 40)), self.n)
        ui = [plant.inputs.index(f"pto:{name}") for name in self.ptos]
        ei = [i for i, name in enumerate(plant.inputs) if name.startswith("excitation:")]
        self.m = len(ui)
        A, Bu, Be = plant.A, plant.B[:, ui], plant.B[:, ei]
        self.A, self.Bu, self.Be = A, Bu, Be
        Cv = plant.C[[plant.outputs.index(f"pto:{name}.velocity") for name in self.ptos]]
        Cx = plant.C[[plant.outputs.index(f"pto:{name}.displacement") for name in self.ptos]]
        Phi, Gu, Ge = prediction_matrices(A, Bu, Be, self.n)
        nx = A.shape[0]
        # rates at x_0..x_n (x_0 = the state when the first command starts), then the step averages
        m = self.m

        def averaged(first, G):      # first: the rate's map at x_0; G: x_1..x_n
            r = np.vstack([first, block_rows(Cv, G)])
            return 0.5 * (r[:-m] + r[m:])

        self.v0 = averaged(Cv, Phi)
        self.vu, self.ve = averaged(np.zeros((m, Gu.shape[1])), Gu), averaged(np.zeros((m, Ge.shape[1])), Ge)
        step_of_block = np.minimum(np.arange(self.n) * blocks // self.n, blocks - 1)
        Mb = np.kron(np.eye(blocks)[step_of_block], np.eye(self.m))        # (n m, blocks m)
        self.Mb = Mb
        # - sum_i u_i v_i Ts, plus the force penalty rho sum_i u_i^2 Ts (a convex stand-in for the PTO's losses)
        H = -(self.vu + self.vu.T) * self.ts + 2 * float(p.get("force_penalty", 0.0)) * self.ts * np.eye(self.vu.shape[0])
        Hb = Mb.T @ H @ Mb
        ev = np.linalg.eigvalsh(0.5 * (Hb + Hb.T))
        reg = max(0.0, -ev.min()) + 1e-6 * abs(ev).max()
        self.Hb = 0.5 * (Hb + Hb.T) + reg * np.eye(Hb.shape[0])
        scale = float(info["limits"]["max_force"] or p.get("force_scale", 1e6))
        self.scale = scale
        rows = [np.eye(Mb.shape[1])]
        fmax = info["limits"]["max_force"]
        self.fmax = math.inf if fmax is None else float(fmax)
        X0, XU, XE = Phi, Gu, Ge
        self.limits = []
        for key, C in (("stroke_limit", Cx), ("velocity_limit", Cv)):
            if key in p:
                rows.append(block_rows(C, XU) @ Mb)
                self.limits.append((float(p[key]), block_rows(C, X0), block_rows(C, XE)))
        self.Ac = np.vstack(rows) * scale
        self.qp_H = np.ascontiguousarray(self.Hb * scale ** 2)
        self.qp_A = np.ascontiguousarray(self.Ac)
        self.qp_sense = np.zeros(self.Ac.shape[0], dtype=np.int32)
        self.pred = self._predictor(p, info, len(ei))
        self.preview_times = np.asarray(info["preview_times"], float)
        self.mech = [plant.states.index(s) for s in plant.states if not s.startswith("radiation:")]
        self.mech_names = [s for s in plant.states if not s.startswith("radiation:")]
        self.bodies = list(info["bodies"])
        self.x = np.zeros(nx)
        self.u_prev = np.zeros(self.m)
        self.plan = None
        self.solve_times: list[float] = []       # wall clock, s
        self.solve_cpu_times: list[float] = []   # this thread's CPU time, s (the cost without preemption)
        self.fallbacks = 0

    def _predictor(self, p: dict, info: dict, n_exc: int) -> WavePredictor:
        """The excitation predictor of the parameters (module docstring)."""
        omega = np.atleast_1d(np.asarray(p["omega"], float))
        x = (np.asarray(p["excitation_re"], float) + 1j * np.asarray(p["excitation_im"], float)).reshape(omega.size, n_exc)
        self.predictor_kind = p.get("predictor", "preview")
        shift = None
        if self.predictor_kind == "gauge":      # deep water: k = w^2 / g
            shift = np.exp(1j * omega ** 2 / float(p.get("gravity", 9.81)) * float(p["gauge_distance"]))
        elif not len(info["preview_times"]):
            raise ValueError('mpc: predictor = "preview" needs preview > 0 in the scene\'s [[controllers]]')
        return WavePredictor(omega, x, float(p.get("history", 2 * math.pi / omega.min())), shift)

    def _bounds(self, x1, E):
        """Constraint bounds (scaled force) for the state x1 at the first command's start."""
        lo, hi = [np.full(self.Mb.shape[1], -self.fmax)], [np.full(self.Mb.shape[1], self.fmax)]
        for bound, R0, RE in self.limits:
            free = R0 @ x1 + RE @ E
            lo.append(-bound - free)
            hi.append(bound - free)
        lo, hi = np.concatenate(lo), np.concatenate(hi)
        return np.where(np.isfinite(lo), lo, -1e30), np.where(np.isfinite(hi), hi, 1e30)

    def _measured(self, m) -> np.ndarray:
        """The mechanical states from body_position / body_velocity."""
        out = np.empty(len(self.mech))
        for j, name in enumerate(self.mech_names):
            body, dof, kind = name.rsplit(".", 2)
            arr = m["body_position"] if kind == "position" else m["body_velocity"]
            out[j] = arr[self.bodies.index(body), ("surge", "sway", "heave", "roll", "pitch", "yaw").index(dof)]
        return out

    def on_step(self, t, m):
        eta_now = float(m["wave_elevation"][0])
        self.pred.add(t, eta_now)
        self.x[self.mech] = self._measured(m)
        mids = (np.arange(self.n + 1) + 0.5) * self.ts          # e over [t_k, t_k+1], then the horizon's steps
        if self.predictor_kind == "preview":
            e = self.pred.excitation(t, mids, self.preview_times, m["wave_preview"][0])
        else:
            e = self.pred.excitation(t, mids)
        x1 = self.A @ self.x + self.Bu @ self.u_prev + self.Be @ e[0]
        E = e[1:].reshape(-1)
        free = self.v0 @ x1 + self.ve @ E
        q = self.Mb.T @ (-free * self.ts) * self.scale
        lo, hi = self._bounds(x1, E)
        t0, c0 = time.perf_counter(), time.thread_time()
        x, _, flag, _ = daqp.solve(self.qp_H, q, self.qp_A, hi, lo, self.qp_sense, iter_limit=2000)
        self.solve_times.append(time.perf_counter() - t0)
        self.solve_cpu_times.append(time.thread_time() - c0)
        status = _DAQP_EXIT.get(int(flag), f"exit flag {flag}")
        if flag == 1 and np.all(np.isfinite(x)):
            self.plan = (self.Mb @ x * self.scale).reshape(self.n, self.m)
            u = self.plan[0]
        else:
            self.fallbacks += 1
            if self.fallbacks <= 5 or self.fallbacks % 100 == 0:
                log.warning("mpc: QP not solved at t = %.3f s (%s, %d so far): the previous plan's next command",
                            t, status, self.fallbacks)
            if self.plan is not None and self.plan.shape[0] > 1:
                self.plan = self.plan[1:]
                u = self.plan[0]
            else:
                self.plan, u = None, np.zeros(self.m)
        u = np.clip(u, -self.fmax, self.fmax)
        # the estimate's next state: the command in force over [t_k, t_k+1] is u_prev
        self.x = x1
        self.u_prev = u
        return {p: float(u[i]) for i, p in enumerate(self.ptos)}
