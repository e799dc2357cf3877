"""The internal loads along a body's axis (shear, bending, torsion) from a run's recorded motion: the
method is docs/generalized-modes.md "Loads along a body".

For each station s the part P of the body beyond it (axis coordinate > s) is held in equilibrium by
the load the rest of the body exerts on it across the cut: F_s = m_P a_P - F_water,P - F_weight,P
(and the moments about the station's point on the mass line), linear in the motion, in the body's
axes. Every linear part is a (S, 6, n) matrix of the cut rows built once from the panel set
(server/hdb/build/panels.py) and the mass line: the water's pressures summed over P with the weights
-n dS and -(r - S) x n dS, the hydrostatic rise of each panel, P's weight turning with the body and
its inertia. A run's series then takes a few matrix products and one FFT convolution."""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from hydrolink.protocol.scene import Body, BodySections, Scene
from hydrolink.server.allocation import require_size
from hydrolink.server.errors import ModelError
from hydrolink.server.hdb.build.panels import PanelPressures
from hydrolink.server.loads.water import RecordedMotion, linear_rows, water_series
from hydrolink.server.sea.waves import WaveComponents

AXES = {"x": 0, "y": 1, "z": 2}
MASS_TOLERANCE = 1e-3      # the mass line's total and centre against the body's (relative; centre: of its length)
INERTIA_WARNING = 0.01     # its rotary inertia against the body's: warned about beyond this share


def _skew(v: np.ndarray) -> np.ndarray:
    """(..., 3, 3) the cross-product matrices of v (..., 3): skew(v) @ u = v x u."""
    out = np.zeros((*v.shape[:-1], 3, 3))
    out[..., 0, 1], out[..., 0, 2], out[..., 1, 2] = -v[..., 2], v[..., 1], -v[..., 0]
    out[..., 1, 0], out[..., 2, 0], out[..., 2, 1] = v[..., 2], -v[..., 1], v[..., 0]
    return out


@dataclass(frozen=True)
class MassLine:
    """A body's mass along its axis: uniform segments and point masses on the line through ``line``."""
    axis: int
    edges: np.ndarray        # (k + 1,) segment edges along the axis
    per_length: np.ndarray   # (k,) kg/m
    own: np.ndarray          # (k, 3) each segment's rotary inertia per length about its centroid (x, y, z)
    points: np.ndarray       # (q, 2) [position, kg]
    line: np.ndarray         # (3,) a point of the line (the body's centre of mass)

    def beyond(self, s: float) -> tuple[float, np.ndarray, np.ndarray]:
        """Mass, centre (3,) and inertia tensor about that centre (3, 3) of the part beyond ``s``."""
        lo = np.clip(self.edges[:-1], s, None)
        length = np.clip(self.edges[1:] - lo, 0.0, None)
        m = np.concatenate((self.per_length * length, self.points[self.points[:, 0] > s, 1]))
        at = np.concatenate((lo + 0.5 * length, self.points[self.points[:, 0] > s, 0]))
        own = np.concatenate(((self.own * length[:, None]).sum(axis=0, keepdims=True), np.zeros((1, 3))))
        total = float(m.sum())
        centre = self.line.copy()
        inertia = np.diag(own.sum(axis=0))
        if total <= 0.0:
            return 0.0, centre, np.zeros((3, 3))
        centre[self.axis] = float(m @ at) / total
        across = (self.per_length * length ** 3).sum() / 12.0 + float(m @ (at - centre[self.axis]) ** 2)
        for k in range(3):
            if k != self.axis:
                inertia[k, k] += across
        return total, centre, inertia


