"""Morison elements on wet bodies (issue 10): slender members cut into segments, Morison's
equation in relative form on each wetted segment with the undisturbed wave's kinematics at the
segment's mean position, u plus the scene's steady current there (server/sea/kinematics.py):

    f_s = rho (1 + ca) V_s a_n + 1/2 rho cd D L_s |w_n| w_n,    w = u - v_s,

n the components normal to the member's axis, u and a the fluid's particle velocity and
acceleration, v_s the segment's velocity (body velocity + angular velocity x lever arm). The
member's own added mass, rho ca V_s on the normal directions, is constant and goes into the body's
mass matrix (``added_mass``, SPEC §5.1), not into this force. A segment is wet while its centre is
below the still water line (linear theory's integral to z = 0), followed with the body's heave,
roll and pitch. Forces and moments about the body's reference point, one reply field ``morison``;
the force term is :class:`MorisonTerm` (server/terms/base.py)."""

from __future__ import annotations

import numpy as np
from hydrolink.protocol.scene import Scene
from hydrolink.server import compiler
from hydrolink.server.terms import morison_kernel
from hydrolink.server.terms.base import ForceTerm, TermContext
from hydrolink.server.sea.kinematics import Kinematics
from hydrolink.server.sea.waves import WaveComponents, WavePhases


def _skew(r: np.ndarray) -> np.ndarray:
    """(S, 3, 3): the matrices [r]x with [r]x f = r x f, for rows r (S, 3)."""
    out = np.zeros(r.shape[:1] + (3, 3))
    out[:, 0, 1], out[:, 0, 2], out[:, 1, 2] = -r[:, 2], r[:, 1], -r[:, 0]
    return out - out.transpose(0, 2, 1)


def normal_basis(axis: np.ndarray) -> np.ndarray:
    """(S, 2, 3): two orthonormal directions normal to each unit ``axis`` (S, 3), the first along
    axis x e with e the coordinate axis least aligned with it (a vertical axis: y and -x, exactly)."""
    e = np.eye(3)[np.argmin(np.abs(axis), axis=1)]
    first = np.cross(axis, e)
    first /= np.linalg.norm(first, axis=1, keepdims=True)
    return np.stack([first, np.cross(axis, first)], axis=1)


