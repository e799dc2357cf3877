"""The run's own CPU a controlled step (issue 36, docs/realtime.md): RM3 at 1 kHz with the reactive
example controller (``--case wavestar``: WECCCOMP's WaveStar, examples/wavestar/wavestar.toml, with
its WAPPAC controller wappac_damping.py) in its own process on the run's own polled server's direct channel, unpaced;
the compiled exchange (clients/exudyn/compiled_exchange.py) against the reference path (the same
run with ``ExudynMultibody.compiled_exchange`` switched off), interleaved in one process.

    python bench/bench_controlled_step.py [--case rm3|wavestar] [--seconds 3] [--repeat 3] [--radiation state-space]
                                          [--rt-priority N]

Per run, CPU µs a step from exchange ``--warm`` to the last one's end (the start — the first
step's wait for the controller's join, the kernels' loading, the heap's collection before the
loop — and the last flush left out): the run's process (every thread: the results writer's,
ZeroMQ's I/O thread), the run's thread, and of that thread
what is the controllers' side of the polled server — its loop's turns (``ForceServer.serve_ready``,
``ForceServer.await_local``: reading, unpacking and answering the controller's messages, the wait's
polls) and the relay of the measurements (``ControlHub.relay``: the controller's sample, its
packing and write) — and the rest, **the run's own**: the client, Exudyn's step, the model's
step, the measurements, the decisions and the commands applied. The controller's CPU a step is
its own report (``hydrolink control``). Thread CPU (``time.thread_time``) is what a loaded host
inflates least; the load average is printed beside every run.
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

from bench_realtime import LoopCost, run_controlled, scene
from bench_wavestar import EXAMPLE, scene as wavestar_scene

REPO = Path(__file__).resolve().parents[1]
PARTS = ("serve_ready", "await_local", "relay")   # the controllers' side of the polled server


class Window:
    """CPU of the steps from exchange ``warm`` to the last one's end (the loop's start — the first
    step's wait for the controller's join, the kernels' loading, the heap's collection before a
    paced loop — and the results' last flush left out): the run's process, its thread, and the
    thread's time in the controllers' side of the server (PARTS, wrapped methods)."""

    def __init__(self, warm: int) -> None:
        self.warm, self.open = warm, False
        self.steps = 0
        self.cpu = {"process": 0.0, "thread": 0.0, **dict.fromkeys(PARTS, 0.0)}
        self._undo: list = []

    def wrap(self, owner: type, name: str, part: str | None = None, at=None) -> None:
        """Time ``owner.name`` into ``part`` while the window is open; ``at(e)`` after a call with
        exchange ``e`` (PacedSteps' release and done)."""
        real = getattr(owner, name)
        cpu = self.cpu

        def timed(*args, **kwargs):
            if part is None or not self.open:
                out = real(*args, **kwargs)
                if at is not None:
                    at(args[1])
                return out
            c0 = time.thread_time()
            try:
                return real(*args, **kwargs)
            finally:
                cpu[part] += time.thread_time() - c0
        setattr(owner, name, timed)
        self._undo.append(lambda: setattr(owner, name, real))

    def release(self, e: int) -> None:
        if e == self.warm:
            self.open, self.steps = True, -e
            self._c0 = (time.process_time(), time.thread_time())

    def done(self, e: int, last: int) -> None:
        if self.open and e == last:
            self.open = False
            self.steps += e + 1
            self.cpu["process"] += time.process_time() - self._c0[0]
            self.cpu["thread"] += time.thread_time() - self._c0[1]

    def restore(self) -> None:
        for undo in self._undo:
            undo()


def one(tmp: Path, path: str, seconds: float, radiation: str, rt_priority: int | None, warm: int,
        case: str = "rm3") -> dict:
    """One unpaced controlled run (released at once: ``--realtime 1e9``, bench_realtime.py's
    unpaced run) of ``case`` ("rm3": ``radiation``; "wavestar": the example's, state-space) along
    ``path`` ("compiled" or "reference"): CPU µs a step by part."""
    from hydrolink.clients.exudyn.client import ExudynMultibody
    from hydrolink.clients.lockstep import driver
    from hydrolink.server.service.controllers import ControlHub
    from hydrolink.server.service.force_server import ForceServer

    scene_path = tmp / f"{case}_{path}.toml"
    text = scene(1e-3, seconds, radiation) if case == "rm3" else wavestar_scene("wavestar.toml", seconds)
    scene_path.write_text(text)
    controller = REPO / "examples" / "controllers" / "reactive.py" if case == "rm3" else EXAMPLE / "wappac_damping.py"
    last = int(round(seconds / 1e-3)) - 1
    w = Window(warm)
    for owner, name in ((ForceServer, "serve_ready"), (ForceServer, "await_local"), (ControlHub, "relay")):
        w.wrap(owner, name, name)
    w.wrap(driver.PacedSteps, "release", at=w.release)
    w.wrap(driver.PacedSteps, "done", at=lambda e: w.done(e, last))
    plain_compiled = ExudynMultibody.compiled_exchange
    if path == "reference":
        ExudynMultibody.compiled_exchange = lambda *args: None
    cost = LoopCost()
    load = os.getloadavg()[0]
    try:
        run_controlled(scene_path, controller, 1e9, cost=cost, rt_priority=rt_priority)
    finally:
        ExudynMultibody.compiled_exchange = plain_compiled
        w.restore()
    n = max(w.steps, 1)
    us = {k: 1e6 * v / n for k, v in w.cpu.items()}
    return {"path": path, "load": load, "steps": w.steps, **us, "own": us["thread"] - sum(us[k] for k in PARTS),
            "controller": cost.controller_us}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--case", default="rm3", choices=["rm3", "wavestar"])
    ap.add_argument("--seconds", type=float, default=3.0, help="simulated seconds of each run (3000 steps of 1 ms)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each path, interleaved")
    ap.add_argument("--warm", type=int, default=200, help="exchanges before the counted window")
    ap.add_argument("--radiation", default="state-space", choices=["convolution", "state-space"])
    ap.add_argument("--rt-priority", type=int, default=None, metavar="N",
                    help="the run and the controller under SCHED_FIFO at N (as bench_realtime.py)")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as d:
        for _ in range(args.repeat):
            for path in ("reference", "compiled"):
                rows.append(one(Path(d), path, args.seconds, args.radiation, args.rt_priority, args.warm, args.case))
                print(rows[-1], file=sys.stderr, flush=True)
    cols = ("process", "thread", *PARTS, "own", "controller")
    what = f"RM3 {args.radiation}" if args.case == "rm3" else "WaveStar (wavestar.toml, WAPPAC), state-space"
    print(f"{what}, dt 1 ms, {args.seconds:g} s unpaced a run, CPU µs a step ({os.cpu_count()} CPUs)\n")
    print("| path | load | run's process | run's thread | serve_ready | await_local | relay | **run's own** | controller |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r['path']} | {r['load']:.2f} | " + " | ".join(f"{r[c]:.0f}" for c in cols) + " |")
    for path in ("reference", "compiled"):
        own = [r["own"] for r in rows if r["path"] == path]
        print(f"\n{path}: the run's own µs a step, median {statistics.median(own):.0f} (runs {', '.join(f'{x:.0f}' for x in own)})",
              end="")
    print()


if __name__ == "__main__":
    main()
