"""Exudyn multibody client: owns the mechanism, exchanges state and forces with the force server.

Model (see shared/notes/exudyn-coupling.md for the measured facts behind it):

- the mechanism (bodies wet and dry, point masses, gravity/buoyancy, joints, constraints) is built by
  :mod:`hydrolink.clients.exudyn.mechanism`: one ``NodeRigidBodyRxyz`` per body at its reference point (for
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

import json
import logging
import math
from dataclasses import dataclass, field, replace

import numpy as np

import exudyn as exu
from exudyn.itemInterface import ObjectGenericODE2, VObjectGenericODE2

from hydrolink.clients.lockstep import driver as lockstep
from hydrolink.clients.lockstep.coupling_schemes import Predictor, make_scheme
from hydrolink.clients.lockstep.driver import BLOW_UP_LIMIT, CouplingError, DivergenceWatch, ForceLink, Lockstep, RunInterrupted, SimulationDiverged, progress_bar
from hydrolink.protocol.pacing import Pacer
from hydrolink.clients.lockstep.preflight import preflight
from hydrolink.clients.lockstep.results import add_force_term_variables, add_modal_variables
from hydrolink.clients.lockstep.summary import CouplingReport, RunSummary
from hydrolink.clients.exudyn.mechanism import JointOutputs, Mechanism, build_mechanism
from hydrolink.clients.exudyn.modes import ModalStructure, add_modal_node, modal_structure
from hydrolink.clients.exudyn.moorings import MooringSet, build_moorings
from hydrolink.clients.exudyn.ptos import PTOSet, build_ptos
from hydrolink.protocol.scene import Coupling, Scene
from hydrolink.protocol.setup import Setup

log = logging.getLogger(__name__)

#: systems with more ODE2 coordinates than this use Exudyn's sparse linear solver (EigenSparse)
SPARSE_ABOVE = 60
_ZERO_SLOT = np.zeros(1)   # the locked DOFs' slot that ends a reduced model's state vectors (read, never written)


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
    hydro_coordinates: np.ndarray = field(default_factory=lambda: np.zeros(0, int))  # the 6N entries it holds
    net_buoyancy: np.ndarray = field(default_factory=lambda: np.zeros(0))   # (N,) setup's, on heave (load)
    padded: bool = False            # reduced bodies: state vectors end in a zero slot (locked DOFs)
    modal: ModalStructure | None = None   # the generalized modes after the 6N wet DOFs (clients/exudyn/modes.py)
    load: np.ndarray | None = None  # the wet DOFs' load last written (6N, then the modes'): held bodies' reactions
    #: held wet bodies (mechanism.py "Held bodies") by name: their 6 rows, the hydro object's mass and
    #: stiffness rows over its coordinates, those coordinates' ODE2 indices (JointOutputs' ``hydro``)
    held_rows: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] = field(default_factory=dict)

    @property
    def mode_labels(self) -> tuple[str, ...]:
        """The generalized modes' ``body.mode`` labels (empty without modes)."""
        return self.modal.labels if self.modal is not None else ()

    @property
    def n_bodies(self) -> int:
        """Number of wet bodies (the server's bodies)."""
        return self.equilibrium.shape[0]

    def set_force(self, force: np.ndarray) -> None:
        """Write all wet bodies' hydrodynamic forces (6N) into the GenericODE2 in one call."""
        if int(self.hydro_object) >= 0:
            self.load = force
            self.mbs.SetObjectParameter(self.hydro_object, "forceVector",
                                        force if self.force_index is None else force[self.force_index])

    def initialize(self) -> None:
        """Initialise the solver (initial accelerations use the force vector set now)."""
        self.solver.InitializeSolver(self.mbs, self.settings)
        self.initialized = True

    def state(self) -> np.ndarray:
        """Displacements, velocities and accelerations of all system ODE2 coordinates as the rows
        of one new (3, n) array (wet bodies' 6N: ``wet_index``; every scene body: ``body_index``),
        with reduced bodies followed by one zero column (their locked DOFs)."""
        sd = self.mbs.systemData
        q, v, a = sd.GetODE2Coordinates(), sd.GetODE2Coordinates_t(), sd.GetODE2Coordinates_tt()
        if self.padded:
            zero = _ZERO_SLOT
            return np.concatenate((q, zero, v, zero, a, zero)).reshape(3, -1)
        return np.concatenate((q, v, a)).reshape(3, -1)

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

    def close(self) -> None:
        """Finalize the solver and release what the moorings hold (MoorDyn instances)."""
        self.finalize()
        if self.moorings is not None:
            self.moorings.close()

    def poses(self, q: np.ndarray) -> np.ndarray:
        """Every scene body's absolute pose (B, 6) from a (padded) state vector ``q``."""
        return self.body_reference + q[self.body_index].reshape(-1, 6)


def _scene_bodies(scene: Scene, names: list[str]):
    by_name = {b.name: b for b in scene.bodies}
    missing = [n for n in names if n not in by_name]
    if missing:
        raise ValueError(f"server setup names bodies {missing} that are not in the scene "
                         f"({list(by_name)})")
    return [by_name[n] for n in names]


def result_bodies(scene: Scene, setup: Setup | None) -> tuple[list[str], np.ndarray]:
    """Every scene body's name and reference position (N, 6): wet bodies' from the server's setup
    (by name), dry bodies' from the scene (``reference_point``, default the centre of mass)."""
    wet = {n: setup.equilibrium_position[i] for i, n in enumerate(setup.bodies)} if setup else {}
    ref = [wet[b.name] if b.name in wet else np.r_[b.dry_node(), 0.0, 0.0, 0.0] for b in scene.bodies]
    return [b.name for b in scene.bodies], np.asarray(ref, float).reshape(len(ref), 6)


