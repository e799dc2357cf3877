"""Capytaine datasets (in memory, or saved by ``capytaine.export_dataset(..., format="netcdf")``).

Capytaine uses exp(-i w t) and SI units: nothing is rescaled. Conversions:

* Frequencies: the ``omega`` coordinate (made the dimension if Capytaine used period/freq/...);
  omega = inf rows become ``added_mass_inf``, omega = 0 rows are dropped.
* DOFs: labels ``<body>__<Dof>`` (multibody) or ``<Dof>`` (single body, named by ``body_name``);
  radiating DOFs beyond the rigid ones are the body's generalized modes, by the file's names, after its six;
  rigid-body DOF names Surge..Yaw in any case. DOFs that were not solved are zero.
* Body names (one rule): the prefix shared by all bodies' names up to and including its last
  ``_`` is removed when there are several bodies and the rest stays unique and non-empty:
  ``rm3_float``, ``rm3_spar`` -> ``float``, ``spar``. Dots become ``_`` (labels are body.dof).
  The names as in the file are kept in the attribute ``body_names_in_file``.
* Reference point of each body's rotations, first found of: the caller's ``reference_points``,
  Capytaine's ``rotation_center`` coordinate, the ``center_of_mass`` coordinate (Capytaine puts
  rotation DOFs there when no centre is given), else the origin with a warning (Capytaine's
  ``rigid_body_dofs()`` default). The attribute ``reference_point_from`` says which.
* Headings: the ``wave_direction`` coordinate's ``units`` attribute says radians (Capytaine's
  "rad", or none) or degrees (converted); a value the unit cannot hold (more than 2 pi radians or
  360 degrees) is an error.
* Time convention of the complex amplitudes (Capytaine: exp(-i w t); WecOptTool 3.3's ``run_bem``
  conjugates the Froude-Krylov, diffraction and excitation forces to exp(+i w t) and marks nothing):
  the one the file declares (an attribute whose name holds "convention", e.g.
  ``time_convention = "exp(+iwt)"``) or the caller states (``convention``: a scene's
  ``bodies[i].hdb_convention``); else the forces' phases decide (time_convention.py: long-wave
  limits of the Froude-Krylov and diffraction forces): exp(-iwt) is read, exp(+iwt) is an error
  asking for ``hdb_convention``. When the phases cannot tell, a file that shows it went through
  another tool (WecOptTool's ``friction`` variable or ``<body>_immersed`` names) is an error too, and
  any other is read as exp(-iwt) with a warning. exp(+i w t) amplitudes are conjugated here, once;
  the attributes ``time_convention_in_file`` and ``time_convention_from`` say what was read and why.
* Hydrostatics: Capytaine's ``hydrostatic_stiffness`` includes the gravity terms -m g (z_G - z_c)
  (roll/pitch) and m g (x_G - x_c), m g (y_G - y_c) (roll-yaw/pitch-yaw); they are removed here
  (schema: buoyancy and waterplane only) when ``center_of_mass`` is recorded. Without it the
  centre of mass is taken to be the rotation centre, where those terms vanish.
"""

from __future__ import annotations

import math
import os
import warnings
from collections.abc import Mapping, Sequence
from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.server.hdb.reader_warnings import HDBWarning
from hydrolink.protocol.hdb.layout import DOF_NAMES, MODE_NAME, BodyDofs, HDBError
from hydrolink.protocol.hdb.schema import make_hdb

from hydrolink.server.hdb.time_convention import ConventionEvidence, evidence

_FREQ_DIMS = ("omega", "period", "freq", "wavenumber", "wavelength")


def merge_complex(ds: xr.Dataset) -> xr.Dataset:
    """Undo Capytaine's NetCDF split of complex variables along a ``complex`` = [re, im] dim."""
    if "complex" not in ds.dims:
        return ds
    merged = {name: ds[name].sel(complex="re", drop=True) + 1j * ds[name].sel(complex="im", drop=True)
              for name in ds.data_vars if "complex" in ds[name].dims}
    return ds.drop_vars([*merged, "complex"]).assign(merged)


def read_capytaine(path: str | Path, *,
                   reference_points: Mapping[str, Sequence[float]] | None = None) -> xr.Dataset:
    """Read a Capytaine NetCDF export into the internal HDB layout."""
    path = Path(path)
    if not path.is_file():
        raise HDBError(path, "file", "not found")
    try:
        with xr.open_dataset(path, engine="netcdf4") as raw:
            ds = raw.load()
    except (OSError, ValueError) as exc:
        raise HDBError(path, "file", f"not a readable NetCDF file ({exc})") from None
    return from_capytaine_dataset(ds, path, reference_points=reference_points)


