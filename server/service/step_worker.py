"""Heavy sessions step in worker processes of their own, off the server's loop (issue 35 item 4).

A session's model is built in a set-up thread (server/service/setup_workers.py), then its step is
timed there (:func:`step_cost`, the model put back as it was). A session whose step costs more than
the server's ``isolate_step_s`` steps in a child process (a fork of a forkserver that has imported
the model): :class:`StepWorker` hands it the model over a pipe and the loop polls the pipe beside
its ROUTER socket, so a heavy step neither waits for nor delays the others' (a light session's step
stays on the loop: a hop to a process would cost it more than it takes). The child holds the
session (:class:`~hydrolink.server.service.session.Session`): steps, saved states, the
controllers' wave probes. It has an address-space limit (its model's size plus a base); the loop
gives each request a time budget, and a child over it, or dead, is killed and its session ended
with error 16 ``session_failed`` (SPEC §5.6). At most ``max_workers`` children at once: a heavy
hello beyond them is refused busy (``limit`` ``"workers"``). Every child is reaped when its session
ends and when the server stops.
"""

from __future__ import annotations

import dataclasses
import math
import os
import resource
import threading
import time
import traceback
from collections import deque
from dataclasses import dataclass
from multiprocessing.connection import Connection
from typing import Any

import numpy as np
import xarray as xr

from hydrolink.protocol.codec import Code, ProtocolError
from hydrolink.protocol.scene import Scene
from hydrolink.server.allocation import footprint
from hydrolink.server.hdb.file_set import FileSetReader
from hydrolink.server.model import HydroModel
from hydrolink.server.processes import children
from hydrolink.server.service.capacity import ISOLATE_STEP_S, MAX_WORKERS, ServerBusy
from hydrolink.server.service.session import (ModelInputs, PlantBuilder, Session, SessionInfo, model_from,
                                              read_hello)

__all__ = ["ISOLATE_STEP_S", "MAX_WORKERS", "STEP_TIMEOUT", "Flight", "Placed", "StepWorker", "WorkerFailed",
           "WorkerSession", "WorkerSlots", "place", "step_cost"]

STEP_TIMEOUT = 60.0       # s a worker may take for one request before its session is ended (error 16)
START_TIMEOUT = 120.0     # s a worker may take to start and load its model
WORKER_BASE_MEMORY = 3 * 2**30   # bytes of address space a worker may use beyond ...
WORKER_PER_MODEL_BYTE = 4        # ... this many times its model's arrays (footprint)


def step_cost(model: HydroModel, tries: int = 3) -> float:
    """The seconds one step of ``model`` takes (the least of ``tries``: a first step may compile
    kernels), at rest in its equilibrium turned by 0.01 rad of yaw (a passive-yaw body's step costs
    more off its initial heading: server/sea/passive_yaw.py); the model is put back as it was (its
    :meth:`state`). CPU time of this thread: a loaded machine (or the set-up thread's lower priority)
    does not make a light model look heavy. A model that cannot take that step costs ``inf`` (it is
    isolated)."""
    saved = model.state()
    x = np.array(model.setup_info().equilibrium_position, float)
    x[:, 5] += 0.01
    v = np.zeros_like(x)
    m = model.modes.size    # generalized modes at rest (server/modes.py)
    modal = {"modal_position": np.zeros(m), "modal_velocity": np.zeros(m)} if m else {}
    best = math.inf
    try:
        for i in range(tries):
            t0 = time.thread_time()
            model.step(0.0, x, v, replace_last=i > 0, **modal)
            best = min(best, time.thread_time() - t0)
    except Exception:  # noqa: BLE001 - a scene the trial cannot step: its own steps will say why
        return math.inf
    finally:
        model.set_state(saved)
    return best


class WorkerSlots:
    """At most ``maximum`` workers at once (taken in set-up threads, given back by the loop)."""

    def __init__(self, maximum: int):
        self.maximum = int(maximum)
        self._held = 0
        self._lock = threading.Lock()

    def take(self) -> None:
        """One worker more, or :class:`ServerBusy` (``limit`` ``"workers"``)."""
        with self._lock:
            if self._held >= self.maximum:
                raise ServerBusy("workers", self.maximum, self._held,
                                 f"server busy: {self._held} heavy sessions step in worker processes, at most "
                                 f"{self.maximum} (max_workers; hydrolink serve --max-workers raises it); nothing "
                                 "of this hello was kept: send it again after a heavy session closes")
            self._held += 1

    def give_back(self) -> None:
        with self._lock:
            self._held -= 1


