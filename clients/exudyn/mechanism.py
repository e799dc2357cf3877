"""The mechanism in Exudyn: bodies (wet, dry), point masses, ground, markers; joints and constraints.

Interface for other client modules (PTOs, moorings) — kept small and stable:

``BodyHandle(name, kind, node, object, reference, dofs)``
    ``kind`` is ``"rigid"`` (a scene body, wet or dry: ``NodeRigidBodyRxyz`` + ``ObjectRigidBody``),
    ``"slider"`` or ``"reduced"`` (a scene body built with its active coordinates only, see
    "Reduced bodies" below), ``"held"`` (a body held to ground, not in the system: "Held bodies"
    below; ``node`` is -1, ``object`` the ground's, ``dofs`` ()), ``"point"`` (a point mass:
    ``NodePoint`` + ``ObjectMassPoint``) or ``"ground"`` (an ``ObjectGround`` at the origin; ``node``
    is -1). ``reference`` is the body's
    global reference position at t = 0 (for ground: the origin). Bodies start unrotated: their body
    frame is the global frame in the reference configuration, so a body-fixed point is
    ``point_global - reference`` in local coordinates. ``dofs``: for a slider/reduced body the DOFs
    (0..5, surge..yaw) its node's coordinates are, in order; () for a held body; None for the others.

``marker_at(mbs, handle, point_global, rotation=None) -> int``
    A marker at a point given in the global frame of the reference configuration:
    ``MarkerBodyRigid`` (position and orientation; ``rotation`` — a 3x3 matrix whose columns are the
    marker frame's axes in the global frame — gives the marker frame, default the global axes) on
    rigid bodies and on ground, ``MarkerBodyPosition`` (position only) on point masses — a point
    mass has no extent, so ``point_global`` and ``rotation`` are ignored there — and on sliders (no
    ``rotation``: a slider has no orientation); a ``"reduced"`` body takes no marker; a ``"held"``
    body's markers are on ground at the same point and frame.

``Mechanism.handles`` maps every name (bodies, point masses, ``"ground"``) to its handle.

Gravity and buoyancy: dry bodies and point masses carry their weight (-m g ez at the centre of mass,
exact for large rotations) and, when ``buoyancy_volume`` > 0, a constant rho g V ez at the centre of
buoyancy (default: the centre of mass). Wet bodies get no Exudyn gravity — their restoring
stiffness (hydrostatics + gravity) comes from the force server — only the constant net vertical force
rho g V - m g the server reports, at the reference point.

Reduced bodies (``build_mechanism(..., reduce=True)``): a body whose locked DOFs need no rigid-body
node is built with its active coordinates only — no ``NodeRigidBodyRxyz``, no coordinate
constraints, no Newton iterations on a DAE. It qualifies when (:func:`reduction_blocker`) no joint,
mooring or rotary PTO attaches to it (they need its pose), and its full-form equations of motion
restricted to the active DOFs are exactly linear, so that both forms agree to round-off: at most
one active rotation, and with a rotation plus translations (or a dry body's weight/buoyancy) the
centre of mass (and of buoyancy) on that rotation's axis through the reference point (else the
inertia coupling / gravity moment depends on the angle). Built as

- ``"slider"``: one active translation (heave-only, ...): ``Node1D`` + ``ObjectMass1D`` along the
  DOF's global axis. Its points translate with it, so it takes position markers: linear PTOs attach
  to it unchanged (a PTO line between two heave-only bodies acts on their relative heave);
- ``"reduced"``: otherwise: ``NodeGenericODE2`` over the active DOFs + ``ObjectGenericODE2`` with
  the 6×6 rigid-body mass matrix about the reference point (centre-of-mass offset included)
  restricted to them; nothing attaches to it.

Constant loads (weight, buoyancy, net buoyancy) act on a reduced body's coordinates as
``LoadCoordinate`` (the force and its moment about the reference point, active components); a
locked DOF's share is what the full form's coordinate constraint would carry. The node's
coordinates are displacements from the reference, like a rigid body node's.

Held bodies (``build_mechanism(..., reduce=True)``, :func:`held_bodies`): a body held to ground by a
``fixed`` joint never moves, so it is not integrated: it gets no node (its pose is its reference, its
velocity zero; its entries of the client's state vectors are the zero slot, as a reduced body's
locked DOFs are), its joints to other bodies are built to ground at the same points and frames, and
its constant loads (weight and buoyancy, or a wet body's net buoyancy) are not applied. Its wet
DOFs stay in the force server's model (their forces are computed and written to the results as
before) and out of the hydro object's coordinates. Its fixed joint has no Exudyn object; that
joint's reaction follows from the held body's own equation (it does not accelerate): minus the
loads on it — its constant loads, its hydrodynamic load (what the client applies to its DOFs, minus
the A∞ and hydrostatic coupling to the coordinates that move) and the other joints' reactions on it
— about the joint point (:class:`JointOutputs`); its violations are zero. Against the full form
(the body integrated under the joint's six Lagrange multipliers) the other bodies' motion agrees to
Newton's tolerance and the reactions' forces to the full form's multiplier noise
(tests/test_held_bodies.py). It does not apply — the body stays in the system — where the reaction
could not account for a load or the full form reports an error (:func:`hold_blocker`): a PTO or
mooring acting on it, generalized modes on it, hydrodynamic states in the scene,
a second joint to ground or to another held body, a ``[[constraints]]`` entry or locked ``dofs`` on
it, a nonzero initial state, or every wet body held (nothing left to integrate). A fixed joint
between two bodies holds neither (it is a joint like any other).

Joints are ``ObjectJointGeneric`` with the constrained axes of the joint frame (see
:data:`JOINT_AXES`). Redundant constraints are found from the constraint Jacobian at t = 0: a planar
loop (revolute axes parallel to one normal, prismatic axes in the plane) is reduced by freeing the
dependent (out-of-plane) axes of the joint that closes the loop; anything else is refused naming the
joints. Friction on a revolute/prismatic joint is a regularised Coulomb force/torque
``F tanh(v / v_reg)`` on the free relative coordinate: an ``ObjectConnectorRigidBodySpringDamper``
on the joint's markers whose user function is an Exudyn symbolic one (``exudyn.symbolic``: the law
recorded once as an expression tree Exudyn evaluates in C++, no Python call in the step; it was a
Python function, ≈ 120 µs per step and joint). Its force or torque is part of the load the joint
passes: ``joint_force`` is the constraint's reaction plus the friction (:class:`JointOutputs`), and
a held body's reaction takes it with the other joints' loads. :class:`JointOutputs` reads four
outputs of a joint a step (five where its marker-0 frame moves, one more with friction): ≈ 15 µs for
the OSWEC's hinge and held base (2-vCPU VM, load 6) with numpy; the compiled exchange takes its
arithmetic as one numba call (``JointOutputs.compiled``).
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field, replace

import numpy as np

import exudyn as exu
from exudyn.advancedUtilities import CreateSymbolicUserFunction
from exudyn.itemInterface import (CoordinateConstraint, LoadCoordinate, LoadForceVector, MarkerBodyPosition,
                                  MarkerBodyRigid, MarkerNodeCoordinate, Node1D, NodeGenericODE2, NodePoint,
                                  NodePointGround, NodeRigidBodyRxyz, ObjectConnectorRigidBodySpringDamper,
                                  ObjectGenericODE2, ObjectGround, ObjectJointGeneric, ObjectJointSpherical,
                                  ObjectMass1D, ObjectMassPoint, ObjectRigidBody, VObjectGenericODE2,
                                  VObjectJointSpherical, VObjectMass1D, VObjectRigidBody)
from exudyn.rigidBodyUtilities import RigidBodyInertia

from hydrolink.clients.exudyn.kernels.joint_moments import (FRICTION_FORCE, FRICTION_TORQUE, NO_FRICTION, add_friction,
                                                            local_moment, rotation_pairs)
from hydrolink.server.rigid_body import rigid_body_mass_matrix
from hydrolink.protocol.scene import DOF_NAMES, Body, Joint, LinearPTO, PointMass, Scene, SceneError

GROUND = "ground"

#: constrained axes (x, y, z translation; x, y, z rotation) of each joint type in its joint frame.
#: Joint frame: revolute/cylindrical z = axis; prismatic x = axis; planar z = normal;
#: universal x = axis (free, body1), y = axis2 (free, body2), z = x × y (locked: x1 · y2 = 0).
JOINT_AXES: dict[str, tuple[int, ...]] = {
    "fixed": (1, 1, 1, 1, 1, 1),
    "spherical": (1, 1, 1, 0, 0, 0),
    "revolute": (1, 1, 1, 1, 1, 0),
    "prismatic": (0, 1, 1, 1, 1, 1),
    "cylindrical": (1, 1, 0, 1, 1, 0),
    "planar": (0, 0, 1, 1, 1, 0),
    "universal": (1, 1, 1, 0, 0, 1),
}
_AXIS_WORDS = ("translation along x", "translation along y", "translation along z",
               "rotation about x", "rotation about y", "rotation about z")


@dataclass(frozen=True)
class BodyHandle:
    """An Exudyn body of the scene: see the module docstring."""

    name: str
    kind: str                 # "rigid" | "slider" | "reduced" | "point" | "ground"
    node: int                 # Exudyn node index (-1 for ground)
    object: int               # Exudyn object index (ObjectRigidBody / ObjectMass1D / ObjectGenericODE2 /
    #                           ObjectMassPoint / ObjectGround)
    reference: tuple[float, float, float]   # global reference position at t = 0
    dofs: tuple[int, ...] | None = None      # slider/reduced: the body DOF of each node coordinate


def marker_at(mbs, handle: BodyHandle, point_global, rotation=None) -> int:
    """A marker on ``handle`` at ``point_global`` (global frame at t = 0); see the module docstring."""
    if handle.kind == "point":
        return mbs.AddMarker(MarkerBodyPosition(bodyNumber=handle.object, localPosition=[0.0, 0.0, 0.0]))
    origin = (0.0, 0.0, 0.0) if handle.kind == "held" else handle.reference   # a held body's markers: on ground
    local = (np.asarray(point_global, float).reshape(3) - np.asarray(origin, float)).tolist()
    if handle.kind == "slider" and rotation is None:
        local = (slider_rotation(handle.dofs[0]).T @ np.asarray(local)).tolist()
        return mbs.AddMarker(MarkerBodyPosition(bodyNumber=handle.object, localPosition=local))
    if handle.kind in ("slider", "reduced"):
        raise ValueError(f"body {handle.name!r} is built with its active coordinates only ({handle.kind}): "
                         "it takes no marker frame" + ("" if handle.kind == "slider" else " or point"))
    if handle.kind not in ("rigid", "ground", "held"):
        raise ValueError(f"unknown body kind {handle.kind!r}")
    if rotation is None:
        return mbs.AddMarker(MarkerBodyRigid(bodyNumber=handle.object, localPosition=local))
    ht = exu.HT(rotation=np.asarray(rotation, float).reshape(3, 3), translation=local)
    return mbs.AddMarker(MarkerBodyRigid(bodyNumber=handle.object, localHT=ht))


@dataclass(frozen=True)
class JointInfo:
    """A joint as built: its label (``name`` or ``joints[i]``), Exudyn indices and locked axes."""

    label: str
    key: str                  # joints[i]
    type: str
    object: int
    markers: tuple[int, int]
    constrained: tuple[int, ...]
    frame: np.ndarray         # 3x3, columns = joint axes (global, reference configuration)
    friction_object: int = -1          # the friction connector (-1: none)
    friction_function: object = None   # its symbolic user function, kept alive with the joint (Exudyn's advice)
    point_mass: bool = False  # a spherical joint with a point mass: ObjectJointSpherical, global outputs
    bodies: tuple[str, str] = ("", "")                   # body1, body2
    point: tuple[float, float, float] = (0.0, 0.0, 0.0)  # the joint point (global, reference configuration)


@dataclass
class Mechanism:
    """Everything the mechanism added to an Exudyn system."""

    handles: dict[str, BodyHandle]
    joints: list[JointInfo]
    ground_coordinate_marker: int
    warnings: list[str] = field(default_factory=list)
    reductions: list[str] = field(default_factory=list)   # reduced bodies; planar-loop joints whose axes were freed
    full_bodies: dict[str, str] = field(default_factory=dict)   # bodies with locked DOFs kept rigid: why
    coordinate_constraints: list[tuple[str, int]] = field(default_factory=list)  # (key, object)
    held: dict[str, "HeldBody"] = field(default_factory=dict)   # bodies held to ground, out of the system

    @property
    def ground(self) -> BodyHandle:
        return self.handles[GROUND]

    def rigid_nodes(self, names: list[str]) -> list[int]:
        """Node indices of the named scene bodies (rigid, slider or reduced), in that order."""
        return [self.handles[n].node for n in names]

    def joint_outputs(self, mbs) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """Reaction force and moment on body2 from body1 (J, 3, global frame, about the joint point)
        and the position-level violation: constrained relative translation (m) and rotation (rad);
        a held wet body's hydrodynamic load left out (a run keeps a :class:`JointOutputs`)."""
        wrench, gap, rot_gap = JointOutputs(mbs, self)()
        return wrench[:, :3], wrench[:, 3:], gap, rot_gap

    @property
    def joint_labels(self) -> list[str]:
        return [j.label for j in self.joints]