def _scalar(ds: xr.Dataset, name: str, source: str, default: float | None = None) -> float:
    """A parameter Capytaine stores as a scalar coordinate (or a length-1 dimension)."""
    if name not in ds.variables:
        if default is None:
            raise HDBError(source, name, "missing (expected a scalar coordinate)")
        return default
    values = np.asarray(ds[name].values, float).ravel()
    if values.size != 1:
        raise HDBError(source, name, f"the dataset holds {values.size} values; select one before converting")
    return float(values[0])


def _frequency_axis(ds: xr.Dataset, source: str) -> xr.Dataset:
    """Make ``omega`` the frequency dimension."""
    if "omega" in ds.dims:
        return ds
    dim = next((d for d in _FREQ_DIMS if d in ds.dims), None)
    if dim is None or "omega" not in ds.coords:
        raise HDBError(source, "omega", "no frequency dimension with an 'omega' coordinate")
    return ds.swap_dims({dim: "omega"})


_DEGREES = ("deg", "degree", "degrees", "°")
_RADIANS = ("rad", "radian", "radians")


def _headings_in_radians(ds: xr.Dataset, source: str) -> xr.Dataset:
    """The ``wave_direction`` coordinate in radians, its unit read from its ``units`` attribute
    (Capytaine writes "rad"; none: radians, Capytaine's). Refused: an unknown unit, and values
    that cannot be the stated unit's (|beta| > 2 pi in radians, > 360 in degrees)."""
    if "wave_direction" not in ds.variables:
        return ds
    da = ds["wave_direction"]
    stated = str(da.attrs.get("units", "")).strip()
    unit = stated.lower()
    values = np.asarray(da.values, float)
    largest = float(np.abs(values).max()) if values.size else 0.0
    if unit in _DEGREES:
        if largest > 360.0 + 1e-9:
            raise HDBError(source, "wave_direction", f"{largest:g} is more than 360 degrees (units = {stated!r})")
        return ds.assign_coords(wave_direction=xr.DataArray(np.deg2rad(values), dims=da.dims,
                                                            attrs={**da.attrs, "units": "rad"}))
    if unit not in ("", *_RADIANS):
        raise HDBError(source, "wave_direction.units", f"{stated!r} is neither radians ({', '.join(_RADIANS)}) "
                                                       f"nor degrees ({', '.join(_DEGREES)})")
    if largest > 2 * math.pi + 1e-9:
        said = f"units = {stated!r}" if stated else "no units attribute: radians, Capytaine's"
        raise HDBError(source, "wave_direction", f"{largest:g} is more than 2 pi in a field in radians ({said}): "
                                                 "headings in degrees? set the coordinate's units to \"degrees\"")
    return ds


def _parse_dofs(labels: Sequence[str], single_body: str, source: str, field: str,
                modes: Mapping[str, Sequence[str]] | None = None) -> list[tuple[str, int]]:
    """(body name as in file, dof index) per label: 0-5 the rigid DOFs (Surge..Yaw, any case),
    6 + k the body's k-th generalized mode in ``modes`` (from :func:`_file_modes`)."""
    out = []
    for label in map(str, labels):
        body, _, dof = label.rpartition("__")
        body = body or single_body
        if dof.lower() in DOF_NAMES:
            out.append((body, DOF_NAMES.index(dof.lower())))
            continue
        own = (modes or {}).get(body, ())
        if dof not in own:
            raise HDBError(source, field, f"DOF {label!r} is neither a rigid-body DOF ({', '.join(DOF_NAMES)}) nor a "
                                          f"generalized mode of the radiating DOFs ({list(own)})")
        out.append((body, len(DOF_NAMES) + own.index(dof)))
    return out


def _file_modes(labels: Sequence[str], single_body: str, source: str) -> dict[str, tuple[str, ...]]:
    """Each body's generalized modes (issue 38): its radiating DOFs beyond the six rigid ones, by
    the file's names in the file's order; a name hydrolink cannot label is an error."""
    modes: dict[str, list[str]] = {}
    for label in map(str, labels):
        body, _, dof = label.rpartition("__")
        if dof.lower() in DOF_NAMES:
            continue
        if not MODE_NAME.match(dof) or dof in modes.get(body or single_body, []):
            raise HDBError(source, "radiating_dof", f"mode {label!r}: a generalized mode's name must be unique and "
                                                    "of letters, digits, _ or - (it becomes the label <body>.<mode>)")
        modes.setdefault(body or single_body, []).append(dof)
    return {b: tuple(m) for b, m in modes.items()}


