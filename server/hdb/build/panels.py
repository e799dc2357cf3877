"""``panel_pressures = true`` in a build spec: the linear pressure on every hull panel of each
radiation and diffraction problem the build solved, for the loads along a body (sectional loads,
server/loads/sections.py) and the panel pressures of a run (server/loads/panel_output.py).

Stored beside the cached HDB in a NetCDF file of its own (the HDB the server loads stays as it
was; its attribute ``panel_pressure_file`` names it). One body (a one-body spec), its hull's panels
in the global frame at rest (the HDB's), SI, Capytaine's exp(-i w t) convention (the schema's):

    coords  omega (rad/s), wave_direction (rad), dof (the HDB's labels of the body), panel, xyz
    vars    center, normal (panel, xyz): the normal points out of the body, into the water
            area (panel); second_moment (panel, xyz, xyz): the integral of r r^T over the panel (flat panels:
                a linearly varying pressure, the hydrostatic one, is integrated exactly with it)
            added_mass_pressure, damping_pressure (omega, dof, panel); added_mass_pressure_inf (dof, panel):
                the radiation pressure p = -a(w) x'' - b(w) x' of DOF j's motion (per unit acceleration and
                velocity), so the force the water exerts on DOF i is -sum_panels p (V_i . n) dS: its sum
                over the hull gives the HDB's A(w), B(w) and A-infinity exactly (the same solve)
            excitation_pressure_re/_im (omega, wave_direction, panel): incident + diffracted pressure per unit
                wave amplitude at the origin (the HDB's excitation X_i = -sum e (V_i . n) dS)

The hydrostatic pressure is -rho g z at each panel's centre (no file needed)."""

from __future__ import annotations

import math
from dataclasses import dataclass
from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.server.allocation import require_size
from hydrolink.server.disk_cache import write_atomic

SCHEMA = "hydrolink panel pressures 1"


