"""Does one session's set-up stall the others? (issue 22 item 3; server/service/setup_workers.py)

Against a separately started ``hydrolink serve`` over loopback TCP: session A (the IEA Task-10
sphere, examples/data/sphere_task10, heave, regular waves, dt = 0.05 s, irf_duration = 4 s) steps
in lockstep and every round trip is timed by the client. First ``--baseline`` steps alone; then a
second client sends a ``hello`` of the same scene at ``--dt`` (default 2e-6 s: 2e6 IRF samples
over the HDB's 240 frequencies, seconds of set-up) and A keeps stepping until that hello is
answered. Printed: A's round-trip latency p50 / p99 / max in both phases (goal: p99 < 10 ms
during the set-up), the hello's wall time and the server's peak RSS.

    python bench/bench_setup_isolation.py [--dt 2e-6] [--baseline 3000]
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

REPO = Path(__file__).resolve().parents[1]
SPHERE = REPO / "examples" / "data" / "sphere_task10" / "sphere.h5"


def scene(dt: float, duration: float) -> str:
    return f"""
[simulation]
dt = {dt!r}
duration = {duration!r}
[water]
density = 1000.0
gravity = 9.81
depth = 200.0
[waves]
type = "regular"
height = 1.0
period = 8.0
[hydro]
irf_duration = 4.0
[[bodies]]
name = "sphere"
hdb = "{SPHERE.as_posix()}"
mass = 261800.0
center_of_mass = [0.0, 0.0, -2.0]
inertia = [1.0e6, 1.0e6, 1.0e6]
dofs = ["heave"]
"""


def stats(ms: np.ndarray) -> str:
    return (f"{ms.size:6d} steps  p50 {np.percentile(ms, 50):7.3f} ms  p99 {np.percentile(ms, 99):7.3f} ms  "
            f"max {ms.max():8.3f} ms")


def peak_rss_mb(pid: int) -> float:
    text = Path(f"/proc/{pid}/status").read_text()
    return int(re.search(r"VmHWM:\s+(\d+) kB", text).group(1)) / 1024


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--dt", type=float, default=2e-6, help="dt of the concurrent hello [s]")
    parser.add_argument("--baseline", type=int, default=3000, help="steps of A alone")
    args = parser.parse_args()
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    proc = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "serve", "--bind", "tcp://127.0.0.1:*"],
                            stderr=subprocess.PIPE, text=True, env=env)
    address = re.search(r"listening on (tcp://\S+)", proc.stderr.readline()).group(1)
    try:
        text_a = scene(0.05, 20000.0)
        hdbs = load_scene_hdbs(parse_scene(text_a), REPO)
        with ServerConnection(address, timeout=60.0) as a:
            setup = a.hello(text_a, hdbs)
            x = np.array(setup.equilibrium_position, float)
            v = np.zeros_like(x)
            seq = 0

            def step() -> float:
                nonlocal seq
                t0 = time.perf_counter()
                a.step(seq, seq * 0.05, x, v)
                seq += 1
                return (time.perf_counter() - t0) * 1e3

            for _ in range(200):   # warm-up
                step()
            alone = np.array([step() for _ in range(args.baseline)])
            print(f"load average {os.getloadavg()[0]:.2f}; server RSS before the hello {peak_rss_mb(proc.pid):.0f} MB")
            print(f"A alone              {stats(alone)}")
            done: dict = {}

            def hello_b() -> None:
                text_b = scene(args.dt, 0.1)
                with ServerConnection(address, timeout=1800.0) as b:
                    t0 = time.perf_counter()
                    try:
                        b.hello(text_b, hdbs)
                        done["result"] = "welcome"
                    except Exception as exc:  # noqa: BLE001 - reported
                        done["result"] = f"{type(exc).__name__}: {exc}"
                    done["seconds"] = time.perf_counter() - t0

            thread = threading.Thread(target=hello_b)
            thread.start()
            during = []
            while thread.is_alive():
                during.append(step())
            thread.join()
            during = np.array(during)
            print(f"A during the hello   {stats(during)}")
            print(f"hello dt = {args.dt:g}: {done['result']} after {done['seconds']:.2f} s; "
                  f"server peak RSS {peak_rss_mb(proc.pid):.0f} MB; load average {os.getloadavg()[0]:.2f}")
            print(f"steps over 10 ms during the hello: {int((during > 10).sum())} of {during.size}")
    finally:
        proc.terminate()
        proc.wait(10)


if __name__ == "__main__":
    main()
