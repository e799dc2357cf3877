"""An HDB sent as its original files (SPEC §5.1 "HDB file set"): check the set, resolve each file's
content (inline bytes, or a SHA-256 the server's store holds), and read it with the same readers a
client uses on its own disk (:func:`hydrolink.server.hdb.io.load_hdb`), in a child process with time
and memory limits (server/hdb/isolated.py: the bytes are a stranger's).

The files are written under their client-given names into a fresh temporary folder only for the
reader; a name is a plain file name (no folder, no leading dot), so nothing lands outside it. A
read HDB is kept (a few, least recently used out) under the digests of its files, so a second
session on the same contents neither uploads nor parses anything.
"""

from __future__ import annotations

import json
import re
import tempfile
import threading
from collections import OrderedDict
from dataclasses import dataclass
from pathlib import Path

import xarray as xr

from hydrolink.protocol import codec
from hydrolink.protocol.codec import Code, ProtocolError
from hydrolink.protocol.hdb.wire import FILE_FORMATS
from hydrolink.server.hdb.isolated import PARSE_TIMEOUT, ParseFailure, load_isolated
from hydrolink.protocol.hdb.layout import WARNINGS_ATTR, HDBError, hdb_warnings
from hydrolink.server.hdb.wamit.reader import WAMIT_SUFFIXES
from hydrolink.server.processes import start_children
from hydrolink.server.hdb.store import HASH, ContentStore

MAX_FILES = 16
FILE_NAME = re.compile(r"[A-Za-z0-9_-][A-Za-z0-9._-]{0,127}")
PARSED_KEEP = 8              # read HDBs kept in memory by their files' digests ...
PARSED_BYTES = 512 * 2**20   # ... and their arrays at most this many bytes together
MAIN_SUFFIXES = {"wamit": (".1",), "bemio": (".h5", ".hdf5"), "netcdf": (".nc",)}   # the file a reader opens


class MissingContent(ProtocolError):
    """Error 13 ``missing_content``: file contents named by a hash the store lacks (``missing``)."""

    def __init__(self, field: str, missing: list[str]):
        super().__init__(Code.MISSING_CONTENT, field,
                         f"the server's HDB store lacks {len(missing)} content(s) named by SHA-256: upload "
                         "them (SPEC §5.8) and send hello again", extra={"missing": missing})


@dataclass(frozen=True)
class FileSet:
    """A checked HDB file set: the format, each file's name and digest, the reader's options."""

    format: str
    files: tuple[tuple[str, str], ...]   # (name, sha256), in the client's order
    main: str                            # the file the reader opens (.1, .h5, .nc)
    rho: float | None


def is_file_set(entry: object) -> bool:
    """Whether an ``hdbs`` entry is a file set (it has ``format``) rather than an HDB map."""
    return isinstance(entry, dict) and "format" in entry


def check_file_set(entry: dict, where: str, store: ContentStore) -> tuple[FileSet, dict[str, bytes]]:
    """Validate a file set and store its inline contents; returns it and the inline bytes by
    digest. ProtocolError 5 naming the field; MissingContent when referred contents are absent."""
    fmt = codec.require_str(entry, "format", path=f"{where}.format")
    if fmt not in FILE_FORMATS:
        raise ProtocolError(Code.BAD_VALUE, f"{where}.format", f"must be one of {list(FILE_FORMATS)}, "
                            f"got {codec.describe(fmt)}")
    files = codec.require_map(entry, "files", path=f"{where}.files")
    if not 1 <= len(files) <= MAX_FILES:
        raise ProtocolError(Code.BAD_VALUE, f"{where}.files", f"holds {len(files)} files; 1 to {MAX_FILES}")
    rho = entry.get("rho")
    if rho is not None:
        rho = codec.require_float(entry, "rho", path=f"{where}.rho")
        if fmt != "wamit":
            raise ProtocolError(Code.BAD_VALUE, f"{where}.rho", "only for WAMIT files (nondimensional); "
                                "BEMIO and NetCDF files carry their own rho")
    named, inline = [], {}
    for name, value in files.items():
        at = codec.key_path(f"{where}.files", name)
        if not isinstance(name, str) or not FILE_NAME.fullmatch(name) or name in (".", ".."):
            raise ProtocolError(Code.BAD_VALUE, at, "a file name is 1 to 128 of A-Z a-z 0-9 . _ - (no folder, "
                                f"not starting with a dot), got {codec.describe(name)}")
        if isinstance(value, (bytes, bytearray, memoryview)):
            try:
                digest, _ = store.put(bytes(value))
            except ValueError as exc:
                raise ProtocolError(Code.BAD_VALUE, at, str(exc)) from None
            inline[digest] = bytes(value)
        elif isinstance(value, str) and HASH.fullmatch(value):
            digest = value
        else:
            raise ProtocolError(Code.BAD_VALUE, at, "must be the file's bytes (bin) or the lowercase hex SHA-256 "
                                f"of its bytes (64 characters), got {codec.describe(value)}")
        named.append((name, digest))
    missing = store.missing([d for _, d in named])
    if missing:
        raise MissingContent(f"{where}.files", missing)
    suffixes = MAIN_SUFFIXES[fmt]
    alone = fmt == "wamit" and not any(n.lower().endswith(".1") for n, _ in named)
    if alone:
        suffixes = (".out",)      # a run known by its report alone (server/hdb/wamit/out_tables.py)
    mains = [n for n, _ in named if n.lower().endswith(suffixes)]
    if len(mains) != 1:
        what = "one .1 file (or, for a run known by its report alone, one .out)" if alone else \
            f"one {'/'.join(suffixes)} file"
        raise ProtocolError(Code.BAD_VALUE, f"{where}.files", f"a {fmt} file set holds exactly {what}, got "
                            f"{mains or 'none'}")
    if fmt == "wamit":
        stem = mains[0][:-len(suffixes[0])]
        strays = [n for n, _ in named if not any(n == stem + s for s in WAMIT_SUFFIXES)]
        if strays:
            raise ProtocolError(Code.BAD_VALUE, f"{where}.files", f"the WAMIT files of run {stem!r} are "
                                f"{stem}{{{','.join(WAMIT_SUFFIXES)}}}; not {strays}")
    elif len(named) != 1:
        raise ProtocolError(Code.BAD_VALUE, f"{where}.files", f"a {fmt} file set is one file, got {len(named)}")
    return FileSet(fmt, tuple(named), mains[0], rho), inline


