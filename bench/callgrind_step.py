"""Instructions per lockstep step by callgrind (valid on a loaded host), beside the bare-Exudyn floor.

    python bench/callgrind_step.py [--short 200] [--long 800] [--cases floor,rm3,rm3-reference,cylinder,cylinder-reference]

Each case runs twice under ``valgrind --tool=callgrind`` (whole program, every thread): ``--short``
and ``--long`` steps at dt 0.01 (results flushed once, at the end: ``flush_seconds`` a day); the
difference of the two totals over the difference of the steps is the cost of one step with
everything a run does per step (start-up, the HDB, the model's set-up and the file's creation
cancel). Cases:

- ``floor``: bench/bench_lockstep.py's bare-Exudyn floor (RM3's linear system in one
  ObjectGenericODE2, a Python PreStep with the radiation convolution and the wave force);
- ``rm3``, ``cylinder``: bench/bench_lockstep.py's scenes run embedded (``hydrolink run``'s
  in-process server), the exchange compiled (clients/exudyn/compiled_exchange.py);
- ``rm3-reference``, ``cylinder-reference``: the same with the reference path (ForceLink,
  LocalStep, the Exudyn client's Python rows: 58bba31's path).

Numba's cached kernels are keyed on the CPU, and valgrind reports another: the first run under
valgrind compiles them (minutes), and there they are unvectorised, so the kernels' share is above
their native one. Figures from the same run of this script compare; the load does not matter.
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


def inner(case: str, steps: int) -> None:
    """One run of ``case`` for ``steps`` steps (in this process: what valgrind counts)."""
    sys.path.insert(0, str(HERE))
    from bench_lockstep import bare_exudyn_us, cylinder_scene, rm3_scene

    logging.disable(logging.WARNING)
    duration = steps * DT
    with tempfile.TemporaryDirectory() as tmp:
        scene = Path(tmp) / "scene.toml"
        if case == "floor":
            scene.write_text(rm3_scene(duration))
            bare_exudyn_us(scene, steps)
            return
        from hydrolink.clients.exudyn import client
        from hydrolink.clients.run import run_scene_file

        text = rm3_scene(duration) if case.startswith("rm3") else cylinder_scene(duration)
        scene.write_text(text.replace("[simulation]\n", "[simulation]\nflush_seconds = 86400.0\n", 1))
        if case.endswith("-reference"):
            client.ExudynMultibody.compiled_exchange = lambda *args: None   # the reference path
        summary = run_scene_file(scene, Path(tmp) / "out.nc", progress=False)
        assert summary.status == "complete" and summary.steps == steps, summary


def instructions(case: str, steps: int, folder: Path) -> int:
    """Callgrind's total instruction count of one run."""
    out = folder / f"{case}.{steps}.out"
    subprocess.run(["valgrind", "--tool=callgrind", f"--callgrind-out-file={out}", sys.executable, __file__,
                    "--inner", case, str(steps)], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    return int(re.search(r"(?m)^(?:summary|totals): (\d+)", out.read_text()).group(1))


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--short", type=int, default=200)
    parser.add_argument("--long", type=int, default=800)
    parser.add_argument("--cases", default="floor,rm3,rm3-reference,cylinder,cylinder-reference")
    parser.add_argument("--inner", nargs=2, metavar=("CASE", "STEPS"), help=argparse.SUPPRESS)
    args = parser.parse_args()
    if args.inner:
        inner(args.inner[0], int(args.inner[1]))
        return
    cases = args.cases.split(",")
    per_step = {}
    with tempfile.TemporaryDirectory() as tmp:
        for case in cases:
            a, b = (instructions(case, n, Path(tmp)) for n in (args.short, args.long))
            per_step[case] = (b - a) / (args.long - args.short)
            print(f"{case}: {per_step[case]:,.0f} instructions a step ({a:,} at {args.short} steps, "
                  f"{b:,} at {args.long})", flush=True)
    floor = per_step.get("floor")
    print(f"\nsteps {args.short} and {args.long} at dt {DT} s; load average {os.getloadavg()[0]:.1f} (no effect on "
          "the counts)\n\n| case | instructions a step | × the floor |\n|---|---|---|")
    for case, ir in per_step.items():
        print(f"| {case} | {ir:,.0f} | {ir / floor:.2f} |" if floor else f"| {case} | {ir:,.0f} | |")


if __name__ == "__main__":
    main()
