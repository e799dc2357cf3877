"""Reader for WAMIT numeric output (``.1``, ``.3``/``.2``, ``.hst``, optional ``.out``/``.cfg``, and
the second-order ``.7``/``.8``/``.9``/``.1Xd``/``.1Xs`` files of :mod:`.wamit_second_order`).

WAMIT files are nondimensional and use exp(+i w t). This module dimensionalises with the ULEN
and g of the run and the caller's rho (A = rho L^k Abar, B = rho w L^k Bbar, X = rho g L^m Xbar,
C = rho g L^k Cbar) and conjugates the excitation once, here, into the internal exp(-i w t).

The run's facts (g, ULEN, water depth, body names, XBODY: the point the rotational modes refer
to, used as ``reference_point``; VCG; displaced volume and centre of buoyancy, shifted by XBODY into
the global frame; the first column's meaning, IPEROUT) are read from the ``.out``, else the
``.mmx``/``.pot``/``.frc``/``.cfg`` beside the ``.1``, else taken from the scene's
``bodies[i].wamit`` table; none is assumed (:mod:`.wamit_run`). The siblings are looked for beside
the path as given (a symlinked ``.1`` finds the files beside the link).

Generalized modes (NEWMDS, issue 38): each body's modes are its rigid six then its NEWMDS(k)
generalized modes, numbered on in the files (body k's block of 6 + NEWMDS(k) after body k-1's),
labelled ``mode1``..``modeN``; their columns scale like translations' (ULEN = 1 reads them as
written; another ULEN is warned about, the modes' own scaling being the user's).

Hydrostatics: WAMIT's ``.hst`` includes the gravity terms -m g VCG in C44 and C55 (m = rho V,
alternative form 1 of the ``.frc``) when a body's VCG is not 0; they are taken out here (the
schema's stiffness is buoyancy and waterplane only; the scene's mass and centre of gravity add
gravity once, server/hydrostatics.py).

Without a ``.1`` the tables are read from the run's ``.out`` report where there is one
(:mod:`.out_tables`: the radiation, diffraction and hydrostatic tables it prints).

Without a ``.3`` (or ``.2``) the set is read only for a scene that needs no excitation
(``excitation_needed`` False: still water), with a zero excitation force at heading 0 and the
attribute ``excitation_force`` saying so.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import numpy as np
import xarray as xr

from hydrolink.protocol.hdb.layout import BodyDofs, HDBError
from hydrolink.protocol.hdb.schema import make_hdb
from hydrolink.server.hdb.wamit.out_tables import Table, read_out_tables
from hydrolink.server.hdb.wamit.second_order import SECOND_ORDER_SUFFIXES, read_drift, read_qtf
from hydrolink.server.hdb.wamit.run import RunFacts, run_facts
from hydrolink.server.hdb.wamit.table import Units, frequencies, mode_indices, read_table, scale_exponent, special_rows

WAMIT_SUFFIXES = (".1", ".2", ".3", ".3fk", ".3sc", ".hst", ".out", ".cfg", ".pot", ".frc", ".mmx", ".4",
                  *SECOND_ORDER_SUFFIXES)


def wamit_stem(path: str | Path) -> Path:
    """The common stem of a WAMIT run (``rm3`` for ``rm3.1``, ``rm3.hst``, or ``rm3`` itself)."""
    path = Path(path)
    for suffix in sorted(WAMIT_SUFFIXES, key=len, reverse=True):
        if path.name.lower().endswith(suffix) and len(path.name) > len(suffix):
            return path.with_name(path.name[: -len(suffix)])
    return path


def read_wamit(path: str | Path, rho: float = 1000.0, stated: Mapping | None = None) -> xr.Dataset:
    """Read a WAMIT run (``.1`` file or common stem) into the internal HDB layout.
    ``stated``: the scene's ``bodies[i].wamit`` table (what no file of the run states) and
    ``excitation_needed`` (default True: a set without ``.3``/``.2`` is refused)."""
    stated = dict(stated or {})
    excitation_needed = bool(stated.pop("excitation_needed", True))
    stem = wamit_stem(path)
    file1 = stem.with_name(stem.name + ".1")
    report = stem.with_name(stem.name + ".out")
    tables = read_out_tables(report) if not file1.is_file() and report.is_file() else None
    if tables is not None:
        file1 = report        # the run's report stands for its numeric files (errors name it)
    elif not file1.is_file():
        raise HDBError(path, "file", f"WAMIT radiation file {file1.name} (or the run's report {report.name}) not found")
    excitation_file = next((stem.with_name(stem.name + s) for s in (".3", ".2")
                            if stem.with_name(stem.name + s).is_file()), None)
    if tables is not None:
        excitation_file = None if tables.excitation is None else report
    if excitation_file is None and excitation_needed:
        raise HDBError(file1, "excitation_force", f"no {stem.name}.3 (or .2) excitation file beside it, and the "
                                                  "scene's waves need the excitation force (a still-water scene "
                                                  "reads the set without it)")
    hst_file = report if tables is not None else stem.with_name(stem.name + ".hst")
    if not hst_file.is_file():
        raise HDBError(file1, "hydrostatic_stiffness", f"no {hst_file.name} beside it")
    if not (np.isfinite(rho) and rho > 0):
        raise HDBError(file1, "rho", f"must be finite and > 0, got {rho}")

    t1, l1 = ((tables.radiation.rows, tables.radiation.lines) if tables is not None
              else read_table(file1, (4, 5), "PER I J Abar [Bbar]"))
    ij = mode_indices(file1, t1, l1, [1, 2])
    facts = run_facts(stem, file1, t1[:, 0], int(ij.max()), stated)
    dofs = BodyDofs(tuple(facts.names), tuple(tuple(f"mode{k}" for k in range(1, n + 1)) for n in facts.modes))
    rotational = np.zeros(dofs.size, bool)
    for at in dofs.offsets:
        rotational[at + 3:at + 6] = True
    units = Units(rho, facts.g, facts.ulen, facts.iperout, rotational)
    rad = _read_radiation(file1, t1, l1, ij, units, dofs.size)
    if excitation_file is not None:
        betas, excitation = _read_excitation(excitation_file, file1, rad, units, tables and tables.excitation)
    else:
        betas, excitation = np.zeros(1), np.zeros((rad.omega.size, 1, rad.n_dof), complex)
    stiffness = _without_gravity(_read_hydrostatics(hst_file, file1, rad.n_dof, units, tables and tables.hydrostatics),
                                 facts, units, dofs)
    ds = make_hdb(
        bodies=facts.names, omega=rad.omega, wave_direction=np.deg2rad(betas),
        added_mass=rad.added_mass, radiation_damping=rad.damping, excitation_force=excitation,
        hydrostatic_stiffness=stiffness, reference_point=facts.xbody,
        rho=rho, g=facts.g, water_depth=facts.depth, source=str(file1),
        added_mass_inf=rad.added_mass_inf, displaced_volume=facts.volume, center_of_buoyancy=facts.cb,
        mean_drift=read_drift(stem, units, rad.n_dof), qtf=read_qtf(stem, units, rad.n_dof),
        modes=dofs.mode_map(),
    )
    ds.attrs["wamit_facts_from"] = "; ".join(f"{k}: {v}" for k, v in facts.origin.items())
    if excitation_file is None:
        ds.attrs["excitation_force"] = f"absent (no {stem.name}.3 or .2): zero, for a still-water scene only"
    return ds


def _without_gravity(stiffness: np.ndarray, facts: RunFacts, u: Units, dofs: BodyDofs) -> np.ndarray:
    """The ``.hst`` stiffness without WAMIT's gravity terms -m g VCG (m = rho V) in C44 and C55."""
    if not np.any(facts.vcg != 0.0):
        return stiffness
    stiffness = stiffness.copy()
    for at, vcg, volume in zip(dofs.offsets, facts.vcg, facts.volume):
        for k in (at + 3, at + 4):
            stiffness[k, k] += u.rho * u.g * volume * vcg
    return stiffness