class MorisonSet:
    """The segments and the fixed linear maps of a step (built once by :func:`build_morison`).

    Velocities, accelerations and forces are taken along the two directions normal to each member
    (:func:`normal_basis`), plane-major: entry d S + s is segment s along direction d. One product
    ``flow`` @ [cos, sin, v, 1] gives the relative velocities w = u + current - v_s and the
    accelerations (Kinematics.trig); one more, ``loads``, the bodies' loads. With ``compiled``
    (numba installed) all of it after the trig row is one call (server/terms/morison_kernel.py)."""

    def __init__(self, body: np.ndarray, lever: np.ndarray, z0: np.ndarray, basis: np.ndarray, inertia: np.ndarray,
                 drag: np.ndarray, wave: Kinematics, active: np.ndarray, compiled: bool | None = None):
        """The segments on server bodies ``body`` (S,) with levers (S, 3) from their body's
        reference point, centre heights ``z0`` (S,) at equilibrium, normal directions ``basis``
        (S, 2, 3), coefficients rho (1 + ca) V and 1/2 rho cd D L (S,), ``wave`` along the
        directions, for the bodies' ``active`` DOFs (N, 6); ``compiled``: the step by the compiled
        kernel, else by numpy (same results to round-off)."""
        n_seg, n_bodies = len(body), active.shape[0]
        rows = np.arange(n_seg)
        #: (S, 6N) the centre's height change for displacements x (heave, roll, pitch)
        self.heave = np.zeros((n_seg, 6 * n_bodies))
        cols = 6 * body
        self.heave[rows, cols + 2], self.heave[rows, cols + 3], self.heave[rows, cols + 4] = \
            1.0, lever[:, 1], -lever[:, 0]
        self.below = -z0        # wet: the height change at most this (z0 + dz <= 0, exactly so in floats)
        self.wave = wave
        # the segment's velocity along direction e: e . (v + omega x r) = e . v + (r x e) . omega
        arm = np.cross(lever[:, None, :], basis)                              # (S, 2, 3)
        along = np.zeros((2, n_seg, n_bodies, 6))
        along[:, rows, body, :3] = basis.transpose(1, 0, 2)
        along[:, rows, body, 3:] = arm.transpose(1, 0, 2)
        along = along.reshape(2 * n_seg, 6 * n_bodies)
        n2 = 2 * wave.omega.size
        # the wave's velocities then accelerations, each plane-major
        waves = wave.matrix.reshape(n2, 2, n_seg, 2).transpose(0, 1, 3, 2).reshape(n2, 4 * n_seg)
        rest = np.zeros((6 * n_bodies + 1, 4 * n_seg))
        rest[:-1, :2 * n_seg], rest[-1, :2 * n_seg] = -along.T, wave.steady.T.reshape(-1)
        #: (4S, 2n + 6N + 1): [w; a] = flow @ [cos, sin, v, 1]: the wave's velocity, -along and the
        #: current, then the wave's acceleration
        self.flow = np.ascontiguousarray(np.vstack([waves, rest]).T)
        if wave.rhs.size != self.flow.shape[1]:
            raise ValueError("MorisonSet: the kinematics' rhs needs 6N + 1 extra entries")
        #: (N, 6, 4S): force and moment about the reference point of the drag and inertia forces along
        #: the directions (the transpose of ``along``), per unit |w| w and a (their coefficients
        #: 1/2 rho cd D L and rho (1 + ca) V taken in), zero in inactive DOFs
        loads = along.T * active.reshape(-1, 1)
        self.loads = np.hstack([loads * np.tile(drag, 2), loads * np.tile(inertia, 2)]).reshape(n_bodies, 6, -1)
        self._loads = self.loads.reshape(6 * n_bodies, -1)
        self._v = wave.rhs[n2:-1].reshape(n_bodies, 6)      # rhs: [cos, sin, v, 1]
        wave.rhs[-1] = 1.0
        self._out = np.empty((2, 2, n_seg))                 # w, a along the two directions
        self._flat_out = self._out.reshape(-1)
        self._w0, self._w1 = self._out[0]
        self._mask = np.empty((2, 1, n_seg))                # |w| if wet, 1 if wet
        self._speed, self._wet = self._mask[:, 0]
        self._f = np.empty((2, 2, n_seg))                   # |w| w, a on the wet segments
        self._flat_f = self._f.reshape(-1)
        # None: compiled where numba is installed and imports (server/compiler.py)
        self.compiled = compiler.AVAILABLE and compiler.imports() if compiled is None else compiled
        if self.compiled:
            morison_kernel.warm_up()

    def force(self, t: float, x: np.ndarray, v: np.ndarray) -> np.ndarray:
        """(N, 6) force and moment on each body for displacements ``x`` and velocities ``v``
        (N, 6) from equilibrium, zero in inactive DOFs (``x`` writable and C contiguous)."""
        self.wave.trig(t)
        np.copyto(self._v, v)
        if self.compiled:
            return morison_kernel.morison_loads(self.flow, self.wave.rhs, self.heave, x.reshape(-1), self.below,
                                                self._loads).reshape(-1, 6)
        np.dot(self.flow, self.wave.rhs, out=self._flat_out)
        self._wet[:] = np.dot(self.heave, x.reshape(-1)) <= self.below
        np.hypot(self._w0, self._w1, out=self._speed)
        self._speed *= self._wet
        np.multiply(self._out, self._mask, out=self._f)
        return np.dot(self.loads, self._flat_f)


def build_morison(scene: Scene, wet: list[int], waves: WaveComponents, reference_points: np.ndarray,
                  active: np.ndarray, phases: WavePhases | None = None) -> tuple[MorisonSet, np.ndarray] | None:
    """The scene's Morison elements over the server's wet bodies (scene indices ``wet``) for their
    ``active`` DOFs (N, 6), and their added mass (6N, 6N); None when the scene has none. ``phases``:
    the step's [cos wt; sin wt] shared with the linear excitation (None: their own)."""
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
    basis = normal_basis(np.asarray(axes))
    flow = Kinematics(waves, centre, scene.water.gravity, scene.water.depth_m, scene.current, along=basis,
                      phases=phases, extra=6 * len(wet) + 1)
    ms = MorisonSet(body, lever, centre[:, 2].copy(), basis, np.asarray(inertia), np.asarray(drag), flow, active)
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
        self._eq = equilibrium.copy()

    @classmethod
    def build(cls, ctx: TermContext) -> MorisonTerm | None:
        built = build_morison(ctx.scene, ctx.wet, ctx.waves, ctx.equilibrium[:, :3], ctx.active, ctx.phases)
        return None if built is None else cls(*built, ctx.equilibrium, ctx.active)

    def force(self, t: float, position: np.ndarray, velocity: np.ndarray) -> tuple[np.ndarray]:
        return (self.members.force(t, position - self._eq, velocity),)
