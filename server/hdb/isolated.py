"""HDB files from strangers, parsed where a hang or a crash can be killed: one child process per
parse, with a time limit and an address-space limit (issue 35 item 7).

A server reads the files a client sends by hash (SPEC §5.8) with the same readers a client uses on
its own disk, but the bytes are untrusted: a corrupt NetCDF file can make the netCDF library spin
forever, a WAMIT ``.1`` whose mode index is 99999 asks for terabytes, a malformed HDF5 file raises
from deep inside h5py. In the server's own process the first would hold a set-up worker for ever,
the second a gigabytes-long allocation, the third an internal error. Here the reader runs in a
child (a fork of a forkserver that has already imported the readers, so a parse costs a fork, not
an interpreter start): the child sends back the dataset or the error; the parent waits at most
``timeout`` seconds from the moment the child starts reading (the forkserver's own start — its
imports, tens of seconds on a loaded machine — and the fork are the server's, not the file's: they
get :data:`START_TIMEOUT`), then kills it. Every outcome is a :class:`ParseFailure` naming the file and
why, or the reader's own :class:`~hydrolink.protocol.hdb.layout.HDBError`.
"""

from __future__ import annotations

import resource
import time
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any

import xarray as xr

from hydrolink.protocol.hdb.layout import HDBError
from hydrolink.server.processes import children

__all__ = ["PARSE_TIMEOUT", "ParseFailure", "load_isolated", "memory_limit"]

PARSE_TIMEOUT = 20.0           # s a parse may take (a real HDB takes well under a second or two)
START_TIMEOUT = 300.0          # s the child may take to start (the forkserver's first start imports the readers)
BASE_MEMORY = 2 * 2**30        # bytes of address space the child may use beyond the files' size ...
PER_FILE_BYTE = 64             # ... plus this many per byte of the files (decoded arrays, copies)
MAX_MEMORY = 16 * 2**30



class ParseFailure(Exception):
    """The child could not parse the file: ``why`` says how (timeout, memory, crash, exception)."""

    def __init__(self, why: str):
        super().__init__(why)
        self.why = why


def memory_limit(files_bytes: int) -> int:
    """The address space a parse of files totalling ``files_bytes`` may use (bytes)."""
    return min(MAX_MEMORY, BASE_MEMORY + PER_FILE_BYTE * int(files_bytes))


def _parse(conn: Connection, path: str, kwargs: dict, memory: int) -> None:
    """In the child: read ``path`` under the address-space limit; send ("ok", dataset) or the error."""
    try:
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        limit = memory if hard == resource.RLIM_INFINITY else min(memory, hard)
        resource.setrlimit(resource.RLIMIT_AS, (limit, hard))
    except (ValueError, OSError):   # a platform without it: the time limit still holds
        pass
    try:
        from hydrolink.server.hdb.io import load_hdb

        conn.send(("started", None))
        ds = load_hdb(path, **kwargs).load()
        conn.send(("ok", ds))
    except HDBError as exc:
        conn.send(("hdb", (str(exc.source), exc.key, exc.why)))
    except MemoryError:
        conn.send(("failed", f"the reader needed more than {memory / 2**30:.1f} GiB of memory (sizes in the "
                             "file far beyond its own length?)"))
    except BaseException as exc:  # noqa: BLE001 - whatever a corrupt file makes a reader raise, named
        try:
            conn.send(("failed", f"the reader failed: {type(exc).__name__}: {exc}"))
        except BaseException:  # noqa: BLE001 - e.g. a message too large to pickle under the limit
            pass
    finally:
        conn.close()


def _receive(receive: Connection, proc, timeout: float, late: str) -> tuple[str, Any]:
    """The child's next message within ``timeout`` s, else ParseFailure(``late``); a child that died
    first is ParseFailure too."""
    if not receive.poll(timeout):
        raise ParseFailure(late)
    try:
        return receive.recv()
    except (EOFError, OSError):
        proc.join(5.0)
        raise ParseFailure(f"the reader died (exit code {proc.exitcode})") from None


def load_isolated(path: str | Path, *, timeout: float = PARSE_TIMEOUT, **kwargs: Any) -> xr.Dataset:
    """:func:`hydrolink.server.hdb.io.load_hdb` (``kwargs``) of ``path`` in a child process: the
    dataset, or HDBError as the reader raised it, or ParseFailure (the time or memory limit, a crash,
    any other exception of the reader). The child is gone when this returns."""
    path = Path(path)
    files_bytes = sum(p.stat().st_size for p in path.parent.iterdir() if p.is_file())
    memory = memory_limit(files_bytes)
    ctx = children()
    receive, send = ctx.Pipe(duplex=False)
    proc = ctx.Process(target=_parse, args=(send, str(path), kwargs, memory), daemon=True,
                       name="hydrolink-hdb-parse")
    proc.start()
    send.close()
    try:
        status, payload = _receive(receive, proc, START_TIMEOUT,
                                   f"the reading process did not start within {START_TIMEOUT:g} s (stopped)")
        if status == "started":
            late = f"reading it took longer than {timeout:g} s (stopped)"
            started = time.monotonic()
            status, payload = _receive(receive, proc, timeout, late)
            if time.monotonic() - started > timeout:     # the answer came, but late: the limit is the limit
                raise ParseFailure(late)
    finally:
        receive.close()
        if proc.is_alive():
            proc.kill()
        proc.join(5.0)
    if status == "ok":
        return payload
    if status == "hdb":
        raise HDBError(*payload)
    raise ParseFailure(payload)
