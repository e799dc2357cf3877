"""Morison elements on wet bodies (issue 10): slender members cut into segments, Morison's
equation in relative form on each wetted segment with the undisturbed wave's kinematics at the
segment's mean position, u plus the scene's steady current there (server/kinematics.py):

    f_s = rho (1 + ca) V_s a_n + 1/2 rho cd D L_s |w_n| w_n,    w = u - v_s,

n the components normal to the member's axis, u and a the fluid's particle velocity and
acceleration, v_s the segment's velocity (body velocity + angular velocity x lever arm). The
member's own added mass, rho ca V_s on the normal directions, is constant and goes into the body's
mass matrix (``added_mass``, SPEC §5.1), not into this force. A segment is wet while its centre is
below the still water line (linear theory's integral to z = 0), followed with the body's heave,
roll and pitch. Forces and moments about the body's reference point, one reply field ``morison``;
the force term is :class:`MorisonTerm` (server/force_term.py)."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrolink.protocol.scene import Scene
from hydrolink.server.force_term import ForceTerm, TermContext
from hydrolink.server.kinematics import Kinematics
from hydrolink.server.waves import WaveComponents


def _skew(r: np.ndarray) -> np.ndarray:
    """(S, 3, 3): the matrices [r]x with [r]x f = r x f, for rows r (S, 3)."""
    out = np.zeros(r.shape[:1] + (3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
    return out - out.transpose(0, 2, 1)


@dataclass(frozen=True)
class MorisonSet:
    """The segments and the fixed linear maps of a step (built once by :func:`build_morison`)."""
    lever: np.ndarray       # (S, 3) segment centre minus the body's reference point, at equilibrium
    z0: np.ndarray          # (S,) segment centre height at equilibrium
    inertia: np.ndarray     # (S,) rho (1 + ca) V
    drag: np.ndarray        # (S,) 1/2 rho cd D L
    heave: np.ndarray       # (S, 6N): the centre's height change for displacements x (heave, roll, pitch)
    motion: np.ndarray      # (3S, 6N): the centres' velocities v + omega x lever, normal to the member
    loads: np.ndarray       # (6N, 3S): force and moment about the reference point of the segment forces
    wave: Kinematics        # at the segments' centres, normal to the member
    n_bodies: int

    @classmethod
    def of(cls, body: np.ndarray, lever: np.ndarray, z0: np.ndarray, axis: np.ndarray, inertia: np.ndarray,
           drag: np.ndarray, wave: Kinematics, n_bodies: int) -> "MorisonSet":
        """The set of segments on server bodies ``body`` (S,) along unit ``axis`` (S, 3), its linear
        maps assembled (``wave`` already normal to the axes: Kinematics ``normal_to``)."""
        n_seg = len(body)
        heave = np.zeros((n_seg, 6 * n_bodies))
        cols = 6 * body
        rows = np.arange(n_seg)
        heave[rows, cols + 2], heave[rows, cols + 3], heave[rows, cols + 4] = 1.0, lever[:, 1], -lever[:, 0]
        skew = _skew(lever)
        motion = np.zeros((n_seg, 3, n_bodies, 6))
        motion[rows, :, body, :3] = np.eye(3)
        motion[rows, :, body, 3:] = -skew                                   # omega x r = -[r]x omega
        normal = np.eye(3)[None] - axis[:, :, None] * axis[:, None, :]        # (S, 3, 3): w - (w.a) a
        motion = np.einsum("sij,sjnk->sink", normal, motion)
        loads = np.zeros((n_bodies, 6, n_seg, 3))
        loads[body, :3, rows, :] = np.eye(3)
        loads[body, 3:, rows, :] = skew                                     # r x f
        return cls(lever, z0, inertia, drag, heave, motion.reshape(3 * n_seg, -1),
                   loads.reshape(6 * n_bodies, -1), wave, n_bodies)

    def force(self, t: float, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(N, 6) force and moment on each body for displacements ``x`` and velocities ``v``
        (N, 6) from equilibrium."""
        wet = (self.z0 + self.heave @ x.reshape(-1)) <= 0.0
        un, an = self.wave.velocity_acceleration(t)
        wn = un - (self.motion @ v.reshape(-1)).reshape(-1, 3)
        f = (self.inertia[:, None] * an + (self.drag * np.sqrt((wn * wn).sum(axis=1)))[:, None] * wn) * wet[:, None]
        return (self.loads @ f.reshape(-1)).reshape(self.n_bodies, 6)


