"""``hdb build``: a hydrodynamic database computed with Capytaine from a small TOML build spec.

The spec format is documented in ``docs/hdb-spec.md``. :func:`build_hdb` meshes the body (immersed
part only, with a lid against irregular frequencies), solves radiation and diffraction over the
frequency grid plus radiation at infinite frequency (A∞), computes the buoyancy/waterplane
hydrostatics and returns the HDB in the schema's layout (:mod:`hydrolink.server.hdb.schema`).
Results are cached on disk, keyed by everything that determines them.
"""

from __future__ import annotations

import hashlib
import json
import logging
import math
import os
import sys
import tempfile
import time
import warnings
from pathlib import Path
from typing import Annotated, Literal, Optional, Union

import numpy as np
import xarray as xr
from pydantic import BaseModel, ConfigDict, Field, ValidationError, model_validator

from hydrolink.server.hdb.capytaine_io import from_capytaine_dataset
from hydrolink.server.hdb.schema import SCHEMA_VERSION, HDBError, from_netcdf_dataset, to_netcdf

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

LOG = logging.getLogger(__name__)

BUILD_RECIPE_VERSION = 1  # bump when meshing/solving changes: invalidates cached HDBs
CPT_DOFS = ("Surge", "Sway", "Heave", "Roll", "Pitch", "Yaw")


class SpecError(HDBError):
    """A build spec that cannot be built; the message names the spec file, the key and why.
    (An HDBError, so callers reporting bad HDB inputs in one line report these too.)"""

    def __init__(self, source: str | Path, key: str, why: str):
        ValueError.__init__(self, f"{source}: {key}: {why}" if key else f"{source}: {why}")
        self.source, self.key, self.field, self.why = str(source), key, key, why


# ----------------------------------------------------------------------------------------------
# Spec model
# ----------------------------------------------------------------------------------------------

class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
Vector3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]

# Keys each shape needs / accepts (beyond name, shape, center, reference_point, lid).
_SHAPE_KEYS: dict[str, tuple[set[str], set[str]]] = {
    "sphere": ({"radius"}, {"panel_size"}),
    "vertical_cylinder": ({"radius", "draft"}, {"freeboard", "height", "panel_size"}),
    "box": ({"length", "width", "draft"}, {"freeboard", "height", "panel_size"}),
    "mesh": ({"mesh"}, {"mesh_format"}),
}


class BodySpec(_Section):
    name: Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_\-]+$")]
    shape: Literal["sphere", "vertical_cylinder", "box", "mesh"]
    radius: Optional[PositiveFloat] = None
    length: Optional[PositiveFloat] = None
    width: Optional[PositiveFloat] = None
    draft: Optional[PositiveFloat] = None
    freeboard: Optional[FiniteFloat] = None
    height: Optional[PositiveFloat] = None
    center: Vector3 = [0.0, 0.0, 0.0]
    reference_point: Optional[Vector3] = None
    mesh: Optional[Annotated[str, Field(min_length=1)]] = None
    mesh_format: Optional[str] = None
    panel_size: Optional[PositiveFloat] = None
    lid: bool = True

    @model_validator(mode="after")
    def _shape_keys(self) -> "BodySpec":
        required, optional = _SHAPE_KEYS[self.shape]
        for key in sorted(required):
            if getattr(self, key) is None:
                raise ValueError(f"body.{key}: required for shape = {self.shape!r}")
        allowed = required | optional
        for key in ("radius", "length", "width", "draft", "freeboard", "height", "mesh",
                    "mesh_format", "panel_size"):
            if key not in allowed and getattr(self, key) is not None:
                raise ValueError(f"body.{key}: not used for shape = {self.shape!r} "
                                 f"(it takes {', '.join(sorted(allowed))})")
        if self.freeboard is not None and self.height is not None:
            if not math.isclose(self.draft + self.freeboard, self.height, rel_tol=1e-9, abs_tol=1e-12):
                raise ValueError(f"body.height: {self.height} contradicts draft + freeboard = "
                                 f"{self.draft + self.freeboard} (give one of freeboard/height)")
        if self.shape in ("vertical_cylinder", "box"):
            if self.center[2] != 0.0:
                raise ValueError("body.center: z must be 0 for this shape (center is the waterline "
                                 "centre; the vertical placement is set by draft/freeboard)")
            if self.top <= -self.draft:
                raise ValueError(f"body.freeboard: the top ({self.top} m) must be above the bottom "
                                 f"(-draft = {-self.draft} m)")
        if self.shape == "sphere" and self.center[2] - self.radius >= 0:
            raise ValueError("body.center: the sphere is entirely above the water (z - radius >= 0)")
        return self

    @property
    def top(self) -> float:
        """z of the top of a cylinder/box (negative: fully submerged)."""
        if self.height is not None:
            return self.height - self.draft
        return self.freeboard if self.freeboard is not None else self.draft

    @property
    def ref_point(self) -> list[float]:
        return list(self.reference_point if self.reference_point is not None else self.center)


