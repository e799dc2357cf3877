"""The HDB on the wire (SPEC §5.1): an internal HDB dataset as a plain map and back ("HDB map"),
or an HDB's original files by content ("HDB file set", :class:`HDBFiles`).

One half of the session contract (the other is :mod:`hydrolink.protocol.setup`): a client sends
``to_wire(ds)`` or ``HDBFiles.entry()`` for each ``hdbs`` entry of ``hello``; the server rebuilds
and validates a map with ``from_wire`` — the same checks as for a file
(:func:`hydrolink.protocol.hdb.schema.validate_hdb`), every error naming the entry and the field —
and reads a file set with the readers of :mod:`hydrolink.server.hdb` (``server/hdb/file_set.py``).
"""

from __future__ import annotations

import hashlib
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.protocol.hdb.layout import (OPTIONAL_VARS, REQUIRED_ATTRS, REQUIRED_VARS, SECOND_ORDER_VARS, WARNINGS_ATTR,
                                           HDBError, hdb_warnings, with_hdb_warnings)
from hydrolink.protocol.hdb.schema import hdb_dofs, make_hdb, validate_hdb
from hydrolink.protocol.hdb.second_order import BODY_FIXED, QTF, MeanDrift, drift_body_fixed, qtf_kinds

FIRST_ORDER_OPTIONAL = tuple(k for k in OPTIONAL_VARS if k not in SECOND_ORDER_VARS)
DRIFT_FIELDS = ("drift_method", "drift_omega", "drift_direction")        # beside "mean_drift"
QTF_FIELDS = ("qtf_omega", "qtf_direction_i", "qtf_direction_j")        # beside "difference_qtf"/"sum_qtf"
SECOND_ORDER_ATTRS = ("mean_drift_note", "qtf_source")                  # strings in "attrs"
# and "attrs".mean_drift_body_fixed (0 or 1) with mean_drift


def to_wire(ds: xr.Dataset) -> dict:
    """Plain dict of numpy arrays and scalars (for the protocol's ``hello``); inverse of from_wire."""
    ds = validate_hdb(ds, ds.attrs.get("source", "<hdb>"))
    out: dict = {
        "bodies": [str(b) for b in ds["body"].values],
        "omega": ds["omega"].values.astype(float),
        "wave_direction": ds["wave_direction"].values.astype(float),
        "attrs": {k: (float(ds.attrs[k]) if k in REQUIRED_ATTRS else str(ds.attrs[k]))
                  for k in (*REQUIRED_ATTRS, "source") if k in ds.attrs},
    }
    for name in (*REQUIRED_VARS, *OPTIONAL_VARS):
        if name in ds:
            out[name] = np.ascontiguousarray(ds[name].values)
    if "mean_drift" in ds:
        out.update(drift_method=[str(m) for m in ds["drift_method"].values],
                   drift_omega=ds["drift_omega"].values.astype(float),
                   drift_direction=ds["drift_direction"].values.astype(float))
    if qtf_kinds(ds):
        out.update(qtf_omega=ds["qtf_omega_i"].values.astype(float),
                   qtf_direction_i=ds["qtf_direction_i"].values.astype(float),
                   qtf_direction_j=ds["qtf_direction_j"].values.astype(float))
    for key in SECOND_ORDER_ATTRS:
        if key in ds.attrs:
            out["attrs"][key] = str(ds.attrs[key])
    if "mean_drift" in ds:
        out["attrs"][BODY_FIXED] = int(drift_body_fixed(ds))
    if hdb_warnings(ds):
        out["attrs"][WARNINGS_ATTR] = list(hdb_warnings(ds))
    modes = hdb_dofs(ds).mode_map()
    if modes:                                  # generalized modes (SPEC 1.11): only when a body has some
        out["modes"] = {body: list(names) for body, names in modes.items()}
    return out


def _modes(data: dict, source: str) -> dict[str, list[str]] | None:
    """The map's ``modes`` field (each body's generalized modes after its six rigid DOFs), None
    when absent; HDBError naming it when it is not a map of body name to a list of mode names."""
    modes = data.get("modes")
    if modes is None:
        return None
    if not isinstance(modes, dict) or not all(isinstance(b, str) and isinstance(m, list)
                                              and all(isinstance(n, str) for n in m) for b, m in modes.items()):
        raise HDBError(source, "modes", "must be a map of body name to a list of mode names")
    unknown = [b for b in modes if b not in data["bodies"]]
    if unknown:
        raise HDBError(source, "modes", f"bodies {unknown} are not among the map's bodies {data['bodies']}")
    return modes


