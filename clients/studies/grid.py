"""Grids of scene keys: the one grid format of ``hydrolink bench accuracy`` and ``hydrolink sweep``.

A grid names scene keys by their dotted path (``waves.hs``, ``simulation.dt``) or a short alias
(``dt``, ``radiation``: :data:`ALIASES`). Entries of the scene's arrays of tables are named by their
``name`` (``ptos.pto.damping``, ``bodies.float.mass``) or, for unnamed entries, their index
(``joints.0.friction``). Combinations (``mode``):

- ``product``: every combination of the grid's values;
- ``zip``: the i-th values of every key together (all lists of one length);
- ``axes``: one key varied at a time, the other keys left as they are (the scene's, or a reference).

Explicit ``[[cases]]`` (a set of keys each, an optional ``label``) are added to the combinations.
This module also holds the scene-document helpers both commands use: reading and writing keys,
TOML text of a document, and relative paths made absolute.
"""

from __future__ import annotations

import itertools
import json
import math
from pathlib import Path
from typing import Any, Literal, Union

from pydantic import BaseModel, ConfigDict, field_validator, model_validator

from hydrolink.protocol.errors import KeyedError

ALIASES = {
    "dt": "simulation.dt",
    "duration": "simulation.duration",
    "irf_duration": "hydro.irf_duration",
    "irf_taper": "hydro.irf_taper",
    "radiation": "hydro.radiation",
    "ss_tolerance": "hydro.ss_tolerance",
    "excitation": "waves.excitation",
    "excitation_irf_duration": "waves.excitation_irf_duration",
    "coupling": "coupling.scheme",
    "exchange_every": "coupling.exchange_every",
    "between_exchanges": "coupling.between_exchanges",
    "reduce": "client.reduce",
    "nonlinear": "hydro.nonlinear",
}
SHORT = {v: k for k, v in ALIASES.items()}
GridMode = Literal["product", "zip", "axes"]
Value = Union[bool, int, float, str, list, dict]


class GridError(KeyedError):
    """A grid or scene key that cannot be used; the message names the file, the key and why."""


def full_key(key: str) -> str:
    """The dotted scene key of ``key`` (an alias resolved)."""
    return ALIASES.get(key, key)


def short_key(key: str) -> str:
    """The alias of a dotted scene key, if it has one."""
    return SHORT.get(key, key)


def quoted(key: str) -> str:
    """A key as TOML writes it inside a table: bare when it can be, else quoted ("waves.hs")."""
    return key if key.replace("_", "").replace("-", "").isalnum() else json.dumps(key)


class GridSpec(BaseModel):
    """The grid part of a grid file: ``mode``, ``[grid]`` (key -> non-empty list of values) and
    ``[[cases]]`` (key -> value, optional ``label``)."""
    model_config = ConfigDict(extra="forbid")
    mode: GridMode = "product"
    grid: dict[str, list[Value]] = {}
    cases: list[dict[str, Value]] = []

    @field_validator("grid", mode="before")
    @classmethod
    def _non_empty(cls, grid):
        for key, values in (grid or {}).items():
            if not isinstance(values, list) or not values:
                raise ValueError(f"grid.{quoted(key)}: a non-empty list of values (got {values!r})")
        return grid

    @field_validator("cases")
    @classmethod
    def _labels(cls, cases: list[dict]) -> list[dict]:
        for i, case in enumerate(cases):
            if "label" in case and not isinstance(case["label"], str):
                raise ValueError(f"cases[{i}].label: a string")
            if not [k for k in case if k != "label"]:
                raise ValueError(f"cases[{i}]: sets no key")
        return cases

    @model_validator(mode="after")
    def _zip_lengths(self) -> "GridSpec":
        if self.mode == "zip" and self.grid:
            first, n = next(iter(self.grid.items()))[0], len(next(iter(self.grid.values())))
            for key, values in self.grid.items():
                if len(values) != n:
                    raise ValueError(f"grid.{quoted(key)}: mode = \"zip\" needs lists of one length "
                                     f"({len(values)} values, {quoted(first)} has {n})")
        return self

    def combinations(self) -> list[dict[str, Any]]:
        """The grid's combinations in ``mode`` (keys as written), explicit cases not included."""
        return combinations(self.grid, self.mode)

    def keys(self) -> list[str]:
        """Every key of the grid and the cases, in order of appearance (as written)."""
        keys = list(self.grid) + [k for c in self.cases for k in c if k != "label"]
        return list(dict.fromkeys(keys))


def combinations(grid: dict[str, list], mode: str) -> list[dict[str, Any]]:
    """Key -> value dicts of a grid: every combination (product), the i-th values together (zip),
    or one key at a time (axes)."""
    if not grid:
        return []
    keys = list(grid)
    if mode == "product":
        return [dict(zip(keys, combo)) for combo in itertools.product(*(grid[k] for k in keys))]
    if mode == "zip":
        return [dict(zip(keys, combo)) for combo in zip(*(grid[k] for k in keys))]
    if mode == "axes":
        return [{k: v} for k in keys for v in grid[k]]
    raise ValueError(f"mode: \"product\", \"zip\" or \"axes\" (got {mode!r})")


# ------------------------------------------------------------------ scene documents

def _entry(items: list, part: str, path: str):
    """The entry of an array of tables named ``part`` (its ``name``), else at index ``part``."""
    for item in items:
        if isinstance(item, dict) and item.get("name") == part:
            return item
    if part.isdigit() and int(part) < len(items):
        return items[int(part)]
    names = [item.get("name") for item in items if isinstance(item, dict) and item.get("name")]
    raise KeyError(f"no {path} entry named {part!r} (known: {names})" if names
                   else f"no {path} entry {part!r} ({len(items)} entries, unnamed: use an index)")