class Frequencies(_Section):
    omega_min: Optional[PositiveFloat] = None
    omega_max: Optional[PositiveFloat] = None
    n: Optional[Annotated[int, Field(ge=2, le=2000)]] = None
    values: Optional[Annotated[list[PositiveFloat], Field(min_length=2)]] = None
    infinite: bool = True

    @model_validator(mode="after")
    def _grid(self) -> "Frequencies":
        linear = (self.omega_min, self.omega_max, self.n)
        if self.values is not None:
            if any(v is not None for v in linear):
                raise ValueError("frequencies.values: give either values or omega_min/omega_max/n, not both")
            if any(b <= a for a, b in zip(self.values, self.values[1:])):
                raise ValueError("frequencies.values: must be strictly increasing")
        else:
            for key, v in zip(("omega_min", "omega_max", "n"), linear):
                if v is None:
                    raise ValueError(f"frequencies.{key}: required key is missing (or give values = [...])")
            if self.omega_max <= self.omega_min:
                raise ValueError(f"frequencies.omega_max: must be > omega_min = {self.omega_min}")
        return self

    @property
    def omega(self) -> np.ndarray:
        if self.values is not None:
            return np.asarray(self.values, float)
        return np.linspace(self.omega_min, self.omega_max, self.n)


class Water(_Section):
    density: PositiveFloat = 1025.0
    gravity: PositiveFloat = 9.81
    depth: Union[Literal["inf"], PositiveFloat] = "inf"

    @property
    def depth_m(self) -> float:
        return math.inf if self.depth == "inf" else float(self.depth)


class Waves(_Section):
    directions: Annotated[list[FiniteFloat], Field(min_length=1)] = [0.0]

    @model_validator(mode="after")
    def _unique(self) -> "Waves":
        if len(set(self.directions)) != len(self.directions):
            raise ValueError(f"waves.directions: repeated direction in {self.directions}")
        return self


class BuildSpec(_Section):
    body: BodySpec
    frequencies: Frequencies
    water: Water = Water()
    waves: Waves = Waves()

    @model_validator(mode="after")
    def _depth(self) -> "BuildSpec":
        depth = self.water.depth_m
        if math.isfinite(depth):
            b = self.body
            bottom = (b.center[2] - b.radius) if b.shape == "sphere" else (-b.draft if b.draft else None)
            if bottom is not None and bottom <= -depth:
                raise ValueError(f"water.depth: the body reaches z = {bottom} m, below the sea bed "
                                 f"(depth {depth} m)")
        return self


