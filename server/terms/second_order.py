"""Second-order wave forces (issue 23): mean drift, Newman slow drift, full difference QTF, sum QTF.

Scene keys: ``[hydro] second_order`` (a body's own ``second_order`` overrides it), ``[hydro]
drift_method``, ``[hydro] sum_frequency``; data: protocol/hdb/second_order.py's layout.

Wave components (server/sea/waves.py): eta = sum_i A_i cos(w_i t - phi_i) = Re sum_i z_i(t) with
z_i(t) = c_i e^{-i w_i t}, c_i = A_i e^{+i phi_i}. The HDB's a_i = A_i e^{-i phi_i} belongs to
eta = sum A_i cos(w_i t + phi_i), i.e. a_i is our c_i with phi -> -phi: the HDB's formulas hold
with a_i e^{-i w_i t} = z_i(t). So, for each force DOF d and r(t) the excitation's ramp,

    mean drift   F_d = r^2 sum_i A_i^2 T_ii,d      (T_ii: mean_drift at w_i, b_i; an HDB without mean
                                                    drift: the difference QTF's diagonal T-(w_i, w_i))
    Newman       F_d = r^2 Re[(sum_i z_i T_ii,d) conj(sum_j z_j)]
                 (Newman's T_ij = 1/2 (T_ii + T_jj) exactly: the double sum Re sum_ij z_i conj(z_j)
                 1/2 (T_ii + T_jj) is the real part of one product of two single sums, O(N))
    difference   F_d = r^2 Re sum_ij z_i conj(z_j) T-_ij,d
    sum          F_d = r^2 Re sum_ij z_i z_j T+_ij,d

(the ramp squared: the force is quadratic in the amplitudes). The QTFs are interpolated
bilinearly from their grid, T_ij = sum_ab L_ia L_jb G_ab with L (n_c, n_q) the linear
interpolation weights, so with y = L^T z (n_q values per heading) the double sums are
Re y^T G conj(y) and Re y^T G y: O(N n_q + n_q^2) per step, never O(N^2). The diagonal T_ii has one
interpolation in every mode, linear along the diagonal (along drift_omega for mean drift, along
T-(w, w) for the QTF): the difference QTF's double sum holds the bilinear value there, so the
constant r^2 sum_i A_i^2 (T_ii - T_ii,bilinear) is added to it. A regular wave is the
one-component case (mean A^2 T(w, w); the sum QTF adds the 2w force).
Headings (server/sea/headings.py, the one rule the excitation follows too): the mean drift is
interpolated linearly in heading around the circle (any labelling of the data's headings, the wrap
at +-180 deg included); the QTF of a unidirectional wave along its diagonal pairs (h, h), of two
headings bilinearly over the pairs (h, k) the data hold. A heading in the gap the data leave out, or
a pair they do not hold, is a ModelError naming the wave key.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, replace

import numpy as np
import xarray as xr

from hydrolink.protocol.hdb.layout import MEAN_DRIFT_DIMS, QTF_DIMS, HDBError
from hydrolink.protocol.hdb.schema import select_bodies
from hydrolink.protocol.hdb.second_order import drift_body_fixed, drift_methods, qtf_kinds
from hydrolink.protocol.scene import Scene
from hydrolink.server.allocation import require_size
from hydrolink.server.errors import ModelError
from hydrolink.server.terms.base import ForceTerm, TermContext
from hydrolink.server.sea.headings import heading_weights
from hydrolink.server.sea.passive_yaw import YAW_POINTS, grid_position, rotate_yaw, yaw_grid
from hydrolink.server.sea.waves import WaveComponents, WaveError, ramp_factor

_TOL = 1e-6   # relative tolerance on frequencies, absolute (rad) on headings


def _wave_key(waves: WaveComponents, what: str) -> str:
    """The scene key a component frequency (``what`` = "omega") or heading is refused under."""
    if what == "omega":
        return "waves.period" if waves.kind == "regular" else "waves.omega_range"
    return waves.heading_key or ("waves.spreading" if waves.headings is not None else "waves.direction")


def interpolation_weights(grid: np.ndarray, x: np.ndarray, key: str, what: str) -> np.ndarray:
    """(len(x), len(grid)) linear interpolation weights of ``x`` on ``grid`` (a single-point
    grid takes only its own value); ModelError naming ``key`` for a value outside the grid."""
    lo, hi = grid[0] * (1 - _TOL) - _TOL, grid[-1] * (1 + _TOL) + _TOL
    bad = (x < lo) | (x > hi)
    if np.any(bad):
        v = x[np.argmax(bad)]
        raise ModelError(key, f"{what} {v:.6g} is outside the data's range {grid[0]:.6g}-{grid[-1]:.6g}")
    w = np.zeros((x.size, grid.size))
    if grid.size == 1:
        w[:, 0] = 1.0
        return w
    k = np.clip(np.searchsorted(grid, x) - 1, 0, grid.size - 2)
    f = np.clip((x - grid[k]) / (grid[k + 1] - grid[k]), 0.0, 1.0)
    rows = np.arange(x.size)
    w[rows, k] = 1.0 - f
    w[rows, k + 1] += f
    return w


@dataclass(frozen=True)
class BodySecondOrder:
    """One body's second-order force from the components z (n_c,) at a time, before the ramp.

    ``mean`` (6,) constant; ``newman`` (n_c, 6) the diagonal T_ii (Newman); ``lift``
    (n_c, n_y) the QTF interpolation L over the heading groups; ``difference`` / ``sum``
    (6 n_y, n_y) the QTF G of each DOF stacked (rows d n_y + a)."""

    row: int                           # the body's position among the served bodies
    mean: np.ndarray | None = None
    newman: np.ndarray | None = None
    lift: np.ndarray | None = None
    difference: np.ndarray | None = None
    sum: np.ndarray | None = None
    # a passive-yaw body (server/sea/passive_yaw.py): ``mean`` (n_psi, 6) and ``newman`` (n_psi, n_c,
    # 6) at the tabulated yaws, the first the fixed heading's; blended at the body's yaw each step
    yawing: bool = False
    # a passive-yaw body's QTF: its parts at a yaw other than 0 (:class:`TurningQTF`)
    turning: "TurningQTF | None" = None

    def force(self, z: np.ndarray, yaw: float = 0.0) -> np.ndarray:
        """(6,) the force for the component phasors ``z`` (no ramp); ``yaw`` (rad) the body's, read
        by a passive-yaw body only."""
        if self.yawing:
            j0, j1, s = grid_position(yaw, YAW_POINTS)
            f = np.zeros(6) if self.mean is None else (1.0 - s) * self.mean[j0] + s * self.mean[j1]
            if self.newman is not None:
                conj = np.conj(z.sum())
                f += (1.0 - s) * ((z @ self.newman[j0]) * conj).real + s * ((z @ self.newman[j1]) * conj).real
            return f
        if self.turning is not None and yaw != 0.0:
            return self.turning(yaw).force(z)
        f = np.zeros(6) if self.mean is None else self.mean.copy()
        if self.newman is not None:
            f += ((z @ self.newman) * np.conj(z.sum())).real
        if self.lift is not None:
            y = z @ self.lift
            n = y.size
            if self.difference is not None:
                f += ((self.difference @ np.conj(y)).reshape(6, n) @ y).real
            if self.sum is not None:
                f += ((self.sum @ y).reshape(6, n) @ y).real
        return f


def _mean_drift_diagonal(sub: xr.Dataset, method: str, waves: WaveComponents, scale: float) -> np.ndarray:
    """(n_c, 6) T_ii of the method at each component's frequency and heading (N/m^2, N m/m^2): linear
    in frequency, and in heading around the circle (server/sea/headings.py, as the excitation)."""
    md = sub["mean_drift"].transpose(*MEAN_DRIFT_DIMS).sel(drift_method=method).values * scale
    w_grid, b_grid = sub["drift_omega"].values, sub["drift_direction"].values
    lw = interpolation_weights(w_grid, waves.hdb_omega, _wave_key(waves, "omega"), "wave frequency (rad/s)")
    lb = _heading_weights(b_grid, waves.heading_of(), waves, "the mean drift's headings")
    return np.einsum("ca,cb,abd->cd", lw, lb, md)


def _yawed_drift_diagonal(sub: xr.Dataset, method: str, waves: WaveComponents, scale: float, psi: np.ndarray,
                          key: str) -> np.ndarray:
    """(n_psi, n_c, 6) T_ii of a passive-yaw body yawed by each ``psi``: at each component's heading
    relative to the body, turned into the global frame (server/sea/passive_yaw.py); the same
    interpolation as :func:`_mean_drift_diagonal`, a heading the data leave out a ModelError(key)."""
    md = sub["mean_drift"].transpose(*MEAN_DRIFT_DIMS).sel(drift_method=method).values * scale
    w_grid, b_grid = sub["drift_omega"].values, sub["drift_direction"].values
    lw = interpolation_weights(w_grid, waves.hdb_omega, _wave_key(waves, "omega"), "wave frequency (rad/s)")
    mw = np.tensordot(lw, md, axes=(1, 0))          # (n_c, n_b, 6): at the components' frequencies
    heads = waves.heading_of()
    out = np.empty((psi.size, heads.size, 6))
    for beta in np.unique(heads):
        on = heads == beta
        try:
            lb = heading_weights(b_grid, beta - psi, key, "the mean drift's headings (the body yawing)")
        except WaveError as exc:
            raise ModelError(exc.key, exc.why) from None
        out[:, on] = np.tensordot(lb, mw[on], axes=(1, 1))
    return rotate_yaw(out, psi)


def _heading_weights(grid: np.ndarray, heads: np.ndarray, waves: WaveComponents, what: str) -> np.ndarray:
    """heading_weights with its WaveError as the ModelError of the wave key."""
    try:
        return heading_weights(grid, heads, _wave_key(waves, "heading"), what)
    except WaveError as exc:
        raise ModelError(exc.key, exc.why) from None


def _qtf_pair_weights(sub: xr.Dataset, groups: np.ndarray, waves: WaveComponents, src: str) -> np.ndarray:
    """(n_g, n_g, n_h) weights C so that T(b_a, b_b) = sum_h C[a, b, h] T(pair h) for the wave
    headings ``groups``: each heading interpolated between the QTF's headings around the circle
    (server/sea/headings.py); the same heading twice (a unidirectional wave) along the diagonal
    pairs (h, h), two headings bilinearly over the pairs (h, k) (bi-directional data). ModelError
    naming the wave key for a heading the data leave out or a pair they do not hold."""
    bi, bj = sub["qtf_direction_i"].values.astype(float), sub["qtf_direction_j"].values.astype(float)
    grid = np.unique(np.round(np.concatenate([bi, bj]), 9))
    w = _heading_weights(grid, groups, waves, "the QTF's headings")       # (n_g, n_grid)
    index = {(round(float(a), 9), round(float(b), 9)): h for h, (a, b) in enumerate(zip(bi, bj))}
    held = ", ".join(f"({np.degrees(a):g}, {np.degrees(b):g})" for a, b in zip(bi, bj))
    out = np.zeros((groups.size, groups.size, bi.size))
    for a in range(groups.size):
        for b in range(groups.size):
            terms = [(h, h, w[a, h]) for h in np.flatnonzero(w[a])] if a == b else \
                [(h, k, w[a, h] * w[b, k]) for h in np.flatnonzero(w[a]) for k in np.flatnonzero(w[b])]
            for h, k, c in terms:
                pair = index.get((grid[h], grid[k]))
                if pair is None:
                    raise ModelError(_wave_key(waves, "heading"), f"the QTF of {src!r} has no heading pair "
                                     f"({np.degrees(grid[h]):g}, {np.degrees(grid[k]):g}) deg for the wave headings "
                                     f"({np.degrees(groups[a]):g}, {np.degrees(groups[b]):g}) deg (it holds {held} deg)")
                out[a, b, pair] += c
    return out


def _qtf_tables(sub: xr.Dataset, kinds: tuple[str, ...], scale: float) -> dict[str, np.ndarray]:
    """Each kind's QTF (n_q, n_q, n_h, 6) in the scene's water, read once."""
    return {kind: sub[f"{kind}_qtf"].transpose(*QTF_DIMS).values * scale for kind in kinds}


def _qtf_diagonal(sub: xr.Dataset, waves: WaveComponents, scale: float, src: str,
                  tables: dict[str, np.ndarray] | None = None) -> tuple[np.ndarray, np.ndarray]:
    """(n_c, 6) twice: the difference QTF's T_ii at each component, interpolated linearly along the
    diagonal T(w, w) (the one interpolation of T_ii, as the mean drift's along drift_omega), and the
    value the bilinear interpolation on the square gives there (what the factorised double sum
    holds on its diagonal, corrected to the first by a constant). ``tables``: :func:`_qtf_tables`."""
    grid = sub["qtf_omega_i"].values
    lw = interpolation_weights(grid, waves.hdb_omega, _wave_key(waves, "omega"), "wave frequency (rad/s)")
    heads = np.round(waves.heading_of(), 9)
    t = (tables or _qtf_tables(sub, ("difference",), scale))["difference"]   # (n_q, n_q, n_h, 6)
    linear, bilinear = np.zeros((waves.size, 6)), np.zeros((waves.size, 6))
    # each component's weights are on two neighbouring grid points k, k + 1 (one on a 1-point grid)
    k = np.minimum(np.argmax(lw != 0.0, axis=1), max(grid.size - 2, 0))
    wa, wb = lw[np.arange(waves.size), k][:, None], lw[np.arange(waves.size), np.minimum(k + 1, grid.size - 1)][:, None]
    groups = np.unique(heads)
    weights = _qtf_pair_weights(sub, groups, waves, src)
    for g, b in enumerate(groups):
        on = heads == b
        nz = np.flatnonzero(weights[g, g])                                # the few pairs the heading is between
        square = np.tensordot(t[:, :, nz], weights[g, g, nz], axes=([2], [0]))   # (n_q, n_q, 6), real diagonal
        linear[on] = lw[on] @ np.einsum("aad->ad", square).real
        if grid.size == 1:
            bilinear[on] = linear[on]
            continue
        ko = k[on]
        bilinear[on] = (wa[on] ** 2 * square[ko, ko] + wa[on] * wb[on] * (square[ko, ko + 1] + square[ko + 1, ko])
                        + wb[on] ** 2 * square[ko + 1, ko + 1]).real
    return linear, bilinear


def _qtf_parts(sub: xr.Dataset, kinds: tuple[str, ...], waves: WaveComponents, scale: float, src: str,
               tables: dict[str, np.ndarray] | None = None) -> tuple[np.ndarray, dict[str, np.ndarray]]:
    """The interpolation L (n_c, n_g n_q) over the heading groups and each kind's stacked G
    (``tables``: :func:`_qtf_tables`)."""
    grid = sub["qtf_omega_i"].values
    lw = interpolation_weights(grid, waves.hdb_omega, _wave_key(waves, "omega"), "wave frequency (rad/s)")
    heads = waves.heading_of()
    groups = np.unique(np.round(heads, 9))
    n_q, n_g = grid.size, groups.size

    key = _wave_key(waves, "heading")
    require_size(key, "the QTF over the wave headings' pairs", (6 * n_g * n_q, n_g * n_q), 16,
                 "fewer spreading directions, or a coarser QTF grid")
    require_size("waves.components", "the QTF interpolation onto the wave components", (waves.size, n_g * n_q), 16)
    lift = np.zeros((waves.size, n_g * n_q))
    for g, b in enumerate(groups):
        on = np.isclose(np.round(heads, 9), b)
        lift[on, g * n_q:(g + 1) * n_q] = lw[on]
    weights = _qtf_pair_weights(sub, groups, waves, src)               # (n_g, n_g, n_h)
    nz = np.flatnonzero(weights.any(axis=(0, 1)))                      # the pairs the headings are between
    tables = tables or _qtf_tables(sub, kinds, scale)
    out = {}
    for kind in kinds:
        g_full = np.einsum("ijhd,abh->ijabd", tables[kind][:, :, nz], weights[:, :, nz])   # (n_q, n_q, n_g, n_g, 6)
        g_full = g_full.transpose(4, 2, 0, 3, 1).reshape(6 * n_g * n_q, n_g * n_q)
        out[kind] = np.ascontiguousarray(g_full)
    return lift, out


def _drift_method(sub: xr.Dataset, mode: str, key: str, method: str | None, name: str, src: str) -> str | None:
    """The mean drift method T_ii of ``mode`` ("mean-drift", "newman") is read from, or None for the
    diagonal of the difference QTF (an HDB without mean drift coefficients; ``hydro.drift_method``
    unset); ModelError naming the key when the HDB holds neither, or not the method asked for."""
    methods = drift_methods(sub)
    if not methods:
        if "difference" not in qtf_kinds(sub):
            raise ModelError(key, f"{mode!r} for body {name!r}: the HDB {src!r} holds no mean drift coefficients "
                                  "(WAMIT .7/.8/.9, BEMIO mean_drift or hdb build's far-field) and no difference QTF "
                                  "whose diagonal gives them")
        if method is not None:
            raise ModelError("hydro.drift_method", f"{method!r} for body {name!r}: the HDB {src!r} holds no mean drift "
                                                   "coefficients, only a difference QTF: leave hydro.drift_method "
                                                   "unset to take T_ii from the QTF's diagonal")
        return None
    if method is None:
        if len(methods) > 1:
            raise ModelError("hydro.drift_method", f"the HDB {src!r} holds the mean drift of several methods "
                                                   f"{list(methods)}: choose one")
        return methods[0]
    if method not in methods:
        raise ModelError("hydro.drift_method", f"{method!r} for body {name!r}: the HDB {src!r} holds only "
                                               f"{list(methods)}")
    return method


def _qtf_body_parts(sub: xr.Dataset, kinds: tuple[str, ...], waves: WaveComponents, scale: float, src: str,
                    row: int, tables: dict[str, np.ndarray] | None = None) -> BodySecondOrder:
    """A body's QTF parts (the lift, each kind's G, and the difference QTF's diagonal constant)."""
    parts: dict[str, np.ndarray] = {}
    tables = tables or _qtf_tables(sub, kinds, scale)
    lift, g = _qtf_parts(sub, kinds, waves, scale, src, tables)
    if "difference" in kinds:
        # the diagonal i = j of the double sum is A_i^2 T_ii, constant: with this constant it is the
        # T_ii interpolated along the diagonal (as "mean-drift" and "newman" take it), not the
        # bilinear value on the square, which mixes the neighbouring off-diagonal cells in
        linear, bilinear = _qtf_diagonal(sub, waves, scale, src, tables)
        parts["mean"] = (waves.amplitude ** 2) @ (linear - bilinear)
    parts["lift"] = lift.astype(complex)   # complex once, not cast each step
    for kind in kinds:
        parts[kind] = g[kind]
    return BodySecondOrder(row, **parts)


class TurningQTF:
    """A passive-yaw body's QTF parts at its yaw psi (server/sea/passive_yaw.py): the QTF read at the
    components' headings relative to the body (beta - psi), its forces and moments turned into the
    global frame by R(psi); computed when the yaw changes (the last kept: a step recomputed at the
    same yaw reuses it). Its heading pairs are checked at set-up on the 1-deg yaw grid, so a step
    never meets a pair the data lack."""

    def __init__(self, sub: xr.Dataset, kinds: tuple[str, ...], waves: WaveComponents, scale: float, src: str,
                 row: int, key: str):
        self._args = (sub, kinds, scale, src, row)
        self._tables = _qtf_tables(sub, kinds, scale)
        self._waves, self._last = waves, (None, None)
        heads = np.unique(np.round(waves.heading_of(), 9))
        for psi in yaw_grid()[1:]:
            try:
                _qtf_pair_weights(sub, np.unique(np.round(heads - psi, 9)), waves, src)
            except ModelError as exc:
                raise ModelError(key, f"at a yaw of {np.degrees(psi):g} deg: {exc.why}") from None

    def __call__(self, psi: float) -> BodySecondOrder:
        if self._last[0] != psi:
            sub, kinds, scale, src, row = self._args
            waves = replace(self._waves, headings=self._waves.heading_of() - psi)
            parts = _qtf_body_parts(sub, kinds, waves, scale, src, row, self._tables)
            turn = np.array([psi])
            mean = None if parts.mean is None else rotate_yaw(parts.mean[None, None, :], turn)[0, 0]
            turned = {}
            for kind in kinds:
                g = getattr(parts, kind)
                m = g.shape[1]
                rows = np.moveaxis(g.reshape(6, m * m), 0, -1)[None]            # (1, M M, 6)
                turned[kind] = np.ascontiguousarray(np.moveaxis(rotate_yaw(rows, turn)[0], -1, 0).reshape(6 * m, m))
            self._last = (psi, BodySecondOrder(row, mean=mean, lift=parts.lift, **turned))
        return self._last[1]


def body_second_order(scene: Scene, i: int, row: int, ds: xr.Dataset, waves: WaveComponents
                      ) -> tuple[BodySecondOrder, list[str]]:
    """Body ``i``'s (scene index) second-order part from its HDB ``ds``, and its setup warnings."""
    body, hydro = scene.bodies[i], scene.hydro
    mode, key = scene.second_order_of(body), scene.second_order_key(i)
    src = str(ds.attrs.get("source", "?"))
    try:
        sub = select_bodies(ds, [body.hdb_body_name])
    except HDBError as exc:
        raise ModelError(f"bodies[{i}].hdb_body", str(exc)) from None
    scale = scene.water.density * scene.water.gravity / (float(ds.attrs["rho"]) * float(ds.attrs["g"]))
    warnings: list[str] = []
    parts: dict[str, np.ndarray] = {}
    kinds = ("difference",) if mode == "qtf" else ()
    if hydro.sum_frequency:
        kinds += ("sum",)
    if body.passive_yaw and kinds and mode != "qtf":
        raise ModelError(f"bodies[{i}].passive_yaw", f"with {key} = {mode!r} and hydro.sum_frequency: not built (the "
                                                     "tabulated drift and the turning QTF in one body); use "
                                                     "second_order = \"qtf\" with it")
    held = qtf_kinds(sub)
    for kind in kinds:
        if kind not in held:
            k = key if kind == "difference" else "hydro.sum_frequency"
            raise ModelError(k, f"body {body.name!r}: the HDB {src!r} holds no {kind}-frequency QTF "
                                f"(it holds {list(held) or 'none'})")
    if mode in ("mean-drift", "newman"):
        method = _drift_method(sub, mode, key, hydro.drift_method, body.name, src)
        if body.passive_yaw and method is None:
            raise ModelError(f"bodies[{i}].passive_yaw", f"with {key} = {mode!r}: needs the HDB's mean drift "
                             f"coefficients ({src!r} holds only a QTF, whose diagonal does not turn with the body yet)")
        diag = (_mean_drift_diagonal(sub, method, waves, scale) if method is not None
                else _qtf_diagonal(sub, waves, scale, src)[0])
        if body.passive_yaw:    # at the tabulated yaws; the first, yaw 0, the fixed heading's own
            diag = np.concatenate([diag[None], _yawed_drift_diagonal(sub, method, waves, scale, yaw_grid()[1:],
                                                                     f"bodies[{i}].passive_yaw")])
            parts["yawing"] = True
        if mode == "mean-drift":
            a2 = waves.amplitude ** 2
            parts["mean"] = a2 @ diag if not body.passive_yaw else np.stack([a2 @ d for d in diag])
        else:
            parts["newman"] = diag.astype(complex)   # complex already: a real operand would be cast each step
        moving = [d for d in body.dofs]
        if drift_body_fixed(sub) and moving:
            note = str(ds.attrs.get("mean_drift_note", ""))
            warnings.append(f"{key}: the mean drift of {src!r} was computed for the body held fixed ({note}) "
                            f"but body {body.name!r} moves in {moving}: its drift includes no motion effect; "
                            f"lock bodies[{i}].dofs or use coefficients computed with the body's motions")
    if kinds:
        qtf = _qtf_body_parts(sub, kinds, waves, scale, src, row)
        parts.update({k: getattr(qtf, k) for k in ("mean", "lift", *kinds) if getattr(qtf, k) is not None})
        if body.passive_yaw:
            parts["turning"] = TurningQTF(sub, kinds, waves, scale, src, row, f"bodies[{i}].passive_yaw")
    return BodySecondOrder(row, **parts), warnings


class SecondOrderTerm(ForceTerm):
    """The second-order wave forces of the served bodies (reply field ``drift``).

    The phasors z_i(t) = c_i e^{-i w_i t} are advanced from the previous step by the rotation
    e^{-i w_i dt} (one complex product per component instead of an exponential), evaluated afresh
    at any other time and every RESYNC steps (the rotations' round-off stays ~1e-13); the phasors
    are the term's state for the session rollback."""

    name = "second_order"
    scene_keys = ("hydro.second_order", "bodies[i].second_order", "hydro.drift_method", "hydro.sum_frequency")
    features = ("second_order",)
    needs = frozenset({"time", "position"})   # position: the yaw of passive-yaw bodies
    steady = "pointwise"     # hydrolink steady: a load at its nodes (regular waves: mean, and 2w with sum)
    stateless = False
    RESYNC = 1024

    def __init__(self, parts: list[BodySecondOrder], waves: WaveComponents, active: np.ndarray, dt: float,
                 warnings: list[str], heading: Callable[[int], float] | None = None):
        super().__init__(("drift",))
        self.parts, self._mask = parts, active.astype(float)
        self._c = waves.amplitude * np.exp(1j * waves.phase)
        self._w = waves.omega
        self._dt = float(dt)
        self._rotation = np.exp(-1j * self._w * self._dt)
        self._ramp = float(waves.ramp)
        self._phasors = any(p.newman is not None or p.lift is not None for p in parts)  # else constant
        self._t, self._z, self._since = np.nan, self._c, 0    # the newest phasors, at time _t
        self.warnings = tuple(warnings)
        self._heading = heading   # a passive-yaw body's heading at a row, this step (TermContext.yaw_heading)

    @classmethod
    def build(cls, ctx: TermContext) -> "SecondOrderTerm | None":
        scene = ctx.scene
        bodies = [(row, i) for row, i in enumerate(ctx.wet) if scene.second_order_of(scene.bodies[i]) != "none"]
        if not bodies:
            return None
        if ctx.waves.kind == "elevation":
            raise ModelError(scene.second_order_key(bodies[0][1]),
                             "second-order forces need wave components (regular or irregular waves); "
                             "[waves] type = \"elevation\" has none")
        parts, warnings = [], []
        for row, i in bodies:
            part, warn = body_second_order(scene, i, row, ctx.hdbs[scene.bodies[i].name], ctx.waves)
            parts.append(part)
            warnings += warn
        return cls(parts, ctx.waves, ctx.active, scene.exchange_dt, warnings, ctx.yaw_heading)

    def _phasors_at(self, t: float) -> np.ndarray:
        """z(t), rotated from the newest phasors when t is one step later."""
        if t == self._t:
            return self._z
        if abs(t - self._t - self._dt) <= 1e-9 * self._dt and self._since < self.RESYNC:
            self._z, self._since = self._z * self._rotation, self._since + 1
        else:
            self._z, self._since = self._c * np.exp(-1j * self._w * t), 0
        self._t = t
        return self._z

    def force(self, t: float, position: np.ndarray, velocity: np.ndarray) -> tuple[np.ndarray]:
        out = np.zeros(self._mask.shape)
        if self._w.size == 0:
            return (out,)
        z = self._phasors_at(float(t)) if self._phasors else self._c
        for part in self.parts:
            turns = part.yawing or part.turning is not None
            yaw = 0.0 if not turns else (self._heading(part.row) if self._heading is not None
                                         else float(position[part.row, 5]))
            out[part.row] = part.force(z, yaw)
        r = 1.0 if t >= self._ramp else float(ramp_factor(t, self._ramp))
        out *= self._mask * (r * r)
        return (out,)

    def state(self) -> tuple[float, np.ndarray, int]:
        return self._t, self._z.copy(), self._since

    def set_state(self, state: tuple[float, np.ndarray, int]) -> None:
        self._t, z, self._since = state
        self._z = z.copy()
