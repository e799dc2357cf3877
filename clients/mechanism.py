"""The mechanism in Exudyn: bodies (wet, dry), point masses, ground, markers; joints and constraints.

Interface for other client modules (PTOs, moorings) — kept small and stable:

``BodyHandle(name, kind, node, object, reference)``
    ``kind`` is ``"rigid"`` (a scene body, wet or dry: ``NodeRigidBodyRxyz`` + ``ObjectRigidBody``),
    ``"point"`` (a point mass: ``NodePoint`` + ``ObjectMassPoint``) or ``"ground"`` (an
    ``ObjectGround`` at the origin; ``node`` is -1). ``reference`` is the node's global position at
    t = 0 (for ground: the origin). Bodies start unrotated: their body frame is the global frame at
    t = 0, so a body-fixed point is ``point_global - reference`` in local coordinates.

``marker_at(mbs, handle, point_global) -> int``
    A marker at a point given in the global frame at t = 0: ``MarkerBodyRigid`` (position and
    orientation) on rigid bodies and on ground, ``MarkerBodyPosition`` (position only) on point
    masses — a point mass has no extent, so ``point_global`` is ignored there.

``Mechanism.handles`` maps every name (bodies, point masses, ``"ground"``) to its handle.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from exudyn.itemInterface import MarkerBodyPosition, MarkerBodyRigid

GROUND = "ground"


@dataclass(frozen=True)
class BodyHandle:
    """An Exudyn body of the scene: see the module docstring."""

    name: str
    kind: str                 # "rigid" | "point" | "ground"
    node: int                 # Exudyn node index (-1 for ground)
    object: int               # Exudyn object index (ObjectRigidBody / ObjectMassPoint / ObjectGround)
    reference: tuple[float, float, float]   # global node position at t = 0


def marker_at(mbs, handle: BodyHandle, point_global) -> int:
    """A marker on ``handle`` at ``point_global`` (global frame at t = 0); see the module docstring."""
    p = np.asarray(point_global, float).reshape(3)
    if handle.kind == "point":
        return mbs.AddMarker(MarkerBodyPosition(bodyNumber=handle.object, localPosition=[0.0, 0.0, 0.0],
                                                visualization={"show": False}))
    if handle.kind not in ("rigid", "ground"):
        raise ValueError(f"unknown body kind {handle.kind!r}")
    local = p - np.asarray(handle.reference, float)
    return mbs.AddMarker(MarkerBodyRigid(bodyNumber=handle.object, localPosition=local.tolist(),
                                         visualization={"show": False}))