def _body_indices(mech: Mechanism, names: list[str], ltg, pad: int) -> np.ndarray:
    """(6 len(names),) ODE2 indices of the named bodies' six DOFs; a reduced body's locked DOFs
    and a held body's six point at ``pad`` (the zero slot after the ODE2 coordinates)."""
    out = np.full(6 * len(names), pad, int)
    for i, nm in enumerate(names):
        h = mech.handles[nm]
        if h.dofs != ():
            out[6 * i + np.asarray(h.dofs if h.dofs is not None else range(6), int)] = ltg(h.node)
    return out


def build_model(scene: Scene, setup: Setup | None, *, spectral_radius: float = 1.0,
                added_mass_in_matrix: bool = True, newmark: bool = False,
                reduce: bool | None = None, moordyn_files: dict | None = None) -> ExudynModel:
    """Build the Exudyn system from the scene (bodies, point masses, joints, constraints, initial
    state) and the server's setup (wet bodies by name, active DOFs, A∞, hydrostatic stiffness,
    equilibrium, net buoyancy, dt); ``setup`` None when no body is wet.

    ``spectral_radius`` of the generalized-alpha integrator: 1 (default) is the energy-conserving
    trapezoidal rule — no numerical damping of the lightly damped wave-body modes.
    ``added_mass_in_matrix`` False leaves A∞ out of the mass matrix (the explicit and implicit
    coupling schemes feed it back as a force); ``newmark`` uses Newmark's trapezoidal rule
    (bit-exact rollback, for the implicit scheme) instead of generalized-alpha. ``reduce`` (default:
    the scene's ``[client] reduce``) builds the bodies that qualify with their active coordinates
    only (clients/exudyn/mechanism.py, "Reduced bodies"); False is the full form. ``moordyn_files``: the
    layouts of the scene's MoorDyn files by mooring index (clients/exudyn/moordyn_mooring.py); their
    systems are started (initial-condition solve) at the bodies' initial poses before the solver's
    initial accelerations."""
    names = list(setup.bodies) if setup else []
    n = len(names)
    served = [b.name for b in scene.served_bodies]
    if sorted(names) != sorted(served):
        raise ValueError(f"server setup names bodies {names}, the scene's served bodies (wet, or with Morison "
                         f"elements) are {served}")
    _scene_bodies(scene, names)
    equilibrium = setup.equilibrium_position if setup else np.zeros((0, 6))
    active = setup.active if setup else np.zeros((0, 6), bool)
    # what goes into the mass matrix (A_inf, or A(w0) with hydro.radiation = "constant")
    a_inf = setup.added_mass if setup else np.zeros((0, 0))
    stiffness = setup.hydrostatic_stiffness if setup else np.zeros((0, 0))
    dt = float(scene.simulation.dt)   # the client's step (the server's is [coupling] exchange_every times it)
    net = {nm: float(v) for nm, v in zip(names, setup.net_buoyancy) if v} if setup else {}

    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    if reduce is None:
        reduce = bool(getattr(scene.client, "reduce", True))
    mech = build_mechanism(mbs, scene, {nm: equilibrium[i, :3] for i, nm in enumerate(names)}, net,
                           reduce=reduce)
    ptos = build_ptos(mbs, scene.ptos, mech.handles) if scene.ptos else None
    all_names, reference = result_bodies(scene, setup)
    moorings = build_moorings(mbs, scene.moorings, mech.handles, scene.water, moordyn_files, all_names,
                              reference, scene.current) if scene.moorings else None
    padded = any(h.dofs is not None for h in mech.handles.values())
    modal = modal_structure(scene, setup)
    modal_node = add_modal_node(mbs, modal) if modal.size else None
    hydro, sel = _hydro_object(mbs, mech, names, a_inf if added_mass_in_matrix else None, stiffness,
                               modal, modal_node)
    mbs.Assemble()
    ltg = mbs.systemData.GetNodeLTGODE2
    pad = len(mbs.systemData.GetODE2Coordinates())
    held_rows = {}
    if mech.held and int(hydro) >= 0:
        coords = np.asarray(mbs.systemData.GetObjectLTGODE2(hydro), int)
        mass = a_inf if added_mass_in_matrix else np.zeros_like(stiffness)
        rows = {nm: 6 * i + np.arange(6) for i, nm in enumerate(names) if nm in mech.held}
        held_rows = {nm: (r, mass[np.ix_(r, sel)], stiffness[np.ix_(r, sel)], coords) for nm, r in rows.items()}
    body_index = _body_indices(mech, all_names, ltg, pad)
    wet_index = _body_indices(mech, names, ltg, pad)
    if modal_node is not None:
        wet_index = np.concatenate((wet_index, np.asarray(ltg(modal_node), int)))

    ss = exu.SimulationSettings()
    ss.solution.file.write = False
    ss.solution.sensors.active = False
    ss.timeIntegration.verboseMode = 0
    ss.timeIntegration.adaptiveStep = False
    ss.timeIntegration.numberOfSteps = 1
    ss.timeIntegration.endTime = dt
    ss.timeIntegration.generalizedAlpha.spectralRadius = float(spectral_radius)
    # the modified Newton's Jacobian renewed at each step's start, as a SolveSteps call of one step
    # does: the compiled exchange's one SolveSteps over the run (clients/exudyn/compiled_exchange.py)
    # then takes the same iterations, to the bit, as a call a step
    ss.timeIntegration.newton.modifiedNewtonJacUpdatePerStep = True
    if newmark:   # trapezoidal rule as Newmark (beta 1/4, gamma 1/2): a rollback + redo is bit-exact
        ga = ss.timeIntegration.generalizedAlpha
        ga.useNewmark, ga.newmarkBeta, ga.newmarkGamma, ga.useIndex2Constraints = True, 0.25, 0.5, True
    if setup is not None and setup.hydro_state:   # a switch changes the hydro object's mass matrix mid-run
        ss.timeIntegration.reuseConstantMassMatrix = False
    if len(mbs.systemData.GetODE2Coordinates()) > SPARSE_ABOVE:
        # large mechanisms (arrays of bodies + arms): Exudyn's default dense LU dominates the step;
        # measured on 9N9LA (108 body coordinates + 54 constraints): 9.8 -> 2.3 ms per step
        ss.linearSolver.solverType = exu.LinearSolverType.EigenSparse
    if moorings is not None and moorings.moordyn:
        sd, shape = mbs.systemData, (len(all_names), 6)
        q0 = np.append(sd.GetODE2Coordinates(configuration=exu.ConfigurationType.Initial), 0.0)
        pose0 = reference + q0[body_index].reshape(shape)
        moorings.start_moordyn(mbs, pose0)
        _moordyn_offsets(scene, moorings, pose0, pose0 - reference, all_names, names, stiffness, net)
    return ExudynModel(sc, mbs, exu.MainSolverImplicitSecondOrder(), ss, hydro, equilibrium,
                       active, stiffness, dt, mech, wet_index, all_names, reference, body_index,
                       np.array([all_names.index(nm) for nm in names], int), ptos, moorings,
                       added_mass=a_inf, added_mass_in_matrix=added_mass_in_matrix,
                       force_index=sel if sel.size < a_inf.shape[0] else None, padded=padded,
                       modal=modal, hydro_coordinates=sel, held_rows=held_rows,
                       net_buoyancy=setup.net_buoyancy if setup else np.zeros(0))