class FileSetReader:
    """Reads file sets from a store, keeping the last few read HDBs by their contents' digests."""

    def __init__(self, store: ContentStore, parse_timeout: float = PARSE_TIMEOUT):
        """``parse_timeout``: seconds a file set's parse may take (server/hdb/isolated.py)."""
        self.store = store
        self.parse_timeout = parse_timeout
        self._parsed: OrderedDict[tuple, xr.Dataset] = OrderedDict()
        self._lock = threading.Lock()   # hellos are set up in worker threads (server/service/setup_workers.py)

    def read(self, entry: dict, where: str, convention: str | None, wamit: dict | None = None) -> xr.Dataset:
        """The HDB of a file-set ``hdbs`` entry; ProtocolError 5/13 for the set, 9 for the files.
        ``wamit``: the scene's statement for a WAMIT run (``Scene.wamit_statement``)."""
        start_children()   # the parse's forkserver imports while the set is checked (and its missing files come)
        fs, inline = check_file_set(entry, where, self.store)
        stated = repr(sorted((k, v) for k, v in (wamit or {}).items()     # other formats: without excitation_needed
                             if fs.format == "wamit" or k != "excitation_needed"))   # (any other key is refused)
        key = (fs.format, tuple(sorted(fs.files)), fs.rho, convention, stated)
        with self._lock:
            ds = self._parsed.get(key)
            if ds is not None:
                self._parsed.move_to_end(key)
                return ds
        with tempfile.TemporaryDirectory(prefix="hydrolink-hdb-") as tmp:
            for name, digest in fs.files:
                data = inline.get(digest)
                if data is None:
                    data = self.store.get(digest)
                if data is None:   # evicted between the check and now
                    raise MissingContent(f"{where}.files", [digest])
                (Path(tmp) / name).write_bytes(data)
            main = fs.main
            try:   # untrusted bytes: parsed in a child process with time and memory limits
                ds = load_isolated(Path(tmp) / main, timeout=self.parse_timeout, rho=fs.rho,
                                   convention=convention if fs.format == "netcdf" else None, wamit=wamit)
            except ParseFailure as exc:
                raise ProtocolError(Code.BAD_HDB, codec.key_path(f"{where}.files", main),
                                    f"{main}: not a readable {fs.format} file: {exc.why}") from None
            except HDBError as exc:
                name = Path(str(exc.source)).name if exc.source else main
                at = codec.key_path(f"{where}.files", name if name in dict(fs.files) else main)
                raise ProtocolError(Code.BAD_HDB, f"{at}.{exc.field}" if exc.field else at,
                                    str(exc).replace(tmp + "/", "")) from None
            except (OSError, ValueError, KeyError) as exc:   # a reader's own failure on corrupt bytes
                raise ProtocolError(Code.BAD_HDB, codec.key_path(f"{where}.files", main),
                                    f"not a readable {fs.format} file: {type(exc).__name__}: "
                                    f"{str(exc).replace(tmp + '/', '')}") from None
            notes = hdb_warnings(ds)   # they name the files as the client did, not by the folder here
            if notes:
                ds.attrs[WARNINGS_ATTR] = json.dumps([n.replace(tmp + "/", "") for n in notes])
        ds.attrs["source"] = f"{main} (sha256 {dict(fs.files)[main][:12]})"
        with self._lock:
            if ds.nbytes <= PARSED_BYTES:
                self._parsed[key] = ds
            while len(self._parsed) > PARSED_KEEP or sum(d.nbytes for d in self._parsed.values()) > PARSED_BYTES:
                self._parsed.popitem(last=False)
        return ds