def _loc(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif str(part).startswith(("function-", "list[", "literal[", "union[")) or part in ("float", "str"):
            continue
        else:
            out += ("." if out else "") + str(part)
    return out


def parse_spec(text: str, source: str | Path = "<spec>") -> BuildSpec:
    """Parse and validate build-spec TOML text; raise SpecError naming the key."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SpecError(source, "", f"not valid TOML: {exc}") from None
    try:
        return BuildSpec.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        key, msg = _loc(err["loc"]), err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        elif err["type"] == "missing":
            msg = "required key is missing"
        elif "input" in err and not isinstance(err["input"], dict) and err["type"] != "value_error":
            msg = f"{msg} (got {err['input']!r})"
        if msg.startswith("Value error, "):
            msg = msg[len("Value error, "):]
            head = msg.split(": ", 1)[0]
            if ": " in msg and head.split(".")[0] in ("body", "frequencies", "water", "waves"):
                key, msg = msg.split(": ", 1)
        more = f" (and {len(exc.errors()) - 1} more problem(s))" if len(exc.errors()) > 1 else ""
        raise SpecError(source, key, msg + more) from None


def load_spec(path: str | Path) -> BuildSpec:
    """Read and validate a build spec file."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise SpecError(path, "", f"cannot read the build spec: {exc.strerror}") from None
    return parse_spec(text, path)


def mesh_path(spec: BuildSpec, spec_path: str | Path) -> Path | None:
    """The mesh file of a ``shape = "mesh"`` body, resolved against the spec's folder."""
    if spec.body.mesh is None:
        return None
    p = Path(spec.body.mesh).expanduser()
    return p if p.is_absolute() else (Path(spec_path).resolve().parent / p)


# ----------------------------------------------------------------------------------------------
# Mesh
# ----------------------------------------------------------------------------------------------

def default_panel_size(spec: BuildSpec) -> float:
    """A modest default: a sixth of the body's smallest dimension (radius, half length/width,
    draft), and at most lambda_min / 8 for the shortest wave (Capytaine warns when a panel's
    radius, about 0.7 x its edge, exceeds lambda / 8)."""
    b = spec.body
    dims = [d for d in (b.radius, b.length and b.length / 2, b.width and b.width / 2, b.draft) if d]
    w_max = float(spec.frequencies.omega.max())
    k_max = w_max ** 2 / spec.water.gravity  # deep-water wavenumber: shortest wave (conservative)
    return min([d / 6 for d in dims] + [(2 * np.pi / k_max) / 8])


def _lid_depth(hull) -> float:
    """Lid just below the free surface (1 % of the immersed depth). A lid at depth d moves the
    first irregular frequency up to roughly sqrt(g k coth(k d)), i.e. far above any grid here;
    deeper lids (e.g. Capytaine's ``lowest_lid_position``) gave visibly noisier damping and
    excitation on coarse meshes of the example cylinder, a lid at 1 % converged smoothly."""
    return -0.01 * max(1e-3, -float(hull.z_span[0]))


def _axisymmetric_lid(hull, z: float, n_theta: int, h: float, axis_xy: tuple[float, float]):
    """A disk lid at depth z inside an axisymmetric hull of n_theta sectors: its radius is the
    hull's radius at z (from the panel edges crossing z) times cos(pi/n), so it stays inside."""
    import capytaine as cpt

    merged = hull.merged() if hasattr(hull, "merged") else hull
    v = merged.vertices
    radii = []
    for face in merged.faces:
        pts = v[face]
        for a, b in zip(pts, np.roll(pts, -1, axis=0)):
            if (a[2] - z) * (b[2] - z) <= 0 and a[2] != b[2]:
                p = a + (z - a[2]) / (b[2] - a[2]) * (b - a)
                radii.append(math.hypot(p[0] - axis_xy[0], p[1] - axis_xy[1]))
    if not radii:
        return None
    r = min(radii) * math.cos(np.pi / n_theta)
    if r <= 0:
        return None
    return _downward(cpt.mesh_disk(radius=r, center=(axis_xy[0], axis_xy[1], z), normal=(0, 0, 1),
                                   resolution=(max(1, int(math.ceil(r / h))), n_theta),
                                   axial_symmetry=True, name="lid"))


def _rectangle(x0: float, x1: float, y0: float, y1: float, z: float, nx: int, ny: int):
    """Horizontal rectangle of nx x ny quads at height z, normals pointing down (as a lid's)."""
    import capytaine as cpt

    xs, ys = np.linspace(x0, x1, nx + 1), np.linspace(y0, y1, ny + 1)
    vertices = np.array([(x, y, z) for x in xs for y in ys])
    at = lambda i, j: i * (ny + 1) + j  # noqa: E731
    # (i,j) -> (i,j+1) -> (i+1,j+1) -> (i+1,j) turns clockwise seen from above: normal down
    faces = np.array([(at(i, j), at(i, j + 1), at(i + 1, j + 1), at(i + 1, j))
                      for i in range(nx) for j in range(ny)])
    return cpt.Mesh(vertices=vertices, faces=faces, name="lid")


def _box_lid(b: BodySpec, z: float, res: tuple[int, int], symmetric: bool):
    """Lid covering the box's interior waterplane; mirrors the hull's nested symmetry if any."""
    import capytaine as cpt

    nx, ny = res
    if symmetric:  # mesh_parallelepiped(reflection_symmetry=True): xOz of (yOz of the x<0, y<0 quarter)
        quarter = _rectangle(-b.length / 2, 0, -b.width / 2, 0, z, nx // 2, ny // 2)
        return cpt.ReflectionSymmetricMesh(cpt.ReflectionSymmetricMesh(quarter, plane="yOz"), plane="xOz",
                                           name="lid")
    cx, cy = b.center[:2]
    return _rectangle(cx - b.length / 2, cx + b.length / 2, cy - b.width / 2, cy + b.width / 2, z, nx, ny)


def _downward(mesh):
    """The same mesh with normals pointing down, keeping its rotation symmetry (Capytaine would
    otherwise flip it itself, with a warning)."""
    import capytaine as cpt

    if isinstance(mesh, cpt.RotationSymmetricMesh):
        return cpt.RotationSymmetricMesh(_downward(mesh.wedge), mesh.n, axis=mesh.axis, name=mesh.name)
    if np.all(mesh.faces_normals[:, 2] > 0):
        return cpt.Mesh(vertices=mesh.vertices, faces=mesh.faces[:, ::-1], name=mesh.name)
    return mesh


def make_meshes(spec: BuildSpec, spec_path: str | Path):
    """Hull mesh (immersed part only) and lid mesh (or None) for the body, in the global frame.

    Primitives use Capytaine's symmetric meshes (axisymmetric cylinder/sphere, mirror-symmetric
    box) and a lid built to match; a file mesh gets Capytaine's generic ``generate_lid``."""
    import capytaine as cpt

    b = spec.body
    depth = spec.water.depth_m
    h = b.panel_size or default_panel_size(spec)
    cx, cy, cz = b.center
    n_theta, res_xy = 0, (0, 0)
    if b.shape == "vertical_cylinder":
        n_theta = max(12, int(math.ceil(2 * np.pi * b.radius / h)))
        # equal-area polygon: the waterplane area and displaced volume are exact
        r_mesh = b.radius * math.sqrt(2 * np.pi / (n_theta * math.sin(2 * np.pi / n_theta)))
        n_r = max(2, int(math.ceil(b.radius / h)))
        # top at +draft when it pierces the surface, so z = 0 falls on a panel edge before clipping
        top = b.draft if b.top >= 0 else b.top
        n_z = max(2, int(math.ceil((top + b.draft) / h)))
        if b.top >= 0:
            n_z += n_z % 2
        full = cpt.mesh_vertical_cylinder(length=top + b.draft, radius=r_mesh,
                                          center=(0, 0, (top - b.draft) / 2),
                                          resolution=(n_r, n_theta, n_z), axial_symmetry=True,
                                          name=b.name)
        full = full.translated((cx, cy, 0.0), name=b.name) if (cx or cy) else full
    elif b.shape == "sphere":
        n_z = max(8, int(math.ceil(np.pi * b.radius / h)))
        n_z += n_z % 2
        n_theta = max(12, int(math.ceil(2 * np.pi * b.radius / h)))
        unit = cpt.mesh_sphere(radius=b.radius, center=(0, 0, 0), resolution=(n_z, n_theta),
                               axial_symmetry=True, name=b.name)
        # volume-preserving polyhedron: scale so the closed mesh holds (4/3) pi R^3
        scale = ((4 / 3) * np.pi * b.radius ** 3 / unit.volume) ** (1 / 3)
        full = cpt.mesh_sphere(radius=b.radius * scale, center=(cx, cy, cz),
                               resolution=(n_z, n_theta), axial_symmetry=True, name=b.name)
    elif b.shape == "box":
        top = b.draft if b.top >= 0 else b.top
        n_z = max(2, int(math.ceil((top + b.draft) / h)))
        if b.top >= 0:
            n_z += n_z % 2
        res_xy = tuple(max(2, 2 * int(math.ceil(L / (2 * h)))) for L in (b.length, b.width))
        full = cpt.mesh_parallelepiped(size=(b.length, b.width, top + b.draft),
                                       center=(cx, cy, (top - b.draft) / 2), resolution=res_xy + (n_z,),
                                       reflection_symmetry=(cx == 0 and cy == 0), name=b.name)
    else:
        path = mesh_path(spec, spec_path)
        if not path.is_file():
            raise SpecError(spec_path, "body.mesh", f"mesh file not found: {path}")
        try:
            full = cpt.load_mesh(str(path), b.mesh_format) if b.mesh_format else cpt.load_mesh(str(path))
        except Exception as exc:  # noqa: BLE001 - any reader failure is a bad spec input
            raise SpecError(spec_path, "body.mesh", f"cannot read mesh {path}: {exc}") from None
        if any(b.center):
            full = full.translated(tuple(b.center), name=b.name)
    hull = full.immersed_part(water_depth=depth)
    if hull.nb_faces == 0:
        raise SpecError(spec_path, "body.mesh" if b.shape == "mesh" else "body.center",
                        "no part of the body is below the free surface z = 0")
    pierces = hull.z_span[1] > -1e-9 and (b.shape != "vertical_cylinder" and b.shape != "box" or b.top >= 0)
    if not (b.lid and pierces):
        return hull, None
    z_lid = _lid_depth(hull)
    if b.shape in ("vertical_cylinder", "sphere"):
        lid = _axisymmetric_lid(hull, z_lid, n_theta, h, (cx, cy))
    elif b.shape == "box":
        lid = _box_lid(b, z_lid, res_xy, symmetric=isinstance(hull, cpt.ReflectionSymmetricMesh))
    else:
        lid = hull.generate_lid(z=z_lid)
        if lid.nb_faces == 0 and hasattr(hull, "merged"):
            lid = hull.merged().generate_lid(z=z_lid)
    if lid is None or lid.nb_faces == 0:
        warnings.warn(f"{spec_path}: body.lid: Capytaine could not generate a lid for this mesh; "
                      f"solving without one (irregular frequencies may show up)", stacklevel=3)
        return hull, None
    return hull, lid


# ----------------------------------------------------------------------------------------------
# Cache
# ----------------------------------------------------------------------------------------------

def default_cache_dir() -> Path:
    """``$HYDROLINK_CACHE``, else ``$XDG_CACHE_HOME/hydrolink/hdb``, else ``~/.cache/hydrolink/hdb``."""
    if os.environ.get("HYDROLINK_CACHE"):
        return Path(os.environ["HYDROLINK_CACHE"]).expanduser()
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base).expanduser() / "hydrolink" / "hdb"


def cache_key(spec: BuildSpec, spec_path: str | Path) -> str:
    """sha256 of the normalised spec, the mesh file's bytes, Capytaine's version, the schema
    version and this module's recipe version (the spec's own location does not matter)."""
    import capytaine as cpt

    normalised = spec.model_dump(mode="json")
    normalised["body"].pop("mesh", None)
    path = mesh_path(spec, spec_path)
    mesh_digest = None
    if path is not None:
        try:
            mesh_digest = hashlib.sha256(path.read_bytes()).hexdigest()
        except OSError as exc:
            raise SpecError(spec_path, "body.mesh", f"cannot read mesh file {path}: {exc.strerror}") from None
    blob = json.dumps({"spec": normalised, "mesh_sha256": mesh_digest,
                       "capytaine": cpt.__version__, "hdb_schema_version": SCHEMA_VERSION,
                       "recipe": BUILD_RECIPE_VERSION}, sort_keys=True)
    return hashlib.sha256(blob.encode()).hexdigest()


def _read_cached(path: Path) -> xr.Dataset | None:
    try:
        with xr.open_dataset(path, engine="netcdf4") as raw:
            return from_netcdf_dataset(raw.load(), path)
    except Exception as exc:  # noqa: BLE001 - a damaged cache entry is rebuilt, not fatal
        warnings.warn(f"ignoring unreadable cached HDB {path}: {exc}", stacklevel=3)
        return None


def _write_atomic(ds: xr.Dataset, path: Path) -> None:
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=".nc.tmp", dir=path.parent)
    os.close(fd)
    try:
        to_netcdf(ds, tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)


