"""Moorings in Exudyn: linear 6×6 springs to ground and 3D ropes of ANCF cable elements.

``LinearMooring``
    ``ObjectConnectorRigidBodySpringDamper`` from a ground marker (marker 0) to a body marker
    (marker 1), both at ``point`` with the global axes: generalised force on the body about the point
    ``-K [Δx; θ] - D [Δv; Δω]`` (Δx the point's displacement, θ the Tait-Bryan xyz angles of the body
    relative to ground, global frame). ``pretension`` (force, moment about the point, global) is
    what the mooring exerts at zero displacement: a constant ``LoadForceVector`` +
    ``LoadTorqueVector`` (global directions). A dry body on it alone settles at ``K⁻¹ pretension``.

``RopeMooring``
    ``elements`` ``ObjectANCFCable`` (3D, ``NodePointSlope1``) of length ``length/elements``; the
    reference configuration is the unstretched straight rope from the anchor towards the attachment.
    Anchor node: ``ObjectJointSpherical`` to ground; last node: ``ObjectJointSpherical`` to the body /
    point mass marker. Submerged weight per metre ``(μ - ρ π d²/4) g`` as a ``LoadMassProportional``
    per element (the whole rope counts as submerged). Internal strain-rate damping gives 2 % of
    critical on the first fixed-fixed axial mode (more on higher modes: quiets element-level ringing).
    ``bending_stiffness`` 0 means ``1e-3 w h³`` (w submerged weight per metre, h element length):
    negligible against gravity over an element, enough to keep slack ropes regular.
    Seabed (finite depth, ``seabed = true``): one ``ObjectContactCoordinate`` per free node on its z
    coordinate — a frictionless penalty spring-damper, active only below z = -depth, stiffness
    such that a node's own submerged weight sinks it ``SEABED_PENETRATION`` m, 10 % critical damping
    (Exudyn's native discontinuous-iteration contact; no Python user function). Slack ropes on the
    seabed need numerical damping in the dynamic run (generalized-alpha spectral radius < 1, e.g.
    0.8) and moderate motions; with the trapezoidal rule (spectral radius 1) Newton fails after a
    few steps of a moving touchdown. A rope longer than (horizontal span + height) cannot be laid
    out without slack piling on the bed and is not supported.
    Initial shape: a catenary through anchor and attachment with the unstretched length (clipped at
    the seabed), or the straight stretched line when the rope is taut; then Exudyn's static solver
    finds the rope's equilibrium with both ends held (in a separate small system) and the main
    system starts from it — the rope does not snap. The bodies start where the scene says; the
    rope's tension then acts on them from t = 0.

``MoorDynMooring``
    A MoorDyn v2 system (clients/exudyn/moordyn_mooring.py) acting on one or more scene bodies: per coupled
    body a ``LoadForceVector`` and a ``LoadTorqueVector`` (global directions) at its reference point,
    set every step from MoorDyn's forces (:meth:`MooringSet.step_moordyn`, called by the Exudyn
    adapter before each step: loads act at the step's end, so they are MoorDyn's forces at t_k+1).

Outputs: ``MooringSet.sample(mbs)`` → (n_entries, 6): force (N) and moment (N m) the mooring exerts
on the body, global frame, moment about the mooring point (linear) / attachment point (rope: zero) /
the body's reference point (MoorDyn: one entry per coupled body, named "mooring:body" when the
system couples several bodies).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

import exudyn as exu
from exudyn.itemInterface import (LoadForceVector, LoadMassProportional, LoadTorqueVector,
                                  MarkerBodyMass, MarkerNodeCoordinate, MarkerNodePosition,
                                  NodeGenericData, NodePointGround, NodePointSlope1, ObjectANCFCable,
                                  ObjectConnectorRigidBodySpringDamper, ObjectContactCoordinate,
                                  ObjectGround, ObjectJointSpherical, VObjectANCFCable,
                                  VObjectConnectorRigidBodySpringDamper, VObjectContactCoordinate,
                                  VObjectJointSpherical)

from hydrolink.clients.exudyn.mechanism import BodyHandle, marker_at
from hydrolink.protocol.current import Current
from hydrolink.protocol.scene import LinearMooring, MoorDynMooring, RopeMooring, SceneError, Water

_OV = exu.OutputVariableType
#: static seabed penetration of a rope node under its own submerged weight (m)
SEABED_PENETRATION = 1e-3


def matrix6(value) -> np.ndarray:
    """A 6×6 matrix from a diagonal (6 values) or a 6×6 table."""
    a = np.asarray(value, float)
    return np.diag(a) if a.ndim == 1 else a


def mooring_label(mooring, i: int) -> str:
    return mooring.name or f"moorings[{i}]"


# -- rope geometry -------------------------------------------------------------------------------
def catenary_guess(anchor, attach, length: float, n: int, seabed_z: float = -math.inf
                   ) -> tuple[np.ndarray, np.ndarray]:
    """Node positions (n+1, 3) and unit tangents of an inextensible catenary of ``length`` from
    ``anchor`` to ``attach`` (equal arc length spacing), raised to ``seabed_z`` where below it.
    A rope no longer than the chord is the straight line (stretched)."""
    a, b = np.asarray(anchor, float), np.asarray(attach, float)
    chord = b - a
    dist = float(np.linalg.norm(chord))
    horiz = chord.copy()
    horiz[2] = 0.0
    span, rise = float(np.linalg.norm(horiz)), float(chord[2])
    s = np.linspace(0.0, 1.0, n + 1)
    if length <= dist * (1 + 1e-9) or span < 1e-6 * length:
        if length <= dist * (1 + 1e-9):
            pos = a + s[:, None] * chord
            tangent = np.tile(chord / dist, (n + 1, 1))
            return pos, tangent
        # (nearly) vertical slack rope: hang down from the higher end, fold at the bottom
        top, low = (a, b) if a[2] >= b[2] else (b, a)
        drop = 0.5 * (length + (top[2] - low[2]))
        arc = s * length if a[2] >= b[2] else (1 - s) * length
        z = np.where(arc <= drop, top[2] - arc, top[2] - drop + (arc - drop))
        pos = np.column_stack([np.full(n + 1, a[0]), np.full(n + 1, a[1]), z])
        pos[:, 2] = np.maximum(pos[:, 2], seabed_z)
        return pos, _tangents(pos)
    ex = horiz / span
    # sqrt(L² - rise²) = 2 c sinh(span / (2 c)): solve for the catenary parameter c by bisection on log c
    target = math.sqrt(length * length - rise * rise)
    lo, hi = math.log(span * 1e-4), math.log(span * 1e4)
    for _ in range(200):
        mid = 0.5 * (lo + hi)
        c = math.exp(mid)
        val = 2 * c * math.sinh(min(span / (2 * c), 700.0))
        lo, hi = (mid, hi) if val > target else (lo, mid)
    c = math.exp(0.5 * (lo + hi))
    # z(x) = c cosh((x - x0)/c) + z0 through (0, 0) and (span, rise)
    x0 = span / 2 - c * math.asinh(rise / (2 * c * math.sinh(span / (2 * c))))
    s0 = c * math.sinh(-x0 / c)                      # arc-length coordinate of the anchor
    x = x0 + c * np.arcsinh((s0 + s * length) / c)
    z = c * (np.cosh((x - x0) / c) - math.cosh(x0 / c))
    pos = a + x[:, None] * ex + z[:, None] * np.array([0.0, 0.0, 1.0])
    if pos[:, 2].min() < seabed_z and abs(a[2] - seabed_z) <= 1e-6 * length:
        touchdown = _touchdown(a, ex, span, rise, length, s)
        if touchdown is not None:
            pos = touchdown
    pos[:, 2] = np.maximum(pos[:, 2], seabed_z)
    return pos, _tangents(pos)


def _touchdown(a: np.ndarray, ex: np.ndarray, span: float, rise: float, length: float,
               s: np.ndarray) -> np.ndarray | None:
    """Rope from an anchor on the seabed: a straight part on the bed, then a catenary with a
    horizontal tangent at the touchdown point; None if the rope does not touch down."""
    def suspended(c: float) -> tuple[float, float]:
        ls = math.sqrt(rise * rise + 2 * rise * c)
        return ls, c * math.asinh(ls / c)

    def gap(c: float) -> float:           # bed length + horizontal extent of the hanging part - span
        ls, x = suspended(c)
        return length - ls + x - span

    c_lo, c_hi = 1e-9 * length, (length * length - rise * rise) / (2 * rise)
    if rise <= 0 or gap(c_lo) >= 0 or gap(c_hi) <= 0:
        return None            # too long to hang with a horizontal touchdown, or never touching
    for _ in range(200):
        mid = math.sqrt(c_lo * c_hi)
        c_lo, c_hi = (c_lo, mid) if gap(mid) > 0 else (mid, c_hi)
    c = math.sqrt(c_lo * c_hi)
    bed = length - suspended(c)[0]
    arc = s * length
    hang = np.maximum(arc - bed, 0.0)
    x = np.where(arc <= bed, arc, bed + c * np.arcsinh(hang / c))
    z = np.sqrt(c * c + hang * hang) - c
    return a + x[:, None] * ex + z[:, None] * np.array([0.0, 0.0, 1.0])


def _tangents(pos: np.ndarray) -> np.ndarray:
    t = np.gradient(pos, axis=0)
    norm = np.linalg.norm(t, axis=1, keepdims=True)
    return t / np.where(norm > 0, norm, 1.0)


# -- rope items ------------------------------------------------------------------------------------
@dataclass
class RopeItems:
    nodes: list[int]
    elements: list[int]
    contacts: list[int]
    anchor_joint: int
    end_marker: int           # position marker on the last node
    reference: np.ndarray     # (n+1, 6) reference coordinates of the nodes


def rope_properties(rope: RopeMooring, water: Water) -> dict[str, float]:
    """Derived rope numbers: submerged weight per metre, EI used, axial damping, seabed contact."""
    g, n = water.gravity, rope.elements
    h = rope.length / n
    w = (rope.mass_per_length - water.density * math.pi * rope.diameter ** 2 / 4) * g
    ei = rope.bending_stiffness or 1e-3 * max(abs(w), 1e-3 * rope.mass_per_length * g) * h ** 3
    omega1 = math.pi / rope.length * math.sqrt(rope.axial_stiffness / rope.mass_per_length)
    axial_damping = 2 * 0.02 * rope.axial_stiffness / omega1
    node_weight = max(abs(w), 0.1 * rope.mass_per_length * g) * h
    k_sb = node_weight / SEABED_PENETRATION
    d_sb = 2 * 0.1 * math.sqrt(k_sb * rope.mass_per_length * h)
    return {"weight_per_length": w, "bending_stiffness": ei, "axial_damping": axial_damping,
            "seabed_stiffness": k_sb, "seabed_damping": d_sb, "element_length": h}


def add_rope(mbs, rope: RopeMooring, water: Water, ground: int, initial: np.ndarray | None = None,
             attach=None) -> RopeItems:
    """Nodes, cable elements, submerged weight, seabed contacts and the anchor joint of ``rope``
    (``ground``: a ground object index). ``initial``: node coordinates (n+1, 6) to start from
    (default: the catenary guess); ``attach``: attachment point (global, t = 0)."""
    n, props = rope.elements, rope_properties(rope, water)
    h = props["element_length"]
    anchor = np.asarray(rope.anchor, float)
    attach = np.asarray(attach, float)
    direction = attach - anchor
    dist = float(np.linalg.norm(direction))
    if dist < 1e-9:
        raise ValueError("anchor and attachment coincide")
    direction /= dist
    ref = np.zeros((n + 1, 6))
    ref[:, :3] = anchor + np.outer(np.arange(n + 1) * h, direction)
    ref[:, 3:] = direction
    depth = water.depth_m
    seabed_z = -depth if (rope.seabed and math.isfinite(depth)) else -math.inf
    if initial is None:
        pos, tangent = catenary_guess(anchor, attach, rope.length, n, seabed_z)
        stretch = max(1.0, float(np.linalg.norm(attach - anchor)) / rope.length)
        initial = np.hstack([pos, tangent * stretch])
    nodes = [mbs.AddNode(NodePointSlope1(referenceCoordinates=ref[i].tolist(),
                                         initialCoordinates=(initial[i] - ref[i]).tolist()))
             for i in range(n + 1)]
    elements, loads = [], []
    for i in range(n):
        e = mbs.AddObject(ObjectANCFCable(
            nodeNumbers=[nodes[i], nodes[i + 1]], length=h, massPerLength=rope.mass_per_length,
            axialStiffness=rope.axial_stiffness, bendingStiffness=props["bending_stiffness"],
            axialDamping=props["axial_damping"], visualization=VObjectANCFCable(show=False)))
        elements.append(e)
        g_eff = props["weight_per_length"] / rope.mass_per_length
        m = mbs.AddMarker(MarkerBodyMass(bodyNumber=e, visualization={"show": False}))
        loads.append(mbs.AddLoad(LoadMassProportional(markerNumber=m, loadVector=[0.0, 0.0, -g_eff])))
    contacts = []
    if math.isfinite(seabed_z):
        gnode = mbs.AddNode(NodePointGround(referenceCoordinates=[0.0, 0.0, 0.0]))
        gmarker = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=gnode, coordinate=2, visualization={"show": False}))
        for i in range(1, n + 1):   # data coordinate = gap: nodes starting on the bed are in contact
            data = mbs.AddNode(NodeGenericData(initialCoordinates=[float(initial[i, 2] - seabed_z)],
                                               numberOfDataCoordinates=1))
            mz = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=nodes[i], coordinate=2, visualization={"show": False}))
            contacts.append(mbs.AddObject(ObjectContactCoordinate(
                markerNumbers=[gmarker, mz], nodeNumber=data, contactStiffness=props["seabed_stiffness"],
                contactDamping=props["seabed_damping"], offset=float(seabed_z - ref[i, 2]),
                visualization=VObjectContactCoordinate(show=False))))
    ma = mbs.AddMarker(MarkerNodePosition(nodeNumber=nodes[0], visualization={"show": False}))
    mg = mbs.AddMarker(_ground_position_marker(ground, anchor))
    anchor_joint = mbs.AddObject(ObjectJointSpherical(markerNumbers=[mg, ma],
                                                      visualization=VObjectJointSpherical(show=False)))
    end_marker = mbs.AddMarker(MarkerNodePosition(nodeNumber=nodes[-1], visualization={"show": False}))
    return RopeItems(nodes, elements, contacts, anchor_joint, end_marker, ref)


def _ground_position_marker(ground: int, point):
    from exudyn.itemInterface import MarkerBodyPosition
    return MarkerBodyPosition(bodyNumber=ground, localPosition=[float(x) for x in point],
                              visualization={"show": False})


def rope_equilibrium(rope: RopeMooring, water: Water, attach) -> np.ndarray:
    """Static equilibrium of the rope alone with both ends held (anchor; attachment at ``attach``):
    node coordinates (n+1, 6), from Exudyn's static solver started at the catenary guess."""
    sc = exu.SystemContainer()
    mbs = sc.AddSystem()
    ground = mbs.AddObject(ObjectGround(referencePosition=[0.0, 0.0, 0.0]))
    items = add_rope(mbs, rope, water, ground, attach=attach)
    mend = mbs.AddMarker(_ground_position_marker(ground, attach))
    mbs.AddObject(ObjectJointSpherical(markerNumbers=[mend, items.end_marker],
                                       visualization=VObjectJointSpherical(show=False)))
    mbs.Assemble()
    start = np.asarray(mbs.systemData.GetODE2Coordinates(configuration=exu.ConfigurationType.Initial))
    # the catenary guess is usually close; slack parts on the seabed need the stabiliser (a
    # mass-proportional Jacobian term fading out over the load steps: the end state is exact)
    for steps, tol, stabilizer in ((1, 1e-8, 0.0), (10, 1e-8, 1e3), (50, 1e-6, 1e4)):
        ss = exu.SimulationSettings()
        ss.solution.file.write = False
        ss.solution.sensors.active = False
        ss.staticSolver.verboseMode = 0
        ss.staticSolver.numberOfLoadSteps = steps
        ss.staticSolver.newton.relativeTolerance = tol
        ss.staticSolver.newton.absoluteTolerance = 1e-12 * rope.axial_stiffness   # round-off floor
        ss.staticSolver.stabilizerODE2term = stabilizer
        mbs.systemData.SetODE2Coordinates(start, configuration=exu.ConfigurationType.Initial)
        try:
            if mbs.SolveStatic(ss):
                break
        except exu.SolverError:
            pass
    else:
        raise RuntimeError("Exudyn's static solver found no equilibrium of the rope (from its catenary guess)")
    q = np.asarray(mbs.systemData.GetODE2Coordinates())
    out = np.empty_like(items.reference)
    for i, node in enumerate(items.nodes):
        k = int(mbs.GetNodeODE2Index(node))
        out[i] = items.reference[i] + q[k:k + 6]
    return out


