"""WAMIT second-order files beside the ``.1``: mean drift (``.7``/``.8``/``.9``) and QTFs
(``.10d``/``.11d``/``.12d`` difference, ``.10s``/``.11s``/``.12s`` sum), converted once into the
layout of :mod:`hydrolink.protocol.hdb.second_order`.

Mean drift rows ``PER BETA1 BETA2 I Mod Pha Re Im``: F = rho g A^2 L^m Re (m = 1 forces, 2
moments); the kept rows are those with BETA1 = BETA2 (a unidirectional regular wave), the mean
force being real (the conjugation of exp(+iwt) leaves it unchanged). Dropped, as stated here:
PER <= 0 rows (the zero/infinite-frequency limits), bidirectional rows (BETA1 != BETA2) and rows
with I = -4, -5, -6 (the .7 and .9 add them as a second set of moments; the I = 4..6 rows about
the body's reference point are the ones kept). The ``.8`` (momentum conservation) holds surge,
sway and yaw of the whole configuration: read for one body; for several bodies it is not the
force on each, so it is left out with a warning.

QTF rows ``PER_i PER_j BETA_i BETA_j I Mod Pha Re Im``: T = rho g L^m conj(Re + i Im) per A_i A_j
(exp(+iwt) -> exp(-iwt)); one triangle may be stored, the other is filled (difference: conjugate
symmetry, sum: plain symmetry). Of .12 (direct, full), .11 (indirect) and .10 (quadratic part
only) the most complete present is read; ``qtf_source`` names the files.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import numpy as np

from hydrolink.server.hdb.reader_warnings import HDBWarning
from hydrolink.protocol.hdb.layout import HDBError
from hydrolink.protocol.hdb.second_order import QTF, MeanDrift, fill_qtf_square, merge_drift
from hydrolink.server.hdb.wamit.table import Units, frequencies, read_table, scale_exponent, special_rows

DRIFT_FILES = ((".8", "momentum"), (".7", "control-surface"), (".9", "pressure"))
QTF_LEVELS = ((".12", "direct"), (".11", "indirect"), (".10", "quadratic part only"))
SECOND_ORDER_SUFFIXES = tuple(s for s, _ in DRIFT_FILES) + tuple(
    f"{level}{kind}" for level, _ in QTF_LEVELS for kind in ("d", "s"))
DROPPED_MODES = (-4, -5, -6)


def _modes(path: Path, table: np.ndarray, lines: np.ndarray, col: int, n_dof: int) -> tuple[np.ndarray, np.ndarray]:
    """0-based mode of each row and the mask of rows kept (I = -4..-6 dropped); HDBError for
    any other non-positive or non-integer I, or a mode beyond the run's."""
    i = table[:, col]
    kept = ~np.isin(i, DROPPED_MODES)
    bad = kept & ((i != np.round(i)) | (i < 1) | (i > n_dof))
    if np.any(bad):
        k = int(np.argmax(bad))
        raise HDBError(path.name, f"line {lines[k]}", f"mode I must be 1..{n_dof} (or -4..-6, dropped), got {i[k]:g}")
    return np.where(kept, np.round(i).astype(int) - 1, -1), kept


def read_drift(stem: Path, units: Units, n_dof: int) -> MeanDrift | None:
    """The mean drift of every ``.7``/``.8``/``.9`` beside the ``.1`` (None when there is none)."""
    parts = []
    for suffix, method in DRIFT_FILES:
        path = stem.with_name(stem.name + suffix)
        if not path.is_file():
            continue
        if suffix == ".8" and n_dof > 6:
            warnings.warn(f"{path.name}: momentum-conservation drift of a {n_dof // 6}-body run is the total on "
                          "all bodies, not each body's: left out (use the .7 or .9)", HDBWarning, stacklevel=3)
            continue
        parts.append(_read_drift_file(path, method, units, n_dof))
    return merge_drift(parts, stem.with_name(stem.name + ".1"))


