"""`hydrolink steady`: the periodic steady state in regular waves by pseudo-spectral collocation.

Instead of time stepping to steady state, the response over one wave period T = 2 pi / w is written
as a truncated Fourier series of ``order`` N harmonics, q(t) = sum_{k=-N..N} c_k e^{i k w t}, and the
equations of motion are collocated at P = 2N + 1 equally spaced instants t_j = j T / P (the unknowns
are the nodal values q(t_j); derivatives through the Fourier differentiation matrix D, q' = D q,
q'' = D^2 q). The nonlinear terms (force/torque-limited PTOs) are evaluated pointwise at the nodes and
the algebraic system is solved with Newton (exact Jacobian, backtracking on the residual norm); with no
active limit it is linear and one Newton step solves it.

Equations (linearised about the reference configuration, coordinates q = Exudyn's ODE2 coordinates:
displacements from equilibrium, Tait-Bryan angles of every body node, point-mass positions)::

    M q'' + D q' + K q + F_mem[q] + G^T lambda = F_ex(t) + f_0 + F_pto(q, q')       G q = 0

Where each term comes from — the same sources as ``hydrolink run``:

- ``M``, ``K``, ``D``: ``mbs.ComputeLinearizedSystem`` of the system the time-domain client builds
  (:func:`hydrolink.clients.exudyn.client.build_model`, bodies at their reference configuration,
  PTOs left out): rigid-body mass matrices about the reference points, A_inf (the hydrodynamic
  ``ObjectGenericODE2`` mass matrix), hydrostatic + gravity stiffness (its stiffness matrix, from the
  server model's ``setup_info``), linear mooring connectors (stiffness and damping).
  ``tests/test_steady.py`` checks them against an independent assembly from the scene.
- Constant loads ``f_0`` (net buoyancy of wet bodies, weight/buoyancy of dry bodies and point masses,
  mooring pretension): Exudyn's ODE2 right-hand side at the reference state; their load-rotation
  (geometric) stiffness, which Exudyn's Jacobian leaves out, is added here from the scene
  (a constant global force F at a body point r: d(moment)/d(theta) = r F^T - (F.r) I).
- ``G``: the constraint Jacobian of Exudyn's algebraic equations (locked DOFs, ``[[constraints]]``,
  joints, as built and reduced by clients/exudyn/mechanism.py) at the reference configuration; rows of
  unconstrained joint axes (zero) are dropped.
- ``F_mem``: radiation memory, per harmonic k >= 1 the frequency-dependent coefficients
  ``-(A(kw) - A_inf) q'' - B(kw) q'`` from the server model (:meth:`HydroModel.radiation_coefficients`,
  the HDB interpolated in w, A_inf / 0 beyond its grid); k = 0: none (hydrostatics only).
  ``[hydro] radiation = "off"`` leaves it out, as the time-domain run does.
- ``F_ex``: the regular wave's excitation phasor from the server model
  (:meth:`HydroModel.excitation_phasors`, after the ramp).
- ``F_pto``: each PTO as a line (linear PTO: extension g^T q of point1 -> point2, linearised
  geometry) or an axis (rotary PTO: relative rotation about a frame axis), force clipped at
  ``force_limit``/``torque_limit``, generalised force -g T; this is the same spring-damper law as
  clients/exudyn/ptos.py. The test checks g g^T k, g g^T c against Exudyn's linearisation with the PTOs in.
- the server's force terms beyond the linear core that steady takes (viscous damping and drag,
  Morison elements: server/terms/base.py ``steady``), pointwise at the nodes with their own dF/dv
  or one by central differences; the others are refused (protocol/capabilities.py).

Two formulations (``[steady] formulation`` / ``--formulation``):

- ``dae``: all body coordinates plus one multiplier per constraint and node,
  [[J, G^T], [G, 0]] (J the collocated dynamics Jacobian).
- ``ode``: independent coordinates z with q = N z, N an orthonormal basis of the null space of G
  (SVD): the dynamics are projected, N^T (...) N, and the multipliers drop out.

A mode with no static stiffness (e.g. a free surge) has an undetermined mean: its mean is set to
zero; a nonzero mean force on it (a drift: constant loads, or a force term's mean such as a current's
drag) is an error. Results: one period, resampled at dt by
trigonometric interpolation, written in the layout of ``hydrolink run`` (clients/lockstep/results.py).
Not supported (refused with the reason): irregular or still waves, rope and MoorDyn moorings (catenary and
seabed contact), joint friction, controllers, FMU clients, nonzero constraint values.
"""

from __future__ import annotations

import math
import time as _time
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hydrolink.protocol.capabilities import refuse_unsupported
from hydrolink.protocol.errors import KeyedError
from hydrolink.protocol.scene import DOF_NAMES, LinearMooring, LinearPTO, MoorDynMooring, RegularWave, RopeMooring, Scene
from hydrolink.protocol.setup import Setup

TIME_DOMAIN_NOTE = "steady state by pseudo-spectral collocation (hydrolink steady)"


