"""TOML text validated by a pydantic model, with errors that name the file, the key and why.

Shared by the scene format (protocol/scene.py) and the HDB build spec (server/hdb/build/spec.py).
A validator may raise ``ValueError("key: why")``: an absolute key (its first part is one of the
model's top-level keys) replaces the location; any other key (or ``.key``) is relative to it.
Every problem is reported (up to MAX_PROBLEMS), each with its key; an unknown key gets the closest
valid key of its table ("did you mean").
"""

from __future__ import annotations

import difflib
import re
import tomllib
from pathlib import Path
from typing import Any, Callable, TypeVar, get_args

from pydantic import BaseModel, ValidationError

from hydrolink.protocol.codec import describe

M = TypeVar("M", bound=BaseModel)
_SKIP_PREFIXES = ("function-", "list[", "literal[", "union[")
MAX_PROBLEMS = 100   # listed in one error (a scene with more is garbage past the first hundred)
_KEY = re.compile(r"\.?[A-Za-z_][\w\[\]\.]*")


def _loc(loc: tuple, union_tags: tuple[str, ...], model: type[BaseModel] | None = None) -> str:
    """The dotted key of a pydantic error location: union branch tags and pydantic's own parts left
    out. A part that is a field of the tables reached so far is a key even where it is also a
    branch tag elsewhere (``components``: irregular waves' count, and the component list's tag)."""
    out = ""
    here = [model] if model is not None else []
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
            continue
        tagged = [c for c in here if "type" in c.model_fields and part in get_args(c.model_fields["type"].annotation)]
        if tagged and len(here) > 1:   # the branch of a union of tables
            here = tagged
            continue
        fields = [m for c in here if part in c.model_fields for m in models_in(c.model_fields[part].annotation)]
        is_field = any(part in c.model_fields for c in here)
        if not is_field and (part in union_tags or str(part).startswith(_SKIP_PREFIXES)
                             or part in ("float", "str", "int", "bool")):
            continue  # union branch tags and pydantic's own parts, not keys
        out += ("." if out else "") + str(part)
        here = fields if is_field else here   # not a field: a key of a dict of tables (the same tables hold)
    return out


def models_in(annotation: Any) -> list[type[BaseModel]]:
    """The pydantic models an annotation holds (through Annotated, unions, lists, dicts)."""
    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for arg in get_args(annotation) for m in models_in(arg)]


def _keys_at(model: type[BaseModel], loc: tuple) -> list[str]:
    """The valid keys of the table at ``loc`` (a pydantic error location, its last part the key)."""
    here = [model]
    for part in loc[:-1]:
        if isinstance(part, int):
            continue
        inner = [m for c in here if part in c.model_fields for m in models_in(c.model_fields[part].annotation)]
        tagged = [c for c in here if "type" in c.model_fields and part in get_args(c.model_fields["type"].annotation)]
        here = inner or tagged or here   # neither: a key of a dict of tables (the same tables hold)
    return sorted({k for c in here for k in c.model_fields})


def _problem(err: dict, model: type[BaseModel], union_tags: tuple[str, ...]) -> tuple[str, str]:
    """(key, why) of one pydantic error."""
    key, msg = _loc(err["loc"], union_tags, model), err["msg"]
    ctx = err.get("ctx") or {}
    if err["type"] == "extra_forbidden":
        msg = "unknown key"
        close = difflib.get_close_matches(str(err["loc"][-1]), _keys_at(model, err["loc"]), n=1, cutoff=0.6)
        if close:
            msg += f" (did you mean {close[0]!r}?)"
    elif err["type"] == "missing":
        msg = "required key is missing"
    elif err["type"] == "union_tag_invalid":
        key = f"{key}.type".lstrip(".")
        msg = f"must be one of {ctx['expected_tags']} (got {ctx['tag']!r})"
    elif "input" in err and not isinstance(err["input"], dict) and err["type"] != "value_error":
        msg = f"{msg} (got {describe(err['input'])})"
    if "why" in ctx:
        msg += f": {ctx['why']}"
    if msg.startswith("Value error, "):
        msg = msg[len("Value error, "):]
        head, _, rest = msg.partition(": ")
        if rest and _KEY.fullmatch(head):
            root = head.split("[")[0].split(".")[0]
            absolute = not head.startswith(".") and root in model.model_fields
            key = head if absolute else f"{key}.{head.lstrip('.')}".lstrip(".")
            msg = rest
    return key, msg


def read_toml_file(path: Path, error: Callable[[str | Path, str, str], Exception], what: str) -> str:
    """The text of the TOML file at ``path``; ``error(path, "", why)`` naming ``what`` (e.g. "the
    scene file") when it cannot be read."""
    try:
        return path.read_text()
    except OSError as exc:
        raise error(path, "", f"cannot read {what}: {exc.strerror}") from None


def parse_toml(text: str, source: str | Path, error: Callable[[str | Path, str, str], Exception]) -> dict:
    """The TOML document ``text`` as a dict; ``error(source, "", why)`` when it is not TOML. (The
    one TOML reader: scenes, build specs, grids and sweeps all come through it.)"""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(source, "", f"not valid TOML: {exc}") from None


def validate_toml(text: str, source: str | Path, model: type[M],
                  error: Callable[[str | Path, str, str], Exception],
                  union_tags: tuple[str, ...] = (),
                  more: Callable[[dict], list[tuple[str, str]]] | None = None) -> M:
    """Parse ``text`` and validate it as ``model``; raise ``error(source, key, why)`` naming the
    first problem's key, its ``why`` followed by one line "source: key: why" per further problem
    (every problem, up to MAX_PROBLEMS). ``more``: the document's further (key, why) problems the
    schema cannot see (e.g. files it names that do not exist), found on the parsed document and
    listed after the schema's own, in the same error."""
    raw = parse_toml(text, source, error)
    extra = more(raw) if more is not None else []
    try:
        result = model.model_validate(raw)
    except ValidationError as exc:
        errors = exc.errors()
        problems = [_problem(err, model, union_tags) for err in errors[:MAX_PROBLEMS]]
        raise _listed(problems + extra, len(errors) + len(extra), source, error) from None
    if extra:
        raise _listed(extra, len(extra), source, error)
    return result


def _listed(problems: list[tuple[str, str]], total: int, source: str | Path,
            error: Callable[[str | Path, str, str], Exception]) -> Exception:
    """One error naming the first problem's key, one line "source: key: why" per further problem."""
    problems = problems[:MAX_PROBLEMS]
    (key, why), rest = problems[0], problems[1:]
    lines = [f"\n{source}: {k}: {w}" if k else f"\n{source}: {w}" for k, w in rest]
    if total > len(problems):
        lines.append(f"\n{source}: and {total - len(problems)} more problems")
    return error(source, key, why + "".join(lines))