def short_body_names(names: Sequence[str]) -> list[str]:
    """The body naming rule (see the module docstring)."""
    names = [n.replace(".", "_") for n in names]
    if len(names) < 2:
        return names
    prefix = os.path.commonprefix(names)
    cut = prefix.rfind("_") + 1
    short = [n[cut:] for n in names]
    if cut and all(short) and len(set(short)) == len(short):
        return short
    return names


def _per_body(ds: xr.Dataset, name: str, file_bodies: list[str], source: str) -> np.ndarray | None:
    """A (body, space_coordinate) or single-body (space_coordinate) variable as (N, 3)."""
    if name not in ds.variables:
        return None
    da = ds[name]
    if "body" not in da.dims:
        if len(file_bodies) != 1:
            return np.tile(np.asarray(da.values, float).ravel()[:3], (len(file_bodies), 1))
        return np.asarray(da.values, float).reshape(1, 3)
    labels = [str(b) for b in da["body"].values] if "body" in da.coords else file_bodies
    missing = [b for b in file_bodies if b not in labels]
    if missing:
        raise HDBError(source, name, f"no entry for bodies {missing}")
    da = da.assign_coords(body=labels).sel(body=file_bodies)
    other = [d for d in da.dims if d != "body"]
    return np.asarray(da.transpose("body", *other).values, float).reshape(len(file_bodies), 3)


def _reference_points(ds, file_bodies, names, given, source) -> tuple[np.ndarray, str]:
    if given is not None:
        missing = [n for n in names if n not in given]
        if missing:
            raise HDBError(source, "reference_points", f"no point given for bodies {missing}")
        return np.asarray([given[n] for n in names], float).reshape(len(names), 3), "caller"
    for coord in ("rotation_center", "center_of_mass"):
        points = _per_body(ds, coord, file_bodies, source)
        if points is not None and np.all(np.isfinite(points)):
            return points, coord
    warnings.warn(f"{source}: no rotation_center or center_of_mass recorded; rotational modes are taken "
                  "about the origin; if the run used another centre, record it in the file (Capytaine's FloatingBody "
                  "rotation_center or center_of_mass)", HDBWarning, stacklevel=3)
    return np.zeros((len(names), 3)), "origin (assumed, not recorded)"


def _remove_gravity(k: np.ndarray, ds: xr.Dataset, dofs: BodyDofs, ref: np.ndarray, g: float, source) -> np.ndarray:
    """Subtract Capytaine's gravity terms from its hydrostatic stiffness (see module docstring;
    the rigid DOFs' only: Capytaine has none for generalized modes)."""
    file_bodies = list(dofs.bodies)
    cog = _per_body(ds, "center_of_mass", file_bodies, source)
    if cog is None or "inertia_matrix" not in ds:
        return k
    k = k.copy()
    mass = _mass_per_body(ds, dofs, source)
    for o, m, c, r in zip(dofs.offsets, mass, cog, ref):
        k[o + 3, o + 3] += m * g * (c[2] - r[2])
        k[o + 4, o + 4] += m * g * (c[2] - r[2])
        k[o + 3, o + 5] -= m * g * (c[0] - r[0])
        k[o + 4, o + 5] -= m * g * (c[1] - r[1])
    return k


def _mass_per_body(ds: xr.Dataset, layout: BodyDofs, source: str) -> np.ndarray:
    file_bodies = list(layout.bodies)
    inertia = ds["inertia_matrix"]
    labels = [str(v) for v in inertia["influenced_dof"].values]
    dofs = _parse_dofs(labels, file_bodies[0], source, "inertia_matrix", layout.mode_map())
    diag = np.diag(np.asarray(inertia.transpose("influenced_dof", "radiating_dof").values, float))
    mass = np.zeros(len(file_bodies))
    for (body, dof), value in zip(dofs, diag):
        if dof < 3:
            mass[file_bodies.index(body)] = value
    return mass


def _scatter(target: np.ndarray, values: np.ndarray, rows: np.ndarray | None, cols: np.ndarray | None) -> None:
    """target[..., rows, cols] = values on the trailing axes (None = axis not indexed)."""
    index = [slice(None)] * (target.ndim - (rows is not None) - (cols is not None))
    if rows is not None and cols is not None:
        target[(*index, rows[:, None], cols[None, :])] = values
    else:
        target[(*index, rows if rows is not None else cols)] = values


