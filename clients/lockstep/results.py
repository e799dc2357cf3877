"""Progressive NetCDF results file of a run (NETCDF4, unlimited ``time``).

Rows are buffered in memory in preallocated blocks; a block is written + synced by the writer's own
thread once ``flush_seconds`` of wall time have passed since the last hand-off or it holds
``flush_rows`` rows, so the stepping thread never writes to the file: it hands the block over (a
put on a bounded queue) and fills the next free one. A paced run writes from a process of its own
instead (:meth:`ResultWriter.write_in_process`: the blocks in shared memory, the hand-off a message;
no write holds the run's GIL). ``blocks`` (default 3) bound the rows in flight; only when every block is still on its way to the file does the stepping thread wait for
one (the time is counted in ``io_seconds``: a paced run's "io"). A run killed part way (even with
SIGKILL) leaves a readable file holding every row up to the last completed write. The global
``status`` attribute says "running", then "complete" or "interrupted: <why>" (:meth:`finish`
writes every row first). To look at a file while its run is still going, read it with
``HDF5_USE_FILE_LOCKING=FALSE`` set (HDF5 locks files open for writing); a killed run's file opens
normally.

Layout (readable with ``xarray.open_dataset``)::

    dims   time (unlimited), body, dof (surge, sway, heave, roll, pitch, yaw)
    vars   position, velocity, excitation_force, radiation_force, hydrostatic_force  (time, body, dof)
           wave_elevation (time), equilibrium_position (body, dof)
    extra  variables declared by the client with :meth:`ResultWriter.add_variable`, dims
           (time, *their dims): joint outputs over ``joint``; ``pto_force``, ``pto_velocity``,
           ``pto_power`` over ``pto`` and ``total_pto_power``; ``mooring_force`` over
           (``mooring``, ``mooring_component``); MoorDyn: ``line_tension`` (its own fairlead tension)
           and ``line_end_force`` over ``line`` and
           ``line_node_position`` over (``line``, ``node``, ``xyz``); attribute ``moordyn`` (JSON:
           files, initial tensions and loads, static offsets); the optional forces' variables
           (``viscous_force``, ``viscous_power``, ``morison_force``, ...: protocol/reply.py) with
           :func:`add_force_term_variables` / :meth:`ResultWriter.stage_forces`

Extra variables: ``add_variable(name, dims, coords, units, long_name)`` before the first row
(``coords`` gives the labels of any dimension not yet in the file; ``dtype``, default f8, and
``fill``: the value of a row that does not stage it), then per row ``stage_extra({name: value,
...})`` BEFORE ``append(...)``: the staged values belong to the row that ``append`` adds (a
variable without a fill that is not staged for a row keeps its previous value, NaN at first).
Values known only after a row is committed (a paced step's latency, clients/lockstep/driver.py)
go in with :attr:`ResultWriter.hold` set: sealed blocks wait, :meth:`ResultWriter.amend` gives
the row's slot, :meth:`ResultWriter.release_held` hands them on.
"""

from __future__ import annotations

import datetime as _dt
import functools
import json
import mmap
import os
import queue
import socket
import subprocess
import sys
import tempfile
import threading
import time as _time
from importlib import metadata
from multiprocessing.connection import Connection
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import netCDF4

from hydrolink.clients.lockstep.rt_priority import ordinary_policy
from hydrolink.protocol.capabilities import reply_fields
from hydrolink.protocol.reply import dissipated_power, reply_field
from hydrolink.protocol.scene import Scene
from hydrolink.protocol.setup import Setup

DOF_NAMES: tuple[str, ...] = ("surge", "sway", "heave", "roll", "pitch", "yaw")

