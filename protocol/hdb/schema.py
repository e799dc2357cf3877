"""Assembling, validating and storing an HDB in the layout of :mod:`.layout` (the one internal
hydrodynamic database: a labelled xarray dataset, SI units, exp(-iwt)); its second-order parts are
:mod:`.second_order`'s."""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.protocol.hdb.layout import ATTR_RANGES, COMPLEX_VARS, OPTIONAL_VARS, REQUIRED_ATTRS, REQUIRED_VARS, SCHEMA_VERSION, TIME_CONVENTION, BodyDofs, HDBError, body_dofs, dof_labels, hdb_warnings
from hydrolink.protocol.hdb.second_order import QTF, MeanDrift, check_second_order, second_order_vars


def make_hdb(
    *,
    bodies: list[str],
    omega: np.ndarray,
    wave_direction: np.ndarray,
    added_mass: np.ndarray,
    radiation_damping: np.ndarray,
    excitation_force: np.ndarray,
    hydrostatic_stiffness: np.ndarray,
    reference_point: np.ndarray,
    rho: float,
    g: float,
    water_depth: float,
    source: str,
    added_mass_inf: np.ndarray | None = None,
    displaced_volume: np.ndarray | None = None,
    center_of_buoyancy: np.ndarray | None = None,
    mass: np.ndarray | None = None,
    center_of_mass: np.ndarray | None = None,
    mean_drift: MeanDrift | None = None,
    qtf: QTF | None = None,
    modes: Mapping[str, Sequence[str]] | None = None,
) -> xr.Dataset:
    """Assemble an HDB dataset in the schema's layout from plain arrays (already converted to
    SI units and the exp(-iwt) convention) and the optional second-order parts, then validate it.
    ``modes``: each body's generalized modes by name (after its six rigid DOFs; none when absent)."""
    labels = dof_labels(list(bodies), modes)
    data_vars = {
        "added_mass": (REQUIRED_VARS["added_mass"], np.asarray(added_mass, float)),
        "radiation_damping": (REQUIRED_VARS["radiation_damping"], np.asarray(radiation_damping, float)),
        "excitation_force": (REQUIRED_VARS["excitation_force"], np.asarray(excitation_force, complex)),
        "hydrostatic_stiffness": (REQUIRED_VARS["hydrostatic_stiffness"], np.asarray(hydrostatic_stiffness, float)),
        "reference_point": (REQUIRED_VARS["reference_point"], np.asarray(reference_point, float)),
    }
    for name, value in (("added_mass_inf", added_mass_inf), ("displaced_volume", displaced_volume),
                        ("center_of_buoyancy", center_of_buoyancy), ("mass", mass),
                        ("center_of_mass", center_of_mass)):
        if value is not None:
            data_vars[name] = (OPTIONAL_VARS[name], np.asarray(value, float))
    so_vars, so_coords, so_attrs = second_order_vars(mean_drift, qtf)
    ds = xr.Dataset(
        {**data_vars, **so_vars},
        coords={
            "omega": np.asarray(omega, float),
            "wave_direction": np.asarray(wave_direction, float),
            "body": list(bodies),
            "xyz": ["x", "y", "z"],
            "influenced_dof": labels,
            "radiating_dof": labels,
            **so_coords,
        },
        attrs={
            "rho": float(rho), "g": float(g), "water_depth": float(water_depth),
            "time_convention": TIME_CONVENTION, "source": str(source),
            "hdb_schema_version": SCHEMA_VERSION, **so_attrs,
        },
    )
    return validate_hdb(ds, source)