def _second_order(data: dict, source: str) -> tuple[MeanDrift | None, QTF | None]:
    """The mean drift and QTF parts of an HDB map (each with its grid fields), None where absent."""
    drift = qtf = None
    if "mean_drift" in data:
        for key in DRIFT_FIELDS:
            if key not in data:
                raise HDBError(source, key, "missing field (needed with mean_drift)")
        methods = data["drift_method"]
        if not isinstance(methods, list) or not all(isinstance(m, str) for m in methods):
            raise HDBError(source, "drift_method", "must be a list of method names")
        fixed = data["attrs"].get(BODY_FIXED)
        if isinstance(fixed, bool) or fixed not in (0, 1):
            raise HDBError(source, f"attrs.{BODY_FIXED}", f"must be 0 or 1 with mean_drift (1: computed with the body "
                                                         f"held fixed), got {fixed!r}")
        drift = MeanDrift(tuple(methods), data["drift_omega"], data["drift_direction"], data["mean_drift"],
                          str(data["attrs"].get("mean_drift_note", "")), fixed == 1)
    if "difference_qtf" in data or "sum_qtf" in data:
        for key in QTF_FIELDS:
            if key not in data:
                raise HDBError(source, key, "missing field (needed with a QTF)")
        qtf = QTF(data["qtf_omega"], data["qtf_direction_i"], data["qtf_direction_j"],
                  data.get("difference_qtf"), data.get("sum_qtf"), str(data["attrs"].get("qtf_source", "?")))
    return drift, qtf


def from_wire(data: dict, source: str) -> xr.Dataset:
    """Rebuild and validate an HDB sent by :func:`to_wire`; errors name ``source`` and the field."""
    if not isinstance(data, dict):
        raise HDBError(source, "", "must be a map of HDB fields")
    for key in ("bodies", "omega", "wave_direction", "attrs", *REQUIRED_VARS):
        if key not in data:
            raise HDBError(source, key, "missing field")
    attrs = data["attrs"]
    if not isinstance(attrs, dict):
        raise HDBError(source, "attrs", "must be a map")
    bodies = data["bodies"]
    if not isinstance(bodies, list) or not all(isinstance(b, str) for b in bodies):
        raise HDBError(source, "bodies", "must be a list of names")
    notes = attrs.get(WARNINGS_ATTR, [])
    if not isinstance(notes, list) or not all(isinstance(n, str) for n in notes):
        raise HDBError(source, f"attrs.{WARNINGS_ATTR}", "must be a list of str (what the HDB's reader found doubtful)")
    try:
        drift, qtf = _second_order(data, source)
        ds = make_hdb(
            bodies=bodies, omega=data["omega"], wave_direction=data["wave_direction"],
            **{k: data[k] for k in REQUIRED_VARS},
            **{k: data.get(k) for k in FIRST_ORDER_OPTIONAL}, mean_drift=drift, qtf=qtf,
            rho=attrs.get("rho", float("nan")), g=attrs.get("g", float("nan")),
            water_depth=attrs.get("water_depth", float("nan")),
            source=f"{source} (from {attrs.get('source', '?')})", modes=_modes(data, source))
    except HDBError:
        raise
    except (ValueError, TypeError) as exc:
        raise HDBError(source, "", f"fields do not fit together: {exc}") from None
    with_hdb_warnings(ds, notes)
    return ds


FILE_FORMATS = ("wamit", "bemio", "netcdf")


@dataclass(frozen=True)
class HDBFiles:
    """An HDB as its original files (SPEC §5.1 "HDB file set"): ``format`` one of FILE_FORMATS,
    the files' paths (WAMIT: the run's ``.1``, ``.3`` or ``.2``, ``.hst`` and, where present,
    ``.out``/``.cfg``; BEMIO: the ``.h5``; NetCDF: the Capytaine or hydrolink ``.nc``), ``rho``
    for WAMIT's nondimensional files. Contents are read once, on first use."""

    format: str
    paths: tuple[Path, ...]
    rho: float | None = None
    _read: dict = field(default_factory=dict, compare=False, repr=False)

    def _load(self) -> None:
        if not self._read:
            digests, contents = [], {}
            for p in self.paths:
                data = Path(p).read_bytes()
                digests.append(hashlib.sha256(data).hexdigest())
                contents[digests[-1]] = data
            self._read.update(digests=digests, contents=contents)

    def contents(self) -> dict[str, bytes]:
        """Each file's bytes by the lowercase hex SHA-256 of those bytes."""
        self._load()
        return self._read["contents"]

    def entry(self, inline: bool = False) -> dict:
        """The ``hdbs`` entry: every file by its SHA-256, or by its bytes with ``inline``."""
        self._load()
        contents = self._read["contents"]
        files = {Path(p).name: (contents[d] if inline else d) for p, d in zip(self.paths, self._read["digests"])}
        out: dict = {"format": self.format, "files": files}
        if self.rho is not None:
            out["rho"] = float(self.rho)
        return out
