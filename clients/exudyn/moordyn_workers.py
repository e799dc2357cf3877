"""MoorDyn groups stepped in worker processes (scene ``[[moorings]] workers = N``).

Each group (clients/exudyn/moordyn_split.py; with one worker, the whole file) is one MoorDyn
instance in a process of its own (:func:`main` under ``python -c``: numpy and MoorDyn only, its
stdout and stderr — MoorDyn's console output — into a file, so no per-call redirection). It
starts from the whole file's initial-condition state (``Init_NoIC`` + ``LoadState``) and is
stepped through shared memory (a file in its folder, mapped by both): the caller writes t, dt, the
coupled state and velocity into the worker's block and sends one byte on a socket pair; the worker
steps and writes the coupled forces, its coupled points' mass matrices, its lines' fairlead
tensions, end forces and (``record_nodes``) node positions, then answers one byte (or ``E`` and
MoorDyn's message). The socket is the wait (a blocking ``recv``: no core spun while MoorDyn runs,
which on a machine with fewer cores than processes costs the worker its core) and the death notice (a
worker that dies closes it: :class:`MoorDynWorkerDied`, naming the mooring and the group).

``launch`` and ``collect`` are separate so that the caller can start MoorDyn's next step before it
is asked for, while it does other work (clients/exudyn/moordyn_mooring.py ``step_ahead``): the
caller vouches that the step it will ask for is that one. A step cannot be undone cheaply (MoorDyn's
``Serialize`` costs as much as a step: 434 against 456 CPU µs on SEA-Stack's RM3 file; its
``SaveState`` keeps the lines' state but not a coupled body's last velocity, from which the next
step's inertia is taken), so a step started ahead and then not asked for is an error, as is a
``save`` while one is in flight. ``save``/``restore`` keep and restore one state in each worker
(the implicit scheme's redo).

Every worker is reaped: ``close`` asks it to end (MoorDyn closes its files), waits, kills after
:data:`EXIT_TIMEOUT`; a finalizer does the same if the owner is dropped without ``close``. A worker
runs in a session of its own (a terminal's Ctrl-C stops the run, which then ends its workers) and
ends by itself when its socket closes (the run process gone).
"""

from __future__ import annotations

import json
import math
import mmap
import os
import socket
import struct
import subprocess
import sys
import weakref
from dataclasses import dataclass
from pathlib import Path

import numpy as np

#: seconds a worker may take to start (read its file, load its state) or to end
START_TIMEOUT = 120.0
EXIT_TIMEOUT = 10.0


class MoorDynWorkerError(RuntimeError):
    """A worker's MoorDyn failed; the message names the mooring, the group and MoorDyn's complaint."""


class MoorDynWorkerDied(MoorDynWorkerError):
    """A worker process ended unasked."""


def complaint(output: bytes) -> str:
    """MoorDyn's error lines (from its first "ERR" line on, the file path shortened), else its last
    warning, else its last lines."""
    lines = [ln.strip() for ln in output.decode("utf-8", "replace").replace("\r", "\n").splitlines()
             if ln.strip() and not ln.startswith((" ", "\t", "t = ", "Traceback", "  File", "RuntimeError"))]
    for marker in ("ERR ", "WRN "):
        first = [k for k, ln in enumerate(lines) if ln.startswith(marker)]
        if first:
            said = lines[first[0]:first[0] + 3] if marker == "ERR " else lines[first[-1]:first[-1] + 1]
            said[0] = said[0].split("): ", 1)[-1]      # drop MoorDyn's source location
            return " | ".join(said)
    return " | ".join(lines[-3:]) or "no message"


@dataclass(frozen=True)
class WorkerSpec:
    """What one worker runs: its MoorDyn file (in its own folder), the state to start from, the
    coupled state at t = 0, its block's sizes."""
    file: str
    state: str
    x: tuple[float, ...]
    coupled_points: int            # its coupled points (after the coupled bodies' 6 values each)
    fairlead: tuple[int, ...]      # each of its lines' fairlead node
    nodes: int                     # node positions recorded per line (0: none)

    @property
    def n_coupled(self) -> int:
        return len(self.x)

    def layout(self) -> dict[str, tuple[int, int]]:
        """Its block's parts: name -> (offset, length) in float64 values."""
        nc, lines = self.n_coupled, len(self.fairlead)
        sizes = (("t", 2), ("x", nc), ("v", nc), ("f", nc), ("mass", 9 * self.coupled_points),
                 ("tension", lines), ("end_force", lines), ("nodes", lines * self.nodes * 3))
        out, at = {}, 0
        for name, n in sizes:
            out[name] = (at, n)
            at += n
        return out