class JointOutputs:
    """The joints' results variables at the current state (:meth:`Mechanism.joint_outputs`): an
    ``ObjectJointGeneric``'s ``ForceLocal``, ``TorqueLocal``, ``DisplacementLocal`` and ``Rotation``,
    with its marker-0 frame A₀ (read once where the marker is on ground or on a held body, else each
    call), and its friction connector's ``ForceLocal`` (prismatic) or ``TorqueLocal`` (revolute). The
    load on body2 from body1, global, about the joint point (marker 1's point): force −A₀
    (``ForceLocal`` + the friction force); moment −A₀ (m + the friction torque), m the rotation
    multipliers (``TorqueLocal``) mapped to the moment they exert (clients/exudyn/kernels/joint_moments.py:
    they are multipliers of dot-product constraints, not moment components).

    A held body's fixed joint (module docstring, "Held bodies") has no Exudyn object: its reaction
    follows from the held body's equation (it does not accelerate): minus the loads on it — its
    constant load, its hydrodynamic load and the other joints' reactions on it — about the joint
    point; its violations are zero. ``hydro`` gives a held wet body's hydrodynamic load: by name,
    its rows of the client's load vector (6), the hydro object's mass and stiffness rows over its
    coordinates (6 × m) and those coordinates' ODE2 indices (m): load − mass · a − stiffness · q
    (the A∞ and hydrostatic coupling to the coordinates that move). The reaction is then one
    product of a matrix made here with the stacked load rows, a, q and the other joints' wrenches."""

    def __init__(self, mbs, mech: Mechanism,
                 hydro: dict[str, tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]] | None = None):
        ovt = exu.OutputVariableType
        self._mbs, self._n = mbs, len(mech.joints)
        self._generic: list[tuple[int, int, np.ndarray | int, np.ndarray, tuple, int, int]] = []
        self._point: list[tuple[int, int]] = []
        for k, j in enumerate(mech.joints):
            if int(j.object) < 0:
                continue
            if j.point_mass:
                self._point.append((k, j.object))
                continue
            body0 = mech.handles[j.bodies[0]]
            a0 = np.asarray(mbs.GetMarkerOutput(j.markers[0], ovt.RotationMatrix)).reshape(3, 3) \
                if body0.kind in ("ground", "held") else j.markers[0]
            which = NO_FRICTION if int(j.friction_object) < 0 else FRICTION_FORCE if friction_axis(j.type) < 3 \
                else FRICTION_TORQUE
            self._generic.append((k, j.object, a0, np.asarray(j.constrained, bool),
                                  tuple(map(tuple, rotation_pairs(j.constrained).tolist())), j.friction_object, which))
        self._moment = np.zeros(3)
        # a held body's fixed joint: its reaction (on body2, about the joint point) = offset + transfer @
        # (its load rows, a, q at the hydro object's coordinates, the other joints' wrenches)
        self._held = []
        hydro = hydro or {}
        for name, h in mech.held.items():
            own = mech.joints[h.joint]
            point = np.asarray(own.point, float)
            sign = 1.0 if own.bodies[1] == name else -1.0
            t0 = _transfer(h.reference - point)
            rows, mass, stiff, coords = hydro.get(name, (np.zeros(0, int), np.zeros((6, 0)), np.zeros((6, 0)),
                                                         np.zeros(0, int)))
            blocks = [t0, -t0.dot(mass), -t0.dot(stiff)] if rows.size else []
            others = [k for k, j in enumerate(mech.joints) if k != h.joint and name in j.bodies]
            for k in others:     # joint k's reaction on the held body: its output, or minus it (body1)
                j = mech.joints[k]
                blocks.append((1.0 if j.bodies[1] == name else -1.0) * _transfer(np.asarray(j.point, float) - point))
            transfer = -sign * np.hstack(blocks) if blocks else np.zeros((6, 0))   # nothing but its constant load
            self._held.append((h.joint, -sign * t0.dot(h.constant), transfer, rows, coords, np.asarray(others, int)))

    def __call__(self, load: np.ndarray | None = None) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(J, 6) reaction force and moment on body2 from body1 (global, about the joint point), the
        translation and rotation violations (J,); ``load``: the client's load vector last applied
        (the held wet bodies' reactions read it; None: no held wet body)."""
        mbs, n, ovt = self._mbs, self._n, exu.OutputVariableType
        wrench = np.zeros((n, 6))
        gap, rot_gap = np.zeros(n), np.zeros(n)
        get = mbs.GetObjectOutput
        for k, obj in self._point:   # ObjectJointSpherical: -Force is the force on body2 (dynamic solver), global
            wrench[k, :3] = -np.asarray(get(obj, ovt.Force))
            gap[k] = float(np.linalg.norm(get(obj, ovt.Displacement)))
        m = self._moment
        for k, obj, a0, c, pairs, fobj, which in self._generic:
            if not isinstance(a0, np.ndarray):
                a0 = np.asarray(mbs.GetMarkerOutput(a0, ovt.RotationMatrix)).reshape(3, 3)
            angles = np.asarray(get(obj, ovt.Rotation))
            local_moment(np.asarray(get(obj, ovt.TorqueLocal)).tolist(), angles.tolist(), pairs, m)
            force = np.asarray(get(obj, ovt.ForceLocal))
            if which != NO_FRICTION:
                add_friction(which, get(fobj, _FRICTION_OUTPUT[which]).tolist(), force, m)
            wrench[k, :3] = -a0.dot(force)
            wrench[k, 3:] = -a0.dot(m)
            d, r = np.asarray(get(obj, ovt.DisplacementLocal))[c[:3]], angles[c[3:]]
            gap[k], rot_gap[k] = math.sqrt(d.dot(d)), math.sqrt(r.dot(r))      # np.linalg.norm's value
        if self._held:
            sd, now = mbs.systemData, exu.ConfigurationType.Current
            q, a = sd.GetODE2Coordinates(now, False), sd.GetODE2Coordinates_tt(now, False)
            for k, offset, transfer, rows, coords, others in self._held:
                own = (load[rows] if load is not None else np.zeros(rows.size)) if rows.size else rows
                parts = (own, a[coords], q[coords]) if rows.size else ()
                wrench[k] = offset + transfer.dot(np.concatenate((*parts, wrench[others].reshape(-1))))
        return wrench, gap, rot_gap

    def compiled(self):
        """This call's arithmetic as one compiled call (clients/exudyn/kernels/joints.py): a function
        ``(load, slots)`` filling the results row's slots of joint_force, joint_violation and
        joint_rotation_violation (``ResultWriter.slots``: (1, J, 6), (1, J), (1, J)) with this call's
        values, bit for bit; None where a point-mass joint is among them."""
        if self._point:
            return None
        from numba import typeof

        from hydrolink.clients.exudyn.kernels import joints as jk
        mbs, ovt, n = self._mbs, exu.OutputVariableType, self._n
        generic = self._generic
        raw, frames = np.zeros((len(generic), 5, 3)), np.zeros((len(generic), 3, 3))
        moving = [(g, a0) for g, (_, _, a0, *_) in enumerate(generic) if not isinstance(a0, np.ndarray)]
        for g, (_, _, a0, *_) in enumerate(generic):
            if isinstance(a0, np.ndarray):
                frames[g] = a0
        rows = np.array([k for k, *_ in generic], np.int64)
        locked = np.array([g[3] for g in generic], bool).reshape(len(generic), 6)
        pairs = np.array([g[4] for g in generic], np.int64).reshape(len(generic), 3, 2)
        friction = np.array([g[6] for g in generic], np.int64)
        rubbing = [(g, fobj, _FRICTION_OUTPUT[which]) for g, (*_, fobj, which) in enumerate(generic)
                   if which != NO_FRICTION]
        width = np.array([t.shape[1] for _, _, t, *_ in self._held], np.int64)
        start = np.concatenate(([0], np.cumsum(6 * width)[:-1])).astype(np.int64)
        kind = np.full((len(self._held), int(width.max(initial=0))), -1, np.int64)
        index = np.zeros_like(kind)
        for h, (_, _, transfer, hrows, coords, others) in enumerate(self._held):
            sources = ([(jk.LOAD, i) for i in hrows] + [(jk.ACC, i) for i in coords] + [(jk.POS, i) for i in coords]
                       if hrows.size else []) + [(jk.WRENCH, 6 * k + i) for k in others for i in range(6)]
            kind[h, :len(sources)], index[h, :len(sources)] = zip(*sources) if sources else ((), ())
        held = (np.array([h[0] for h in self._held], np.int64), np.array([h[1] for h in self._held]).reshape(-1, 6),
                np.concatenate([h[2].reshape(-1) for h in self._held]) if self._held else np.zeros(0), start, width,
                kind, index)
        sd, now = mbs.systemData, exu.ConfigurationType.Current
        slot = (np.zeros((n, 6)), np.zeros(n), np.zeros(n))
        views = (sd.GetODE2Coordinates(now, False), sd.GetODE2Coordinates_tt(now, False))
        args = (raw, frames, rows, locked, pairs, friction, *held, np.zeros(1), *views, *slot)
        entry = jk.joint_rows.compile(tuple(typeof(x) for x in args))    # numba's per-call typing skipped
        get, marker = mbs.GetObjectOutput, mbs.GetMarkerOutput
        outputs = (ovt.ForceLocal, ovt.TorqueLocal, ovt.DisplacementLocal, ovt.Rotation)
        rotation = ovt.RotationMatrix

        def fill(load: np.ndarray, slots: tuple[np.ndarray, ...]) -> None:
            for g, m0 in moving:
                frames[g] = np.asarray(marker(m0, rotation)).reshape(3, 3)
            for g, (_, obj, *_) in enumerate(generic):
                for i, what in enumerate(outputs):
                    raw[g, i] = get(obj, what)
            for g, fobj, what in rubbing:
                raw[g, 4] = get(fobj, what)
            entry(raw, frames, rows, locked, pairs, friction, *held, load, sd.GetODE2Coordinates(now, False),
                  sd.GetODE2Coordinates_tt(now, False), slots[0][0], slots[1][0], slots[2][0])
        return fill


#: the friction connector's output a joint's load takes (joint_moments.add_friction's ``which``)
_FRICTION_OUTPUT = {FRICTION_FORCE: exu.OutputVariableType.ForceLocal, FRICTION_TORQUE: exu.OutputVariableType.TorqueLocal}


def _transfer(r: np.ndarray) -> np.ndarray:
    """(6, 6): a wrench (force, moment) about a point to the same wrench about the point ``r``
    behind it (moment + r x force)."""
    t = np.eye(6)
    t[3:, :3] = [[0.0, -r[2], r[1]], [r[2], 0.0, -r[0]], [-r[1], r[0], 0.0]]
    return t


# -- bodies ------------------------------------------------------------------------------------

def _initial(scene: Scene, body: Body, what: str) -> np.ndarray:
    """A body's initial displacement/velocity; nonzero values in inactive DOFs are a scene error."""
    value = np.asarray(getattr(body, what), float)
    active = np.asarray(body.active_mask, bool)
    locked = ~active & (value != 0)
    if locked.any():
        i = scene.bodies.index(body)
        dofs = [DOF_NAMES[j] for j in np.flatnonzero(locked)]
        raise SceneError("scene", f"bodies[{i}].{what}",
                         f"nonzero in inactive DOF(s) {dofs}; inactive DOFs are held at equilibrium "
                         f"(add them to bodies[{i}].dofs or set them to 0)")
    return value


def add_ground(mbs) -> tuple[BodyHandle, int]:
    """Ground object (for markers) and a ground coordinate marker (for coordinate constraints)."""
    obj = mbs.AddObject(ObjectGround(name=GROUND, referencePosition=[0.0, 0.0, 0.0]))
    node = mbs.AddNode(NodePointGround(referenceCoordinates=[0.0, 0.0, 0.0]))
    marker = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=node, coordinate=0))
    return BodyHandle(GROUND, "ground", -1, obj, (0.0, 0.0, 0.0)), marker


