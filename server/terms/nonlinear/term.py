"""Nonlinear hydrostatics and Froude–Krylov forces on the instantaneous wetted surface (issue 10;
``[hydro] nonlinear`` or a body's ``nonlinear``; docs/forces.md).

Each step, for every nonlinear body, its closed hull (server/terms/nonlinear/hull.py) is put in the pose
the client sent (reference point + Tait–Bryan angles), cut at the free surface and the pressure
integrated over the wet part:

- ``"hydrostatic"``: the still-water plane z = 0 and p = -rho g z;
- ``"froude-krylov"``: the undisturbed incident wave's surface z = eta(x, y, t) and
  p = -rho g z + p_FK, with the linear incident-wave pressure p_FK = rho g Re sum_c a_c e^{i(theta_c -
  w_c t)} f_c(z_s) (ramp included) at the Wheeler-stretched height z_s = h (z - eta) / (h + eta)
  (z - eta in deep water): the total pressure is zero on the free surface.

The body's weight moves with it (its moment about the reference point follows the rotation). The
client keeps applying the linear parts it already has (the hydrostatic stiffness in its matrix,
the net buoyancy, the HDB's excitation), so this term sends the **difference** to them, two reply
fields over the wet bodies (zero for linear bodies and inactive DOFs):

    nonlinear_hydrostatic   = F_p,hs(x) + F_weight(x) - (net buoyancy e_z - C (x - x_eq))
    nonlinear_froude_krylov = F_p,FK(x, t) - F_FK,lin(t)

F_FK,lin is the same pressure integrated over the hull's mean wetted surface (z <= 0 at rest,
unstretched): in small motion and small waves both differences vanish and the run is the linear
one (up to the HDB's own hydrostatics against the mesh's). The diffraction part stays linear.

The force term is :class:`NonlinearTerm` (server/terms/base.py)."""

from __future__ import annotations

import math
from dataclasses import dataclass, replace
from typing import Any

import numpy as np
from hydrolink.protocol.scene import Scene
from hydrolink.server.terms.nonlinear import hull_kernel, kernels
from hydrolink.server.errors import ModelError
from hydrolink.server.terms.base import ForceTerm, TermContext
from hydrolink.server.terms.nonlinear.rows import BodyConstants, reply_rows
from hydrolink.server.terms.nonlinear.pressure_boxes import BoxGroup, box_table, layout
from hydrolink.server.compiler import AVAILABLE, imports
from hydrolink.server.terms.nonlinear.kernels import HullPass, HullTables, RecurrenceTable
from hydrolink.server.terms.nonlinear.elevation_series import PhaseExpansion, flatten
from hydrolink.server.sea.waves import WaveComponents, ramp_at
from hydrolink.server.terms.nonlinear.hull_kernel import cut_hull_loads
from hydrolink.server.terms.hulls import Hull
from hydrolink.server.terms.nonlinear.hull import clip_wet, corner_loads, interpolate, pressure_load, rotation_xyz

__all__ = ["NonlinearBody", "NonlinearHydro", "NonlinearTerm", "build_nonlinear", "strongest_components"]


def _depth_factor(k: np.ndarray, z: np.ndarray, depth: float) -> np.ndarray:
    """cosh(k (z + h)) / cosh(k h) for z <= 0 (e^{kz} in deep water), (P, n_c), overflow-safe:
    (e^{kz} + e^{-k (z + 2h)}) / (1 + e^{-2kh}), the second term and the division evaluated only
    for the components where, at the lowest point, they reach round-off (e^{-2k (z + h)} > e^{-40}):
    elsewhere they change nothing in floating point."""
    out = np.exp(k[None, :] * z[:, None])
    if math.isinf(depth) or not len(z):
        return out
    near = np.flatnonzero(2.0 * k * (float(z.min()) + depth) < 40.0)
    if len(near):
        kn = k[near]
        out[:, near] = (out[:, near] + np.exp(-kn[None, :] * (z[:, None] + 2 * depth))) / (1.0 + np.exp(-2 * kn * depth))
    return out


# Measured costs [ns] of the compiled sums (server/terms/nonlinear/kernels_numba.py, this 2-vCPU VM): a recurrence's
# start at each point (three complex exponentials, server/terms/nonlinear/vector_math.py's), a point and component
# of it (blocks of points sorted by height stop early), and one component summed directly (two
# exponentials, a cosine and a sine) at a point.
_RECURRENCE_POINT = 25.0
_RECURRENCE_PAIR = 0.5
_DIRECT_PAIR = 40.0