# -- the mooring set -------------------------------------------------------------------------------
@dataclass
class MooringSet:
    """The moorings built into one Exudyn system and their per-step force sampler."""

    names: list[str] = field(default_factory=list)
    kinds: list[str] = field(default_factory=list)          # "linear" | "rope" | "moordyn"
    objects: list = field(default_factory=list)             # connector / attachment joint / (system, body)
    pretension: list[np.ndarray] = field(default_factory=list)
    ropes: dict[int, RopeItems] = field(default_factory=dict)   # by mooring index
    moordyn: list = field(default_factory=list)             # MoorDynSystem, scene order
    moordyn_loads: list[np.ndarray] = field(default_factory=list)   # per system: (bodies, 2) load ids
    moordyn_rows: list[np.ndarray] = field(default_factory=list)    # per system: scene body rows

    def __len__(self) -> int:
        return len(self.names)

    # -- MoorDyn ---------------------------------------------------------------------------------
    def _set_moordyn_loads(self, mbs, k: int) -> None:
        set_load = mbs.SetLoadParameter
        for (lf, lt), f in zip(self.moordyn_loads[k].tolist(), self.moordyn[k].loads.tolist()):
            set_load(lf, "loadVector", f[:3])
            set_load(lt, "loadVector", f[3:])

    def start_moordyn(self, mbs, pose: np.ndarray) -> None:
        """Initialise every MoorDyn system at the bodies' poses (B, 6) and set its loads at t = 0."""
        for k, system in enumerate(self.moordyn):
            system.start(pose)
            self._set_moordyn_loads(mbs, k)

    def step_moordyn(self, mbs, t0: float, dt: float, pose0: np.ndarray, pose1: np.ndarray) -> None:
        """Step every MoorDyn system over [t0, t0 + dt] (bodies moving from pose0 to pose1, (B, 6))
        and set the loads the multibody step applies at its end (systems in worker processes all
        started before the first is waited for)."""
        for system in self.moordyn:
            system.step_ahead(t0, dt, pose0, pose1, ahead=False)
        for k, system in enumerate(self.moordyn):
            system.step(t0, dt, pose0, pose1)
            self._set_moordyn_loads(mbs, k)

    def step_moordyn_ahead(self, t0: float, dt: float, pose0: np.ndarray, pose1: np.ndarray) -> None:
        """Start the next :meth:`step_moordyn` (same arguments) in the systems' worker processes,
        the caller vouching that it is the next step asked for (clients/exudyn/moordyn_mooring.py)."""
        for system in self.moordyn:
            system.step_ahead(t0, dt, pose0, pose1)

    def save_moordyn(self) -> list:
        return [system.save() for system in self.moordyn]

    def restore_moordyn(self, mbs, saved: list) -> None:
        for k, (system, state) in enumerate(zip(self.moordyn, saved)):
            system.restore(state)
            self._set_moordyn_loads(mbs, k)

    def close(self) -> None:
        for system in self.moordyn:
            system.close()

    def sample(self, mbs) -> np.ndarray:
        """Force and moment each mooring exerts on its body (n, 6), global frame."""
        out = np.zeros((len(self.names), 6))
        get = mbs.GetObjectOutput
        for i, (kind, obj) in enumerate(zip(self.kinds, self.objects)):
            if kind == "moordyn":
                out[i] = self.moordyn[obj[0]].loads[obj[1]]
            elif kind == "linear":
                out[i, :3] = -np.asarray(get(obj, _OV.ForceLocal))
                out[i, 3:] = -np.asarray(get(obj, _OV.TorqueLocal))
                out[i] += self.pretension[i]
            else:
                # the attachment joint's reaction on the rope end, as Exudyn's dynamic solver reports
                # it (its static solver reports the opposite sign: callers sampling after a static
                # solve negate); exact, unlike the end element's axial strain (2 % off at 20 elements)
                out[i, :3] = np.asarray(get(obj, _OV.Force))
        return out


