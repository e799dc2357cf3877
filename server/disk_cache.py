"""hydrolink's on-disk caches: one folder per kind ("hdb", "state_space") under
``$XDG_CACHE_HOME/hydrolink`` (default ``~/.cache/hydrolink``), each overridable by an environment
variable naming the folder itself, and the atomic write every entry goes through."""

from __future__ import annotations

import os
import tempfile
from collections.abc import Callable
from pathlib import Path


def env_dir(name: str) -> Path | None:
    """The folder named by environment variable ``name`` (``~`` expanded), None when unset or empty."""
    value = os.environ.get(name)
    return Path(value).expanduser() if value else None


def user_cache_dir(kind: str) -> Path:
    """``$XDG_CACHE_HOME/hydrolink/<kind>``, else ``~/.cache/hydrolink/<kind>``."""
    base = os.environ.get("XDG_CACHE_HOME") or str(Path.home() / ".cache")
    return Path(base).expanduser() / "hydrolink" / kind


def write_atomic(path: Path, write: Callable[[str], None]) -> None:
    """Create ``path``'s folder, let ``write`` fill a temporary file beside it, then rename it to
    ``path`` (readers never see a partial entry; the temporary file is removed on failure)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.stem}.", suffix=f"{path.suffix}.tmp", dir=path.parent)
    os.close(fd)
    try:
        write(tmp)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
