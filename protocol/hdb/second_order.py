"""Second-order wave-force data of an HDB (issue 23): mean drift coefficients and QTFs, as typed
parts the readers build, their place in the internal dataset and the checks on them.

Layout (optional parts of :mod:`hydrolink.protocol.hdb.layout`, SI, exp(-i w t))::

    dims    drift_method    labels, a subset of DRIFT_METHODS in that order: the methods the data hold
            drift_omega     rad/s, > 0, strictly increasing (the drift's own grid)
            drift_direction rad, strictly increasing (heading of the regular wave)
            qtf_omega_i, qtf_omega_j   rad/s, the same values (> 0, strictly increasing)
            qtf_heading     index of a heading pair; coords qtf_direction_i, qtf_direction_j (rad)
                            on it: the pairs the data hold, each with its mirror (beta_j, beta_i)
    vars    mean_drift      (drift_method, drift_omega, drift_direction, influenced_dof)  real,
                            N/m^2 (forces), N m/m^2 (moments): a regular wave of amplitude A gives
                            the mean force A^2 T(w, w). DOFs a method does not give are 0 (momentum
                            and far-field: surge, sway, yaw only).
            difference_qtf  (qtf_omega_i, qtf_omega_j, qtf_heading, influenced_dof)  complex, per
                            A_i A_j: F(t) = Re sum_i sum_j a_i conj(a_j) T-_ij exp(-i (w_i - w_j) t)
                            with a_i = A_i exp(-i phi_i) the complex amplitudes of eta (exp(-iwt));
                            the full square, T-_ji(b_j, b_i) = conj(T-_ij(b_i, b_j)).
            sum_qtf         same dims: F(t) = Re sum_i sum_j a_i a_j T+_ij exp(-i (w_i + w_j) t);
                            T+_ji(b_j, b_i) = T+_ij(b_i, b_j).
    attrs   mean_drift_body_fixed  0 or 1, with mean_drift: 1 when the coefficients were computed with
                            the body held fixed (diffraction only, no motion terms), 0 when with its motions
            qtf_source      where the QTFs come from (file and method), when there are QTFs

Mean drift in a regular wave: A^2 T-(w, w) (real); an exp(+i w t) format's QTF is the complex
conjugate of the internal one (readers conjugate once).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.protocol.hdb.layout import DRIFT_METHODS, MEAN_DRIFT_DIMS, QTF_DIMS, QTF_KINDS, HDBError

BODY_FIXED = "mean_drift_body_fixed"   # the dataset attribute of MeanDrift.body_fixed (0 or 1)


@dataclass(frozen=True)
class MeanDrift:
    """Mean drift coefficients of several methods on one grid (see the module layout)."""

    methods: tuple[str, ...]     # each one of DRIFT_METHODS
    omega: np.ndarray            # (n_w,) rad/s
    direction: np.ndarray        # (n_b,) rad
    values: np.ndarray           # (n_methods, n_w, n_b, 6N) N/m^2, N m/m^2
    note: str = ""               # how the coefficients were obtained (for people: hdb info shows it)
    body_fixed: bool = False     # computed with the body held fixed (no motion terms), else with its motions


@dataclass(frozen=True)
class QTF:
    """Difference and/or sum QTFs on one frequency grid and one list of heading pairs, full square."""

    omega: np.ndarray            # (n_q,) rad/s
    direction_i: np.ndarray      # (n_h,) rad
    direction_j: np.ndarray      # (n_h,) rad
    difference: np.ndarray | None   # (n_q, n_q, n_h, 6N) complex, per A_i A_j, exp(-iwt)
    sum: np.ndarray | None          # same
    source: str                  # file and method, e.g. "run.12d (WAMIT direct)"


def merge_drift(parts: list[MeanDrift], source: str | Path) -> MeanDrift | None:
    """One MeanDrift from per-method parts read from different files (same grid required)."""
    if not parts:
        return None
    first = parts[0]
    for p in parts[1:]:
        if p.omega.shape != first.omega.shape or not np.allclose(p.omega, first.omega, rtol=1e-9):
            raise HDBError(source, "mean_drift.omega",
                                   f"{p.methods[0]} and {first.methods[0]} coefficients are on different "
                                   f"frequency grids ({p.omega.size} and {first.omega.size} values)")
        if p.direction.shape != first.direction.shape or not np.allclose(p.direction, first.direction):
            raise HDBError(source, "mean_drift.direction",
                                   f"{p.methods[0]} and {first.methods[0]} coefficients have different headings")
    order = sorted(range(len(parts)), key=lambda k: DRIFT_METHODS.index(parts[k].methods[0]))
    return MeanDrift(tuple(m for k in order for m in parts[k].methods), first.omega, first.direction,
                     np.concatenate([parts[k].values for k in order]),
                     "; ".join(dict.fromkeys(parts[k].note for k in order if parts[k].note)),
                     any(p.body_fixed for p in parts))


def fill_qtf_square(omega_i: np.ndarray, omega_j: np.ndarray, beta_i: np.ndarray, beta_j: np.ndarray,
                    dof: np.ndarray, value: np.ndarray, n_dof: int, kind: str, source: str | Path,
                    ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The full QTF square from rows that may hold one triangle: each row (w_i, w_j, b_i, b_j, dof,
    T) also gives (w_j, w_i, b_j, b_i) = conj(T) (difference) or T (sum). Frequencies and headings
    are matched to 1e-6 relative. Returns (omega, direction_i, direction_j, T (n, n, n_h, n_dof))
    with zeros for DOFs without rows; HDBError when a cell has no value either way, or two
    rows give different values."""
    omega = _distinct(np.concatenate([omega_i, omega_j]))
    pairs = sorted(set(zip(_round(beta_i), _round(beta_j))) | set(zip(_round(beta_j), _round(beta_i))))
    heading = {p: h for h, p in enumerate(pairs)}
    wi, wj = _index(omega, omega_i), _index(omega, omega_j)
    h_ij = np.array([heading[p] for p in zip(_round(beta_i), _round(beta_j))], int)
    h_ji = np.array([heading[p] for p in zip(_round(beta_j), _round(beta_i))], int)
    mirror = np.conj(value) if kind == "difference" else value
    out = np.full((omega.size, omega.size, len(pairs), n_dof), np.nan + 0j)
    dofs = np.unique(dof)
    out[:, :, :, np.setdiff1d(np.arange(n_dof), dofs)] = 0.0
    cells = np.concatenate([np.stack([wi, wj, h_ij, dof], 1), np.stack([wj, wi, h_ji, dof], 1)])
    vals = np.concatenate([value, mirror])
    out[tuple(cells.T)] = vals
    scale = max(np.abs(vals).max(initial=0.0), 1e-300)
    clash = np.abs(out[tuple(cells.T)] - vals) > 1e-6 * scale + 1e-4 * np.abs(vals)
    if np.any(clash):
        k = int(np.argmax(clash)) % value.size
        raise HDBError(source, f"{kind}_qtf", f"rows disagree with the {'conjugate ' if kind == 'difference' else ''}"
                               f"symmetry at w_i = {omega_i[k]:.6g}, w_j = {omega_j[k]:.6g} rad/s, mode {dof[k] + 1}")
    if np.any(np.isnan(out)):
        a, b, h, d = np.argwhere(np.isnan(out))[0]
        bi, bj = pairs[h]
        raise HDBError(source, f"{kind}_qtf",
                               f"no value for w_i = {omega[a]:.6g}, w_j = {omega[b]:.6g} rad/s, headings "
                               f"({np.degrees(bi):g}, {np.degrees(bj):g}) deg, mode {d + 1} (neither the row "
                               "nor its mirror is in the file)")
    # a file holding both triangles agrees only to its printed digits: the mean makes the square exact
    out = 0.5 * (out + _mirror(out, [pairs.index((b, a)) for a, b in pairs], kind))
    return omega, np.array([p[0] for p in pairs]), np.array([p[1] for p in pairs]), out