CONVENTIONS = ("exp(-iwt)", "exp(+iwt)")
# a variable or body name another tool leaves in a Capytaine dataset (it went through that tool,
# whose time convention may differ): WecOptTool's add_linear_friction adds "friction", its run_bem
# names the solved body "<name>_immersed"
_OTHER_TOOLS = {"friction": "WecOptTool's add_linear_friction"}
_OTHER_TOOL_BODY_SUFFIX = {"_immersed": "WecOptTool's run_bem"}


def declared_convention(ds: xr.Dataset, source: str) -> str | None:
    """The time convention a file's attributes declare ("exp(-iwt)" / "exp(+iwt)"), else None."""
    for name, value in ds.attrs.items():
        if "convention" not in name.lower():
            continue
        text = str(value).replace(" ", "").replace("ω", "w").lower()
        if "+iwt" in text or "+i*w*t" in text:
            return "exp(+iwt)"
        if "-iwt" in text or "-i*w*t" in text or "−iwt" in text:
            return "exp(-iwt)"
        raise HDBError(source, f"attrs.{name}", f"{value!r} names no time convention (exp(-iwt) or exp(+iwt))")
    return None


def _other_tool(ds: xr.Dataset, file_bodies: list[str]) -> str | None:
    """The other tool a file shows it went through, else None."""
    marks = [f"variable {v!r} ({tool})" for v, tool in _OTHER_TOOLS.items() if v in ds.variables]
    marks += [f"body name {b!r} ({tool})" for b in file_bodies for suffix, tool in _OTHER_TOOL_BODY_SUFFIX.items()
              if b.endswith(suffix)]
    return ", ".join(marks) or None


def _convention(ds: xr.Dataset, source: str, stated: str | None, file_bodies: list[str],
                physics: ConventionEvidence | None) -> tuple[str, str]:
    """The convention to read the file's complex amplitudes in, and why (module docstring).
    ``physics``: what the excitation's phases say (time_convention.py), None without the
    Froude-Krylov force."""
    declared = declared_convention(ds, source)
    if stated is not None and stated not in CONVENTIONS:
        raise HDBError(source, "convention", f"{stated!r}: one of {list(CONVENTIONS)}")
    if declared and stated and declared != stated:
        raise HDBError(source, "convention", f"the file declares {declared}, the scene states {stated}")
    checked = physics.detail if physics is not None else "no Froude_Krylov_force to check the phases on"
    if declared or stated:
        chosen = declared or stated
        why = "declared by the file's attributes" if declared else "stated (hdb_convention)"
        if physics is not None and physics.verdict not in (None, chosen):
            warnings.warn(f"{source}: read as {chosen} ({why}), but {checked}: check hdb_convention", HDBWarning,
                          stacklevel=4)
        return chosen, f"{why}; {checked}"
    ask = f'state the body\'s hdb_convention ("exp(-iwt)" for Capytaine, "exp(+iwt)" for WecOptTool)'
    if physics is not None and physics.verdict == "exp(+iwt)":
        raise HDBError(source, "hdb_convention", f"the file does not declare its time convention and its force "
                       f"phases are exp(+iwt)'s, not Capytaine's exp(-iwt) ({checked}): {ask}")
    if physics is not None and physics.verdict == "exp(-iwt)":
        return "exp(-iwt)", f"Capytaine's, checked: {checked}"
    tool = _other_tool(ds, file_bodies)
    if tool:
        raise HDBError(source, "hdb_convention", f"the file does not declare its time convention, holds {tool} "
                       f"whose convention may not be Capytaine's, and {checked}: {ask}")
    warnings.warn(f"{source}: read in Capytaine's exp(-iwt), not declared and not checked ({checked}); "
                  f"{ask} to be sure", HDBWarning, stacklevel=4)
    return "exp(-iwt)", f"Capytaine's, assumed: not declared and {checked}"