def _hydro_object(mbs, mech: Mechanism, names: list[str], mass: np.ndarray | None, stiffness: np.ndarray,
                  modal: ModalStructure, modal_node: int | None) -> tuple[int, np.ndarray]:
    """The ``ObjectGenericODE2`` over the wet bodies' nodes (-1 without any) and the entries of the
    setup's vector it takes: each body's node coordinates (a reduced body's active DOFs), then the
    generalized modes' node, whose structure (clients/exudyn/modes.py) joins its matrices. ``mass``
    what goes into its mass matrix (None: nothing, A∞ fed back as a force)."""
    n = len(names)
    dofs = [mech.handles[nm].dofs for nm in names]     # () for a held body: none of its DOFs
    sel = np.concatenate([6 * i + np.asarray(d if d is not None else range(6), int) for i, d in enumerate(dofs)]
                         ) if n else np.zeros(0, int)
    if not n:
        return -1, sel
    nodes = [node for node, d in zip(mech.rigid_nodes(names), dofs) if d != ()]
    if modal_node is not None:
        sel, nodes = np.concatenate((sel, 6 * n + np.arange(modal.size))), nodes + [modal_node]
    ix = np.ix_(sel, sel)
    m = mass[ix] if mass is not None else np.zeros((sel.size, sel.size))
    k = stiffness[ix]
    extra = {}
    if modal_node is not None:    # the modes' structure in the same matrices
        m, k, damping = m.copy(), k.copy(), np.zeros_like(k)
        tail = slice(sel.size - modal.size, sel.size)
        m[tail, tail] += modal.mass
        k[tail, tail] += modal.stiffness + np.diag(modal.pto_stiffness)     # the modal PTOs: exact, implicit
        damping[tail, tail] = modal.damping + np.diag(modal.pto_damping)
        extra["dampingMatrix"] = damping
    hydro = mbs.AddObject(ObjectGenericODE2(
        name="hydrodynamics", nodeNumbers=nodes, massMatrix=m, stiffnessMatrix=k, forceVector=np.zeros(sel.size),
        visualization=VObjectGenericODE2(show=False), **extra))
    return hydro, sel


JOINT_COMPONENTS = ("fx", "fy", "fz", "mx", "my", "mz")


def _add_joint_variables(writer, labels: list[str]) -> None:
    """Declare the joint outputs in the results file (dims ``joint``, ``joint_component``)."""
    coords = {"joint": labels, "joint_component": list(JOINT_COMPONENTS)}
    writer.add_variable("joint_force", ("joint", "joint_component"), coords, "N (fx, fy, fz); N m (mx, my, mz)",
                        "load on body2 from body1 through the joint (constraint reaction plus joint friction), "
                        "global frame: force at the joint point, moment about it")
    writer.add_variable("joint_violation", ("joint",), coords, "m",
                        "position-level joint violation: norm of the constrained relative translation")
    writer.add_variable("joint_rotation_violation", ("joint",), coords, "rad",
                        "norm of the constrained relative rotation angles")


def _add_pto_mooring_variables(writer, ptos: PTOSet | None, moorings: MooringSet | None,
                               modal: ModalStructure | None = None) -> None:
    """Declare the PTO outputs (dim ``pto``: the mechanism's PTOs, then the PTOs on modes named by
    their modes' labels, attribute ``pto_modes``) and mooring forces (dims ``mooring``,
    ``mooring_component``)."""
    on_modes = modal.pto_names if modal is not None else []
    if ptos is not None or on_modes:
        coords = {"pto": list(ptos.names if ptos is not None else ()) + on_modes}
        if on_modes:
            writer.set_attribute("pto_modes", json.dumps({n: {"body": n.split(".", 1)[0], "mode": n.split(".", 1)[1]}
                                                          for n in on_modes}))
        writer.add_variable("pto_force", ("pto",), coords, "N (linear); N m (rotary axis); generalized (mode)",
                            "force on body1 along the line point1 -> point2 (tension > 0) / torque on "
                            "body1 about the PTO axis / a mode's PTO: k q + c dq/dt, resisting the mode")
        writer.add_variable("pto_velocity", ("pto",), coords, "m/s (linear); rad/s (rotary axis); 1/s (mode)",
                            "extension rate of the line / angular velocity of body2 relative to body1 / "
                            "the modal coordinate's rate")
        writer.add_variable("pto_power", ("pto",), coords, "W",
                            "absorbed power pto_force * pto_velocity (> 0: into the PTO)")
        writer.add_variable("total_pto_power", (), None, "W", "sum of pto_power over all PTOs")
    if moorings is not None:
        writer.add_variable("mooring_force", ("mooring", "mooring_component"),
                            {"mooring": list(moorings.names), "mooring_component": list(JOINT_COMPONENTS)},
                            "N (fx, fy, fz); N m (mx, my, mz)",
                            "force and moment the mooring exerts on its body, global frame, about the "
                            "mooring point (linear) / the attachment point (rope)")


