"""The server's child processes come from one forkserver, shared by the HDB parses
(server/hdb/isolated.py) and the session workers (server/service/step_worker.py): a fork of a
process that has imported the readers and the model once, so a child costs a fork, not an import.

It is started when a child is first needed, ahead of the child when it can be told to come
(:func:`start_children`, which does not wait for its imports): at an ``upload`` (a file-set hello
follows) and at a hello holding a file set (its missing files are uploaded, or its parse comes next).
``hydrolink serve`` also starts it WARM_CHILDREN_S after its loop started, once no set-up runs
(ForceServer ``children_after_s``): its imports (about 2 s of CPU, 2-4 s of wall clock at load 7)
do not compete with the server's start and first hellos, a serve that lives less never pays
them, and a long-lived server parses a stranger's first file set without waiting for
them (its 10 s goal; started at the upload instead, the first corrupt file set took 18 s at load 9).
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.forkserver
import threading

PRELOAD = ("hydrolink.server.hdb.io", "hydrolink.server.hdb.bemio",   # imported once, by name (bemio:
           "hydrolink.server.service.step_worker")              # h5py, which io imports only for a BEMIO file)

WARM_CHILDREN_S = 2.0   # s after hydrolink serve's loop starts: the forkserver started if nothing needed it yet
_lock = threading.Lock()   # set_forkserver_preload and the first start are process-wide


def children():
    """The multiprocessing context every child of the server is made in."""
    with _lock:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(list(PRELOAD))
        return ctx


def start_children() -> None:
    """Start the forkserver now if it is not running (it imports :data:`PRELOAD` in its own
    process, not in this one; this returns at once, and the first child waits for the imports)."""
    children()
    with _lock:
        multiprocessing.forkserver.ensure_running()