def _check_inertia(scene: Scene, body: Body) -> None:
    """SceneError naming ``bodies[i].inertia`` when the body's mass matrix is numerically singular."""
    m6 = np.zeros((6, 6))
    m6[:3, :3] = body.mass * np.eye(3)
    m6[3:, 3:] = body.inertia_matrix
    ev = np.linalg.eigvalsh(m6)
    if ev[0] <= 1e-12 * ev[-1]:
        raise SceneError("scene", f"bodies[{scene.bodies.index(body)}].inertia",
                         f"the body's mass matrix is numerically singular (eigenvalues {ev[0]:.3g} .. {ev[-1]:.3g}); "
                         "give every principal moment of inertia a physical value")


def add_rigid_body(mbs, scene: Scene, body: Body, reference, initial_displacement=None,
                   initial_velocity=None) -> BodyHandle:
    """``NodeRigidBodyRxyz`` at ``reference`` + ``ObjectRigidBody`` (inertia moved to the node)."""
    ref = np.asarray(reference, float).reshape(3)
    com = body.com_or(ref) - ref
    _check_inertia(scene, body)
    inertia = RigidBodyInertia(body.mass, body.inertia_matrix, com, inertiaTensorAtCOM=True)
    q0 = initial_displacement if initial_displacement is not None else _initial(scene, body, "initial_displacement")
    v0 = initial_velocity if initial_velocity is not None else _initial(scene, body, "initial_velocity")
    node = mbs.AddNode(NodeRigidBodyRxyz(name=f"{body.name}_node", referenceCoordinates=[*ref, 0.0, 0.0, 0.0],
                                         initialCoordinates=list(q0), initialVelocities=list(v0)))
    obj = mbs.AddObject(ObjectRigidBody(name=body.name, nodeNumber=node, mass=body.mass,
                                        inertia=inertia.GetInertia6D(), centerOfMass=com.tolist(),
                                        visualization=VObjectRigidBody(show=False)))
    return BodyHandle(body.name, "rigid", node, obj, tuple(float(x) for x in ref))