@dataclass(frozen=True)
class _Recurrence:
    """Components of one heading whose wave numbers are a quadratic in their index, ordered by
    frequency: k_c = k0 + c dk + c (c - 1) d2 / 2 (w_c = w0 + c dw, k = w^2 / g in deep water), the
    pressure's sum over them by the compiled recurrence (server/terms/nonlinear/kernels.py)."""
    columns: np.ndarray      # (n_g,) component indices, by increasing frequency
    direction: np.ndarray    # (2,) cos b, sin b
    k0: float
    dk: float
    d2: float


@dataclass(frozen=True)
class _PressureSplit:
    """How the compiled pass sums the Froude–Krylov pressure over the components, per heading:
    the short waves (deep water for them, k h >= 20, and their depth factor e^{kz} to round-off at
    every height above ``floor``) in runs of evenly spaced frequencies by recurrences; the others,
    and the longest of those where that is cheaper, by the boxes' series (server/terms/nonlinear/pressure_boxes.py);
    a heading's others one by one (``direct``) where no box grid is cheaper."""
    recurrences: tuple[_Recurrence, ...]
    boxes: tuple[BoxGroup, ...]
    direct: np.ndarray            # component indices summed one by one
    floor: float                  # m: the lowest stretched height the split holds for (below: all direct)


def _recurrence(cols: np.ndarray, omega: np.ndarray, k: np.ndarray, direction: np.ndarray, g: float,
                reach: float) -> _Recurrence | None:
    """The recurrence of evenly spaced deep-water components ``cols`` (three or more, by frequency)
    where their wave numbers are its quadratic to within a phase of 1e-11 over ``reach``."""
    w, c = omega[cols], np.arange(len(cols), dtype=float)
    dw = (w[-1] - w[0]) / (len(w) - 1)
    k0, dk, d2 = w[0] ** 2 / g, (2.0 * w[0] * dw + dw * dw) / g, 2.0 * dw * dw / g
    if np.max(np.abs(k0 + c * dk + 0.5 * c * (c - 1.0) * d2 - k[cols])) * reach > 1e-11:
        return None
    return _Recurrence(cols, direction, k0, dk, d2)


def _recurrence_cost(runs: list[np.ndarray], points: int) -> float:
    """The estimated cost [ns] of the recurrences ``runs`` (component indices each) at ``points``."""
    return points * sum(_RECURRENCE_POINT + _RECURRENCE_PAIR * len(r) for r in runs)