def _moordyn_offsets(scene: Scene, moorings: MooringSet, pose: np.ndarray, displacement: np.ndarray,
                     all_names: list[str], wet_names: list[str], stiffness: np.ndarray,
                     net_buoyancy: dict[str, float]) -> None:
    """Each MoorDyn system's static offset estimate (``static_offset = true``): the coupled bodies'
    displacement from their reference positions where their hydrostatic stiffness and net
    buoyancy (wet) or constant weight and buoyancy (dry) balance the mooring's load, from their
    initial ``pose`` (= reference + ``displacement``)."""
    c = np.zeros((len(all_names), 6, 6))
    for i, nm in enumerate(wet_names):
        c[all_names.index(nm)] = stiffness[6 * i:6 * i + 6, 6 * i:6 * i + 6]
    g, rho = scene.water.gravity, scene.water.density
    constant = np.zeros((len(all_names), 6))
    for row, b in enumerate(scene.bodies):
        if b.wet:
            constant[row, 2] = net_buoyancy.get(b.name, 0.0)
            continue
        ref = b.dry_node()
        com = np.asarray(b.center_of_mass, float)
        cob = np.asarray(b.center_of_buoyancy if b.center_of_buoyancy is not None else com, float)
        weight, lift = np.array([0.0, 0.0, -b.mass * g]), np.array([0.0, 0.0, rho * g * b.buoyancy_volume])
        constant[row, :3] = weight + lift
        constant[row, 3:] = np.cross(com - ref, weight) + np.cross(cob - ref, lift)
    active = np.array([b.active_mask for b in scene.bodies], bool)
    for system in moorings.moordyn:
        if system.spec.static_offset:
            system.offset, system.offset_residual = system.static_offset(pose, displacement, c, constant, active)
            for name, off in zip(system.names, system.offset):
                log.info("%s: %s's moored equilibrium is %s (m, rad) from its reference position (its "
                         "initial_displacement to start there)", system.key, name, np.array2string(off, precision=4))


def _add_moordyn_variables(writer, moorings: MooringSet) -> None:
    """Declare the MoorDyn outputs: ``line_tension`` (MoorDyn's own fairlead tension) and
    ``line_end_force`` (the end node's pull on the fairlead), dim ``line``: "mooring:k", MoorDyn's
    line k, and, when a system records them, ``line_node_position`` (line, node, xyz)."""
    systems = moorings.moordyn
    lines = [f"{s.spec.name}:{k}" for s in systems for k in range(1, s.n_lines + 1)]
    writer.add_variable("line_tension", ("line",), {"line": lines}, "N",
                        "MoorDyn's fairlead tension: the tension of the line's end segment at its fairlead, as "
                        "MoorDyn reports it (GetLineFairTen, its FairTen output channel)")
    writer.add_variable("line_end_force", ("line",), {"line": lines}, "N",
                        "magnitude of the force the line's fairlead end node passes on to its fairlead: "
                        "line_tension plus the node's weight, buoyancy, drag and seabed contact")
    n_nodes = max((s.max_nodes for s in systems if s.spec.record_nodes), default=0)
    if n_nodes:
        writer.add_variable("line_node_position", ("line", "node", "xyz"),
                            {"node": [str(k) for k in range(n_nodes)], "xyz": ["x", "y", "z"]}, "m",
                            "MoorDyn line node positions from the anchor end (NaN past a line's last node and "
                            "for systems without record_nodes)")


def _moordyn_report(moorings: MooringSet) -> list[dict]:
    """What each MoorDyn system started from: its file, lines, the fairlead tensions and the loads
    on the coupled bodies after MoorDyn's initial-condition solve, and the bodies' static offset
    under the mooring — their displacement from the reference position at the moored equilibrium,
    m and rad (None with static_offset = false) — with the out-of-balance load left."""
    return [{"mooring": s.spec.name, "file": str(s.layout.path), "lines": s.n_lines, "bodies": s.names,
             "initial_line_tension": s.tensions().tolist(),
             "initial_line_end_force": s.end_forces().tolist(), "initial_load": s.initial_loads.tolist(),
             "static_offset": None if s.offset is None else s.offset.tolist(),
             "static_offset_residual": s.offset_residual}
            for s in moorings.moordyn]


def wet_rigid_mass(scene: Scene, setup: Setup) -> np.ndarray:
    """Rigid-body mass matrix (6N × 6N) of the wet bodies about their reference points (dry bodies
    attached by joints are left out, which can only overstate the added-mass ratio)."""
    from hydrolink.server.rigid_body import rigid_body_mass_matrix
    names, eq = list(setup.bodies), setup.equilibrium_position
    m = np.zeros((6 * len(names), 6 * len(names)))
    for i, b in enumerate(_scene_bodies(scene, names)):
        m[6 * i:6 * i + 6, 6 * i:6 * i + 6] = rigid_body_mass_matrix(
            b.mass, b.inertia_matrix, b.com_or(eq[i, :3]) - eq[i, :3])
    return m


