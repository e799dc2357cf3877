"""hydrolink's numba kernels compiled once for a pytest-xdist run (tests/conftest.py), not once per
worker: on a fresh clone numba's cache (``__pycache__`` beside the kernels' sources) is empty, and
each worker, and each process a test starts, that reaches a kernel before another has written it
compiles it again (the Froude–Krylov kernels: ~46 s of CPU; the fused linear step: ~12 s).

``python tests/numba_warmup.py GROUP`` compiles GROUP's kernels into numba's cache (or loads
them, where they are there), with the signatures the product's own warm-ups compile at set-up:
``linear``, the fused linear step (its state's excitation matrix read-only, as a summed sea gives
it, and writable, as a sea by convolution does) and the Morison kernel; ``froude-krylov``, the
nonlinear Froude–Krylov kernels. The controller starts one process a group before the workers and
holds a lock for it (:func:`start`); a worker waits for a group's lock where it first imports that
group's compiled module (:func:`gate_imports`), so the group is compiled once while the workers run
the tests that need no kernel."""

from __future__ import annotations

import fcntl
import importlib.abc
import importlib.util
import os
import subprocess
import sys
from dataclasses import dataclass
from pathlib import Path

# the module whose first import in a worker waits for its group's compile
GROUPS = {"linear": "hydrolink.server.fused.kernel_numba",
          "froude-krylov": "hydrolink.server.terms.nonlinear.kernels_numba"}


@dataclass(frozen=True)
class Warmup:
    """A group's compiling process, its lock file (held until the process ends) and its log."""

    group: str
    process: subprocess.Popen
    lock: Path
    log: Path


def start(folder: Path) -> list[Warmup]:
    """One process a group compiling its kernels, each holding the lock ``folder``/GROUP.lock from
    before this returns until it exits (the lock taken here on the file description the process
    inherits); output in ``folder``/GROUP.log. None started where numba is not installed."""
    if importlib.util.find_spec("numba") is None:
        return []
    started = []
    for group in GROUPS:
        lock, log = folder / f"{group}.lock", folder / f"{group}.log"
        fd = os.open(lock, os.O_RDWR | os.O_CREAT, 0o600)
        try:
            fcntl.flock(fd, fcntl.LOCK_EX)
            with open(log, "w") as out:
                proc = subprocess.Popen([sys.executable, __file__, group], stdout=out, stderr=subprocess.STDOUT,
                                        pass_fds=(fd,), stdin=subprocess.DEVNULL)
        finally:
            os.close(fd)     # the process's copy keeps the lock
        started.append(Warmup(group, proc, lock, log))
    return started


def finish(warmups: list[Warmup]) -> list[str]:
    """Each process ended (terminated if still running) and reaped; a line for each that failed."""
    failed = []
    for w in warmups:
        if w.process.poll() is None:        # a run shorter than the compile
            w.process.terminate()
        try:
            w.process.wait(60)
        except subprocess.TimeoutExpired:
            w.process.kill()
            w.process.wait()
        if w.process.returncode not in (0, -15):
            failed.append(f"numba warm-up {w.group!r} exited {w.process.returncode} (the tests compiled "
                          f"its kernels themselves): {w.log.read_text().strip()[-2000:]}")
    return failed


class _Gate(importlib.abc.MetaPathFinder):
    """Before a group's module is first imported, wait until its lock is free (its compile done)."""

    def __init__(self, folder: Path):
        self.waiting = {module: folder / f"{group}.lock" for group, module in GROUPS.items()}

    def find_spec(self, fullname, path, target=None):
        lock = self.waiting.pop(fullname, None)
        if lock is not None:
            fd = os.open(lock, os.O_RDWR)
            try:
                fcntl.flock(fd, fcntl.LOCK_SH)       # blocks while the group's process runs
            finally:
                os.close(fd)
        return None                                  # the ordinary finders import it


def gate_imports(folder: Path) -> None:
    """In a worker: each group's module imported only once that group's compile is done."""
    sys.meta_path.insert(0, _Gate(folder))


def compile_group(group: str) -> None:
    """Compile (or load from numba's cache) ``group``'s kernels, as the module docstring says."""
    import numpy as np

    if group == "linear":
        from hydrolink.server.fused.step import FusedLinearStep, FusedRadiation
        from hydrolink.server.terms import morison_kernel

        exc = np.zeros((7, 2))
        summed = exc.copy()
        summed.flags.writeable = False
        for matrix in (summed, exc):
            FusedLinearStep(np.arange(6), matrix, np.ones(1), 0.0, np.zeros((6, 6)), np.zeros(6),
                            FusedRadiation("none")).warm_up(6)
        morison_kernel.warm_up()
    elif group == "froude-krylov":
        from hydrolink.server.terms.nonlinear import hull_kernel, kernels

        kernels.warm_up()
        hull_kernel.warm_up()
    else:
        raise SystemExit(f"numba_warmup.py: no group {group!r} (one of {', '.join(GROUPS)})")


if __name__ == "__main__":
    compile_group(sys.argv[1])