def _mirror(t: np.ndarray, mirror: list[int], kind: str) -> np.ndarray:
    """T_ji at (i, j): axes 0 and 1 swapped, each heading pair replaced by its mirror, conjugated
    for the difference QTF."""
    swapped = np.swapaxes(t, 0, 1)[:, :, mirror]
    return np.conj(swapped) if kind == "difference" else swapped


def _round(beta: np.ndarray) -> list[float]:
    """Headings as hashable keys (rad, rounded to 1e-9)."""
    return [round(float(b), 9) for b in beta]


def _distinct(values: np.ndarray) -> np.ndarray:
    """Sorted distinct values, merging those within 1e-6 relative (printed-period round-off)."""
    v = np.sort(values)
    keep = np.concatenate([[True], np.diff(v) > 1e-6 * np.abs(v[1:])])
    return v[keep]


def _index(grid: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Position of each of ``values`` in ``grid`` (within 1e-6 relative)."""
    k = np.clip(np.searchsorted(grid, values * (1 - 1e-6)), 0, grid.size - 1)
    return k


def second_order_vars(drift: MeanDrift | None, qtf: QTF | None) -> tuple[dict, dict, dict]:
    """(data_vars, coords, attrs) of the second-order parts, for :func:`.schema.make_hdb`."""
    data_vars, coords, attrs = {}, {}, {}
    if drift is not None:
        data_vars["mean_drift"] = (MEAN_DRIFT_DIMS, np.asarray(drift.values, float))
        coords.update(drift_method=list(drift.methods), drift_omega=np.asarray(drift.omega, float),
                      drift_direction=np.asarray(drift.direction, float))
        if drift.note:
            attrs["mean_drift_note"] = drift.note
        attrs[BODY_FIXED] = int(bool(drift.body_fixed))
    if qtf is not None:
        for kind, value in (("difference", qtf.difference), ("sum", qtf.sum)):
            if value is not None:
                data_vars[f"{kind}_qtf"] = (QTF_DIMS, np.asarray(value, complex))
        omega = np.asarray(qtf.omega, float)
        coords.update(qtf_omega_i=omega, qtf_omega_j=omega,
                      qtf_direction_i=("qtf_heading", np.asarray(qtf.direction_i, float)),
                      qtf_direction_j=("qtf_heading", np.asarray(qtf.direction_j, float)))
        attrs["qtf_source"] = str(qtf.source)
    return data_vars, coords, attrs


def check_second_order(ds: xr.Dataset, source: str | Path) -> None:
    """The checks beyond dims/shape/finite (done by the schema): method labels, grids, symmetry."""
    if "mean_drift" in ds:
        methods = [str(m) for m in ds["drift_method"].values]
        unknown = [m for m in methods if m not in DRIFT_METHODS]
        if unknown or len(set(methods)) != len(methods) or not methods:
            raise HDBError(source, "drift_method", f"must be distinct labels among {list(DRIFT_METHODS)}, "
                                                           f"got {methods}")
        _check_grid(ds["drift_omega"].values, "drift_omega", source, positive=True)
        _check_grid(ds["drift_direction"].values, "drift_direction", source, positive=False)
        if np.iscomplexobj(ds["mean_drift"].values):
            raise HDBError(source, "mean_drift", "must be real (the regular-wave mean force per A^2)")
        fixed = ds.attrs.get(BODY_FIXED)
        if fixed is None:
            raise HDBError(source, BODY_FIXED, "missing attribute (needed with mean_drift): 1 when the drift was "
                                               "computed with the body held fixed, 0 when with its motions")
        if isinstance(fixed, (bool, np.bool_)) or not (isinstance(fixed, (int, np.integer)) and int(fixed) in (0, 1)):
            raise HDBError(source, BODY_FIXED, f"must be the integer 0 or 1, got {fixed!r}")
    qtfs = [k for k in QTF_KINDS if f"{k}_qtf" in ds]
    if not qtfs:
        return
    wi, wj = ds["qtf_omega_i"].values, ds["qtf_omega_j"].values
    _check_grid(wi, "qtf_omega_i", source, positive=True)
    if wi.shape != wj.shape or not np.array_equal(wi, wj):
        raise HDBError(source, "qtf_omega_j", "must equal qtf_omega_i (the QTF is a square)")
    for name in ("qtf_direction_i", "qtf_direction_j"):
        if name not in ds.coords or ds[name].dims != ("qtf_heading",):
            raise HDBError(source, name, "missing coordinate on qtf_heading")
    pairs = list(zip(ds["qtf_direction_i"].values.tolist(), ds["qtf_direction_j"].values.tolist()))
    if len(set(pairs)) != len(pairs):
        raise HDBError(source, "qtf_heading", "repeated heading pair")
    try:
        mirror = [pairs.index((b, a)) for a, b in pairs]
    except ValueError:
        raise HDBError(source, "qtf_heading", "each heading pair (b_i, b_j) needs its mirror (b_j, b_i)") from None
    for kind in qtfs:
        t = ds[f"{kind}_qtf"].transpose(*QTF_DIMS).values
        scale = np.abs(t).max(initial=0.0)
        if np.abs(t - _mirror(t, mirror, kind)).max(initial=0.0) > 1e-9 * scale:
            raise HDBError(source, f"{kind}_qtf", "is not the full square: T_ji must be "
                                   + ("conj(T_ij)" if kind == "difference" else "T_ij") + " (fill it at the reader)")


def _check_grid(values: np.ndarray, name: str, source: str | Path, *, positive: bool) -> None:
    v = np.asarray(values, float)
    if v.ndim != 1 or v.size < 1 or not np.all(np.isfinite(v)):
        raise HDBError(source, name, "must be a non-empty list of finite numbers")
    if positive and v[0] <= 0:
        raise HDBError(source, name, f"must be > 0, got {v[0]}")
    if np.any(np.diff(v) <= 0):
        raise HDBError(source, name, "must be strictly increasing")


def drift_body_fixed(ds: xr.Dataset) -> bool:
    """Whether an HDB's mean drift was computed with the body held fixed (False without mean drift)."""
    return "mean_drift" in ds and int(ds.attrs[BODY_FIXED]) == 1


def drift_methods(ds: xr.Dataset) -> tuple[str, ...]:
    """The mean-drift methods an HDB holds (empty when it has none)."""
    return tuple(str(m) for m in ds["drift_method"].values) if "mean_drift" in ds else ()


def qtf_kinds(ds: xr.Dataset) -> tuple[str, ...]:
    """The QTF kinds ("difference", "sum") an HDB holds."""
    return tuple(k for k in QTF_KINDS if f"{k}_qtf" in ds)