def active_dofs(body: Body) -> tuple[int, ...]:
    """The body's active DOFs (0..5: surge, sway, heave, roll, pitch, yaw), in that order."""
    return tuple(j for j, on in enumerate(body.active_mask) if on)


def reduction_blocker(scene: Scene, body: Body, reference) -> str | None:
    """Why ``body`` (reference point ``reference``) needs a full rigid-body node; None when it can be
    built with its active coordinates only (module docstring, "Reduced bodies")."""
    dofs = active_dofs(body)
    if len(dofs) in (0, 6):
        return "no DOF is locked" if dofs else "no active DOF"
    for i, j in enumerate(scene.joints):
        if body.name in (j.body1, j.body2):
            return f"joints[{i}] needs its pose"
    for i, m in enumerate(scene.moorings):
        if body.name in (getattr(m, "body", None), getattr(m, "attach_to", None), *getattr(m, "coupled_bodies", ())):
            return f"moorings[{i}] needs its pose"
    slider = len(dofs) == 1 and dofs[0] < 3
    for i, p in enumerate(scene.ptos):
        if body.name in (p.body1, p.body2) and not (slider and isinstance(p, LinearPTO)):
            return (f"ptos[{i}] needs its pose (a linear PTO attaches to a body with one active translation "
                    "only)")
    rot = [j for j in dofs if j >= 3]
    if len(rot) > 1:
        return f"{' and '.join(DOF_NAMES[j] for j in rot)} are active: the rotation kinematics are nonlinear"
    if not rot:
        return None
    axis = np.eye(3)[rot[0] - 3]
    ref = np.asarray(reference, float).reshape(3)
    points = []
    if len(dofs) > 1 or not body.wet:
        points.append(("centre of mass", body.com_or(ref)))
    if not body.wet and body.buoyancy_volume > 0 and body.center_of_buoyancy is not None:
        points.append(("centre of buoyancy", body.center_of_buoyancy))
    for what, point in points:
        r = np.asarray(point, float) - ref
        off = float(np.linalg.norm(r - axis * float(r @ axis)))
        if off > 1e-12 * max(1.0, float(np.abs(ref).max())):
            return (f"its {what} is {off:.3g} m off the {DOF_NAMES[rot[0]]} axis through its reference point: "
                    f"the {'gravity moment' if len(dofs) == 1 else 'inertia coupling'} depends on the angle")
    return None


