"""The HDB on the wire (SPEC §5.1 "HDB map"): an internal HDB dataset as a plain map and back.

One half of the session contract (the other is :mod:`hydrolink.protocol.setup`): a client sends
``to_wire(ds)`` for each ``hdbs`` entry of ``hello``; the server rebuilds and validates it with
``from_wire`` — the same checks as for a file (:func:`hydrolink.server.hdb.schema.validate_hdb`),
every error naming the entry and the field.
"""

from __future__ import annotations

import numpy as np
import xarray as xr

from hydrolink.server.hdb.schema import (OPTIONAL_VARS, REQUIRED_ATTRS, REQUIRED_VARS, HDBError, make_hdb,
                                         validate_hdb)


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
    return out


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
    try:
        return make_hdb(
            bodies=bodies, omega=data["omega"], wave_direction=data["wave_direction"],
            **{k: data[k] for k in REQUIRED_VARS},
            **{k: data.get(k) for k in OPTIONAL_VARS},
            rho=attrs.get("rho", float("nan")), g=attrs.get("g", float("nan")),
            water_depth=attrs.get("water_depth", float("nan")),
            source=f"{source} (from {attrs.get('source', '?')})")
    except HDBError:
        raise
    except (ValueError, TypeError) as exc:
        raise HDBError(source, "", f"fields do not fit together: {exc}") from None