def _excitation_evidence(physics: ConventionEvidence, fk_plus_d: np.ndarray, excitation: np.ndarray,
                         source: str) -> ConventionEvidence:
    """The phases' verdict, judged on the Froude-Krylov and diffraction forces, carried to the
    excitation force: the same when it is their sum, the other when it is its conjugate (a file
    whose parts were conjugated and not the excitation: noted)."""
    scale = float(np.abs(excitation).max()) or 1.0
    if np.abs(excitation - fk_plus_d).max() <= 1e-6 * scale:
        return physics
    if np.abs(excitation - np.conj(fk_plus_d)).max() <= 1e-6 * scale:
        other = CONVENTIONS[1 - CONVENTIONS.index(physics.verdict)]
        warnings.warn(f"{source}: its Froude_Krylov_force + diffraction_force are the complex conjugates of its "
                      f"excitation_force: their phases are {physics.verdict}'s, so excitation_force is read as "
                      f"{other}; state the body's hdb_convention if it is not", HDBWarning, stacklevel=4)
        return ConventionEvidence(other, f"{physics.detail}, on Froude_Krylov_force + diffraction_force, the "
                                         "conjugates of excitation_force")
    return ConventionEvidence(None, f"{physics.detail}, but excitation_force is not Froude_Krylov_force + "
                                    "diffraction_force: not carried to it")


def _radiation_matrix(ds: xr.Dataset, name: str) -> np.ndarray:
    """A radiation coefficient as stored, (omega, influenced_dof, radiating_dof)."""
    da = ds[name]
    if "wave_direction" in da.dims:  # Capytaine may repeat radiation data per heading
        da = da.isel(wave_direction=0, drop=True)
    return np.asarray(da.transpose("omega", "influenced_dof", "radiating_dof").values)


def _hydrostatic_stiffness(ds: xr.Dataset, dofs: BodyDofs, single: str, source: str) -> np.ndarray:
    """The file's hydrostatic stiffness on all DOFs of its bodies (gravity terms still in)."""
    k = ds["hydrostatic_stiffness"]
    idx = [np.array([dofs.index(b, d) for b, d in _parse_dofs(
        [str(v) for v in k[dim].values], single, source, "hydrostatic_stiffness", dofs.mode_map())])
        for dim in ("influenced_dof", "radiating_dof")]
    stiffness = np.zeros((dofs.size, dofs.size))
    _scatter(stiffness, np.asarray(k.transpose("influenced_dof", "radiating_dof").values, float), *idx)
    return stiffness


def _recorded_mass(ds: xr.Dataset, dofs: BodyDofs, source: str) -> tuple[np.ndarray | None, np.ndarray | None]:
    """The body mass and centre of gravity the file records (Capytaine's inertia_matrix and
    center_of_mass), None where it records none: kept so that a scene that disagrees can be told
    (server/model.py)."""
    mass = _mass_per_body(ds, dofs, source) if "inertia_matrix" in ds else None
    if mass is not None and not np.all(mass > 0):
        mass = None                     # no translational DOF in the inertia matrix: not recorded
    cog = _per_body(ds, "center_of_mass", list(dofs.bodies), source)
    if cog is not None and not np.all(np.isfinite(cog)):
        cog = None
    return mass, cog