# -- the worker process --------------------------------------------------------------------------------
def _serve(spec: WorkerSpec, block: np.ndarray, sock: socket.socket) -> None:
    import cmoordyn
    import moordyn
    parts = {k: block[a:a + n] for k, (a, n) in spec.layout().items()}
    x = list(spec.x)
    m = moordyn.Create(spec.file)
    err = moordyn.Init_NoIC(m, x, [0.0] * len(x))
    if err:
        raise RuntimeError(f"MoorDyn's Init_NoIC failed (error code {err})")
    moordyn.LoadState(m, spec.state)
    points = (moordyn.GetPoint(m, k) for k in range(1, moordyn.GetNumberPoints(m) + 1))
    cpoints = [p for p in points if moordyn.GetPointType(p) == moordyn.POINT_TYPE_COUPLED]
    lines = [moordyn.GetLine(m, k) for k in range(1, moordyn.GetNumberLines(m) + 1)]
    counts = [moordyn.GetLineN(line) for line in lines]
    t, xs, vs, f, mass = parts["t"], parts["x"], parts["v"], parts["f"], parts["mass"].reshape(-1, 3, 3)
    tension, end_force = parts["tension"], parts["end_force"]
    nodes = parts["nodes"].reshape(len(lines), spec.nodes, 3) if spec.nodes else None
    step, ten, force, node_pos = cmoordyn.step, cmoordyn.line_get_node_ten, cmoordyn.line_get_node_force, \
        cmoordyn.line_get_node_pos
    saved = None
    sock.sendall(b"\0")
    while True:
        cmd = sock.recv(1)
        if not cmd or cmd == b"q":
            break
        try:
            if cmd == b"s":
                f[:] = step(m, xs.tolist(), vs.tolist(), float(t[0]), float(t[1]))
                for k, p in enumerate(cpoints):
                    mass[k] = cmoordyn.point_get_m(p)
                for k, (line, j) in enumerate(zip(lines, spec.fairlead)):
                    tension[k] = math.hypot(*ten(line, j))
                    end_force[k] = math.hypot(*force(line, j))
                if nodes is not None:
                    nodes.fill(np.nan)
                    for k, (line, n) in enumerate(zip(lines, counts)):
                        nodes[k, :n + 1] = [node_pos(line, i) for i in range(n + 1)]
            elif cmd == b"v":
                saved = moordyn.Serialize(m)
            elif cmd == b"r":
                moordyn.Deserialize(m, saved)
            sock.sendall(b"\0")
        except (RuntimeError, ValueError, TypeError) as exc:
            msg = str(exc).encode("utf-8", "replace")[:4000]
            sock.sendall(b"E" + struct.pack("<I", len(msg)) + msg)
    moordyn.Close(m)


def _block(path: Path, size: int) -> tuple[mmap.mmap, np.ndarray]:
    """The shared block: ``size`` float64 values of the file at ``path`` mapped shared."""
    with open(path, "r+b") as f:
        mm = mmap.mmap(f.fileno(), 8 * size)
    return mm, np.ndarray((size,), np.float64, buffer=mm)


def _size(spec: WorkerSpec) -> int:
    return max(sum(n for _, n in spec.layout().values()), 1)


def main(argv: list[str]) -> None:
    """Worker process entry: ``spec.json`` (beside it, ``block``: the shared block), the socket's fd."""
    folder = Path(argv[0]).parent
    d = json.loads(Path(argv[0]).read_text())
    spec = WorkerSpec(d["file"], d["state"], tuple(d["x"]), d["coupled_points"], tuple(d["fairlead"]), d["nodes"])
    sock = socket.socket(fileno=int(argv[1]))
    mm, block = _block(folder / "block", _size(spec))
    try:
        os.chdir(Path(spec.file).parent)       # MoorDyn writes its outputs beside its file
        _serve(spec, block, sock)
    finally:
        del block
        mm.close()
        sock.close()


