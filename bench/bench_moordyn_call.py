"""What hydrolink's MoorDyn coupling costs a step beyond MoorDyn's own integration.

    python bench/bench_moordyn_call.py [--steps 400]

For each MoorDyn file of the benchmark suite (the RM3 example's three chains, SEA-Stack's RM3 file
bench/suite/rm3_lines.txt, the five-body array's ten chains), one instance stepped bare
(``cmoordyn.step`` with fixed lists: MoorDyn's substeps and nothing else) and one through
:class:`~hydrolink.clients.exudyn.moordyn_mooring.MoorDynSystem` (``step`` — coupled state from the
body poses, the quiet redirection, the loads about the bodies' reference points — then the results
row's ``tensions`` and ``end_forces``), in interleaved blocks of 20 steps in one process, CPU time
(``time.process_time``). Beside them, MoorDyn's output files' share: one more instance stepped bare
from a copy of the file that writes none (every line's ``LineOutputs`` "-", no OUTPUTS channels,
no log). Also MoorDyn's cost of one call with dt = 0 (nothing integrated) and of hydrolink's fd
redirection around a call alone (``_Quiet``). State the load (printed) beside the figures.
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import tempfile
import time
from pathlib import Path

import numpy as np

from hydrolink.clients.exudyn.moordyn_mooring import MoorDynSystem, read_layout
from hydrolink.clients.exudyn.moordyn_split import sections
from hydrolink.protocol.scene import MoorDynMooring

REPO = Path(__file__).resolve().parents[1]
FIVE = [(0.0, y, -3.0) for y in (-40.0, -20.0, 0.0, 20.0, 40.0)]
CASES = (   # file, coupled scene bodies' reference points, coupling step (s)
    ("examples/rm3_moordyn/lines.dat", [(0.0, 0.0, -21.29)], 0.01),
    ("bench/suite/rm3_lines.txt", [(0.0, 0.0, -21.29)], 0.01),
    ("bench/suite/five_body_lines.dat", FIVE, 0.02),
)


def without_outputs(path: Path) -> Path:
    """A copy of MoorDyn file ``path`` (in a folder of its own) that writes no output file: every
    line's LineOutputs "-", no OUTPUTS channels, writeLog 0."""
    text = path.read_text()
    _, secs = sections(text)
    for sec in secs:
        if sec.kind == "lines":
            for row in sec.rows:
                w = row.split()
                text = text.replace(row, " ".join([*w[:6], "-"]), 1)
        elif sec.kind == "outputs":
            for row in sec.rows:
                text = text.replace(row + "\n", "", 1)
    text = re.sub(r"(?m)^\s*\S+\s+writeLog\b.*$", "0 writeLog", text)
    folder = path.parent / "silent"
    folder.mkdir()
    out = folder / path.name
    out.write_text(text)
    return out


def measure(path: Path, points: list, dt: float, steps: int) -> dict:
    """CPU µs a step: bare MoorDyn with and without its output files, hydrolink's step + outputs,
    MoorDyn's empty call, the quiet redirection alone."""
    import cmoordyn
    names = [f"b{k + 1}" for k in range(len(points))]
    pose = np.array([[*p, 0.0, 0.0, 0.0] for p in points])
    moved = pose.copy()
    moved[:, 0] += 1e-4            # a slow surge drift: every step moves the fairleads
    rows = {n: k for k, n in enumerate(names)}
    silent_path = without_outputs(path)
    systems = []
    for p in (path, path, silent_path):
        spec = MoorDynMooring(type="moordyn", name="m", file=str(p), bodies=names, workers=0)   # in this process
        systems.append(MoorDynSystem(spec, read_layout(p), "moorings[0]", rows, pose))
        systems[-1].start(pose)
    bare, coupled, silent = systems
    x = bare._coupled(pose).tolist()
    v = ((bare._coupled(moved) - bare._coupled(pose)) / dt).tolist()
    tags = ("bare", "silent", "hydrolink")
    cpu = dict.fromkeys(tags, 0.0)
    t = dict.fromkeys(tags, 0.0)
    blocks = max(steps // 20, 2)
    for b in range(blocks):
        for tag in tags if b % 2 == 0 else tags[::-1]:
            c0 = time.process_time()
            if tag in ("bare", "silent"):
                instance = (bare if tag == "bare" else silent).instance
                for _ in range(20):
                    cmoordyn.step(instance, x, v, t[tag], dt)
                    t[tag] += dt
            else:
                for _ in range(20):
                    coupled.step(t[tag], dt, pose, moved)
                    coupled.tensions()
                    coupled.end_forces()
                    t[tag] += dt
            cpu[tag] += time.process_time() - c0
    n = 20 * blocks
    c0 = time.process_time()
    for _ in range(n):
        cmoordyn.step(bare.instance, x, v, t["bare"], 0.0)
    empty = (time.process_time() - c0) / n * 1e6
    c0 = time.process_time()
    for _ in range(n):
        with coupled._quiet():
            pass
    quiet = (time.process_time() - c0) / n * 1e6
    out = {"file": path.name, "dtM": bare.dtm, "substeps": round(dt / bare.dtm), "lines": bare.n_lines,
           "bare_us": cpu["bare"] / n * 1e6, "silent_us": cpu["silent"] / n * 1e6,
           "hydrolink_us": cpu["hydrolink"] / n * 1e6, "empty_call_us": empty, "quiet_us": quiet}
    for system in systems:
        system.close()
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=400, help="steps per file and path")
    args = parser.parse_args()
    print(f"load {os.getloadavg()[0]:.1f}")
    for file, points, dt in CASES:
        with tempfile.TemporaryDirectory() as tmp:     # MoorDyn writes its outputs and log beside its file
            copy = Path(tmp) / Path(file).name
            shutil.copyfile(REPO / file, copy)
            r = measure(copy, points, dt, args.steps) | {"file": file}
        print(f"{r['file']}: {r['lines']} lines, dtM {r['dtM']:g} s ({r['substeps']} substeps a {dt:g} s step): "
              f"bare MoorDyn {r['bare_us']:.0f} CPU µs a step (without its output files {r['silent_us']:.0f}), "
              f"through hydrolink (step + outputs) {r['hydrolink_us']:.0f} (+{r['hydrolink_us'] - r['bare_us']:.0f}); "
              f"an empty call {r['empty_call_us']:.1f}, the redirection alone {r['quiet_us']:.1f}", flush=True)
    print(f"load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
