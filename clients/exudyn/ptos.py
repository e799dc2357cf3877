"""Power take-offs (PTOs) in Exudyn, and their per-step outputs.

Elements (all Exudyn-native; a force/torque limit is a *symbolic* user function, evaluated in C++:
measured +0.5 µs per step against +1.4 µs for the same limit as a Python user function):

- ``LinearPTO``: ``ObjectConnectorSpringDamper`` between ``point1`` on ``body1`` (marker 0) and
  ``point2`` on ``body2`` or ground (marker 1). Tension ``T = k (L - L0) + c dL/dt``, clipped to
  ±``force_limit`` when set. Given by a ``direction`` e (to ground, along a global axis) instead:
  ``ObjectConnectorCartesianSpringDamper`` from ground to ``point1`` on that axis only, the line
  fixed in space: ``L - L0 = -u·e``, ``T = k (L - L0) + c dL/dt`` with u the motion of point1.
- ``RotaryPTO``: ``ObjectConnectorRigidBodySpringDamper`` between body1 (marker 0) and body2
  (marker 1) at ``point``, both markers' frames = the PTO frame (columns = ``frame`` axes,
  global at t = 0; default the global axes). Its 6×6 stiffness/damping are zero except on the chosen
  rotational axes, so it only acts on those relative rotations (Tait-Bryan xyz angles of body2
  relative to body1 in the PTO frame; the translations are left to a joint, e.g. a spherical one).
  ``torque_limit`` clips each axis' torque.

Outputs — one entry per linear PTO (``name``) and one per rotary PTO axis (``name.pitch``):

- ``pto_velocity``: linear: dL/dt = (v2 - v1)·e, e the unit vector from point1 to point2 (> 0:
  extending); rotary: relative angular velocity of body2 w.r.t. body1 about the axis (PTO frame).
- ``pto_force``: the force (N) / torque (N m) the PTO exerts ON body1 along +e / about +axis: the
  tension T, resp. ``k θ + c ω`` (after the limit). The force on body2 is the opposite.
- ``pto_power = pto_force · pto_velocity``: power absorbed by the PTO (spring + damper); > 0 when
  energy flows from the bodies into the PTO; ``c v²`` for a pure damper.

The sampler reads two ``GetObjectOutput`` values per connector (linear: Displacement, Velocity;
rotary: TorqueLocal, AngularVelocityLocal): ≈ 26 µs per step for 2 linear + 1 three-axis rotary PTO.
Recomputing them with numpy from the bulk ODE2 state (gather + Rxyz kinematics) was measured at
≈ 130 µs for the same set — numpy's per-call overhead dominates at these sizes.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field

import numpy as np

import exudyn as exu
from exudyn.advancedUtilities import CreateSymbolicUserFunction
from exudyn.itemInterface import (ObjectConnectorCartesianSpringDamper, ObjectConnectorRigidBodySpringDamper,
                                  ObjectConnectorSpringDamper, VObjectConnectorCartesianSpringDamper,
                                  VObjectConnectorRigidBodySpringDamper, VObjectConnectorSpringDamper)

from hydrolink.clients.exudyn.mechanism import BodyHandle, marker_at
from hydrolink.protocol.scene import LinearPTO, RotaryPTO, SceneError

AXES = ("roll", "pitch", "yaw")
_esym = exu.symbolic
_OV = exu.OutputVariableType
_DISPLACEMENT, _VELOCITY = _OV.Displacement, _OV.Velocity   # read once: the per-step sampler's


def frame_matrix(frame) -> np.ndarray:
    """The PTO frame as a rotation matrix whose columns are the frame axes (global, t = 0)."""
    if frame is None:
        return np.eye(3)
    m = np.array(frame, float).T
    m /= np.linalg.norm(m, axis=0)
    if not np.allclose(m.T @ m, np.eye(3), atol=1e-6) or np.linalg.det(m) < 0:
        raise ValueError("frame: the three axes must be orthonormal and right-handed")
    return m


def _per_axis(value, n: int) -> list[float]:
    return [float(x) for x in value] if isinstance(value, list) else [float(value)] * n


# -- the PTO set -------------------------------------------------------------------------------
@dataclass
class PTOSample:
    force: np.ndarray       # (n_entries,) N or N m, on body1
    velocity: np.ndarray    # (n_entries,) m/s or rad/s, body2 relative to body1
    power: np.ndarray       # (n_entries,) W absorbed
    extension: np.ndarray | None = None   # (n_linear,) L - L0 of the linear PTOs (scene order)

    @property
    def total_power(self) -> float:
        return float(np.add.reduce(self.power))   # = power.sum(), without its Python wrapper


@dataclass(frozen=True)
class _Linear:
    entry: int
    object: int
    stiffness: float
    damping: float
    rest_length: float
    limit: float            # inf when unlimited


@dataclass(frozen=True)
class _Axial:
    """A linear PTO to ground along a fixed global axis e (``direction``)."""
    entry: int
    object: int
    axis: int               # 0, 1, 2: the global axis of e
    sign: float             # e = sign * unit vector of ``axis``
    stiffness: float
    damping: float


@dataclass(frozen=True)
class _Rotary:
    entries: tuple[int, ...]
    object: int
    axes: tuple[int, ...]   # 0 roll, 1 pitch, 2 yaw (PTO frame)


@dataclass
class PTOSet:
    """The PTOs built into one Exudyn system and their per-step sampler."""

    names: list[str] = field(default_factory=list)   # entries: "name" (linear), "name.axis" (rotary)
    objects: list[int] = field(default_factory=list)  # Exudyn connector per scene PTO
    linear: list[_Linear] = field(default_factory=list)
    axial: list[_Axial] = field(default_factory=list)
    rotary: list[_Rotary] = field(default_factory=list)
    keep_alive: list = field(default_factory=list)    # symbolic user functions must outlive the run
    # current stiffness, damping and added force of each linear PTO (controllers change them)
    current: dict[int, list[float]] = field(default_factory=dict)

    def __len__(self) -> int:
        return len(self.names)

    def set_linear(self, mbs, index: int, *, stiffness: float | None = None, damping: float | None = None,
                   force: float | None = None) -> None:
        """Change linear PTO ``index`` (among the linear PTOs) between steps: stiffness, damping,
        added tension (the connector's ``force``); None keeps the value in force."""
        p = self.linear[index]
        cur = self.current.setdefault(p.object, [p.stiffness, p.damping, 0.0])
        for i, (key, value) in enumerate((("stiffness", stiffness), ("damping", damping), ("force", force))):
            if value is not None and value != cur[i]:
                mbs.SetObjectParameter(p.object, key, float(value))
                cur[i] = float(value)

    def linear_table(self) -> tuple[list[int], np.ndarray] | None:
        """The linear PTOs' connectors and, one row each, their entry, stiffness, damping, added
        force, rest length and limit (what :meth:`sample` computes their outputs from, for
        clients/exudyn/kernels/exchange.py ``linear_ptos``); None when the set has PTOs of
        another kind or more than 7 (``total_power``'s sum is then numpy's pairwise one)."""
        if self.axial or self.rotary or not self.linear or len(self.linear) > 7:
            return None
        rows = []
        for p in self.linear:
            k, c, f0 = self.current.get(p.object) or (p.stiffness, p.damping, 0.0)
            rows.append((p.entry, k, c, f0, p.rest_length, p.limit))
        return [p.object for p in self.linear], np.array(rows, float)

    def sample(self, mbs) -> PTOSample:
        """Forces, velocities and absorbed powers of all entries in the current state."""
        n = len(self.names)
        force, vel, ext = np.zeros(n), np.zeros(n), np.zeros(len(self.linear))
        out = mbs.GetObjectOutput
        current = self.current
        for i, p in enumerate(self.linear):
            (dx, dy, dz) = out(p.object, _DISPLACEMENT).tolist()        # point2 - point1
            (vx, vy, vz) = out(p.object, _VELOCITY).tolist()
            length = math.sqrt(dx * dx + dy * dy + dz * dz)
            rate = (vx * dx + vy * dy + vz * dz) / length if length > 0 else 0.0
            k, c, f0 = current.get(p.object) or (p.stiffness, p.damping, 0.0)
            f = k * (length - p.rest_length) + c * rate + f0
            force[p.entry], vel[p.entry] = min(max(f, -p.limit), p.limit), rate
            ext[i] = length - p.rest_length
        for p in self.axial:      # L - L0 = -u.e (moving along e shortens the line), rate = -v.e
            u = p.sign * float(out(p.object, _OV.Displacement)[p.axis])
            v = p.sign * float(out(p.object, _OV.Velocity)[p.axis])
            force[p.entry], vel[p.entry] = -p.stiffness * u - p.damping * v, -v
        for p in self.rotary:
            torque = out(p.object, _OV.TorqueLocal)    # on body1, PTO frame
            omega = out(p.object, _OV.AngularVelocityLocal)
            for entry, axis in zip(p.entries, p.axes):
                force[entry], vel[entry] = torque[axis], omega[axis]
        return PTOSample(force, vel, force * vel, ext)


def _limited_spring(limit: float):
    def uf(mbs, t, itemIndex, u, v, k, d, f0):
        return _esym.min(_esym.max(k * u + d * v + f0, -limit), limit)
    return uf


def _limited_rotary(k6: np.ndarray, c6: np.ndarray, limit: float):
    def uf(mbs, t, itemIndex, displacement, rotation, velocity, angularVelocity, stiffness, damping,
           rotJ0, rotJ1, offset):
        out = [0.0 * displacement[0]] * 3
        for j in range(3):
            out.append(_esym.min(_esym.max(float(k6[3 + j]) * rotation[j]
                                           + float(c6[3 + j]) * angularVelocity[j], -limit), limit))
        return out
    return uf


def build_ptos(mbs, ptos: list, handles: dict[str, BodyHandle]) -> PTOSet:
    """Add the scene's PTOs to ``mbs`` (before ``Assemble``); returns the set with its sampler."""
    out = PTOSet()
    for i, pto in enumerate(ptos):
        h1, h2 = handles[pto.body1], handles[pto.body2]
        if isinstance(pto, LinearPTO) and pto.direction is not None:
            # a Cartesian spring-damper on the one global axis of e, ground (marker 0) to point1
            # (marker 1): exact whatever the body's other motions
            axis = int(np.argmax(np.abs(pto.direction)))
            k3, c3 = [0.0] * 3, [0.0] * 3
            k3[axis], c3[axis] = float(pto.stiffness), float(pto.damping)
            m0, m1 = marker_at(mbs, h2, pto.point1), marker_at(mbs, h1, pto.point1)
            obj = mbs.AddObject(ObjectConnectorCartesianSpringDamper(
                name=f"pto_{pto.name}", markerNumbers=[m0, m1], stiffness=k3, damping=c3,
                visualization=VObjectConnectorCartesianSpringDamper(show=False)))
            out.axial.append(_Axial(len(out.names), obj, axis, float(np.sign(pto.direction[axis])),
                                    float(pto.stiffness), float(pto.damping)))
            out.names.append(pto.name)
        elif isinstance(pto, LinearPTO):
            m1, m2 = marker_at(mbs, h1, pto.point1), marker_at(mbs, h2, pto.point2)
            l0 = (float(np.linalg.norm(np.subtract(pto.point2, pto.point1)))
                  if pto.rest_length is None else float(pto.rest_length))
            kw = {}
            if pto.force_limit is not None:
                uf = CreateSymbolicUserFunction(mbs, _limited_spring(float(pto.force_limit)),
                                                "springForceUserFunction",
                                                itemTypeName="ObjectConnectorSpringDamper")
                out.keep_alive.append(uf)
                kw["springForceUserFunction"] = uf
            obj = mbs.AddObject(ObjectConnectorSpringDamper(
                name=f"pto_{pto.name}", markerNumbers=[m1, m2], referenceLength=l0,
                stiffness=float(pto.stiffness), damping=float(pto.damping),
                visualization=VObjectConnectorSpringDamper(show=False), **kw))
            out.linear.append(_Linear(len(out.names), obj, float(pto.stiffness), float(pto.damping), l0,
                                      math.inf if pto.force_limit is None else float(pto.force_limit)))
            out.names.append(pto.name)
        elif isinstance(pto, RotaryPTO):
            try:
                frame = frame_matrix(pto.frame)
            except ValueError as exc:
                raise SceneError("scene", f"ptos[{i}].frame", str(exc).split(": ", 1)[-1]) from None
            axes = [AXES.index(a) for a in pto.axes]
            k6, c6 = np.zeros(6), np.zeros(6)
            k6[[3 + a for a in axes]] = _per_axis(pto.stiffness, len(axes))
            c6[[3 + a for a in axes]] = _per_axis(pto.damping, len(axes))
            m1, m2 = marker_at(mbs, h1, pto.point, frame), marker_at(mbs, h2, pto.point, frame)
            kw = {}
            if pto.torque_limit is not None:
                uf = CreateSymbolicUserFunction(mbs, _limited_rotary(k6, c6, float(pto.torque_limit)),
                                                "springForceTorqueUserFunction",
                                                itemTypeName="ObjectConnectorRigidBodySpringDamper")
                out.keep_alive.append(uf)
                kw["springForceTorqueUserFunction"] = uf
            obj = mbs.AddObject(ObjectConnectorRigidBodySpringDamper(
                name=f"pto_{pto.name}", markerNumbers=[m1, m2], stiffness=np.diag(k6),
                damping=np.diag(c6),
                visualization=VObjectConnectorRigidBodySpringDamper(show=False), **kw))
            entries = tuple(range(len(out.names), len(out.names) + len(axes)))
            out.rotary.append(_Rotary(entries, obj, tuple(axes)))
            out.names.extend(f"{pto.name}.{a}" for a in pto.axes)
        else:  # pragma: no cover - the scene schema admits only these
            raise TypeError(f"unknown PTO type {type(pto).__name__}")
        out.objects.append(obj)
    return out