class WorkerFailed(Exception):
    """The worker died or passed its time budget: ``why`` says which."""

    def __init__(self, why: str):
        super().__init__(why)
        self.why = why


def _memory_limit(footprint: int) -> int:
    return WORKER_BASE_MEMORY + WORKER_PER_MODEL_BYTE * int(footprint)


def _serve(conn: Connection, session_id: str, memory: int) -> None:
    """In the child: take the model, then answer requests in order until the pipe closes."""
    try:
        soft, hard = resource.getrlimit(resource.RLIMIT_AS)
        resource.setrlimit(resource.RLIMIT_AS, (memory if hard == resource.RLIM_INFINITY else min(memory, hard), hard))
    except (ValueError, OSError):   # a platform without it: the time budget still holds
        pass
    try:
        session = Session(session_id, model_from(conn.recv()))
    except ProtocolError as exc:   # the parent built the same model: not expected, but named
        conn.send(("error", (exc.code, exc.field, exc.message, exc.extra)))
        return
    except MemoryError:
        conn.send(("error", (Code.BUSY, None, "the session's worker ran out of its memory building the model",
                             {"limit": "memory"})))
        return
    conn.send(("ready", None))
    while True:
        try:
            op, args = conn.recv()
        except (EOFError, OSError):
            return
        conn.send(_answer(session, op, args))


def _answer(session: Session, op: str, args: tuple) -> tuple[str, Any]:
    """One request in the child: ("ok", result) or the error as plain values (the loop rebuilds it)."""
    try:
        if op == "step":
            msg, grids, step, hydro = args
            fields = session.step(msg, hydro)
            waves = session.previews(grids, step) if grids else {}
            return "ok", (fields, waves, session.steps, session.compute_s, session.last_iteration)
        result = getattr(session, op)(*args)   # save / restore / release
        return "ok", (result, None, session.steps, session.compute_s, session.last_iteration)
    except ProtocolError as exc:
        return "error", (exc.code, exc.field, exc.message, exc.extra)
    except MemoryError:
        return "error", (Code.BUSY, None, "the session's worker ran out of its memory handling this request",
                         {"limit": "memory"})
    except Exception as exc:  # noqa: BLE001 - a bug: the loop answers it as an internal error
        return "internal", f"{type(exc).__name__}: {exc}\n{traceback.format_exc(limit=-3)}"


@dataclass
class Flight:
    """The request a worker is computing: what its reply needs when it comes back."""
    op: str
    msg: dict
    msg_id: Any
    route: list[bytes]
    started: float
    arrived: float
    control: tuple | None = None   # a controlled step's (seq, iteration, new, measurements)


class StepWorker:
    """One worker process holding one session's model (see the module docstring)."""

    def __init__(self, inputs: ModelInputs, session_id: str, footprint: int, timeout: float = START_TIMEOUT):
        """Start the child and have it build its model from ``inputs`` (a model does not pickle
        faithfully: its arrays share memory through views; built from the same inputs it is the
        same model). In the set-up thread: this waits until the child is ready."""
        ctx = children()
        self.conn, there = ctx.Pipe(duplex=True)
        self.process = ctx.Process(target=_serve, args=(there, session_id, _memory_limit(footprint)), daemon=True,
                                   name=f"hydrolink-session-{session_id[:8]}")
        self.process.start()
        there.close()
        try:
            self.conn.send(inputs)
            if not self.conn.poll(timeout):
                raise WorkerFailed(f"the session's worker did not start within {timeout:g} s")
            status, value = self.conn.recv()
            if status != "ready":
                raise ProtocolError(value[0], value[1], value[2], extra=value[3])
        except (EOFError, OSError) as exc:
            self.stop()
            raise WorkerFailed(f"the session's worker died starting (exit code {self.process.exitcode}): "
                               f"{type(exc).__name__}") from None
        except BaseException:
            self.stop()
            raise

    def fileno(self) -> int:
        return self.conn.fileno()

    def send(self, op: str, args: tuple) -> None:
        try:
            self.conn.send((op, args))
        except (OSError, ValueError) as exc:
            raise WorkerFailed(f"the session's worker is gone (exit code {self.process.exitcode}): {exc}") from None

    def receive(self) -> tuple[str, Any]:
        """The answer to the request sent (the pipe is readable); WorkerFailed when the child died."""
        try:
            return self.conn.recv()
        except (EOFError, OSError):
            self.process.join(1.0)
            code = self.process.exitcode
            raise WorkerFailed("the session's worker died" + (f" (killed by signal {-code})" if code and code < 0
                                                               else f" (exit code {code})")) from None

    def stop(self) -> None:
        """Kill the child (if alive) and reap it."""
        try:
            self.conn.close()
        except OSError:
            pass
        if self.process.is_alive():
            self.process.kill()
        self.process.join(5.0)


