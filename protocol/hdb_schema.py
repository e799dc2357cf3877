"""The internal hydrodynamic database (HDB): one labelled xarray dataset, one convention.

Every reader converts its format into this layout once; everything downstream (IRF, forces,
``hdb info``, the wire) reads only this. Layout::

    dims    omega (n_w, strictly increasing, > 0), influenced_dof (6N), radiating_dof (6N),
            wave_direction (n_b, radians), body (N), xyz (3)
    coords  omega [rad/s]; wave_direction [rad]; body (names);
            influenced_dof / radiating_dof: labels "<body>.<dof>", body-major, dof in DOF_NAMES order
    vars    added_mass            (omega, influenced_dof, radiating_dof)   kg, kg m, kg m^2
            radiation_damping     (omega, influenced_dof, radiating_dof)   N s/m, ...
            excitation_force      (omega, wave_direction, influenced_dof)  complex, per metre of wave
                                                                            amplitude, exp(-i w t)
            hydrostatic_stiffness (influenced_dof, radiating_dof)          buoyancy + waterplane only
                                                                            (no gravity terms)
            reference_point       (body, xyz)   point the rotational modes refer to, global frame
                                                at equilibrium (m)
            added_mass_inf        (influenced_dof, radiating_dof)   optional; absent -> Ogilvie
            displaced_volume      (body)        optional (m^3)
            center_of_buoyancy    (body, xyz)   optional (m)
            mass                  (body)        optional (kg): the body mass the file records
            center_of_mass        (body, xyz)   optional (m): the centre of gravity the file records
            mean_drift, difference_qtf, sum_qtf   optional second-order data: layout and
                                                  conventions in :mod:`.hdb_second_order`
    attrs   rho, g, water_depth (float, inf for deep water), time_convention = "exp(-iwt)",
            source (where it came from), hdb_schema_version = 2 (2: mean_drift_body_fixed required
            with mean_drift; hdb build's cache keys change with it)

Time convention: a regular wave with elevation eta(t) = Re{a exp(-i w t)} at the origin gives the
excitation force Re{a X(w) exp(-i w t)} (Capytaine's convention). Readers of exp(+i w t) formats
(WAMIT, BEMIO/WEC-Sim) take the complex conjugate.

Row index = force component (influenced), column = motion (radiating): F = -A a - B v.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

import numpy as np
import xarray as xr

from hydrolink.protocol.errors import KeyedError
from hydrolink.protocol.scene_bounds import DENSITY_RANGE, DEPTH_RANGE, GRAVITY_RANGE

DOF_NAMES: tuple[str, ...] = ("surge", "sway", "heave", "roll", "pitch", "yaw")
TIME_CONVENTION = "exp(-iwt)"
SCHEMA_VERSION = 2

REQUIRED_VARS = {
    "added_mass": ("omega", "influenced_dof", "radiating_dof"),
    "radiation_damping": ("omega", "influenced_dof", "radiating_dof"),
    "excitation_force": ("omega", "wave_direction", "influenced_dof"),
    "hydrostatic_stiffness": ("influenced_dof", "radiating_dof"),
    "reference_point": ("body", "xyz"),
}
DRIFT_METHODS: tuple[str, ...] = ("momentum", "control-surface", "pressure", "far-field")
QTF_KINDS: tuple[str, ...] = ("difference", "sum")
MEAN_DRIFT_DIMS = ("drift_method", "drift_omega", "drift_direction", "influenced_dof")
QTF_DIMS = ("qtf_omega_i", "qtf_omega_j", "qtf_heading", "influenced_dof")
SECOND_ORDER_VARS = {"mean_drift": MEAN_DRIFT_DIMS, "difference_qtf": QTF_DIMS, "sum_qtf": QTF_DIMS}
OPTIONAL_VARS = {
    "added_mass_inf": ("influenced_dof", "radiating_dof"),
    "displaced_volume": ("body",),
    "center_of_buoyancy": ("body", "xyz"),
    "mass": ("body",),
    "center_of_mass": ("body", "xyz"),
    **SECOND_ORDER_VARS,
}
COMPLEX_VARS = ("excitation_force", "difference_qtf", "sum_qtf")   # split into _re/_im in NetCDF
REQUIRED_ATTRS = ("rho", "g", "water_depth")
ATTR_RANGES = {"rho": DENSITY_RANGE, "g": GRAVITY_RANGE, "water_depth": DEPTH_RANGE}


class HDBError(KeyedError):
    """A hydrodynamic database that cannot be used; the message names the file and the field."""

    @property
    def field(self) -> str:
        """The file's field (variable, column, line) at fault: the error's key."""
        return self.key


def dof_labels(bodies: list[str]) -> list[str]:
    """Mode labels "<body>.<dof>" in the schema's order (body-major)."""
    return [f"{b}.{d}" for b in bodies for d in DOF_NAMES]


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
    mean_drift: "MeanDrift | None" = None,
    qtf: "QTF | None" = None,
) -> xr.Dataset:
    """Assemble an HDB dataset in the schema's layout from plain arrays (already converted to
    SI units and the exp(-iwt) convention) and the optional second-order parts, then validate it."""
    from hydrolink.protocol.hdb_second_order import second_order_vars

    labels = dof_labels(list(bodies))
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
    expected = dof_labels(bodies)
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
    from hydrolink.protocol.hdb_second_order import check_second_order
    check_second_order(ds, source)
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


def select_bodies(ds: xr.Dataset, bodies: list[str]) -> xr.Dataset:
    """Sub-HDB holding only ``bodies`` (their own blocks and the blocks between them)."""
    missing = [b for b in bodies if b not in list(ds["body"].values)]
    if missing:
        raise HDBError(ds.attrs.get("source", "?"), "body",
                       f"no body named {missing} (the file holds {list(map(str, ds['body'].values))})")
    labels = dof_labels(bodies)
    return ds.sel(body=bodies, influenced_dof=labels, radiating_dof=labels)


if TYPE_CHECKING:
    from hydrolink.protocol.hdb_second_order import QTF, MeanDrift


