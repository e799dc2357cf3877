"""FMU master: a co-simulation FMU (FMI 2.0 or 3.0) as the multibody client of the force server.

The FMU owns the mechanism (bodies, PTO, ...); the master exchanges, once per time step ``dt``,
the bodies' state (FMU outputs) for the hydrodynamic forces (FMU inputs). Over a step t_k → t_k+1
the FMU input is held constant at the step average ½(F(t_k) + F(t_k+1)) — the trapezoidal rule —
with F(t_k+1) evaluated at the state the step ends in.

A∞ (see :mod:`hydrolink.clients.lockstep.relaxation`), per the scene's ``[coupling] scheme`` (the one
vocabulary of every client; the deprecated ``[client.coupling] mode`` is read as it, see
``protocol/scene.py`` MODE_SCHEME):

- ``mass-matrix``: every A∞ entry of the active DOFs goes into FMU parameters (``added_mass``
  mapping); F(t_k+1) is taken at a predicted state, one FMU step per time step (like the Exudyn
  client);
- ``implicit``: the A∞ not passed as parameters comes back as −A∞·ā (ā the step's mean
  acceleration); each step is iterated to a fixed point with rollback (get/set FMU state) and
  Aitken relaxation, the server's sample replaced at each iteration (SPEC §5.3 rule 2);
- ``explicit-predictor`` / ``explicit``: −A∞·ā of the previous step fed back, one pass — only on
  request and only when the spectral radius of M⁻¹A∞ is at most ``explicit_limit``; otherwise
  refused. Even then the one-step lag adds a spurious damping ≈ A∞·dt·ω² (measured: −4 % heave
  amplitude on the sphere at ratio 0.5, 100 steps per period);
- ``auto``: mass-matrix if the parameters cover A∞, else implicit if the FMU can roll back, else a
  refusal naming the reasons (never explicit).
"""

from __future__ import annotations

import shutil
import tempfile
import time as _time
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Any, Sequence

import numpy as np

from hydrolink.clients.lockstep import driver as lockstep
from hydrolink.clients.lockstep.relaxation import added_mass_ratio
from hydrolink.server.rigid_body import rigid_body_mass_matrix
from hydrolink.clients.lockstep.coupling_schemes import make_scheme
from hydrolink.protocol.pacing import Pacer
from hydrolink.clients.lockstep.driver import BLOW_UP_LIMIT, DivergenceWatch, ForceLink, Lockstep, progress_bar
from hydrolink.clients.lockstep.preflight import preflight
from hydrolink.clients.lockstep.summary import CouplingReport, RunSummary
from hydrolink.protocol.scene import DOF_NAMES, Coupling, FMUClient, Scene, SceneError, resolve_path
from hydrolink.protocol.setup import Setup

COMPONENTS = ("excitation", "radiation", "hydrostatic")
PORT_KINDS = ("force",) + COMPONENTS
ZERO = 1e-9          # relative size below which a matrix entry counts as zero


# ------------------------------------------------------------------------------------ the FMU

