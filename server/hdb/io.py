"""``load_hdb``: one entry point that recognises the HDB file format and returns the internal HDB.

* WAMIT: ``.1``/``.2``/``.3``/``.hst``/``.out``/... or the common stem (``rm3`` -> ``rm3.1`` ...);
  nondimensional, so ``rho`` applies (default 1000; a scene's run passes its [water] density);
  ``wamit``: the scene's ``bodies[i].wamit`` table for what the run's files do not state.
* BEMIO (WEC-Sim): ``.h5``/``.hdf5``.
* NetCDF ``.nc``: hydrolink's own (attribute ``hydrolink_hdb``) or a Capytaine export.

Dimensional formats carry their own rho; a ``rho`` that disagrees with it is an error (the
coefficients cannot be rescaled to another density without knowing which terms scale).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Mapping

import xarray as xr

from hydrolink.server.hdb.capytaine_io import from_capytaine_dataset
from hydrolink.protocol.hdb.layout import HDBError, with_hdb_warnings
from hydrolink.server.hdb.reader_warnings import recorded
from hydrolink.protocol.hdb.schema import from_netcdf_dataset
from hydrolink.server.hdb.wamit.reader import WAMIT_SUFFIXES, read_wamit, wamit_stem
from hydrolink.server.hdb.wamit.second_order import QTF_LEVELS, SECOND_ORDER_SUFFIXES

WAMIT_READ = (".1", ".2", ".3", ".hst", ".out", ".cfg", ".pot", ".mmx", ".frc",
              *SECOND_ORDER_SUFFIXES)   # the files read_wamit opens (where present)

DEFAULT_RHO = 1000.0


def _check_rho(ds: xr.Dataset, rho: float | None, path: Path) -> xr.Dataset:
    if rho is not None and not math.isclose(float(ds.attrs["rho"]), rho, rel_tol=1e-9):
        raise HDBError(path, "rho", f"the file was computed with rho={ds.attrs['rho']:g}; "
                                    f"rho={rho:g} can only be chosen for nondimensional (WAMIT) files")
    return ds


def _load_netcdf(path: Path, convention: str | None = None) -> xr.Dataset:
    try:
        with xr.open_dataset(path, engine="netcdf4") as raw:
            ds = raw.load()
    except (OSError, ValueError) as exc:
        raise HDBError(path, "file", f"not a readable NetCDF file ({exc})") from None
    if "hydrolink_hdb" in ds.attrs:
        return from_netcdf_dataset(ds, path)
    if "radiating_dof" in ds.variables and "influenced_dof" in ds.variables and "added_mass" in ds:
        return from_capytaine_dataset(ds, path, convention=convention)
    raise HDBError(path, "format", "NetCDF file is neither a hydrolink HDB (attribute 'hydrolink_hdb') "
                                   "nor a Capytaine dataset (added_mass over radiating_dof/influenced_dof)")


def _is_wamit(path: Path) -> bool:
    """A WAMIT file name (``rm3.1``, ``rm3.hst``...) or a stem with a ``.1`` (or ``.out``) beside it."""
    stem = wamit_stem(path)
    return stem != path or (not path.is_file() and any(stem.with_name(stem.name + s).is_file() for s in (".1", ".out")))


def nondimensional(path: str | Path) -> bool:
    """Whether ``path`` names a nondimensional HDB (a WAMIT run), whose density is the caller's."""
    path = Path(path)
    return path.suffix.lower() not in (".h5", ".hdf5", ".nc", ".toml") and _is_wamit(path)


def _noted(ds: xr.Dataset, in_file: str, why: str) -> xr.Dataset:
    """Record the time convention the file was read in and why, unless its reader did
    (``hydrolink hdb info`` shows them)."""
    ds.attrs.setdefault("time_convention_in_file", in_file)
    ds.attrs.setdefault("time_convention_from", why)
    return ds


def load_hdb(path: str | Path, *, rho: float | None = None, convention: str | None = None,
             wamit: Mapping | None = None) -> xr.Dataset:
    """Read an HDB file of any supported format into the internal layout (validated); what the
    reader found doubtful is kept in the HDB's ``warnings`` attribute, not shown (server/hdb/
    reader_warnings.py: it travels with the HDB into ``setup.warnings``).
    ``convention``: the time convention of a Capytaine-layout file's complex amplitudes when the
    file does not declare it ("exp(-iwt)", Capytaine's, by default; "exp(+iwt)": conjugated).
    ``wamit``: for a WAMIT run, what its files do not state (the scene's ``bodies[i].wamit`` table,
    :meth:`Scene.wamit_statement`), with ``excitation_needed`` (False: a set without ``.3`` is read)."""
    notes: list[str] = []
    with recorded(notes):
        ds = _read(Path(path), rho, convention, wamit)
    with_hdb_warnings(ds, notes)
    return ds


