"""The first-order hydrodynamic tables of a WAMIT ``.out`` report, for a run whose numeric files
(``.1``, ``.3``, ``.hst``) are not at hand (WECCCOMP's WaveStar ships only its ``wavestar.out``).

The report prints the same nondimensional quantities as the numeric files, so they are returned
as the rows those files hold and the reader (:mod:`.reader`) makes them SI exactly as it does the
files' rows:

* radiation (the ``.1``'s ``PER I J Abar [Bbar]``): each ``ADDED-MASS [AND DAMPING] COEFFICIENTS``
  block; PER is the block's ``Wave period (sec)``, -1 for ``Wave period = infinite`` (w = 0) and 0
  for ``Wave period = zero`` (w = inf, A_inf), as WAMIT writes them in the ``.1``;
* excitation (the ``.3``'s ``PER BETA I Mod Pha Re Im``): the ``DIFFRACTION EXCITING FORCES AND
  MOMENTS`` rows ``I Mod Pha`` under each ``Wave Heading (deg)``, Re and Im from Mod and Pha (the
  report prints the phase in whole degrees: the excitation is good to +-0.5 deg, the ``.3`` to 1e-7);
* hydrostatics (the ``.hst``'s ``I J Cbar``): each body's ``C(3,3),C(3,4),C(3,5)``,
  ``C(4,4),C(4,5),C(4,6)`` and ``C(5,5),C(5,6)`` lines of the body parameters, (3,4), (3,5) and (4,5)
  mirrored as in the ``.hst`` (whose (6,4) and (6,5) are 0).

The report's other tables (Haskind and Froude-Krylov forces, RAOs, pressures, drift) are not read.
The period column is periods in s (the report prints periods whatever the run's IPEROUT).
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydrolink.protocol.hdb.layout import HDBError

_FLOAT = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eEdD][-+]?\d+)?"
_HYDROSTATIC_LINES = {"C(3,3),C(3,4),C(3,5):": ((3, 3), (3, 4), (3, 5)),
                      "C(4,4),C(4,5),C(4,6):": ((4, 4), (4, 5), (4, 6)),
                      "C(5,5),C(5,6):": ((5, 5), (5, 6))}
_MIRRORED = {(3, 4), (3, 5), (4, 5)}


@dataclass(frozen=True)
class Table:
    """Rows as the numeric file holds them (NaN where a row has fewer columns) and the report's
    1-based line number of each."""
    rows: np.ndarray
    lines: np.ndarray


@dataclass(frozen=True)
class OutTables:
    """A report's tables in the layout of the numeric files (module docstring)."""
    radiation: Table       # PER I J Abar Bbar
    excitation: Table | None   # PER BETA I Mod Pha Re Im (None: the report has no diffraction forces)
    hydrostatics: Table    # I J Cbar


def _table(rows: list[list[float]], lines: list[int], width: int) -> Table:
    padded = [r + [math.nan] * (width - len(r)) for r in rows]
    return Table(np.asarray(padded, float).reshape(-1, width), np.asarray(lines, int))


_NUMBER_START = frozenset("0123456789+-.")


def _numbers(line: str) -> list[float] | None:
    """The line's numbers when it is nothing but numbers (None otherwise). Most of a report's
    lines are table rows: converted at once, the few others fail on their first word."""
    tokens = line.split()
    if not tokens or tokens[0][0] not in _NUMBER_START:
        return None
    try:
        values = [float(t) for t in tokens]
    except ValueError:
        if not all(re.fullmatch(_FLOAT, t) for t in tokens):      # Fortran's D exponents
            return None
        values = [float(t.replace("D", "E").replace("d", "e")) for t in tokens]
    return values if all(map(math.isfinite, values)) and "_" not in line else None