class FMUInstance:
    """An extracted and instantiated co-simulation FMU; ``slave`` is its version's adapter."""

    def __init__(self, path: str | Path, instance_name: str = "hydrolink"):
        from fmpy import extract, read_model_description

        self.path = Path(path)
        if not self.path.is_file():
            raise FileNotFoundError(f"FMU not found: {self.path}")
        self.md = read_model_description(str(self.path))
        if self.md.coSimulation is None:
            raise ValueError(f"{self.path.name} is not a co-simulation FMU (model exchange only)")
        self.variables = {v.name: v for v in self.md.modelVariables}
        self._dir = tempfile.mkdtemp(prefix="hydrolink-fmu-")
        try:
            extract(str(self.path), unzipdir=self._dir)
            if self.md.fmiVersion.startswith("3"):
                from hydrolink.clients.fmu.fmi3 import FMI3Slave as Slave
            elif self.md.fmiVersion.startswith("2"):
                from hydrolink.clients.fmu.fmi2 import FMI2Slave as Slave
            else:
                raise ValueError(f"{self.path.name}: FMI {self.md.fmiVersion} is not supported (2.0, 3.0)")
            self.slave = Slave(self.md, self._dir, instance_name)
        except BaseException:
            shutil.rmtree(self._dir, ignore_errors=True)
            raise

    @property
    def fmi_version(self) -> str:
        return self.md.fmiVersion

    def variable(self, name: str, key: str, causalities: Sequence[str], real: bool = True) -> Any:
        """The model variable ``name`` (SceneError naming ``key`` if absent or of the wrong kind)."""
        v = self.variables.get(name)
        if v is None:
            raise SceneError("scene", key, f"the FMU {self.path.name} has no variable {name!r}")
        if v.causality not in causalities:
            raise SceneError("scene", key, f"FMU variable {name!r} has causality {v.causality!r}, "
                                           f"expected {' or '.join(causalities)}")
        if real and v.type not in ("Real", "Float64"):
            raise SceneError("scene", key, f"FMU variable {name!r} is {v.type}, expected a real")
        return v

    def close(self) -> None:
        try:
            self.slave.close()
        finally:
            shutil.rmtree(self._dir, ignore_errors=True)

    def __enter__(self) -> "FMUInstance":
        return self

    def __exit__(self, *exc: Any) -> None:
        self.close()


# ------------------------------------------------------------------------------------ the plan

@dataclass
class Wiring:
    """FMU variables and matrices over the active DOFs (in setup order, body-major)."""

    active: np.ndarray              # flat indices into 6N of the active DOFs
    labels: list[str]               # "body.dof" per active DOF
    position_vrs: list[int]
    velocity_vrs: list[int]
    port_vrs: list[int]             # FMU inputs
    port_dof: np.ndarray            # active-DOF index of each input
    port_kind: list[str]            # "force" | "excitation" | "radiation" | "hydrostatic"
    parameters: list[tuple[Any, Any, str]]   # (variable, value, scene key)
    a_rest: np.ndarray              # A∞ not passed to the FMU (n_a × n_a): fed back as −A·ā
    c_passed: np.ndarray            # hydrostatic stiffness the FMU applies itself
    mass: np.ndarray                # rigid-body + passed added mass (n_a × n_a), from the scene
    net_buoyancy: np.ndarray        # constant rho g V - m g on active heave DOFs (as the Exudyn client)


@dataclass
class Plan:
    scheme: str                     # resolved [coupling] scheme: "mass-matrix" | "implicit" | "explicit*"
    reason: str
    ratio: float                    # spectral radius of M⁻¹ A_rest


def _pairs(mapping: dict[str, str], body: int, key: str) -> list[tuple[int, int, str, str]]:
    """(row, col, variable, scene key) in 6N indices for "dof" / "dof,dof" keys."""
    out = []
    for dofs, name in mapping.items():
        a, _, b = dofs.partition(",")
        i, j = 6 * body + DOF_NAMES.index(a), 6 * body + DOF_NAMES.index(b or a)
        out.append((i, j, name, f"{key}.{dofs}"))
    return out


