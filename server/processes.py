"""The server's child processes come from one forkserver, shared by the HDB parses
(server/hdb/isolated.py) and the session workers (server/service/step_worker.py): a fork of a
process that has imported the readers and the model once, so a child costs a fork, not an import.

``hydrolink serve`` starts it with the server (:func:`start_children`): the first corrupt upload or
heavy session then does not wait for those imports.
"""

from __future__ import annotations

import multiprocessing
import multiprocessing.forkserver
import threading

PRELOAD = ("hydrolink.server.hdb.io", "hydrolink.server.service.step_worker")   # imported once, by name

_lock = threading.Lock()   # set_forkserver_preload and the first start are process-wide


def children():
    """The multiprocessing context every child of the server is made in."""
    with _lock:
        ctx = multiprocessing.get_context("forkserver")
        ctx.set_forkserver_preload(list(PRELOAD))
        return ctx


def start_children() -> None:
    """Start the forkserver now (it imports :data:`PRELOAD` in its own process, not in this one)."""
    children()
    with _lock:
        multiprocessing.forkserver.ensure_running()