class _Scan:
    """The state of one pass over the report: the current period, heading and table."""

    def __init__(self, path: Path):
        self.path = path
        self.period: float | None = None
        self.heading: float | None = None
        self.section = ""
        self.body = -1
        self.radiation: tuple[list, list] = ([], [])
        self.excitation: tuple[list, list] = ([], [])
        self.hydrostatics: tuple[list, list] = ([], [])

    def fail(self, number: int, why: str) -> HDBError:
        return HDBError(self.path.name, f"line {number}", why)

    def header(self, line: str, number: int) -> None:
        """A line that is not a table row: it may start a period, a table or a heading."""
        stripped = line.strip()
        if not stripped or stripped[0] in "*-":
            return
        if m := re.match(r"Wave period\s*=\s*(infinite|zero)\b", stripped):
            self.period, self.section = (-1.0 if m.group(1) == "infinite" else 0.0), ""
        elif m := re.match(rf"Wave period \(sec\)\s*=\s*({_FLOAT})", stripped):
            self.period, self.section = float(m.group(1)), ""
        elif stripped.startswith("ADDED-MASS"):
            self.section = "radiation"
        elif stripped.startswith("DIFFRACTION EXCITING FORCES"):
            self.section, self.heading = "excitation", None
        elif m := re.match(rf"Wave Heading \(deg\)\s*:\s*({_FLOAT})", stripped):
            self.heading = float(m.group(1))
        elif stripped.startswith("XBODY"):
            self.body += 1
        elif key := next((k for k in _HYDROSTATIC_LINES if stripped.startswith(k)), None):
            self._hydrostatic(stripped[len(key):], _HYDROSTATIC_LINES[key], number)
        elif stripped == stripped.upper() and re.search(r"[A-Z]{4}", stripped) and not stripped.startswith("I "):
            self.section = ""   # another table (Haskind, RAOs, pressures...): not read

    def _hydrostatic(self, text: str, entries: tuple, number: int) -> None:
        values = [float(v.replace("D", "E").replace("d", "e")) for v in re.findall(_FLOAT, text)]
        if self.body < 0 or len(values) != len(entries):
            raise self.fail(number, f"expected {len(entries)} hydrostatic coefficients after a body's XBODY line")
        rows, lines = self.hydrostatics
        for (i, j), value in zip(entries, values):
            for a, b in ((i, j), (j, i)) if (i, j) in _MIRRORED else ((i, j),):
                rows.append([6 * self.body + a, 6 * self.body + b, value])
                lines.append(number)

    def row(self, values: list[float], number: int) -> None:
        """A line of numbers in the current table."""
        if self.section == "radiation":
            if self.period is None or len(values) != (3 if self.period == -1.0 or self.period == 0.0 else 4):
                raise self.fail(number, "expected 'I J A(I,J) [B(I,J)]' under a wave period")
            self.radiation[0].append([self.period, *values])
            self.radiation[1].append(number)
        elif self.section == "excitation":
            if self.period is None or self.heading is None or len(values) != 3:
                raise self.fail(number, "expected 'I Mod Pha' under a wave period and a wave heading")
            i, mod, pha = values
            self.excitation[0].append([self.period, self.heading, i, mod, pha, mod * math.cos(math.radians(pha)),
                                       mod * math.sin(math.radians(pha))])
            self.excitation[1].append(number)


def read_out_tables(path: str | Path) -> OutTables:
    """The radiation, diffraction-excitation and hydrostatic tables of a WAMIT ``.out`` report
    (module docstring); HDBError naming the file and line of what cannot be read."""
    path = Path(path)
    scan = _Scan(path)
    try:
        text = path.read_text(errors="replace")
    except OSError as exc:
        raise HDBError(path, "file", f"cannot read: {exc.strerror or exc}") from None
    for number, line in enumerate(text.splitlines(), start=1):
        values = _numbers(line)
        if values is None:
            scan.header(line, number)
        elif scan.section:
            scan.row(values, number)
    if not scan.radiation[0]:
        raise HDBError(path.name, "added_mass", "no ADDED-MASS AND DAMPING COEFFICIENTS table: not a WAMIT "
                                                "report of a radiation run")
    if not scan.hydrostatics[0]:
        raise HDBError(path.name, "hydrostatic_stiffness", "no body's C(3,3),C(3,4),C(3,5) line")
    excitation = _table(*scan.excitation, 7) if scan.excitation[0] else None
    return OutTables(_table(*scan.radiation, 5), excitation, _table(*scan.hydrostatics, 3))
