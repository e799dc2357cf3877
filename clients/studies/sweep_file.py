"""The sweep file of ``hydrolink sweep`` (TOML), validated before anything runs.

::

    scene = "rm3.toml"              # relative to this file
    mode = "product"                # "product" | "zip" | "axes" (clients/studies/grid.py)
    solver = "run"                  # "run": hydrolink run (embedded server); "steady": hydrolink steady
                                    # (regular waves; a case it cannot solve is an error); "auto": steady
                                    # where the case allows, run elsewhere
    window = [100.0, 1200.0]        # s, the summaries' averaging window (default: end of the wave ramp
                                    # to the end; regular waves: shortened to whole wave periods)
    characteristic_width = 20.0     # m, for the capture width ratio (optional)
    case_series = "tail"            # each case's file: "tail" (default): its summary and the last `tail`
                                    # s of every series; "full": its summary and every sample of the run
    tail = 60.0                     # s (default: 5 wave periods of the case, T or Tp)
    [set]                           # keys set in every case, not swept (optional)
    "simulation.duration" = 1200.0
    [grid]                          # dotted scene keys; entries of arrays of tables by name
    "waves.hs" = [1.0, 2.0, 3.0]
    "waves.te" = [7.5, 9.5]         # derived key: the energy period, sets waves.tp = Te / (Te/Tp of
                                    # the case's spectrum)
    "ptos.pto.damping" = [6e5, 1.2e6]
    [[cases]]                       # extra explicit cases (optional label)
    label = "stiff"
    "ptos.pto.stiffness" = 1e5
    [site]                          # optional: the site's scatter diagram (CSV or NetCDF)
    scatter = "scatter.csv"

Every key of ``[set]``, ``[grid]`` and ``[[cases]]`` is applied to the scene and the result validated
by the scene's own model (protocol/scene.py): a key the scene does not have, a value of the wrong
type, an empty grid or a case that makes the scene invalid is one :class:`SweepError` naming the
sweep file and the key.
"""

from __future__ import annotations

import copy
import hashlib
import json
import math
import re
from dataclasses import dataclass, field
from importlib import metadata
from pathlib import Path
from typing import Any, Literal

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, field_validator

from hydrolink.protocol.errors import KeyedError
from hydrolink.clients.studies.grid import GridSpec, Value, absolute_paths, dump_toml, effective_value, full_key, quoted, scene_location, set_key
from hydrolink.protocol.scene import IrregularWave, Scene, SceneError, load_scene, parse_scene
from hydrolink.protocol.toml_model import parse_toml, read_toml_file, validate_toml

TE_KEY = "waves.te"
SEA_STATE_KEYS = ("waves.hs", "waves.tp", TE_KEY, "waves.height", "waves.period")
REALISATION_KEYS = ("waves.seed",)


class SweepError(KeyedError):
    """A sweep that cannot run; the message names the sweep file, the key and why (one line)."""


class Site(BaseModel):
    """``[site]``: the scatter diagram of the site (power_matrix.read_scatter)."""
    model_config = ConfigDict(extra="forbid")
    scatter: str = Field(min_length=1)          # relative to the sweep file


class SweepFile(GridSpec):
    """The sweep file's keys (module docstring)."""
    model_config = ConfigDict(extra="forbid", populate_by_name=True)
    scene: str = Field(min_length=1)
    solver: Literal["run", "steady", "auto"] = "run"
    window: tuple[float, float] | None = None
    characteristic_width: float | None = Field(default=None, gt=0, allow_inf_nan=False)
    fixed: dict[str, Value] = Field(default={}, alias="set")
    site: Site | None = None
    case_series: Literal["tail", "full"] = "tail"
    tail: float | None = Field(default=None, gt=0, allow_inf_nan=False)

    @field_validator("window")
    @classmethod
    def _window(cls, w):
        if w is not None and not (0 <= w[0] < w[1] and math.isfinite(w[1])):
            raise ValueError(f"[start, end] in s with 0 <= start < end (got {list(w)})")
        return w


@dataclass
class Case:
    """One case of a sweep: its overrides (sweep keys as written), its coordinate on every sweep
    key, the validated scene and its TOML text (absolute paths), the solver it runs with, the
    seconds of series its file keeps (None: all) and its files' name (:func:`case_name`)."""
    index: int
    label: str
    overrides: dict[str, Any]
    coords: dict[str, Any]
    scene: Scene
    text: str
    solver: str
    tail: float | None
    name: str = ""
    case_id: str = ""