def _read(path: Path, rho: float | None, convention: str | None, wamit: Mapping | None) -> xr.Dataset:
    """:func:`load_hdb`'s reading, by format."""
    suffix = path.suffix.lower()
    if convention is not None and suffix != ".nc":
        raise HDBError(path, "convention", "only for a Capytaine-layout NetCDF file: WAMIT and BEMIO files have "
                                          "their own (exp(+iwt)), converted by their readers")
    if wamit and any(k != "excitation_needed" for k in wamit) and not _is_wamit(path):
        raise HDBError(path, "wamit", "only for a WAMIT run's files: this format states its own run facts")
    if suffix in (".h5", ".hdf5"):
        from hydrolink.server.hdb.bemio import read_bemio   # h5py: only a BEMIO file's reading needs it
        return _noted(_check_rho(read_bemio(path), rho, path), "exp(+iwt)", "BEMIO's (WEC-Sim), conjugated at reading")
    if suffix == ".nc":
        if not path.is_file():
            raise HDBError(path, "file", "not found")
        return _noted(_check_rho(_load_netcdf(path, convention), rho, path), "exp(-iwt)",
                      "hydrolink's own HDB file (its attribute time_convention)")
    if _is_wamit(path):
        return _noted(read_wamit(path, rho=DEFAULT_RHO if rho is None else rho, stated=wamit), "exp(+iwt)",
                      "WAMIT's, conjugated at reading")
    if not path.exists():
        raise HDBError(path, "file", "not found")
    raise HDBError(path, "format", "unknown HDB format (expected WAMIT .1/.3/.hst or stem, BEMIO .h5, "
                                   f"hydrolink or Capytaine .nc; WAMIT suffixes: {' '.join(WAMIT_SUFFIXES)})")


def _unread_qtf_level(stem: Path, suffix: str) -> bool:
    """A QTF file of a level the reader does not read (a more complete level of its kind is beside it)."""
    levels = [level for level, _ in QTF_LEVELS]
    if suffix[:-1] not in levels:
        return False
    better = levels[:levels.index(suffix[:-1])]
    return any(stem.with_name(f"{stem.name}{level}{suffix[-1]}").is_file() for level in better)


def file_set(path: str | Path, *, rho: float | None = None) -> "HDBFiles":
    """The files ``load_hdb(path)`` reads, as an HDB file set to send by content (SPEC §5.1):
    a WAMIT run's ``.1``, ``.2``/``.3``, ``.hst``, ``.out``, ``.cfg``, ``.pot``, ``.mmx``, ``.frc``
    (and second-order files) where present, found beside ``path`` as given; a BEMIO or
    NetCDF file alone. HDBError naming the file when it is not an HDB file of a known format."""
    from hydrolink.protocol.hdb.wire import HDBFiles
    path = Path(path)
    suffix = path.suffix.lower()
    if suffix in (".h5", ".hdf5", ".nc"):
        if not path.is_file():
            raise HDBError(path, "file", "not found")
        if rho is not None:
            raise HDBError(path, "rho", "only for nondimensional (WAMIT) files")
        return HDBFiles("bemio" if suffix != ".nc" else "netcdf", (path,))
    if _is_wamit(path):
        stem = wamit_stem(path)
        paths = tuple(p for s in WAMIT_READ if (p := stem.with_name(stem.name + s)).is_file()
                      and not (s == ".2" and stem.with_name(stem.name + ".3").is_file())
                      and not _unread_qtf_level(stem, s))
        if not any(p.suffix in (".1", ".out") for p in paths):
            raise HDBError(path, "file", f"WAMIT radiation file {stem.name}.1 (or the run's report {stem.name}.out) "
                                         "not found")
        return HDBFiles("wamit", paths, rho)
    raise HDBError(path, "format", "no HDB file set for this file (WAMIT .1 or stem, BEMIO .h5, .nc)")