def validate_hdb(ds: xr.Dataset, source: str | Path) -> xr.Dataset:
    """Check an HDB dataset against the schema; raise HDBError naming the file and field.

    Returns the dataset with every variable transposed to the schema's dimension order."""
    for attr in REQUIRED_ATTRS:
        if attr not in ds.attrs:
            raise HDBError(source, attr, "missing attribute")
        try:
            value = float(ds.attrs[attr])
        except (TypeError, ValueError):
            raise HDBError(source, attr, f"must be a number, got {ds.attrs[attr]!r}") from None
        lo, hi = ATTR_RANGES[attr]
        if not (lo <= value <= hi or (attr == "water_depth" and value == np.inf)):
            raise HDBError(source, attr, f"must be in [{lo:g}, {hi:g}]{' or inf' if attr == 'water_depth' else ''}"
                                         f" (the scene's bounds), got {value}")
    if ds.attrs.get("time_convention", TIME_CONVENTION) != TIME_CONVENTION:
        raise HDBError(source, "time_convention",
                       f"must be {TIME_CONVENTION!r} (convert at the reader), got {ds.attrs['time_convention']!r}")
    for coord in ("omega", "body", "influenced_dof", "radiating_dof", "wave_direction"):
        if coord not in ds.coords:
            raise HDBError(source, coord, "missing coordinate")
    omega = np.asarray(ds["omega"].values, float)
    if omega.ndim != 1 or omega.size < 2:
        raise HDBError(source, "omega", f"needs at least 2 frequencies, got {omega.size}")
    if not np.all(np.isfinite(omega)) or omega[0] <= 0:
        raise HDBError(source, "omega", "must be finite and > 0 (zero/infinite frequency rows go elsewhere)")
    if np.any(np.diff(omega) <= 0):
        i = int(np.argmax(np.diff(omega) <= 0))
        raise HDBError(source, "omega", f"must be strictly increasing; omega[{i + 1}]={omega[i + 1]} "
                                        f"follows omega[{i}]={omega[i]}")
    bodies = [str(b) for b in ds["body"].values]
    expected = body_dofs(bodies, ds["influenced_dof"].values, source).labels()
    for coord in ("influenced_dof", "radiating_dof"):
        got = [str(v) for v in ds[coord].values]
        if got != expected:
            raise HDBError(source, coord, f"labels must be {expected}, got {got}")
    sizes = dict(ds.sizes)
    out = {}
    for name, dims in {**REQUIRED_VARS, **{k: v for k, v in OPTIONAL_VARS.items() if k in ds}}.items():
        if name not in ds:
            raise HDBError(source, name, "missing variable")
        var = ds[name]
        if set(var.dims) != set(dims):
            raise HDBError(source, name, f"dimensions must be {dims}, got {var.dims}")
        var = var.transpose(*dims)
        want = tuple(sizes[d] for d in dims)
        if var.shape != want:
            raise HDBError(source, name, f"shape must be {want}, got {var.shape}")
        values = np.asarray(var.values)
        if not np.all(np.isfinite(values)):
            bad = np.argwhere(~np.isfinite(values))[0]
            where = ", ".join(f"{d}={ds[d].values[i].item()!r}" if d in ds.coords else f"{d}={i}"
                              for d, i in zip(dims, bad))
            raise HDBError(source, name, f"contains NaN or inf (first at {where})")
        out[name] = var
    for name in COMPLEX_VARS:
        if name in out and not np.iscomplexobj(out[name].values):
            out[name] = out[name].astype(complex)
    check_second_order(ds, source)
    hdb_warnings(ds)   # the reader's warnings, if any: a JSON list of str
    return ds.assign(out)


def to_netcdf(ds: xr.Dataset, path: str | Path) -> None:
    """Write an HDB in hydrolink's own NetCDF form (complex variables split into _re/_im)."""
    ds = validate_hdb(ds, path)
    complex_vars = [name for name in COMPLEX_VARS if name in ds]
    out = ds.drop_vars(complex_vars).assign(
        {f"{name}_{part}": getattr(ds[name], attr) for name in complex_vars
         for part, attr in (("re", "real"), ("im", "imag"))})
    out.attrs["hydrolink_hdb"] = 1
    out.to_netcdf(path, engine="netcdf4")


def from_netcdf_dataset(raw: xr.Dataset, source: str | Path) -> xr.Dataset:
    """Inverse of :func:`to_netcdf` for an already opened dataset."""
    merged = {}
    for name in COMPLEX_VARS:
        parts = [f"{name}_re", f"{name}_im"]
        present = [p for p in parts if p in raw]
        if not present and name != "excitation_force":
            continue
        for part in parts:
            if part not in raw:
                raise HDBError(source, part, "missing variable")
        merged[name] = raw[parts[0]] + 1j * raw[parts[1]]
    ds = raw.drop_vars([f"{n}_{p}" for n in merged for p in ("re", "im")]).assign(merged)
    return validate_hdb(ds, source)


def hdb_dofs(ds: xr.Dataset) -> BodyDofs:
    """The DOFs of a (validated) HDB's bodies: each body's generalized modes after its six rigid
    DOFs, offsets and counts (layout.BodyDofs)."""
    return body_dofs(ds["body"].values, ds["influenced_dof"].values, ds.attrs.get("source", "<hdb>"))


def select_bodies(ds: xr.Dataset, bodies: list[str]) -> xr.Dataset:
    """Sub-HDB holding only ``bodies`` (their own blocks and the blocks between them)."""
    missing = [b for b in bodies if b not in list(ds["body"].values)]
    if missing:
        raise HDBError(ds.attrs.get("source", "?"), "body",
                       f"no body named {missing} (the file holds {list(map(str, ds['body'].values))})")
    dofs = hdb_dofs(ds)
    labels = dof_labels(bodies, {b: dofs.of(b) for b in bodies})
    return ds.sel(body=bodies, influenced_dof=labels, radiating_dof=labels)


def with_second_order(ds: xr.Dataset, *, mean_drift: MeanDrift | None = None, qtf: QTF | None = None,
                      source: str | Path | None = None) -> xr.Dataset:
    """``ds`` with the given parts added (each replacing the same part ``ds`` holds), validated."""
    drop: list[str] = []
    if mean_drift is not None:
        drop += [n for n in ("mean_drift", "drift_method", "drift_omega", "drift_direction") if n in ds.variables]
    if qtf is not None:
        drop += [n for n in ("difference_qtf", "sum_qtf", "qtf_omega_i", "qtf_omega_j", "qtf_direction_i",
                             "qtf_direction_j", "qtf_heading") if n in ds.variables]
    data_vars, coords, attrs = second_order_vars(mean_drift, qtf)
    out = ds.drop_vars(drop).assign_coords(coords).assign(data_vars)
    out.attrs.update(attrs)
    return validate_hdb(out, source if source is not None else ds.attrs.get("source", "<hdb>"))
