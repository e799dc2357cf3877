"""MoorDyn in worker processes (``[[moorings]] workers``): the suite's MoorDyn cases at each worker
count, interleaved, and the cost of the wait a worker's step takes.

    python bench/bench_moordyn_workers.py [--scale 0.05] [--workers 0,1,3] [--repeat 2] [--cases ...]

Runs: bench/bench_suite.py's ``rm3_mooring_irreg_conv`` (SEA-Stack's RM3 MoorDyn file: three
legs, 20 substeps a step) and ``five_body_spreading`` (ten chains), their durations times
``--scale``, each worker count in turn, ``--repeat`` rounds (a first short run warms the caches).
Per run: wall time of the loop (set-up excluded), RTF, µs a step, the run process's CPU time a
step (its every thread, set-up included: compare between counts), the workers' CPU a step (the
children's, less what the workers = 0 run's children took: MoorDyn's layout probe), the steps
started ahead (the log line of moordyn_mooring), the load average.

Wait: one process sends a byte to another, which answers (a blocking ``recv`` on a socket pair,
what the workers use), against both spinning on a shared mapped word; ``--wait-rounds`` round
trips, the sender busy 300 µs between them (the run's own work between MoorDyn steps). On a
machine with fewer free cores than spinning processes, the spinning peer holds a core the other
needs: state the load with the figures.
"""

from __future__ import annotations

import argparse
import logging
import mmap
import os
import re
import resource
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent))
import bench_suite  # noqa: E402

_PEER = r'''
import mmap, socket, sys
import numpy as np
sock, path, mode = socket.socket(fileno=int(sys.argv[1])), sys.argv[2], sys.argv[3]
with open(path, "r+b") as f:
    mm = mmap.mmap(f.fileno(), 64)
word = np.ndarray((8,), np.int64, buffer=mm)
seq = 0
while True:
    if mode == "block":
        c = sock.recv(1)
        if c != b"s":
            break
        sock.sendall(b"\0")
    else:
        seq += 1
        while word[0] != seq:
            if word[0] < 0:
                sys.exit(0)
        word[1] = seq
'''


def wait_cost(mode: str, rounds: int, folder: Path) -> np.ndarray:
    """Round-trip times (µs) of ``rounds`` wake-ups of a peer process by ``mode`` ("block", "spin")."""
    block = folder / "word"
    block.write_bytes(bytes(64))
    mine, theirs = socket.socketpair()
    peer = subprocess.Popen([sys.executable, "-c", _PEER, str(theirs.fileno()), str(block), mode],
                            pass_fds=(theirs.fileno(),))
    theirs.close()
    with open(block, "r+b") as f:
        mm = mmap.mmap(f.fileno(), 64)
    word = np.ndarray((8,), np.int64, buffer=mm)
    out = np.empty(rounds)
    try:
        time.sleep(0.3)
        for k in range(1, rounds + 1):
            t0 = time.perf_counter()
            if mode == "block":
                mine.sendall(b"s")
                mine.recv(1)
            else:
                word[0] = k
                while word[1] != k:
                    pass
            out[k - 1] = time.perf_counter() - t0
            t1 = time.perf_counter()
            while time.perf_counter() - t1 < 300e-6:
                pass
    finally:
        if mode == "block":
            mine.sendall(b"q")
        else:
            word[0] = -1
        peer.wait(timeout=60)
        mine.close()
        del word
        mm.close()
    return out * 1e6


class _Counts(logging.Handler):
    """The steps started ahead, from moordyn_mooring's log line at a system's close."""

    def __init__(self) -> None:
        super().__init__(logging.INFO)
        self.ahead = 0

    def emit(self, record: logging.LogRecord) -> None:
        m = re.search(r"(\d+) of them started ahead", record.getMessage())
        if m:
            self.ahead += int(m.group(1))


