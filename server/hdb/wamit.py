"""Reader for WAMIT numeric output (``.1``, ``.3``/``.2``, ``.hst``, optional ``.out``/``.cfg``, and
the second-order ``.7``/``.8``/``.9``/``.1Xd``/``.1Xs`` files of :mod:`.wamit_second_order`).

WAMIT files are nondimensional and use exp(+i w t). This module dimensionalises with the ULEN
and g of the run and the caller's rho (A = rho L^k Abar, B = rho w L^k Bbar, X = rho g L^m Xbar,
C = rho g L^k Cbar) and conjugates the excitation once, here, into the internal exp(-i w t).

Optional ``.out`` facts: g, ULEN, water depth, body names (from the ``.gdf`` file names), XBODY
(the point the rotational modes refer to, used as ``reference_point``), displaced volume (VOLX)
and centre of buoyancy (reported in body axes, shifted here by XBODY into the global frame).
Without an ``.out``: bodies ``body1``, ``body2``..., reference points at the origin, g from the
``.cfg`` (GRAV) or 9.80665 (WAMIT's default), infinite depth.
"""

from __future__ import annotations

import math
import re
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.protocol.hdb.layout import HDBError
from hydrolink.protocol.hdb.schema import make_hdb
from hydrolink.server.hdb.wamit_second_order import SECOND_ORDER_SUFFIXES, read_drift, read_qtf
from hydrolink.server.hdb.wamit_table import Units, frequencies, mode_indices, read_table, scale_exponent, special_rows

WAMIT_SUFFIXES = (".1", ".2", ".3", ".3fk", ".3sc", ".hst", ".out", ".cfg", ".pot", ".frc", ".4", *SECOND_ORDER_SUFFIXES)
DEFAULT_G = 9.80665
_FLOAT = r"[-+]?(?:\d+\.?\d*|\.\d+)(?:[eEdD][-+]?\d+)?"


def wamit_stem(path: str | Path) -> Path:
    """The common stem of a WAMIT run (``rm3`` for ``rm3.1``, ``rm3.hst``, or ``rm3`` itself)."""
    path = Path(path)
    for suffix in sorted(WAMIT_SUFFIXES, key=len, reverse=True):
        if path.name.lower().endswith(suffix) and len(path.name) > len(suffix):
            return path.with_name(path.name[: -len(suffix)])
    return path


def _read_cfg(stem: Path) -> dict[str, str]:
    """KEY=value settings of the ``.cfg`` (upper-case keys), empty if there is none."""
    cfg = stem.with_name(stem.name + ".cfg")
    if not cfg.is_file():
        return {}
    out = {}
    for match in re.finditer(r"^\s*([A-Za-z_]\w*)\s*=\s*(\S+)", cfg.read_text(errors="replace"), re.M):
        out[match.group(1).upper()] = match.group(2)
    return out


def _read_out(stem: Path) -> dict:
    """Run facts from the ``.out`` report (only the part before the first frequency's results)."""
    out_path = stem.with_name(stem.name + ".out")
    if not out_path.is_file():
        return {}
    facts: dict = {"gdf": [], "xbody": [], "volume": [], "cb": []}
    with out_path.open(errors="replace") as fh:
        for number, line in enumerate(fh, start=1):
            if "Wave period" in line or "Output from  WAMIT" in line:
                break
            try:
                if m := re.search(r"N=\s*\d+\s+(\S+\.gdf)", line, re.I):
                    facts["gdf"].append(Path(m.group(1)).stem)
                elif m := re.search(rf"Gravity:\s*({_FLOAT})", line):
                    facts["g"] = float(m.group(1))
                    if m2 := re.search(rf"Length scale:\s*({_FLOAT})", line):
                        facts["ulen"] = float(m2.group(1))
                elif m := re.search(r"Water depth:\s*(\S+)", line):
                    word = m.group(1)
                    facts["depth"] = math.inf if word.lower().startswith("inf") else float(word)
                elif "XBODY" in line and "=" in line:
                    vals = [float(v) for v in re.findall(rf"=\s*({_FLOAT})", line)]
                    facts["xbody"].append(vals[:4])
                elif line.strip().startswith("Volumes"):
                    facts["volume"].append(float(re.findall(_FLOAT, line.split(":", 1)[1])[0]))
                elif line.strip().startswith("Center of Buoyancy"):
                    facts["cb"].append([float(v) for v in re.findall(_FLOAT, line.split(":", 1)[1])[:3]])
            except (ValueError, IndexError):
                raise HDBError(out_path.name, f"line {number}", f"cannot parse {line.strip()!r}") from None
    return facts