_TRANSLATION_ROTATION = "(surge, sway, heave); {rot} (roll, pitch, yaw)"
ROW_VARIABLES: dict[str, tuple[str, str]] = {
    "position": ("m " + _TRANSLATION_ROTATION.format(rot="rad"),
                 "absolute position of the body reference point and small rotation angles"),
    "velocity": ("m/s " + _TRANSLATION_ROTATION.format(rot="rad/s"),
                 "velocity of the body reference point and angular velocity (angle rates)"),
    "excitation_force": ("N " + _TRANSLATION_ROTATION.format(rot="N m"),
                         "wave excitation force and moment about the reference point"),
    "radiation_force": ("N " + _TRANSLATION_ROTATION.format(rot="N m"),
                        "radiation memory force -int K(tau) v(t - tau) dtau (the infinite-frequency "
                        "added mass is in the mass matrix, not here)"),
    "hydrostatic_force": ("N " + _TRANSLATION_ROTATION.format(rot="N m"),
                          "linear restoring force -C (x - x_eq), gravity terms included"),
}
_VERSIONED = ("hydrolink", "exudyn", "numpy", "capytaine", "xarray")
#: row blocks of a writer: one being filled, the others queued for or being written by its thread
BLOCKS = 3



def _nc_lock() -> Any:
    """The lock of every netCDF/HDF5 call in this process: netCDF-C and HDF5 are not thread-safe,
    the writers' threads share xarray's HDF5 lock (imported here, not at the module's import: the
    writer's process has no use for xarray)."""
    try:
        from xarray.backends.locks import HDF5_LOCK
    except ImportError:   # pragma: no cover - an xarray without it
        return _OWN_LOCK
    return HDF5_LOCK


_OWN_LOCK = threading.Lock()


def package_versions() -> dict[str, str]:
    """Installed versions of the packages a result depends on ("not installed" if absent)."""
    return dict(_installed_versions())


@functools.cache
def _installed_versions() -> tuple[tuple[str, str], ...]:
    """:func:`package_versions`, looked up once a process (the code a process runs keeps the version
    it was imported at): 3 ms of every results file's set-up in a sweep's worker (bench/bench_setup.py)."""
    out = []
    for name in _VERSIONED:
        try:
            out.append((name, metadata.version(name)))
        except metadata.PackageNotFoundError:
            out.append((name, "not installed"))
    return tuple(out)


def _block_fields(capacity: int, n_bodies: int, extras: dict[str, tuple[tuple[int, ...], str, Any]]
                  ) -> list[tuple[str, tuple[int, ...], str]]:
    """A block's arrays (name, shape, dtype), in the order they lie in a shared block."""
    return [("time", (capacity,), "f8"), ("rows", (len(ROW_VARIABLES), capacity, n_bodies, 6), "f8"),
            ("eta", (capacity,), "f8"), *((name, (capacity, *shape), dtype) for name, (shape, dtype, _) in extras.items())]


