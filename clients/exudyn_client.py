"""Exudyn multibody client: owns the mechanism, exchanges state and forces with the force server.

Model (see shared/notes/exudyn-coupling.md for the measured facts behind it):

- the mechanism (bodies wet and dry, point masses, gravity/buoyancy, joints, constraints) is built by
  :mod:`hydrolink.clients.mechanism`: one ``NodeRigidBodyRxyz`` per body at its reference point (for
  a wet body the point the HDB's rotational modes refer to); its coordinates are displacements from equilibrium (xyz + Tait-Bryan angles, angle
  rates ≈ angular velocity for small angles) and ``ObjectRigidBody`` with the body's mass, its
  centre of mass relative to the reference point and the inertia moved there (parallel axes);
- no gravity: weight and buoyancy balance at equilibrium, the restoring stiffness (with its gravity
  terms) comes from the server;
- inactive DOFs locked to ground at equilibrium with coordinate constraints — or, for a body whose
  locked DOFs need no rigid-body node (``[client] reduce``, default true), no node for them at all:
  the body is built with its active coordinates only (mechanism.py, "Reduced bodies"); the state
  vectors :meth:`ExudynModel.state` returns then end in one constant zero slot, which the locked
  DOFs' entries of ``wet_index``/``body_index`` point at;
- ONE ``ObjectGenericODE2`` over the WET bodies' nodes (mapped by name to the server's setup): ``massMatrix`` = A∞ (added mass in the system mass
  matrix, never a lagged force), ``stiffnessMatrix`` = hydrostatic stiffness (implicit) and
  ``forceVector`` = excitation + radiation memory from the server, written once per step.

Timing: implicit integrators apply loads at the end of the step, so for t_k → t_{k+1} the server is
asked for F(t_{k+1}) with the predicted state (x + h v + h²/2 a, v + h a).

Coupling schemes (scene ``[coupling]``, README "Coupling schemes", docs/stability.md):

- ``mass-matrix`` (default): as above — A∞ in the mass matrix, forces at the predicted state;
- ``explicit``: staggered — the forces of the state at t_k held over the step and A∞ NOT in the
  mass matrix but fed back as the lagged force −A∞·a_k: the classic added-mass instability (an
  acceleration error is multiplied by −M⁻¹A∞ every step). Refused when the added-mass ratio (the
  spectral radius of M⁻¹A∞ over the wet bodies' active DOFs) exceeds ``explicit_limit``;
- ``explicit-predictor``: the same lagged −A∞·a_k, the forces at t_{k+1} from the predicted state;
- ``implicit``: −A∞·a_{k+1} and the forces at the state the step ends in, iterated to
  ``tolerance`` with rollback of the Exudyn state (system state, accelerations, time) and the
  server's ``iteration`` (SPEC §5.3 rule 2), Aitken-relaxed. The integrator is then Newmark's
  trapezoidal rule (β = 1/4, γ = 1/2, index-2 constraints), whose redo is bit-exact (generalized-
  alpha's algorithmic accelerations cannot be restored);
- ``exchange_every = k``: k client steps of dt per server exchange (the server's step is k dt);
  between exchanges the forces are held or varied linearly through the last two samples.

A scene without wet bodies runs without a force server (``connection`` and ``setup`` None).
"""

from __future__ import annotations

import logging
import math
import sys
import time as _time
from dataclasses import dataclass, field

import numpy as np

import exudyn as exu
from exudyn.itemInterface import ObjectGenericODE2, VObjectGenericODE2

from hydrolink.clients.mechanism import Mechanism, body_reference, build_mechanism
from hydrolink.clients.moorings import MooringSet, build_moorings
from hydrolink.clients.ptos import PTOSet, build_ptos
from hydrolink.protocol.scene import Scene

log = logging.getLogger(__name__)

#: systems with more ODE2 coordinates than this use Exudyn's sparse linear solver (EigenSparse)
SPARSE_ABOVE = 60

#: explicit schemes: the added-mass instability is called after this many consecutive steps whose
#: second difference of the accelerations alternates in sign and grows by more than WATCH_GROWTH,
#: once it exceeds WATCH_FLOOR times the largest acceleration seen (clear of round-off)
WATCH_STEPS, WATCH_GROWTH, WATCH_FLOOR = 6, 1.001, 1e-6

#: default bound on |displacement| (m, rad) and |velocity| (m/s, rad/s) before a run is called diverged
BLOW_UP_LIMIT = 1.0e4


class RunInterrupted(RuntimeError):
    """A run stopped before its end; every row computed before ``step`` is in the results file."""

    def __init__(self, message: str, *, step: int, time: float, rows: int):
        super().__init__(message)
        self.step, self.time, self.rows = step, time, rows


class SimulationDiverged(RunInterrupted):
    """The state went non-finite or absurdly large."""