# -- the owner's side ---------------------------------------------------------------------------------
class _Worker:
    """One worker process, its socket and its block."""

    def __init__(self, spec: WorkerSpec, label: str, folder: Path):
        self.spec, self.label = spec, label
        self.layout = spec.layout()
        size = _size(spec)
        (folder / "block").write_bytes(bytes(8 * size))
        self.mm, self.block = _block(folder / "block", size)
        self.parts = {k: self.block[a:a + n] for k, (a, n) in self.layout.items()}
        self.console = folder / "console.txt"
        (folder / "spec.json").write_text(json.dumps(spec.__dict__))
        mine, theirs = socket.socketpair()
        self.sock = mine
        code = "import sys; from hydrolink.clients.exudyn.moordyn_workers import main; main(sys.argv[1:])"
        with open(self.console, "wb") as out:
            self.proc = subprocess.Popen([sys.executable, "-c", code, str(folder / "spec.json"), str(theirs.fileno())],
                                         pass_fds=(theirs.fileno(),), stdin=subprocess.DEVNULL,
                                         stdout=out, stderr=subprocess.STDOUT, cwd=str(folder),
                                         start_new_session=True)   # a terminal's Ctrl-C is the run's to handle
        theirs.close()

    def send(self, cmd: bytes) -> None:
        try:
            self.sock.sendall(cmd)
        except OSError:
            raise self._died() from None

    def answer(self) -> None:
        """Wait for the worker's answer (MoorDynWorkerError on a failure or its death)."""
        try:
            got = self.sock.recv(1)
        except OSError:
            got = b""
        if got == b"\0":
            return
        if got == b"E":
            n = struct.unpack("<I", self._read(4))[0]
            raise MoorDynWorkerError(f"{self.label}: {self._read(n).decode('utf-8', 'replace')} "
                                     f"(MoorDyn: {self.said()})")
        raise self._died()

    def _read(self, n: int) -> bytes:
        out = b""
        while len(out) < n:
            chunk = self.sock.recv(n - len(out))
            if not chunk:
                raise self._died()
            out += chunk
        return out

    def said(self) -> str:
        try:
            return complaint(self.console.read_bytes())
        except OSError:
            return "no message"

    def _died(self) -> MoorDynWorkerDied:
        try:
            code = self.proc.wait(timeout=EXIT_TIMEOUT)
        except subprocess.TimeoutExpired:
            code = None
        how = ("did not answer" if code is None else f"was killed by signal {-code}" if code < 0
               else f"ended with exit code {code}")
        return MoorDynWorkerDied(f"{self.label}: its worker process (pid {self.proc.pid}) {how} ({self.said()})")


def _reap(workers: list[_Worker]) -> None:
    """End every worker (asked, then killed) and free its block."""
    for w in workers:
        try:
            w.sock.sendall(b"q")
        except OSError:
            pass
    for w in workers:
        try:
            w.proc.wait(timeout=EXIT_TIMEOUT)
        except subprocess.TimeoutExpired:
            w.proc.kill()
            w.proc.wait()
        w.sock.close()
        w.block = w.parts = None
        try:
            w.mm.close()
        except BufferError:        # a view still held by a caller: the map goes with it
            pass