def _split_components(omega: np.ndarray, k: np.ndarray, heading: np.ndarray, amplitude: np.ndarray, g: float,
                      depth: float, radius: float, floor: float, points: np.ndarray) -> _PressureSplit:
    """The :class:`_PressureSplit` of the components for hulls within ``radius`` (m) horizontally
    of their reference points, ``points`` (P, 3) the largest one's wet vertices at rest (offsets
    x, y from its reference point, height z) to weigh the costs: per heading, the components deep
    to round-off down to ``floor`` (k h >= 20 and 2 k (floor + h) >= 40), in runs of evenly spaced
    frequencies of three or more (one run for a sea's grid; several where ``froude_krylov_energy``
    < 1 kept a subset), whose wave numbers are the recurrence's quadratic to within a phase of 1e-11
    over the hull's diameter, are recurrences but for the longest of them, the boxes' (with the
    others) up to the wave number that makes the heading's estimated cost least."""
    recurrences, boxes, direct = [], [], []
    total = float(amplitude.sum())
    n_p = len(points)
    for b in np.unique(heading):
        direction = np.array([np.cos(b), np.sin(b)])
        cols = np.flatnonzero(heading == b)
        cols = cols[np.argsort(omega[cols], kind="stable")]
        deep = np.ones(len(cols), bool) if math.isinf(depth) else \
            (k[cols] * depth >= 20.0) & (2.0 * k[cols] * (floor + depth) >= 40.0)
        runs, forced = [], [cols[~deep]]
        for run in _even_runs(omega[cols[deep]]):
            run_cols = cols[deep][run]
            if len(run_cols) >= 3 and _recurrence(run_cols, omega, k, direction, g, 2.0 * radius) is not None:
                runs.append(run_cols)
            else:
                forced.append(run_cols)
        forced = np.concatenate(forced)
        sz = np.column_stack([points[:, :2] @ direction, points[:, 2]])
        short = np.sort(k[np.concatenate(runs)]) if runs else np.zeros(0)
        best = (n_p * len(forced) * _DIRECT_PAIR + _recurrence_cost(runs, n_p), None, -math.inf, forced)
        for cut in np.unique(np.concatenate([[-math.inf], short[::max(1, len(short) // 24)], short[-1:]])):
            kept = [r[k[r] > cut] for r in runs]
            boxed = np.concatenate([forced] + [r[k[r] <= cut] for r in runs] + [r for r in kept if len(r) < 3])
            if not len(boxed):
                continue
            n_s, rows, cost = layout(k[boxed], amplitude[boxed], depth, radius, floor, sz, total)
            cost += _recurrence_cost([r for r in kept if len(r) >= 3], n_p)
            if cost < best[0]:
                best = (cost, (n_s, rows), cut, boxed)
        cost, grid, cut, boxed = best
        for r in runs:
            kept = r[k[r] > cut]
            if len(kept) >= 3:
                recurrences.append(_recurrence(kept, omega, k, direction, g, 2.0 * radius))
        if grid is None:
            direct.append(forced)
            continue
        boxes.append(BoxGroup(boxed[np.argsort(k[boxed], kind="stable")], direction, grid[0], grid[1]))
    direct = np.sort(np.concatenate(direct)) if direct else np.zeros(0, np.int64)
    return _PressureSplit(tuple(recurrences), tuple(boxes), direct.astype(np.int64), floor)


def _even_runs(w: np.ndarray) -> list[np.ndarray]:
    """Index runs of ``w`` (sorted) whose steps are equal to within 1e-9 of the step."""
    if len(w) < 2:
        return [np.arange(len(w))] if len(w) else []
    step = np.diff(w)
    breaks = np.flatnonzero(np.abs(np.diff(step)) > 1e-9 * np.abs(step[1:])) + 1   # step i differs from i - 1
    runs, start = [], 0
    for i in breaks:      # step i joins w[i] and w[i + 1]: a run ends at w[i]
        if i > start:
            runs.append(np.arange(start, i + 1))
            start = i + 1
    runs.append(np.arange(start, len(w)))
    return [r for r in runs if len(r)]


def _recurrence_table(split: _PressureSplit, amplitude: np.ndarray) -> RecurrenceTable:
    """The split's recurrences as the compiled pass's flat table, for the components' real
    ``amplitude`` (n_c,)."""
    r = split.recurrences
    return RecurrenceTable(
        direction=np.array([x.direction for x in r], float).reshape(-1, 2),
        start=np.cumsum([0] + [len(x.columns) for x in r]).astype(np.int64),
        columns=flatten([x.columns for x in r], np.int64)[0],
        tail=flatten([np.cumsum(np.abs(amplitude[x.columns])[::-1])[::-1] for x in r])[0],
        k0=np.array([x.k0 for x in r], float), dk=np.array([x.dk for x in r], float),
        d2=np.array([x.d2 for x in r], float), floor=float(split.floor))


@dataclass(frozen=True)
class NonlinearBody:
    """One nonlinear body: where it sits among the wet bodies and what its linear model holds."""
    index: int              # position among the server's wet bodies
    mode: str               # "hydrostatic" | "froude-krylov"
    hull: Hull              # relative to the reference point
    loads: np.ndarray       # (T, 3, 6) its triangles' corner_loads in the body's frame
    vertex_loads: np.ndarray   # (V, 6) their sums over each vertex's triangles
    reference: np.ndarray   # (6,) the pose at equilibrium: reference point, zero angles
    weight: float           # m g [N]
    lever: np.ndarray       # (3,) centre of mass minus reference point, at equilibrium
    linear_net: float       # the net buoyancy rho g V - m g the client applies (setup.net_buoyancy)
    stiffness: np.ndarray   # (6, 6) the body's block of setup.hydrostatic_stiffness (active DOFs only)
    fk_linear: np.ndarray | None   # (6, n_c) phasors of the Froude–Krylov force on the mean wetted surface
    active: np.ndarray      # (6,) 1.0 on active DOFs


class NonlinearHydro:
    """The nonlinear hydrostatic and Froude–Krylov differences for a scene's nonlinear bodies."""

    def __init__(self, bodies: list[NonlinearBody], waves: WaveComponents, rho: float, g: float, depth: float,
                 n_bodies: int, compiled: bool = AVAILABLE):
        """``compiled``: the incident wave on the hulls by the compiled kernels where they apply
        (server/terms/nonlinear/kernels.py), else by numpy (same results to round-off)."""
        self.compiled = compiled
        self.split: _PressureSplit | None = None   # set by prepare (needs the hulls' reach)
        self.tables: HullTables | None = None   # the compiled pass's tables (with the split)
        self.passes: dict[int, HullPass] = {}   # by body index: the Froude-Krylov bodies' compiled passes
        self._rows = reply_rows   # server/terms/nonlinear/rows.py's, compiled on the compiled path (prepare)
        self.constants: dict[int, BodyConstants] = {}   # by body index: the rows' constants (prepare)
        self.bodies, self.rho, self.g, self.depth, self.n_bodies = bodies, rho, g, depth, n_bodies
        self.ramp = waves.ramp
        self.still = waves.size == 0
        self.omega = waves.omega.copy()
        if not self.still:
            self.k = waves.wave_numbers(g, depth)
            beta = self.heading = waves.heading_of()
            self.amp = waves.amplitude * np.exp(1j * waves.phase)
            self.amplitude, self.phase = waves.amplitude.copy(), waves.phase.copy()
            self.k_xy = self.k * np.vstack([np.cos(beta), np.sin(beta)])   # (2, n_c): theta = (x, y) @ k_xy
        self.expansion: PhaseExpansion | None = None   # set by prepare once the hulls are known
        self.warnings: list[str] = []
        self.froude_krylov = False   # some body has "froude-krylov": the reply carries that field (prepare)

    def prepare(self, bodies: list[NonlinearBody]) -> None:
        """Takes the bodies and builds what the steps need of the sea over their hulls: the
        elevation's expansion (every vertex within its radius of the reference point) and, on the
        compiled path, the split of the components (its floor twice the lowest hull's depth) and
        the compiled pass's tables, the kernels compiled or loaded now."""
        self.bodies = bodies
        self.froude_krylov = any(b.mode == "froude-krylov" for b in bodies)
        c = np.ascontiguousarray
        self.constants = {b.index: BodyConstants(self.rho * self.g, c(b.lever, float), float(b.weight),
                                                 c(b.stiffness, float), c(b.reference, float), float(b.linear_net),
                                                 c(b.active, float)) for b in bodies}
        if self.compiled:
            kernels.warm_up()
            hull_kernel.warm_up()
            self._rows = kernels.reply_rows()
        if self.still:
            return
        radius = max(float(np.linalg.norm(b.hull.vertices, axis=1).max()) for b in bodies)
        self.expansion = PhaseExpansion(self.k, self.heading, radius, compiled=self.compiled,
                                        points=max(len(b.hull.vertices) for b in bodies))
        if self.compiled:
            floor = 2.0 * min(float(b.reference[2]) - radius for b in bodies)
            largest = max(bodies, key=lambda b: len(b.hull.vertices))
            at_rest = largest.hull.vertices + [0.0, 0.0, float(largest.reference[2])]
            self.split = _split_components(self.omega, self.k, self.heading, self.amplitude, self.g, self.depth,
                                           self.expansion.radius, floor, at_rest[at_rest[:, 2] <= 0.0])
            direct = self.split.direct
            direction = np.column_stack([np.cos(self.heading), np.sin(self.heading)])
            self.tables = HullTables(self.expansion.table, _recurrence_table(self.split, self.amplitude),
                                     box_table(list(self.split.boxes), self.k, self.depth, self.expansion.radius, floor),
                                     direct, direction[direct], direction)
            self.passes = {b.index: HullPass(b.hull.vertices, b.hull.triangles, b.loads, b.vertex_loads, self.omega,
                                             self.amp, self.k, self.depth, self.tables, b.fk_linear,
                                             self.constants[b.index])
                           for b in bodies if b.mode == "froude-krylov"}

    def _phasors(self, pts: np.ndarray) -> np.ndarray:
        """a_c e^{i theta_c(x, y)} at points (P, 3): (P, n_c)."""
        return self.amp[None, :] * np.exp(1j * (pts[:, :2] @ self.k_xy))

    def _stretched(self, z: np.ndarray, eta: np.ndarray) -> np.ndarray:
        """Wheeler-stretched heights of points at heights ``z`` under the elevation ``eta``, at most
        at the surface and at least at the seabed (a hull sent below the seabed gets the seabed's
        pressure, not an overflow of the depth factor)."""
        h = self.depth
        return np.clip(z - eta if math.isinf(h) else h * (z - eta) / (h + eta), -h, 0.0)

    def _direct_pressure(self, pts: np.ndarray, z_s: np.ndarray, cols, t: float) -> np.ndarray:
        """sum_c a_c cos(theta_c(x, y) + phi_c - w_c t) f_c(z_s) over the components ``cols`` at
        points (P, 3), stretched heights ``z_s`` (P,) <= 0: one cosine and one depth factor per
        point and component (no complex exponential, no sine)."""
        theta = pts[:, :2] @ self.k_xy[:, cols]
        theta += self.phase[cols] - self.omega[cols] * t
        f = _depth_factor(self.k[cols], z_s, self.depth)
        f *= np.cos(theta, out=theta)
        return f @ self.amplitude[cols]

    def fk_linear_phasors(self, hull: Hull, reference: np.ndarray) -> np.ndarray:
        """(6, n_c) complex: the Froude–Krylov force and moment of each wave component (unit time
        factor e^{-iwt}) over the hull's wetted surface at rest, unstretched."""
        corners = (hull.vertices + reference)[hull.triangles]
        pts, _ = clip_wet(corners, corners[..., 2])
        flat = pts.reshape(-1, 3)
        p = self.rho * self.g * self._phasors(flat) * _depth_factor(self.k, np.minimum(flat[:, 2], 0.0), self.depth)
        p = p.reshape(len(pts), 3, -1)
        lever = pts - reference
        return pressure_load(lever, p.real) + 1j * pressure_load(lever, p.imag)

    def force(self, t: float, position: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The two differences (N, 6) each (module docstring) for the absolute poses (N, 6).

        The pressures are integrated over the wet part of each hull in the body's frame about its
        reference point, and the loads turned to the global axes at the end: for a Froude–Krylov
        body on the compiled path in one pass (kernels.HullPass), else the pressures at
        the vertices by :meth:`_surface` and their integral by server/terms/nonlinear/hull_kernel.py
        (compiled) or :func:`_wet_loads`; the rows from the loads by server/terms/nonlinear/rows.py."""
        hs, fk = np.zeros((self.n_bodies, 6)), np.zeros((self.n_bodies, 6))
        ramp = ramp_at(t, self.ramp)
        for b in self.bodies:
            pose = np.ascontiguousarray(position[b.index], np.float64)
            compiled = self.passes.get(b.index)     # a Froude–Krylov body in waves, on the compiled path
            if compiled is not None and compiled(pose, t, ramp, hs[b.index], fk[b.index]):
                continue
            waves = b.mode == "froude-krylov" and not self.still
            rot = rotation_xyz(pose[3:])
            z, d, p_v = self._surface(b, pose, rot, t, ramp) if waves else self._still_surface(b, pose, rot)
            if self.compiled:
                loads = cut_hull_loads(b.hull.vertices, b.hull.triangles, d, z, p_v, b.loads, b.vertex_loads)
            else:
                loads = _wet_loads(b, z, d, np.flatnonzero(d <= 0.0), p_v)
            fk_linear = np.ascontiguousarray(np.real(b.fk_linear @ (ramp * np.exp(-1j * self.omega * t)))) \
                if waves else np.zeros(6)
            self._rows(loads, fk_linear, rot, pose, self.constants[b.index], hs[b.index], fk[b.index])
        return hs, fk

    @staticmethod
    def _still_surface(b: NonlinearBody, pose: np.ndarray, rot: np.ndarray) -> tuple[np.ndarray, ...]:
        """(z, d, p) of :meth:`_surface` on the still-water plane: d = z, no Froude–Krylov pressure."""
        z = pose[2] + b.hull.vertices @ rot[2]
        return z, z, np.zeros(len(z))

    def _surface(self, b: NonlinearBody, pose: np.ndarray, rot: np.ndarray, t: float,
                 ramp: float) -> tuple[np.ndarray, ...]:
        """(z, d, p) (V,) each: the hull's vertices' global heights, their signed heights above the
        incident free surface (z - eta, the elevation by the Jacobi–Anger series) and the
        Froude–Krylov pressure per unit rho g at the wet ones (zero at the dry), Wheeler-stretched,
        by :meth:`_direct_pressure`: the numpy path, and the compiled one's below its floor."""
        offset = b.hull.vertices @ rot.T
        verts = pose[:3] + offset
        eta = ramp * self.expansion.elevation(offset[:, :2], pose[:2], self.phase - self.omega * t, self.amplitude)
        d = verts[:, 2] - eta
        wet = np.flatnonzero(d <= 0.0)
        p = np.zeros(len(verts))
        p[wet] = ramp * self._direct_pressure(verts[wet], self._stretched(verts[wet, 2], eta[wet]), slice(None), t)
        return verts[:, 2], d, p


def _wet_loads(b: NonlinearBody, z: np.ndarray, d: np.ndarray, wet_v: np.ndarray, p_v: np.ndarray) -> np.ndarray:
    """(2, 6): the loads per unit rho g of the hydrostatic pressure -z and the Froude–Krylov
    pressure ``p_v`` (V,) over the wet part of the hull (d <= 0) in the body's frame, by numpy
    (server/terms/nonlinear/hull_kernel.py compiles the same sum): the wholly wet triangles as the wet
    vertices' pressures times their per-vertex load sums, less what the cut triangles' wet corners
    added there; the cut triangles through :func:`clip_wet`."""
    tris = b.hull.triangles
    count = (d <= 0.0)[tris].sum(axis=1)
    part = np.flatnonzero((count == 1) | (count == 2))
    pts, cut = clip_wet(b.hull.vertices[tris[part]], d[tris[part]])
    z_c = interpolate(z[tris[part]], cut)                       # global heights of their corners
    p_c = interpolate(p_v[tris[part]], cut)
    surface = cut.s < 1.0
    p_c[surface] = z_c[surface]   # on the free surface p_FK = rho g eta = rho g z (stretched)
    p = np.stack([-z, p_v])
    p[0, d > 0.0] = 0.0
    full = p[:, wet_v] @ b.vertex_loads[wet_v] - p[:, tris[part]].reshape(2, -1) @ b.loads[part].reshape(-1, 6)
    return full + np.stack([-z_c.reshape(-1), p_c.reshape(-1)]) @ corner_loads(pts).reshape(-1, 6)


def _vertex_sums(hull: Hull, loads: np.ndarray) -> np.ndarray:
    """(V, 6): the corner loads (T, 3, 6) of the hull's triangles summed over each vertex."""
    out = np.zeros((len(hull.vertices), 6))
    np.add.at(out, hull.triangles.reshape(-1), loads.reshape(-1, 6))
    return out


def strongest_components(waves: WaveComponents, fraction: float) -> WaveComponents:
    """The fewest components, most energetic first, whose variance sum a_c^2 / 2 reaches
    ``fraction`` of the sea's (``[hydro] froude_krylov_energy``; all of them at 1), in their
    original order."""
    if fraction >= 1.0 or waves.size <= 1:
        return waves
    energy = waves.amplitude ** 2
    order = np.argsort(-energy, kind="stable")
    n = int(np.searchsorted(np.cumsum(energy[order]), fraction * energy.sum() * (1 - 1e-12))) + 1
    keep = np.sort(order[:min(n, waves.size)])
    return replace(waves, omega=waves.omega[keep], amplitude=waves.amplitude[keep], phase=waves.phase[keep],
                   headings=None if waves.headings is None else waves.headings[keep])


def build_nonlinear(scene: Scene, wet: list[int], hulls: dict[str, Hull], waves: WaveComponents,
                    references: np.ndarray, stiffness: np.ndarray, net_buoyancy: list[float | None],
                    active: np.ndarray) -> NonlinearHydro | None:
    """The scene's nonlinear bodies over the server's wet bodies (scene indices ``wet``), or None
    when every body is linear. ``hulls`` by body name (checked by the caller: one for each
    nonlinear body); ``stiffness`` the setup's (6N, 6N) hydrostatic stiffness, ``net_buoyancy``
    the setup's per wet body (None: none applied)."""
    water = scene.water
    kept = strongest_components(waves, scene.hydro.froude_krylov_energy)
    model = NonlinearHydro([], kept, water.density, water.gravity, water.depth_m, len(wet),
                           compiled=AVAILABLE and imports())
    bodies = []
    for k, i in enumerate(wet):
        body = scene.bodies[i]
        mode = scene.nonlinear_of(body)
        if mode == "none":
            continue
        ref = np.asarray(references[k], float)
        equilibrium = np.concatenate([ref, np.zeros(3)])
        hull = Hull(hulls[body.name].vertices - ref, hulls[body.name].triangles, hulls[body.name].volume)
        fk = model.fk_linear_phasors(hull, ref) if mode == "froude-krylov" and kept.size else None
        at_rest = hull.vertices[hull.triangles]
        pts, _ = clip_wet(at_rest, at_rest[..., 2] + ref[2])
        volume = float(pressure_load(pts, -(pts[..., 2] + ref[2]))[2])    # buoyancy / (rho g) at rest
        linear_volume = (float(net_buoyancy[k]) + body.mass * water.gravity) / (water.density * water.gravity) \
            if net_buoyancy[k] is not None else None
        if linear_volume is not None and abs(volume - linear_volume) > 0.01 * linear_volume:
            model.warnings.append(
                f"bodies[{i}].mesh: the hull of body {body.name!r} displaces {volume:.6g} m^3 at rest, its HDB "
                f"{linear_volume:.6g} m^3 ({100 * (volume / linear_volume - 1):+.3g} %): the nonlinear hydrostatic "
                f"force holds the difference, {water.density * water.gravity * (volume - linear_volume):.4g} N, "
                "from the start")
        loads = corner_loads(hull.vertices[hull.triangles])
        bodies.append(NonlinearBody(
            index=k, mode=mode, hull=hull, loads=loads, vertex_loads=_vertex_sums(hull, loads), reference=equilibrium,
            weight=body.mass * water.gravity,
            lever=body.com_or(ref) - ref, linear_net=float(net_buoyancy[k] or 0.0),
            stiffness=stiffness[6 * k:6 * k + 6, 6 * k:6 * k + 6].copy(), fk_linear=fk,
            active=active[k].astype(float)))
    if not bodies:
        return None
    if kept.size < waves.size and any(b.mode == "froude-krylov" for b in bodies):
        share = float(np.sum(kept.amplitude ** 2) / np.sum(waves.amplitude ** 2))
        model.warnings.append(
            f"hydro.froude_krylov_energy: the nonlinear Froude-Krylov pressure and free surface use the "
            f"{kept.size} most energetic of {waves.size} wave components ({100 * share:.4g} % of the variance); "
            "the others act through the linear excitation only. Set it to 1 for all of them")
    model.prepare(bodies)
    return model


class NonlinearTerm(ForceTerm):
    """The nonlinear hydrostatic (and Froude–Krylov) differences as a force term: reply fields
    ``nonlinear_hydrostatic`` and, when some body has ``"froude-krylov"``, ``nonlinear_froude_krylov``."""

    name = "nonlinear_hydrostatics"
    scene_keys = ("hydro.nonlinear", "bodies[i].nonlinear", "bodies[i].mesh")
    features = ("nonlinear_hydrostatics", "nonlinear_froude_krylov")
    needs = frozenset({"time", "position"})
    steady = None      # its Jacobian in position is not part of hydrolink steady's Newton yet

    def __init__(self, model: NonlinearHydro):
        super().__init__(("nonlinear_hydrostatic",) + (("nonlinear_froude_krylov",) if model.froude_krylov else ()))
        self.model, self.warnings = model, tuple(model.warnings)

    @classmethod
    def build(cls, ctx: TermContext) -> NonlinearTerm | None:
        scene = ctx.scene
        for i in ctx.wet:
            body = scene.bodies[i]
            if scene.nonlinear_of(body) != "none" and body.name not in ctx.hulls:
                raise ModelError(f"bodies[{i}].mesh", f"body {body.name!r} has nonlinear hydrostatics "
                                 f"({scene.nonlinear_of(body)!r}) but the hello brought no hull for it (meshes, "
                                 "SPEC §5.1: the client sends the closed hull it reads from the body's mesh or "
                                 "build spec)")
        model = build_nonlinear(scene, ctx.wet, dict(ctx.hulls), ctx.waves, ctx.equilibrium[:, :3],
                                ctx.hydrostatic_stiffness, ctx.net_buoyancy, ctx.active)
        return None if model is None else cls(model)

    def force(self, t: float, position: np.ndarray, velocity: np.ndarray) -> tuple[np.ndarray, ...]:
        hs, fk = self.model.force(t, position)
        return (hs, fk) if self.model.froude_krylov else (hs,)

    def setup_entries(self, bodies: tuple[str, ...]) -> dict[str, Any]:
        return {"nonlinear": {bodies[b.index]: b.mode for b in self.model.bodies}}