def wire(fmu: FMUInstance, scene: Scene, setup: Setup) -> Wiring:
    """Resolve the scene's variable mapping against the FMU and the server's setup."""
    client: FMUClient = scene.client
    names = list(setup.bodies)
    n = len(names)
    active = np.flatnonzero(setup.active.reshape(6 * n))
    where = {int(k): i for i, k in enumerate(active)}
    a_inf = setup.added_mass        # A(w0) with radiation "constant"
    c_full = setup.hydrostatic_stiffness
    eq = setup.equilibrium_position
    by_name = {b.name: b for b in scene.bodies}
    labels = [f"{names[k // 6]}.{DOF_NAMES[k % 6]}" for k in active]

    pos, vel, ports, kinds, params = [], [], [], [], []
    a_pass, c_pass = np.zeros((6 * n, 6 * n)), np.zeros((6 * n, 6 * n))
    mass = np.zeros((6 * n, 6 * n))
    for b, name in enumerate(names):
        m, body, base = client.bodies[name], by_name[name], f"client.bodies.{name}"
        mass[6 * b:6 * b + 6, 6 * b:6 * b + 6] = rigid_body_mass_matrix(
            body.mass, body.inertia_matrix, body.com_or(eq[b, :3]) - eq[b, :3])
        for k in active[active // 6 == b]:
            d = DOF_NAMES[k % 6]
            pos.append(fmu.variable(m.position[d], f"{base}.position.{d}", ("output",)).valueReference)
            vel.append(fmu.variable(m.velocity[d], f"{base}.velocity.{d}", ("output",)).valueReference)
            for kind in PORT_KINDS:
                var = getattr(m, kind).get(d)
                if var is not None:
                    ports.append((fmu.variable(var, f"{base}.{kind}.{d}", ("input",)).valueReference,
                                  where[int(k)]))
                    kinds.append(kind)
        for target, mapping, key in ((a_pass, m.added_mass, "added_mass"),
                                     (c_pass, m.hydrostatic_stiffness, "hydrostatic_stiffness")):
            full = a_inf if target is a_pass else c_full
            for i, j, var, skey in _pairs(mapping, b, f"{base}.{key}"):
                if i not in where or j not in where:
                    raise SceneError("scene", skey, "names an inactive DOF")
                if abs(full[i, j] - full[j, i]) > ZERO * max(np.abs(full).max(), 1.0):
                    raise SceneError("scene", skey, f"the matrix is not symmetric here ({full[i, j]:.6g} vs "
                                                    f"{full[j, i]:.6g}): one parameter cannot hold both")
                target[i, j] = target[j, i] = full[i, j]
                params.append((fmu.variable(var, skey, ("parameter",)), float(full[i, j]), skey))
    sub = np.ix_(active, active)
    a_rest = (a_inf - a_pass)[sub]
    a_rest[np.abs(a_rest) <= ZERO * max(np.abs(a_inf[sub]).max(initial=0.0), 1e-300)] = 0.0
    c_rest = (c_full - c_pass)[sub]
    port_dof = np.array([p[1] for p in ports], int)
    net = np.zeros(6 * n)
    net[2::6] = setup.net_buoyancy
    for i, label in enumerate(labels):
        own = {kinds[j] for j in np.flatnonzero(port_dof == i)}
        needed = {"excitation", "radiation"} | ({"hydrostatic"} if np.any(c_rest[i]) or net[active[i]] else set())
        if "force" not in own and not needed <= own:
            body, d = label.split(".")
            missing = sorted(needed - own)
            raise SceneError("scene", f"client.bodies.{body}.{missing[0]}.{d}",
                             f"no FMU input for the {missing[0]} force of {label} (map force, or every component)")
    return Wiring(active, labels, pos, vel, [p[0] for p in ports], port_dof, kinds, params, a_rest,
                  c_pass[sub], (mass + a_pass)[sub], net[active])


def plan(wiring: Wiring, coupling: Coupling, can_roll_back: bool, *, allow_unstable: bool = False) -> Plan:
    """Resolve ``[coupling] scheme`` for this FMU, or refuse (SceneError naming coupling.scheme and why)."""
    scheme, limit = coupling.scheme, coupling.explicit_limit
    ratio = added_mass_ratio(wiring.mass, wiring.a_rest)
    covered = not np.any(wiring.a_rest)
    uncovered = [f"{wiring.labels[i]}/{wiring.labels[j]}" for i, j in zip(*np.nonzero(wiring.a_rest))]
    no_rollback = "the FMU cannot roll back (canGetAndSetFMUstate is false)"
    unstable = (f"explicit coupling with −A∞·a fed back is unstable or not provably stable here: the "
                f"added-mass ratio (spectral radius of M⁻¹A∞) is {ratio:.3g} > explicit_limit {limit:g}")
    key = "coupling.scheme"
    if scheme == "mass-matrix" and not covered:
        raise SceneError("scene", key, f"A∞ entries {uncovered} are not mapped to FMU parameters "
                                       "(client.bodies.<body>.added_mass)")
    if scheme == "implicit" and not can_roll_back:
        raise SceneError("scene", key, f"implicit coupling needs rollback, but {no_rollback}")
    if scheme in ("explicit", "explicit-predictor") and ratio > limit and not allow_unstable:
        raise SceneError("scene", key, f"refused: {unstable}")
    if scheme == "auto":
        if covered:
            scheme = "mass-matrix"
        elif can_roll_back:
            scheme = "implicit"
        else:   # never explicit by default: stable at best, and first order in the added-mass force
            why = unstable if ratio > limit else (
                f"scheme = \"explicit-predictor\" would be stable here (ratio {ratio:.3g} ≤ {limit:g}) but lags "
                "the added-mass force by one step (spurious damping ≈ A∞·dt·ω²): set it to accept that")
            raise SceneError("scene", key, f"refused to run: A∞ is not passed to the FMU (no added_mass "
                                           f"parameters for {uncovered}), {no_rollback}, and {why}")
    reason = {"mass-matrix": "A∞ passed to FMU parameters",
              "implicit": f"A∞ fed back and iterated with rollback (ratio {ratio:.3g})",
              "explicit-predictor": f"A∞ fed back explicitly, forces at the predicted state (ratio {ratio:.3g} ≤ {limit:g})",
              "explicit": f"A∞ fed back explicitly, forces of the step's start held (ratio {ratio:.3g} ≤ {limit:g})"
              }[scheme]
    return Plan(scheme, reason, ratio)


# ------------------------------------------------------------------------------------ the run

def run(scene: Scene, scene_text: str, connection, setup: Setup, writer, *,
        scene_path: str | Path = "scene.toml", progress: bool = True,
        blow_up_limit: float = BLOW_UP_LIMIT, record: Sequence[str] = (),
        allow_unstable: bool = False, realtime: float | None = None, rt_priority: int | None = None) -> RunSummary:
    """Run the scene's FMU in lockstep with the server to ``scene.simulation.duration``.

    Like :func:`hydrolink.clients.exudyn.client.run` (same results rows, same errors, the same
    driver: :mod:`hydrolink.clients.lockstep.driver`); ``record`` names further FMU real outputs whose values
    at every step are returned in ``summary.recorded``; ``allow_unstable`` lets the explicit mode
    run beyond its limit (only to demonstrate the instability). The summary adds mode, iterations per
    step (mean, max) and per-step costs in µs (FMU calls, server round trips, the rest). ``realtime``:
    pace the exchanges at FACTOR x wall clock (:mod:`hydrolink.protocol.pacing`); ``rt_priority``: the
    exchanges under ``SCHED_FIFO`` at that priority (the driver's ``rt_priority``)."""
    client: FMUClient = scene.client
    if not isinstance(client, FMUClient):
        raise SceneError("scene", "client.type", "the FMU master needs [client] type = \"fmu\"")
    pre = preflight(scene, setup, writer, "fmu_master")
    h = setup.dt
    hc = client.communication_step or h
    n_sub = int(round(h / hc))
    if n_sub < 1 or abs(n_sub * hc - h) > 1e-9 * h:
        raise SceneError("scene", "client.communication_step",
                         f"must divide simulation.dt = {h:g} s into whole steps (got {hc:g} s)")
    with FMUInstance(resolve_path(scene_path, client.fmu)) as fmu:
        mb = FMUMultibody(scene, client, fmu, setup, writer, h, n_sub, record, allow_unstable)
        try:
            mb.initialize()
            loop = Lockstep(mb, ForceLink(connection, setup, writer), writer, DivergenceWatch(blow_up_limit),
                            bar=progress_bar(pre.n_steps, progress and scene.simulation.progress,
                                             "hydrolink run (fmu)"))
            cpl = scene.coupling
            scheme = make_scheme(mb.plan.scheme, tolerance=cpl.tolerance, max_iterations=cpl.max_iterations,
                                 ratio=mb.plan.ratio, n_exchanges=pre.n_exchanges)
            coupling = CouplingReport(scheme=mb.plan.scheme, reason=mb.plan.reason, added_mass_ratio=mb.plan.ratio)
            out = lockstep.run(loop, scheme, pre.n_exchanges, coupling,
                               hint=lambda exc: f"coupling.scheme = \"{mb.plan.scheme}\"",
                               pacer=None if realtime is None else Pacer(pre.exchange_dt, realtime),
                               rt_priority=rt_priority)
        finally:
            mb.close()
    return replace(out, client="fmu", fmi_version=fmu.fmi_version, warnings=pre.warnings,
                   fmu_us_per_step=mb.t_fmu / max(out.steps, 1) * 1e6,
                   recorded={name: np.array([r[i] for r in mb.recorded]) for i, name in enumerate(mb.record)})


class FMUMultibody:
    """The FMU as the lockstep driver's multibody code (:class:`~hydrolink.clients.lockstep.driver.Multibody`).

    Its inputs are the FMU's force ports, held over the step at the step average ½(F(t_k) + F(t_k+1))
    (the trapezoidal rule), component by component, with the A∞ it does not take as parameters fed
    back as −A·ā (ā the step's mean acceleration) and the stiffness it applies itself removed."""

    label = "the FMU state"
    substeps = 1

    def __init__(self, scene, client, fmu, setup, writer, h, n_sub, record, allow_unstable):
        self.scene, self.client, self.fmu, self.writer = scene, client, fmu, writer
        self.h, self.n_sub = h, n_sub
        n = self.n = setup.n
        self.eq = setup.equilibrium_position.reshape(6 * n)
        self.w = wire(fmu, scene, setup)
        self.plan = plan(self.w, scene.coupling, fmu.slave.can_rollback, allow_unstable=allow_unstable)
        self.record_vrs = [fmu.variable(r, f"record[{r}]", ("output", "local")).valueReference for r in record]
        self.record = list(record)
        self.absolute = client.positions == "absolute"
        self.out_vrs = self.w.position_vrs + self.w.velocity_vrs + self.record_vrs
        self.t_fmu = 0.0
        self.recorded: list[np.ndarray] = []
        self._saved = None
        self._pos, self._vel = self.eq.copy(), np.zeros(6 * n)      # scratch: active DOFs scattered to 6N
        self._x = self._v = self._rec = self._abar = None

    def initialize(self) -> None:
        """Parameters (A∞/stiffness mappings and [client.parameters]) in, initialisation, first read."""
        slave = self.fmu.slave
        for var, value, key in self.w.parameters:
            slave.set_value(var, value)
        for name, value in self.client.parameters.items():
            var = self.fmu.variables.get(name)
            if var is None or var.causality not in ("parameter", "input"):
                raise SceneError("scene", f"client.parameters.{name}",
                                 f"the FMU {self.fmu.path.name} has no parameter {name!r}")
            slave.set_value(var, value)
        slave.initialize()
        self._read()
        self._abar = np.zeros_like(self._v)
        self._check_initial(self._x, self._v)

    def close(self) -> None:
        if self._saved is not None:
            self.fmu.slave.free_state(self._saved)
            self._saved = None

    def _read(self) -> None:
        t0 = _time.perf_counter()
        out = np.asarray(self.fmu.slave.get_real(self.out_vrs), float)
        self.t_fmu += _time.perf_counter() - t0
        na = len(self.w.active)
        x, v = out[:na], out[na:2 * na]
        self._x = x - self.eq[self.w.active] if self.absolute else x
        self._v, self._rec = v, out[2 * na:]

    def _scatter(self, x: np.ndarray, out: np.ndarray) -> np.ndarray:
        out[:] = 0.0
        out[self.w.active] = x
        return out

    # -- the driver's interface -------------------------------------------------------------
    def begin(self, s0, feedback: bool) -> int:
        return 0

    def state(self) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """6N displacement and velocity, and the mean acceleration of the last step (active DOFs
        scattered; the acceleration stays over the active DOFs, as the feedback matrix)."""
        return self._scatter(self._x, np.zeros(6 * self.n)), self._scatter(self._v, np.zeros(6 * self.n)), \
            self._scatter(self._abar, np.zeros(6 * self.n))

    def extent(self, limit: float) -> float:
        return max(float(np.abs(self._x).max(initial=0.0)), float(np.abs(self._v).max(initial=0.0)))

    def inputs(self, s0, s1, acc, x0, x1) -> np.ndarray:
        """FMU inputs over the step: component averages, A_rest·ā and the passed stiffness removed."""
        a = self.w.active
        exc = 0.5 * (s0.excitation[a] + s1.excitation[a])
        rad = 0.5 * (s0.radiation[a] + s1.radiation[a])
        if acc is not None:
            rad = rad - self.w.a_rest @ acc[a]
        hs = (0.5 * (s0.hydrostatic[a] + s1.hydrostatic[a]) + self.w.c_passed @ (0.5 * (x0[a] + x1[a]))
              + self.w.net_buoyancy)
        parts = {"excitation": exc, "radiation": rad, "hydrostatic": hs, "force": exc + rad + hs}
        return np.array([parts[kind][i] for kind, i in zip(self.w.port_kind, self.w.port_dof)])

    def advance(self, t0: float, t1: float, u: np.ndarray) -> None:
        t_start = _time.perf_counter()
        slave, hc = self.fmu.slave, self.h / self.n_sub
        slave.set_real(self.w.port_vrs, u.tolist())
        for s in range(self.n_sub):
            slave.do_step(t0 + s * hc, hc, may_roll_back=self.plan.scheme == "implicit")
        self.t_fmu += _time.perf_counter() - t_start
        v0 = self._v
        self._read()
        self._abar = (self._v - v0) / self.h

    def save(self):
        self._saved = self.fmu.slave.save_state(self._saved)
        return self._x, self._v, self._rec, self._abar

    def restore(self, saved) -> None:
        self.fmu.slave.restore_state(self._saved)
        self._x, self._v, self._rec, self._abar = saved

    def snapshot(self):
        return self._x, self._v, self._rec

    def write(self, t: float, s, snap) -> None:
        x, v, rec = snap
        shape = (self.n, 6)
        pos = self.eq.copy()
        pos[self.w.active] += x
        self.writer.append(t, pos.reshape(shape), self._scatter(v, np.zeros(6 * self.n)).reshape(shape),
                           s.excitation.reshape(shape), s.radiation.reshape(shape), s.hydrostatic.reshape(shape),
                           s.eta)
        self.recorded.append(rec)

    def measurements(self, step: int) -> None:
        return None

    def apply_control(self, decisions) -> None:
        pass

    def _check_initial(self, x: np.ndarray, v: np.ndarray) -> None:
        """The FMU's initial state must be the scene's (the scene cannot set FMU states)."""
        by_name = {b.name: (i, b) for i, b in enumerate(self.scene.bodies)}
        for got, what in ((x, "initial_displacement"), (v, "initial_velocity")):
            for j, label in enumerate(self.w.labels):
                body, d = label.split(".")
                i, b = by_name[body]
                want = getattr(b, what)[DOF_NAMES.index(d)]
                if abs(got[j] - want) > 1e-9 * max(1.0, abs(want)):
                    raise SceneError("scene", f"bodies[{i}].{what}",
                                     f"the FMU starts at {d} = {got[j]:.6g} but the scene says {want:.6g}; "
                                     f"set the FMU's initial state with [client.parameters]")