def mass_line(sections: BodySections, body: Body, key: str) -> tuple[MassLine, list[str]]:
    """The scene's mass line, checked against the body's mass and centre of mass (ModelError naming
    ``key.mass_per_length``) and its rotary inertia (a warning naming ``key.section_inertia``)."""
    a = AXES[sections.axis]
    k = len(sections.mass_per_length)
    own = np.zeros((k, 3)) if sections.section_inertia is None else np.asarray(sections.section_inertia, float)
    cog = np.asarray(body.com_or(np.zeros(3)), float)
    ml = MassLine(a, np.asarray(sections.mass_stations, float), np.asarray(sections.mass_per_length, float), own,
                  np.asarray(sections.point_masses, float).reshape(-1, 2), cog)
    mass, centre, inertia = ml.beyond(-np.inf)
    length = float(ml.edges[-1] - ml.edges[0])
    if abs(mass - body.mass) > MASS_TOLERANCE * body.mass or abs(centre[a] - cog[a]) > MASS_TOLERANCE * length:
        raise ModelError(f"{key}.mass_per_length", f"the mass line holds {mass:.6g} kg centred at {sections.axis} = "
                         f"{centre[a]:.6g} m; the body has mass {body.mass:.6g} kg at {cog[a]:.6g} m (within "
                         f"{100 * MASS_TOLERANCE:g} %): the loads would not balance")
    warnings = []
    if body.inertia is not None:
        given = np.asarray(body.inertia, float)
        given = np.diag(given) if given.ndim == 1 else given
        off = np.abs(np.diag(inertia) - np.diag(given)) / np.maximum(np.abs(np.diag(given)), 1e-300)
        if off.max() > INERTIA_WARNING:
            warnings.append(f"{key}.section_inertia: the mass line's rotary inertia {np.round(np.diag(inertia), 1).tolist()} "
                            f"kg m^2 differs from the body's inertia {np.round(np.diag(given), 1).tolist()} by up to "
                            f"{100 * off.max():.3g} %: the moments at the near end will not vanish")
    return ml, warnings


def _linear_load(ps: PanelPressures, beyond: np.ndarray, points: np.ndarray, alpha: float, beta: np.ndarray,
                 ) -> np.ndarray:
    """(S, 6) the load -[integral of p n dS; integral of p (r - S) x n dS] over each station's part of a
    pressure p = alpha + beta . r, exact on flat panels (their area, first and second moments)."""
    first = ps.area[:, None] * ps.center                                          # (P, 3) integral of r dS
    amount = alpha * ps.area + first @ beta                                        # (P,) integral of p dS
    # integral of p (r - S) dS = alpha (first - S A) + R2 beta - S (beta . first)
    q = (alpha * first + ps.second_moment @ beta)[None] - points[:, None, :] * amount[None, :, None]   # (S, P, 3)
    force = -np.einsum("sp,p,pk->sk", beyond, amount, ps.normal)
    moment = -np.einsum("sp,spk->sk", beyond, np.cross(q, ps.normal[None]))
    return np.concatenate((force, moment), axis=1)


@dataclass(frozen=True)
class SectionCuts:
    """The linear cut rows of one body's stations (module docstring): each (S, 6, ...) maps to the
    load [force; moment] on the part beyond each station, in the body's axes."""
    body: str
    axis: int
    stations: np.ndarray       # (S,)
    points: np.ndarray         # (S, 3) the stations' points on the mass line
    still: np.ndarray          # (S, 6) the load at rest in calm water
    inertia: np.ndarray        # (S, 6, 6) over the body's acceleration [a_r; alpha]
    restoring: np.ndarray      # (S, 6, 6) the water's and weight's change over [xi; theta]
    weights: np.ndarray        # (S, 6, P) pressure -> load on P
    dofs: tuple[str, ...]      # the panel set's DOFs (the radiation's columns)

    def after_first(self) -> "SectionCuts":
        """These cuts without their first station (a check station computed with the others)."""
        return SectionCuts(self.body, self.axis, self.stations[1:], self.points[1:], self.still[1:], self.inertia[1:],
                           self.restoring[1:], self.weights[1:], self.dofs)

    def rows(self, panel_values: np.ndarray) -> np.ndarray:
        """(..., P) per-panel values -> (..., S, 6): summed over each station's part."""
        return np.einsum("skp,...p->...sk", self.weights, panel_values)