@dataclass(frozen=True)
class HeldBody:
    """A body held to ground by a ``fixed`` joint and left out of Exudyn's system (module docstring,
    "Held bodies"): the holding joint's index, the body's reference point and its constant load
    (weight and buoyancy, or a wet body's net buoyancy: force, moment about the reference point)."""

    name: str
    joint: int                # scene joint index (= Mechanism.joints index)
    reference: np.ndarray     # (3,)
    constant: np.ndarray      # (6,), filled while the mechanism is built


def held_bodies(scene: Scene) -> dict[str, int]:
    """The bodies held to ground by a ``fixed`` joint that can be left out of the integrated system,
    each with its joint's index (module docstring, "Held bodies"); see :func:`hold_blocker`."""
    fixed = scene.fixed_to_ground()
    bodies = {b.name: b for b in scene.bodies}
    if any(b.hydro_states for b in scene.bodies):    # a switch changes the hydro matrices the reactions read
        return {}
    out = {name: ks[0] for name, ks in fixed.items()
           if name in bodies and hold_blocker(scene, bodies[name], ks, set(fixed)) is None}
    wet = [b.name for b in scene.bodies if b.wet]
    if wet and all(name in out for name in wet):     # nothing wet would be integrated
        return {}
    return out


def hold_blocker(scene: Scene, body: Body, holding: list[int], candidates: set[str]) -> str | None:
    """Why ``body``, held to ground by the fixed joints ``holding``, stays in the integrated system
    (None: it can be left out): what its reaction could not account for or what the full form
    reports as an error (a redundant or violated fixed joint)."""
    i = scene.bodies.index(body)
    if len(holding) > 1:
        return f"joints{holding} hold it twice (redundant)"
    if not all(body.active_mask):
        return f"bodies[{i}].dofs locks DOFs as well (redundant)"
    if any(np.any(np.asarray(getattr(body, w), float) != 0) for w in ("initial_displacement", "initial_velocity")):
        return "its initial state is not its reference pose"
    if getattr(body, "modes", None):
        return "it has generalized modes"
    if any(c.body == body.name for c in scene.constraints):
        return "a [[constraints]] entry acts on it"
    for k, j in enumerate(scene.joints):
        if body.name in (j.body1, j.body2) and k not in holding:
            other = j.body2 if j.body1 == body.name else j.body1
            if other in candidates or other == GROUND:
                return f"joints[{k}] joins it to another held body or to ground"
    for k, m in enumerate(scene.moorings):
        if body.name in (getattr(m, "body", None), getattr(m, "attach_to", None), *getattr(m, "coupled_bodies", ())):
            return f"moorings[{k}] acts on it"
    for k, p in enumerate(scene.ptos):
        if body.name in (p.body1, p.body2):
            return f"ptos[{k}] acts on it"
    return None


def _wrench(r: np.ndarray, force: np.ndarray) -> np.ndarray:
    """A force at offset ``r`` as (force, moment about the offset's origin)."""
    return np.r_[force, np.cross(r, force)]


def slider_rotation(dof: int) -> np.ndarray:
    """Rotation whose first column is the global axis of translation DOF ``dof`` (right-handed)."""
    return np.roll(np.eye(3), -dof, axis=1)


def add_reduced_body(mbs, scene: Scene, body: Body, reference, initial_displacement: np.ndarray,
                     initial_velocity: np.ndarray) -> BodyHandle:
    """A body with its active coordinates only (module docstring, "Reduced bodies"): a slider
    (``Node1D`` + ``ObjectMass1D``) for one active translation, else ``NodeGenericODE2`` +
    ``ObjectGenericODE2`` with the rigid-body mass matrix restricted to the active DOFs."""
    dofs = active_dofs(body)
    ref = np.asarray(reference, float).reshape(3)
    _check_inertia(scene, body)
    q0, v0 = np.asarray(initial_displacement, float)[list(dofs)], np.asarray(initial_velocity, float)[list(dofs)]
    if len(dofs) == 1 and dofs[0] < 3:
        node = mbs.AddNode(Node1D(name=f"{body.name}_node", referenceCoordinates=[0.0],
                                  initialCoordinates=q0.tolist(), initialVelocities=v0.tolist()))
        obj = mbs.AddObject(ObjectMass1D(name=body.name, nodeNumber=node, mass=body.mass,
                                         referencePosition=ref.tolist(), referenceRotation=slider_rotation(dofs[0]),
                                         visualization=VObjectMass1D(show=False)))
        return BodyHandle(body.name, "slider", node, obj, tuple(float(x) for x in ref), dofs)
    m6 = rigid_body_mass_matrix(body.mass, body.inertia_matrix, body.com_or(ref) - ref)
    node = mbs.AddNode(NodeGenericODE2(name=f"{body.name}_node", numberOfODE2Coordinates=len(dofs),
                                       referenceCoordinates=np.r_[ref, 0.0, 0.0, 0.0][list(dofs)].tolist(),
                                       initialCoordinates=q0.tolist(), initialCoordinates_t=v0.tolist()))
    obj = mbs.AddObject(ObjectGenericODE2(name=body.name, nodeNumbers=[node], massMatrix=m6[np.ix_(dofs, dofs)],
                                          visualization=VObjectGenericODE2(show=False)))
    return BodyHandle(body.name, "reduced", node, obj, tuple(float(x) for x in ref), dofs)


def add_coordinate_loads(mbs, handle: BodyHandle, point, force) -> list[int]:
    """A constant global ``force`` at ``point`` on a slider/reduced body: its generalised force
    (force; moment about the reference point) on the node's coordinates, as ``LoadCoordinate``."""
    f = np.asarray(force, float).reshape(3)
    r = np.asarray(point, float).reshape(3) - np.asarray(handle.reference, float)
    f6 = np.r_[f, np.cross(r, f)]
    loads = []
    for c, dof in enumerate(handle.dofs):
        if f6[dof] != 0.0:
            m = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=handle.node, coordinate=c))
            loads.append(mbs.AddLoad(LoadCoordinate(markerNumber=m, load=float(f6[dof]))))
    return loads


def add_point_mass(mbs, pm: PointMass) -> BodyHandle:
    """``NodePoint`` + ``ObjectMassPoint`` at the point mass's position."""
    node = mbs.AddNode(NodePoint(name=f"{pm.name}_node", referenceCoordinates=list(pm.position),
                                 initialVelocities=list(pm.initial_velocity)))
    obj = mbs.AddObject(ObjectMassPoint(name=pm.name, nodeNumber=node, mass=pm.mass))
    return BodyHandle(pm.name, "point", node, obj, tuple(float(x) for x in pm.position))