def _aligned(nbytes: int) -> int:
    """``nbytes`` rounded up to the 64-byte boundary each array of a shared block starts on."""
    return -(-nbytes // 64) * 64


def _block_bytes(fields: list[tuple[str, tuple[int, ...], str]]) -> int:
    """Bytes of one block's arrays laid one after the other, each on a 64-byte boundary."""
    return sum(_aligned(int(np.prod(shape)) * np.dtype(dtype).itemsize) for _, shape, dtype in fields)


class _Block:
    """Rows buffered for one write: ``first`` the file index of its row 0, ``n`` rows filled;
    ``index`` its place among the writer's blocks. Its arrays are its own, or views into
    ``buffer`` from ``offset`` (a block shared with the writer's process); either way every page is
    touched here (``touch``), not at the block's first row in the loop."""

    __slots__ = ("time", "rows", "eta", "extra", "first", "n", "index")

    def __init__(self, fields: list[tuple[str, tuple[int, ...], str]], index: int = 0, buffer: Any = None,
                 offset: int = 0, touch: bool = True):
        arrays = {}
        for name, shape, dtype in fields:
            if buffer is None:
                arrays[name] = np.zeros(shape, dtype)
            else:
                arrays[name] = np.ndarray(shape, dtype, buffer, offset)
                offset += _aligned(arrays[name].nbytes)
            if touch:
                arrays[name].fill(0)
        self.time, self.rows, self.eta = arrays.pop("time"), arrays.pop("rows"), arrays.pop("eta")
        self.extra = arrays
        self.index, self.first, self.n = index, 0, 0


def _write_block(ds: netCDF4.Dataset, blk: _Block) -> int:
    """Block ``blk``'s rows into the open dataset, then a sync; returns the rows in the file."""
    m, i0 = blk.n, blk.first
    i1 = i0 + m
    if m:
        for k, name in enumerate(ROW_VARIABLES):
            ds[name][i0:i1] = blk.rows[k, :m]
        ds["wave_elevation"][i0:i1] = blk.eta[:m]
        for name, arr in blk.extra.items():
            ds[name][i0:i1] = arr[:m]
        ds["time"][i0:i1] = blk.time[:m]  # last: marks the rows as present
    ds.sync()
    return i1


class ResultWriter:
    """Append-only results file; use as a context manager (an exception marks it interrupted)."""

    def __init__(self, path: str | Path, *, scene: Any = None, scene_text: str = "",
                 setup: Setup | None = None, bodies: list[str] | None = None,
                 equilibrium_position: np.ndarray | None = None, dt: float | None = None,
                 flush_seconds: float = 1.0, flush_rows: int = 2000, blocks: int = BLOCKS):
        """``bodies``/``equilibrium_position`` default to the setup's wet bodies (else the scene's
        bodies at the origin); ``dt`` (the row spacing, an attribute) to the setup's. ``blocks``:
        row blocks in all (at least 2: one filling, the rest on their way to the file)."""
        if bodies is None:
            bodies = list(setup.bodies) if setup else [b.name for b in scene.bodies]
        if equilibrium_position is None:
            equilibrium_position = setup.equilibrium_position if setup else np.zeros((len(bodies), 6))
        if dt is None and setup:
            dt = setup.dt
        eq = np.asarray(equilibrium_position, float)
        if eq.shape != (len(bodies), 6):
            raise ValueError(f"equilibrium_position must have shape ({len(bodies)}, 6), got {eq.shape}")
        if int(blocks) < 2:
            raise ValueError(f"blocks must be at least 2 (one filling, one being written), got {blocks}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.n_bodies = len(bodies)
        self.flush_seconds, self.flush_rows = float(flush_seconds), int(flush_rows)
        self.n_blocks = int(blocks)
        self.rows_written = 0             # rows in the file (set by the writer thread)
        self.status = "running"
        self.io_seconds = 0.0             # stepping thread's time waiting for a free block (the queue full)
        self.io_waits = 0
        self.hold = False                 # keep sealed blocks until release_held() (a paced step's rows)
        self._rows = 0                    # rows committed
        self._extras: dict[str, tuple[tuple[int, ...], str, Any]] = {}   # name -> (shape, dtype, fill)
        self._staged: dict[str, bool] = {}                               # extras staged for the next row
        self._full: dict[str, np.ndarray] = {}                           # stage_forces' (B, 6) scratch
        self._cur: _Block | None = None   # the block being filled (None before the first row)
        self._prev: _Block | None = None  # the last block sealed: its last row is row 0's "previous"
        self._held: list[_Block] = []
        self._free: queue.Queue[_Block] = queue.Queue()
        self._queue: queue.Queue[_Block | None] = queue.Queue(maxsize=self.n_blocks)
        self._thread: threading.Thread | None = None
        self._blocks: list[_Block] = []
        self._proc: subprocess.Popen | None = None    # the writer's process (write_in_process)
        self._conn: Connection | None = None          # to it: requests; from it: (block index, rows, error)
        self._shared: mmap.mmap | None = None         # the blocks it reads
        self._pending = 0                             # requests it has not answered yet
        self._error: BaseException | None = None
        self._io = _nc_lock()             # every use of the dataset, either thread
        self._last_flush = _time.monotonic()
        with self._io:
            self._ds = netCDF4.Dataset(self.path, "w", format="NETCDF4")
            try:
                self._create(bodies, eq, scene_text, dt, setup.warnings if setup else ())
            except BaseException:
                self._ds.close()
                raise

    # -- layout ------------------------------------------------------------------------------
    def _create(self, bodies: list[str], eq: np.ndarray, scene_text: str, dt: float | None,
                warnings: tuple[str, ...]) -> None:
        ds, n = self._ds, len(bodies)
        ds.createDimension("time", None)
        ds.createDimension("body", n)
        ds.createDimension("dof", 6)
        chunk = 512
        t = ds.createVariable("time", "f8", ("time",), chunksizes=(chunk,))
        t.units, t.long_name, t.standard_name = "s", "simulation time", "time"
        b = ds.createVariable("body", str, ("body",))
        b.long_name = "body name"
        for i, name in enumerate(bodies):
            b[i] = name
        d = ds.createVariable("dof", str, ("dof",))
        d.long_name = "degree of freedom (rotations about the body reference point)"
        for i, name in enumerate(DOF_NAMES):
            d[i] = name
        for name, (units, long_name) in ROW_VARIABLES.items():
            v = ds.createVariable(name, "f8", ("time", "body", "dof"), chunksizes=(chunk, n, 6))
            v.units, v.long_name = units, long_name
        w = ds.createVariable("wave_elevation", "f8", ("time",), chunksizes=(chunk,))
        w.units, w.long_name = "m", "undisturbed incident wave elevation at the origin"
        e = ds.createVariable("equilibrium_position", "f8", ("body", "dof"))
        e.units = ROW_VARIABLES["position"][0]
        e.long_name = "body reference point at equilibrium (where the HDB's rotational modes refer), zero angles"
        e[:] = eq
        attrs = {
            "title": "hydrolink co-simulation results",
            "scene": scene_text,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "status": self.status,
            "dof_convention": "positions absolute (reference point xyz + small rotation angles); "
                              "forces act at the reference point",
        }
        if dt is not None:
            attrs["dt"] = float(dt)
        attrs["warnings"] = json.dumps(list(warnings))  # the setup's; run_scene_file writes the run's final list
        attrs.update({f"{k}_version": v for k, v in package_versions().items()})
        ds.setncatts(attrs)
        ds.sync()

    def add_variable(self, name: str, dims: tuple[str, ...], coords: dict[str, list[str]] | None = None,
                     units: str = "", long_name: str = "", *, dtype: str = "f8", fill: Any = None) -> None:
        """Declare an extra per-row variable with dims (time, *dims); see the module docstring.
        ``fill``: the value of a row that does not stage it (None: the previous row's, NaN at
        first; an integer ``dtype`` needs a fill)."""
        if self._rows or self._cur is not None:
            raise RuntimeError(f"add_variable({name!r}) after rows were written")
        if name in self._ds.variables:
            raise ValueError(f"results variable {name!r} already exists")
        if fill is None and np.dtype(dtype).kind != "f":
            raise ValueError(f"add_variable({name!r}): a {dtype} variable needs a fill value")
        coords = coords or {}
        shape = []
        with self._io:
            for dim in dims:
                if dim not in self._ds.dimensions:
                    if dim not in coords:
                        raise ValueError(f"add_variable({name!r}): labels for the new dimension {dim!r} are needed")
                    labels = list(coords[dim])
                    self._ds.createDimension(dim, len(labels))
                    c = self._ds.createVariable(dim, str, (dim,))
                    for i, label in enumerate(labels):
                        c[i] = str(label)
                shape.append(len(self._ds.dimensions[dim]))
            v = self._ds.createVariable(name, dtype, ("time", *dims), chunksizes=(512, *shape))
            v.units, v.long_name = units, long_name
        self._extras[name] = (tuple(shape), dtype, fill)
        self._staged[name] = False

    def _start(self) -> _Block:
        """The blocks, made at the first row (every variable is declared by then)."""
        fields = _block_fields(max(self.flush_rows, 1), self.n_bodies, self._extras)
        blocks = self._blocks = [_Block(fields, k) for k in range(self.n_blocks)]
        for name, arr in blocks[0].extra.items():
            arr[0] = np.nan if self._extras[name][2] is None else self._extras[name][2]
        for b in blocks[1:]:
            self._free.put(b)
        self._cur = blocks[0]
        return blocks[0]

    def stage_forces(self, optional: Mapping[str, np.ndarray], rows: np.ndarray, velocity: np.ndarray) -> None:
        """Stage the variables of the optional forces for the next row: each force (6N over the
        served bodies) put at the flat positions ``rows`` of the file's (B, 6) bodies (zero for the
        others); ``velocity`` (B, 6) the row's, for a dissipated power."""
        for name, part in optional.items():
            full = self._full.get(name)
            if full is None:
                full = self._full[name] = np.zeros((self.n_bodies, 6))
            full.reshape(-1)[rows] = part
            for v in reply_field(name).variables:
                self._stage(v.name, full if v.value == "force" else dissipated_power(full, velocity))

    def stage_extra(self, values: dict[str, Any]) -> None:
        """Values of extra variables for the row the next :meth:`append` adds."""
        for name, value in values.items():
            self._stage(name, value)

    def _stage(self, name: str, value: Any) -> None:
        blk = self._cur if self._cur is not None else self._start()
        blk.extra[name][blk.n] = value
        self._staged[name] = True

    def slots(self, names: tuple[str, ...]) -> tuple[np.ndarray, ...]:
        """The next row's values of the extra variables ``names`` as views into the block, each
        (1, *dims), staged: filled in place before :meth:`commit` (as :meth:`row` is for the row
        variables; :meth:`stage_extra` without the copies)."""
        blk = self._cur if self._cur is not None else self._start()
        i, staged, extra = blk.n, self._staged, blk.extra
        for name in names:
            staged[name] = True
        return tuple(extra[name][i:i + 1] for name in names)

    # -- rows --------------------------------------------------------------------------------
    def append(self, time: float, position, velocity, excitation, radiation, hydrostatic,
               wave_elevation) -> None:
        """Buffer one row: (N, 6) arrays and a number for the elevation (copied into the block);
        hands the block to the writer thread when the wall-time or row budget is used up."""
        block = self.row()
        block[0] = position
        block[1] = velocity
        block[2] = excitation
        block[3] = radiation
        block[4] = hydrostatic
        self.commit(time, wave_elevation)

    def row(self) -> np.ndarray:
        """The next row's slot in the block, (5, N, 6) in ROW_VARIABLES order, to be filled in
        place (e.g. with ``out=``) and then added by :meth:`commit` — :meth:`append` without copies."""
        blk = self._cur if self._cur is not None else self._start()
        return blk.rows[:, blk.n]

    def commit(self, time: float, wave_elevation: float) -> None:
        """Add the row filled in :meth:`row` (and the extras staged); when the wall-time or row
        budget is used up, the block goes to the writer thread (:meth:`hold`: after
        :meth:`release_held`) and the next row starts a free one."""
        blk = self._cur if self._cur is not None else self._start()
        i = blk.n
        blk.time[i] = time
        blk.eta[i] = wave_elevation
        if self._extras:
            staged, extras = self._staged, self._extras
            for name, arr in blk.extra.items():
                if staged[name]:
                    staged[name] = False
                    continue
                fill = extras[name][2]
                if fill is not None:
                    arr[i] = fill
                elif i:                       # unstaged: the previous row's value
                    arr[i] = arr[i - 1]
                elif self._prev is not None:
                    arr[0] = self._prev.extra[name][self._prev.n - 1]
        blk.n = i + 1
        self._rows += 1
        if blk.n >= blk.time.size or _time.monotonic() - self._last_flush >= self.flush_seconds:
            self._seal()

    def _seal(self) -> None:
        """The current block is complete: on to the writer (or held), and a free block next."""
        if self._error is not None:
            self._raise_error()
        blk = self._cur
        self._prev = blk
        if self.hold:
            self._held.append(blk)
        else:
            self._send(blk)
        nxt = self._next_free()
        nxt.first, nxt.n = blk.first + blk.n, 0
        self._cur = nxt
        self._last_flush = _time.monotonic()

    def _next_free(self) -> _Block:
        """A free block; when every block is on its way to the file, the wait for one (I/O)."""
        if self._conn is not None:
            self._collect(wait=False)
        try:
            return self._free.get_nowait()
        except queue.Empty:
            pass
        t0 = _time.perf_counter()
        if self._conn is None:
            nxt = self._free.get()
        else:
            while self._free.empty() and self._pending:
                self._collect(wait=True)
            if self._error is not None:
                self._raise_error()
            nxt = self._free.get_nowait()
        self.io_seconds += _time.perf_counter() - t0
        self.io_waits += 1
        return nxt

    def release_held(self) -> None:
        """Hand the blocks sealed while :attr:`hold` was set to the writer thread."""
        held = self._held
        while held:
            self._send(held.pop(0))

    def amend(self, row: int) -> tuple[dict[str, np.ndarray], int]:
        """The extras of committed row ``row`` not yet handed to the writer thread, to change in
        place: (name -> block array, index in it)."""
        for blk in (self._cur, *self._held):
            if blk is not None and blk.first <= row < blk.first + blk.n:
                return blk.extra, row - blk.first
        raise ValueError(f"row {row} is no longer buffered (already handed to the writer)")

    def _send(self, blk: _Block) -> None:
        if self._conn is not None:
            self._post(("block", blk.index, blk.first, blk.n))
            return
        if self._thread is None:
            self._thread = threading.Thread(target=self._work, name=f"results {self.path.name}", daemon=True)
            self._thread.start()
        self._queue.put(blk)              # never waits: fewer blocks exist than the queue holds

    def _work(self) -> None:
        """The writer thread: each block into the file, then a sync; the block back to the pool."""
        while True:
            blk = self._queue.get()
            try:
                if blk is None:
                    return
                if self._error is None:
                    with self._io:
                        self._write(blk)
            except BaseException as exc:  # noqa: BLE001 - reported on the stepping thread
                self._error = exc
            finally:
                if blk is not None:
                    self._free.put(blk)
                self._queue.task_done()

    def _write(self, blk: _Block) -> None:
        if self._ds.isopen():
            self.rows_written = _write_block(self._ds, blk)

    # -- the writer's process ----------------------------------------------------------------
    def write_in_process(self) -> None:
        """Write from now on in a process of its own (a paced run: PacedSteps, clients/lockstep/driver.py):
        the blocks sealed so far into the file, the file closed here and reopened there, the blocks
        put in shared memory (a file in /dev/shm, unlinked once both sides have it; the one being
        filled copied over, so blocks end where they would have). netCDF4's Python and HDF5's C
        calls then hold neither this process's GIL nor its CPU. The process starts under the
        ordinary policy, its threads too, when the run's thread is real-time (the stepping thread's
        core is not its to take: ``blocks`` - 1 blocks of slack), may run on any core (not only the
        run's, ``--cpu``), and its own session keeps it out of a terminal's Ctrl-C, so an
        interrupted run's last rows still reach the file."""
        if self._conn is not None:
            return
        old = self._cur if self._cur is not None else self._start()
        self.release_held()
        if self._thread is not None:      # every sealed block into the file
            self._queue.join()
            self._queue.put(None)
            self._thread.join()
            self._thread = None
        if self._error is not None:
            self._raise_error()
        fields = _block_fields(old.time.size, self.n_bodies, self._extras)
        size = _block_bytes(fields)
        fd, shared = _shared_file(size * self.n_blocks)
        try:
            self._shared = mmap.mmap(fd, size * self.n_blocks)
            blocks = [_Block(fields, k, self._shared, k * size) for k in range(self.n_blocks)]
            ours, theirs = socket.socketpair()
            with theirs, ordinary_policy():
                self._proc = subprocess.Popen([sys.executable, "-m", __name__, str(theirs.fileno())],
                                              pass_fds=(theirs.fileno(),), start_new_session=True)
            self._conn = Connection(ours.detach())
            with self._io:
                self._ds.close()
            self._post(("open", str(self.path), shared, fields))
            self._drain()
        finally:
            os.close(fd)
            os.unlink(shared)
        if self._error is not None:
            self._raise_error()
        cur = blocks[0]                   # the block being filled goes on in shared memory
        cur.time[:], cur.rows[:], cur.eta[:], cur.first, cur.n = old.time, old.rows, old.eta, old.first, old.n
        for name, arr in old.extra.items():
            cur.extra[name][:] = arr
        self._cur, self._blocks, self._free = cur, blocks, queue.Queue()
        for b in blocks[1:]:
            self._free.put(b)

    def _post(self, request: tuple) -> None:
        """A request to the writer's process (answered in order; :meth:`_collect`)."""
        try:
            self._conn.send(request)
            self._pending += 1
        except OSError as exc:
            self._process_ended(exc)

    def _collect(self, wait: bool) -> None:
        """The answers of the writer's process so far (``wait``: at least one): written blocks back
        to the pool, the rows in the file, an error kept for the stepping thread."""
        conn = self._conn
        try:
            while self._pending and conn.poll(None if wait else 0):
                wait = False
                index, rows, error = conn.recv()
                self._pending -= 1
                if index >= 0:
                    self._free.put(self._blocks[index])
                if rows is not None:
                    self.rows_written = rows
                if error is not None and self._error is None:
                    self._error = RuntimeError(f"in the writer's process: {error}")
        except (EOFError, OSError) as exc:
            self._process_ended(exc)

    def _drain(self) -> None:
        """Wait for every answer of the writer's process."""
        while self._pending:
            self._collect(wait=True)

    def _process_ended(self, exc: BaseException) -> None:
        self._pending = 0
        if self._error is None:
            code = self._proc.poll() if self._proc is not None else None
            self._error = RuntimeError(f"the writer's process ended (exit code {code}): {type(exc).__name__}: {exc}")

    def _raise_error(self) -> None:
        exc = self._error
        raise RuntimeError(f"writing the results file {self.path} failed: {type(exc).__name__}: {exc}") from exc

    def flush(self) -> None:
        """Write every row committed so far and sync the file to disk; returns when done."""
        if self._cur is not None and self._cur.n:
            hold, self.hold = self.hold, False
            self.release_held()
            self._seal()
            self.hold = hold
        self.release_held()
        if self._conn is not None:
            self._drain()
        elif self._thread is not None:
            self._queue.join()
        elif self._ds.isopen():
            with self._io:
                self._ds.sync()
        self._last_flush = _time.monotonic()
        if self._error is not None:
            self._raise_error()

    def set_attribute(self, name: str, value: Any) -> None:
        """Set a global attribute of the file (e.g. a run summary)."""
        if self._conn is not None:
            self._post(("attr", name, value))
            return
        with self._io:
            if self._ds.isopen():
                self._ds.setncattr(name, value)

    # -- end ---------------------------------------------------------------------------------
    @property
    def rows(self) -> int:
        """Rows appended so far (written or still buffered; all are saved by :meth:`finish`)."""
        return self._rows

    def finish(self, status: str) -> None:
        """Flush everything and record the final status ("complete" or "interrupted: ...")."""
        self.status = status
        if self._conn is not None:
            try:
                self.flush()
            finally:
                self._post(("attr", "status", status))
                self._post(("attr", "rows", self.rows_written))
                self._drain()
        elif self._ds.isopen():
            try:
                self.flush()
            finally:
                with self._io:
                    self._ds.setncattr("status", status)
                    self._ds.setncattr("rows", self.rows_written)
                    self._ds.sync()

    def close(self) -> None:
        """Flush and close; a file still "running" is marked as not finished."""
        if self._conn is None and not self._ds.isopen():
            return
        try:
            if self.status == "running":
                self.finish("interrupted: closed before the run finished")
        finally:
            if self._conn is not None:
                self._post(("close",))
                self._drain()
                self._conn.close()
                self._conn = None
                self._proc.wait()
                self._shared.close()
            if self._thread is not None:
                self._queue.put(None)
                self._thread.join()
                self._thread = None
            with self._io:
                if self._ds.isopen():
                    self._ds.close()

    def __enter__(self) -> "ResultWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None and self.status == "running":
            why = f"{exc_type.__name__}: {exc}" if str(exc) else exc_type.__name__
            self.finish(f"interrupted: {why}")
        self.close()


def add_force_term_variables(writer: ResultWriter, scene: Scene) -> None:
    """The results variables of the optional forces the scene's replies carry (its features'
    reply fields, protocol/capabilities.py), each as protocol/reply.py declares it, and the
    ``nonlinear`` attribute; :meth:`ResultWriter.stage_forces` fills them each row."""
    modes = {b.name: scene.nonlinear_of(b) for b in scene.nonlinear_bodies}
    if modes:
        writer.set_attribute("nonlinear", json.dumps(modes))
    for name in reply_fields(scene):
        for v in reply_field(name).variables:
            writer.add_variable(v.name, v.dims, None, v.units, v.description)


#: the generalized modes' results variables (dim ``mode``, labels "body.mode"): name, units, description
MODAL_VARIABLES: tuple[tuple[str, str, str], ...] = (
    ("modal_position", "modal coordinate (m for a mode shape in metres)",
     "generalized mode coordinate q_k: the body's deformation is sum_k q_k times the mode's shape"),
    ("modal_velocity", "modal coordinate per second", "rate of the generalized mode coordinate"),
    ("modal_excitation", "generalized force", "wave excitation on the mode (server)"),
    ("modal_radiation", "generalized force", "radiation memory force on the mode, without the A_inf term (server)"),
    ("modal_hydrostatic", "generalized force", "-C q of the mode's row of the hydrostatic stiffness (in the "
                                               "client's stiffness matrix)"),
)


def add_modal_variables(writer: ResultWriter, labels: tuple[str, ...]) -> None:
    """The generalized modes' results variables (dim ``mode``: the setup's ``body.mode`` labels,
    beyond each body's six rigid DOFs); the client stages them every row (a PTO on a mode is among
    the ``pto_*`` variables)."""
    for name, units, description in MODAL_VARIABLES:
        writer.add_variable(name, ("mode",), {"mode": list(labels)}, units, description)


def _shared_file(size: int) -> tuple[int, str]:
    """A new file of ``size`` bytes for the blocks of a writer's process, its space taken now (no
    SIGBUS at a row when memory runs short): in /dev/shm (memory), else, when that has no room, in
    the temporary folder; (descriptor, path)."""
    if os.path.isdir("/dev/shm"):
        try:
            return _allocated_file(size, "/dev/shm")
        except OSError:
            pass
    return _allocated_file(size, None)


def _allocated_file(size: int, folder: str | None) -> tuple[int, str]:
    fd, path = tempfile.mkstemp(prefix="hydrolink-results-", dir=folder)
    try:
        if hasattr(os, "posix_fallocate"):
            os.posix_fallocate(fd, 0, size)
        else:   # pragma: no cover - macOS
            os.ftruncate(fd, size)
    except OSError:
        os.close(fd)
        os.unlink(path)
        raise
    return fd, path


def _serve_blocks(fd: int) -> None:
    """The writer's process (:meth:`ResultWriter.write_in_process`), talking over the connection on
    ``fd``: ("open", path, shared file, block fields) opens the file to append and maps the blocks,
    ("block", index, first, n) writes one, ("attr", name, value) sets a global attribute,
    ("close",) closes the file; each is answered (block index or -1, rows in the file or None, the
    error or None). The end of the connection (its run killed) closes the file."""
    if hasattr(os, "sched_setaffinity"):   # not the core the run was pinned to (--cpu): any
        try:
            os.sched_setaffinity(0, range(os.cpu_count() or 1))
        except OSError:                    # a cpuset narrower than the machine: as inherited
            pass
    conn = Connection(fd)
    ds: netCDF4.Dataset | None = None
    blocks: list[_Block] = []
    while True:
        try:
            request = conn.recv()
        except EOFError:
            break
        index, rows, error = -1, None, None
        try:
            if request[0] == "block":
                index, first, n = request[1:]
                blk = blocks[index]
                blk.first, blk.n = first, n
                rows = _write_block(ds, blk)
            elif request[0] == "attr":
                ds.setncattr(request[1], request[2])
                ds.sync()
            elif request[0] == "open":
                path, shared, fields = request[1:]
                ds = netCDF4.Dataset(path, "a")
                with open(shared, "r+b") as f:
                    buffer = mmap.mmap(f.fileno(), 0)
                size = _block_bytes(fields)
                blocks = [_Block(fields, k, buffer, k * size, touch=False) for k in range(len(buffer) // size)]
            elif request[0] == "close":
                ds.close()
                ds = None
        except Exception as exc:  # noqa: BLE001 - answered to the stepping process
            error = f"{type(exc).__name__}: {exc}"
        conn.send((index, rows, error))
        if request[0] == "close":
            break
    if ds is not None:
        ds.close()


if __name__ == "__main__":   # the writer's process: python -m hydrolink.clients.lockstep.results FD
    _serve_blocks(int(sys.argv[1]))