def run_once(text: str, workers: int, work: Path, hdbs: dict, counts: _Counts) -> dict:
    from hydrolink.clients.run import run_scene_file
    text = text.replace('type = "moordyn"', f'type = "moordyn"\nworkers = {workers}')
    path = work / f"w{workers}.toml"
    path.write_text(text)
    counts.ahead = 0
    load = os.getloadavg()[0]
    c0 = time.process_time()
    ch0 = resource.getrusage(resource.RUSAGE_CHILDREN)
    s = run_scene_file(path, work / f"w{workers}.nc", progress=False, hdbs=hdbs)
    ch1 = resource.getrusage(resource.RUSAGE_CHILDREN)
    if s.status != "complete":
        raise RuntimeError(f"workers = {workers}: {s.status}")
    return {"workers": workers, "steps": s.steps, "rtf": s.time / s.wall_time, "us": s.wall_time / s.steps * 1e6,
            "cpu_us": (time.process_time() - c0) / s.steps * 1e6,
            "children_us": (ch1.ru_utime + ch1.ru_stime - ch0.ru_utime - ch0.ru_stime) / s.steps * 1e6,
            "ahead": counts.ahead, "load": load}


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--scale", type=float, default=0.05, help="scale the cases' durations (1: 300 s, 200 s)")
    parser.add_argument("--workers", default="0,1,3", help="worker counts, comma-separated")
    parser.add_argument("--repeat", type=int, default=2)
    parser.add_argument("--cases", default="rm3_mooring_irreg_conv,five_body_spreading")
    parser.add_argument("--wait-rounds", type=int, default=2000, help="0: skip the wait measurement")
    args = parser.parse_args()
    logging.getLogger().setLevel(logging.ERROR)     # the scenes' set-up warnings are not what is measured
    counts = _Counts()
    md_log = logging.getLogger("hydrolink.clients.exudyn.moordyn_mooring")
    md_log.setLevel(logging.INFO)
    md_log.addHandler(counts)
    md_log.propagate = False
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        for k in range(2 if args.wait_rounds else 0):
            for mode in ("block", "spin"):
                us = wait_cost(mode, args.wait_rounds, tmp)
                print(f"wait {mode}: round trip median {np.median(us):.1f} µs, p90 {np.percentile(us, 90):.0f}, "
                      f"p99 {np.percentile(us, 99):.0f}; load {os.getloadavg()[0]:.2f}", flush=True)
        from hydrolink.clients.run import run_scene_file
        from hydrolink.clients.scene_inputs import load_scene_hdbs
        from hydrolink.protocol.scene import load_scene
        counts_list = [int(w) for w in args.workers.split(",")]
        for case in (c for c in bench_suite.cases(args.scale) if c.name in args.cases.split(",")):
            work = tmp / case.name
            text = bench_suite._input_copies(case.scenes[0], work)
            short = work / "short.toml"
            short.write_text(re.sub(r"(?m)^duration = .*$", "duration = 0.1", text, count=1))
            scene, _ = load_scene(short)
            hdbs = load_scene_hdbs(scene, short, progress=False)
            run_scene_file(short, work / "warm.nc", progress=False, hdbs=hdbs)
            rows = []
            for r in range(args.repeat):
                for w in counts_list if r % 2 == 0 else counts_list[::-1]:
                    rows.append(run_once(text, w, work, hdbs, counts))
            base = np.median([x["children_us"] for x in rows if x["workers"] == 0]) if 0 in counts_list else 0.0
            for w in counts_list:
                mine = [x for x in rows if x["workers"] == w]
                med = {k: float(np.median([x[k] for x in mine])) for k in ("rtf", "us", "cpu_us", "children_us", "load")}
                print(f"{case.name} workers={w}: RTF {med['rtf']:.2f} [{min(x['rtf'] for x in mine):.2f}-"
                      f"{max(x['rtf'] for x in mine):.2f}], {med['us']:.0f} µs a step; CPU a step: run process "
                      f"{med['cpu_us']:.0f}, workers {med['children_us'] - base:.0f}; steps {mine[0]['steps']}, "
                      f"ahead {mine[0]['ahead']}; load {med['load']:.2f}", flush=True)


if __name__ == "__main__":
    main()
