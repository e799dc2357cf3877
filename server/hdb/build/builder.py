"""``hdb build``: a hydrodynamic database computed with Capytaine from a small TOML build spec.

The spec format is documented in ``docs/hdb-spec.md`` (model: :mod:`.build_spec`, meshes:
:mod:`.build_mesh`). :func:`build_hdb` meshes the bodies (immersed part only, with lids against
irregular frequencies), solves radiation for all DOFs of the bodies together (six rigid each and
the generalized modes a body is given, modes.py; solved together so the
body-to-body blocks are in the HDB) and diffraction over the frequency grid, plus radiation at
infinite frequency (A∞), computes each body's buoyancy/waterplane hydrostatics and returns the HDB
in the schema's layout (:mod:`hydrolink.protocol.hdb.schema`). Results are cached on disk, keyed by
everything that determines them.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import sys
import time
import warnings
from importlib import metadata
from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.server.hdb.reader_warnings import HDBWarning, recorded
from hydrolink.server.disk_cache import env_dir, user_cache_dir, write_atomic
from hydrolink.server.hdb.build.modes import ModeField, mode_fields, table_path
from hydrolink.server.hdb.build.spec import BodySpec, BuildSpec, SpecError, load_spec, mesh_path, parse_spec
from hydrolink.server.hdb.capytaine_io import from_capytaine_dataset, short_body_names
from hydrolink.protocol.hdb.layout import SCHEMA_VERSION, dof_labels, with_hdb_warnings
from hydrolink.protocol.hdb.schema import from_netcdf_dataset, to_netcdf
from hydrolink.protocol.hdb.second_order import MeanDrift
from hydrolink.protocol.hdb.schema import with_second_order
from hydrolink.server.hdb.build.drift import far_field_drift
from hydrolink.server.hdb.build.panels import (PanelPressures, panel_pressure_file, panel_pressures_of,
                                               store_panel_pressures)
from hydrolink.server.hdb.build.free_surface import free_surface_file, solve_free_surface, store_free_surface

LOG = logging.getLogger(__name__)

BUILD_RECIPE_VERSION = 2  # bump when meshing/solving changes: invalidates cached HDBs
CPT_DOFS = ("Surge", "Sway", "Heave", "Roll", "Pitch", "Yaw")


# ----------------------------------------------------------------------------------------------
# Cache
# ----------------------------------------------------------------------------------------------

def default_cache_dir() -> Path:
    """``$HYDROLINK_CACHE``, else ``$XDG_CACHE_HOME/hydrolink/hdb``, else ``~/.cache/hydrolink/hdb``."""
    return env_dir("HYDROLINK_CACHE") or user_cache_dir("hdb")


def cache_key(spec: BuildSpec, spec_path: str | Path) -> str:
    """sha256 of the normalised spec, the mesh files' bytes, Capytaine's version, the schema
    version and this module's recipe version (the spec's own location does not matter).
    Capytaine's version is its installed distribution's (the ``__version__`` it states): a cache
    hit imports neither Capytaine nor the meshing (0.87 G of the 6.1 G instructions a fresh process
    took to read the cylinder example's scene and cached HDB, callgrind)."""
    normalised = spec.model_dump(mode="json")
    if spec.second_order == spec.second_order.__class__():
        normalised.pop("second_order")   # specs without second-order data keep their cached builds
    normalised.pop("panel_pressures")    # a file of its own beside the HDB (panels.py), not in the HDB
    normalised.pop("free_surface")       # stored in a file of its own (free_surface.py), not in the HDB
    digests = []
    for body, key, table in zip(spec.all_bodies, spec.body_keys,
                                [normalised["body"]] if spec.body is not None else normalised["bodies"]):
        table.pop("mesh", None)
        if table.get("modes") is None:
            table.pop("modes", None)     # rigid bodies keep their cached builds
        files = [(f"{key}.mesh", mesh_path(body, spec_path))]
        files += [(f"{key}.modes[{j}].file", table_path(m, spec_path)) for j, m in enumerate(body.modes or [])
                  if m.kind == "table"]
        for j, m in enumerate(table.get("modes") or []):
            m.pop("file", None)
        digest = None
        for file_key, path in files:
            if path is None:
                continue
            try:
                data = path.read_bytes()
            except OSError as exc:
                raise SpecError(spec_path, file_key, f"cannot read {path}: {exc.strerror}") from None
            digest = hashlib.sha256(data).hexdigest() if digest is None else \
                hashlib.sha256((digest + hashlib.sha256(data).hexdigest()).encode()).hexdigest()
        digests.append(digest)
    blob = json.dumps({"spec": normalised, "mesh_sha256": digests,
                       "capytaine": metadata.version("capytaine"), "hdb_schema_version": SCHEMA_VERSION,
                       "recipe": BUILD_RECIPE_VERSION}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def _read_cached(path: Path) -> xr.Dataset | None:
    try:
        with xr.open_dataset(path, engine="netcdf4") as raw:
            return from_netcdf_dataset(raw.load(), path)
    except Exception as exc:  # noqa: BLE001 - a damaged cache entry is rebuilt, not fatal
        warnings.warn(f"ignoring unreadable cached HDB {path}: {exc}", stacklevel=3)
        return None


# ----------------------------------------------------------------------------------------------
# Solve
# ----------------------------------------------------------------------------------------------

TABULATION_LOGGER = "capytaine.green_functions.delhommeau"


class _TabulationNote(logging.Filter):
    """Capytaine's first-run ``WARNING ... Precomputing tabulation`` (timestamped, it reads like a
    fault) replaced by one plain line of hydrolink's saying what happens."""

    def __init__(self, say):
        super().__init__()
        self.say = say

    def filter(self, record: logging.LogRecord) -> bool:
        if record.getMessage().startswith("Precomputing tabulation"):
            from capytaine.tools.cache_on_disk import cache_directory
            self.say("hdb build: Capytaine is tabulating its Green function, once on this machine (about half a "
                     f"minute on 2 cores; kept in {cache_directory()})")
            return False
        return True


def bem_solver(progress: bool):
    """Capytaine's BEM solver, its one-off Green-function tabulation said in hydrolink's words: one
    line on stderr with ``progress`` (else at INFO level), never Capytaine's warning."""
    import capytaine as cpt

    def say(line: str) -> None:
        if progress:
            print(line, file=sys.stderr, flush=True)
        else:
            LOG.info(line)
    note = _TabulationNote(say)
    logger = logging.getLogger(TABULATION_LOGGER)
    logger.addFilter(note)
    try:
        return cpt.BEMSolver()
    finally:
        logger.removeFilter(note)


def _solve(body, spec: BuildSpec, progress: bool, desc: str, motion: tuple[np.ndarray, np.ndarray] | None = None,
           ) -> tuple[xr.Dataset, MeanDrift | None, list]:
    """Radiation (every DOF of ``body``, a FloatingBody or Multibody) and diffraction over the
    grid, radiation at omega = inf; Capytaine's own dataset (exp(-iwt)) and, when the spec asks
    for it, the far-field mean drift (:mod:`.build_drift`; ``motion`` its free body's mass and
    stiffness matrices, None for the body held fixed); with ``panel_pressures`` also the results
    themselves (their panel pressures; else an empty list)."""
    import capytaine as cpt
    from tqdm import tqdm

    w = spec.water
    omegas = list(spec.frequencies.omega)
    if spec.frequencies.infinite:
        omegas = [math.inf] + omegas
    headings = np.radians(spec.waves.directions)
    dofs = list(body.dofs)
    common = dict(body=body, rho=w.density, g=w.gravity, water_depth=w.depth_m)
    solver = bem_solver(progress)
    drift_spec = spec.second_order
    keep = drift_spec.mean_drift == "far-field" or spec.panel_pressures   # the sources / the pressures
    n_total = sum(len(dofs) + (len(headings) if math.isfinite(om) else 0) for om in omegas)
    results = []
    # disable=None: tqdm leaves the bar out where stderr is not a terminal (no redraws in a log)
    with tqdm(total=n_total, desc=desc, unit="pb", disable=None if progress else True, leave=False) as bar:
        for om in omegas:  # one omega at a time: Capytaine reuses the influence matrices
            problems = [cpt.RadiationProblem(radiating_dof=d, omega=om, **common) for d in dofs]
            if math.isfinite(om):
                problems += [cpt.DiffractionProblem(wave_direction=float(b), omega=om, **common)
                             for b in headings]
            for pb in problems:
                results.append(solver.solve(pb, keep_details=keep, _check_wavelength=False))
                bar.update()
    cds = cpt.assemble_dataset(results, hydrostatics=False)
    drift = far_field_drift(results, cds, drift_spec.kochin_directions, motion) \
        if drift_spec.mean_drift == "far-field" else None
    return cds, drift, results if spec.panel_pressures else []


def _hydrostatics(hull, ref: np.ndarray, rho: float, g: float, *, mass: float = 0.0,
                  center_of_mass: np.ndarray | None = None) -> tuple[np.ndarray, float, np.ndarray]:
    """Buoyancy + waterplane stiffness about ``ref`` (no gravity terms), volume, centre of buoyancy;
    with ``mass`` and ``center_of_mass``, the full stiffness (gravity terms added).

    Capytaine's ``compute_hydrostatic_stiffness`` adds the weight terms -m g (z_G - z_ref) (and
    m g (x_G - x_ref) in roll-yaw/pitch-yaw) with m the displaced mass unless ``mass`` is given;
    setting mass = 0 leaves exactly the buoyancy/waterplane part the schema wants."""
    import capytaine as cpt

    # Gauss-Legendre 2 quadrature: the waterplane moments are exact on flat panels (the default
    # one-point rule is ~1.5 % off for a coarse cylinder's C44)
    body = cpt.FloatingBody(mesh=hull.with_quadrature("Gauss-Legendre 2"),
                            dofs=cpt.rigid_body_dofs(rotation_center=ref),
                            center_of_mass=ref if center_of_mass is None else center_of_mass, mass=mass,
                            name="hydrostatics")
    K = body.compute_hydrostatic_stiffness(rho=rho, g=g).sel(influenced_dof=list(CPT_DOFS),
                                                             radiating_dof=list(CPT_DOFS))
    return np.asarray(K.values, float), float(body.disp_volume), np.asarray(body.center_of_buoyancy, float)


def _with_mode_stiffness(rigid: np.ndarray, hull, body: BodySpec, fields: list[ModeField], rho: float,
                         g: float) -> np.ndarray:
    """The body's buoyancy/waterplane stiffness over its six rigid DOFs and its generalized modes:
    ``rigid`` (6x6) and, for every pair involving a mode, Capytaine's Newman (1994) integral
    C_ij = rho g integral over the hull of (n . V_j)(w_i + z div V_i) dS with each mode's divergence (modes.py)."""
    if not fields:
        return rigid
    import capytaine as cpt

    ref = np.asarray(body.ref_point, float)
    rigid_dofs = {name: dof.evaluate_motion(hull) for name, dof in cpt.rigid_body_dofs(rotation_center=ref).items()}
    # every DOF as a panel field: Capytaine's Newman branch takes arrays only (the rigid block is ``rigid``)
    flexible = cpt.FloatingBody(mesh=hull.with_quadrature("Gauss-Legendre 2"), center_of_mass=ref, name="modes",
                                dofs={**rigid_dofs, **{f.name: f.motion for f in fields}})
    names = [*CPT_DOFS, *(f.name for f in fields)]
    with warnings.catch_warnings():
        warnings.simplefilter("ignore")      # Capytaine notes the NaN inertia of the modes
        divergence = {**{n: np.zeros(hull.nb_faces) for n in rigid_dofs}, **{f.name: f.divergence for f in fields}}
        k = flexible.compute_hydrostatic_stiffness(divergence=divergence, rho=rho, g=g)
    out = np.asarray(k.sel(influenced_dof=names, radiating_dof=names).values, float)
    out[:6, :6] = rigid
    fields_all = [*rigid_dofs.values(), *(f.motion for f in fields)]
    for i, f in enumerate(fields, start=6):
        if f.gradient is not None:
            out[i] += rho * g * _material_term(hull, f.gradient, fields_all)
        else:
            warnings.warn(f"{body.name}: mode {f.name!r} is a displacement table (no gradient): its row of the "
                          "hydrostatic stiffness is Newman's formula alone, without the material term (a surging "
                          "body may load it); check it or give the mode as a beam mode (modes[].kind)",
                          HDBWarning, stacklevel=4)
    return out


def _material_term(hull, gradient: np.ndarray, motions: list[np.ndarray]) -> np.ndarray:
    """The term a generalized mode's row of the hydrostatic stiffness adds to Newman's: its force
    is the virtual work on material points, whose field moves with the body, so
    C_ij += rho g integral over the hull of z n . ((V_j . grad) V_i) dS (per rho g, for each j of
    ``motions``). Without it a surging box would load its antisymmetric bending modes."""
    normals = np.asarray(hull.faces_normals, float)
    z_area = np.asarray(hull.faces_centers, float)[:, 2] * np.asarray(hull.faces_areas, float)
    return np.array([np.sum(z_area * np.einsum("fi,fik,fk->f", normals, gradient, v)) for v in motions])


def _free_motion(spec: BuildSpec, hull, volume: float) -> tuple[np.ndarray, np.ndarray]:
    """The one body's mass matrix and full hydrostatic stiffness (6x6 about its reference point)
    floating freely: mass rho V, the spec's ``[second_order]`` centre of mass and inertia."""
    from hydrolink.server.rigid_body import rigid_body_mass_matrix

    so, w = spec.second_order, spec.water
    ref, cog = np.asarray(spec.all_bodies[0].ref_point, float), np.asarray(so.center_of_mass, float)
    mass = w.density * volume
    stiffness = _hydrostatics(hull, ref, w.density, w.gravity, mass=mass, center_of_mass=cog)[0]
    return rigid_body_mass_matrix(mass, np.diag(so.inertia), cog - ref), stiffness


def _with_hydrostatics(cds: xr.Dataset, labels: list[str], names: list[str], stiffness: np.ndarray,
                       volumes: list[float], cobs: list[np.ndarray], rho: float, multibody: bool) -> xr.Dataset:
    """Attach our hydrostatics (block diagonal over the bodies) to Capytaine's dataset, in its
    own names and layout (no ``center_of_mass``/``inertia_matrix``: no gravity terms to remove)."""
    k = xr.DataArray(stiffness, dims=("influenced_dof", "radiating_dof"),
                     coords={"influenced_dof": labels, "radiating_dof": labels})
    if not multibody:
        return cds.assign(hydrostatic_stiffness=k, disp_mass=rho * volumes[0],
                          center_of_buoyancy=xr.DataArray(cobs[0], dims=("space_coordinate",)))
    return cds.assign(
        hydrostatic_stiffness=k,
        disp_mass=xr.DataArray(rho * np.asarray(volumes), dims=("body",), coords={"body": names}),
        center_of_buoyancy=xr.DataArray(np.asarray(cobs), dims=("body", "space_coordinate"),
                                        coords={"body": names}),
    )


def _floating_bodies(spec: BuildSpec, spec_path: str | Path):
    """Capytaine bodies (hull + lid, six rigid DOFs about each reference point, then the body's
    generalized modes on its hull's panels: modes.py), hulls, lids, each body's modes;
    one xOz mirror-symmetric problem when every mesh allows it (multi-body/compound only)."""
    import capytaine as cpt

    from hydrolink.server.hdb.build.mesh import body_meshes, check_apart, xoz_symmetric   # scipy's: a build's only

    n = len(spec.all_bodies)
    lone = n == 1 and spec.all_bodies[0].shape != "compound"
    meshes = [body_meshes(spec, i, spec_path, lone=lone) for i in range(n)]
    check_apart([h for h, _ in meshes], spec, spec_path)
    if not lone:
        sym = [(xoz_symmetric(h), xoz_symmetric(ld) if ld is not None else None) for h, ld in meshes]
        refs_on_plane = all(abs(b.ref_point[1]) < 1e-12 for b in spec.all_bodies)
        if refs_on_plane and all(h is not None and (ld is not None or m[1] is None)
                                 for (h, ld), m in zip(sym, meshes)):
            meshes = sym
    modes = [mode_fields(b, key, hull, spec_path, spec.water.depth_m)
             for b, key, (hull, _) in zip(spec.all_bodies, spec.body_keys, meshes)]
    bodies = [cpt.FloatingBody(mesh=hull, lid_mesh=lid, name=b.name, center_of_mass=b.ref_point,
                               dofs={**cpt.rigid_body_dofs(rotation_center=np.asarray(b.ref_point, float)),
                                     **{f.name: f.motion for f in fields}})
              for b, (hull, lid), fields in zip(spec.all_bodies, meshes, modes)]
    return bodies, [h for h, _ in meshes], [ld for _, ld in meshes], modes


def build_hdb_uncached(spec: BuildSpec, spec_path: str | Path, *, progress: bool = True,
                       panels_to: Path | None = None) -> xr.Dataset:
    """Mesh, solve and convert, without looking at the cache; what the build found doubtful (a
    coarse panel, a missing lid) is kept in the HDB's ``warnings`` attribute, cached with it
    (server/hdb/reader_warnings.py). With the spec's ``panel_pressures``, the panel set is written
    to ``panels_to`` (panels.py; default beside the spec) and named by the HDB's attribute
    ``panel_pressure_file``."""
    notes: list[str] = []
    with recorded(notes):
        ds, panels = _build(spec, spec_path, progress)
    with_hdb_warnings(ds, notes)
    if panels is not None:
        path = panels_to or panel_pressure_file(Path(spec_path).with_suffix(".nc"))
        store_panel_pressures(panels, path)
        ds.attrs["panel_pressure_file"] = str(path)
    return ds


def _build(spec: BuildSpec, spec_path: str | Path, progress: bool) -> tuple[xr.Dataset, PanelPressures | None]:
    """:func:`build_hdb_uncached`'s mesh, solve and conversion (and the panel set, when asked)."""
    import capytaine as cpt

    t0 = time.perf_counter()
    bodies, hulls, lids, modes = _floating_bodies(spec, spec_path)
    names = [b.name for b in spec.all_bodies]
    mode_names = {n: tuple(f.name for f in fields) for n, fields in zip(names, modes) if fields}
    body = bodies[0] if not spec.multibody else cpt.Multibody(bodies, name="+".join(names))
    lam_min = 2 * np.pi * spec.water.gravity / float(spec.frequencies.omega.max()) ** 2
    mesh = body.mesh_including_lid
    shallow = mesh.faces_centers[:, 2] > -lam_min / 2  # deeper, the shortest wave is < 4 % (e^-pi)
    r_max = float(mesh.faces_radiuses[shallow].max()) if np.any(shallow) else 0.0
    if r_max > lam_min / 8:
        key = spec.body_keys[0] if len(bodies) == 1 else "bodies"
        warnings.warn(f"{spec_path}: {key}.panel_size: largest panel radius {r_max:.3g} m exceeds "
                      f"wavelength/8 = {lam_min / 8:.3g} m at omega_max; results near omega_max may "
                      f"be inaccurate", HDBWarning, stacklevel=3)
    symmetric = isinstance(body.mesh_including_lid, cpt.ReflectionSymmetricMesh)
    t_mesh = time.perf_counter()
    w = spec.water
    hydro = [_hydrostatics(h, np.asarray(b.ref_point, float), w.density, w.gravity)
             for h, b in zip(hulls, spec.all_bodies)]
    cds, drift, solved = _solve(body, spec, progress, desc=f"hdb build {'+'.join(names)}",
                        motion=_free_motion(spec, hulls[0], hydro[0][1]) if spec.second_order.motions == "free" else None)
    t_solve = time.perf_counter()
    blocks = [_with_mode_stiffness(k, h, b, fields, w.density, w.gravity)
              for (k, _, _), h, b, fields in zip(hydro, hulls, spec.all_bodies, modes)]
    sizes = [len(k) for k in blocks]
    stiffness = np.zeros((sum(sizes), sum(sizes)))
    for at, k in zip(np.cumsum([0] + sizes[:-1]), blocks):
        stiffness[at:at + len(k), at:at + len(k)] = k
    own = [(*CPT_DOFS, *mode_names.get(n, ())) for n in names]
    cpt_labels = list(own[0]) if not spec.multibody else [f"{n}__{d}" for n, dofs in zip(names, own) for d in dofs]
    cds = _with_hydrostatics(cds, cpt_labels, names, stiffness, [v for _, v, _ in hydro],
                             [c for _, _, c in hydro], w.density, spec.multibody)
    if not spec.multibody:
        cds = cds.assign_coords(body=names[0])
    short = short_body_names(names)
    ds = from_capytaine_dataset(cds, f"capytaine {cpt.__version__} build of {Path(spec_path).name}",
                                reference_points={s: b.ref_point for s, b in zip(short, spec.all_bodies)},
                                convention="exp(-iwt)")   # solved here by Capytaine: its convention, known
    if short != names:  # keep the spec's names (the reader shortens shared prefixes)
        labels = dof_labels(names, mode_names)
        ds = ds.assign_coords(body=names, influenced_dof=labels, radiating_dof=labels)
    if drift is not None:
        ds = with_second_order(ds, mean_drift=drift)
    panels = panel_pressures_of(solved, bodies[0], [str(v) for v in ds["radiating_dof"].values], names[0],
                                np.asarray(spec.all_bodies[0].ref_point, float), w.density, w.gravity) \
        if solved else None
    n_panels = [int(h.nb_faces) for h in hulls]
    n_lid = [int(ld.nb_faces) if ld is not None else 0 for ld in lids]
    ds.attrs.update({
        "builder": "hydrolink hdb build", "capytaine_version": cpt.__version__,
        "n_panels": sum(n_panels), "n_lid_panels": sum(n_lid),
        "panels_per_body": json.dumps({n: {"hull": p, "lid": q} for n, p, q in zip(names, n_panels, n_lid)}),
        "xoz_symmetry": int(symmetric),
        "build_seconds": round(time.perf_counter() - t0, 3),
        "mesh_seconds": round(t_mesh - t0, 3), "solve_seconds": round(t_solve - t_mesh, 3),
    })
    return ds, panels


def cache_file_name(spec: BuildSpec, key: str) -> str:
    """``<body names>-<key prefix>.nc`` (names joined by ``+``, cut to 60 characters)."""
    stem = "+".join(b.name for b in spec.all_bodies)
    return f"{stem[:60]}-{key[:24]}.nc"


def build_hdb(spec_path: str | Path, *, cache_dir: str | Path | None = None, progress: bool = True,
              force: bool = False, free_surface: bool = False) -> xr.Dataset:
    """Build (or fetch from the cache) the HDB described by the TOML spec at ``spec_path``.

    ``cache_dir`` overrides ``$HYDROLINK_CACHE`` / the XDG default; ``force`` rebuilds and
    overwrites the cache entry. The dataset's ``attrs['cache_file']`` says where it is stored.
    ``free_surface``: also the spec's ``[free_surface]`` solution (built once; its file in
    ``attrs['free_surface_file']``): what ``hdb build`` and ``view`` ask for, not a run."""
    spec_path = Path(spec_path)
    spec = load_spec(spec_path)
    key = cache_key(spec, spec_path)
    folder = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
    path = folder / cache_file_name(spec, key)
    panels = panel_pressure_file(path)
    if path.is_file() and not force and (not spec.panel_pressures or panels.is_file()):
        ds = _read_cached(path)
        if ds is not None:
            if spec.panel_pressures:
                ds.attrs["panel_pressure_file"] = str(panels)
            ds.attrs["cache_file"] = str(path)
            ds.attrs["cache_hit"] = 1
            return _with_free_surface(ds, spec, spec_path, folder, key, progress, force) if free_surface else ds
    ds = build_hdb_uncached(spec, spec_path, progress=progress, panels_to=panels)
    ds.attrs["build_spec_sha256"] = key
    try:
        write_atomic(path, lambda tmp: to_netcdf(ds, tmp))
        ds.attrs["cache_file"] = str(path)
    except OSError as exc:
        warnings.warn(f"could not write the HDB cache {path}: {exc}", stacklevel=2)
    ds.attrs["cache_hit"] = 0
    return _with_free_surface(ds, spec, spec_path, folder, key, progress, force) if free_surface else ds


def _with_free_surface(ds: xr.Dataset, spec: BuildSpec, spec_path: Path, folder: Path, key: str, progress: bool,
                       force: bool) -> xr.Dataset:
    """With ``[free_surface]``: its solution (free_surface.py) built once into the cache folder,
    named by the HDB's attribute ``free_surface_file``."""
    if spec.free_surface is None:
        return ds
    path = free_surface_file(spec, folder, key)
    if force or not path.is_file():
        bodies, _, _, _ = _floating_bodies(spec, spec_path)
        import capytaine as cpt
        body = bodies[0] if not spec.multibody else cpt.Multibody(bodies, name="+".join(b.name for b in bodies))
        store_free_surface(solve_free_surface(body, spec, bem_solver(progress), progress), path)
    ds.attrs["free_surface_file"] = str(path)
    return ds


def body_hydrostatics(spec: BuildSpec, spec_path: str | Path) -> dict[str, dict]:
    """Per body, without solving any BEM problem: displaced ``volume`` (m^3), ``mass`` = rho V,
    ``center_of_buoyancy``, the buoyancy/waterplane ``stiffness`` (about the reference point, over
    the six rigid DOFs and the body's ``modes``), from the meshes the build would solve."""
    _, hulls, _, modes = _floating_bodies(spec, spec_path)
    w, out = spec.water, {}
    for hull, b, fields in zip(hulls, spec.all_bodies, modes):
        k, vol, cob = _hydrostatics(hull, np.asarray(b.ref_point, float), w.density, w.gravity)
        out[b.name] = {"volume": vol, "mass": w.density * vol, "center_of_buoyancy": cob,
                       "stiffness": _with_mode_stiffness(k, hull, b, fields, w.density, w.gravity),
                       "modes": tuple(f.name for f in fields)}
    return out


def make_meshes(spec: BuildSpec, spec_path: str | Path):
    """Hull and lid meshes of a one-body spec (as solved; see :mod:`.build_mesh`)."""
    _, hulls, lids, _ = _floating_bodies(spec, spec_path)
    return (hulls[0], lids[0]) if len(hulls) == 1 else (hulls, lids)


__all__ = ["BuildSpec", "SpecError", "body_hydrostatics", "build_hdb", "build_hdb_uncached", "cache_key", "default_cache_dir",
           "load_spec", "make_meshes", "parse_spec"]