def from_capytaine_dataset(ds: xr.Dataset, source: str | Path, *,
                           reference_points: Mapping[str, Sequence[float]] | None = None,
                           convention: str | None = None) -> xr.Dataset:
    """Convert a Capytaine result dataset (in memory or re-opened NetCDF) to the internal HDB;
    ``convention``: the time convention of its complex amplitudes when the file does not say."""
    source = str(source)
    ds = _headings_in_radians(_frequency_axis(merge_complex(ds), source), source)
    for name in ("added_mass", "radiation_damping", "excitation_force", "hydrostatic_stiffness"):
        if name not in ds:
            hint = " (solve the diffraction problems too)" if name == "excitation_force" else (
                " (assemble with hydrostatics=True and a center_of_mass)" if name == "hydrostatic_stiffness" else "")
            raise HDBError(source, name, f"missing variable{hint}")
    if not math.isclose(_scalar(ds, "forward_speed", source, 0.0), 0.0):
        raise HDBError(source, "forward_speed", "only zero forward speed is supported")
    rho, g = _scalar(ds, "rho", source), _scalar(ds, "g", source)
    depth = _scalar(ds, "water_depth", source, math.inf)

    single = next((str(ds[n].values) for n in ("body_name", "body") if n in ds.variables and ds[n].ndim == 0),
                  "body1")
    inf_labels = [str(v) for v in ds["influenced_dof"].values]
    rad_labels = [str(v) for v in ds["radiating_dof"].values]
    modes = _file_modes(rad_labels, single, source)
    inf_dofs = _parse_dofs(inf_labels, single, source, "influenced_dof", modes)
    rad_dofs = _parse_dofs(rad_labels, single, source, "radiating_dof", modes)
    file_bodies = list(dict.fromkeys(b for b, _ in inf_dofs + rad_dofs))
    names = short_body_names(file_bodies)
    dofs = BodyDofs(tuple(file_bodies), tuple(modes.get(b, ()) for b in file_bodies))
    n_dof = dofs.size
    inf_idx = np.array([dofs.index(b, d) for b, d in inf_dofs])
    rad_idx = np.array([dofs.index(b, d) for b, d in rad_dofs])

    omega_all = np.asarray(ds["omega"].values, float)
    regular = np.isfinite(omega_all) & (omega_all > 0)
    at_inf = np.isinf(omega_all)
    order = np.argsort(omega_all[regular], kind="stable")
    omega = omega_all[regular][order]
    a_raw, b_raw = _radiation_matrix(ds, "added_mass").real, _radiation_matrix(ds, "radiation_damping").real
    added_mass = np.zeros((omega.size, n_dof, n_dof))
    damping = np.zeros_like(added_mass)
    _scatter(added_mass, a_raw[regular][order], inf_idx, rad_idx)
    _scatter(damping, b_raw[regular][order], inf_idx, rad_idx)
    a_inf = None
    if np.any(at_inf):
        a_inf = np.zeros((n_dof, n_dof))
        _scatter(a_inf, a_raw[np.argmax(at_inf)], inf_idx, rad_idx)

    def forces(name: str) -> np.ndarray:
        """A wave force as stored, (omega, wave_direction, n_dof) on the sorted regular frequencies."""
        da = ds[name]
        if "wave_direction" not in da.dims:
            da = da.expand_dims(wave_direction=np.atleast_1d(ds["wave_direction"].values)
                                if "wave_direction" in ds.variables else [0.0])
        da = da.sortby("wave_direction")
        out = np.zeros((omega.size, da.sizes["wave_direction"], n_dof), complex)
        _scatter(out, np.asarray(da.transpose("omega", "wave_direction", "influenced_dof").values)[regular][order],
                 None, np.array([dofs.index(b, d) for b, d in _parse_dofs(
                     [str(v) for v in da["influenced_dof"].values], single, source, name, modes)]))
        return out

    excitation = forces("excitation_force")
    directions = np.sort(np.atleast_1d(ds["wave_direction"].values).astype(float)) \
        if "wave_direction" in ds.variables else np.zeros(1)

    ref, ref_from = _reference_points(ds, file_bodies, names, reference_points, source)
    stiffness = _remove_gravity(_hydrostatic_stiffness(ds, dofs, single, source), ds, dofs, ref, g, source)

    cb = _per_body(ds, "center_of_buoyancy", file_bodies, source)
    volume = np.asarray(ds["disp_mass"].values, float).ravel() / rho if "disp_mass" in ds.variables else None
    if volume is not None and volume.size != len(names):
        volume = None

    physics = None
    if "Froude_Krylov_force" in ds:     # the forces' phases against the long-wave limits
        froude_krylov = forces("Froude_Krylov_force")
        diffraction = forces("diffraction_force") if "diffraction_force" in ds else None
        physics = evidence(omega=omega, wave_direction=directions, bodies=names, offsets=list(dofs.offsets), rho=rho,
                           g=g, depth=depth, added_mass=added_mass, radiation_damping=damping, stiffness=stiffness,
                           volume=volume, froude_krylov=froude_krylov, diffraction=diffraction)
        if diffraction is not None and physics.verdict is not None:
            physics = _excitation_evidence(physics, froude_krylov + diffraction, excitation, source)
    time_convention, convention_from = _convention(ds, source, convention, file_bodies, physics)
    if time_convention == "exp(+iwt)":      # converted once, here (schema: exp(-iwt))
        excitation = np.conj(excitation)

    mass, cog = _recorded_mass(ds, dofs, source)
    out = make_hdb(
        bodies=names, omega=omega, wave_direction=directions,
        added_mass=added_mass, radiation_damping=damping, excitation_force=excitation,
        hydrostatic_stiffness=stiffness, reference_point=ref, rho=rho, g=g, water_depth=depth,
        source=source, added_mass_inf=a_inf, displaced_volume=volume, center_of_buoyancy=cb,
        mass=mass, center_of_mass=cog, modes={n: m for n, m in zip(names, dofs.modes) if m},
    )
    out.attrs["body_names_in_file"] = ",".join(file_bodies)
    out.attrs["time_convention_in_file"] = time_convention
    out.attrs["time_convention_from"] = convention_from
    out.attrs["reference_point_from"] = ref_from
    return out