def coupling_ratio(scene: Scene, setup: Setup | None) -> float:
    """The added-mass ratio of the explicit schemes: spectral radius of M⁻¹A∞ over the wet bodies'
    active DOFs and their generalized modes (M the rigid-body and modal mass matrix). An explicitly
    fed-back −A∞·a multiplies an acceleration error by −M⁻¹A∞ every step: unstable above 1."""
    from hydrolink.clients.lockstep.relaxation import added_mass_ratio
    if not setup or not setup.bodies:
        return 0.0
    act = np.flatnonzero(setup.active.reshape(-1))
    a, m = setup.added_mass, wet_rigid_mass(scene, setup)
    modal = modal_structure(scene, setup)
    if modal.size:    # the generalized modes: their structural mass beside the rigid bodies'
        import scipy.linalg
        m = scipy.linalg.block_diag(m, modal.mass)
        act = np.concatenate((act, 6 * setup.n + np.arange(modal.size)))
    return added_mass_ratio(m[np.ix_(act, act)], a[np.ix_(act, act)])


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


class ExudynMultibody:
    """The Exudyn model as the lockstep driver's multibody code (:class:`~hydrolink.clients.lockstep.driver.Multibody`).

    Its input is the wet bodies' force vector (6N): excitation + radiation at the step's end (the
    implicit integrator applies loads at the end of the step), minus A∞·a when A∞ is fed back.
    Rows hold every scene body; the hydrostatic force written is −C·q (C is in the stiffness matrix)."""

    label = "the body state"

    def __init__(self, model: ExudynModel, writer, substeps: int, feedback: bool, coupling: Coupling,
                 ratio: float, control=None):
        self.model, self.writer, self.control = model, writer, control
        self.coupling, self.ratio = coupling, ratio
        self.h, self.substeps = model.dt, substeps
        self.a_fb = model.added_mass if feedback else None
        self.n, self.nb = model.n_bodies, len(model.body_names)
        mech = model.mechanism
        self.joints = JointOutputs(model.mbs, mech, model.held_rows) if mech and mech.joints else None
        self._forces = np.zeros((3, self.nb, 6))
        # every scene body wet, in setup order: the forces go straight into the results row
        self._all_wet = self.n == self.nb and np.array_equal(model.wet_rows, np.arange(self.nb))
        self._hs = np.zeros(model.wet_index.size)   # scratch: C q (6N, then the modes')
        self._r = 6 * self.n                          # the rigid DOFs' entries; the modes' after them
        # the wet bodies' 6N entries in the (B, 6) rows (the optional forces' results variables)
        self._wet_flat = (6 * np.asarray(model.wet_rows, int)[:, None] + np.arange(6)).reshape(-1)
        self._pto_sample = None
        self._rest_shift: np.ndarray | None = None   # C_s (x_eq,s - x_eq,0) of a hydro state resting elsewhere
        self._state_load: np.ndarray | None = None   # the hydro state's constant load beside the setup's
        self.hydro_state: str | None = None                # the state entered at the newest switch
        self.state_names: list[str] = []                   # the switching body's states (results: hydro_state)
        # MoorDyn: each step is driven towards the pose it ends in (clients/exudyn/moordyn_mooring.py):
        # predicted, or on a redo the end poses of the previous pass (one per step since the save)
        moorings = model.moorings
        self._md = moorings if moorings is not None and moorings.moordyn else None
        self._md_nodes = max((s.max_nodes for s in moorings.moordyn if s.spec.record_nodes), default=0) \
            if self._md else 0
        self._ends: list[np.ndarray] = []
        self._targets: list[np.ndarray] = []
        # the wet DOFs' q, v, a and every body's q, v as flat indices into model.state()'s (3, n)
        cols = len(model.mbs.systemData.GetODE2Coordinates()) + model.padded
        self._wet_take = (cols * np.arange(3)[:, None] + model.wet_index).reshape(-1)
        self._body_take = (cols * np.arange(2)[:, None] + model.body_index).reshape(-1)
        self._refresh()

    def _refresh(self) -> None:
        """The state after a change: q, v, a of every coordinate (new arrays: a snapshot keeps them)
        and of the wet DOFs."""
        s = self._s = self.model.state()
        self._q, self._v, self._a = s
        w = self._w = s.reshape(-1).take(self._wet_take).reshape(3, -1)
        self._wet = (w[0], w[1], w[2])

    def compiled_exchange(self, link: ForceLink, scheme, n_exchanges: int):
        """The run's exchange in two compiled calls (clients/exudyn/compiled_exchange.py) in place of
        ``scheme``, or None where the reference path runs: A∞ not in the mass matrix or the scheme
        not ``Predictor``'s, several client steps an exchange, MoorDyn, hydro states, generalized
        modes, no wet body, a server that is not this process's own (socketless, or polled with
        controllers) whose model steps as its compiled linear core alone (``LocalStep.compiled``),
        or controllers beside PTOs other than linear ones, moorings or point-mass joints."""
        m = self.model
        if not (type(scheme) is Predictor and not scheme.feedback and self.a_fb is None and self.substeps == 1
                and self._md is None and not self.state_names
                and not m.mode_labels and self.n and int(m.hydro_object) >= 0 and link.local is not None):
            return None
        step = link.local.compiled()
        if step is None:
            return None
        from hydrolink.clients.exudyn.compiled_exchange import CompiledExchange
        # the mechanism's outputs by the compiled calls where they make all of them: linear PTOs
        # (linear_ptos), joints but point-mass ones (JointOutputs.compiled), no moorings
        linear = m.ptos.linear_table() if m.ptos is not None and m.moorings is None else None
        rows = self.joints.compiled() if self.joints is not None and m.moorings is None else None
        compiled = (m.moorings is None and (m.ptos is None or linear is not None)
                    and (self.joints is None or rows is not None))
        if not compiled:
            linear = rows = None
        if self.control is not None and linear is None:   # (its measurements come from linear_ptos)
            return None
        has_outputs = self.joints is not None or m.moorings is not None or m.ptos is not None
        return CompiledExchange(m, link, step, wet_take=self._wet_take, body_take=self._body_take,
                                state=lambda: self._s, outputs=self.outputs if has_outputs and not compiled else None,
                                refresh=self._refresh if self.control is None else self._resync,
                                n_exchanges=n_exchanges, linear_ptos=linear, control=self.control,
                                joints=None if rows is None else lambda slots: rows(m.load, slots),
                                wet_flat=self._wet_flat)

    def _resync(self) -> None:
        """:meth:`_refresh` and the PTOs' sample the controllers' measurements take (:meth:`outputs`'),
        for a run with controllers whose steps the compiled exchange took."""
        self._refresh()
        self._pto_sample = self.model.ptos.sample(self.model.mbs)

    # -- the driver's interface -------------------------------------------------------------
    def begin(self, s0, feedback: bool) -> int:
        """Initial accelerations from F(0); with A∞ fed back, consistent with −A∞·a0 (a fixed point)."""
        m, its = self.model, 0
        if feedback and self.n:
            its = self._consistent_start(s0.load)
        else:
            m.set_force(s0.load)
            m.initialize()
        self._refresh()
        return its

    def _consistent_start(self, f0: np.ndarray) -> int:
        from hydrolink.clients.lockstep.relaxation import Aitken
        m, cpl = self.model, self.coupling
        aitken = Aitken(1.0 / (1.0 + self.ratio))
        u = f0.copy()
        for it in range(cpl.max_iterations):
            m.set_force(u)
            m.initialize()
            g = f0 - self.a_fb @ m.state()[2, m.wet_index]
            scale = max(float(np.abs(g).max(initial=0.0)), float(np.abs(f0).max(initial=0.0)), 1e-300)
            if not np.isfinite(g).all() or float(np.abs(g - u).max(initial=0.0)) <= cpl.tolerance * scale:
                return it + 1
            m.finalize()
            u = aitken.update(u, g)
        m.set_force(u)
        m.initialize()
        return cpl.max_iterations

    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        return self._wet

    def extent(self, limit: float) -> float:
        qv = self._s[:2].reshape(-1)   # q then v
        ss = float(qv @ qv)
        if ss < limit * limit:   # cheap bound (each |x| <= the 2-norm); NaN fails `<`
            return math.sqrt(ss)
        return float(np.abs(qv).max(initial=0.0))

    def inputs(self, s0, s1, acc, x0, x1) -> np.ndarray:
        load = s1.load if self._state_load is None else s1.load + self._state_load
        return load if acc is None else load - self.a_fb @ acc

    def apply_hydro_state(self, change) -> None:
        """A switch of hydrodynamic state (protocol/reply.py HydroStateChange): its A∞ into the hydro object's mass
        matrix, its stiffness C_s into the stiffness matrix (which holds −C q about the setup's
        equilibrium), and as a constant load beside the setup's: the change of net buoyancy and
        C_s (x_eq,s − x_eq,0) where the state's rest pose differs from the setup's."""
        m = self.model
        ix = np.ix_(m.hydro_coordinates, m.hydro_coordinates)
        m.mbs.SetObjectParameter(m.hydro_object, "stiffnessMatrix", change.hydrostatic_stiffness[ix])
        m.stiffness = change.hydrostatic_stiffness
        if m.added_mass_in_matrix:
            m.mbs.SetObjectParameter(m.hydro_object, "massMatrix", change.added_mass[ix])
        m.added_mass = change.added_mass
        shift = change.hydrostatic_stiffness @ (change.equilibrium_position - m.equilibrium).reshape(-1)
        self._rest_shift = shift if shift.any() else None     # C_s (x_eq,s - x_eq,0), also in the results
        extra = shift.copy()
        extra[2::6] += change.net_buoyancy - m.net_buoyancy
        self._state_load = extra if extra.any() else None
        self.hydro_state = change.state

    def advance(self, t0: float, t1: float, u: np.ndarray) -> None:
        if self._md is not None:
            self._step_moordyn(t0, t1)
        self.model.set_force(u)
        self.model.advance(t0, t1)
        self._refresh()
        if self._md is not None:
            pose = self.model.poses(self._q)
            self._ends.append(pose)
            if not self._targets:      # MoorDyn workers step on while the hydro forces are computed
                self._md.step_moordyn_ahead(t1, self.h, pose, self._predicted(pose))

    def _predicted(self, pose0: np.ndarray) -> np.ndarray:
        """The poses a step from ``pose0`` (the current state's) ends in: x + h v + h²/2 a."""
        idx, h = self.model.body_index, self.h
        return pose0 + (h * self._v[idx] + 0.5 * h * h * self._a[idx]).reshape(pose0.shape)

    def _step_moordyn(self, t0: float, t1: float) -> None:
        """Step the MoorDyn systems over t0 -> t1 towards the predicted (or, on a redo, the last
        pass's) end poses; a MoorDyn failure stops the run naming the file and the step."""
        m, h = self.model, self.h          # the nominal step: t1 - t0 carries round-off into MoorDyn's substeps
        pose0 = m.poses(self._q)
        pose1 = self._targets.pop(0) if self._targets else self._predicted(pose0)
        try:
            self._md.step_moordyn(m.mbs, t0, h, pose0, pose1)
        except RuntimeError as exc:
            step, rows = int(round(t1 / m.dt)), self.writer.rows
            where = getattr(self.writer, "path", "the results file")
            raise RunInterrupted(f"MoorDyn failed at step {step} (t = {t1:.6g} s): {exc}; the {rows} rows before "
                                 f"it are saved in {where}", step=step, time=t1, rows=rows) from None

    def save(self):
        self._ends = []
        return self.model.save(), (self._md.save_moordyn() if self._md is not None else None)

    def restore(self, saved) -> None:
        state, moordyn = saved
        self.model.restore(state)
        if self._md is not None:
            self._md.restore_moordyn(self.model.mbs, moordyn)
            self._targets, self._ends = self._ends, []
        self._refresh()

    def snapshot(self):
        return self._s, self._w, self.outputs()

    def write(self, t: float, s, snap) -> None:
        state, wet, out = snap
        q, v = state[0], state[1]
        m, nb = self.model, self.nb
        if self.control is not None:
            self.control.stage()
        r = self._r
        if m.mode_labels and m.modal.has_pto:   # the modes' PTOs after the mechanism's (dim pto)
            w = m.wet_index[r:]
            out = m.modal.pto_outputs(q[w], v[w], out)
        if out:
            self.writer.stage_extra(out)
        row = self.writer.row()    # filled in place: position, velocity, excitation, radiation, hydrostatic
        row[:2] = state.reshape(-1).take(self._body_take).reshape(2, nb, 6)   # q, v of every body
        np.add(m.body_reference, row[0], out=row[0])
        if self._all_wet:
            row[2] = s.excitation[:r].reshape(nb, 6)
            row[3] = s.radiation[:r].reshape(nb, 6)
            np.dot(m.stiffness, wet[0], out=self._hs)
            if self._rest_shift is not None:     # a hydro state resting elsewhere: -C_s (x - x_eq,s)
                self._hs -= self._rest_shift
            np.negative(self._hs[:r], out=row[4].reshape(-1))
        else:
            f = self._forces   # dry bodies' rows stay zero
            if self.n:
                rows, shape = m.wet_rows, (self.n, 6)
                f[0, rows], f[1, rows] = s.excitation[:r].reshape(shape), s.radiation[:r].reshape(shape)
                np.dot(m.stiffness, wet[0], out=self._hs)
                if self._rest_shift is not None:     # a hydro state resting elsewhere: -C_s (x - x_eq,s)
                    self._hs -= self._rest_shift
                f[2, rows] = -self._hs[:r].reshape(shape)
            row[2:] = f
        if m.mode_labels:   # the modes' coordinates and forces (clients/lockstep/results.py)
            w = m.wet_index[r:]
            self.writer.stage_extra({"modal_position": q[w], "modal_velocity": v[w],
                                     "modal_excitation": s.excitation[r:], "modal_radiation": s.radiation[r:],
                                     "modal_hydrostatic": -self._hs[r:]})
        if s.optional:
            self.writer.stage_forces(s.optional, self._wet_flat, row[1])
        self.writer.commit(t, s.eta)

    def measurements(self, step: int) -> dict | None:
        c = self.control
        if c is None or not c.is_sample(step):
            return None
        idx, shape = self.model.body_index, (self.nb, 6)
        return c.measurements(step, self._q[idx].reshape(shape), self._v[idx].reshape(shape), self._pto_sample)

    def apply_control(self, decisions: dict | None) -> None:
        if self.control is not None:
            self.control.apply(decisions)

    # -- results ----------------------------------------------------------------------------
    def outputs(self) -> dict:
        """The mechanism's outputs at the current state (joints, PTOs, moorings)."""
        m, out = self.model, {}
        if self.joints is not None:
            wrench, gap, rot = self.joints(m.load)
            out.update({"joint_force": wrench, "joint_violation": gap, "joint_rotation_violation": rot})
        if m.ptos is not None:
            s = self._pto_sample = m.ptos.sample(m.mbs)
            out["pto_force"], out["pto_velocity"], out["pto_power"] = s.force, s.velocity, s.power
            out["total_pto_power"] = s.total_power
        if self.state_names:
            out["hydro_state"] = np.float64(self.state_names.index(self.hydro_state or self.state_names[0]))
        if m.moorings is not None:
            out["mooring_force"] = m.moorings.sample(m.mbs)
        if self._md is not None:
            systems = self._md.moordyn
            out["line_tension"] = np.concatenate([s.tensions() for s in systems])
            out["line_end_force"] = np.concatenate([s.end_forces() for s in systems])
            if self._md_nodes:
                out["line_node_position"] = np.concatenate([
                    s.node_positions(self._md_nodes) if s.spec.record_nodes
                    else np.full((s.n_lines, self._md_nodes, 3), np.nan) for s in systems])
        return out