def section_cuts(ps: PanelPressures, sections: BodySections, body: Body, key: str, rho: float, g: float,
                 ) -> tuple[SectionCuts, list[str]]:
    """The cut rows of a body (module docstring); ModelError naming ``key`` for stations outside its
    hull or a mass line that does not fit the body."""
    ml, warnings = mass_line(sections, body, key)
    a = ml.axis
    along = ps.center[:, a]
    st = np.asarray(sections.stations, float)
    if st[0] < along.min() or st[-1] > along.max():
        raise ModelError(f"{key}.stations", f"stations {st.tolist()} reach beyond the hull's panels "
                         f"({along.min():.4g}..{along.max():.4g} m along {sections.axis})")
    require_size(f"{key}.stations", "the stations' panel weights", (st.size, 6, ps.panels))
    points = np.repeat(ml.line[None], st.size, axis=0)
    points[:, a] = st
    # a panel is beyond a station when its centre is; one whose centre lies on the cut belongs to the part
    # beyond when it faces back (a near end face): so the hull's first end cuts off all, its last none
    tie = np.isclose(along[None, :], st[:, None], rtol=0.0, atol=1e-9 * (1.0 + np.abs(along).max()))
    beyond = ((along[None, :] > st[:, None]) & ~tie | tie & (ps.normal[None, :, a] < 0)).astype(float)  # (S, P)
    n_ds = ps.normal * ps.area[:, None]                                            # (P, 3)
    arm = ps.center[None, :, :] - points[:, None, :]                               # (S, P, 3)
    weights = -np.concatenate((np.broadcast_to(n_ds.T[None], (st.size, 3, ps.panels)),
                               np.cross(arm, n_ds[None]).transpose(0, 2, 1)), axis=1) * beyond[:, None, :]
    ref = ps.reference_point
    g_vec = np.array([0.0, 0.0, -g])
    # the hydrostatic pressure, linear in r: at rest -rho g z, its change -rho g dz with the panel's rise
    # dz = xi_3 + theta_1 (y - y_r) - theta_2 (x - x_r): each (alpha, beta) of p = alpha + beta . r
    still = _linear_load(ps, beyond, points, 0.0, np.array([0.0, 0.0, -rho * g]))
    restoring = np.zeros((st.size, 6, 6))
    for j, (alpha, beta) in {2: (-rho * g, np.zeros(3)), 3: (rho * g * ref[1], np.array([0.0, -rho * g, 0.0])),
                             4: (-rho * g * ref[0], np.array([rho * g, 0.0, 0.0]))}.items():
        restoring[:, :, j] = _linear_load(ps, beyond, points, alpha, beta)
    inertia = np.zeros((st.size, 6, 6))
    for i, s in enumerate(st):
        m, c, i_c = ml.beyond(float(s))
        lever = c - points[i]
        still[i, :3] += m * g_vec
        still[i, 3:] += m * np.cross(lever, g_vec)
        # F_s = m a_G, a_G = a_r + alpha x (c - r); M_s = I_c alpha + lever x m a_G
        to_g = np.hstack((np.eye(3), -_skew(c - ref)))                              # (3, 6): [a_r; alpha] -> a_G
        inertia[i, :3] = m * to_g
        inertia[i, 3:] = m * _skew(lever) @ to_g
        inertia[i, 3:, 3:] += i_c
        # the weight in the body's axes, m (g - theta x g): its change m g x theta ... over theta
        turn = m * _skew(g_vec)                                                     # -theta x g = g x theta
        restoring[i, :3, 3:] += turn
        restoring[i, 3:, 3:] += _skew(lever) @ turn
    cuts = SectionCuts(body.name, a, st, points, -still, inertia, restoring, weights, ps.dofs)
    return cuts, warnings


def section_loads(cuts: SectionCuts, ps: PanelPressures, motion: RecordedMotion, scene: Scene, waves: WaveComponents,
                  ) -> np.ndarray:
    """(T, S, 6) the loads at the stations over the recorded rows (module docstring), the still-water
    part included; ``waves`` the model's components (server/sea), ``scene`` its [hydro] radiation."""
    t = motion.time
    shape = (t.size, *cuts.still.shape)
    require_size("bodies.sections", "the loads along the body over the run", shape)
    loads = cuts.still + np.einsum("skj,tj->tsk", cuts.inertia, motion.acceleration) \
        - np.einsum("skj,tj->tsk", cuts.restoring, motion.displacement)
    rows = linear_rows(ps, cuts.weights.reshape(-1, ps.panels))
    return loads - water_series(rows, ps, motion, scene, waves, cuts.body).reshape(shape)
