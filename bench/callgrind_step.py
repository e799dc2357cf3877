"""Instructions per lockstep step by callgrind (valid on a loaded host), beside the bare-Exudyn floor.

    python bench/callgrind_step.py [--warm 50] [--steps 500] [--cases floor,rm3,rm3-reference,cylinder,cylinder-reference]

Each case runs once under ``valgrind --tool=callgrind --instr-atstart=no``, its instrumentation
switched on at step ``--warm`` and off ``--steps`` steps later (callgrind's client requests, from a
small C library compiled here with gcc and called through ctypes), so only those steps are counted,
every thread included (the results flushed once, at the end: ``flush_seconds`` a day; warm +
steps < 2000 rows, so no block goes to the writer inside the window). Cases, dt 0.01 s:

- ``floor``: bench/bench_lockstep.py's bare-Exudyn floor (RM3's linear system in one
  ObjectGenericODE2, a Python PreStep with the radiation convolution and the wave force), counted
  from its PreStep's call ``--warm``;
- ``rm3``, ``cylinder``: bench/bench_lockstep.py's scenes run embedded (``hydrolink run``'s
  in-process server), the exchange compiled (clients/exudyn/compiled_exchange.py), counted from
  exchange ``--warm``;
- ``rm3-reference``, ``cylinder-reference``: the same with the reference path (ForceLink,
  LocalStep, the Exudyn client's Python rows: 58bba31's path);
- any case of bench/bench_suite.py by its name (``sphere_decay_conv``, ``oswec_reg_batch``, ...; its
  first scene, at its own dt; ``-reference`` likewise) and ``floor:<name>``, that case's bare-Exudyn
  floor (bench_suite.py ``bare_exudyn``), counted from its PreStep's call ``--warm``;
  ``<name>+friction``: that case with regularised Coulomb friction (:data:`FRICTION`) on its
  first revolute joint (``oswec_reg_batch+friction``: the flap's hinge); ``+full``: with ``[client]
  reduce = false`` (no body held or reduced: ``oswec_reg_batch+friction+full`` keeps the base in the
  system, as friction on the hinge did before 68d8335).

``--keep DIR`` keeps callgrind's files (``callgrind_annotate DIR/<case>.out.*`` for where the
instructions go).

The switch is one Python call a step wrapped around the floor's force and each case's exchange
alike. Numba's cached kernels are keyed on the CPU, and valgrind reports another: the first run
under valgrind compiles them, and there they are unvectorised, so the kernels' share is above
their native one. The load does not change the counts.
"""

from __future__ import annotations

import argparse
import logging
import os
import re
import subprocess
import sys
import tempfile
from pathlib import Path

HERE = Path(__file__).resolve().parent
DT = 0.01
#: the joint friction of a ``<case>+friction`` (its first revolute joint's)
FRICTION = "friction = {force = 2.0e5, velocity = 1.0e-2}"


SWITCH = r"""
#include <valgrind/callgrind.h>
void on(void) { CALLGRIND_ZERO_STATS; CALLGRIND_START_INSTRUMENTATION; }
void off(void) { CALLGRIND_STOP_INSTRUMENTATION; CALLGRIND_DUMP_STATS_AT("window"); }
"""


def switch_library(folder: Path) -> Path:
    """The client requests' C library (gcc), compiled into ``folder``."""
    src, lib = folder / "switch.c", folder / "switch.so"
    src.write_text(SWITCH)
    subprocess.run(["gcc", "-O1", "-shared", "-fPIC", "-o", str(lib), str(src)], check=True)
    return lib


def inner(case: str, warm: int, steps: int, library: str) -> None:
    """One run of ``case`` (in this process: what valgrind counts), instrumented over steps
    ``warm`` to ``warm + steps``."""
    import ctypes

    sys.path.insert(0, str(HERE))
    import bench_lockstep

    lib = ctypes.CDLL(library)
    last = warm + steps

    def toggle(k: int) -> None:
        if k == warm:
            lib.on()
        elif k == last:
            lib.off()

    logging.disable(logging.WARNING)
    duration = (last + 10) * DT
    with tempfile.TemporaryDirectory() as tmp:
        scene = Path(tmp) / "scene.toml"
        if case.startswith("floor:"):
            _suite_floor(case[len("floor:"):], Path(tmp), toggle, last + 10)
            return
        if case == "floor":
            _count_floor(toggle)
            scene.write_text(bench_lockstep.rm3_scene(duration))
            bench_lockstep.bare_exudyn_us(scene, last + 10)
            return
        from hydrolink.clients.exudyn import client
        from hydrolink.clients.lockstep import driver
        from hydrolink.clients.run import run_scene_file

        name = case.removesuffix("-reference")
        if name in ("rm3", "cylinder"):
            text = bench_lockstep.rm3_scene(duration) if name == "rm3" else bench_lockstep.cylinder_scene(duration)
        else:
            text = _suite_scene(name, last + 10)
        scene.write_text(text.replace("[simulation]\n", "[simulation]\nflush_seconds = 86400.0\n", 1))
        if case.endswith("-reference"):
            client.ExudynMultibody.compiled_exchange = lambda *args: None   # the reference path
        loop_run = driver.run

        class Counted:
            def __init__(self, scheme):
                self.scheme, self.feedback = scheme, scheme.feedback
                if isinstance(scheme, driver.LoopsItself):   # the compiled exchange's own loop: toggled after each exchange
                    self.prepare = scheme.prepare
                    self.run_exchanges = lambda loop, n, check, paced=None: scheme.run_exchanges(
                        loop, n, lambda: (toggle(loop.step), check()), paced)

            def exchange(self, loop, e, s):
                toggle(e)
                return self.scheme.exchange(loop, e, s)

        driver.run = lambda loop, scheme, *args, **kw: loop_run(loop, Counted(scheme), *args, **kw)
        summary = run_scene_file(scene, Path(tmp) / "out.nc", progress=False)
        assert summary.status == "complete", summary