def add_vertical_force(mbs, handle: BodyHandle, point, fz: float) -> int | None:
    """A constant global vertical force ``fz`` at ``point`` (global, reference configuration)."""
    if fz == 0.0:
        return None
    if handle.dofs is not None:
        loads = add_coordinate_loads(mbs, handle, point, [0.0, 0.0, fz])
        return loads[0] if loads else None
    if handle.kind == "point":
        m = marker_at(mbs, handle, point)
    else:
        local = (np.asarray(point, float) - np.asarray(handle.reference, float)).tolist()
        m = mbs.AddMarker(MarkerBodyPosition(bodyNumber=handle.object, localPosition=local))
    return mbs.AddLoad(LoadForceVector(markerNumber=m, loadVector=[0.0, 0.0, float(fz)], bodyFixed=False))


def vertical_loads(scene: Scene, handles: dict[str, BodyHandle],
                   net_buoyancy: dict[str, float]) -> list[tuple[str, np.ndarray, float]]:
    """The constant vertical loads (body, global point, fz): the dry bodies' and point masses' weight
    (and constant buoyancy), then the wet bodies' net buoyancy at their reference point."""
    g, rho = scene.water.gravity, scene.water.density
    out = []
    for body in scene.bodies:
        if body.wet:
            continue
        out.append((body.name, np.asarray(body.center_of_mass, float), -body.mass * g))
        if body.buoyancy_volume > 0:
            cob = body.center_of_buoyancy if body.center_of_buoyancy is not None else body.center_of_mass
            out.append((body.name, np.asarray(cob, float), rho * g * body.buoyancy_volume))
    for pm in scene.point_masses:
        out.append((pm.name, np.asarray(pm.position, float), (rho * pm.buoyancy_volume - pm.mass) * g))
    for name, fz in net_buoyancy.items():
        if fz:
            out.append((name, np.asarray(handles[name].reference, float), float(fz)))
    return out


# -- joints ------------------------------------------------------------------------------------

def frame_from_axis(axis, column: int = 2) -> np.ndarray:
    """A right-handed orthonormal frame whose column ``column`` is ``axis`` (normalised)."""
    a = np.asarray(axis, float)
    a = a / np.linalg.norm(a)
    helper = np.eye(3)[int(np.argmin(np.abs(a)))]
    b = np.cross(a, helper)
    b /= np.linalg.norm(b)
    c = np.cross(a, b)
    cols = [None, None, None]
    cols[column], cols[(column + 1) % 3], cols[(column + 2) % 3] = a, b, c
    return np.column_stack(cols)


def joint_frame(joint: Joint) -> np.ndarray:
    """The joint frame (columns = axes in the global frame) for ``joint``'s type and axes."""
    if joint.type in ("fixed", "spherical"):
        return np.eye(3)
    if joint.type == "prismatic":
        return frame_from_axis(joint.axis, 0)
    if joint.type == "universal":
        x = np.asarray(joint.axis, float) / np.linalg.norm(joint.axis)
        y = np.asarray(joint.axis2, float) / np.linalg.norm(joint.axis2)
        y = y - x * float(x @ y)
        y /= np.linalg.norm(y)
        return np.column_stack([x, y, np.cross(x, y)])
    return frame_from_axis(joint.axis, 2)


def joint_label(scene: Scene, i: int) -> str:
    return scene.joints[i].name or f"joints[{i}]"


def friction_axis(joint_type: str) -> int:
    """The axis (joint frame: 0..2 translations, 3..5 rotations) a joint's friction acts along: the
    one its type leaves free (a prismatic joint's x translation, a revolute's z rotation)."""
    return JOINT_AXES[joint_type].index(0)


def _friction_function(mbs, free_axis: int, level: float, v_reg: float):
    """The friction connector's user function: the regularised Coulomb force/torque on the joint's
    free axis (joint frame), recorded as an Exudyn symbolic function (evaluated in C++)."""
    def friction(mbs, t, itemNumber, displacement, rotation, velocity, angularVelocity, stiffness, damping, rotJ0,
                 rotJ1, offset):   # the names and number Exudyn's recording checks
        out = [0.0] * 6
        v = velocity[free_axis] if free_axis < 3 else angularVelocity[free_axis - 3]
        out[free_axis] = level * exu.symbolic.tanh(v / v_reg)   # the connector applies minus this to body2
        return out
    return CreateSymbolicUserFunction(mbs, friction, "springForceTorqueUserFunction",
                                      itemTypeName="ObjectConnectorRigidBodySpringDamper")


def add_joint(mbs, scene: Scene, i: int, handles: dict[str, BodyHandle]) -> JointInfo:
    """One scene joint as an ``ObjectJointGeneric`` (+ friction connector); a spherical joint with a
    point mass (a rope connection point on a body) as an ``ObjectJointSpherical``."""
    joint = scene.joints[i]
    frame = joint_frame(joint)
    h1, h2 = handles[joint.body1], handles[joint.body2]
    label = joint_label(scene, i)
    where = ((joint.body1, joint.body2), tuple(float(x) for x in joint.point))
    if "held" in (h1.kind, h2.kind) and GROUND in (joint.body1, joint.body2):   # the joint holding it: no object
        return JointInfo(label, f"joints[{i}]", joint.type, -1, (-1, -1), JOINT_AXES[joint.type], frame,
                         bodies=where[0], point=where[1])
    if "point" in (h1.kind, h2.kind):   # the scene admits only spherical joints with point masses
        m0, m1 = marker_at(mbs, h1, joint.point), marker_at(mbs, h2, joint.point)
        obj = mbs.AddObject(ObjectJointSpherical(name=label if joint.name else f"joint{i}", markerNumbers=[m0, m1],
                                                 visualization=VObjectJointSpherical(show=False)))
        return JointInfo(label, f"joints[{i}]", joint.type, obj, (m0, m1), JOINT_AXES["spherical"], frame,
                         point_mass=True, bodies=where[0], point=where[1])
    m0 = marker_at(mbs, h1, joint.point, frame)
    m1 = marker_at(mbs, h2, joint.point, frame)
    axes = JOINT_AXES[joint.type]
    obj = mbs.AddObject(ObjectJointGeneric(name=label if joint.name else f"joint{i}", markerNumbers=[m0, m1],
                                           constrainedAxes=list(axes)))
    fobj, law = -1, None
    if joint.friction is not None:
        law = _friction_function(mbs, friction_axis(joint.type), joint.friction.force, joint.friction.velocity)
        fobj = mbs.AddObject(ObjectConnectorRigidBodySpringDamper(name=f"{label}_friction", markerNumbers=[m0, m1],
                                                                  springForceTorqueUserFunction=law))
    return JointInfo(label, f"joints[{i}]", joint.type, obj, (m0, m1), axes, frame, fobj, law, bodies=where[0],
                     point=where[1])