# ----------------------------------------------------------------------------------------------
# Solve
# ----------------------------------------------------------------------------------------------

def _solve(body, spec: BuildSpec, progress: bool, desc: str) -> xr.Dataset:
    """Radiation (6 DOFs) and diffraction over the grid, radiation at omega = inf; Capytaine's
    own dataset (exp(-iwt))."""
    import capytaine as cpt
    from tqdm import tqdm

    w = spec.water
    omegas = list(spec.frequencies.omega)
    if spec.frequencies.infinite:
        omegas = [math.inf] + omegas
    headings = np.radians(spec.waves.directions)
    common = dict(body=body, rho=w.density, g=w.gravity, water_depth=w.depth_m)
    solver = cpt.BEMSolver()
    n_total = sum(len(CPT_DOFS) + (len(headings) if math.isfinite(om) else 0) for om in omegas)
    results = []
    with tqdm(total=n_total, desc=desc, unit="pb", disable=not progress, leave=False) as bar:
        for om in omegas:  # one omega at a time: Capytaine reuses the influence matrices
            problems = [cpt.RadiationProblem(radiating_dof=d, omega=om, **common) for d in CPT_DOFS]
            if math.isfinite(om):
                problems += [cpt.DiffractionProblem(wave_direction=float(b), omega=om, **common)
                             for b in headings]
            for pb in problems:
                results.append(solver.solve(pb, keep_details=False, _check_wavelength=False))
                bar.update()
    return cpt.assemble_dataset(results, hydrostatics=False)


