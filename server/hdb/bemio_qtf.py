"""The QTF groups of a WEC-Sim BEMIO HDF5 file (``bodyN/hydro_coeffs/excitation/QTF<N>/{Sum,Diff}<dof>/``),
read into the QTF part of an HDB (:mod:`hydrolink.protocol.hdb.second_order`).

Layout, from WEC-Sim's own sources (``source/functions/BEMIO/writeBEMIOH5.m``,
``QTFs/triToFullMatrix.m``, ``QTFs/assignIDs.m``, ``readWAMIT.m``/``readNEMOH.m``; releases v6.1 to
v7.1): under body N, group ``QTF<N>`` holds ``Diff1``..``Diff6`` and ``Sum1``..``Sum6`` (the body's
DOFs), each with

* ``PER_i`` (n,): the periods (s) of the square's rows and columns, in the order the WAMIT/NEMOH
  rows first gave them (not sorted);
* ``BETA_i``, ``BETA_j`` (n,): the headings (deg) on the square's diagonal (WEC-Sim takes one
  heading pair per file);
* ``Re_F_ij``, ``Im_F_ij`` (n^2,): the full square, MATLAB's column-major ``F(:)``, so
  F(i, j) = flat[i + n j] (row i the first frequency); dimensional per A_i A_j (rho g L^m times
  the BEM file's value, WEC-Sim's L = 1), the lower triangle filled by symmetry;
* ``PHS_F_ij`` (not read; ``MOD_F_ij`` is not written).

The complex value: the difference square is rho g (Re - i Im) of the WAMIT/NEMOH row, i.e. the
conjugate of the exp(+iwt) row: exactly the internal exp(-iwt) QTF, read as stored. The sum square
is rho g (Re - i Im) in WEC-Sim v6.1.x but rho g (Re + i Im) from v7.0 (commit b5046992, May
2025); the file records neither its writer's version nor the sign, so the sum QTF is not read
(a warning names the group): give it as WAMIT .12s or NEMOH files.
"""

from __future__ import annotations

import warnings
from pathlib import Path

import h5py
import numpy as np

from hydrolink.server.hdb.reader_warnings import HDBWarning
from hydrolink.protocol.hdb.layout import BodyDofs, HDBError
from hydrolink.protocol.hdb.second_order import QTF, fill_qtf_square


def qtf_group(fh: h5py.File, body: str, source: Path) -> str | None:
    """The ``QTF<k>`` group under a body's excitation (None when there is none; HDBError for several)."""
    where = f"{body}/hydro_coeffs/excitation"
    found = [k for k in fh[where].keys() if k.startswith("QTF")] if where in fh else []
    if len(found) > 1:
        raise HDBError(source, where, f"holds several QTF groups {found}; WEC-Sim writes one per body")
    return f"{where}/{found[0]}" if found else None


def read_bemio_qtf(fh: h5py.File, bodies: list[str], source: Path, dofs: BodyDofs) -> QTF | None:
    """The difference QTF of every body's ``QTF<k>/Diff<dof>`` groups (see the module docstring),
    in SI and exp(-iwt), on one grid (``dofs``: the bodies' DOF layout; rigid DOFs only, none
    for generalized modes); None when no body has QTF groups."""
    groups = {n: g for n, body in enumerate(bodies) if (g := qtf_group(fh, body, source)) is not None}
    if not groups:
        return None
    rows: list[tuple[np.ndarray, ...]] = []
    sums = []
    for n, group in groups.items():
        for dof in range(6):
            if f"{group}/Sum{dof + 1}" in fh:
                sums.append(f"{group}/Sum{dof + 1}")
            name = f"{group}/Diff{dof + 1}"
            if name in fh:
                rows.append(_square_rows(fh, name, dofs.offsets[n] + dof, source))
    if sums:
        warnings.warn(f"{source}: {sums[0]} (and the other Sum groups) left out: WEC-Sim v6.1 stores the sum QTF "
                      "conjugated, v7.0 on not, and the file does not say which wrote it; give the sum QTF as WAMIT "
                      ".12s or NEMOH OUT_QTFP files", HDBWarning, stacklevel=4)
    if not rows:
        raise HDBError(source, next(iter(groups.values())), "a QTF group without Diff<dof> groups")
    w_i, w_j, b_i, b_j, dof, value = (np.concatenate(c) for c in zip(*rows))
    omega, d_i, d_j, square = fill_qtf_square(w_i, w_j, b_i, b_j, dof, value, dofs.size, "difference",
                                              source)
    return QTF(omega, d_i, d_j, square, None, f"{Path(source).name}: {', '.join(groups.values())} Diff (WEC-Sim BEMIO)")


def _vector(fh: h5py.File, name: str, source: Path) -> np.ndarray:
    """A dataset as a flat float vector (MATLAB writes (n, 1) as h5py (1, n))."""
    if name not in fh or not isinstance(fh[name], h5py.Dataset):
        raise HDBError(source, name, "missing dataset")
    value = np.asarray(fh[name][()])
    if not np.issubdtype(value.dtype, np.number) or np.iscomplexobj(value):
        raise HDBError(source, name, f"must hold real numbers, got {value.dtype}")
    value = value.astype(float).ravel()
    if not np.all(np.isfinite(value)):
        raise HDBError(source, name, "contains NaN or inf")
    return value


def _square_rows(fh: h5py.File, group: str, dof: int, source: Path) -> tuple[np.ndarray, ...]:
    """Every cell of one Diff<dof> square as rows (w_i, w_j, beta_i, beta_j, dof, T)."""
    per = _vector(fh, f"{group}/PER_i", source)
    n = per.size
    if n < 1 or np.any(per <= 0):
        raise HDBError(source, f"{group}/PER_i", "must be positive periods (s)")
    if np.unique(per).size != n:
        raise HDBError(source, f"{group}/PER_i", "repeats a period (one per row of the square)")
    beta_i, beta_j = (_vector(fh, f"{group}/BETA_{s}", source) for s in "ij")
    for s, beta in (("i", beta_i), ("j", beta_j)):
        if beta.size != n or np.ptp(beta) > 1e-9:
            raise HDBError(source, f"{group}/BETA_{s}", f"must hold one heading {n} times (the diagonal's; WEC-Sim "
                                                        f"takes one heading pair), got {np.unique(beta).tolist()}")
    re, im = (_vector(fh, f"{group}/{p}_F_ij", source) for p in ("Re", "Im"))
    for p, v in (("Re", re), ("Im", im)):
        if v.size != n * n:
            raise HDBError(source, f"{group}/{p}_F_ij", f"must hold the {n} x {n} square ({n * n} values, "
                                                        f"PER_i has {n}), got {v.size}")
    square = (re + 1j * im).reshape(n, n, order="F")          # F(i, j) = flat[i + n j]
    i, j = np.meshgrid(np.arange(n), np.arange(n), indexing="ij")
    w = 2 * np.pi / per
    ones = np.ones(n * n)
    return (w[i.ravel()], w[j.ravel()], np.deg2rad(beta_i[0]) * ones, np.deg2rad(beta_j[0]) * ones,
            np.full(n * n, dof), square.ravel())