def build_moorings(mbs, moorings: list, handles: dict[str, BodyHandle], water: Water,
                   moordyn_files: dict | None = None, body_names: list[str] | None = None,
                   body_reference: np.ndarray | None = None, current: Current | None = None) -> MooringSet:
    """Add the scene's moorings to ``mbs`` (before ``Assemble``); ropes get their static
    equilibrium shape first. MoorDyn moorings need their files' layouts (``moordyn_files`` by
    mooring index, :func:`hydrolink.clients.exudyn.moordyn_mooring.load_moordyn_files`) and every scene
    body's name and reference position (B, 6), the rows of the poses they are stepped with."""
    out = MooringSet()
    ground = handles["ground"]
    for i, m in enumerate(moorings):
        if isinstance(m, MoorDynMooring):
            from hydrolink.clients.exudyn.moordyn_mooring import MoorDynSystem
            if moordyn_files is None or i not in moordyn_files:
                raise SceneError("scene", f"moorings[{i}].file", "MoorDyn files are read with the scene file "
                                 "(hydrolink run; run_scene_file or exudyn_client.run with moordyn_files)")
            rows = {n: k for k, n in enumerate(body_names)}
            system = MoorDynSystem(m, moordyn_files[i], f"moorings[{i}]", rows, body_reference, current)
            loads = []
            for j, name in enumerate(m.coupled_bodies):
                h = handles[name]
                mk = marker_at(mbs, h, h.reference)
                loads.append((mbs.AddLoad(LoadForceVector(markerNumber=mk, loadVector=[0.0] * 3, bodyFixed=False)),
                              mbs.AddLoad(LoadTorqueVector(markerNumber=mk, loadVector=[0.0] * 3, bodyFixed=False))))
                several = len(m.coupled_bodies) > 1
                out.names.append(f"{m.name}:{name}" if several else m.name)
                out.kinds.append("moordyn")
                out.objects.append((len(out.moordyn), j))
                out.pretension.append(np.zeros(6))
            out.moordyn.append(system)
            out.moordyn_loads.append(np.asarray(loads, int))
            out.moordyn_rows.append(np.array([rows[n] for n in m.coupled_bodies], int))
            continue
        out.names.append(mooring_label(m, i))
        if isinstance(m, LinearMooring):
            h = handles[m.body]
            m0, m1 = marker_at(mbs, ground, m.point), marker_at(mbs, h, m.point)
            obj = mbs.AddObject(ObjectConnectorRigidBodySpringDamper(
                markerNumbers=[m0, m1], stiffness=matrix6(m.stiffness), damping=matrix6(m.damping),
                visualization=VObjectConnectorRigidBodySpringDamper(show=False)))
            p = np.asarray(m.pretension, float)
            if np.any(p[:3]):
                mbs.AddLoad(LoadForceVector(markerNumber=m1, loadVector=p[:3].tolist(), bodyFixed=False))
            if np.any(p[3:]):
                mbs.AddLoad(LoadTorqueVector(markerNumber=m1, loadVector=p[3:].tolist(), bodyFixed=False))
            out.kinds.append("linear")
            out.objects.append(obj)
            out.pretension.append(p)
        elif isinstance(m, RopeMooring):
            h = handles[m.attach_to]
            attach = np.asarray(h.reference if m.point is None or h.kind == "point" else m.point, float)
            try:
                initial = rope_equilibrium(m, water, attach)
            except (RuntimeError, ValueError) as exc:
                raise SceneError("scene", f"moorings[{i}]", str(exc)) from None
            items = add_rope(mbs, m, water, ground.object, initial=initial, attach=attach)
            mb = marker_at(mbs, h, attach)
            joint = mbs.AddObject(ObjectJointSpherical(markerNumbers=[mb, items.end_marker],
                                                       visualization=VObjectJointSpherical(show=False)))
            out.kinds.append("rope")
            out.objects.append(joint)
            out.pretension.append(np.zeros(6))
            out.ropes[i] = items
        else:  # pragma: no cover - the scene schema admits only these
            raise TypeError(f"unknown mooring type {type(m).__name__}")
    return out