def _hydrostatics(hull, ref: np.ndarray, rho: float, g: float) -> tuple[np.ndarray, float, np.ndarray]:
    """Buoyancy + waterplane stiffness about ``ref`` (no gravity terms), volume, centre of buoyancy.

    Capytaine's ``compute_hydrostatic_stiffness`` adds the weight terms -m g (z_G - z_ref) (and
    m g (x_G - x_ref) in roll-yaw/pitch-yaw) with m the displaced mass unless ``mass`` is given;
    setting mass = 0 leaves exactly the buoyancy/waterplane part the schema wants."""
    import capytaine as cpt

    # Gauss-Legendre 2 quadrature: the waterplane moments are exact on flat panels (the default
    # one-point rule is ~1.5 % off for a coarse cylinder's C44)
    body = cpt.FloatingBody(mesh=hull.with_quadrature("Gauss-Legendre 2"),
                            dofs=cpt.rigid_body_dofs(rotation_center=ref),
                            center_of_mass=ref, mass=0.0, name="hydrostatics")
    K = body.compute_hydrostatic_stiffness(rho=rho, g=g).sel(influenced_dof=list(CPT_DOFS),
                                                             radiating_dof=list(CPT_DOFS))
    return np.asarray(K.values, float), float(body.disp_volume), np.asarray(body.center_of_buoyancy, float)