class SteadyError(KeyedError):
    """A scene the steady-state solver cannot solve; the message names the key and why."""

    def __init__(self, key: str, why: str):
        super().__init__("", key, why)


def check_scene(scene: Scene) -> None:
    """Refuse what the periodic linearised solver cannot represent (first problem as SteadyError)."""
    if not isinstance(scene.waves, RegularWave):
        raise SteadyError("waves.type", f"hydrolink steady needs regular waves (got {scene.waves.type!r}); "
                                        "run irregular seas with hydrolink run")
    if scene.controllers:
        raise SteadyError("controllers", "a controller's commands are not part of the periodic model")
    check_mechanism(scene)


def check_mechanism(scene: Scene) -> None:
    """Refuse what the linearised periodic model cannot represent, whatever the waves and controllers
    (``hydrolink optimize`` takes irregular seas and replaces the controllers by its own forces)."""
    if scene.client.type != "exudyn":
        raise SteadyError("client.type", "hydrolink steady builds the mechanism with the Exudyn client, "
                                         "an FMU's equations are not accessible")
    for i, m in enumerate(scene.moorings):
        if isinstance(m, RopeMooring):
            raise SteadyError(f"moorings[{i}]", "rope moorings are not supported by hydrolink steady "
                                                "(catenary and seabed contact); use a linear mooring")
        if isinstance(m, MoorDynMooring):
            raise SteadyError(f"moorings[{i}]", "MoorDyn moorings are not supported by hydrolink steady "
                                                "(lumped-mass line dynamics with seabed contact, stepped in time); "
                                                "run the scene with hydrolink run, or use a linear mooring")
    for i, j in enumerate(scene.joints):
        if j.friction is not None:
            raise SteadyError(f"joints[{i}].friction", "joint friction is not supported by hydrolink steady")
    refuse_unsupported(scene, "steady", SteadyError)
    for i, c in enumerate(scene.constraints):
        if c.value != 0.0:
            raise SteadyError(f"constraints[{i}].value", "hydrolink steady needs constraint values of 0 "
                                                         "(a prescribed velocity has no periodic state)")
    if not scene.served_bodies:
        raise SteadyError("bodies", "no wet body and no Morison element: nothing is forced by the waves")


# -- the linearised system ---------------------------------------------------------------------

@dataclass
class PTOLine:
    """A PTO entry as a line/axis in the coordinates: extension s = g.q (+ s0), T = clip(k s + c s')."""
    name: str
    g: np.ndarray
    stiffness: float
    damping: float
    preload: float          # k (L_initial - rest_length)
    limit: float            # inf: unlimited


