"""HDB files from strangers, parsed where a hang or a crash can be killed: one child process per
parse, with a time limit and an address-space limit (issue 35 item 7).

A server reads the files a client sends by hash (SPEC §5.8) with the same readers a client uses on
its own disk, but the bytes are untrusted: a corrupt NetCDF file can make the netCDF library spin
forever, a WAMIT ``.1`` whose mode index is 99999 asks for terabytes, a malformed HDF5 file raises
from deep inside h5py. In the server's own process the first would hold a set-up worker for ever,
the second a gigabytes-long allocation, the third an internal error. Here the reader runs in a
child (a fork of a forkserver that has already imported the readers, so a parse costs a fork, not
an interpreter start): the child sends back the dataset or the error; the parent waits at most
``timeout`` seconds of the child's CPU from the moment it starts reading (the kernel's CPU limit
stops a reader that spins; a reader that blocks without using CPU is stopped after
:data:`WALL_FACTOR` times as many seconds of wall clock), so a loaded machine, where a parse waits for
a core, does not refuse a good file. The forkserver's own start — its imports, tens of seconds on a
loaded machine — and the fork are the server's, not the file's: they get :data:`START_TIMEOUT`.
Every outcome is a :class:`ParseFailure` naming the file and why, or the reader's own
:class:`~hydrolink.protocol.hdb.layout.HDBError`.
"""

from __future__ import annotations

import math
import resource
import signal
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
WALL_FACTOR = 10.0             # a parse's wall-clock bound, in multiples of its CPU bound (a reader that blocks)
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


def _limit(which: int, value: int) -> None:
    """Lower the resource limit ``which`` to ``value`` (never above its hard limit); a platform
    without it: the other limits still hold."""
    try:
        soft, hard = resource.getrlimit(which)
        limit = value if hard == resource.RLIM_INFINITY else min(value, hard)
        resource.setrlimit(which, (limit, hard))
    except (ValueError, OSError):
        pass


def _parse(conn: Connection, path: str, kwargs: dict, memory: int, cpu_seconds: float) -> None:
    """In the child: read ``path`` under the address-space and CPU limits; send ("ok", (dataset, CPU
    seconds the read took)) or the error."""
    _limit(resource.RLIMIT_AS, memory)
    try:
        from hydrolink.server.hdb.io import load_hdb

        # the kernel stops the child (SIGXCPU) a second past the parse's CPU bound
        _limit(resource.RLIMIT_CPU, math.ceil(time.process_time() + cpu_seconds) + 1)
        conn.send(("started", None))
        t0 = time.process_time()
        ds = load_hdb(path, **kwargs).load()
        conn.send(("ok", (ds, time.process_time() - t0)))
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


def _receive(receive: Connection, proc, timeout: float, late: str, over_cpu: str | None = None) -> tuple[str, Any]:
    """The child's next message within ``timeout`` s, else ParseFailure(``late``); a child that died
    first is ParseFailure too (``over_cpu`` if the kernel stopped it at its CPU limit)."""
    if not receive.poll(timeout):
        raise ParseFailure(late)
    try:
        return receive.recv()
    except (EOFError, OSError):
        proc.join(5.0)
        if proc.exitcode == -signal.SIGXCPU and over_cpu is not None:
            raise ParseFailure(over_cpu) from None
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
    proc = ctx.Process(target=_parse, args=(send, str(path), kwargs, memory, timeout), daemon=True,
                       name="hydrolink-hdb-parse")
    proc.start()
    send.close()
    try:
        status, payload = _receive(receive, proc, START_TIMEOUT,
                                   f"the reading process did not start within {START_TIMEOUT:g} s (stopped)")
        if status == "started":
            late = f"reading it took longer than {timeout:g} s of CPU (stopped)"
            status, payload = _receive(receive, proc, WALL_FACTOR * timeout,
                                       f"reading it took longer than {WALL_FACTOR * timeout:g} s (stopped)", late)
            if status == "ok":
                payload, cpu = payload
                if cpu > timeout:     # the answer came, but over the bound: the limit is the limit
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
