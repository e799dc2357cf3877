"""The ``hdb build`` spec: TOML -> validated pydantic model (format in ``docs/hdb-spec.md``).

One body (``[body]``) or several solved together (``[[bodies]]``); each body is a primitive
(sphere, vertical cylinder, box), a ``compound`` of primitive ``parts`` (e.g. a box with a
damping plate) or a mesh file. Errors name the spec file and the key
(``f3of.toml: bodies[1].parts[0].draft: required for shape = 'box'``).
"""

from __future__ import annotations

import math
from pathlib import Path
from typing import Annotated, Literal, Optional, Union

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, model_validator

from hydrolink.protocol.scene import Water  # the same [water] table as a scene's
from hydrolink.protocol.toml_model import read_toml_file, validate_toml

from hydrolink.protocol.hdb.layout import HDBError


class SpecError(HDBError):
    """A build spec that cannot be built; the message names the spec file, the key and why.
    (An HDBError, so callers reporting bad HDB inputs in one line report these too.)"""


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]
Vector3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]
PRIMITIVES = ("sphere", "vertical_cylinder", "box")
_GEOMETRY_KEYS = ("radius", "length", "width", "draft", "freeboard", "height", "mesh", "mesh_format",
                  "panel_size", "parts")

# Keys each shape needs / accepts (beyond name, shape, center, reference_point, lid).
_SHAPE_KEYS: dict[str, tuple[set[str], set[str]]] = {
    "sphere": ({"radius"}, {"panel_size"}),
    "vertical_cylinder": ({"radius", "draft"}, {"freeboard", "height", "panel_size"}),
    "box": ({"length", "width", "draft"}, {"freeboard", "height", "panel_size"}),
    "mesh": ({"mesh"}, {"mesh_format"}),
    "compound": ({"parts"}, {"panel_size"}),
}


def _check_geometry(obj) -> None:
    """Shape-dependent key rules shared by bodies and parts. Messages start with ``.key:``
    (relative to the table; :func:`parse_spec` prefixes the table's location)."""
    required, optional = _SHAPE_KEYS[obj.shape]
    for key in sorted(required):
        if getattr(obj, key, None) is None:
            raise ValueError(f".{key}: required for shape = {obj.shape!r}")
    allowed = required | optional
    for key in _GEOMETRY_KEYS:
        if key not in allowed and getattr(obj, key, None) is not None:
            raise ValueError(f".{key}: not used for shape = {obj.shape!r} "
                             f"(it takes {', '.join(sorted(allowed))})")
    if obj.freeboard is not None and obj.height is not None:
        if not math.isclose(obj.draft + obj.freeboard, obj.height, rel_tol=1e-9, abs_tol=1e-12):
            raise ValueError(f".height: {obj.height} contradicts draft + freeboard = "
                             f"{obj.draft + obj.freeboard} (give one of freeboard/height)")
    if obj.shape in ("vertical_cylinder", "box", "compound"):
        if obj.center[2] != 0.0:
            raise ValueError(".center: z must be 0 for this shape (center is the waterline centre; "
                             "the vertical placement is set by draft/freeboard)")
    if obj.shape in ("vertical_cylinder", "box") and obj.top <= -obj.draft:
        raise ValueError(f".freeboard: the top ({obj.top} m) must be above the bottom "
                         f"(-draft = {-obj.draft} m)")
    if obj.shape == "sphere" and obj.center[2] - obj.radius >= 0:
        raise ValueError(".center: the sphere is entirely above the water (z - radius >= 0)")


class _Geometry(_Section):
    radius: Optional[PositiveFloat] = None
    length: Optional[PositiveFloat] = None
    width: Optional[PositiveFloat] = None
    draft: Optional[PositiveFloat] = None
    freeboard: Optional[FiniteFloat] = None
    height: Optional[PositiveFloat] = None
    center: Vector3 = [0.0, 0.0, 0.0]
    panel_size: Optional[PositiveFloat] = None

    @property
    def top(self) -> float:
        """z of the top of a cylinder/box (negative: fully submerged)."""
        if self.height is not None:
            return self.height - self.draft
        return self.freeboard if self.freeboard is not None else self.draft

    @property
    def pierces(self) -> bool:
        """Whether the primitive crosses the free surface."""
        if self.shape == "sphere":
            return self.center[2] + self.radius > 0
        return self.top >= 0

    def extent(self) -> tuple[np.ndarray, np.ndarray]:
        """Bounding box (low, high corners) of the immersed part of a primitive."""
        c = np.asarray(self.center, float)
        if self.shape == "sphere":
            lo, hi = c - self.radius, c + self.radius
        else:
            half = (self.radius, self.radius) if self.shape == "vertical_cylinder" else (
                self.length / 2, self.width / 2)
            lo = np.array([c[0] - half[0], c[1] - half[1], -self.draft])
            hi = np.array([c[0] + half[0], c[1] + half[1], self.top])
        hi[2] = min(hi[2], 0.0)
        return lo, hi