def _body_names(gdf: list[str], n_bodies: int) -> list[str]:
    """Body names from the ``.gdf`` stems (dots replaced, made unique) or body1, body2..."""
    if len(gdf) != n_bodies:
        return [f"body{n + 1}" for n in range(n_bodies)]
    names = [g.replace(".", "_") or f"body{n + 1}" for n, g in enumerate(gdf)]
    if len(set(names)) != len(names):
        names = [f"{name}{n + 1}" for n, name in enumerate(names)]
    return names


def read_wamit(path: str | Path, rho: float = 1000.0, g: float | None = None) -> xr.Dataset:
    """Read a WAMIT run (``.1`` file or common stem) into the internal HDB layout."""
    stem = wamit_stem(path)
    file1 = stem.with_name(stem.name + ".1")
    if not file1.is_file():
        raise HDBError(path, "file", f"WAMIT radiation file {file1.name} not found")
    excitation_file = next((stem.with_name(stem.name + s) for s in (".3", ".2")
                            if stem.with_name(stem.name + s).is_file()), None)
    if excitation_file is None:
        raise HDBError(file1, "excitation_force", f"no {stem.name}.3 (or .2) excitation file beside it")
    hst_file = stem.with_name(stem.name + ".hst")
    if not hst_file.is_file():
        raise HDBError(file1, "hydrostatic_stiffness", f"no {hst_file.name} beside it")
    if not (np.isfinite(rho) and rho > 0):
        raise HDBError(file1, "rho", f"must be finite and > 0, got {rho}")

    cfg, facts = _read_cfg(stem), _read_out(stem)
    try:
        g = float(g if g is not None else facts.get("g", cfg.get("GRAV", DEFAULT_G)))
        ulen = float(facts.get("ulen", cfg.get("ULEN", 1.0)))
        iperout = int(cfg.get("IPEROUT", 1))
    except ValueError as exc:
        raise HDBError(stem.with_name(stem.name + ".cfg"), "GRAV/ULEN/IPEROUT", str(exc)) from None
    units = Units(rho, g, ulen, iperout)
    rad = _read_radiation(file1, units, len(facts.get("xbody", [])))
    betas, excitation = _read_excitation(excitation_file, file1, rad, units)
    stiffness = _read_hydrostatics(hst_file, file1, rad.n_dof, units)
    n_bodies = rad.n_dof // 6
    reference_point, volume, cb = _body_geometry(stem, facts, n_bodies)
    return make_hdb(
        bodies=_body_names(facts.get("gdf", []), n_bodies), omega=rad.omega, wave_direction=np.deg2rad(betas),
        added_mass=rad.added_mass, radiation_damping=rad.damping, excitation_force=excitation,
        hydrostatic_stiffness=stiffness, reference_point=reference_point,
        rho=rho, g=g, water_depth=facts.get("depth", math.inf), source=str(file1),
        added_mass_inf=rad.added_mass_inf, displaced_volume=volume, center_of_buoyancy=cb,
        mean_drift=read_drift(stem, units, rad.n_dof), qtf=read_qtf(stem, units, rad.n_dof),
    )


@dataclass(frozen=True)
class _Radiation:
    """The ``.1`` file in SI: its period column values, the sorted frequencies and each period's rank."""
    periods: np.ndarray          # (n_w,) the distinct period-column values, sorted as numbers
    rank: np.ndarray             # (n_w,) position of each of ``periods`` in ``omega``
    omega: np.ndarray            # (n_w,) rad/s, ascending
    added_mass: np.ndarray       # (n_w, 6N, 6N)
    damping: np.ndarray          # (n_w, 6N, 6N)
    added_mass_inf: np.ndarray | None   # (6N, 6N) from the PER = 0 rows
    n_dof: int


