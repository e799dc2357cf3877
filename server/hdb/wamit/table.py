"""WAMIT's free-format numeric tables and the units that make them SI: shared by the first-order
reader (:mod:`.wamit`) and the second-order one (:mod:`.wamit_second_order`)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydrolink.protocol.hdb.layout import HDBError


def is_number(token: str) -> bool:
    try:
        float(token)
    except ValueError:
        return False
    return True


def read_table(path: Path, ncols: tuple[int, ...], expected: str) -> tuple[np.ndarray, np.ndarray]:
    """Rows of a free-format numeric file, padded with NaN to ``max(ncols)`` columns.

    Leading header lines (first token not a number) are skipped; afterwards every non-blank line
    must hold one of ``ncols`` numbers. Returns (rows, 1-based line numbers)."""
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise HDBError(path, "file", f"cannot read: {exc.strerror or exc}") from None
    width = max(ncols)
    rows: list[list[float]] = []
    lines: list[int] = []
    for number, line in enumerate(text.splitlines(), start=1):
        tokens = line.replace("D", "E").replace("d", "e").split()
        if not tokens or (not rows and not is_number(tokens[0])):
            continue
        try:
            values = [float(t) for t in tokens]
        except ValueError:
            values = []
        if len(values) not in ncols:
            raise HDBError(path.name, f"line {number}", f"expected '{expected}', got {line.strip()!r}")
        if not all(math.isfinite(v) for v in values):
            raise HDBError(path.name, f"line {number}", f"not a finite number in {line.strip()!r}")
        rows.append(values + [math.nan] * (width - len(values)))
        lines.append(number)
    if not rows:
        raise HDBError(path.name, "file", f"no data lines (expected '{expected}')")
    return np.asarray(rows, float), np.asarray(lines)


def mode_indices(path: Path, table: np.ndarray, lines: np.ndarray, cols: list[int]) -> np.ndarray:
    """Integer mode indices (1-based) from ``cols`` of ``table``; HDBError on non-integers."""
    idx = table[:, cols]
    bad = (idx != np.round(idx)) | (idx < 1)
    if np.any(bad):
        row = int(np.argwhere(bad)[0, 0])
        raise HDBError(path.name, f"line {lines[row]}", f"mode index must be an integer >= 1, got {idx[row]}")
    return idx.astype(int)


def scale_exponent(i: np.ndarray, j: np.ndarray | None, base: int, rotational: np.ndarray | None = None) -> np.ndarray:
    """WAMIT length-scale exponent: ``base`` plus one per rotational mode index (1-based);
    ``rotational``: which modes (0-based) are rotations when a run has generalized modes (those
    count as translations), else modes 4-6 of every six."""
    rot = (lambda m: (m - 1) % 6 >= 3) if rotational is None else (lambda m: rotational[m - 1])   # noqa: E731
    k = base + rot(np.asarray(i))
    if j is not None:
        k = k + rot(np.asarray(j))
    return k


def frequencies(values: np.ndarray, iperout: int, g: float, source: str, ulen: float = 1.0) -> np.ndarray:
    """Angular frequency of each positive first-column value (IPEROUT 3: ω²L/g, so ω = sqrt(g v / L))."""
    if iperout == 1:
        return 2.0 * np.pi / values
    if iperout == 2:
        return values
    if iperout == 3:
        return np.sqrt(g * values / ulen)
    raise HDBError(source, "IPEROUT", f"output frequency type {iperout} is not supported (use 1, 2 or 3)")


def special_rows(first: np.ndarray, iperout: int) -> tuple[np.ndarray, np.ndarray]:
    """Masks of (infinite-frequency, ignored) rows: WAMIT marks the zero and infinite periods with
    -1 and 0 in the first column whatever IPEROUT (``iperout`` is not used): 0 is w = inf (kept
    as A_inf), a negative value w = 0 (ignored)."""
    del iperout
    return first == 0.0, first < 0.0


@dataclass(frozen=True)
class Units:
    """What turns WAMIT's nondimensional columns into SI: rho, g, ULEN and the period column's meaning."""
    rho: float
    g: float
    ulen: float
    iperout: int
    rotational: np.ndarray | None = None   # (n_dof,) bool: which modes are rotations (generalized modes: not)
