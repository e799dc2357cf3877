"""``[free_surface]`` of a build spec: Capytaine's free-surface elevation of each radiation and
diffraction problem on a horizontal grid, for ``hydrolink view``'s radiated and diffracted waves.

Stored beside the cached HDB in a NetCDF file of its own (the HDB the server loads stays as it
was), keyed by the HDB's cache key and the ``[free_surface]`` table, built once. Layout, complex
amplitudes in Capytaine's exp(-i w t) convention:

    coords  omega (rad/s), wave_direction (rad), body, dof (surge..yaw), y, x (m)
    vars    radiated_re/_im (omega, body, dof, y, x): elevation per unit motion amplitude of the
            DOF (m per m or per rad, about the body's reference point, attrs ``reference_points``)
            diffracted_re/_im (omega, wave_direction, y, x): the diffracted (scattered) wave per
            unit incident amplitude at the origin (the incident wave not included)

Inside a body's waterline the values are Capytaine's potential there, not a free surface."""

from __future__ import annotations

import hashlib
import json
from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.server.allocation import require_size
from hydrolink.server.disk_cache import write_atomic
from hydrolink.server.hdb.build.spec import BuildSpec

DOFS = ("surge", "sway", "heave", "roll", "pitch", "yaw")
CPT_DOFS = ("Surge", "Sway", "Heave", "Roll", "Pitch", "Yaw")


def free_surface_file(spec: BuildSpec, folder: Path, hdb_key: str) -> Path:
    """Where the free-surface solution of a spec lives in the cache folder."""
    blob = json.dumps({"hdb": hdb_key, "free_surface": spec.free_surface.model_dump(mode="json")}, sort_keys=True)
    key = hashlib.sha256(blob.encode()).hexdigest()
    stem = "+".join(b.name for b in spec.all_bodies)[:60]
    return folder / f"{stem}-{key[:24]}.free_surface.nc"


def solve_free_surface(body, spec: BuildSpec, solver, progress: bool = True) -> xr.Dataset:
    """Radiation of every DOF and diffraction per heading of ``body`` (a Capytaine FloatingBody or
    Multibody, DOFs about the reference points) at each ``[free_surface] omega``, and their
    elevation on the grid."""
    import capytaine as cpt
    from tqdm import tqdm

    fs, w = spec.free_surface, spec.water
    names = [b.name for b in spec.all_bodies]
    xx, yy = np.meshgrid(fs.x, fs.y)
    points = np.column_stack([xx.ravel(), yy.ravel()])
    headings = np.radians(spec.waves.directions)
    require_size("free_surface.cells", "the free-surface solution (frequencies x problems x grid points)",
                 (len(fs.omega), 6 * len(names) + len(headings), points.shape[0]), itemsize=16,
                 hint="fewer cells or frequencies")
    rad = np.zeros((len(fs.omega), len(names), 6, points.shape[0]), complex)
    dif = np.zeros((len(fs.omega), len(headings), points.shape[0]), complex)
    common = dict(body=body, rho=w.density, g=w.gravity, water_depth=w.depth_m)
    label = (lambda b, d: CPT_DOFS[d]) if len(names) == 1 else (lambda b, d: f"{names[b]}__{CPT_DOFS[d]}")
    with tqdm(total=rad[:, :, :, 0].size + dif[:, :, 0].size, desc="hdb build: free surface", unit="pb",
              disable=None if progress else True, leave=False) as bar:
        for i, om in enumerate(fs.omega):
            results = []
            for b in range(len(names)):
                for d in range(6):
                    results.append(solver.solve(cpt.RadiationProblem(radiating_dof=label(b, d), omega=om, **common),
                                                keep_details=True, _check_wavelength=False))
                    bar.update()
            for beta in headings:
                results.append(solver.solve(cpt.DiffractionProblem(wave_direction=float(beta), omega=om, **common),
                                            keep_details=True, _check_wavelength=False))
                bar.update()
            eta = elevations(solver, points, results)
            rad[i] = eta[:6 * len(names)].reshape(len(names), 6, -1)
            dif[i] = eta[6 * len(names):]
    shape = (len(fs.y), len(fs.x))
    coords = {"omega": np.asarray(fs.omega, float), "wave_direction": headings, "body": names,
              "dof": list(DOFS), "y": fs.y, "x": fs.x}
    r = rad.reshape(*rad.shape[:3], *shape)
    d = dif.reshape(*dif.shape[:2], *shape)
    dims_r, dims_d = ("omega", "body", "dof", "y", "x"), ("omega", "wave_direction", "y", "x")
    return xr.Dataset({"radiated_re": (dims_r, r.real), "radiated_im": (dims_r, r.imag),
                       "diffracted_re": (dims_d, d.real), "diffracted_im": (dims_d, d.imag)}, coords=coords,
                      attrs={"convention": "exp(-iwt)", "capytaine_version": cpt.__version__,
                             "reference_points": json.dumps({b.name: list(b.ref_point) for b in spec.all_bodies}),
                             "gravity": w.gravity, "depth": w.depth_m})


def elevations(solver, points: np.ndarray, results: list) -> np.ndarray:
    """The free-surface elevation (len(results), P) of solved problems of one body at one frequency:
    what Capytaine's ``compute_free_surface_elevation`` gives each, (i w / g) S @ sources, with
    its influence matrix S between the points and the panels built once for them all."""
    r = results[0]
    pts = np.column_stack([points, np.zeros(points.shape[0])])
    gf = dict(free_surface=r.free_surface, water_depth=r.water_depth, wavenumber=r.encounter_wavenumber)
    S = solver.engine.build_S_matrix(pts, r.body.mesh_including_lid, **gf)
    return np.stack([(1j * res.omega / res.g) * (S @ res.sources) for res in results])


def store_free_surface(ds: xr.Dataset, path: Path) -> Path:
    """Write the solution atomically (no partial file on a crash)."""
    write_atomic(path, lambda tmp: ds.to_netcdf(tmp))
    return path


def read_free_surface(path: str | Path) -> tuple[xr.DataArray, xr.DataArray]:
    """The radiated (omega, body, dof, y, x) and diffracted (omega, wave_direction, y, x) complex fields."""
    with xr.open_dataset(path, engine="netcdf4") as ds:
        ds = ds.load()
    return ds["radiated_re"] + 1j * ds["radiated_im"], ds["diffracted_re"] + 1j * ds["diffracted_im"]