def _read_radiation(file1: Path, u: Units, n_out_bodies: int) -> _Radiation:
    """Added mass and damping (A = rho L^k Abar, B = rho omega L^k Bbar) and A_inf of a ``.1`` file."""
    t1, l1 = read_table(file1, (4, 5), "PER I J Abar [Bbar]")
    ij = mode_indices(file1, t1, l1, [1, 2])
    inf_rows, skip_rows = special_rows(t1[:, 0], u.iperout)
    freq_rows = ~inf_rows & ~skip_rows
    missing_b = freq_rows & np.isnan(t1[:, 4])
    if np.any(missing_b):
        raise HDBError(file1.name, f"line {l1[np.argmax(missing_b)]}", "expected 'PER I J Abar Bbar' (no Bbar)")
    n_dof = 6 * max(-(-int(ij.max()) // 6), n_out_bodies)
    periods = np.unique(t1[freq_rows, 0])
    if periods.size < 2:
        raise HDBError(file1.name, "omega", f"needs at least 2 frequencies, got {periods.size}")
    omega_unsorted = frequencies(periods, u.iperout, u.g, str(file1))
    order = np.argsort(omega_unsorted)
    omega = omega_unsorted[order]
    rank = np.empty_like(order)
    rank[order] = np.arange(order.size)

    i, j = ij[freq_rows, 0] - 1, ij[freq_rows, 1] - 1
    w_idx = rank[np.searchsorted(periods, t1[freq_rows, 0])]
    k = scale_exponent(i + 1, j + 1, 3)
    added_mass = np.zeros((omega.size, n_dof, n_dof))
    damping = np.zeros_like(added_mass)
    added_mass[w_idx, i, j] = u.rho * u.ulen ** k * t1[freq_rows, 3]
    damping[w_idx, i, j] = u.rho * omega[w_idx] * u.ulen ** k * t1[freq_rows, 4]
    added_mass_inf = None
    if np.any(inf_rows):
        ii, jj = ij[inf_rows, 0] - 1, ij[inf_rows, 1] - 1
        added_mass_inf = np.zeros((n_dof, n_dof))
        added_mass_inf[ii, jj] = u.rho * u.ulen ** scale_exponent(ii + 1, jj + 1, 3) * t1[inf_rows, 3]
    return _Radiation(periods, rank, omega, added_mass, damping, added_mass_inf, n_dof)


def _read_excitation(path: Path, file1: Path, rad: _Radiation, u: Units) -> tuple[np.ndarray, np.ndarray]:
    """Headings (deg) and excitation per unit wave amplitude (n_w, n_beta, 6N) of a ``.3``/``.2``
    file, X = rho g L^m (Re + i Im), conjugated to exp(-i omega t)."""
    t3, l3 = read_table(path, (7,), "PER BETA I Mod Pha Re Im")
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
    m = scale_exponent(modes3 + 1, None, 2)
    excitation = np.zeros((rad.omega.size, betas.size, rad.n_dof), complex)
    excitation[rad.rank[np.searchsorted(rad.periods, t3[:, 0])], beta_idx, modes3] = (
        u.rho * u.g * u.ulen ** m * (t3[:, 5] - 1j * t3[:, 6]))
    return betas, excitation


def _read_hydrostatics(path: Path, file1: Path, n_dof: int, u: Units) -> np.ndarray:
    """The hydrostatic stiffness (6N, 6N) of a ``.hst`` file, C = rho g L^k Cbar."""
    th, lh = read_table(path, (3,), "I J Cbar")
    ijh = mode_indices(path, th, lh, [0, 1]) - 1
    if np.any(ijh >= n_dof):
        raise HDBError(path.name, f"line {lh[np.argmax((ijh >= n_dof).any(axis=1))]}",
                       f"mode index exceeds the {n_dof} modes of {file1.name}")
    stiffness = np.zeros((n_dof, n_dof))
    stiffness[ijh[:, 0], ijh[:, 1]] = (u.rho * u.g * u.ulen ** scale_exponent(ijh[:, 0] + 1, ijh[:, 1] + 1, 2)
                                       * th[:, 2])
    return stiffness


def _body_geometry(stem: Path, facts: dict, n_bodies: int) -> tuple[np.ndarray, np.ndarray | None, np.ndarray | None]:
    """Reference points (XBODY), displaced volumes and centres of buoyancy of the bodies from the
    ``.out`` report (zeros and None where it does not have them)."""
    reference_point = np.zeros((n_bodies, 3))
    volume = cb = None
    xbody = facts.get("xbody", [])
    if len(xbody) == n_bodies:
        xb = np.asarray(xbody, float)
        if xb.shape[1] >= 4 and np.any(xb[:, 3] != 0.0):
            raise HDBError(stem.with_name(stem.name + ".out"), "PHIBODY",
                           "bodies rotated about z (PHIBODY != 0) are not supported: their coefficients are in body axes")
        reference_point = xb[:, :3]
        if len(facts["volume"]) == n_bodies:
            volume = np.asarray(facts["volume"], float)
        if len(facts["cb"]) == n_bodies:
            cb = reference_point + np.asarray(facts["cb"], float)
    return reference_point, volume, cb
