"""NEMOH v3 QTF output (``results/QTF/OUT_QTFM_N*.dat`` difference, ``OUT_QTFP_N*.dat`` sum) read
into the QTF part of an HDB (:mod:`hydrolink.protocol.hdb.second_order`).

Rows after a header line: ``w_1 w_2 beta_1 beta_2 DoF |QTF|/(rho g) phase(deg) Re/(rho g) Im/(rho g)``
(one triangle of the square; the other is filled: conjugate symmetry for the difference QTF, plain
symmetry for the sum), headings in degrees, DoF 1..6N, no length scale. The frequency column's unit
is the one ``Nemoh.cal``'s QTF post-processing line chose and the file does not record it, nor the
time convention of its complex values: the caller states both (``frequency_unit``, ``convention``);
exp(+i w t) values are conjugated here, once. NEMOH has no linear HDB reader in hydrolink: the QTF
is added to an HDB read from another format, from a scene by ``bodies[i].qtf`` (which states the
unit and convention; :func:`hydrolink.clients.run.with_nemoh_qtf`), or in Python with
:func:`hydrolink.protocol.hdb.second_order.with_second_order`.
"""

from __future__ import annotations

from pathlib import Path

import numpy as np

from hydrolink.protocol.hdb.layout import TIME_CONVENTION, HDBError
from hydrolink.protocol.hdb.second_order import QTF, fill_qtf_square
from hydrolink.server.hdb.wamit.table import read_table

FREQUENCY_UNITS = ("rad/s", "Hz", "s")
CONVENTIONS = (TIME_CONVENTION, "exp(+iwt)")


def read_nemoh_qtf(*, difference: str | Path | None = None, total_sum: str | Path | None = None, rho: float,
                   g: float, n_dof: int, frequency_unit: str, convention: str) -> QTF:
    """The difference (``OUT_QTFM_N*.dat``) and/or sum (``OUT_QTFP_N*.dat``) QTF in SI, exp(-iwt),
    for an HDB of ``n_dof`` modes. HDBError naming the file and line or field."""
    if frequency_unit not in FREQUENCY_UNITS:
        raise HDBError(difference or total_sum or "", "frequency_unit",
                       f"must be one of {list(FREQUENCY_UNITS)}, got {frequency_unit!r}")
    if convention not in CONVENTIONS:
        raise HDBError(difference or total_sum or "", "convention",
                       f"must be one of {list(CONVENTIONS)}, got {convention!r}")
    read = {}
    for kind, path in (("difference", difference), ("sum", total_sum)):
        if path is not None:
            read[kind] = (Path(path), _read_file(Path(path), kind, rho, g, n_dof, frequency_unit, convention))
    if not read:
        raise HDBError("", "difference", "give the difference and/or the sum QTF file")
    (first_path, first), *rest = read.values()
    for path, grid in rest:
        if grid[0].shape != first[0].shape or not np.allclose(grid[0], first[0], rtol=1e-6) or not (
                np.array_equal(grid[1], first[1]) and np.array_equal(grid[2], first[2])):
            raise HDBError(path.name, "qtf_omega", f"frequencies or heading pairs differ from {first_path.name}'s")
    source = "; ".join(f"{p.name} (NEMOH)" for p, _ in read.values())
    return QTF(first[0], first[1], first[2], read["difference"][1][3] if "difference" in read else None,
               read["sum"][1][3] if "sum" in read else None, source)


def _read_file(path: Path, kind: str, rho: float, g: float, n_dof: int, unit: str, convention: str):
    if not path.is_file():
        raise HDBError(path, "file", "not found")
    table, lines = read_table(path, (9,), "w1 w2 beta1 beta2 DoF Mod Pha Re Im")
    dof = table[:, 4]
    bad = (dof != np.round(dof)) | (dof < 1) | (dof > n_dof)
    if np.any(bad):
        k = int(np.argmax(bad))
        raise HDBError(path.name, f"line {lines[k]}", f"DoF must be an integer 1..{n_dof}, got {dof[k]:g}")
    if np.any(table[:, :2] <= 0):
        k = int(np.argmax((table[:, :2] <= 0).any(axis=1)))
        raise HDBError(path.name, f"line {lines[k]}", "frequencies must be > 0")
    w = table[:, :2] * (2 * np.pi if unit == "Hz" else 1.0)
    if unit == "s":
        w = 2 * np.pi / table[:, :2]
    value = rho * g * (table[:, 7] + 1j * table[:, 8])
    if convention != TIME_CONVENTION:
        value = np.conj(value)
    return fill_qtf_square(w[:, 0], w[:, 1], np.deg2rad(table[:, 2]), np.deg2rad(table[:, 3]),
                           np.round(dof).astype(int) - 1, value, n_dof, kind, path.name)