@dataclass(frozen=True)
class PanelPressures:
    """One body's hull panels and the linear pressures on them (module docstring)."""
    body: str
    dofs: tuple[str, ...]            # the body's DOF labels (six rigid, then its modes)
    reference_point: np.ndarray      # (3,) the DOFs' rotation centre
    center: np.ndarray               # (P, 3)
    normal: np.ndarray               # (P, 3) out of the body
    area: np.ndarray                 # (P,)
    second_moment: np.ndarray        # (P, 3, 3) integral of r r^T dS
    omega: np.ndarray                # (W,)
    wave_direction: np.ndarray       # (D,) rad, increasing
    added_mass: np.ndarray           # (W, n, P)
    damping: np.ndarray              # (W, n, P)
    added_mass_inf: np.ndarray       # (n, P)
    excitation: np.ndarray           # (W, D, P) complex
    rho: float
    g: float
    source: str                      # the file (messages)

    @property
    def panels(self) -> int:
        return int(self.area.size)

    def hdb_rows(self, motions: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        """A(w), B(w), A-infinity and X(w, beta) of the generalized DOFs whose displacement at each
        panel is ``motions`` (m, P, 3): the pressures integrated as the HDB's forces are,
        -sum p (V . n) dS. Returns (W, m, n), (W, m, n), (m, n), (W, D, m)."""
        w = -np.einsum("mpk,pk,p->mp", motions, self.normal, self.area)
        return (np.einsum("mp,wnp->wmn", w, self.added_mass), np.einsum("mp,wnp->wmn", w, self.damping),
                w @ self.added_mass_inf.T, np.einsum("mp,wdp->wdm", w, self.excitation))


def rigid_motions(points: np.ndarray, reference_point: np.ndarray) -> np.ndarray:
    """(6, P, 3): the displacement at ``points`` of a unit surge, sway, heave, roll, pitch, yaw about
    ``reference_point``."""
    r = np.asarray(points, float) - np.asarray(reference_point, float)
    out = np.zeros((6, r.shape[0], 3))
    for k in range(3):
        out[k, :, k] = 1.0
        e = np.zeros(3)
        e[k] = 1.0
        out[3 + k] = np.cross(e, r)
    return out


def face_vertices(mesh) -> np.ndarray:
    """(P, 4, 3) each panel's corners in the order of the mesh's faces_centers. A Capytaine
    reflection-symmetric mesh is walked half by half: its ``faces`` index each half's own vertices
    (Capytaine 3.0 concatenates them without offsetting the second half's)."""
    if hasattr(mesh, "half") and hasattr(mesh, "other_half"):
        return np.concatenate((face_vertices(mesh.half), face_vertices(mesh.other_half)))
    return np.asarray(mesh.vertices, float)[np.asarray(mesh.faces, int)]


def second_moments(corners: np.ndarray) -> np.ndarray:
    """(P, 3, 3) the integral of r r^T over each flat panel of ``corners`` (P, 4, 3) (quadrilaterals as two
    triangles, a triangle given with a repeated corner): per triangle A/12 (sum v v^T + s s^T), s the
    sum of its corners."""
    out = np.zeros((corners.shape[0], 3, 3))
    for tri in ((0, 1, 2), (0, 2, 3)):
        v = corners[:, tri]                                            # (P, 3, 3): vertex, xyz
        area = 0.5 * np.linalg.norm(np.cross(v[:, 1] - v[:, 0], v[:, 2] - v[:, 0]), axis=1)
        s = v.sum(axis=1)
        out += area[:, None, None] / 12.0 * (np.einsum("pvi,pvj->pij", v, v) + np.einsum("pi,pj->pij", s, s))
    return out


def panel_pressure_file(hdb_file: Path) -> Path:
    """The panel set's file beside a cached HDB."""
    return hdb_file.with_name(hdb_file.name.removesuffix(".nc") + ".panels.nc")


def panel_pressures_of(results: list, body, labels: list[str], name: str, reference_point: np.ndarray,
                       rho: float, g: float) -> PanelPressures:
    """The panel set of one body from Capytaine's results (solved with ``keep_details``): ``body`` the
    FloatingBody, ``labels`` its DOFs' HDB labels in its DOF order."""
    from capytaine.bem.airy_waves import airy_waves_pressure

    mesh = body.mesh
    dofs = list(body.dofs)
    finite = sorted({float(r.omega) for r in results if math.isfinite(float(r.omega)) and float(r.omega) > 0})
    heads = sorted({float(r.problem.wave_direction) for r in results if not hasattr(r, "radiating_dof")})
    n, p = len(dofs), int(mesh.nb_faces)
    require_size("panel_pressures", "the panel pressures (frequencies x problems x panels)",
                 (len(finite), 2 * n + 2 * len(heads), p), hint="a coarser mesh or fewer frequencies")
    a = np.zeros((len(finite), n, p))
    b = np.zeros((len(finite), n, p))
    a_inf = np.full((n, p), np.nan)
    exc = np.zeros((len(finite), len(heads), p), complex)
    hull = np.asarray(body.hull_mask) if body.lid_mesh is not None else slice(None)
    for r in results:
        om = float(r.omega)
        if hasattr(r, "radiating_dof"):
            j = dofs.index(r.radiating_dof)
            if math.isinf(om):   # Capytaine's symbolic infinity: the pressure over w^2 is finite
                a_inf[j] = np.real(np.asarray(r.pressure / r.encounter_omega ** 2))[hull]
                continue
            pressure = np.asarray(r.pressure)[hull]
            if om > 0:
                i = finite.index(om)
                a[i, j], b[i, j] = pressure.real / om ** 2, pressure.imag / om
        else:
            pressure = np.asarray(r.pressure)[hull]
            i, d = finite.index(om), heads.index(float(r.problem.wave_direction))
            exc[i, d] = pressure + airy_waves_pressure(mesh.faces_centers, r.problem)
    return PanelPressures(body=name, dofs=tuple(labels), reference_point=np.asarray(reference_point, float),
                          center=np.asarray(mesh.faces_centers, float), normal=np.asarray(mesh.faces_normals, float),
                          area=np.asarray(mesh.faces_areas, float),
                          second_moment=second_moments(face_vertices(mesh)),
                          omega=np.asarray(finite),
                          wave_direction=np.asarray(heads), added_mass=a, damping=b, added_mass_inf=a_inf,
                          excitation=exc, rho=float(rho), g=float(g), source="(this build)")


def store_panel_pressures(ps: PanelPressures, path: Path) -> None:
    """Write the panel set (module docstring) atomically."""
    ds = xr.Dataset(
        {"center": (("panel", "xyz"), ps.center), "normal": (("panel", "xyz"), ps.normal),
         "area": (("panel",), ps.area), "second_moment": (("panel", "xyz", "xyz2"), ps.second_moment),
         "added_mass_pressure": (("omega", "dof", "panel"), ps.added_mass),
         "damping_pressure": (("omega", "dof", "panel"), ps.damping),
         "added_mass_pressure_inf": (("dof", "panel"), ps.added_mass_inf),
         "excitation_pressure_re": (("omega", "wave_direction", "panel"), ps.excitation.real),
         "excitation_pressure_im": (("omega", "wave_direction", "panel"), ps.excitation.imag)},
        coords={"omega": ps.omega, "wave_direction": ps.wave_direction, "dof": list(ps.dofs),
                "xyz": ["x", "y", "z"]},
        attrs={"schema": SCHEMA, "body": ps.body, "reference_point": ps.reference_point.tolist(),
               "rho": ps.rho, "g": ps.g, "time_convention": "exp(-iwt)"})
    write_atomic(path, lambda tmp: ds.to_netcdf(tmp, engine="netcdf4"))


class PanelFileError(ValueError):
    """A panel set file that cannot be read (the message names the file and variable)."""


def read_panel_pressures(path: Path) -> PanelPressures:
    """The panel set stored by :func:`store_panel_pressures`; PanelFileError naming the file."""
    try:
        with xr.open_dataset(path, engine="netcdf4") as raw:
            ds = raw.load()
    except (OSError, ValueError) as exc:
        raise PanelFileError(f"{path}: cannot read the panel pressures: {exc}") from None
    if ds.attrs.get("schema") != SCHEMA:
        raise PanelFileError(f"{path}: attribute schema: not {SCHEMA!r} (not a panel pressure file of hdb build)")
    a_inf = np.asarray(ds["added_mass_pressure_inf"].values, float)
    return PanelPressures(
        body=str(ds.attrs["body"]), dofs=tuple(str(d) for d in ds["dof"].values),
        reference_point=np.asarray(ds.attrs["reference_point"], float).reshape(3),
        center=np.asarray(ds["center"].values, float), normal=np.asarray(ds["normal"].values, float),
        area=np.asarray(ds["area"].values, float), second_moment=np.asarray(ds["second_moment"].values, float),
        omega=np.asarray(ds["omega"].values, float),
        wave_direction=np.asarray(ds["wave_direction"].values, float),
        added_mass=np.asarray(ds["added_mass_pressure"].values, float),
        damping=np.asarray(ds["damping_pressure"].values, float), added_mass_inf=a_inf,
        excitation=np.asarray(ds["excitation_pressure_re"].values + 1j * ds["excitation_pressure_im"].values),
        rho=float(ds.attrs["rho"]), g=float(ds.attrs["g"]), source=str(path))