class PartSpec(_Geometry):
    """One primitive of a ``compound`` body (global frame, plus the body's ``center`` shift)."""
    shape: Literal["sphere", "vertical_cylinder", "box"]

    @model_validator(mode="after")
    def _shape_keys(self) -> "PartSpec":
        _check_geometry(self)
        return self

    def shifted(self, dx: float, dy: float) -> "PartSpec":
        return self.model_copy(update={"center": [self.center[0] + dx, self.center[1] + dy, self.center[2]]})


class BeamModes(_Section):
    """``[[body.modes]]`` of a slender body (modes.py): the first ``count`` free-free beam modes
    along ``axis`` (through the reference point), bending with deflection along ``deflection`` or
    torsion about the axis; the beam spans ``ends`` along the axis (m; default the hull's extent).
    Named ``<name><k>`` (default ``bend_<deflection>`` / ``twist``)."""
    kind: Literal["bending", "torsion"]
    count: Annotated[int, Field(ge=1, le=12)]
    axis: Literal["x", "y", "z"] = "x"
    deflection: Optional[Literal["x", "y", "z"]] = None
    ends: Optional[Annotated[list[FiniteFloat], Field(min_length=2, max_length=2)]] = None
    name: Optional[Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z][A-Za-z0-9_\-]*$")]] = None

    @model_validator(mode="after")
    def _deflection(self) -> "BeamModes":
        if self.kind == "bending" and self.deflection is None:
            raise ValueError(".deflection: required for kind = \"bending\" (the direction the beam deflects)")
        if self.kind == "torsion" and self.deflection is not None:
            raise ValueError(".deflection: only for kind = \"bending\" (torsion twists about the axis)")
        if self.deflection == self.axis:
            raise ValueError(f".deflection: must be across the axis {self.axis!r}, got {self.deflection!r}")
        if self.ends is not None and self.ends[1] <= self.ends[0]:
            raise ValueError(f".ends: must be increasing, got {self.ends}")
        return self

    @property
    def prefix(self) -> str:
        return self.name or ("twist" if self.kind == "torsion" else f"bend_{self.deflection}")


class TableMode(_Section):
    """``[[body.modes]]`` given as a displacement table: ``file`` (CSV, one row dx, dy, dz per
    vertex of the body's mesh file, in its order) for the mode ``name``."""
    kind: Literal["table"]
    name: Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z][A-Za-z0-9_\-]*$")]
    file: Annotated[str, Field(min_length=1)]


ModeSpec = Annotated[Union[BeamModes, TableMode], Field(discriminator="kind")]


class BodySpec(_Geometry):
    name: Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_\-]+$")]
    shape: Literal["sphere", "vertical_cylinder", "box", "mesh", "compound"]
    reference_point: Optional[Vector3] = None
    mesh: Optional[Annotated[str, Field(min_length=1)]] = None
    mesh_format: Optional[str] = None
    parts: Optional[Annotated[list[PartSpec], Field(min_length=1)]] = None
    lid: bool = True
    modes: Optional[Annotated[list[ModeSpec], Field(min_length=1)]] = None

    @model_validator(mode="after")
    def _shape_keys(self) -> "BodySpec":
        _check_geometry(self)
        if self.parts:
            _check_apart(self.global_parts(), "parts")
        return self

    @property
    def ref_point(self) -> list[float]:
        return list(self.reference_point if self.reference_point is not None else self.center)

    def global_parts(self) -> list[PartSpec]:
        """The primitives making up the body, in the global frame (a primitive body is its own
        single part; a mesh body has none)."""
        if self.shape == "compound":
            return [p.shifted(self.center[0], self.center[1]) for p in self.parts]
        if self.shape in PRIMITIVES:
            return [PartSpec(**self.model_dump(include={"shape", "radius", "length", "width", "draft",
                                                        "freeboard", "height", "center", "panel_size"}))]
        return []

    def bottom(self) -> float | None:
        """Lowest z of a primitive/compound body (None for a mesh file)."""
        parts = self.global_parts()
        return min(float(p.extent()[0][2]) for p in parts) if parts else None


