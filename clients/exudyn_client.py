"""Exudyn multibody client: owns the mechanism, exchanges state and forces with the force server.

Model (see shared/notes/exudyn-coupling.md for the measured facts behind it):

- the mechanism (bodies wet and dry, point masses, gravity/buoyancy, joints, constraints) is built by
  :mod:`hydrolink.clients.mechanism`: one ``NodeRigidBodyRxyz`` per body at its reference point (for
  a wet body the point the HDB's rotational modes refer to); its coordinates are displacements from equilibrium (xyz + Tait-Bryan angles, angle
  rates ≈ angular velocity for small angles) and ``ObjectRigidBody`` with the body's mass, its
  centre of mass relative to the reference point and the inertia moved there (parallel axes);
- no gravity: weight and buoyancy balance at equilibrium, the restoring stiffness (with its gravity
  terms) comes from the server;
- inactive DOFs locked to ground at equilibrium with coordinate constraints;
- ONE ``ObjectGenericODE2`` over the WET bodies' nodes (mapped by name to the server's setup): ``massMatrix`` = A∞ (added mass in the system mass
  matrix, never a lagged force), ``stiffnessMatrix`` = hydrostatic stiffness (implicit) and
  ``forceVector`` = excitation + radiation memory from the server, written once per step.

Timing: implicit integrators apply loads at the end of the step, so for t_k → t_{k+1} the server is
asked for F(t_{k+1}) with the predicted state (x + h v + h²/2 a, v + h a).

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

    @property
    def n_bodies(self) -> int:
        """Number of wet bodies (the server's bodies)."""
        return self.equilibrium.shape[0]

    def set_force(self, force: np.ndarray) -> None:
        """Write all wet bodies' hydrodynamic forces (6N) into the GenericODE2 in one call."""
        if int(self.hydro_object) >= 0:
            self.mbs.SetObjectParameter(self.hydro_object, "forceVector", force)

    def initialize(self) -> None:
        """Initialise the solver (initial accelerations use the force vector set now)."""
        self.solver.InitializeSolver(self.mbs, self.settings)
        self.initialized = True

    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """Displacements, velocities and accelerations of all system ODE2 coordinates (wet bodies'
        6N: ``wet_index``; every scene body: ``body_index``)."""
        sd = self.mbs.systemData
        return (np.asarray(sd.GetODE2Coordinates()), np.asarray(sd.GetODE2Coordinates_t()),
                np.asarray(sd.GetODE2Coordinates_tt()))

    def advance(self, t0: float, t1: float) -> None:
        """Integrate one step t0 → t1 with the force vector currently set."""
        it = self.solver.it
        it.startTime, it.endTime = t0, t1
        if not self.solver.SolveSteps(self.mbs, self.settings):
            raise RuntimeError(f"Exudyn solver failed on the step {t0:g} s -> {t1:g} s: "
                               f"{self.solver.GetErrorString()}")

    def mass_matrix(self) -> np.ndarray:
        """The system mass matrix over the body coordinates (6N × 6N), as the solver sees it."""
        if not self.initialized:
            self.initialize()
        self.solver.ComputeMassMatrix(self.mbs)
        i = self.wet_index
        return np.asarray(self.solver.GetSystemMassMatrix())[np.ix_(i, i)]

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


def build_model(scene: Scene, setup: dict | None, *, spectral_radius: float = 1.0) -> ExudynModel:
    """Build the Exudyn system from the scene (bodies, point masses, joints, constraints, initial
    state) and the server's setup (wet bodies by name, active DOFs, A∞, hydrostatic stiffness,
    equilibrium, net buoyancy, dt); ``setup`` None when no body is wet.

    ``spectral_radius`` of the generalized-alpha integrator: 1 (default) is the energy-conserving
    trapezoidal rule — no numerical damping of the lightly damped wave-body modes."""
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
    dt = float(setup.get("dt", scene.simulation.dt))
    net = {nm: float(v) for nm, v in zip(names, setup.get("net_buoyancy") or [None] * n) if v}

    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    mech = build_mechanism(mbs, scene, {nm: equilibrium[i, :3] for i, nm in enumerate(names)}, net)
    ptos = build_ptos(mbs, scene.ptos, mech.handles) if scene.ptos else None
    moorings = build_moorings(mbs, scene.moorings, mech.handles, scene.water) if scene.moorings else None
    hydro = -1
    if n:
        hydro = mbs.AddObject(ObjectGenericODE2(
            name="hydrodynamics", nodeNumbers=mech.rigid_nodes(names), massMatrix=a_inf,
            stiffnessMatrix=stiffness, forceVector=np.zeros(6 * n),
            visualization=VObjectGenericODE2(show=False)))
    mbs.Assemble()
    ltg = mbs.systemData.GetNodeLTGODE2
    all_names, reference = result_bodies(scene, setup)
    body_index = np.concatenate([np.asarray(ltg(mech.handles[nm].node), int) for nm in all_names])
    wet_index = (np.concatenate([np.asarray(ltg(mech.handles[nm].node), int) for nm in names])
                 if n else np.zeros(0, int))

    ss = exu.SimulationSettings()
    ss.solution.file.write = False
    ss.solution.sensors.active = False
    ss.timeIntegration.verboseMode = 0
    ss.timeIntegration.adaptiveStep = False
    ss.timeIntegration.numberOfSteps = 1
    ss.timeIntegration.endTime = dt
    ss.timeIntegration.generalizedAlpha.spectralRadius = float(spectral_radius)
    if len(mbs.systemData.GetODE2Coordinates()) > SPARSE_ABOVE:
        # large mechanisms (arrays of bodies + arms): Exudyn's default dense LU dominates the step;
        # measured on 9N9LA (108 body coordinates + 54 constraints): 9.8 -> 2.3 ms per step
        ss.linearSolverType = exu.LinearSolverType.EigenSparse
    return ExudynModel(sc, mbs, exu.MainSolverImplicitSecondOrder(), ss, hydro, equilibrium,
                       active, stiffness, dt, mech, wet_index, all_names, reference, body_index,
                       np.array([all_names.index(nm) for nm in names], int), ptos, moorings)


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


def run(scene: Scene, scene_text: str, connection, setup: dict | None, writer, *, progress: bool = True,
        spectral_radius: float | None = None, blow_up_limit: float = BLOW_UP_LIMIT) -> dict:
    """Run the lockstep co-simulation to ``scene.simulation.duration``.

    ``connection`` has already said hello (``setup`` is its reply); it is not closed here. With no
    wet body both are None and no server is asked. Rows hold every scene body (hydrodynamic forces
    zero for dry bodies) and, with joints, the joint outputs (see :mod:`hydrolink.clients.results`).
    Every step is written to ``writer`` (a :class:`~hydrolink.clients.results.ResultWriter`),
    which gets its final status ("complete" / "interrupted: ...") before this returns or raises.
    On Ctrl-C or a server error the rows computed so far are flushed and the error re-raised with
    the step and time named (KeyboardInterrupt stays a KeyboardInterrupt, server errors become
    :class:`RunInterrupted`, a blow-up :class:`SimulationDiverged`).

    Returns a summary: steps, time, wall_time, rows, status and per-step costs in µs
    (``client_us_per_step`` excludes the server round trip, ``round_trip_us_per_step`` is it)."""
    if spectral_radius is None:
        spectral_radius = scene.simulation.spectral_radius
    model = build_model(scene, setup, spectral_radius=spectral_radius)
    n, h = model.n_bodies, model.dt
    n_steps = int(round(scene.simulation.duration / h))
    eq = model.equilibrium.reshape(-1)
    stiffness = model.stiffness
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
    bar = _progress_bar(n_steps, progress and scene.simulation.progress)

    def request(k: int, tk: float, q: np.ndarray, v: np.ndarray, measurements: dict | None = None,
                timeout: float | None = None) -> tuple:
        nonlocal t_server
        if n == 0:
            return zeros, zeros, 0.0
        t0 = _time.perf_counter()
        try:
            reply = connection.step(k, tk, (eq + q).reshape(n, 6), v.reshape(n, 6),
                                    measurements=measurements, timeout=timeout) if control else \
                connection.step(k, tk, (eq + q).reshape(n, 6), v.reshape(n, 6))
            last["decisions"] = reply.get("control")
        except (KeyboardInterrupt, SimulationDiverged):
            raise
        except Exception as exc:
            raise RunInterrupted(
                f"force server error at step {k} (t = {tk:.6g} s): {exc}; the {k} rows before "
                f"it are saved in {getattr(writer, 'path', 'the results file')}",
                step=k, time=tk, rows=k) from exc
        t_server += _time.perf_counter() - t0
        return _forces(reply, n, k, tk)

    force_rows = np.zeros((3, nb, 6))

    def write(tk: float, q: np.ndarray, v: np.ndarray, exc_f, rad_f, eta) -> None:
        force_rows[0, rows], force_rows[1, rows] = exc_f, rad_f
        force_rows[2, rows] = -(stiffness @ q[wet]).reshape(n, 6)
        if joints:
            f, m, gap, rot = mech.joint_outputs(model.mbs)
            writer.stage_extra({"joint_force": np.hstack([f, m]), "joint_violation": gap,
                                "joint_rotation_violation": rot})
        if control is not None:
            control.stage()
        if ptos is not None:
            s = last["sample"] = ptos.sample(model.mbs)
            writer.stage_extra({"pto_force": s.force, "pto_velocity": s.velocity, "pto_power": s.power,
                                "total_pto_power": s.total_power})
        if moorings is not None:
            writer.stage_extra({"mooring_force": moorings.sample(model.mbs)})
        writer.append(tk, ref + q[bodies].reshape(nb, 6), v[bodies].reshape(nb, 6),
                      force_rows[0], force_rows[1], force_rows[2], eta)

    try:
        q, v, _ = model.state()
        _check_state(q, v, 0, 0.0, blow_up_limit, 0, "the initial state")
        exc_f, rad_f, eta = request(0, 0.0, q[wet], v[wet], timeout=(
            control.join_timeout + getattr(connection, "timeout", 30.0)) if control else None)
        model.set_force((exc_f + rad_f).reshape(-1))
        model.initialize()
        q, v, a = model.state()  # initial accelerations from F(0)
        write(0.0, q, v, exc_f, rad_f, eta)
        for step in range(1, n_steps + 1):
            t_prev, t = (step - 1) * h, step * h
            qw, vw, aw = q[wet], v[wet], a[wet]
            meas = None
            if control is not None and control.is_sample(step - 1):
                meas = control.measurements(step - 1, q[bodies].reshape(nb, 6), v[bodies].reshape(nb, 6),
                                            last["sample"])
            exc_f, rad_f, eta = request(step, t, qw + h * vw + 0.5 * h * h * aw, vw + h * aw, meas)
            if control is not None:
                control.apply(last["decisions"])
            model.set_force((exc_f + rad_f).reshape(-1))
            model.advance(t_prev, t)
            q, v, a = model.state()
            _check_state(q, v, step, t, blow_up_limit, step, "the body state")
            write(t, q, v, exc_f, rad_f, eta)
            bar.update(1)
    except KeyboardInterrupt:
        bar.close()
        writer.finish(f"interrupted: KeyboardInterrupt at step {step} (t = {t:.6g} s)")
        raise KeyboardInterrupt(
            f"run interrupted at step {step} (t = {t:.6g} s); {writer.rows_written} rows saved "
            f"in {getattr(writer, 'path', 'the results file')}") from None
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
    return {"controllers": controllers, "steps": n_steps, "time": n_steps * h, "wall_time": wall, "rows": writer.rows_written,
            "status": "complete", "mechanism_notes": (mech.warnings + mech.reductions) if mech else [],
            "client_us_per_step": (wall - t_server) / steps * 1e6,
            "round_trip_us_per_step": t_server / steps * 1e6}