def _with_hydrostatics(cds: xr.Dataset, stiffness: np.ndarray, volume: float, cob: np.ndarray,
                       rho: float) -> xr.Dataset:
    """Attach our hydrostatics to Capytaine's dataset, in Capytaine's own names and layout (no
    ``center_of_mass``/``inertia_matrix``: there are no gravity terms to remove)."""
    return cds.assign(
        hydrostatic_stiffness=xr.DataArray(stiffness, dims=("influenced_dof", "radiating_dof"),
                                           coords={"influenced_dof": list(CPT_DOFS),
                                                   "radiating_dof": list(CPT_DOFS)}),
        disp_mass=rho * volume,
        center_of_buoyancy=xr.DataArray(cob, dims=("space_coordinate",)),
    )


def build_hdb_uncached(spec: BuildSpec, spec_path: str | Path, *, progress: bool = True) -> xr.Dataset:
    """Mesh, solve and convert, without looking at the cache."""
    import capytaine as cpt

    t0 = time.perf_counter()
    hull, lid = make_meshes(spec, spec_path)
    ref = np.asarray(spec.body.ref_point, float)
    body = cpt.FloatingBody(mesh=hull, lid_mesh=lid, dofs=cpt.rigid_body_dofs(rotation_center=ref),
                            center_of_mass=ref, name=spec.body.name)
    lam_min = 2 * np.pi * spec.water.gravity / float(spec.frequencies.omega.max()) ** 2
    r_max = float(body.mesh_including_lid.faces_radiuses.max())
    if r_max > lam_min / 8:
        warnings.warn(f"{spec_path}: body.panel_size: largest panel radius {r_max:.3g} m exceeds "
                      f"wavelength/8 = {lam_min / 8:.3g} m at omega_max; results near omega_max may "
                      f"be inaccurate", stacklevel=3)
    t_mesh = time.perf_counter()
    cds = _solve(body, spec, progress, desc=f"hdb build {spec.body.name}")
    t_solve = time.perf_counter()
    w = spec.water
    K, vol, cob = _hydrostatics(hull, ref, w.density, w.gravity)
    cds = _with_hydrostatics(cds, K, vol, cob, w.density).assign_coords(body=spec.body.name)
    ds = from_capytaine_dataset(cds, f"capytaine {cpt.__version__} build of {Path(spec_path).name}",
                                reference_points={spec.body.name: ref})
    ds.attrs.update({
        "builder": "hydrolink hdb build", "capytaine_version": cpt.__version__,
        "n_panels": int(hull.nb_faces), "n_lid_panels": int(lid.nb_faces if lid is not None else 0),
        "build_seconds": round(time.perf_counter() - t0, 3),
        "mesh_seconds": round(t_mesh - t0, 3), "solve_seconds": round(t_solve - t_mesh, 3),
    })
    return ds