def _suite_scene(name: str, n_steps: int) -> str:
    """The first scene of bench_suite.py's case ``name``, cut to ``n_steps`` steps of its dt."""
    import bench_suite

    base, *extra = name.split("+")
    case = next((c for c in bench_suite.cases(1.0) if c.name == base), None)
    if case is None or not set(extra) <= {"friction", "full"}:
        raise SystemExit(f"unknown case {name!r}")
    text = case.scenes[0]
    if "friction" in extra:
        text = re.sub(r'(?m)^type = "revolute"$', lambda m: f"{m.group(0)}\n{FRICTION}", text, count=1)
    if "full" in extra:
        text += '\n[client]\ntype = "exudyn"\nreduce = false\n'
    dt = float(re.search(r"(?m)^dt = (.*)$", text).group(1))
    return re.sub(r"(?m)^duration = .*$", f"duration = {n_steps * dt!r}", text, count=1)


def _count_floor(toggle) -> None:
    """bench_lockstep.py's floor (``generic_ode2_us``) made to call ``toggle(k)`` before its PreStep's force k."""
    import bench_lockstep

    ode2 = bench_lockstep.generic_ode2_us

    def counted_ode2(mass, stiffness, damping, force, n_steps, dt):
        def counted(k, q, v):
            toggle(k)
            return force(k, q, v)
        return ode2(mass, stiffness, damping, counted, n_steps, dt)
    bench_lockstep.generic_ode2_us = counted_ode2


def _suite_floor(name: str, folder: Path, toggle, n_steps: int) -> None:
    """bench_suite.py's bare-Exudyn floor of case ``name``, ``toggle(k)`` before its PreStep's force k."""
    import bench_suite

    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import load_scene

    _count_floor(toggle)
    path = folder / "floor.toml"
    path.write_text(_suite_scene(name, n_steps))
    scene, _ = load_scene(path)
    bench_suite.bare_exudyn(path, load_scene_hdbs(scene, path, progress=False))


def instructions(case: str, warm: int, steps: int, folder: Path, library: Path) -> int:
    """Callgrind's instruction count over the window of one run of ``case``."""
    out = folder / f"{case}.out"
    subprocess.run(["valgrind", "--tool=callgrind", "--instr-atstart=no", f"--callgrind-out-file={out}",
                    sys.executable, __file__, "--inner", case, str(warm), str(steps), str(library)],
                   check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    dumps = [p for p in folder.glob(f"{case}.out*") if "window" in p.read_text(errors="replace")[:2000]]
    text = dumps[0].read_text()
    return int(re.search(r"(?m)^totals: (\d+)", text).group(1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--warm", type=int, default=50, help="steps before the window")
    parser.add_argument("--steps", type=int, default=500, help="steps counted")
    parser.add_argument("--cases", default="floor,rm3,rm3-reference,cylinder,cylinder-reference")
    parser.add_argument("--keep", type=Path, help="keep callgrind's files in this folder")
    parser.add_argument("--inner", nargs=4, metavar=("CASE", "WARM", "STEPS", "LIBRARY"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.inner:
        inner(args.inner[0], int(args.inner[1]), int(args.inner[2]), args.inner[3])
        return
    per_step = {}
    with tempfile.TemporaryDirectory() as tmp:
        library = switch_library(Path(tmp))
        folder = args.keep or Path(tmp)
        folder.mkdir(parents=True, exist_ok=True)
        for case in args.cases.split(","):
            per_step[case] = instructions(case, args.warm, args.steps, folder, library) / args.steps
            print(f"{case}: {per_step[case]:,.0f} instructions a step", flush=True)
    floor = per_step.get("floor")
    print(f"\nsteps {args.warm} to {args.warm + args.steps} (floor, rm3, cylinder at dt {DT} s; bench_suite's cases at "
          f"their own); load average {os.getloadavg()[0]:.1f} "
          "(no effect on the counts)\n\n| case | instructions a step | × the floor |\n|---|---|---|")
    for case, ir in per_step.items():
        print(f"| {case} | {ir:,.0f} | {ir / floor:.2f} |" if floor else f"| {case} | {ir:,.0f} | |")


if __name__ == "__main__":
    main()
