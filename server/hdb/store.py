"""The server's content-addressed store of HDB file contents (SPEC §5.8): bytes by SHA-256.

A client names an HDB's files by the SHA-256 of their bytes; what the server holds it reads from
here, what it lacks the client uploads once (``upload``). Two tiers, both bounded and least
recently used first out: a memory tier (the contents in use) and a folder on disk (one file per
content, named by its hash and nothing else, so no client value ever becomes a path). Every
content is checked against its hash when it enters and when it is read back from disk. Thread-safe:
hellos are set up in worker threads while the server loop stores uploads.
"""

from __future__ import annotations

import hashlib
import logging
import os
import re
import threading
from collections import OrderedDict
from pathlib import Path

from hydrolink.server.disk_cache import env_dir, user_cache_dir, write_atomic

log = logging.getLogger("hydrolink.server")

HASH = re.compile(r"[0-9a-f]{64}")
DEFAULT_DISK_BYTES = 4 * 2**30      # what a server keeps on disk by default
DEFAULT_MEMORY_BYTES = 512 * 2**20  # and in memory


def default_folder() -> Path:
    """``$HYDROLINK_HDB_STORE``, else ``$HYDROLINK_CACHE/hdb_store``, else the user cache's ``hdb_store``."""
    shared = env_dir("HYDROLINK_CACHE")
    return env_dir("HYDROLINK_HDB_STORE") or (shared / "hdb_store" if shared else user_cache_dir("hdb_store"))


class ContentTooLarge(ValueError):
    """A content over the store's bound (``put``)."""


def sha256(data: bytes) -> str:
    """Lowercase hex SHA-256 of ``data`` (the name of a content on the wire and in the store)."""
    return hashlib.sha256(data).hexdigest()


class ContentStore:
    """Contents by SHA-256: ``put`` (checked), ``get`` (None when absent), ``missing``.

    ``folder`` None keeps contents in memory only. Sizes are bounds in bytes; a content larger
    than the disk bound is refused (ValueError) rather than evicting everything else."""

    def __init__(self, folder: str | Path | None, *, disk_bytes: int = DEFAULT_DISK_BYTES,
                 memory_bytes: int = DEFAULT_MEMORY_BYTES):
        self.folder = None if folder is None else Path(folder)
        self.disk_bytes = int(disk_bytes)
        self.memory_bytes = int(memory_bytes)
        self._memory: OrderedDict[str, bytes] = OrderedDict()
        self._memory_used = 0
        self._lock = threading.Lock()   # over the memory tier (the disk tier's writes are atomic)

    @property
    def max_content_bytes(self) -> int:
        """The largest content this store takes."""
        return self.disk_bytes if self.folder is not None else self.memory_bytes

    def _path(self, digest: str) -> Path:
        assert HASH.fullmatch(digest)  # the only way a name is made: a checked hex digest
        return self.folder / digest

    def has(self, digest: str) -> bool:
        """Whether the content is held (memory or disk); does not read it."""
        return digest in self._memory or (self.folder is not None and self._path(digest).is_file())

    def missing(self, digests: list[str]) -> list[str]:
        """The digests of ``digests`` this store does not hold, in their order, once each."""
        return [d for d in dict.fromkeys(digests) if not self.has(d)]

    def put(self, data: bytes, digest: str | None = None) -> tuple[str, bool]:
        """Store ``data``; returns (its digest, whether it was new). ContentTooLarge when the
        content is over the store's bound (checked first: nothing is hashed), ValueError when
        ``digest`` is given and does not match."""
        if len(data) > self.max_content_bytes:
            raise ContentTooLarge(f"{len(data)} bytes is over the store's bound of {self.max_content_bytes} bytes "
                                  "per content")
        actual = sha256(data)
        if digest is not None and digest != actual:
            raise ValueError(f"the content's SHA-256 is {actual}, not {digest} (corrupted or a wrong hash)")
        new = not self.has(actual)
        if new and self.folder is not None:
            write_atomic(self._path(actual), lambda tmp: Path(tmp).write_bytes(data))
            self._trim_disk()
        self._remember(actual, bytes(data))
        return actual, new

    def get(self, digest: str) -> bytes | None:
        """The content named ``digest`` (marked as recently used), or None when absent. A disk
        entry that no longer matches its name is removed and counts as absent."""
        with self._lock:
            data = self._memory.get(digest)
            if data is not None:
                self._memory.move_to_end(digest)
        if data is not None:
            if self.folder is not None:
                self._touch(digest)
            return data
        if self.folder is None:
            return None
        path = self._path(digest)
        try:
            data = path.read_bytes()
        except FileNotFoundError:
            return None
        if sha256(data) != digest:
            log.warning("HDB store: %s no longer matches its hash; removed", path)
            path.unlink(missing_ok=True)
            return None
        self._touch(digest)
        self._remember(digest, data)
        return data

    # ------------------------------------------------------------ bounds

    def _remember(self, digest: str, data: bytes) -> None:
        if len(data) > self.memory_bytes:
            return
        with self._lock:
            if digest in self._memory:
                self._memory.move_to_end(digest)
                return
            self._memory[digest] = data
            self._memory_used += len(data)
            while self._memory_used > self.memory_bytes:
                _, old = self._memory.popitem(last=False)
                self._memory_used -= len(old)

    def _touch(self, digest: str) -> None:
        try:
            os.utime(self._path(digest))
        except FileNotFoundError:
            pass

    def _trim_disk(self) -> None:
        """Remove the least recently used disk entries until the folder is within its bound."""
        entries = []
        for path in self.folder.iterdir():
            if HASH.fullmatch(path.name):
                try:
                    st = path.stat()
                except FileNotFoundError:
                    continue
                entries.append((st.st_mtime, st.st_size, path))
        used = sum(size for _, size, _ in entries)
        for _, size, path in sorted(entries, key=lambda e: e[0]):
            if used <= self.disk_bytes:
                break
            path.unlink(missing_ok=True)   # (a copy in the memory tier stays usable)
            used -= size