def _check_joint_distance(scene: Scene, i: int, handles: dict[str, BodyHandle]) -> str | None:
    """A warning when a joint's point is far from every (non-ground) body it connects."""
    joint = scene.joints[i]
    by_name = {b.name: b for b in scene.bodies}
    far = []
    for name in (joint.body1, joint.body2):
        if name == GROUND:
            continue
        if name not in by_name:   # a point mass: the joint point is the point mass (gap checked at t = 0)
            return None
        b = by_name[name]
        r_gyr = math.sqrt(float(np.trace(b.inertia_matrix)) / (2.0 * b.mass))
        d = float(np.linalg.norm(np.asarray(joint.point) - b.com_or(handles[name].reference)))
        limit = 10.0 * max(r_gyr, 0.1)
        if d <= limit:
            return None
        far.append(f"{d:.3g} m from {name!r}'s centre of mass (radius of gyration {r_gyr:.3g} m)")
    if not far:
        return None
    return f"joints[{i}].point: far from the bodies it joins ({'; '.join(far)}); is it in global coordinates?"


# -- constraints ---------------------------------------------------------------------------------

def add_coordinate_constraints(mbs, scene: Scene, handles: dict[str, BodyHandle], ground_marker: int,
                               initial: dict[str, tuple[np.ndarray, np.ndarray]]) -> list[tuple[str, int]]:
    """Locked DOFs (``dofs`` shorthand) and ``[[constraints]]`` as coordinate constraints to ground."""
    out = []
    for i, body in enumerate(scene.bodies):
        node = handles[body.name].node
        for j, on in enumerate(body.active_mask):
            if not on and handles[body.name].dofs is None:
                m = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=node, coordinate=j))
                out.append((f"bodies[{i}].dofs", mbs.AddObject(CoordinateConstraint(
                    markerNumbers=[ground_marker, m]))))
    for i, c in enumerate(scene.constraints):
        bi = [b.name for b in scene.bodies].index(c.body)
        j = DOF_NAMES.index(c.dof)
        if not scene.bodies[bi].active_mask[j]:
            raise SceneError("scene", f"constraints[{i}].dof",
                             f"{c.dof} of {c.body!r} is already locked (not in bodies[{bi}].dofs)")
        h = handles[c.body]
        m = mbs.AddMarker(MarkerNodeCoordinate(nodeNumber=h.node, coordinate=j if h.dofs is None else h.dofs.index(j)))
        obj = mbs.AddObject(CoordinateConstraint(markerNumbers=[ground_marker, m], offset=float(c.value),
                                                 velocityLevel=c.type == "velocity"))
        out.append((f"constraints[{i}]", obj))
    return out


def constrained_initial_state(scene: Scene, body: Body) -> tuple[np.ndarray, np.ndarray]:
    """Initial displacement and velocity of a body with its ``[[constraints]]`` applied.

    A constrained DOF left at 0 starts at the constraint's value; a different nonzero initial value
    is a scene error."""
    q = _initial(scene, body, "initial_displacement").copy()
    v = _initial(scene, body, "initial_velocity").copy()
    bi = scene.bodies.index(body)
    for i, c in enumerate(scene.constraints):
        if c.body != body.name:
            continue
        j = DOF_NAMES.index(c.dof)
        arr, what = (q, "initial_displacement") if c.type == "position" else (v, "initial_velocity")
        if arr[j] == 0.0:
            arr[j] = c.value
        elif arr[j] != c.value:
            raise SceneError("scene", f"constraints[{i}].value",
                             f"{c.value:g} contradicts bodies[{bi}].{what} ({arr[j]:g}) in {c.dof}")
    return q, v


# -- redundancy ------------------------------------------------------------------------------------

def _constraint_jacobian(mbs) -> tuple[np.ndarray, int]:
    """Columns = constraints (all AE coordinates), rows = ODE2 coordinates (+ AE): C_q^T stacked on C_λ."""
    ss = exu.SimulationSettings()
    ss.solution.file.write = False
    ss.staticSolver.verboseMode = 0
    solver = exu.MainSolverStatic()
    solver.InitializeSolver(mbs, ss)
    try:
        n2 = solver.GetODE2size()
        solver.ComputeJacobianODE2RHS(mbs, scalarFactor_ODE2=-1, scalarFactor_ODE2_t=0, scalarFactor_ODE1=0)
        solver.ComputeJacobianAE(mbs, scalarFactor_ODE2=1.0, scalarFactor_ODE2_t=0.0, scalarFactor_ODE1=1.0,
                                 velocityLevel=False)
        jac = np.asarray(solver.GetSystemJacobian())
    finally:
        solver.FinalizeSolver(mbs, ss)
    return jac[:n2, n2:], n2


def _planar_normal(joints: list[Joint]) -> np.ndarray | None:
    """The common plane normal of a set of revolute/prismatic joints, None if they are not planar."""
    normal = None
    for j in joints:
        if j.type == "revolute":
            a = np.asarray(j.axis, float) / np.linalg.norm(j.axis)
            if normal is None:
                normal = a
            elif np.linalg.norm(np.cross(normal, a)) > 1e-9:
                return None
        elif j.type != "prismatic":
            return None
    if normal is None:
        return None
    for j in joints:
        if j.type == "prismatic" and abs(float(np.asarray(j.axis) @ normal)) > 1e-9 * np.linalg.norm(j.axis):
            return None
    return normal


def _first_redundancy(mbs, mech: Mechanism, tol: float) -> tuple[int, list[str], int] | None:
    """The first joint (scene order, after the coordinate constraints) with constraint-Jacobian
    columns dependent on those before it: (joint index, keys of the items involved, how many)."""
    cq, _ = _constraint_jacobian(mbs)
    ltg = mbs.systemData.GetObjectLTGAE
    columns: list[np.ndarray] = []
    owners: list[str] = []
    for key, obj in mech.coordinate_constraints:
        col = cq[:, ltg(obj)[0]]
        if _dependent(columns, col, tol) is None:
            columns.append(col)
            owners.append(key)
    for k, info in enumerate(mech.joints):
        if int(info.object) < 0:       # holds a body out of the system: no constraint
            continue
        idx = ltg(info.object)
        involved: set[str] = set()
        n_dep = 0
        for axis in range(6):
            if not info.constrained[axis]:
                continue
            col = cq[:, idx[axis]]
            coef = _dependent(columns, col, tol)
            if coef is None:
                columns.append(col)
                owners.append(info.key)
            else:
                n_dep += 1
                big = np.abs(coef) > 1e-6 * max(float(np.abs(coef).max()), 1e-300)
                involved |= {owners[c] for c in np.flatnonzero(big)}
        if n_dep:
            return k, sorted(involved - {info.key}, key=_key_order), n_dep
    return None


def _key_order(key: str) -> tuple:
    head, _, rest = key.partition("[")
    return (head != "bodies" and head != "constraints", head, int(rest.split("]")[0]) if rest else 0)


def _planar_free_axes(info: JointInfo, normal: np.ndarray) -> tuple[int, ...]:
    """The joint's constrained axes that are out-of-plane motions for a plane with ``normal``: a
    translation along the normal, rotations about in-plane directions."""
    out = []
    for a in range(6):
        if not info.constrained[a]:
            continue
        c = float(info.frame[:, a % 3] @ normal)
        if (a < 3 and abs(abs(c) - 1.0) < 1e-9) or (a >= 3 and abs(c) < 1e-9):
            out.append(a)
    return tuple(out)