@dataclass
class Sweep:
    """A validated sweep: the file, its scene, the sweep keys (one dimension each) and the cases."""
    path: Path
    spec: SweepFile
    text: str
    scene_path: Path
    scene_text: str
    keys: list[str]
    cases: list[Case]
    scatter: Any = None                 # power_matrix.Scatter or None
    notes: list[str] = field(default_factory=list)

    @property
    def other_keys(self) -> list[str]:
        """Sweep keys that are neither the sea state nor its realisation (seed)."""
        return [k for k in self.keys if full_key(k) not in SEA_STATE_KEYS + REALISATION_KEYS]


def _fmt(v) -> str:
    return f"{v:g}" if isinstance(v, float) else json.dumps(v) if isinstance(v, (list, dict)) else str(v)


def case_label(overrides: dict[str, Any]) -> str:
    return ", ".join(f"{k}={_fmt(v)}" for k, v in overrides.items())


TAIL_PERIODS = 5           # default tail of a case's series, in wave periods
NAME_CHARS = 160           # the most characters of keys and values in a case's file name


def _name_value(v) -> str:
    """A value as a file name shows it: 1.2e6 (not 1.2e+06), 0.75, true, text as it is."""
    if isinstance(v, float):
        mantissa, _, exp = f"{v:g}".partition("e")
        return mantissa + (f"e{int(exp)}" if exp else "")
    return json.dumps(v) if isinstance(v, (bool, list, dict)) else str(v)


def case_name(index: int, count: int, label: str | None, overrides: dict[str, Any]) -> str:
    """The stem of a case's files: ``case-012_waves.hs=2.5_ptos.pto.damping=1.2e6`` (the case's
    index, then its explicit label or its keys and values); filesystem-safe (letters, digits and
    ``.=+,-`` kept, anything else one ``_``), unique by its index, at most :data:`NAME_CHARS`
    characters after it."""
    text = label if label else "_".join(f"{k}={_name_value(v)}" for k, v in overrides.items())
    safe = re.sub(r"[^A-Za-z0-9.=+,-]+", "_", text).strip("_")[:NAME_CHARS]
    return f"case-{index:0{max(3, len(str(count - 1)))}d}" + (f"_{safe}" if safe else "")


def wave_period(scene: Scene) -> float | None:
    """The case's wave period (T of regular waves, Tp of irregular ones), None for other waves."""
    return getattr(scene.waves, "period", None) or getattr(scene.waves, "tp", None)


def _coordinate(v):
    """A dimension coordinate: scalars as they are (ints of a float key become floats later), lists
    and tables as their JSON text."""
    return v if isinstance(v, (bool, int, float, str)) else json.dumps(v)


class _CaseBuilder:
    """Applies keys to the scene document and validates the result, naming the sweep key at fault."""

    def __init__(self, source: Path, base: dict):
        self.source, self.base = source, base

    def apply(self, doc: dict, key: str, value, where: str) -> None:
        if full_key(key) == TE_KEY:
            return   # derived: applied after the others (needs the case's spectrum)
        try:
            set_key(doc, full_key(key), value)
        except KeyError as exc:
            raise SweepError(self.source, where, f"not a key of the scene: {exc.args[0]}") from None

    def validate(self, doc: dict, keys: dict[str, str], what: str) -> Scene:
        """Validate a case document; ``keys`` maps each applied sweep key to where it was written."""
        try:
            scene = parse_scene(dump_toml(doc), "scene")
        except SceneError as exc:
            for key, where in keys.items():
                loc = scene_location(doc, full_key(key))
                if exc.key == loc or exc.key.startswith((loc + ".", loc + "[")):
                    why = "not a key of the scene" if exc.why.startswith("unknown key") else exc.why
                    raise SweepError(self.source, where, f"{why} (scene key {exc.key})") from None
            raise SweepError(self.source, what, f"makes the scene invalid: {exc.key}: {exc.why}") from None
        return scene

    def derived(self, doc: dict, scene: Scene, overrides: dict[str, Any], where: dict[str, str]) -> Scene:
        """waves.te -> waves.tp of the case's own spectrum."""
        te = next((v for k, v in overrides.items() if full_key(k) == TE_KEY), None)
        if te is None:
            return scene
        key = where[next(k for k in overrides if full_key(k) == TE_KEY)]
        if not isinstance(scene.waves, IrregularWave):
            raise SweepError(self.source, key, f"the energy period needs irregular waves (the scene's are "
                                               f"{scene.waves.type!r})")
        if any(full_key(k) == "waves.tp" for k in overrides):
            raise SweepError(self.source, key, "give waves.te or waves.tp, not both")
        if isinstance(te, bool) or not isinstance(te, (int, float)) or not te > 0 or not math.isfinite(te):
            raise SweepError(self.source, key, f"a period in s > 0 (got {te!r})")
        from hydrolink.clients.studies.power_matrix import te_over_tp
        set_key(doc, "waves.tp", float(te) / te_over_tp(scene.waves))
        return self.validate(doc, {}, key)