class WorkerSession(SessionInfo):
    """A session whose model steps in a :class:`StepWorker`: the loop's side of it, with one request
    in flight at a time (``flight``) and the session's later requests waiting behind it in order."""

    def __init__(self, placed: "Placed", client: dict | None = None, realtime: float | None = None,
                 plant_builder: PlantBuilder | None = None):
        super().__init__(placed.session_id, placed.scene, placed.hdbs, placed.dt, client, realtime, plant_builder)
        assert placed.worker is not None
        worker = placed.worker
        self.worker = worker
        self.flight: Flight | None = None
        self.waiting: deque[tuple[dict, list[bytes], int]] = deque()   # (request, route, bytes)

    def submit(self, flight: Flight, args: tuple) -> None:
        self.worker.send(flight.op, args)
        self.flight = flight

    def done(self) -> tuple[Flight, tuple[str, Any]]:
        """The request in flight and the worker's answer (its counters taken over)."""
        flight, self.flight = self.flight, None
        status, value = self.worker.receive()
        if status == "ok":
            result, _, self.steps, self.compute_s, self.last_iteration = value
            if "seq" in result:
                self.last_seq = result["seq"]
        return flight, (status, value)


@dataclass(frozen=True)
class Placed:
    """A hello's model, built and timed, and where it steps: ``model`` on the loop, or ``worker``
    (its own copy of the model; this process kept only what the loop needs of it: the scene, the
    HDBs by body name for a linear plant, the welcome's ``setup``). ``session_id`` drawn for it,
    ``footprint`` its arrays' bytes, ``cost`` its step's seconds."""
    session_id: str
    footprint: int
    cost: float
    scene: Scene
    hdbs: dict[str, xr.Dataset]
    dt: float
    n_bodies: int
    n_waves: int
    setup: dict
    model: HydroModel | None = None
    worker: StepWorker | None = None

    @classmethod
    def of(cls, session_id: str, model: HydroModel, cost: float, size: int | None = None,
           worker: StepWorker | None = None) -> "Placed":
        return cls(session_id, footprint(model) if size is None else size, cost, model.scene, model.hdbs, model.dt,
                   len(model.bodies), model.waves.size, model.setup_info().to_wire(),
                   model if worker is None else None, worker)


def place(msg: dict, files: FileSetReader, isolate_step_s: float, slots: WorkerSlots) -> Placed:
    """A hello's set-up in a set-up thread: the model built (session.build_model), timed, and
    handed to a worker when its step costs more than ``isolate_step_s`` (a worker of ``slots``, or
    error 14 ``workers``; a worker that cannot start: error 16)."""
    inputs = read_hello(msg, files)
    model = model_from(inputs)
    sid = os.urandom(16).hex()
    cost = step_cost(model)
    if cost <= isolate_step_s:
        return Placed.of(sid, model, cost)
    facts = Placed.of(sid, model, cost)
    del model   # this process keeps none of it: the worker builds its own
    slots.take()
    try:
        worker = StepWorker(inputs, sid, facts.footprint)
    except WorkerFailed as exc:
        slots.give_back()
        raise ProtocolError(Code.SESSION_FAILED, None, f"{exc.why}; nothing of this hello was kept") from None
    except BaseException:
        slots.give_back()
        raise
    return dataclasses.replace(facts, model=None, worker=worker)
