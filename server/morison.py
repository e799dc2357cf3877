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


def _cross(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Row-wise a x b of (S, 3) arrays (np.cross without its axis handling: the hot path)."""
    return np.column_stack([a[:, 1] * b[:, 2] - a[:, 2] * b[:, 1], a[:, 2] * b[:, 0] - a[:, 0] * b[:, 2],
                            a[:, 0] * b[:, 1] - a[:, 1] * b[:, 0]])


@dataclass(frozen=True)
class MorisonSet:
    body: np.ndarray        # (S,) server body index of each segment
    lever: np.ndarray       # (S, 3) segment centre minus the body's reference point, at equilibrium
    z0: np.ndarray          # (S,) segment centre height at equilibrium
    axis: np.ndarray        # (S, 3) unit vector along the member (the normal part of w: w - (w.a) a)
    gather: np.ndarray      # (N, S) 1 where segment s belongs to body n (sums segments per body)
    inertia: np.ndarray     # (S,) rho (1 + ca) V
    drag: np.ndarray        # (S,) 1/2 rho cd D L
    wave: Kinematics        # at the segments' centres
    n_bodies: int

    def force(self, t: float, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(N, 6) force and moment on each body for displacements ``x`` and velocities ``v``
        (N, 6) from equilibrium."""
        xb, vb = x[self.body], v[self.body]                          # (S, 6)
        z = self.z0 + xb[:, 2] + xb[:, 3] * self.lever[:, 1] - xb[:, 4] * self.lever[:, 0]
        wet = z <= 0.0
        u, acc = self.wave.velocity_acceleration(t)
        w = u - vb[:, :3] - _cross(vb[:, 3:], self.lever)
        wn = w - (w * self.axis).sum(axis=1)[:, None] * self.axis
        an = acc - (acc * self.axis).sum(axis=1)[:, None] * self.axis
        f = (self.inertia[:, None] * an + (self.drag * np.sqrt((wn * wn).sum(axis=1)))[:, None] * wn) * wet[:, None]
        return np.hstack([self.gather @ f, self.gather @ _cross(self.lever, f)])


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
    gather = (np.arange(len(wet))[:, None] == body[None, :]).astype(float)
    flow = Kinematics(waves, centre, scene.water.gravity, scene.water.depth_m, scene.current)
    ms = MorisonSet(body, lever, centre[:, 2].copy(), np.asarray(axes), gather, np.asarray(inertia),
                    np.asarray(drag), flow, len(wet))
    n6 = 6 * len(wet)
    added = np.zeros((n6, n6))
    for s in np.flatnonzero(centre[:, 2] <= 0.0):
        p = ca_vol[s] * (np.eye(3) - np.outer(axes[s], axes[s]))      # normal to the member
        rx = np.array([[0, -lever[s, 2], lever[s, 1]], [lever[s, 2], 0, -lever[s, 0]], [-lever[s, 1], lever[s, 0], 0]])
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