@dataclass
class ExudynModel:
    """An assembled Exudyn system driven one macro step at a time."""

    system_container: exu.SystemContainer
    mbs: exu.MainSystem
    solver: exu.MainSolverImplicitSecondOrder
    settings: exu.SimulationSettings
    hydro_object: int                # -1 when no body is wet
    equilibrium: np.ndarray          # (N, 6): wet bodies' reference point xyz + zero angles
    active: np.ndarray               # (N, 6) bool, wet bodies
    stiffness: np.ndarray            # (6N, 6N)
    dt: float
    mechanism: Mechanism | None = None
    wet_index: np.ndarray = field(default_factory=lambda: np.zeros(0, int))   # (6N,) ODE2 indices
    body_names: list[str] = field(default_factory=list)    # every scene body (results order)
    body_reference: np.ndarray = field(default_factory=lambda: np.zeros((0, 6)))  # (B, 6)
    body_index: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # (6B,) ODE2 indices
    wet_rows: np.ndarray = field(default_factory=lambda: np.zeros(0, int))    # wet bodies' rows in B
    ptos: PTOSet | None = None
    moorings: MooringSet | None = None
    initialized: bool = field(default=False)
    added_mass: np.ndarray = field(default_factory=lambda: np.zeros((0, 0)))  # (6N, 6N) A∞ (setup)
    added_mass_in_matrix: bool = True
    failure_hint: str = ""          # appended to a solver failure's message (what to change)
    force_index: np.ndarray | None = None   # reduced bodies: the 6N entries the hydro object takes
    padded: bool = False            # reduced bodies: state vectors end in a zero slot (locked DOFs)

    @property
    def n_bodies(self) -> int:
        """Number of wet bodies (the server's bodies)."""
        return self.equilibrium.shape[0]

    def set_force(self, force: np.ndarray) -> None:
        """Write all wet bodies' hydrodynamic forces (6N) into the GenericODE2 in one call."""
        if int(self.hydro_object) >= 0:
            self.mbs.SetObjectParameter(self.hydro_object, "forceVector",
                                        force if self.force_index is None else force[self.force_index])

    def initialize(self) -> None:
        """Initialise the solver (initial accelerations use the force vector set now)."""
        self.solver.InitializeSolver(self.mbs, self.settings)
        self.initialized = True

    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Displacements, velocities and accelerations of all system ODE2 coordinates (wet bodies'
        6N: ``wet_index``; every scene body: ``body_index``), with reduced bodies followed by one
        zero slot (their locked DOFs)."""
        sd = self.mbs.systemData
        q, v, a = sd.GetODE2Coordinates(), sd.GetODE2Coordinates_t(), sd.GetODE2Coordinates_tt()
        if self.padded:
            return np.append(q, 0.0), np.append(v, 0.0), np.append(a, 0.0)
        return np.asarray(q), np.asarray(v), np.asarray(a)

    def advance(self, t0: float, t1: float) -> None:
        """Integrate one step t0 → t1 with the force vector currently set."""
        it = self.solver.it
        it.startTime, it.endTime = t0, t1
        if not self.solver.SolveSteps(self.mbs, self.settings):
            raise RuntimeError(f"Exudyn solver failed on the step {t0:g} s -> {t1:g} s: "
                               f"{self.solver.GetErrorString()}{self.failure_hint}")

    def save(self) -> tuple:
        """The whole solver state at the current time (for a rollback with :meth:`restore`)."""
        sd = self.mbs.systemData
        return sd.GetSystemState(), np.array(sd.GetODE2Coordinates_tt()), sd.GetTime()

    def restore(self, saved: tuple) -> None:
        """Roll back to a :meth:`save`: state, accelerations, time and the solver's current time
        (a redo is then bit-exact with the Newmark/trapezoidal integrator)."""
        sd = self.mbs.systemData
        state, acc, t = saved
        sd.SetSystemState(state)
        sd.SetODE2Coordinates_tt(acc)
        sd.SetTime(t)
        self.solver.it.currentTime = t

    def mass_matrix(self) -> np.ndarray:
        """The system mass matrix over the body coordinates (6N × 6N), as the solver sees it (a
        reduced body's locked DOFs: zero rows and columns)."""
        if not self.initialized:
            self.initialize()
        self.solver.ComputeMassMatrix(self.mbs)
        i = self.wet_index
        m = np.asarray(self.solver.GetSystemMassMatrix())
        return (np.pad(m, (0, 1)) if self.padded else m)[np.ix_(i, i)]

    def finalize(self) -> None:
        if self.initialized:
            self.solver.FinalizeSolver(self.mbs, self.settings)
            self.initialized = False


def _scene_bodies(scene: Scene, names: list[str]):
    by_name = {b.name: b for b in scene.bodies}
    missing = [n for n in names if n not in by_name]
    if missing:
        raise ValueError(f"server setup names bodies {missing} that are not in the scene "
                         f"({list(by_name)})")
    return [by_name[n] for n in names]


def result_bodies(scene: Scene, setup: dict | None) -> tuple[list[str], np.ndarray]:
    """Every scene body's name and reference position (N, 6): wet bodies' from the server's setup
    (by name), dry bodies' from the scene (``reference_point``, default the centre of mass)."""
    wet = {}
    if setup:
        eq = np.asarray(setup["equilibrium_position"], float).reshape(-1, 6)
        wet = {str(n): eq[i] for i, n in enumerate(setup["bodies"])}
    ref = [wet[b.name] if b.name in wet else np.r_[body_reference(b), 0.0, 0.0, 0.0] for b in scene.bodies]
    return [b.name for b in scene.bodies], np.asarray(ref, float).reshape(len(ref), 6)


def _body_indices(mech: Mechanism, names: list[str], ltg, pad: int) -> np.ndarray:
    """(6 len(names),) ODE2 indices of the named bodies' six DOFs; a reduced body's locked DOFs
    point at ``pad`` (the zero slot after the ODE2 coordinates)."""
    out = np.full(6 * len(names), pad, int)
    for i, nm in enumerate(names):
        h = mech.handles[nm]
        out[6 * i + np.asarray(h.dofs if h.dofs is not None else range(6), int)] = ltg(h.node)
    return out


def build_model(scene: Scene, setup: dict | None, *, spectral_radius: float = 1.0,
                added_mass_in_matrix: bool = True, newmark: bool = False,
                reduce: bool | None = None) -> ExudynModel:
    """Build the Exudyn system from the scene (bodies, point masses, joints, constraints, initial
    state) and the server's setup (wet bodies by name, active DOFs, A∞, hydrostatic stiffness,
    equilibrium, net buoyancy, dt); ``setup`` None when no body is wet.

    ``spectral_radius`` of the generalized-alpha integrator: 1 (default) is the energy-conserving
    trapezoidal rule — no numerical damping of the lightly damped wave-body modes.
    ``added_mass_in_matrix`` False leaves A∞ out of the mass matrix (the explicit and implicit
    coupling schemes feed it back as a force); ``newmark`` uses Newmark's trapezoidal rule
    (bit-exact rollback, for the implicit scheme) instead of generalized-alpha. ``reduce`` (default:
    the scene's ``[client] reduce``) builds the bodies that qualify with their active coordinates
    only (clients/mechanism.py, "Reduced bodies"); False is the full form."""
    setup = setup or {}
    names = [str(b) for b in setup.get("bodies", [])]
    n = len(names)
    wet_scene = [b.name for b in scene.bodies if b.wet]
    if sorted(names) != sorted(wet_scene):
        raise ValueError(f"server setup names bodies {names}, the scene's wet bodies are {wet_scene}")
    _scene_bodies(scene, names)
    equilibrium = np.asarray(setup.get("equilibrium_position", np.zeros((0, 6))), float).reshape(n, 6)
    active = np.asarray(setup.get("active", np.zeros((0, 6))), bool).reshape(n, 6)
    # "added_mass": what goes into the mass matrix (A_inf, or A(w0) with hydro.radiation = "constant")
    a_inf = np.asarray(setup.get("added_mass", setup.get("added_mass_inf", np.zeros((0, 0)))), float).reshape(6 * n, 6 * n)
    stiffness = np.asarray(setup.get("hydrostatic_stiffness", np.zeros((0, 0))), float).reshape(6 * n, 6 * n)
    dt = float(scene.simulation.dt)   # the client's step (the server's is [coupling] exchange_every times it)
    net = {nm: float(v) for nm, v in zip(names, setup.get("net_buoyancy") or [None] * n) if v}

    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    if reduce is None:
        reduce = bool(getattr(scene.client, "reduce", True))
    mech = build_mechanism(mbs, scene, {nm: equilibrium[i, :3] for i, nm in enumerate(names)}, net,
                           reduce=reduce)
    ptos = build_ptos(mbs, scene.ptos, mech.handles) if scene.ptos else None
    moorings = build_moorings(mbs, scene.moorings, mech.handles, scene.water) if scene.moorings else None
    padded = any(h.dofs is not None for h in mech.handles.values())
    # the hydro object's coordinates: each wet body's node coordinates (a reduced body's active DOFs)
    sel = np.concatenate([6 * i + np.asarray(mech.handles[nm].dofs or range(6), int) for i, nm in enumerate(names)]
                         ) if n else np.zeros(0, int)
    hydro = -1
    if n:
        ix = np.ix_(sel, sel)
        hydro = mbs.AddObject(ObjectGenericODE2(
            name="hydrodynamics", nodeNumbers=mech.rigid_nodes(names),
            massMatrix=a_inf[ix] if added_mass_in_matrix else np.zeros((sel.size, sel.size)),
            stiffnessMatrix=stiffness[ix], forceVector=np.zeros(sel.size),
            visualization=VObjectGenericODE2(show=False)))
    mbs.Assemble()
    ltg = mbs.systemData.GetNodeLTGODE2
    pad = len(mbs.systemData.GetODE2Coordinates())
    all_names, reference = result_bodies(scene, setup)
    body_index = _body_indices(mech, all_names, ltg, pad)
    wet_index = _body_indices(mech, names, ltg, pad)

    ss = exu.SimulationSettings()
    ss.solution.file.write = False
    ss.solution.sensors.active = False
    ss.timeIntegration.verboseMode = 0
    ss.timeIntegration.adaptiveStep = False
    ss.timeIntegration.numberOfSteps = 1
    ss.timeIntegration.endTime = dt
    ss.timeIntegration.generalizedAlpha.spectralRadius = float(spectral_radius)
    if newmark:   # trapezoidal rule as Newmark (beta 1/4, gamma 1/2): a rollback + redo is bit-exact
        ga = ss.timeIntegration.generalizedAlpha
        ga.useNewmark, ga.newmarkBeta, ga.newmarkGamma, ga.useIndex2Constraints = True, 0.25, 0.5, True
    if len(mbs.systemData.GetODE2Coordinates()) > SPARSE_ABOVE:
        # large mechanisms (arrays of bodies + arms): Exudyn's default dense LU dominates the step;
        # measured on 9N9LA (108 body coordinates + 54 constraints): 9.8 -> 2.3 ms per step
        ss.linearSolver.solverType = exu.LinearSolverType.EigenSparse
    return ExudynModel(sc, mbs, exu.MainSolverImplicitSecondOrder(), ss, hydro, equilibrium,
                       active, stiffness, dt, mech, wet_index, all_names, reference, body_index,
                       np.array([all_names.index(nm) for nm in names], int), ptos, moorings,
                       added_mass=a_inf, added_mass_in_matrix=added_mass_in_matrix,
                       force_index=sel if sel.size < 6 * n else None, padded=padded)


def _check_state(q: np.ndarray, v: np.ndarray, step: int, t: float, limit: float, rows: int,
                 where: str) -> None:
    """Raise SimulationDiverged if the state is non-finite or beyond ``limit`` (NaN fails ``<``)."""
    if float(q @ q) + float(v @ v) < limit * limit:
        return  # cheap sufficient test (each |x| <= the 2-norm); the exact max-norm test follows
    big = max(float(np.abs(q).max(initial=0.0)), float(np.abs(v).max(initial=0.0)))
    if big < limit:
        return
    bad = "absurdly large" if np.isfinite(big) else "non-finite"
    raise SimulationDiverged(
        f"simulation diverged at step {step} (t = {t:.6g} s): {where} is {bad} "
        f"(max |x| = {np.nanmax(np.abs(q)):.3g}, max |v| = {np.nanmax(np.abs(v)):.3g}, limit {limit:g}); "
        f"the {rows} rows before it are saved. Try a smaller dt or check the scene's "
        f"masses, stiffness and DOFs", step=step, time=t, rows=rows)


def _forces(reply: dict, n: int, step: int, t: float) -> tuple[np.ndarray, np.ndarray, float]:
    """Excitation and radiation (N, 6) and the wave elevation from a step reply, checked finite.

    The reply's hydrostatic force is not used: the stiffness is applied implicitly by Exudyn."""
    exc = np.asarray(reply["excitation"], float).reshape(n, 6)
    rad = np.asarray(reply["radiation"], float).reshape(n, 6)
    eta = reply["wave_elevation"]
    eta = eta if type(eta) is float else float(np.asarray(eta, float).reshape(-1)[0])
    if not math.isfinite(float(exc.sum() + rad.sum()) + eta):
        raise SimulationDiverged(
            f"the force server returned non-finite forces at step {step} (t = {t:.6g} s); "
            f"the {step} rows before it are saved", step=step, time=t, rows=step)
    return exc, rad, eta


JOINT_COMPONENTS = ("fx", "fy", "fz", "mx", "my", "mz")


def _add_joint_variables(writer, labels: list[str]) -> None:
    """Declare the joint outputs in the results file (dims ``joint``, ``joint_component``)."""
    coords = {"joint": labels, "joint_component": list(JOINT_COMPONENTS)}
    writer.add_variable("joint_force", ("joint", "joint_component"), coords, "N (fx, fy, fz); N m (mx, my, mz)",
                        "joint reaction force and moment on body2 from body1 at the joint point, global frame")
    writer.add_variable("joint_violation", ("joint",), coords, "m",
                        "position-level joint violation: norm of the constrained relative translation")
    writer.add_variable("joint_rotation_violation", ("joint",), coords, "rad",
                        "norm of the constrained relative rotation angles")


def _add_pto_mooring_variables(writer, ptos: PTOSet | None, moorings: MooringSet | None) -> None:
    """Declare the PTO outputs (dim ``pto``) and mooring forces (dims ``mooring``, ``mooring_component``)."""
    if ptos is not None:
        coords = {"pto": list(ptos.names)}
        writer.add_variable("pto_force", ("pto",), coords, "N (linear); N m (rotary axis)",
                            "force on body1 along the line point1 -> point2 (tension > 0) / torque on "
                            "body1 about the PTO axis")
        writer.add_variable("pto_velocity", ("pto",), coords, "m/s (linear); rad/s (rotary axis)",
                            "extension rate of the line / angular velocity of body2 relative to body1")
        writer.add_variable("pto_power", ("pto",), coords, "W",
                            "absorbed power pto_force * pto_velocity (> 0: into the PTO)")
        writer.add_variable("total_pto_power", (), None, "W", "sum of pto_power over all PTOs")
    if moorings is not None:
        writer.add_variable("mooring_force", ("mooring", "mooring_component"),
                            {"mooring": list(moorings.names), "mooring_component": list(JOINT_COMPONENTS)},
                            "N (fx, fy, fz); N m (mx, my, mz)",
                            "force and moment the mooring exerts on its body, global frame, about the "
                            "mooring point (linear) / the attachment point (rope)")


def _progress_bar(total: int, enabled: bool):
    from tqdm import tqdm
    return tqdm(total=total, unit="step", desc="hydrolink run", mininterval=0.5,
                disable=not (enabled and sys.stderr.isatty()))


class CouplingError(RunInterrupted):
    """The implicit coupling did not converge within ``coupling.max_iterations``."""


def wet_rigid_mass(scene: Scene, setup: dict) -> np.ndarray:
    """Rigid-body mass matrix (6N × 6N) of the wet bodies about their reference points (dry bodies
    attached by joints are left out, which can only overstate the added-mass ratio)."""
    from hydrolink.clients.coupling import rigid_body_mass_matrix
    names = [str(b) for b in setup["bodies"]]
    eq = np.asarray(setup["equilibrium_position"], float).reshape(len(names), 6)
    m = np.zeros((6 * len(names), 6 * len(names)))
    for i, b in enumerate(_scene_bodies(scene, names)):
        m[6 * i:6 * i + 6, 6 * i:6 * i + 6] = rigid_body_mass_matrix(
            b.mass, b.inertia_matrix, np.asarray(b.center_of_mass, float) - eq[i, :3])
    return m


def coupling_ratio(scene: Scene, setup: dict | None) -> float:
    """The added-mass ratio of the explicit schemes: spectral radius of M⁻¹A∞ over the wet bodies'
    active DOFs (M the rigid-body mass matrix). An explicitly fed-back −A∞·a multiplies an
    acceleration error by −M⁻¹A∞ every step: unstable above 1."""
    from hydrolink.clients.coupling import added_mass_ratio
    if not setup or not setup.get("bodies"):
        return 0.0
    n = len(setup["bodies"])
    act = np.flatnonzero(np.asarray(setup["active"], bool).reshape(6 * n))
    a = np.asarray(setup.get("added_mass", setup["added_mass_inf"]), float).reshape(6 * n, 6 * n)
    return added_mass_ratio(wet_rigid_mass(scene, setup)[np.ix_(act, act)], a[np.ix_(act, act)])


#: period stretch of the trapezoidal rule (of the wave period at the exchange step) above which a run
#: is refused / warned: 10 % is dt > T/5.6 (T/5 is refused), 1 % is dt > T/18
DT_REFUSE, DT_WARN = 0.10, 0.01


def wave_resolution(scene: Scene, step: float) -> tuple[str, str] | None:
    """("refuse" | "warn", why) when ``step`` (the exchange step, exchange_every × dt) resolves the
    wave period (regular) or peak period (irregular) too coarsely: the trapezoidal rule stretches
    a period T by ωh / (2 atan(ωh/2)) − 1 (12 % at T/5, 3.2 % at T/10, 0.8 % at T/20)."""
    w = scene.waves
    kind = getattr(w, "type", "still")
    if kind not in ("regular", "irregular"):
        return None
    period, what = (w.period, "waves.period") if kind == "regular" else (w.tp, "waves.tp")
    wh = 2 * math.pi * step / period
    stretch = wh / (2 * math.atan(wh / 2)) - 1
    if stretch <= DT_WARN:
        return None
    kx = scene.coupling.exchange_every
    what_step = f"{step:g} s" + (f" (coupling.exchange_every = {kx} × dt)" if kx > 1 else "")
    why = (f"a step of {what_step} resolves {what} = {period:g} s with {period / step:.3g} steps: the "
           f"trapezoidal rule stretches that period by {100 * stretch:.2g} %; use simulation.dt <= "
           f"{period / 20 / kx:.3g} s (T/20: < 1 %)")
    if stretch > DT_REFUSE:
        return "refuse", f"{why} — refused above {100 * DT_REFUSE:g} %"
    return "warn", why


#: PTO/mooring stiffness (N/m) above which a solver failure names the stiffness (docs/stability.md)
STIFF_NOTE = 1e7


def _stiffest(scene: Scene) -> tuple[float, str] | None:
    """The largest PTO or linear-mooring stiffness entry and its scene key."""
    found = []
    for i, p in enumerate(scene.ptos):
        found.append((float(np.max(p.stiffness)), f"ptos[{i}].stiffness"))
    for i, m in enumerate(scene.moorings):
        k = getattr(m, "stiffness", None)
        if k is not None and getattr(m, "type", "") == "linear":
            found.append((float(np.abs(np.asarray(k, float)).max()), f"moorings[{i}].stiffness"))
    return max(found) if found else None


def explicit_refusal(scheme: str, ratio: float, limit: float) -> str:
    return (f"coupling.scheme = \"{scheme}\" feeds A∞ back as the lagged force −A∞·a: explicit added-mass "
            f"coupling is unstable for A∞/m > 1, and this scene's added-mass ratio (spectral radius of "
            f"M⁻¹A∞) is {ratio:.3g} > coupling.explicit_limit = {limit:g}: use coupling.scheme = "
            f"\"mass-matrix\" (A∞ in the mass matrix, the default) or \"implicit\"")


def run(scene: Scene, scene_text: str, connection, setup: dict | None, writer, *, progress: bool = True,
        spectral_radius: float | None = None, blow_up_limit: float = BLOW_UP_LIMIT,
        allow_unstable: bool = False) -> dict:
    """Run the lockstep co-simulation to ``scene.simulation.duration``.

    ``connection`` has already said hello (``setup`` is its reply); it is not closed here. With no
    wet body both are None and no server is asked. Rows hold every scene body (hydrodynamic forces
    zero for dry bodies) and, with joints, the joint outputs (see :mod:`hydrolink.clients.results`).
    Every step is written to ``writer`` (a :class:`~hydrolink.clients.results.ResultWriter`),
    which gets its final status ("complete" / "interrupted: ...") before this returns or raises.
    On Ctrl-C or a server error the rows computed so far are flushed and the error re-raised with
    the step and time named (KeyboardInterrupt stays a KeyboardInterrupt, server errors become
    :class:`RunInterrupted`, a blow-up :class:`SimulationDiverged`, a non-converged implicit step
    :class:`CouplingError`).

    The scene's ``[coupling]`` picks the scheme (module docstring); an explicit scheme above
    ``coupling.explicit_limit`` is refused (SceneError naming coupling.scheme) unless
    ``allow_unstable`` (only to demonstrate the added-mass instability).

    Returns a summary: steps, time, wall_time, rows, status, ``coupling`` (scheme, exchange_every,
    added-mass ratio, iterations per exchange: mean/max, and the list for "implicit"),
    ``warnings`` (the server's setup warnings) and per-step costs in µs (``client_us_per_step``
    excludes the server round trips, ``round_trip_us_per_step`` is them)."""
    from hydrolink.clients.coupling import Aitken
    from hydrolink.protocol.scene import SceneError

    cpl = scene.coupling
    scheme, kx, between = cpl.scheme, int(cpl.exchange_every), cpl.between_exchanges
    feedback = scheme != "mass-matrix"
    if spectral_radius is None:
        spectral_radius = scene.simulation.spectral_radius
    warnings = [str(w) for w in (setup or {}).get("warnings", [])]
    for note in warnings:
        log.warning("%s", note)
    ratio = coupling_ratio(scene, setup) if feedback else 0.0
    if scheme in ("explicit", "explicit-predictor") and ratio > cpl.explicit_limit and not allow_unstable:
        why = explicit_refusal(scheme, ratio, cpl.explicit_limit)
        writer.finish(f"refused: {why}")
        raise SceneError("scene", "coupling.scheme", why)
    if scheme == "implicit" and spectral_radius != 1.0:
        warnings.append(f"simulation.spectral_radius = {spectral_radius:g} is not used by coupling.scheme = "
                        "\"implicit\" (Newmark's trapezoidal rule: bit-exact rollback)")
    model = build_model(scene, setup, spectral_radius=spectral_radius, added_mass_in_matrix=not feedback,
                        newmark=scheme == "implicit")
    stiff = _stiffest(scene)
    if stiff and stiff[0] > STIFF_NOTE:
        model.failure_hint = (f"; the stiffest spring is {stiff[1]} = {stiff[0]:.3g} N/m (N m/rad): above "
                              f"~{STIFF_NOTE:.0e} Exudyn's Newton iteration can stall (measured: 1e9 N/m on "
                              f"a 2.6e5 kg body at dt = 0.01 s); lower it (a joint or constraint models a "
                              f"rigid link) or simulation.dt")
    n, h = model.n_bodies, model.dt
    big_h = kx * h                                    # the server's step
    if setup and abs(float(setup.get("dt", big_h)) - big_h) > 1e-9 * big_h:
        raise ValueError(f"the server's step {setup['dt']} s is not coupling.exchange_every × simulation.dt "
                         f"= {big_h} s")
    n_steps = int(round(scene.simulation.duration / h))
    n_ex = n_steps // kx
    note = wave_resolution(scene, big_h)
    if note and note[0] == "refuse":
        writer.finish(f"refused: {note[1]}")
        raise SceneError("scene", "simulation.dt", note[1])
    if note:
        warnings.append(f"simulation.dt: {note[1]}")
        log.warning("simulation.dt: %s", note[1])
    eq = model.equilibrium.reshape(-1)
    stiffness = model.stiffness
    a_fb = model.added_mass
    wet, bodies, ref = model.wet_index, model.body_index, model.body_reference
    nb, rows = len(model.body_names), model.wet_rows
    mech = model.mechanism
    for note in (mech.warnings + mech.reductions) if mech else []:
        log.warning("%s", note)
    joints = bool(mech and mech.joints)
    if joints:
        _add_joint_variables(writer, mech.joint_labels)
    ptos, moorings = model.ptos, model.moorings
    _add_pto_mooring_variables(writer, ptos, moorings)
    control = None
    if scene.controllers:
        if n == 0:
            raise ValueError("controllers: a scene with controllers needs a wet body (the controllers "
                             "talk to the multibody client through the force server's session)")
        from hydrolink.clients.pto_control import PTOControl
        control = PTOControl(scene, ptos, model.mbs, writer)
    last = {"sample": None, "decisions": None}
    zeros = np.zeros((0, 6))
    wall0 = _time.perf_counter()
    t_server = 0.0
    step, t = 0, 0.0
    iterations: list[int] = []
    init_iterations = 0
    bar = _progress_bar(n_steps, progress and scene.simulation.progress)

    def request(k: int, tk: float, q: np.ndarray, v: np.ndarray, measurements: dict | None = None,
                timeout: float | None = None, iteration: int = 0) -> tuple:
        nonlocal t_server
        if n == 0:
            return zeros, zeros, 0.0
        t0 = _time.perf_counter()
        try:
            reply = connection.step(k, tk, (eq + q).reshape(n, 6), v.reshape(n, 6),
                                    measurements=measurements, timeout=timeout) if control else \
                connection.step(k, tk, (eq + q).reshape(n, 6), v.reshape(n, 6), iteration)
            last["decisions"] = reply.get("control")
        except (KeyboardInterrupt, SimulationDiverged):
            raise
        except Exception as exc:
            raise RunInterrupted(
                f"force server error at step {k} (t = {tk:.6g} s): {exc}; the {done[0]} rows before "
                f"it are saved in {getattr(writer, 'path', 'the results file')}",
                step=k * kx, time=tk, rows=done[0]) from exc
        t_server += _time.perf_counter() - t0
        return _forces(reply, n, k, tk)

    force_rows = np.zeros((3, nb, 6))
    done = [0]    # rows written

    def outputs() -> dict:
        """The mechanism's outputs at the current Exudyn state (joints, PTOs, moorings)."""
        out = {}
        if joints:
            f, m, gap, rot = mech.joint_outputs(model.mbs)
            out.update({"joint_force": np.hstack([f, m]), "joint_violation": gap,
                        "joint_rotation_violation": rot})
        if ptos is not None:
            s = last["sample"] = ptos.sample(model.mbs)
            out.update({"pto_force": s.force, "pto_velocity": s.velocity, "pto_power": s.power,
                        "total_pto_power": s.total_power})
        if moorings is not None:
            out["mooring_force"] = moorings.sample(model.mbs)
        return out

    def write(tk: float, q: np.ndarray, v: np.ndarray, exc_f, rad_f, eta, extra: dict | None = None) -> None:
        force_rows[0, rows], force_rows[1, rows] = exc_f, rad_f
        force_rows[2, rows] = -(stiffness @ q[wet]).reshape(n, 6)
        if control is not None:
            control.stage()
        extra = outputs() if extra is None else extra
        if extra:
            writer.stage_extra(extra)
        writer.append(tk, ref + q[bodies].reshape(nb, 6), v[bodies].reshape(nb, 6),
                      force_rows[0], force_rows[1], force_rows[2], eta)
        done[0] += 1

    def between_samples(s0: tuple, s1: tuple, j: int, extrapolate: bool) -> tuple:
        """The forces at client step j (1..kx) of an exchange interval: s1 held, or linear from s0 to
        s1 (s0 at the interval's start and s1 at its end), or on past it (``extrapolate``: s0 and s1
        one exchange apart, both in the past)."""
        if between == "hold" or kx == 1:
            return s1
        w = 1.0 + j / kx if extrapolate else j / kx
        return tuple(a + w * (b - a) for a, b in zip(s0, s1))

    watch = {"a": [], "run": 0, "top": 0.0}

    def added_mass_watch(aw: np.ndarray, k: int, tk: float) -> None:
        """Explicit schemes: stop at the signature of the added-mass instability — the second
        difference of the fed-back accelerations alternates in sign and grows every step (a lag
        error multiplied by −M⁻¹A∞ each step; physical motion cannot alternate step by step)."""
        hist = watch["a"]
        hist.append(aw.copy())
        watch["top"] = max(watch["top"], float(np.abs(aw).max(initial=0.0)))
        if len(hist) < 4:
            return
        d1, d2 = hist[2] - 2 * hist[1] + hist[0], hist[3] - 2 * hist[2] + hist[1]
        del hist[0]
        n1, n2 = float(np.abs(d1).max(initial=0.0)), float(np.abs(d2).max(initial=0.0))
        if float(d1 @ d2) < 0 and n2 > WATCH_GROWTH * n1 and n2 > WATCH_FLOOR * watch["top"]:
            watch["run"] += 1
        else:
            watch["run"] = 0
        if watch["run"] >= WATCH_STEPS:
            raise SimulationDiverged(
                f"stopped at step {k} (t = {tk:.6g} s): the accelerations fed back as −A∞·a alternate in "
                f"sign and grow every step ({WATCH_STEPS} steps in a row, x{n2 / n1:.3g} in the last): the "
                f"added-mass instability; the {k} rows before it are saved", step=k, time=tk, rows=k)

    def total(sample: tuple) -> np.ndarray:
        return (sample[0] + sample[1]).reshape(-1)

    def check(q, v, k, tk, where="the body state"):
        _check_state(q, v, k, tk, blow_up_limit, k, where)

    def consistent_start(f0: np.ndarray) -> int:
        """A∞ fed back: initial accelerations with −A∞·a0 consistent (Aitken-relaxed fixed point)."""
        aitken = Aitken(1.0 / (1.0 + ratio))
        u = f0.copy()
        for it in range(cpl.max_iterations):
            model.set_force(u)
            model.initialize()
            g = f0 - a_fb @ model.state()[2][wet]
            scale = max(float(np.abs(g).max(initial=0.0)), float(np.abs(f0).max(initial=0.0)), 1e-300)
            if not np.isfinite(g).all() or float(np.abs(g - u).max(initial=0.0)) <= cpl.tolerance * scale:
                return it + 1
            model.finalize()
            u = aitken.update(u, g)
        model.set_force(u)
        model.initialize()
        return cpl.max_iterations

    try:
        q, v, _ = model.state()
        _check_state(q, v, 0, 0.0, blow_up_limit, 0, "the initial state")
        s_prev = request(0, 0.0, q[wet], v[wet], timeout=(
            control.join_timeout + getattr(connection, "timeout", 30.0)) if control else None)
        if feedback and n:
            init_iterations = consistent_start(total(s_prev))
        else:
            model.set_force(total(s_prev))
            model.initialize()
        q, v, a = model.state()  # initial accelerations from F(0)
        write(0.0, q, v, *s_prev)
        s_old = s_prev                       # the sample one exchange before s_prev (explicit)
        u_hist: list[np.ndarray] = []        # implicit: converged interface loads (kx, 6N)
        aitken = Aitken(1.0 / (1.0 + ratio))
        scale = 1e-300
        for e in range(n_ex):
            t_e = e * big_h
            if scheme in ("mass-matrix", "explicit-predictor"):
                qw, vw, aw = q[wet], v[wet], a[wet]
                meas = None
                if control is not None and control.is_sample(step):
                    meas = control.measurements(step, q[bodies].reshape(nb, 6), v[bodies].reshape(nb, 6),
                                                last["sample"])
                s_new = request(e + 1, (e + 1) * big_h, qw + big_h * vw + 0.5 * big_h * big_h * aw,
                                vw + big_h * aw, meas)
                if control is not None:
                    control.apply(last["decisions"])
                for j in range(1, kx + 1):
                    step, t_prev, t = e * kx + j, t_e + (j - 1) * h, t_e + j * h
                    s_j = between_samples(s_prev, s_new, j, False)
                    model.set_force(total(s_j) - a_fb @ a[wet] if feedback else total(s_j))
                    model.advance(t_prev, t)
                    q, v, a = model.state()
                    check(q, v, step, t)
                    if feedback:
                        added_mass_watch(a[wet], step, t)
                    write(t, q, v, *s_j)
                    bar.update(1)
                s_prev = s_new
            elif scheme == "explicit":
                for j in range(1, kx + 1):
                    step, t_prev, t = e * kx + j, t_e + (j - 1) * h, t_e + j * h
                    s_j = between_samples(s_old, s_prev, j, True)
                    model.set_force(total(s_j) - a_fb @ a[wet])
                    model.advance(t_prev, t)
                    q, v, a = model.state()
                    check(q, v, step, t)
                    added_mass_watch(a[wet], step, t)
                    write(t, q, v, *s_j)
                    bar.update(1)
                if e + 1 < n_ex:
                    s_old, s_prev = s_prev, request(e + 1, (e + 1) * big_h, q[wet], v[wet])
            else:   # implicit
                saved = model.save()
                if len(u_hist) >= 2:
                    u = 2 * u_hist[-1] - u_hist[-2]
                elif u_hist:
                    u = u_hist[-1].copy()
                else:
                    u = np.tile(total(s_prev) - a_fb @ a[wet], (kx, 1))
                aitken.restart()
                for it in range(cpl.max_iterations):
                    if it:
                        model.restore(saved)
                    acc, snaps = np.zeros_like(u), []
                    for j in range(1, kx + 1):
                        step, t_prev, t = e * kx + j, t_e + (j - 1) * h, t_e + j * h
                        model.set_force(u[j - 1])
                        model.advance(t_prev, t)
                        q, v, a = model.state()
                        check(q, v, step, t, f"the body state (implicit iteration {it})")
                        acc[j - 1] = a[wet]
                        snaps.append((t, q, v, outputs()))
                    s_new = request(e + 1, (e + 1) * big_h, q[wet], v[wet], iteration=it)
                    s_sub = [between_samples(s_prev, s_new, j, False) for j in range(1, kx + 1)]
                    g = np.array([total(s) for s in s_sub]) - acc @ a_fb.T
                    res = float(np.abs(g - u).max(initial=0.0))
                    scale = max(scale, float(np.abs(g).max(initial=0.0)))
                    if res <= cpl.tolerance * scale:
                        break
                    u = aitken.update(u.reshape(-1), g.reshape(-1)).reshape(u.shape)
                else:
                    raise CouplingError(
                        f"the implicit coupling did not converge at step {step} (t = {t:.6g} s) within "
                        f"{cpl.max_iterations} iterations (residual {res:.3g} N, tolerance "
                        f"{cpl.tolerance:g} × {scale:.3g} N); raise coupling.max_iterations or "
                        f"coupling.tolerance, or reduce simulation.dt; the {e * kx} rows before it are saved",
                        step=step, time=t, rows=e * kx)
                iterations.append(it + 1)
                u_hist = [*u_hist[-1:], u]
                for (tj, qj, vj, ex), s_j in zip(snaps, s_sub):
                    write(tj, qj, vj, *s_j, extra=ex)
                    bar.update(1)
                s_prev = s_new
    except KeyboardInterrupt:
        bar.close()
        writer.finish(f"interrupted: KeyboardInterrupt at step {step} (t = {t:.6g} s)")
        raise KeyboardInterrupt(
            f"run interrupted at step {step} (t = {t:.6g} s); {writer.rows_written} rows saved "
            f"in {getattr(writer, 'path', 'the results file')}") from None
    except SimulationDiverged as exc:
        bar.close()
        hint = _divergence_hint(scheme, ratio, kx, big_h)
        if hint:
            exc = SimulationDiverged(f"{exc}. {hint}", step=exc.step, time=exc.time, rows=exc.rows)
        writer.finish(f"interrupted: {exc}")
        raise exc from None
    except RunInterrupted as exc:
        bar.close()
        writer.finish(f"interrupted: {exc}")
        raise
    except BaseException as exc:
        bar.close()
        writer.finish(f"interrupted: {type(exc).__name__} at step {step} (t = {t:.6g} s): {exc}")
        raise
    finally:
        model.finalize()
    bar.close()
    controllers = control.finish() if control is not None else None
    writer.finish("complete")
    wall = _time.perf_counter() - wall0
    steps = max(n_steps, 1)
    its = np.asarray(iterations or [1])
    coupling = {"scheme": scheme, "exchange_every": kx, "between_exchanges": between,
                "added_mass_ratio": coupling_ratio(scene, setup) if n else 0.0,
                "iterations_mean": float(its.mean()), "iterations_max": int(its.max()),
                "initial_iterations": init_iterations,
                "iterations": np.asarray(iterations, int) if scheme == "implicit" else None}
    return {"controllers": controllers, "steps": n_steps, "time": n_steps * h, "wall_time": wall, "rows": writer.rows_written,
            "status": "complete", "mechanism_notes": (mech.warnings + mech.reductions) if mech else [],
            "coupling": coupling, "warnings": warnings,
            "client_us_per_step": (wall - t_server) / steps * 1e6,
            "round_trip_us_per_step": t_server / steps * 1e6}


def _divergence_hint(scheme: str, ratio: float, kx: int, big_h: float) -> str:
    """What to change after a blow-up, given the coupling."""
    if scheme in ("explicit", "explicit-predictor"):
        if ratio > 1.0:
            return (f"Cause: coupling.scheme = \"{scheme}\": explicit added-mass coupling is unstable for "
                    f"A∞/m > 1 (this scene: {ratio:.3g}); use coupling.scheme = \"mass-matrix\" (or \"implicit\")")
        return (f"coupling.scheme = \"{scheme}\" (added-mass ratio {ratio:.3g}): try coupling.scheme = "
                "\"mass-matrix\" or a smaller simulation.dt")
    if kx > 1:
        return (f"coupling.exchange_every = {kx} holds the forces over {big_h:g} s: try a smaller "
                "exchange_every (or simulation.dt)")
    return ""
