"""hydrolink's on-disk caches: one folder per kind ("hdb", "state_space") under
``$XDG_CACHE_HOME/hydrolink`` (default ``~/.cache/hydrolink``), each overridable by an environment
variable naming the folder itself, and the atomic write every entry goes through."""

from __future__ import annotations

import os
import secrets
import stat
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


def _create_beside(path: Path) -> tuple[str, int]:
    """A new empty file beside ``path`` (hidden, unique name), created as ``open()`` creates files:
    mode 0666 less the process's umask. Returns its name and that mode (read back, so the umask is
    never changed, not even for a moment)."""
    while True:
        tmp = str(path.parent / f".{path.stem}.{secrets.token_hex(6)}{path.suffix}.tmp")
        try:
            fd = os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o666)
        except FileExistsError:
            continue
        try:
            return tmp, stat.S_IMODE(os.fstat(fd).st_mode)
        finally:
            os.close(fd)


def write_atomic(path: Path, write: Callable[[str], None]) -> None:
    """Create ``path``'s folder, let ``write`` fill a temporary file beside it, then rename it to
    ``path`` (readers never see a partial entry; the temporary file is removed on failure). The
    file gets the mode any file the user creates gets (0666 less the umask), whatever ``write`` did
    to the temporary file (a writer may delete and recreate it)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    tmp, mode = _create_beside(path)
    try:
        write(tmp)
        os.chmod(tmp, mode)
        os.replace(tmp, path)
    finally:
        if os.path.exists(tmp):
            os.unlink(tmp)