def _overlap(a: PartSpec, b: PartSpec) -> bool:
    """Whether two primitives' immersed parts intersect or touch (bounding boxes; exact for two
    vertical cylinders side by side)."""
    (alo, ahi), (blo, bhi) = a.extent(), b.extent()
    if np.any(alo > bhi + 1e-9) or np.any(blo > ahi + 1e-9):
        return False
    if a.shape == b.shape == "vertical_cylinder":
        return math.dist(a.center[:2], b.center[:2]) <= a.radius + b.radius + 1e-9
    return True


def _check_apart(parts: list[PartSpec], label: str) -> None:
    for j, b in enumerate(parts):
        for i, a in enumerate(parts[:j]):
            if _overlap(a, b):
                raise ValueError(f".{label}[{j}].center: overlaps or touches {label}[{i}] (their panels would "
                                 f"coincide; leave a gap)")


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
                raise ValueError(".values: give either values or omega_min/omega_max/n, not both")
            if any(b <= a for a, b in zip(self.values, self.values[1:])):
                raise ValueError(".values: must be strictly increasing")
        else:
            for key, v in zip(("omega_min", "omega_max", "n"), linear):
                if v is None:
                    raise ValueError(f".{key}: required key is missing (or give values = [...])")
            if self.omega_max <= self.omega_min:
                raise ValueError(f".omega_max: must be > omega_min = {self.omega_min}")
        return self

    @property
    def omega(self) -> np.ndarray:
        if self.values is not None:
            return np.asarray(self.values, float)
        return np.linspace(self.omega_min, self.omega_max, self.n)


class Waves(_Section):
    directions: Annotated[list[FiniteFloat], Field(min_length=1)] = [0.0]

    @model_validator(mode="after")
    def _unique(self) -> "Waves":
        if len(set(self.directions)) != len(self.directions):
            raise ValueError(f".directions: repeated direction in {self.directions}")
        return self


class SecondOrder(_Section):
    """``[second_order]``: second-order data the build adds. ``mean_drift = "far-field"``: Capytaine's
    far-field (Kochin) mean drift, surge/sway/yaw. ``motions = "fixed"``: of the body held fixed (the
    diffraction drift); ``"free"``: of the body floating freely in the regular wave, moving with its
    linear RAO, which needs its mass properties: mass rho V (it floats), ``center_of_mass`` (global
    frame) and ``inertia`` (principal moments about the centre of mass, kg m^2; global axes)."""
    mean_drift: Literal["none", "far-field"] = "none"
    motions: Literal["fixed", "free"] = "fixed"
    kochin_directions: Annotated[int, Field(ge=36, le=3600)] = 360
    center_of_mass: Optional[Vector3] = None
    inertia: Optional[Annotated[list[PositiveFloat], Field(min_length=3, max_length=3)]] = None

    @model_validator(mode="after")
    def _mass_properties_if_free(self) -> "SecondOrder":
        for key in ("center_of_mass", "inertia"):
            given = getattr(self, key) is not None
            if self.motions == "free" and not given:
                raise ValueError(f".{key}: required with motions = \"free\" (the body's RAO needs it)")
            if self.motions != "free" and given:
                raise ValueError(f".{key}: only with motions = \"free\" (a fixed body does not move)")
        if self.motions == "free" and self.mean_drift == "none":
            raise ValueError(".motions: \"free\" is for mean_drift = \"far-field\" (nothing to compute here)")
        return self


class FreeSurface(_Section):
    """``[free_surface]``: Capytaine's free-surface elevation of every radiation and diffraction
    problem on a grid of ``cells`` (nx, ny) quads over ``extent`` (x0, x1, y0, y1, m), at the
    frequencies ``omega`` (rad/s, increasing; a regular wave's own, or a grid over a sea's band for
    the impulse response of the radiated wave, clients/view/convolved.py), for ``hydrolink view``'s radiated and
    diffracted waves (stored beside the cached HDB: server/hdb/build/free_surface.py)."""
    omega: Annotated[list[PositiveFloat], Field(min_length=1, max_length=512)]
    extent: Annotated[list[FiniteFloat], Field(min_length=4, max_length=4)]
    cells: Annotated[list[Annotated[int, Field(ge=1, le=2000)]], Field(min_length=2, max_length=2)]

    @model_validator(mode="after")
    def _box(self) -> "FreeSurface":
        if any(b <= a for a, b in zip(self.omega, self.omega[1:])):
            raise ValueError(".omega: must be strictly increasing (a grid the radiated wave's impulse response spans)")
        x0, x1, y0, y1 = self.extent
        if not (x1 > x0 and y1 > y0):
            raise ValueError(f".extent: must be [x0, x1, y0, y1] with x0 < x1 and y0 < y1, got {self.extent}")
        return self

    @property
    def x(self) -> np.ndarray:
        return np.linspace(self.extent[0], self.extent[1], self.cells[0] + 1)

    @property
    def y(self) -> np.ndarray:
        return np.linspace(self.extent[2], self.extent[3], self.cells[1] + 1)