def run(scene: Scene, scene_text: str, connection, setup: Setup | None, writer, *, progress: bool = True,
        spectral_radius: float | None = None, blow_up_limit: float = BLOW_UP_LIMIT,
        allow_unstable: bool = False, moordyn_files: dict | None = None, realtime: float | None = None,
        rt_priority: int | None = None) -> RunSummary:
    """Run the lockstep co-simulation to ``scene.simulation.duration`` (:mod:`hydrolink.clients.lockstep.driver`).

    ``connection`` has already said hello (``setup`` is its reply); it is not closed here. With no
    wet body both are None and no server is asked. Rows hold every scene body (hydrodynamic forces
    zero for dry bodies) and, with joints, the joint outputs (see :mod:`hydrolink.clients.lockstep.results`).
    Every step is written to ``writer`` (a :class:`~hydrolink.clients.lockstep.results.ResultWriter`),
    which gets its final status ("complete" / "interrupted: ...") before this returns or raises.
    On Ctrl-C or a server error the rows computed so far are flushed and the error re-raised with
    the step and time named (KeyboardInterrupt stays a KeyboardInterrupt, server errors become
    :class:`RunInterrupted`, a blow-up :class:`SimulationDiverged`, a non-converged implicit step
    :class:`CouplingError`).

    The scene's ``[coupling]`` picks the scheme (module docstring); an explicit scheme above
    ``coupling.explicit_limit`` is refused (SceneError naming coupling.scheme) unless
    ``allow_unstable`` (only to demonstrate the added-mass instability). ``moordyn_files``: the
    layouts of the scene's MoorDyn files (:func:`~hydrolink.clients.exudyn.moordyn_mooring.load_moordyn_files`).
    ``realtime``: pace the exchanges at FACTOR x wall clock (:mod:`hydrolink.protocol.pacing`);
    ``rt_priority``: the exchanges under ``SCHED_FIFO`` at that priority (the driver's ``rt_priority``).

    Returns the :class:`~hydrolink.clients.lockstep.summary.RunSummary` (the checks before the run:
    :func:`~hydrolink.clients.lockstep.preflight.preflight`)."""
    from hydrolink.protocol.scene import SceneError

    cpl = scene.coupling
    scheme = "mass-matrix" if cpl.scheme == "auto" else cpl.scheme   # Exudyn always takes A∞ in its matrix
    feedback = scheme != "mass-matrix"
    if spectral_radius is None:
        spectral_radius = scene.simulation.spectral_radius
    mass_ratio = coupling_ratio(scene, setup)      # 0 without wet bodies
    ratio = mass_ratio if feedback else 0.0        # what the scheme feeds back
    if scheme in ("explicit", "explicit-predictor") and ratio > cpl.explicit_limit and not allow_unstable:
        why = explicit_refusal(scheme, ratio, cpl.explicit_limit)
        writer.finish(f"refused: {why}")
        raise SceneError("scene", "coupling.scheme", why)
    pre = preflight(scene, setup, writer, "exudyn")
    warnings = pre.warnings
    if scheme == "implicit" and spectral_radius != 1.0:
        warnings.append(f"simulation.spectral_radius = {spectral_radius:g} is not used by coupling.scheme = "
                        "\"implicit\" (Newmark's trapezoidal rule: bit-exact rollback)")
    model = build_model(scene, setup, spectral_radius=spectral_radius, added_mass_in_matrix=not feedback,
                        newmark=scheme == "implicit", moordyn_files=moordyn_files)
    model.failure_hint = _stiffness_hint(scene)
    mech = model.mechanism
    for note in mech.warnings if mech else []:
        log.warning("%s", note)
    for note in mech.reductions if mech else []:   # what the model did for the scene: no action needed
        log.info("%s", note)
    moordyn = _add_variables(scene, model, writer, warnings)
    control = None
    if scene.controllers:
        if model.n_bodies == 0:
            raise ValueError("controllers: a scene with controllers needs a wet body (the controllers "
                             "talk to the multibody client through the force server's session)")
        from hydrolink.clients.exudyn.pto_control import PTOControl
        control = PTOControl(scene, model.ptos, model.mbs, writer,
                             modal_ptos=len(model.modal.pto_names) if model.modal is not None else 0)
    kx = pre.exchange_every
    mb = ExudynMultibody(model, writer, kx, feedback, cpl, ratio, control)
    mb.state_names = next((b.state_names() for b in scene.bodies if b.hydro_states), [])
    loop = Lockstep(mb, ForceLink(connection, setup if model.n_bodies else None, writer), writer,
                    DivergenceWatch(blow_up_limit), cpl.between_exchanges,
                    bar=progress_bar(pre.n_steps, progress and scene.simulation.progress))
    first_timeout = control.join_timeout + getattr(connection, "timeout", 30.0) if control else None
    coupling = CouplingReport(scheme=scheme, exchange_every=kx, between_exchanges=cpl.between_exchanges,
                              added_mass_ratio=mass_ratio)
    steps = make_scheme(scheme, tolerance=cpl.tolerance, max_iterations=cpl.max_iterations, ratio=ratio,
                        n_exchanges=pre.n_exchanges)
    # the run's exchange compiled where it qualifies (clients/exudyn/compiled_exchange.py)
    steps = mb.compiled_exchange(loop.link, steps, pre.n_exchanges) or steps
    try:
        out = lockstep.run(loop, steps, pre.n_exchanges, coupling, first_timeout=first_timeout,
                           hint=lambda exc: _divergence_hint(scheme, ratio, kx, pre.exchange_dt),
                           pacer=None if realtime is None else Pacer(pre.exchange_dt, realtime),
                           rt_priority=rt_priority)
    finally:
        model.close()
    return replace(out, warnings=warnings, controllers=control.finish() if control is not None else None,
                   mechanism_notes=(mech.warnings + mech.reductions) if mech else [], moordyn=moordyn)


