"""The scene file (TOML): what to simulate. Parsed and validated identically by clients and server.

The scene travels in the ``hello`` message as its TOML text, so the server validates exactly what
the client read. Every error names the file, the key (``bodies[0].mass``) and why.
"""

from __future__ import annotations

import math
import sys
from pathlib import Path
from typing import Annotated, Literal, Union

from pydantic import (BaseModel, ConfigDict, Field, ValidationError, field_validator,
                      model_validator)

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

DOF_NAMES: tuple[str, ...] = ("surge", "sway", "heave", "roll", "pitch", "yaw")


class SceneError(ValueError):
    """A scene that cannot be run; the message names the file, the key and why."""

    def __init__(self, source: str | Path, key: str, why: str):
        self.source, self.key, self.why = str(source), key, why
        super().__init__(f"{source}: {key}: {why}" if key else f"{source}: {why}")


class _Section(BaseModel):
    model_config = ConfigDict(extra="forbid", frozen=True)


PositiveFloat = Annotated[float, Field(gt=0, allow_inf_nan=False)]
FiniteFloat = Annotated[float, Field(allow_inf_nan=False)]


class Simulation(_Section):
    dt: PositiveFloat
    duration: PositiveFloat
    progress: bool = True

    @property
    def n_steps(self) -> int:
        return int(round(self.duration / self.dt))


class Water(_Section):
    density: PositiveFloat = 1025.0
    gravity: PositiveFloat = 9.81
    depth: Union[Literal["inf"], PositiveFloat] = "inf"

    @property
    def depth_m(self) -> float:
        return math.inf if self.depth == "inf" else float(self.depth)


class StillWater(_Section):
    type: Literal["still"]


class RegularWave(_Section):
    type: Literal["regular"]
    height: Annotated[float, Field(ge=0, allow_inf_nan=False)]
    period: PositiveFloat
    direction: FiniteFloat = 0.0
    phase: FiniteFloat = 0.0
    ramp: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 0.0


class IrregularWave(_Section):
    type: Literal["irregular"]
    spectrum: Literal["jonswap", "pierson-moskowitz"]
    hs: PositiveFloat
    tp: PositiveFloat
    gamma: Annotated[float, Field(ge=1, allow_inf_nan=False)] = 3.3
    seed: Annotated[int, Field(ge=0)] = 0
    direction: FiniteFloat = 0.0
    components: Annotated[int, Field(ge=1, le=100_000)] = 300
    ramp: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 0.0


Waves = Annotated[Union[StillWater, RegularWave, IrregularWave], Field(discriminator="type")]


class Hydro(_Section):
    irf_duration: Annotated[float, Field(ge=0, allow_inf_nan=False)] = 40.0


Vector3 = Annotated[list[FiniteFloat], Field(min_length=3, max_length=3)]
Vector6 = Annotated[list[FiniteFloat], Field(min_length=6, max_length=6)]


class Body(_Section):
    name: Annotated[str, Field(min_length=1, pattern=r"^[A-Za-z0-9_\-]+$")]
    hdb: Annotated[str, Field(min_length=1)]
    hdb_body: str | None = None
    mass: PositiveFloat
    center_of_mass: Vector3
    inertia: Union[Vector3, Annotated[list[Vector3], Field(min_length=3, max_length=3)]]
    dofs: list[Literal["surge", "sway", "heave", "roll", "pitch", "yaw"]] = list(DOF_NAMES)
    initial_displacement: Vector6 = [0.0] * 6
    initial_velocity: Vector6 = [0.0] * 6

    @field_validator("dofs")
    @classmethod
    def _unique_dofs(cls, v: list[str]) -> list[str]:
        if not v:
            raise ValueError("needs at least one DOF")
        if len(set(v)) != len(v):
            raise ValueError(f"repeated DOF in {v}")
        return v

    @field_validator("inertia")
    @classmethod
    def _inertia_valid(cls, v):
        import numpy as np
        m = np.diag(v) if len(v) == 3 and not isinstance(v[0], list) else np.asarray(v, float)
        if not np.allclose(m, m.T, rtol=1e-9, atol=0):
            raise ValueError("3x3 inertia must be symmetric")
        if np.any(np.linalg.eigvalsh(m) <= 0):
            raise ValueError("inertia must be positive definite (all principal moments > 0)")
        return v

    @property
    def inertia_matrix(self):
        import numpy as np
        v = self.inertia
        return np.diag(v).astype(float) if not isinstance(v[0], list) else np.asarray(v, float)

    @property
    def active_mask(self) -> list[bool]:
        return [d in self.dofs for d in DOF_NAMES]

    @property
    def hdb_body_name(self) -> str:
        return self.hdb_body or self.name


class Scene(_Section):
    simulation: Simulation
    water: Water = Water()
    waves: Waves = StillWater(type="still")
    hydro: Hydro = Hydro()
    bodies: Annotated[list[Body], Field(min_length=1)]

    @model_validator(mode="after")
    def _cross_checks(self) -> "Scene":
        names = [b.name for b in self.bodies]
        for i, n in enumerate(names):
            if n in names[:i]:
                raise ValueError(f"bodies[{i}].name: duplicate body name {n!r}")
        return self


def _loc(loc: tuple) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in ("regular", "irregular", "still") or str(part).startswith(("function-", "list[", "literal[")):
            continue  # discriminated-union / union branch tags, not keys
        else:
            out += ("." if out else "") + str(part)
    return out


def parse_scene(text: str, source: str | Path = "<scene>") -> Scene:
    """Parse and validate scene TOML text; raise SceneError naming the key."""
    try:
        raw = tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise SceneError(source, "", f"not valid TOML: {exc}") from None
    try:
        return Scene.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        key = _loc(err["loc"])
        msg = err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        elif err["type"] == "missing":
            msg = "required key is missing"
        elif err["type"] == "union_tag_invalid":
            key, msg = (key + ".type").lstrip("."), f"must be one of {err['ctx']['expected_tags']} (got {err['ctx']['tag']!r})"
        elif "input" in err and not isinstance(err["input"], dict) and err["type"] != "value_error":
            msg = f"{msg} (got {err['input']!r})"
        if msg.startswith("Value error, "):
            msg = msg[len("Value error, "):]
            if ": " in msg and msg.split(": ", 1)[0].startswith("bodies["):
                key, msg = msg.split(": ", 1)
        more = f" (and {len(exc.errors()) - 1} more problem(s))" if len(exc.errors()) > 1 else ""
        raise SceneError(source, key, msg + more) from None


def load_scene(path: str | Path) -> tuple[Scene, str]:
    """Read a scene file; returns the validated scene and its text."""
    path = Path(path)
    try:
        text = path.read_text()
    except OSError as exc:
        raise SceneError(path, "", f"cannot read the scene file: {exc.strerror}") from None
    return parse_scene(text, path), text


def resolve_path(scene_path: str | Path, relative: str) -> Path:
    """Resolve a path written in a scene against the scene file's folder."""
    p = Path(relative).expanduser()
    return p if p.is_absolute() else (Path(scene_path).parent / p).resolve()