@dataclass(frozen=True)
class _Radiation:
    """The ``.1`` file in SI: its period column values, the sorted frequencies and each period's rank."""
    periods: np.ndarray          # (n_w,) the distinct period-column values, sorted as numbers
    rank: np.ndarray             # (n_w,) position of each of ``periods`` in ``omega``
    omega: np.ndarray            # (n_w,) rad/s, ascending
    added_mass: np.ndarray       # (n_w, n_dof, n_dof)
    damping: np.ndarray          # (n_w, n_dof, n_dof)
    added_mass_inf: np.ndarray | None   # (n_dof, n_dof) from the PER = 0 rows
    n_dof: int


def _read_radiation(file1: Path, t1: np.ndarray, l1: np.ndarray, ij: np.ndarray, u: Units,
                    n_dof: int) -> _Radiation:
    """Added mass and damping (A = rho L^k Abar, B = rho omega L^k Bbar) and A_inf of a ``.1`` table."""
    inf_rows, skip_rows = special_rows(t1[:, 0], u.iperout)
    freq_rows = ~inf_rows & ~skip_rows
    missing_b = freq_rows & np.isnan(t1[:, 4])
    if np.any(missing_b):
        raise HDBError(file1.name, f"line {l1[np.argmax(missing_b)]}", "expected 'PER I J Abar Bbar' (no Bbar)")
    periods = np.unique(t1[freq_rows, 0])
    if periods.size < 2:
        raise HDBError(file1.name, "omega", f"needs at least 2 frequencies, got {periods.size}")
    omega_unsorted = frequencies(periods, u.iperout, u.g, str(file1), u.ulen)
    order = np.argsort(omega_unsorted)
    omega = omega_unsorted[order]
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)

    i, j = ij[freq_rows, 0] - 1, ij[freq_rows, 1] - 1
    w_idx = rank[np.searchsorted(periods, t1[freq_rows, 0])]
    k = scale_exponent(i + 1, j + 1, 3, u.rotational)
    added_mass = np.zeros((omega.size, n_dof, n_dof))
    damping = np.zeros_like(added_mass)
    added_mass[w_idx, i, j] = u.rho * u.ulen ** k * t1[freq_rows, 3]
    damping[w_idx, i, j] = u.rho * omega[w_idx] * u.ulen ** k * t1[freq_rows, 4]
    added_mass_inf = None
    if np.any(inf_rows):
        ii, jj = ij[inf_rows, 0] - 1, ij[inf_rows, 1] - 1
        added_mass_inf = np.zeros((n_dof, n_dof))
        added_mass_inf[ii, jj] = u.rho * u.ulen ** scale_exponent(ii + 1, jj + 1, 3, u.rotational) * t1[inf_rows, 3]
    return _Radiation(periods, rank, omega, added_mass, damping, added_mass_inf, n_dof)


