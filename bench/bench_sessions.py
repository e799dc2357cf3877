"""Many concurrent sessions on one ``hydrolink serve`` each get the forces they get alone, bit for
bit (issue 35, "Done when": 100 concurrent sessions).

A ``hydrolink serve`` over loopback TCP (``--max-sessions`` N + 1, ``--max-setups`` the threads); N
sessions of the heave-only Task-10 sphere (bench_setup_isolation.py's scene), each with motions of
its own (amplitude, frequency and phase from its index), opened and stepped from ``--threads``
threads at once (each thread its sessions round-robin, one step of each in turn: the server answers
them interleaved, over the direct channel). The reference: each session's same steps alone, in this
process on an in-process server (no socket, no other session). Printed: the sessions, steps, the
first difference if any, the served step's latency over all sessions, the load.

    python bench/bench_sessions.py [--sessions 100] [--steps 100] [--threads 10]
"""

from __future__ import annotations

import argparse
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np

from hydrolink.clients.lockstep.connection import ServerConnection
from hydrolink.clients.scene_inputs import load_scene_hdbs
from hydrolink.protocol.scene import parse_scene
from hydrolink.server.service.force_server import ForceServer

from bench_setup_isolation import scene   # bench/ is on the path

REPO = Path(__file__).resolve().parents[1]
DT = 0.05
SCENE = scene(DT, 1e5)
KEYS = ("excitation", "radiation", "hydrostatic")


def motion(i: int, steps: int, x0: np.ndarray) -> list[tuple[np.ndarray, np.ndarray]]:
    """Session ``i``'s states: a heave-and-more oscillation of its own about the equilibrium."""
    a, w, phase = 0.05 + 0.01 * (i % 7), 0.3 + 0.02 * i, 0.1 * i
    t = DT * np.arange(steps)
    return [(x0 + a * np.sin(w * ti + phase), np.full_like(x0, a * w * np.cos(w * ti + phase))) for ti in t]


def step_all(conns: list[ServerConnection], runs: list[list], steps: int) -> list[list[dict]]:
    out: list[list[dict]] = [[] for _ in conns]
    for k in range(steps):
        for j, conn in enumerate(conns):
            x, v = runs[j][k]
            out[j].append({key: np.array(value) for key, value in conn.step(k, k * DT, x, v).items() if key in KEYS})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--sessions", type=int, default=100)
    parser.add_argument("--steps", type=int, default=100)
    parser.add_argument("--threads", type=int, default=10)
    args = parser.parse_args()
    hdbs = load_scene_hdbs(parse_scene(SCENE), REPO)
    proc = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "serve", "--bind", "tcp://127.0.0.1:*",
                             "--max-sessions", str(args.sessions + 1), "--max-setups", str(args.threads)], stderr=subprocess.PIPE, text=True, cwd="/")
    try:
        address = re.search(r"listening on (tcp://\S+)", proc.stderr.readline()).group(1)
        load0 = os.getloadavg()[0]
        served: dict[int, list[dict]] = {}
        motions: dict[int, list] = {}
        latency: list[float] = []
        failures: list[BaseException] = []
        ready = threading.Barrier(args.threads)

        def worker(mine: list[int]) -> None:
            conns = [ServerConnection(address, timeout=600.0) for _ in mine]
            try:
                runs = []
                for i, conn in zip(mine, conns):
                    setup = conn.hello(SCENE, hdbs)
                    motions[i] = motion(i, args.steps, np.array(setup.equilibrium_position, float))
                    runs.append(motions[i])
                ready.wait()   # every session open: all step at once
                t0 = time.perf_counter()
                got = step_all(conns, runs, args.steps)
                latency.append((time.perf_counter() - t0) / (args.steps * len(conns)))
                assert all(c._direct is not None for c in conns), "a session left the direct channel"
                served.update(zip(mine, got))
            except BaseException as exc:   # noqa: BLE001 - said below
                failures.append(exc)
                ready.abort()
            finally:
                for conn in conns:
                    conn.close()

        threads = [threading.Thread(target=worker, args=(list(range(t, args.sessions, args.threads)),))
                   for t in range(args.threads)]
        for th in threads:
            th.start()
        for th in threads:
            th.join()
        if failures:
            raise failures[0]
        load1 = os.getloadavg()[0]
    finally:
        proc.terminate()
        proc.wait(60)
    alone_server = ForceServer(None)   # the reference: each session alone, in process
    differing = []
    for i in range(args.sessions):
        with ServerConnection(alone_server) as conn:
            conn.hello(SCENE, hdbs)
            alone = step_all([conn], [motions[i]], args.steps)[0]
        for k, (a, b) in enumerate(zip(served[i], alone)):
            bad = [key for key in KEYS if not np.array_equal(a[key], b[key])]
            if bad:
                differing.append((i, k, bad))
                break
    print(f"{args.sessions} sessions x {args.steps} steps from {args.threads} threads at once (load {load0:.1f} -> "
          f"{load1:.1f}): {args.sessions - len(differing)} bit-identical to the session alone"
          + (f"; first differences (session, step, keys): {differing[:5]}" if differing else "")
          + f"; served step wall time a session-step {1e3 * float(np.median(latency)):.2f} ms (median over threads)")
    raise SystemExit(1 if differing else 0)


if __name__ == "__main__":
    main()