def get_key(doc: dict, dotted: str, default=None):
    """A key's value written in a scene document (arrays of tables by entry name), else ``default``."""
    cur: Any = doc
    for part in dotted.split("."):
        if isinstance(cur, list):
            try:
                cur = _entry(cur, part, "")
            except KeyError:
                return default
        elif isinstance(cur, dict) and part in cur:
            cur = cur[part]
        else:
            return default
    return cur


def set_key(doc: dict, dotted: str, value) -> None:
    """Write a key into a scene document: missing tables are created, entries of arrays of tables
    are found by name (or index); KeyError naming the part that does not exist."""
    parts = dotted.split(".")
    cur: Any = doc
    for i, part in enumerate(parts[:-1]):
        where = ".".join(parts[:i + 1])
        if isinstance(cur, list):
            cur = _entry(cur, part, ".".join(parts[:i]))
        else:
            cur = cur.setdefault(part, {})
        if not isinstance(cur, (dict, list)):
            raise KeyError(f"{where} is a value, not a table")
    if isinstance(cur, list):
        raise KeyError(f"{'.'.join(parts[:-1])} is an array of tables: name an entry "
                       f"({'.'.join(parts[:-1])}.<name>.{parts[-1]})")
    cur[parts[-1]] = value


def scene_location(doc: dict, dotted: str) -> str:
    """Where a key sits in the scene's own error messages: ``ptos.pto.damping`` -> ``ptos[0].damping``."""
    out, cur = [], doc
    for part in dotted.split("."):
        if isinstance(cur, list):
            idx = next((i for i, x in enumerate(cur) if isinstance(x, dict) and x.get("name") == part), None)
            if idx is None and part.isdigit():
                idx = int(part)
            if idx is None or idx >= len(cur):
                return dotted
            out[-1] += f"[{idx}]"
            cur = cur[idx]
        else:
            out.append(part)
            cur = cur.get(part, {}) if isinstance(cur, dict) else {}
    return ".".join(out)


def _toml_value(v) -> str:
    if isinstance(v, bool):
        return "true" if v else "false"
    if isinstance(v, int):
        return str(v)
    if isinstance(v, float):
        if math.isnan(v):
            return "nan"
        if math.isinf(v):
            return "inf" if v > 0 else "-inf"
        return repr(v)
    if isinstance(v, str):
        return json.dumps(v)
    if isinstance(v, (list, tuple)):
        return "[" + ", ".join(_toml_value(x) for x in v) + "]"
    if isinstance(v, dict):
        return "{" + ", ".join(f"{json.dumps(k)} = {_toml_value(x)}" for k, x in v.items()) + "}"
    raise ValueError(f"cannot write {v!r} to TOML")


def dump_toml(doc: dict) -> str:
    """TOML text of a scene document: top-level tables as [sections], lists of tables as [[...]],
    deeper tables inline."""
    out: list[str] = []
    for k, v in doc.items():  # plain top-level keys first
        if not isinstance(v, dict) and not (isinstance(v, list) and v and all(isinstance(x, dict) for x in v)):
            out.append(f"{json.dumps(k)} = {_toml_value(v)}")
    for k, v in doc.items():
        if isinstance(v, dict):
            out.append(f"\n[{k}]")
            out += [f"{json.dumps(kk)} = {_toml_value(vv)}" for kk, vv in v.items()]
        elif isinstance(v, list) and v and all(isinstance(x, dict) for x in v):
            for item in v:
                out.append(f"\n[[{k}]]")
                out += [f"{json.dumps(kk)} = {_toml_value(vv)}" for kk, vv in item.items()]
    return "\n".join(out) + "\n"


def absolute_paths(doc: dict, scene_path: Path) -> dict:
    """The scene document with its relative file paths (bodies[i].hdb, bodies[i].mesh,
    bodies[i].qtf.difference/sum, bodies[i].modes.mmx/shapes, waves.file, client.fmu,
    moorings[i].file) made absolute, so that it runs from any folder."""
    base = Path(scene_path).resolve().parent

    def fix(p: str) -> str:
        q = Path(p).expanduser()
        return str(q if q.is_absolute() else (base / q).resolve())
    for b in doc.get("bodies", []):
        for key in ("hdb", "mesh"):
            if key in b:
                b[key] = fix(b[key])
        for table, keys in (("qtf", ("difference", "sum")), ("modes", ("mmx", "shapes"))):
            if isinstance(b.get(table), dict):
                for key in keys:
                    if key in b[table]:
                        b[table][key] = fix(b[table][key])
    if isinstance(doc.get("waves"), dict) and "file" in doc["waves"]:
        doc["waves"]["file"] = fix(doc["waves"]["file"])
    if isinstance(doc.get("client"), dict) and "fmu" in doc["client"]:
        doc["client"]["fmu"] = fix(doc["client"]["fmu"])
    for m in doc.get("moorings", []):
        if "file" in m:
            m["file"] = fix(m["file"])
    return doc


def effective_value(scene, dotted: str):
    """A key's value in a validated scene (written or the format's default), None if it does not
    apply (e.g. waves.hs of regular waves)."""
    cur: Any = scene
    for part in dotted.split("."):
        if isinstance(cur, list):
            hit = [x for x in cur if getattr(x, "name", None) == part]
            if hit:
                cur = hit[0]
            elif part.isdigit() and int(part) < len(cur):
                cur = cur[int(part)]
            else:
                return None
        else:
            cur = getattr(cur, part, None)
        if cur is None:
            return None
    if isinstance(cur, BaseModel):
        return cur.model_dump()
    return cur