def load_sweep(path: str | Path) -> Sweep:
    """Read and validate a sweep file and every case of it (SweepError on the first problem)."""
    path = Path(path)
    text = read_toml_file(path, SweepError, "the sweep file")
    spec = validate_toml(text, path, SweepFile, SweepError)
    if not spec.grid and not spec.cases:
        raise SweepError(path, "grid", "no cases: give [grid] keys or [[cases]]")
    scene_path = (path.parent / spec.scene).resolve()
    try:
        _, scene_text = load_scene(scene_path)
    except SceneError as exc:
        raise SweepError(path, "scene", str(exc)) from None
    base = absolute_paths(parse_toml(scene_text, scene_path, SweepError), scene_path)
    set_key(base, "simulation.progress", False)
    if isinstance(base.get("client"), dict):
        base["client"].setdefault("type", "exudyn")
    build = _CaseBuilder(path, base)
    for key, value in spec.fixed.items():
        where = f"set.{quoted(key)}"
        if full_key(key) == TE_KEY:
            raise SweepError(path, where, "waves.te is a grid or case key (use waves.tp here)")
        build.apply(base, key, value, where)
        build.validate(copy.deepcopy(base), {key: where}, where)
    # every grid value alone first: an error names the key and the value
    for key, values in spec.grid.items():
        for v in values:
            where = f"grid.{quoted(key)}"
            doc = copy.deepcopy(base)
            build.apply(doc, key, v, where)
            scene = build.validate(doc, {key: where}, where)
            build.derived(doc, scene, {key: v}, {key: where})
    raw = [(None, over) for over in spec.combinations()]
    raw += [(c.get("label"), {k: v for k, v in c.items() if k != "label"}) for c in spec.cases]
    keys = spec.keys()
    cases: list[Case] = []
    names: list[str | None] = []
    seen: set[str] = set()
    for i, (label, over) in enumerate(raw):
        n_grid = len(raw) - len(spec.cases)
        what = f"cases[{i - n_grid}]" if i >= n_grid else f"grid combination {case_label(over)}"
        where = {k: (f"{what}.{quoted(k)}" if i >= n_grid else f"grid.{quoted(k)}") for k in over}
        doc = copy.deepcopy(base)
        for k, v in over.items():
            build.apply(doc, k, v, where[k])
        scene = build.validate(doc, where, what)
        scene = build.derived(doc, scene, over, where)
        coords = {k: _coordinate(over[k]) if k in over else _scene_coordinate(scene, k, path) for k in keys}
        sig = json.dumps(coords, sort_keys=True, default=str)
        if sig in seen:
            continue   # the same case twice (e.g. an explicit case inside the grid)
        seen.add(sig)
        cases.append(Case(len(cases), label or case_label(over), over, coords, scene, dump_toml(doc),
                          _solver(spec.solver, scene, path, what), _tail(spec, scene, path, what)))
        names.append(label)
    for case, label in zip(cases, names):
        case.name = case_name(case.index, len(cases), label, case.overrides)
    sweep = Sweep(path, spec, text, scene_path, scene_text, keys, cases)
    _check_coordinates(sweep)
    if spec.site is not None:
        from hydrolink.clients.studies.power_matrix import PowerMatrixError, read_scatter
        try:
            sweep.scatter = read_scatter((path.parent / spec.site.scatter).resolve())
        except PowerMatrixError as exc:
            raise SweepError(path, "site.scatter", str(exc)) from None
        bad = [c for c in cases if not isinstance(c.scene.waves, IrregularWave)]
        if bad:
            raise SweepError(path, "site", f"a scatter diagram's AEP needs irregular sea states; case "
                                           f"{bad[0].label!r} has {bad[0].scene.waves.type!r} waves")
    return sweep