class BuildSpec(_Section):
    body: Optional[BodySpec] = None
    bodies: Optional[Annotated[list[BodySpec], Field(min_length=1)]] = None
    frequencies: Frequencies
    water: Water = Water()
    waves: Waves = Waves()
    second_order: SecondOrder = SecondOrder()
    free_surface: Optional[FreeSurface] = None
    # the linear pressure on every hull panel of each problem solved, stored beside the HDB
    # (server/hdb/build/panels.py): what a run's sectional loads and panel pressures need
    panel_pressures: bool = False

    @model_validator(mode="after")
    def _bodies(self) -> "BuildSpec":
        if (self.body is None) == (self.bodies is None):
            raise ValueError("body: give either one [body] table or [[bodies]] tables" + (
                ", not both" if self.body is not None else " (required)"))
        names = [b.name for b in self.all_bodies]
        for j, name in enumerate(names):
            if name in names[:j]:
                raise ValueError(f"bodies[{j}].name: {name!r} is used by bodies[{names.index(name)}]")
        keys = self.body_keys
        for j, b in enumerate(self.all_bodies):
            for i, a in enumerate(self.all_bodies[:j]):
                if any(_overlap(p, q) for p in a.global_parts() for q in b.global_parts()):
                    raise ValueError(f"{keys[j]}.center: overlaps or touches {keys[i]} ({a.name!r}); "
                                     f"leave a gap between bodies")
        if self.second_order.mean_drift != "none" and (self.multibody or self.all_bodies[0].shape == "compound"):
            raise ValueError("second_order.mean_drift: the far-field drift is the total on everything in the "
                             "water; only for a one-body spec ([body], not a compound)")
        if self.panel_pressures and self.multibody:
            raise ValueError("panel_pressures: for a one-body spec ([body]): the panel set is one body's hull")
        if self.panel_pressures and not self.frequencies.infinite:
            raise ValueError("panel_pressures: needs frequencies.infinite = true (the A-infinity pressure of each "
                             "DOF: the sectional loads put the sections' A-infinity in the inertia, as the run does)")
        with_modes = [k for k, b in zip(keys, self.all_bodies) if b.modes]
        if with_modes and self.second_order.mean_drift != "none":
            raise ValueError(f"second_order.mean_drift: not with generalized modes ({with_modes[0]}.modes): the "
                             "far-field drift is built for rigid bodies")
        if with_modes and self.free_surface is not None:
            raise ValueError(f"free_surface: not with generalized modes ({with_modes[0]}.modes): the free-surface "
                             "solution is built for the rigid DOFs")
        depth = self.water.depth_m
        if math.isfinite(depth):
            for key, b in zip(keys, self.all_bodies):
                bottom = b.bottom()
                if bottom is not None and bottom <= -depth:
                    what = "the body" if self.body is not None else f"{key} ({b.name!r})"
                    raise ValueError(f"water.depth: {what} reaches z = {bottom} m, below the sea bed "
                                     f"(depth {depth} m)")
        return self

    @property
    def all_bodies(self) -> list[BodySpec]:
        return [self.body] if self.body is not None else list(self.bodies)

    @property
    def body_keys(self) -> list[str]:
        """Each body's table in the spec, for error messages: ``body`` or ``bodies[i]``."""
        return ["body"] if self.body is not None else [f"bodies[{i}]" for i in range(len(self.bodies))]

    @property
    def multibody(self) -> bool:
        return self.bodies is not None


def parse_spec(text: str, source: str | Path = "<spec>") -> BuildSpec:
    """Parse and validate build-spec TOML text; raise SpecError naming the key."""
    return validate_toml(text, source, BuildSpec, SpecError)


def load_spec(path: str | Path) -> BuildSpec:
    """Read and validate a build spec file."""
    path = Path(path)
    text = read_toml_file(path, SpecError, "the build spec")
    return parse_spec(text, path)


def mesh_path(body: BodySpec, spec_path: str | Path) -> Path | None:
    """The mesh file of a ``shape = "mesh"`` body, resolved against the spec's folder."""
    if body.mesh is None:
        return None
    p = Path(body.mesh).expanduser()
    return p if p.is_absolute() else (Path(spec_path).resolve().parent / p)
