"""Lockstep throughput: the cylinder example run embedded and against `hydrolink serve` over loopback TCP.

    python bench/bench_lockstep.py [--duration 100] [--repeat 3] [--pin]

Reports steps/s of the whole co-simulation (Exudyn client + round trip + server), the client's own
cost, the round trip, and the server's model compute time per step (measured inside the server and,
separately, by calling the model directly); then the per-request round trip of ``step`` and ``ping``
alone (no Exudyn) as percentiles. The embedded run has the server in-process (no transport).
``--pin`` puts client and server on CPU 0 (``hydrolink serve --cpu 0``): in lockstep nothing runs in
parallel, and waking the other vCPU costs 40-90 µs a hop on this VM.
Numbers are medians over ``--repeat`` runs [min-max]; this machine is noisy, so compare medians.
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

from hydrolink.clients.run import load_scene_hdbs, run_scene_file
from hydrolink.protocol.scene import load_scene

REPO = Path(__file__).resolve().parents[1]
SPEC = REPO / "examples" / "cylinder" / "cylinder_hdb.toml"


def scene_text(duration: float, dofs: str) -> str:
    return f"""\
[simulation]
dt = 0.01
duration = {duration}
progress = false
[water]
density = 1025.0
[waves]
type = "regular"
height = 0.2
period = 3.0
ramp = 10.0
[hydro]
irf_duration = 20.0
[[bodies]]
name = "cylinder"
hdb = "{SPEC}"
mass = 3220.1
center_of_mass = [0.0, 0.0, -0.5]
inertia = [1408.4, 1408.4, 1609.6]
dofs = {dofs}
"""


def model_step_us(scene_path: Path, n: int = 5000) -> float:
    """Median per-step time of HydroModel.step called directly (no protocol, no client)."""
    from hydrolink.server.model import HydroModel

    scene, _ = load_scene(scene_path)
    hdbs = load_scene_hdbs(scene, scene_path, progress=False)
    model = HydroModel(scene, {b.name: hdbs[b.hdb] for b in scene.bodies})
    eq = model.setup_info().equilibrium_position
    v = np.zeros_like(eq)
    times = np.empty(n)
    for k in range(n):
        t0 = time.perf_counter()
        model.step(k * scene.simulation.dt, eq, v)
        times[k] = time.perf_counter() - t0
    return float(np.median(times) * 1e6)


def round_trips_us(address, scene_path: Path, n: int = 3000) -> dict[str, np.ndarray]:
    """Per-request wall time (µs) of ``step`` (one body at equilibrium) and ``ping``, no Exudyn."""
    from hydrolink.clients.connection import ServerConnection

    scene, text = load_scene(scene_path)
    hdbs = load_scene_hdbs(scene, scene_path, progress=False)
    out = {"step": np.empty(n), "ping": np.empty(n)}
    with ServerConnection(address) as conn:
        eq = conn.hello(text, hdbs).equilibrium_position
        v = np.zeros_like(eq)
        for k in range(n):
            t0 = time.perf_counter()
            conn.step(k, k * scene.simulation.dt, eq, v)
            t1 = time.perf_counter()
            conn.ping()
            out["step"][k], out["ping"][k] = (t1 - t0) * 1e6, (time.perf_counter() - t1) * 1e6
    return out


def start_server(pin: bool) -> tuple[subprocess.Popen, str]:
    cmd = [sys.executable, "-m", "hydrolink.clients.cli", "serve", "--bind", "tcp://127.0.0.1:*"]
    if pin:
        cmd += ["--cpu", "0"]
    proc = subprocess.Popen(cmd, stderr=subprocess.PIPE, text=True)
    line = proc.stderr.readline()
    match = re.search(r"listening on (tcp://\S+)", line)
    if not match:
        proc.kill()
        raise RuntimeError(f"server did not start: {line!r}")
    return proc, match.group(1)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--duration", type=float, default=100.0, help="simulated seconds per run (dt = 0.01)")
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--pin", action="store_true", help="pin client and server to CPU 0")
    parser.add_argument("--dofs", default='["heave"]', help='active DOFs, e.g. \'["surge","heave","pitch"]\'')
    args = parser.parse_args()
    if args.pin:
        os.sched_setaffinity(0, {0})

    with tempfile.TemporaryDirectory() as tmp:
        scene_path = Path(tmp) / "scene.toml"
        scene_path.write_text(scene_text(args.duration, args.dofs))
        load_scene_hdbs(load_scene(scene_path)[0], scene_path)  # build / warm the HDB cache first
        rows: dict[str, list[dict]] = {"embedded (in-process server)": [], "loopback TCP (hydrolink serve)": []}
        trips: dict[str, list[dict]] = {name: [] for name in rows}
        for _ in range(args.repeat):
            rows["embedded (in-process server)"].append(
                run_scene_file(scene_path, Path(tmp) / "embedded.nc", progress=False))
            from hydrolink.server.service import ForceServer
            trips["embedded (in-process server)"].append(round_trips_us(ForceServer(None), scene_path))
            proc, address = start_server(args.pin)
            try:
                rows["loopback TCP (hydrolink serve)"].append(
                    run_scene_file(scene_path, Path(tmp) / "tcp.nc", server=address, progress=False))
                trips["loopback TCP (hydrolink serve)"].append(round_trips_us(address, scene_path))
            finally:
                proc.terminate()
                proc.wait(10)
        direct = model_step_us(scene_path)

    steps = int(round(args.duration / 0.01))
    print(f"cylinder, dofs {args.dofs}, dt 0.01 s, irf 20 s, {steps} steps per run, "
          f"median of {args.repeat}{', pinned to CPU 0' if args.pin else ''}\n")
    print("| path | steps/s [min-max] | client µs/step | round trip µs/step | server compute µs/step |")
    print("|---|---|---|---|---|")
    for name, runs in rows.items():
        med = lambda key: statistics.median(r[key] for r in runs)  # noqa: E731
        rate = [r["steps"] / r["wall_time"] for r in runs]
        print(f"| {name} | {statistics.median(rate):.0f} [{min(rate):.0f}-{max(rate):.0f}] | "
              f"{med('client_us_per_step'):.0f} | {med('round_trip_us_per_step'):.0f} | "
              f"{med('server_compute_us_per_step'):.1f} |")
    print(f"\nHydroModel.step called directly: {direct:.1f} µs/step (median)\n")
    print("| path | request | p10 µs | p50 µs | p90 µs | p99 µs |")
    print("|---|---|---|---|---|---|")
    for name, runs in trips.items():
        for req in ("step", "ping"):
            p = np.percentile(np.concatenate([r[req] for r in runs]), [10, 50, 90, 99])
            print(f"| {name} | {req} | " + " | ".join(f"{x:.0f}" for x in p) + " |")


if __name__ == "__main__":
    main()