def _stiffness_hint(scene: Scene) -> str:
    """What a solver failure should add when a spring is stiff enough to stall Newton's iteration."""
    stiff = _stiffest(scene)
    if not stiff or stiff[0] <= STIFF_NOTE:
        return ""
    return (f"; the stiffest spring is {stiff[1]} = {stiff[0]:.3g} N/m (N m/rad): above ~{STIFF_NOTE:.0e} "
            f"Exudyn's Newton iteration can stall (measured: 1e9 N/m on a 2.6e5 kg body at dt = 0.01 s); lower "
            f"it (a joint or constraint models a rigid link) or simulation.dt")


def _add_variables(scene: Scene, model: ExudynModel, writer, warnings: list[str]) -> list[dict] | None:
    """The results variables of the mechanism's joints, PTOs, moorings, MoorDyn systems and the
    server's optional force terms; returns the MoorDyn report (None without MoorDyn) and appends
    MoorDyn's step notes to ``warnings``."""
    mech = model.mechanism
    if mech and mech.joints:
        _add_joint_variables(writer, mech.joint_labels)
    _add_pto_mooring_variables(writer, model.ptos, model.moorings, model.modal)
    add_force_term_variables(writer, scene)
    if model.mode_labels:
        add_modal_variables(writer, model.mode_labels)
    switching = next((b for b in scene.bodies if b.hydro_states), None)
    if switching is not None:
        writer.add_variable("hydro_state", (), None, "1",
                            f"hydrodynamic state of body {switching.name!r}: index in {switching.state_names()}")
    moordyn = _moordyn_report(model.moorings) if model.moorings is not None and model.moorings.moordyn else None
    if moordyn is not None:
        _add_moordyn_variables(writer, model.moorings)
        writer.set_attribute("moordyn", json.dumps(moordyn))
        for system in model.moorings.moordyn:
            note = system.step_note(model.dt)
            if note:
                warnings.append(note)
                log.warning("%s", note)
    return moordyn


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