def _read_excitation(path: Path, file1: Path, rad: _Radiation, u: Units,
                     table: Table | None = None) -> tuple[np.ndarray, np.ndarray]:
    """Headings (deg) and excitation per unit wave amplitude (n_w, n_beta, 6N) of a ``.3``/``.2``
    file (or ``table``: the report's rows, :mod:`.out_tables`), X = rho g L^m (Re + i Im),
    conjugated to exp(-i omega t)."""
    t3, l3 = (table.rows, table.lines) if table is not None else read_table(path, (7,), "PER BETA I Mod Pha Re Im")
    modes3 = mode_indices(path, t3, l3, [2])[:, 0] - 1
    inf3, skip3 = special_rows(t3[:, 0], u.iperout)
    keep = ~inf3 & ~skip3
    t3, l3, modes3 = t3[keep], l3[keep], modes3[keep]
    unknown = ~np.isin(t3[:, 0], rad.periods)
    if np.any(unknown):
        raise HDBError(path.name, f"line {l3[np.argmax(unknown)]}",
                       f"frequency column {t3[np.argmax(unknown), 0]} is not among the {file1.name} frequencies")
    missing = np.setdiff1d(rad.periods, t3[:, 0])
    if missing.size:
        raise HDBError(path.name, "excitation_force",
                       f"no rows for frequency column {missing[0]} (present in {file1.name})")
    if np.any(modes3 >= rad.n_dof):
        raise HDBError(path.name, f"line {l3[np.argmax(modes3 >= rad.n_dof)]}",
                       f"mode {modes3.max() + 1} exceeds the {rad.n_dof} modes of {file1.name}")
    betas = np.unique(t3[:, 1])
    beta_idx = np.searchsorted(betas, t3[:, 1])
    m = scale_exponent(modes3 + 1, None, 2, u.rotational)
    excitation = np.zeros((rad.omega.size, betas.size, rad.n_dof), complex)
    excitation[rad.rank[np.searchsorted(rad.periods, t3[:, 0])], beta_idx, modes3] = (
        u.rho * u.g * u.ulen ** m * (t3[:, 5] - 1j * t3[:, 6]))
    return betas, excitation


def _read_hydrostatics(path: Path, file1: Path, n_dof: int, u: Units, table: Table | None = None) -> np.ndarray:
    """The hydrostatic stiffness (6N, 6N) of a ``.hst`` file (or ``table``: the report's rows),
    C = rho g L^k Cbar."""
    th, lh = (table.rows, table.lines) if table is not None else read_table(path, (3,), "I J Cbar")
    ijh = mode_indices(path, th, lh, [0, 1]) - 1
    if np.any(ijh >= n_dof):
        raise HDBError(path.name, f"line {lh[np.argmax((ijh >= n_dof).any(axis=1))]}",
                       f"mode index exceeds the {n_dof} modes of {file1.name}")
    stiffness = np.zeros((n_dof, n_dof))
    stiffness[ijh[:, 0], ijh[:, 1]] = (u.rho * u.g * u.ulen ** scale_exponent(ijh[:, 0] + 1, ijh[:, 1] + 1, 2, u.rotational)
                                       * th[:, 2])
    return stiffness