@dataclass
class LinearizedSystem:
    """Everything the collocation needs, over the n Exudyn ODE2 coordinates (see module docstring)."""
    omega: float
    M: np.ndarray
    K: np.ndarray
    D: np.ndarray
    G: np.ndarray                    # (m, n)
    f0: np.ndarray                   # (n,)
    wet_index: np.ndarray            # (6 N_wet,) ODE2 indices of the wet bodies (server order)
    body_index: np.ndarray           # (6 B,) every scene body (results order)
    excitation: np.ndarray           # (n,) complex phasor: F_ex(t) = Re(X e^{-i w t})
    elevation: complex               # eta(t) = Re(e e^{-i w t}) at the origin
    added_mass_inf: np.ndarray       # (6N_wet)^2
    hydrostatic: np.ndarray          # (6N_wet)^2
    radiation: callable              # omega -> (A, B) over the wet DOFs (6N_wet)^2
    ptos: list[PTOLine] = field(default_factory=list)
    moorings: list[tuple[str, np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=list)
    body_names: list[str] = field(default_factory=list)
    reference: np.ndarray | None = None   # (B, 6)
    setup_seconds: float = 0.0
    memory: bool = True
    wet_names: list[str] = field(default_factory=list)
    # the server's force terms beyond the linear core (server/terms/base.py) that steady takes
    # (steady = "jacobian" / "pointwise"), evaluated pointwise at the collocation nodes on the
    # wet bodies' poses (equilibrium (N, 6) + displacement); ``term_active`` the active DOFs (6N,)
    # differences are taken in; ``term_shift`` puts the nodes past the wave ramp (the steady state
    # is periodic)
    terms: list = field(default_factory=list)
    equilibrium: np.ndarray | None = None
    term_active: np.ndarray | None = None
    term_shift: float = 0.0

    @property
    def pto_names(self) -> list[str]:
        return [p.name for p in self.ptos]

    @property
    def mooring_names(self) -> list[str]:
        return [m[0] for m in self.moorings]


def _point_jacobian(n: int, index: np.ndarray, r: np.ndarray) -> np.ndarray:
    """(6, n): displacement and rotation of a body point at r (from the node) for small motions,
    u_P = u - [r]x theta; ``index`` the body's 6 ODE2 indices (3 for a point mass)."""
    j = np.zeros((6, n))
    if index.size == 3:
        j[:3, index] = np.eye(3)
        return j
    j[:3, index[:3]] = np.eye(3)
    rx = np.array([[0, -r[2], r[1]], [r[2], 0, -r[0]], [-r[1], r[0], 0]])
    j[:3, index[3:]] = -rx
    j[3:, index[3:]] = np.eye(3)
    return j


def _load_stiffness(r: np.ndarray, f: np.ndarray) -> np.ndarray:
    """Rotational stiffness of a constant global force f at body point r: -(r f^T - (f.r) I)."""
    return -(np.outer(r, f) - float(f @ r) * np.eye(3))


def linearize(scene: Scene, model, setup: Setup, check=check_scene) -> LinearizedSystem:
    """Assemble the linearised system of ``scene`` (see the module docstring) from the Exudyn client's
    model (built as for ``hydrolink run``, PTOs left out) and the server model ``model``; ``check``
    refuses what the caller cannot represent (default: the steady solver's :func:`check_scene`)."""
    import exudyn as exu

    from hydrolink.clients.exudyn.client import build_model

    t0 = _time.perf_counter()
    check(scene)
    bodies = [b.model_copy(update={"initial_displacement": [0.0] * 6, "initial_velocity": [0.0] * 6})
              for b in scene.bodies]
    bare = scene.model_copy(update={"bodies": bodies, "ptos": []})
    ex = build_model(bare, setup, reduce=False)   # node-based indices below: the full form
    mbs = ex.mbs
    ss = exu.SimulationSettings()
    ss.solution.file.write = False
    ss.staticSolver.verboseMode = 0
    out = mbs.ComputeLinearizedSystem(ss, returnConstraintJacobian=True)   # no C without constraints
    M, K, D = (np.asarray(x, float) for x in out[:3])
    C = out[3] if len(out) > 3 else []
    n = M.shape[0]
    G = np.asarray(C, float).T if np.size(C) else np.zeros((0, n))
    G = G[np.linalg.norm(G, axis=1) > 1e-12 * max(1.0, float(np.abs(G).max(initial=0.0)))]
    solver = exu.MainSolverStatic()
    solver.InitializeSolver(mbs, ss)
    try:
        solver.ComputeODE2RHS(mbs)
        f0 = np.asarray(solver.GetSystemResidual(), float)[:n].copy()
    finally:
        solver.FinalizeSolver(mbs, ss)
    ex.finalize()
    handles = ex.mechanism.handles
    ltg = mbs.systemData.GetNodeLTGODE2

    def index_of(name: str) -> np.ndarray:
        return np.asarray(ltg(handles[name].node), int)

    for name, point, f in _constant_loads(scene):   # their geometric stiffness: Exudyn's Jacobian leaves loads out
        r = point - np.asarray(handles[name].reference, float)
        K[np.ix_(index_of(name)[3:], index_of(name)[3:])] += _load_stiffness(r, f)
    ptos = _pto_lines(scene, handles, index_of, n)
    moorings = []
    for i, m in enumerate(scene.moorings):
        from hydrolink.clients.exudyn.moorings import matrix6, mooring_label
        r = np.asarray(m.point, float) - np.asarray(handles[m.body].reference, float)
        moorings.append((mooring_label(m, i), _point_jacobian(n, index_of(m.body), r),
                         np.asarray(matrix6(m.stiffness), float), np.asarray(matrix6(m.damping), float),
                         np.asarray(m.pretension, float)))

    w, x_c, e_c = model.excitation_phasors()
    omega = float(w[0]) if w.size else math.inf     # the first wave component (none in still water)
    exc = np.zeros(n, complex)
    if w.size:
        exc[ex.wet_index] = x_c[0]
    return LinearizedSystem(
        omega=omega, M=M, K=K, D=D, G=G, f0=f0, wet_index=ex.wet_index, body_index=ex.body_index,
        excitation=exc, elevation=complex(e_c[0]) if w.size else 0j,
        added_mass_inf=setup.added_mass_inf, hydrostatic=setup.hydrostatic_stiffness,
        radiation=(convolution_radiation(model, scene) if scene.steady.radiation == "convolution"
                   else model.radiation_coefficients), ptos=ptos, moorings=moorings,
        body_names=list(ex.body_names), reference=ex.body_reference,
        setup_seconds=_time.perf_counter() - t0, memory=scene.hydro.radiation != "off",
        wet_names=list(setup.bodies), terms=list(model.terms), equilibrium=setup.equilibrium_position,
        term_active=model.active.reshape(-1),
        term_shift=(math.ceil(model.waves.ramp / (2 * math.pi / omega)) * 2 * math.pi / omega if w.size else 0.0))


def _constant_loads(scene: Scene) -> list[tuple[str, np.ndarray, np.ndarray]]:
    """(body, point, force) of the loads that keep their direction: the dry bodies' weight and
    buoyancy and the linear moorings' pretension."""
    g_, rho = scene.water.gravity, scene.water.density
    loads: list[tuple[str, np.ndarray, np.ndarray]] = []
    for b in scene.bodies:
        if not b.wet:
            loads.append((b.name, np.asarray(b.center_of_mass, float), np.array([0, 0, -b.mass * g_])))
            if b.buoyancy_volume > 0:
                cob = b.center_of_buoyancy if b.center_of_buoyancy is not None else b.center_of_mass
                loads.append((b.name, np.asarray(cob, float), np.array([0, 0, rho * g_ * b.buoyancy_volume])))
    for m in scene.moorings:
        if isinstance(m, LinearMooring) and np.any(m.pretension[:3]):
            loads.append((m.body, np.asarray(m.point, float), np.asarray(m.pretension[:3], float)))
    return loads


def _pto_lines(scene: Scene, handles, index_of, n: int) -> list[PTOLine]:
    """The scene's PTOs as lines (linear PTOs) or axes (rotary PTOs) in the n coordinates."""
    ptos: list[PTOLine] = []
    for p in scene.ptos:
        if isinstance(p, LinearPTO):
            p1 = np.asarray(p.point1, float)
            if p.direction is not None:   # to ground along a fixed axis: a line of rest length L0
                e = np.asarray(p.unit_direction, float)
                length, p2 = 1.0, p1 + e
            else:
                p2 = np.asarray(p.point2, float)
                length = float(np.linalg.norm(p2 - p1))
                e = (p2 - p1) / length
            g = np.zeros(n)
            for name, point, sign in ((p.body1, p1, -1.0), (p.body2, p2, 1.0)):
                if handles[name].kind == "ground":
                    continue
                r = point - np.asarray(handles[name].reference, float)
                g += sign * (e @ _point_jacobian(n, index_of(name), r)[:3])
            rest = length if p.rest_length is None else float(p.rest_length)
            ptos.append(PTOLine(p.name, g, float(p.stiffness), float(p.damping),
                                float(p.stiffness) * (length - rest),
                                math.inf if p.force_limit is None else float(p.force_limit)))
        else:
            from hydrolink.clients.exudyn.ptos import AXES, _per_axis, frame_matrix
            frame = frame_matrix(p.frame)
            ks, cs = _per_axis(p.stiffness, len(p.axes)), _per_axis(p.damping, len(p.axes))
            for a, k, c in zip(p.axes, ks, cs):
                axis = frame[:, AXES.index(a)]
                g = np.zeros(n)
                for name, sign in ((p.body1, -1.0), (p.body2, 1.0)):
                    if handles[name].kind != "ground":
                        g[index_of(name)[3:]] += sign * axis
                ptos.append(PTOLine(f"{p.name}.{a}", g, k, c, 0.0,
                                    math.inf if p.torque_limit is None else float(p.torque_limit)))
    return ptos


def convolution_radiation(model, scene: Scene):
    """omega -> (A, B) that the time-domain run's radiation memory realises (``[steady] radiation =
    "convolution"``): K(t) from B(w) as the server builds it (server/radiation/irf.py ``radiation_irf``, the
    default pipeline: no resampling, tail or taper), sampled at dt over irf_duration, applied with the
    trapezoid weights of server/radiation/convolution.py: for v = Re(V e^{-i w t}) the discrete sum gives
    B_eff(w) = dt sum_j w_j K(j dt) cos(w j dt), A_eff(w) = A_inf - dt sum_j w_j K(j dt) sin(w j dt) / w."""
    from hydrolink.server.radiation.irf import irf_samples, radiation_irf

    dt = float(model.dt)    # the server's step: one exchange (simulation.dt times [coupling] exchange_every)
    m = irf_samples(scene.hydro.irf_duration, dt)
    t = np.arange(m + 1) * dt
    wts = np.full(m + 1, dt)
    wts[[0, -1]] *= 0.5
    kernels = [(act, radiation_irf(om, bd, t)) for act, om, _, bd in model._coefficients if act.size]
    a_inf, n = model.added_mass_inf, model.n

    def coefficients(omega: float) -> tuple[np.ndarray, np.ndarray]:
        a, b = a_inf.copy(), np.zeros((n, n))
        if m < 1:
            return a, b
        for act, k in kernels:
            ix = np.ix_(act, act)
            a[ix] -= np.tensordot(wts * np.sin(omega * t), k, axes=(0, 0)) / omega
            b[ix] = np.tensordot(wts * np.cos(omega * t), k, axes=(0, 0))
        return a, b
    return coefficients


# -- collocation -----------------------------------------------------------------------------

def fourier_matrices(order: int, omega: float):
    """Nodes t_j = j T/P (P = 2 order + 1), the DFT E[k, j] = e^{-i k w t_j}/P (k = -N..N), its
    inverse Einv[j, k] = e^{i k w t_j}, and the real differentiation matrix D = Re(Einv ikw E)."""
    p = 2 * order + 1
    t = np.arange(p) * (2 * np.pi / omega) / p
    k = np.arange(-order, order + 1)
    E = np.exp(-1j * np.outer(k, omega * t)) / p
    Einv = np.exp(1j * np.outer(omega * t, k))
    D1 = np.real(Einv @ ((1j * k * omega)[:, None] * E))
    return t, k, E, Einv, D1


@dataclass
class SteadySolution:
    system: LinearizedSystem
    order: int
    formulation: str
    t: np.ndarray            # nodes
    q: np.ndarray            # (n, P) nodal coordinates
    lam: np.ndarray | None   # (m, P) multipliers (dae)
    iterations: int
    residual: float          # relative
    solve_seconds: float
    unknowns: int
    warnings: list[str] = field(default_factory=list)

    @property
    def omega(self) -> float:
        return self.system.omega

    def coefficients(self, values: np.ndarray) -> np.ndarray:
        """Fourier coefficients c_k (k = -N..N) of nodal values (..., P) (e^{+i k w t})."""
        _, _, E, _, _ = fourier_matrices(self.order, self.omega)
        return values @ E.T

    def at(self, values: np.ndarray, times: np.ndarray, derivative: int = 0) -> np.ndarray:
        """Trigonometric interpolation of nodal values (..., P) at ``times`` (its d-th derivative)."""
        k = np.arange(-self.order, self.order + 1)
        c = self.coefficients(values) * (1j * k * self.omega) ** derivative
        return np.real(c @ np.exp(1j * np.outer(k * self.omega, np.asarray(times, float))))

    def harmonic(self, values: np.ndarray, k: int = 1) -> np.ndarray:
        """Complex amplitude of harmonic k in the exp(-i w t) convention: x(t) ~ Re(X e^{-i k w t})."""
        c = self.coefficients(values)[..., self.order - k]   # e^{-ikwt} coefficient
        return 2 * c


def _operators(sys_: LinearizedSystem, order: int, N: np.ndarray | None):
    """Collocated linear operator L (n P)^2 over (projected) coordinates, forcing b (n P), and the
    PTO maps; with ``N`` (ode) everything is projected on the null space."""
    w = sys_.omega
    t, k, E, Einv, D1 = fourier_matrices(order, w)
    p = t.size
    eye = np.eye(p)
    P_ = (lambda a: N.T @ a @ N) if N is not None else (lambda a: a)
    M, K, D = P_(sys_.M), P_(sys_.K), P_(sys_.D)
    L = np.kron(M, D1 @ D1) + np.kron(D, D1) + np.kron(K, eye)
    n = M.shape[0]
    if sys_.memory:
        wet = sys_.wet_index
        nfull = sys_.M.shape[0]
        for kk in range(1, order + 1):
            a, b = sys_.radiation(kk * w)
            h_w = (kk * w) ** 2 * (a - sys_.added_mass_inf) - 1j * kk * w * b   # force = h c_k (e^{+ikwt})
            if not np.any(h_w):
                continue
            h = np.zeros((nfull, nfull), complex)
            h[np.ix_(wet, wet)] = h_w
            h = P_(h)
            o = np.outer(Einv[:, order + kk], E[order + kk, :])
            # memory force -F_mem enters the residual: + (-h) ... with both +-k: 2 Re
            L -= 2 * (np.kron(h.real, o.real) - np.kron(h.imag, o.imag))
    proj = (lambda v: N.T @ v) if N is not None else (lambda v: v)
    fex = np.real(np.outer(proj(sys_.excitation), np.exp(-1j * w * t)))   # (n, P)
    b = (fex + proj(sys_.f0)[:, None]).reshape(-1)
    gs = [proj(pl.g) for pl in sys_.ptos]
    return L, b, gs, D1, t, n


def _pto_forces(sys_, gs, D1, X):
    """Nodal PTO tensions (n_pto, P), extensions, rates and the unclipped mask."""
    out = []
    for pl, g in zip(sys_.ptos, gs):
        s = g @ X
        sd = g @ X @ D1.T
        f = pl.stiffness * s + pl.damping * sd + pl.preload
        free = np.abs(f) < pl.limit
        out.append((np.clip(f, -pl.limit, pl.limit), s, sd, free))
    return out


def solve(sys_: LinearizedSystem, order: int, formulation: str = "dae", *, tolerance: float = 1e-10,
          max_iterations: int = 50) -> SteadySolution:
    """Collocate and solve (see the module docstring)."""
    from scipy.linalg import null_space

    t0 = _time.perf_counter()
    warnings: list[str] = []
    n_full = sys_.M.shape[0]
    N = null_space(sys_.G) if formulation == "ode" and sys_.G.shape[0] else None
    if formulation == "ode" and N is None:
        N = np.eye(n_full)
    L, b, gs, D1, t, n = _operators(sys_, order, N)
    p = t.size
    G = sys_.G if formulation == "dae" else np.zeros((0, n))
    m = G.shape[0]
    pin = _pin_free_modes(sys_, N, m, p, warnings)
    if pin is not None:
        L = L + pin
    if m:
        A = np.block([[L, np.kron(G.T, np.eye(p))], [np.kron(G, np.eye(p)), np.zeros((m * p, m * p))]])
    else:
        A = L
    rhs = np.r_[b, np.zeros(m * p)]
    norm_b = max(float(np.linalg.norm(b)), 1e-300)

    tv = t + sys_.term_shift
    if sys_.terms:   # coordinates -> the wet bodies' 6N displacements: W (6N, n)
        W = np.zeros((sys_.wet_index.size, n_full))
        W[np.arange(sys_.wet_index.size), sys_.wet_index] = 1.0
        if N is not None:
            W = W @ N
        eq = sys_.equilibrium
        cols = np.flatnonzero(sys_.term_active)

        def term_at(term, j: int, x: np.ndarray, v: np.ndarray) -> np.ndarray:
            """The term's load (6N,) at node j: the sum of its reply fields."""
            pose, rate = eq + x.reshape(eq.shape), v.reshape(eq.shape)
            return sum(term.force(tv[j], pose, rate)).reshape(-1)

        def term_jacobian(term, j: int, x: np.ndarray, v: np.ndarray) -> np.ndarray:
            """dF/dv (6N, 6N) at node j: the term's own, or central differences over the active
            DOFs (a wetted length's dependence on x is piecewise constant: left out)."""
            if term.steady == "jacobian":
                return term.velocity_jacobian(tv[j], eq + x.reshape(eq.shape), v.reshape(eq.shape))
            jv = np.zeros((v.size, v.size))
            for c in cols:
                h = 1e-6 * max(1.0, abs(v[c]))
                dv = np.zeros(v.size)
                dv[c] = h
                jv[:, c] = (term_at(term, j, x, v + dv) - term_at(term, j, x, v - dv)) / (2 * h)
            return jv

    def residual(y):
        X = y[:n * p].reshape(n, p)
        r = A @ y - rhs
        jac = A.copy()
        for pl, g, (f, _, _, fr) in zip(sys_.ptos, gs, _pto_forces(sys_, gs, D1, X)):
            r[:n * p] += np.outer(g, f).reshape(-1)          # the PTO's generalised force is -g T
            dT = fr[:, None] * (pl.stiffness * np.eye(p) + pl.damping * D1)   # dT_j / d(g.X)_l
            jac[:n * p, :n * p] += np.kron(np.outer(g, g), dT)
        if sys_.terms:                 # pointwise at the nodes: F(t_j, x_j, v_j), a load (minus in r)
            Xw = W @ X
            Vw = Xw @ D1.T
            for term in sys_.terms:
                F = np.column_stack([term_at(term, j, Xw[:, j], Vw[:, j]) for j in range(p)])
                r[:n * p] -= (W.T @ F).reshape(-1)
                Jn = np.stack([W.T @ term_jacobian(term, j, Xw[:, j], Vw[:, j]) @ W for j in range(p)])  # (P, n, n)
                jac[:n * p, :n * p] -= np.einsum("jab,jl->ajbl", Jn, D1).reshape(n * p, n * p)
        return r, jac

    y, it, rel = _newton(residual, np.zeros(n * p + m * p), norm_b, tolerance, max_iterations)
    X = y[:n * p].reshape(n, p)
    if pin is not None and sys_.terms:   # the pin holds a free mode's mean: a mean term load on it
        held = (pin @ X.reshape(-1)).reshape(n, p).mean(axis=1)
        if np.linalg.norm(held) > 1e-6 * max(norm_b, float(np.linalg.norm(rhs))):
            names = ", ".join(t.name for t in sys_.terms)
            raise SteadyError("bodies", f"a mean load of the force terms ({names}: a current's drag, a wave drift) "
                                        "acts on a mode without stiffness: the bodies drift, there is no periodic "
                                        "steady state (moor them)")
    q = N @ X if N is not None else X
    lam = y[n * p:].reshape(m, p) if m else None
    return SteadySolution(sys_, order, formulation, t, q, lam, it, rel, _time.perf_counter() - t0,
                          y.size, warnings)


def _pin_free_modes(sys_: LinearizedSystem, N: np.ndarray | None, m: int, p: int,
                    warnings: list[str]) -> np.ndarray | None:
    """The static (mean) problem: modes without stiffness get their mean pinned to 0 by the term
    returned (to add to the collocation operator; None when every mode has stiffness); a constant
    force on such a mode is refused."""
    from scipy.linalg import null_space

    n_full = sys_.M.shape[0]
    Ns = N if N is not None else (null_space(sys_.G) if m else np.eye(n_full))
    k_static = sys_.K + sum(pl.stiffness * np.outer(pl.g, pl.g) for pl in sys_.ptos)
    kr = Ns.T @ k_static @ Ns
    scale = max(float(np.abs(kr).max(initial=0.0)), float(np.abs(Ns.T @ sys_.M @ Ns).max()) * sys_.omega ** 2)
    ev, vec = np.linalg.eigh(0.5 * (kr + kr.T))
    free = vec[:, np.abs(ev) <= 1e-9 * scale]
    if not free.shape[1]:
        return None
    zq = Ns @ free                       # free modes in the full coordinates
    zz = zq if N is None else N.T @ zq
    mean_force = zq.T @ sys_.f0
    if np.abs(mean_force).max() > 1e-9 * max(1.0, float(np.abs(sys_.f0).max())):
        raise SteadyError("bodies", f"a constant force {mean_force} acts on a mode without stiffness: "
                                    "the bodies drift, there is no periodic steady state")
    warnings.append(f"{free.shape[1]} mode(s) without static stiffness: their mean displacement is set to 0")
    return np.kron(scale * zz @ zz.T, np.full((p, p), 1.0 / p))


def _newton(residual, y: np.ndarray, norm_b: float, tolerance: float, max_iterations: int
            ) -> tuple[np.ndarray, int, float]:
    """Damped Newton on ``residual(y) -> (r, dr/dy)`` from ``y``; returns (y, iterations, relative
    residual). The residual is measured relative to the forcing: the excitation ``norm_b`` and, at
    rest, the pointwise loads (a Morison-only body has no excitation: its members' wave loads are
    all it gets). SteadyError naming steady.max_iterations when it does not converge."""
    r, jac = residual(y)
    norm_b = max(norm_b, float(np.linalg.norm(r)))
    it = 0
    rel = float(np.linalg.norm(r)) / norm_b
    while rel > tolerance and it < max_iterations:
        dy = np.linalg.solve(jac, -r)
        step, r0 = 1.0, float(np.linalg.norm(r))
        while True:
            y1 = y + step * dy
            r1, jac1 = residual(y1)
            if float(np.linalg.norm(r1)) < (1 - 1e-4 * step) * r0 or step < 1e-4:
                break
            step *= 0.5
        y, r, jac = y1, r1, jac1
        it += 1
        rel = float(np.linalg.norm(r)) / norm_b
    if rel > max(tolerance, 1e-6):
        raise SteadyError("steady.max_iterations", f"Newton did not converge in {max_iterations} iterations "
                                                   f"(relative residual {rel:.3g}); raise steady.max_iterations "
                                                   "or the order")
    return y, it, rel


# -- results -----------------------------------------------------------------------------------

def sample(sol: SteadySolution, times: np.ndarray) -> dict[str, np.ndarray]:
    """The results variables at ``times`` (the layout of ``hydrolink run``): position and velocity of
    every scene body, hydrodynamic forces (wet bodies; the radiation *memory* force, A_inf being in
    the mass matrix), wave elevation, PTO force/velocity/power, linear mooring forces."""
    s = sol.system
    w = s.omega
    times = np.asarray(times, float)
    q, v = sol.at(sol.q, times), sol.at(sol.q, times, 1)           # (n, T)
    nb = len(s.body_names)
    out: dict[str, np.ndarray] = {}
    out["position"] = s.reference[None] + q[s.body_index].T.reshape(-1, nb, 6)
    out["velocity"] = v[s.body_index].T.reshape(-1, nb, 6)
    wet_rows = [s.body_names.index(n) for n in s.body_names if n in s.wet_names]
    nw = len(wet_rows)
    exc = np.real(np.outer(np.exp(-1j * w * times), s.excitation[s.wet_index]))
    rad = np.zeros((times.size, s.wet_index.size))
    if s.memory:
        for k in range(1, sol.order + 1):
            a, b = s.radiation(k * w)
            x = sol.harmonic(sol.q[s.wet_index], k)                  # Re(X e^{-ikwt})
            f = ((k * w) ** 2 * (a - s.added_mass_inf) + 1j * k * w * b) @ x
            rad += np.real(np.outer(np.exp(-1j * k * w * times), f))
    hs = -(s.hydrostatic @ q[s.wet_index]).T
    for name, val in (("excitation_force", exc), ("radiation_force", rad), ("hydrostatic_force", hs)):
        full = np.zeros((times.size, nb, 6))
        full[:, wet_rows] = val.reshape(-1, nw, 6)
        out[name] = full
    out["wave_elevation"] = np.real(s.elevation * np.exp(-1j * w * times))
    if s.ptos:
        f, vel = np.zeros((times.size, len(s.ptos))), np.zeros((times.size, len(s.ptos)))
        for i, pl in enumerate(s.ptos):
            ext, rate = pl.g @ q, pl.g @ v
            f[:, i] = np.clip(pl.stiffness * ext + pl.damping * rate + pl.preload, -pl.limit, pl.limit)
            vel[:, i] = rate
        out["pto_force"], out["pto_velocity"], out["pto_power"] = f, vel, f * vel
        out["total_pto_power"] = (f * vel).sum(axis=1)
    if s.moorings:
        mf = np.zeros((times.size, len(s.moorings), 6))
        for i, (_, jac, k6, c6, pre) in enumerate(s.moorings):
            mf[:, i] = pre[None] - (k6 @ jac @ q).T - (c6 @ jac @ v).T
        out["mooring_force"] = mf
    return out


def write_results(path: str | Path, sol: SteadySolution, scene: Scene, scene_text: str, setup: Setup,
                  dt: float) -> int:
    """One period [0, T) sampled every ``dt`` into ``path`` (clients/lockstep/results.py's layout); returns
    the number of rows. Extra attributes: steady_order, steady_formulation, steady_iterations,
    steady_residual, steady_period, steady_solve_seconds."""
    import netCDF4

    from hydrolink.clients.exudyn.client import _add_pto_mooring_variables
    from hydrolink.clients.lockstep.results import ResultWriter

    s = sol.system
    period = 2 * np.pi / s.omega
    times = period_times(period, dt, 6 * len(s.body_names))
    data = sample(sol, times)
    with ResultWriter(path, scene=scene, scene_text=scene_text, setup=setup, dt=dt,
                      bodies=s.body_names, equilibrium_position=s.reference) as writer:
        _add_pto_mooring_variables(writer, _Names(s.pto_names) if s.ptos else None,
                                   _Names(s.mooring_names) if s.moorings else None)
        extra = [k for k in ("pto_force", "pto_velocity", "pto_power", "total_pto_power", "mooring_force")
                 if k in data]
        for i, t in enumerate(times):
            if extra:
                writer.stage_extra({k: data[k][i] for k in extra})
            writer.append(t, data["position"][i], data["velocity"][i], data["excitation_force"][i],
                          data["radiation_force"][i], data["hydrostatic_force"][i], data["wave_elevation"][i])
        writer.finish("complete")
    with netCDF4.Dataset(path, "a") as ds:
        ds.setncatts({"title": "hydrolink steady state (pseudo-spectral collocation), one period",
                      "steady_order": sol.order, "steady_formulation": sol.formulation,
                      "steady_iterations": sol.iterations, "steady_residual": sol.residual,
                      "steady_period": period, "steady_solve_seconds": sol.solve_seconds,
                      "steady_unknowns": sol.unknowns})
    return times.size


@dataclass
class _Names:
    names: list[str]


def hydro_model(scene: Scene, hdbs: dict):
    """The server's force model for the steady solve: the scene's, without the radiation memory's
    impulse response (the collocation uses A(kw), B(kw) directly, so its cost does not depend on dt
    or irf_duration), and without the compiled step (it never steps: no numba kernels to load)."""
    from hydrolink.server.model import HydroModel

    light = scene.model_copy(update={"hydro": scene.hydro.model_copy(update={"irf_duration": 0.0,
                                                                            "radiation": "convolution"})})
    return HydroModel(light, {b.name: hdbs[b.hdb] for b in scene.bodies if b.wet}, compiled=False)


def sampling_time(dt: float) -> float:
    """``dt`` (``--dt``) as the sampling of a results file or a discrete plant: a scene's time step
    (1 µs to 1 h; far below it a zero-order hold's A is I to the last bit); SteadyError naming
    ``--dt`` outside it."""
    from pydantic import TypeAdapter, ValidationError

    from hydrolink.protocol.scene_bounds import TimeStep
    try:
        return float(TypeAdapter(TimeStep).validate_python(dt))
    except ValidationError as exc:
        raise SteadyError("--dt", f"{dt!r}: the sampling time must be a time step from 1 µs to 1 h "
                                  f"({exc.errors()[0]['msg']})") from None


def period_times(period: float, dt: float, columns: int) -> np.ndarray:
    """The times of one period [0, ``period``) every ``dt`` (a results file of ``columns`` values a
    row): SteadyError naming ``--dt`` when it is longer than the period, ModelError when the rows
    would not fit in memory (allocation.require_size)."""
    from hydrolink.server.allocation import require_size

    if not dt <= period:
        raise SteadyError("--dt", f"{dt!r} s (--dt, else the scene's simulation.dt): longer than the period "
                                  f"({period:.6g} s) it samples")
    require_size("--dt", "the period's rows", (period / dt, columns), hint="a longer --dt")
    return np.arange(int(math.ceil(period / dt - 1e-9))) * dt


def steady_scene_file(scene_path: str | Path, output: str | Path | None = None, *, order: int | None = None,
                      formulation: str | None = None, dt: float | None = None, progress: bool = True,
                      hdbs: dict | None = None) -> dict:
    """``hydrolink steady``: load, linearise, solve, write; returns a summary. ``hdbs``: the scene's
    HDBs already loaded (keyed by each body's ``hdb`` string, as :func:`load_scene_hdbs` returns them)."""
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import load_scene

    scene_path = Path(scene_path)
    scene, text = load_scene(scene_path)
    check_scene(scene)
    dt = scene.simulation.dt if dt is None else sampling_time(dt)
    if hdbs is None:
        hdbs = load_scene_hdbs(scene, scene_path, progress=progress)
    wall0 = _time.perf_counter()
    model = hydro_model(scene, hdbs)
    setup = model.setup_info()
    lin = linearize(scene, model, setup)
    order = order or scene.steady.order
    formulation = formulation or scene.steady.formulation
    sol = solve(lin, order, formulation, tolerance=scene.steady.tolerance,
                max_iterations=scene.steady.max_iterations)
    output = Path(output) if output else scene_path.with_suffix(".steady.nc")
    rows = write_results(output, sol, scene, text, setup, dt)
    return {"output": str(output), "order": order, "formulation": formulation, "rows": rows,
            "iterations": sol.iterations, "residual": sol.residual, "unknowns": sol.unknowns,
            "setup_seconds": lin.setup_seconds, "solve_seconds": sol.solve_seconds,
            "wall_time": _time.perf_counter() - wall0, "warnings": list(model.warnings) + sol.warnings}
