"""TOML text validated by a pydantic model, with errors that name the file, the key and why.

Shared by the scene format (protocol/scene.py) and the HDB build spec (server/hdb/build_spec.py).
A validator may raise ``ValueError("key: why")``: an absolute key (its first part is one of the
model's top-level keys) replaces the location; any other key (or ``.key``) is relative to it.
"""

from __future__ import annotations

import re
import sys
from pathlib import Path
from typing import Callable, TypeVar

from pydantic import BaseModel, ValidationError

if sys.version_info >= (3, 11):
    import tomllib
else:  # pragma: no cover
    import tomli as tomllib

M = TypeVar("M", bound=BaseModel)
_SKIP_PREFIXES = ("function-", "list[", "literal[", "union[")
_KEY = re.compile(r"\.?[A-Za-z_][\w\[\]\.]*")


def _loc(loc: tuple, union_tags: tuple[str, ...]) -> str:
    out = ""
    for part in loc:
        if isinstance(part, int):
            out += f"[{part}]"
        elif part in union_tags or str(part).startswith(_SKIP_PREFIXES) or part in ("float", "str"):
            continue  # union branch tags, not keys
        else:
            out += ("." if out else "") + str(part)
    return out


def parse_toml(text: str, source: str | Path, error: Callable[[str | Path, str, str], Exception]) -> dict:
    """The TOML document ``text`` as a dict; ``error(source, "", why)`` when it is not TOML. (The
    one TOML reader: scenes, build specs, grids and sweeps all come through it.)"""
    try:
        return tomllib.loads(text)
    except tomllib.TOMLDecodeError as exc:
        raise error(source, "", f"not valid TOML: {exc}") from None


def validate_toml(text: str, source: str | Path, model: type[M],
                  error: Callable[[str | Path, str, str], Exception],
                  union_tags: tuple[str, ...] = ()) -> M:
    """Parse ``text`` and validate it as ``model``; raise ``error(source, key, why)`` on the first problem."""
    raw = parse_toml(text, source, error)
    try:
        return model.model_validate(raw)
    except ValidationError as exc:
        err = exc.errors()[0]
        key, msg = _loc(err["loc"], union_tags), err["msg"]
        if err["type"] == "extra_forbidden":
            msg = "unknown key"
        elif err["type"] == "missing":
            msg = "required key is missing"
        elif err["type"] == "union_tag_invalid":
            key = f"{key}.type".lstrip(".")
            msg = f"must be one of {err['ctx']['expected_tags']} (got {err['ctx']['tag']!r})"
        elif "input" in err and not isinstance(err["input"], dict) and err["type"] != "value_error":
            msg = f"{msg} (got {err['input']!r})"
        if msg.startswith("Value error, "):
            msg = msg[len("Value error, "):]
            head, _, rest = msg.partition(": ")
            if rest and _KEY.fullmatch(head):
                root = head.split("[")[0].split(".")[0]
                absolute = not head.startswith(".") and root in model.model_fields
                key = head if absolute else f"{key}.{head.lstrip('.')}".lstrip(".")
                msg = rest
        more = f" (and {len(exc.errors()) - 1} more problem(s))" if len(exc.errors()) > 1 else ""
        raise error(source, key, msg + more) from None
