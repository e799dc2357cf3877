"""Threads that set sessions up (a hello's HDB parsing and model construction) off the server loop.

The loop that answers steps never waits for a set-up: it hands ``build`` to a worker and answers
the hello when the set-up's :class:`~concurrent.futures.Future` is done. The heavy parts of a
set-up (the IRF transforms: numpy ufuncs and BLAS) release the GIL; what the loop then competes
for is a core, so the workers run at a lower scheduling priority (SETUP_NICE, Linux: per thread)
and a step that arrives takes the core first (bench/bench_setup_isolation.py measures the step
latency meanwhile). The queue itself is unbounded: the server admits at most ``max_setups`` hellos
at once (server/service/capacity.py), so it holds no more. Daemon threads: a server that stops does not
wait for a set-up nobody will be answered for.
"""

from __future__ import annotations

import os
import queue
import threading
from concurrent.futures import Future
from typing import Any, Callable

SETUP_WORKERS = 2   # hellos set up at once; later ones wait for a worker (steps never do)
SETUP_NICE = 10     # the workers' niceness above the server's (0-19: lower priority)


class SetupWorkers:
    """At most ``workers`` set-ups at once, in daemon threads started on first use."""

    def __init__(self, workers: int = SETUP_WORKERS, name: str = "hydrolink-setup"):
        self.workers, self.name = int(workers), name
        self._jobs: queue.SimpleQueue[tuple[Future, Callable[..., Any], tuple] | None] = queue.SimpleQueue()
        self._threads: list[threading.Thread] = []

    def submit(self, fn: Callable[..., Any], *args: Any) -> Future:
        """Run ``fn(*args)`` in a worker; its Future holds the result or the exception."""
        future: Future = Future()
        self._jobs.put((future, fn, args))
        if len(self._threads) < self.workers:
            thread = threading.Thread(target=self._work, name=f"{self.name}-{len(self._threads)}", daemon=True)
            self._threads.append(thread)
            thread.start()
        return future

    def _work(self) -> None:
        try:   # Linux: the niceness of this thread alone (its native id); elsewhere left as is
            os.setpriority(os.PRIO_PROCESS, threading.get_native_id(),
                           os.getpriority(os.PRIO_PROCESS, 0) + SETUP_NICE)
        except (AttributeError, OSError):
            pass
        while (job := self._jobs.get()) is not None:
            future, fn, args = job
            if not future.set_running_or_notify_cancel():
                continue
            try:
                future.set_result(fn(*args))
            except BaseException as exc:  # noqa: BLE001 - handed to the loop, which answers the hello
                future.set_exception(exc)

    def close(self) -> None:
        """Cancel the set-ups not started; the running ones end on their own (nobody is answered)."""
        while True:
            try:
                job = self._jobs.get_nowait()
            except queue.Empty:
                break
            if job is not None:
                job[0].cancel()
        for _ in self._threads:
            self._jobs.put(None)