def _read_drift_file(path: Path, method: str, u: Units, n_dof: int) -> MeanDrift:
    table, lines = read_table(path, (8,), "PER BETA1 BETA2 I Mod Pha Re Im")
    inf_rows, skip_rows = special_rows(table[:, 0], u.iperout)
    mode, kept = _modes(path, table, lines, 3, n_dof)
    keep = kept & ~inf_rows & ~skip_rows & (table[:, 1] == table[:, 2])
    if not np.any(keep):
        raise HDBError(path.name, "mean_drift", "no rows with a positive period, BETA1 = BETA2 and a mode 1..6N")
    table, lines, mode = table[keep], lines[keep], mode[keep]
    periods, betas = np.unique(table[:, 0]), np.unique(table[:, 1])
    omega_unsorted = frequencies(periods, u.iperout, u.g, str(path), u.ulen)
    order = np.argsort(omega_unsorted)
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)
    w_idx = rank[np.searchsorted(periods, table[:, 0])]
    b_idx = np.searchsorted(betas, table[:, 1])
    modes = np.unique(mode)
    values = np.full((1, periods.size, betas.size, n_dof), np.nan)
    values[..., np.setdiff1d(np.arange(n_dof), modes)] = 0.0   # modes the method does not give
    values[0, w_idx, b_idx, mode] = u.rho * u.g * u.ulen ** scale_exponent(mode + 1, None, 1, u.rotational) * table[:, 6]
    if np.any(np.isnan(values)):
        _, w, b, d = np.argwhere(np.isnan(values))[0]
        raise HDBError(path.name, "mean_drift", f"no row for period column {periods[order][w]:g}, heading "
                                                f"{betas[b]:g} deg, mode {d + 1} (other rows have that mode)")
    return MeanDrift((method,), omega_unsorted[order], np.deg2rad(betas), values)


def read_qtf(stem: Path, units: Units, n_dof: int) -> QTF | None:
    """The most complete difference and sum QTFs beside the ``.1`` (None when there is none)."""
    found = {}
    for kind, letter in (("difference", "d"), ("sum", "s")):
        for level, name in QTF_LEVELS:
            path = stem.with_name(f"{stem.name}{level}{letter}")
            if path.is_file():
                found[kind] = (path, name, _read_qtf_file(path, kind, units, n_dof))
                break
    if not found:
        return None
    grids = [v[2] for v in found.values()]
    first = grids[0]
    for (path, _, g) in list(found.values())[1:]:
        if g[0].shape != first[0].shape or not np.allclose(g[0], first[0], rtol=1e-6) or not (
                np.array_equal(g[1], first[1]) and np.array_equal(g[2], first[2])):
            raise HDBError(path.name, "qtf_omega", f"frequencies or heading pairs differ from "
                                                   f"{list(found.values())[0][0].name}'s (one QTF grid per HDB)")
    source = "; ".join(f"{p.name} (WAMIT {name})" for p, name, _ in found.values())
    return QTF(first[0], first[1], first[2], found["difference"][2][3] if "difference" in found else None,
               found["sum"][2][3] if "sum" in found else None, source)


def _read_qtf_file(path: Path, kind: str, u: Units, n_dof: int):
    table, lines = read_table(path, (9,), "PER_i PER_j BETA_i BETA_j I Mod Pha Re Im")
    inf_i, skip_i = special_rows(table[:, 0], u.iperout)
    inf_j, skip_j = special_rows(table[:, 1], u.iperout)
    mode, kept = _modes(path, table, lines, 4, n_dof)
    keep = kept & ~(inf_i | skip_i | inf_j | skip_j)
    if not np.any(keep):
        raise HDBError(path.name, f"{kind}_qtf", "no rows with positive periods and a mode 1..6N")
    table, mode = table[keep], mode[keep]
    w_i = frequencies(table[:, 0], u.iperout, u.g, str(path), u.ulen)
    w_j = frequencies(table[:, 1], u.iperout, u.g, str(path), u.ulen)
    value = u.rho * u.g * u.ulen ** scale_exponent(mode + 1, None, 1, u.rotational) * (table[:, 7] - 1j * table[:, 8])
    return fill_qtf_square(w_i, w_j, np.deg2rad(table[:, 2]), np.deg2rad(table[:, 3]), mode, value,
                           n_dof, kind, path.name)
