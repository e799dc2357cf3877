"""The reaction moment of an ``ObjectJointGeneric`` from its rotation multipliers, and a joint
friction's share of the load through the joint.

Exudyn's ``TorqueLocal`` output is not a moment: it is the joint's three rotation Lagrange
multipliers λ₃…λ₅, one per rotation constraint, and each constraint is a dot product of a column of
marker 0's frame A₀ with a column of marker 1's frame A₁ (``CObjectJointGeneric``, Exudyn 1.13):

- three rotations locked: g₃ = z₀·y₁, g₄ = z₀·x₁, g₅ = x₀·y₁;
- two locked (revolute, cylindrical, planar; free axis f): g₃₊ₗ = f₀·l₁ for each locked axis l;
- one locked (universal; free axes f₁ < f₂): g₃₊ₗ = (f₁)₀·(f₂)₁.

The equations of motion carry + Gᵀλ, so the moment these multipliers put on marker 1's body is
−Σ λᵢ ∂gᵢ/∂θ₁, with ∂(u₀·v₁)/∂θ₁ = v₁ × u₀ (θ₁ a small global rotation of body 1). In marker 0's
frame v₁ is a column of the relative rotation R = A₀ᵀA₁ (``Rotation``: its xyz Tait-Bryan angles,
R = Rx Ry Rz), u₀ a unit axis. :func:`local_moment` gives Σ λᵢ (R eᵦ × eₐ) in marker 0's frame: the
reaction moment on body 2 from body 1 is then −A₀ of it, as the force is −A₀ ``ForceLocal``; it is a
couple (the force acts at marker 1's point, the joint point). The axes swap signs (z₀·x₁ gives −y, not
+y) and follow the joint angle (a revolute's locked-axis moment rotates with its marker 1), which the
raw multipliers do not.

A joint with friction (clients/exudyn/mechanism.py ``add_joint``) has a connector on the same
markers applying minus the law's force or torque (marker 0's frame: its ``ForceLocal`` on a prismatic
joint, ``TorqueLocal`` on a revolute) to body 2: :func:`add_friction` adds it to the joint's local force
or moment, so that −A₀ of the sum is the whole load on body 2 from body 1.

Plain scalar arithmetic: ``JointOutputs`` calls both from Python, clients/exudyn/kernels/joints.py
compiles it with numba — the same operations in the same order, so the same bits. numba's cache of
``kernels.joints.joint_rows`` holds this code compiled in but tracks only kernels/joints.py's own
stamp: with any change here, touch kernels/joints.py too (else a cached kernel keeps the old
arithmetic, which tests/test_compiled_exchange.py's bit-for-bit cases then report).
"""

from __future__ import annotations

import math

import numpy as np


def rotation_pairs(constrained) -> np.ndarray:
    """(3, 2) int64: for each rotation constraint 3 + i, the column a of marker 0's frame and the
    column b of marker 1's frame whose dot product it keeps at zero; (-1, -1) for a free axis."""
    locked = [bool(constrained[3 + i]) for i in range(3)]
    pairs = np.full((3, 2), -1, np.int64)
    if all(locked):
        pairs[:] = [(2, 1), (2, 0), (0, 1)]
    elif sum(locked) == 2:
        free = locked.index(False)
        for i in range(3):
            if locked[i]:
                pairs[i] = (free, i)
    elif sum(locked) == 1:
        f1, f2 = [i for i in range(3) if not locked[i]]
        pairs[locked.index(True)] = (f1, f2)
    return pairs


def local_moment(torque, angles, pairs, out) -> None:
    """``out`` (3,) = Σ λᵢ (R e_b × e_a) over the locked rotations (``pairs``): ``torque`` the joint's
    ``TorqueLocal`` (λ₃…λ₅), ``angles`` its ``Rotation`` (R = Rx Ry Rz); marker 0's frame. Sequences
    or arrays alike (Python lists and tuples are the quick ones from Python)."""
    c0, s0 = math.cos(angles[0]), math.sin(angles[0])
    c1, s1 = math.cos(angles[1]), math.sin(angles[1])
    c2, s2 = math.cos(angles[2]), math.sin(angles[2])
    out[0] = 0.0
    out[1] = 0.0
    out[2] = 0.0
    for i in range(3):
        a, b = pairs[i][0], pairs[i][1]
        if a < 0:
            continue
        if b == 0:      # column b of R
            v0, v1, v2 = c1 * c2, s0 * s1 * c2 + c0 * s2, -c0 * s1 * c2 + s0 * s2
        elif b == 1:
            v0, v1, v2 = -c1 * s2, -s0 * s1 * s2 + c0 * c2, c0 * s1 * s2 + s0 * c2
        else:
            v0, v1, v2 = s1, -s0 * c1, c0 * c1
        lam = torque[i]
        if a == 0:      # v × e_a
            out[1] += lam * v2
            out[2] -= lam * v1
        elif a == 1:
            out[0] -= lam * v2
            out[2] += lam * v0
        else:
            out[0] += lam * v1
            out[1] -= lam * v0


#: a friction connector's output a joint reads (``JointOutputs``): none, ``ForceLocal``, ``TorqueLocal``
NO_FRICTION, FRICTION_FORCE, FRICTION_TORQUE = -1, 0, 1


def add_friction(which, friction, force, moment) -> None:
    """The friction connector's local force (``which`` FRICTION_FORCE: a prismatic joint's) added to
    the joint's ``force`` (its ``ForceLocal``), or its local torque (FRICTION_TORQUE: a revolute's)
    to ``moment`` (:func:`local_moment`'s), in place; nothing for NO_FRICTION."""
    if which == FRICTION_FORCE:
        for i in range(3):
            force[i] += friction[i]
    elif which == FRICTION_TORQUE:
        for i in range(3):
            moment[i] += friction[i]