def build_hdb(spec_path: str | Path, *, cache_dir: str | Path | None = None, progress: bool = True,
              force: bool = False) -> xr.Dataset:
    """Build (or fetch from the cache) the HDB described by the TOML spec at ``spec_path``.

    ``cache_dir`` overrides ``$HYDROLINK_CACHE`` / the XDG default; ``force`` rebuilds and
    overwrites the cache entry. The dataset's ``attrs['cache_file']`` says where it is stored."""
    spec_path = Path(spec_path)
    spec = load_spec(spec_path)
    key = cache_key(spec, spec_path)
    folder = Path(cache_dir).expanduser() if cache_dir is not None else default_cache_dir()
    path = folder / f"{spec.body.name}-{key[:24]}.nc"
    if path.is_file() and not force:
        ds = _read_cached(path)
        if ds is not None:
            ds.attrs["cache_file"] = str(path)
            ds.attrs["cache_hit"] = 1
            return ds
    ds = build_hdb_uncached(spec, spec_path, progress=progress)
    ds.attrs["build_spec_sha256"] = key
    try:
        _write_atomic(ds, path)
        ds.attrs["cache_file"] = str(path)
    except OSError as exc:
        warnings.warn(f"could not write the HDB cache {path}: {exc}", stacklevel=2)
    ds.attrs["cache_hit"] = 0
    return ds


__all__ = ["BuildSpec", "SpecError", "build_hdb", "build_hdb_uncached", "cache_key",
           "default_cache_dir", "load_spec", "make_meshes", "parse_spec"]
