"""Viscous forces on wet bodies, beyond potential flow (issue 10), one reply field ``viscous``
(SPEC §5.2) over the active DOFs, built only when some body has one (no term costs anything
unused); the force term is :class:`ViscousTerm` (server/terms/base.py):

- HydroDyn's AddBLin / AddBQuad: F = -B_lin v - B_quad (v |v|) per body, 6x6 about the body's
  reference point, absolute velocity, in the body DOF order;
- WEC-Sim's quadratic drag: F_i = -1/2 rho cd_i area_i |u_i| u_i per DOF with u = v - u_wave, the
  undisturbed wave particle velocity plus the scene's current at the reference point
  (server/sea/kinematics.py; zero for the rotational DOFs), when ``relative``, else u = v (no current)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrolink.protocol.scene import Scene
from hydrolink.server.terms.base import ForceTerm, TermContext
from hydrolink.server.sea.kinematics import Kinematics
from hydrolink.server.sea.waves import WaveComponents, WavePhases


@dataclass(frozen=True)
class DragTerm:
    """WEC-Sim drag over the active DOFs: coefficient 1/2 rho cd area per DOF, and for relative
    drag the wave particle velocity at the bodies' reference points."""

    coefficient: np.ndarray            # (n_active,)
    wave: Kinematics | None            # at the reference points (N, 3); None: absolute velocity
    rows: np.ndarray                   # (n_active,) index into the (N, 3) translational velocities, -1: none

    def force(self, t: float, v: np.ndarray) -> np.ndarray:
        u = v
        if self.wave is not None:
            flow = np.append(self.wave.velocity(t).reshape(-1), 0.0)   # the last entry: rotations
            u = v - flow[self.rows]
        return -self.coefficient * u * np.abs(u)


@dataclass(frozen=True)
class ViscousDamping:
    """The wet bodies' added damping and drag restricted to their active DOFs (``idx`` of 6N)."""

    linear: np.ndarray | None      # (n_active, n_active)
    quadratic: np.ndarray | None   # (n_active, n_active)
    drag: DragTerm | None = None

    def force(self, t: float, v: np.ndarray) -> np.ndarray:
        """The viscous force on the active DOFs at time ``t`` for their velocities ``v``."""
        f = np.zeros_like(v)
        if self.linear is not None:
            f -= self.linear @ v
        if self.quadratic is not None:
            f -= self.quadratic @ (v * np.abs(v))
        if self.drag is not None:
            f += self.drag.force(t, v)
        return f

    def jacobian(self, t: float, v: np.ndarray) -> np.ndarray:
        """dF/dv (n_active, n_active) at time ``t`` and velocities ``v`` (Newton in hydrolink steady)."""
        n = v.size
        jac = np.zeros((n, n))
        if self.linear is not None:
            jac -= self.linear
        if self.quadratic is not None:
            jac -= self.quadratic * (2.0 * np.abs(v))[None, :]
        if self.drag is not None:
            u = v
            if self.drag.wave is not None:
                u = v - np.append(self.drag.wave.velocity(t).reshape(-1), 0.0)[self.drag.rows]
            jac -= np.diag(2.0 * self.drag.coefficient * np.abs(u))
        return jac



def build_viscous(scene: Scene, wet: list[int], idx: np.ndarray, waves: WaveComponents,
                  reference_points: np.ndarray, phases: WavePhases | None = None) -> ViscousDamping | None:
    """The damping and drag of the scene's wet bodies (scene indices ``wet``, in the server's body
    order) over the active DOFs ``idx`` of their 6N vector; None when no body has any.
    ``reference_points`` (N, 3): where relative drag takes the wave's particle velocity; ``phases``
    the step's [cos wt; sin wt] shared with the linear excitation (None: its own)."""
    bodies = [scene.bodies[i] for i in wet]
    parts = {}
    for key in ("linear_damping", "quadratic_damping"):
        if all(b.damping_matrix(key) is None for b in bodies):
            parts[key] = None
            continue
        full = np.zeros((6 * len(bodies), 6 * len(bodies)))
        for k, b in enumerate(bodies):
            m = b.damping_matrix(key)
            if m is not None:
                full[6 * k:6 * k + 6, 6 * k:6 * k + 6] = m
        parts[key] = np.ascontiguousarray(full[np.ix_(idx, idx)])
    drag = None
    if any(b.drag is not None for b in bodies):
        coef = np.zeros(6 * len(bodies))
        relative = False
        for k, b in enumerate(bodies):
            if b.drag is not None:
                coef[6 * k:6 * k + 6] = 0.5 * scene.water.density * np.asarray(b.drag.cd) * np.asarray(b.drag.area)
                relative |= b.drag.relative
        # a body's translational DOF j reads the wave velocity entry 3 k + j; rotations and
        # bodies with absolute drag read the appended zero (index 3N)
        n = len(bodies)
        rows = np.full(6 * n, 3 * n)
        for k, b in enumerate(bodies):
            if b.drag is not None and b.drag.relative:
                rows[6 * k:6 * k + 3] = 3 * k + np.arange(3)
        wave = (Kinematics(waves, reference_points, scene.water.gravity, scene.water.depth_m, scene.current,
                           phases=phases) if relative else None)
        drag = DragTerm(coef[idx], wave, rows[idx])
    if parts["linear_damping"] is None and parts["quadratic_damping"] is None and drag is None:
        return None
    return ViscousDamping(parts["linear_damping"], parts["quadratic_damping"], drag)


class ViscousTerm(ForceTerm):
    """The viscous damping and drag of the served bodies as a force term (reply field ``viscous``)."""

    name = "viscous"
    scene_keys = ("bodies[i].linear_damping", "bodies[i].quadratic_damping", "bodies[i].drag")
    features = ("linear_damping", "quadratic_damping", "drag")
    needs = frozenset({"time", "velocity"})
    steady = "jacobian"

    def __init__(self, damping: ViscousDamping, active_index: np.ndarray, n_bodies: int):
        super().__init__(("viscous",))
        self.damping, self._idx, self._n = damping, active_index, 6 * n_bodies
        self._sel = slice(None) if active_index.size == self._n else active_index  # a view when all are active

    @classmethod
    def build(cls, ctx: TermContext) -> "ViscousTerm | None":
        damping = build_viscous(ctx.scene, ctx.wet, ctx.active_index, ctx.waves, ctx.equilibrium[:, :3],
                                ctx.phases)
        return None if damping is None else cls(damping, ctx.active_index, ctx.n_bodies)

    def force(self, t: float, position: np.ndarray, velocity: np.ndarray) -> tuple[np.ndarray]:
        f = self.damping.force(t, velocity.reshape(-1)[self._sel])
        if self._idx.size == self._n:
            return (f.reshape(-1, 6),)
        out = np.zeros(self._n)
        out[self._idx] = f
        return (out.reshape(-1, 6),)

    def linear_only(self) -> tuple[np.ndarray, np.ndarray] | None:
        """(B_lin over the active DOFs, their positions in the 6N vector) where the term is linear
        damping alone (no quadratic damping, no drag): its force -B_lin v is then one product a
        compiled caller takes (server/service/local_step.py ``CompiledStep.damping``); None otherwise."""
        d = self.damping
        if d.linear is None or d.quadratic is not None or d.drag is not None:
            return None
        return d.linear, self._idx

    def velocity_jacobian(self, t: float, position: np.ndarray, velocity: np.ndarray) -> np.ndarray:
        jac = np.zeros((self._n, self._n))
        jac[np.ix_(self._idx, self._idx)] = self.damping.jacobian(t, velocity.reshape(-1)[self._idx])
        return jac