def _scene_coordinate(scene: Scene, key: str, path: Path):
    """A case's coordinate on a sweep key it does not set: the scene's value (written or default)."""
    if full_key(key) == TE_KEY:
        from hydrolink.clients.studies.power_matrix import sea_state
        state = sea_state(scene)
        return round(state.period, 9) if state and state.kind == "irregular" else math.nan
    v = effective_value(scene, full_key(key))
    return math.nan if v is None else _coordinate(v)


def _check_coordinates(sweep: Sweep) -> None:
    """One type per key (ints and floats mix as floats); NaN only for a derived key that does not apply."""
    for key in sweep.keys:
        values = [c.coords[key] for c in sweep.cases]
        kinds = {("number" if isinstance(v, (int, float)) and not isinstance(v, bool) else type(v).__name__)
                 for v in values}
        if len(kinds) > 1:
            raise SweepError(sweep.path, quoted(key), f"values of different types across the cases ({sorted(kinds)}): "
                                                      "one dimension needs one type")
        if kinds == {"number"}:
            for c in sweep.cases:
                c.coords[key] = float(c.coords[key])


def _tail(spec: SweepFile, scene: Scene, path: Path, what: str) -> float | None:
    """Seconds of series the case's file keeps: None for "full", else ``tail`` or 5 wave periods."""
    if spec.case_series == "full":
        return None
    if spec.tail is not None:
        return spec.tail
    period = wave_period(scene)
    if period is None:
        raise SweepError(path, "tail", f"{what} has {scene.waves.type!r} waves, without a wave period to count the "
                                       f"default tail of its series in: give tail (s), or case_series = \"full\"")
    return TAIL_PERIODS * float(period)


def _solver(solver: str, scene: Scene, path: Path, what: str) -> str:
    if solver == "run":
        return "run"
    from hydrolink.clients.analysis.steady import SteadyError, check_scene
    try:
        check_scene(scene)
    except SteadyError as exc:
        if solver == "steady":
            raise SweepError(path, "solver", f"\"steady\" cannot solve {what}: {exc}") from None
        return "run"
    return "steady"


# ------------------------------------------------------------------ case identity

def hydrolink_version() -> str:
    try:
        return metadata.version("hydrolink")
    except metadata.PackageNotFoundError:  # pragma: no cover - running from a source tree
        return "unknown"


CASE_FILE_FORMAT = 2       # 2: summary + tail (clients/studies/sweep_case_file.py); 1 (hash names, full series) is not resumed
_VOLATILE_ATTRS = {"cache_file", "cache_hit", "build_seconds", "mesh_seconds", "solve_seconds"}


def dataset_digest(ds) -> str:
    """sha256 of an HDB dataset's content: every variable and coordinate (name, dtype, shape,
    bytes) and its attributes (cache bookkeeping left out)."""
    h = hashlib.sha256()
    for name in sorted(ds.variables, key=str):
        a = np.asarray(ds[name].values)
        h.update(f"{name};{a.dtype.str};{a.shape};".encode())
        h.update(a.astype(str).tobytes() if a.dtype.kind in "OUS" else np.ascontiguousarray(a).tobytes())
    attrs = {k: str(v) for k, v in ds.attrs.items() if k not in _VOLATILE_ATTRS}
    h.update(json.dumps(attrs, sort_keys=True).encode())
    return h.hexdigest()


def file_digest(path: str | Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as fh:
        for block in iter(lambda: fh.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def case_identity(case: Case, hdb_digests: dict[str, str]) -> str:
    """The key of a case's results: sha256 of its scene (file paths replaced by their content's
    digests), its solver, the hydrolink version and what its file keeps (format, tail)."""
    doc = parse_toml(case.text, f"case {case.label}", SweepError)
    for b in doc.get("bodies", []):
        if "hdb" in b:
            b["hdb"] = "sha256:" + hdb_digests[b["hdb"]]
    waves = doc.get("waves", {})
    if isinstance(waves, dict) and "file" in waves:
        waves["file"] = "sha256:" + file_digest(waves["file"])
    client = doc.get("client", {})
    if isinstance(client, dict) and "fmu" in client:
        client["fmu"] = "sha256:" + file_digest(client["fmu"])
    for m in doc.get("moorings", []):
        if "file" in m:      # a MoorDyn input file
            m["file"] = "sha256:" + file_digest(m["file"])
    blob = json.dumps({"scene": doc, "solver": case.solver, "hydrolink": hydrolink_version(),
                       "case_file": {"format": CASE_FILE_FORMAT, "tail": case.tail}},
                      sort_keys=True, default=str)
    return hashlib.sha256(blob.encode()).hexdigest()[:20]