class WorkerGroups:
    """The groups of one MoorDyn file in worker processes (module docstring).

    ``coupled``: per group, its coupled points' indices in the whole file's; ``body_values``: the
    coupled bodies' values (6 each) at the head of every group's coupled state and forces; the
    forces come back in the whole file's coupled layout, the bodies' summed over the groups in
    group order. ``lines``: per group, its lines' indices in the whole file's."""

    def __init__(self, label: str, specs: list[WorkerSpec], coupled: list[tuple[int, ...]],
                 lines: list[tuple[int, ...]], body_values: int, n_points: int, n_lines: int, folder: Path):
        self.label, self._nb, self._coupled, self._lines = label, body_values, coupled, lines
        n = len(specs)
        self._workers: list[_Worker] = []
        self._finalizer = weakref.finalize(self, _reap, self._workers)
        for k, spec in enumerate(specs):
            sub = folder / f"worker{k + 1}"
            sub.mkdir(exist_ok=True)
            self._workers.append(_Worker(spec, label if n == 1 else f"{label}, group {k + 1} of {n}", sub))
        self._point_index = [np.asarray(c, int) for c in coupled]
        self.forces = np.zeros(body_values + 3 * n_points)
        self.point_mass = np.zeros((n_points, 3, 3))
        self.tensions = np.zeros(n_lines)
        self.end_forces = np.zeros(n_lines)
        nodes = max(s.nodes for s in specs)
        self.nodes = np.full((n_lines, nodes, 3), np.nan) if nodes else None
        self.pending: tuple | None = None        # the inputs of a step launched and not collected
        self.ahead = False                        # that step was started before it was asked for
        self.counts = {"steps": 0, "ahead": 0}
        self._saved = 0

    def started(self) -> None:
        """Wait until every worker has loaded its file and state (MoorDynWorkerError else)."""
        for w in self._workers:
            w.sock.settimeout(START_TIMEOUT)
            try:
                w.answer()
            except TimeoutError:
                raise MoorDynWorkerDied(f"{w.label}: its worker process took more than {START_TIMEOUT:g} s to start "
                                        f"({w.said()})") from None
            finally:
                w.sock.settimeout(None)

    def launch(self, t0: float, dt: float, x0: np.ndarray, v: np.ndarray, ahead: bool = False) -> None:
        """Start a step over [t0, t0 + dt] from the coupled state ``x0`` at velocity ``v``
        (the whole file's coupled layout) in every worker; ``ahead``: before it is asked for."""
        nb = self._nb
        for w, idx in zip(self._workers, self._point_index):
            p = w.parts
            p["t"][0], p["t"][1] = t0, dt
            for dst, src in ((p["x"], x0), (p["v"], v)):
                dst[:nb] = src[:nb]
                if idx.size:
                    dst[nb:] = src[nb:].reshape(-1, 3)[idx].reshape(-1)
        for w in self._workers:
            w.send(b"s")
        self.pending, self.ahead = (t0, dt, x0.copy(), v.copy()), ahead

    def matches(self, dt: float, x0: np.ndarray, v: np.ndarray) -> bool:
        """Whether the step in flight is this one: dt, the coupled state and velocity bit for bit."""
        p = self.pending
        return p is not None and p[1] == dt and np.array_equal(p[2], x0) and np.array_equal(p[3], v)

    def collect(self) -> np.ndarray:
        """Wait for the step in flight; the coupled forces (whole file's layout), with the groups'
        outputs in ``point_mass``, ``tensions``, ``end_forces``, ``nodes``."""
        self.counts["steps"] += 1
        self.counts["ahead"] += self.ahead
        self.pending = None
        self._wait()
        nb, f = self._nb, self.forces
        f[:] = 0.0
        for w, idx, lines in zip(self._workers, self._point_index, self._lines):
            p = w.parts
            f[:nb] += p["f"][:nb]
            if idx.size:
                f[nb:].reshape(-1, 3)[idx] = p["f"][nb:].reshape(-1, 3)
                self.point_mass[idx] = p["mass"].reshape(-1, 3, 3)
            li = list(lines)
            self.tensions[li] = p["tension"]
            self.end_forces[li] = p["end_force"]
            if self.nodes is not None and w.spec.nodes:
                self.nodes[li] = p["nodes"].reshape(len(li), w.spec.nodes, 3)
        return f

    def refuse_ahead(self, what: str) -> None:
        """A step started ahead is in flight and ``what`` is asked instead: wait for it, then the
        error (module docstring)."""
        self.pending = None
        self._wait()
        raise MoorDynWorkerError(f"{self.label}: MoorDyn's next step was started ahead and {what} was asked "
                                 "instead (moorings' workers need every step started ahead to be taken)")

    def save(self) -> int:
        if self.pending is not None:
            self.refuse_ahead("a save")
        self._all(b"v")
        self._saved += 1
        return self._saved

    def restore(self, token: int) -> None:
        if token != self._saved:
            raise MoorDynWorkerError(f"{self.label}: restore of save {token}, the workers hold save {self._saved}")
        if self.pending is not None:
            self.refuse_ahead("a restore")
        self._all(b"r")

    def _all(self, cmd: bytes) -> None:
        for w in self._workers:
            w.send(cmd)
        self._wait()

    def _wait(self) -> None:
        error = None
        for w in self._workers:
            try:
                w.answer()
            except MoorDynWorkerError as exc:
                error = error or exc
        if error is not None:
            raise error

    @property
    def pids(self) -> list[int]:
        return [w.proc.pid for w in self._workers]

    def close(self) -> None:
        """End the workers (MoorDyn closes its output files) and free the blocks."""
        self._finalizer()


def start_groups(label: str, specs: list[WorkerSpec], coupled: list[tuple[int, ...]], lines: list[tuple[int, ...]],
                 body_values: int, n_points: int, n_lines: int, folder: Path) -> WorkerGroups:
    """Start the workers and wait until each has loaded its state; reaped on any failure."""
    groups = WorkerGroups(label, specs, coupled, lines, body_values, n_points, n_lines, folder)
    try:
        groups.started()
    except BaseException:
        groups.close()
        raise
    return groups