def resolve_redundancy(mbs, scene: Scene, mech: Mechanism, tol: float = 1e-9) -> None:
    """Find redundant constraints at t = 0; reduce planar loops, refuse anything else (SceneError).

    Coordinate constraints (locked DOFs, ``[[constraints]]``) come first, then the joints in scene
    order; a joint whose constraint-Jacobian columns depend on those before it is redundant. If all
    joints involved are revolute with parallel axes (or prismatic in that plane), the redundant
    joint's out-of-plane axes are freed and the check repeats; otherwise a SceneError names them."""
    reduced: set[int] = set()
    for _ in range(len(mech.joints) + 1):
        found = _first_redundancy(mbs, mech, tol)
        if found is None:
            return
        k, involved, n_dep = found
        info = mech.joints[k]
        joint_keys = [o for o in involved if o.startswith("joints[")]
        normal = _planar_normal([scene.joints[int(o[7:-1])] for o in [*joint_keys, info.key]])
        free = _planar_free_axes(info, normal) if normal is not None and joint_keys and k not in reduced else ()
        if len(free) >= n_dep:
            axes = tuple(0 if a in free else c for a, c in enumerate(info.constrained))
            mbs.SetObjectParameter(info.object, "constrainedAxes", list(axes))
            mech.joints[k] = replace(info, constrained=axes)
            mech.reductions.append(f"{info.key}: closes a planar loop with {', '.join(joint_keys)}; freed its "
                                   f"{', '.join(_AXIS_WORDS[a] for a in free)} (joint frame, out of plane)")
            reduced.add(k)
            mbs.Assemble()
            continue
        names = " and ".join([*involved, info.key])
        raise SceneError("scene", info.key,
                         f"singular mechanism: {names} constrain the same motion ({n_dep} of {info.key}'s "
                         "constraints are already imposed by the others at t = 0); remove a joint, use one "
                         "that constrains less (e.g. spherical instead of revolute) or free a DOF")
    raise SceneError("scene", "joints", "singular mechanism: redundant constraints could not be reduced")


def _dependent(columns: list[np.ndarray], col: np.ndarray, tol: float) -> np.ndarray | None:
    """Coefficients expressing ``col`` by ``columns``, or None when it is independent of them."""
    norm = float(np.linalg.norm(col))
    if norm == 0.0:
        return np.zeros(len(columns))
    if not columns:
        return None
    a = np.column_stack(columns)
    coef, *_ = np.linalg.lstsq(a, col, rcond=None)
    if np.linalg.norm(a @ coef - col) <= tol * max(norm, float(np.abs(a).max())):
        return coef
    return None


# -- assembly ------------------------------------------------------------------------------------

def build_mechanism(mbs, scene: Scene, wet_references: dict[str, np.ndarray],
                    net_buoyancy: dict[str, float] | None = None, *, reduce: bool = False) -> Mechanism:
    """Add ground, bodies (wet at ``wet_references``, dry at their reference point), point masses,
    gravity/buoyancy, coordinate constraints and joints to ``mbs``; assemble; check redundancy and
    the initial joint gaps. PTOs/moorings may be added afterwards (then call ``mbs.Assemble()``).
    ``reduce``: build qualifying bodies with their active coordinates only (module docstring)."""
    ground, ground_marker = add_ground(mbs)
    handles: dict[str, BodyHandle] = {GROUND: ground}
    full: dict[str, str] = {}
    holding = held_bodies(scene) if reduce else {}
    held: dict[str, HeldBody] = {}
    for i, body in enumerate(scene.bodies):
        if body.wet:
            if body.name not in wet_references:
                raise SceneError("scene", f"bodies[{i}].hdb", f"the force server did not set up wet body {body.name!r}")
            ref = wet_references[body.name]
        else:
            ref = body.dry_node()
        if body.name in holding:
            handles[body.name] = BodyHandle(body.name, "held", -1, ground.object, tuple(float(x) for x in ref), ())
            held[body.name] = HeldBody(body.name, holding[body.name], np.asarray(ref, float).reshape(3), np.zeros(6))
            continue
        q0, v0 = constrained_initial_state(scene, body)
        why = reduction_blocker(scene, body, ref) if reduce else "reduction off"
        if why is None:
            handles[body.name] = add_reduced_body(mbs, scene, body, ref, q0, v0)
        else:
            handles[body.name] = add_rigid_body(mbs, scene, body, ref, q0, v0)
            if 0 < len(active_dofs(body)) < 6:
                full[body.name] = why
    for pm in scene.point_masses:
        handles[pm.name] = add_point_mass(mbs, pm)
    for name, point, fz in vertical_loads(scene, handles, net_buoyancy or {}):
        if name in held:     # on a held body: a share of its fixed joint's reaction
            held[name].constant[:] += _wrench(point - held[name].reference, np.array([0.0, 0.0, fz]))
        else:
            add_vertical_force(mbs, handles[name], point, fz)
    coords = add_coordinate_constraints(mbs, scene, handles, ground_marker, {})
    joints = [add_joint(mbs, scene, i, handles) for i in range(len(scene.joints))]
    mech = Mechanism(handles, joints, ground_marker, coordinate_constraints=coords, full_bodies=full, held=held)
    if held:
        mech.reductions.append(
            "bodies held to ground by a fixed joint, left out of the integrated system (their pose is their "
            "reference; the joint's reaction from their own equation): " + ", ".join(
                f"{n!r} ({mech.joints[h.joint].key})" for n, h in held.items()))
    reduced = [h for h in handles.values() if h.dofs is not None]
    if reduced:
        n_act = sum(len(h.dofs) for h in reduced)
        mech.reductions.append(
            "reduced bodies (active coordinates only, no rigid-body node or coordinate constraints): "
            + ", ".join(f"{h.name!r} ({'+'.join(DOF_NAMES[j] for j in h.dofs)})" for h in reduced)
            + f": {n_act} coordinates instead of {6 * len(reduced)} and {6 * len(reduced) - n_act} constraints")
    mech.warnings.extend(w for i in range(len(scene.joints)) if (w := _check_joint_distance(scene, i, handles)))
    mbs.Assemble()
    if joints:
        resolve_redundancy(mbs, scene, mech)
        _, _, gap, rot = mech.joint_outputs(mbs)
        ovt = exu.OutputVariableType
        for k, info in enumerate(mech.joints):
            if int(info.object) < 0:
                continue
            if gap[k] > 1e-6 or rot[k] > 1e-6:
                raise SceneError("scene", info.key,
                                 f"the bodies' initial displacements violate this joint by {gap[k]:.3g} m / "
                                 f"{rot[k]:.3g} rad at t = 0; start the joined bodies consistently")
            c = np.asarray(info.constrained, bool)
            if info.point_mass:
                dv, dw = np.asarray(mbs.GetObjectOutput(info.object, ovt.Velocity)), np.zeros(0)
            else:
                dv = np.asarray(mbs.GetObjectOutput(info.object, ovt.VelocityLocal))[c[:3]]
                dw = np.asarray(mbs.GetObjectOutput(info.object, ovt.AngularVelocityLocal))[c[3:]]
            bad = max(float(np.linalg.norm(dv)), float(np.linalg.norm(dw)))
            if bad > 1e-6:
                raise SceneError("scene", info.key,
                                 f"the bodies' initial velocities violate this joint (relative velocity {bad:.3g} "
                                 "m/s or rad/s along its locked axes at t = 0); give the joined bodies "
                                 "consistent initial velocities (an impulse would ring undamped)")
    return mech