def build_morison(scene: Scene, wet: list[int], waves: WaveComponents,
                  reference_points: np.ndarray) -> tuple[MorisonSet, np.ndarray] | None:
    """The scene's Morison elements over the server's wet bodies (scene indices ``wet``), and their
    added mass (6N, 6N); None when the scene has none."""
    if not scene.morison:
        return None
    rho = scene.water.density
    names = [scene.bodies[i].name for i in wet]
    body, centre, axes, inertia, drag, ca_vol = [], [], [], [], [], []
    for m in scene.morison:
        a, b = np.asarray(m.point_a, float), np.asarray(m.point_b, float)
        axis = (b - a) / np.linalg.norm(b - a)
        n = m.segments
        length = float(np.linalg.norm(b - a)) / n
        for s in range(n):
            body.append(names.index(m.body))
            centre.append(a + (s + 0.5) / n * (b - a))
            axes.append(axis)
            vol = np.pi * m.diameter ** 2 / 4 * length
            inertia.append(rho * (1.0 + m.ca) * vol)
            drag.append(0.5 * rho * m.cd * m.diameter * length)
            ca_vol.append(rho * m.ca * vol)
    body, centre = np.asarray(body), np.asarray(centre)
    lever = centre - reference_points[body]
    flow = Kinematics(waves, centre, scene.water.gravity, scene.water.depth_m, scene.current, normal_to=np.asarray(axes))
    ms = MorisonSet.of(body, lever, centre[:, 2].copy(), np.asarray(axes), np.asarray(inertia), np.asarray(drag),
                       flow, len(wet))
    n6 = 6 * len(wet)
    added = np.zeros((n6, n6))
    skew = _skew(lever)
    for s in np.flatnonzero(centre[:, 2] <= 0.0):
        p = ca_vol[s] * (np.eye(3) - np.outer(axes[s], axes[s]))      # normal to the member
        rx = skew[s]
        m6 = np.block([[p, -p @ rx], [rx @ p, -rx @ p @ rx]])
        k = 6 * body[s]
        added[k:k + 6, k:k + 6] += m6
    return ms, added


class MorisonTerm(ForceTerm):
    """The scene's Morison elements as a force term (reply field ``morison``): their force on the
    active DOFs, and their members' added mass in the client's mass matrix."""

    name = "morison"
    scene_keys = ("morison",)
    features = ("morison",)
    needs = frozenset({"time", "position", "velocity"})
    steady = "pointwise"

    def __init__(self, members: MorisonSet, added_mass: np.ndarray, equilibrium: np.ndarray, active: np.ndarray):
        super().__init__(("morison",))
        mask = active.reshape(-1)
        self.members, self.added_mass = members, added_mass * mask[:, None] * mask[None, :]
        self._eq, self._active = equilibrium.copy(), active.astype(float)

    @classmethod
    def build(cls, ctx: TermContext) -> "MorisonTerm | None":
        built = build_morison(ctx.scene, ctx.wet, ctx.waves, ctx.equilibrium[:, :3])
        return None if built is None else cls(*built, ctx.equilibrium, ctx.active)

    def force(self, t: float, position: np.ndarray, velocity: np.ndarray) -> tuple[np.ndarray]:
        return (self.members.force(t, position - self._eq, velocity) * self._active,)
