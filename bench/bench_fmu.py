"""Cost per step of hydrolink's forces through an FMU: the native (C) FMU, the pythonfmu FMU
(``--python``), and the Python client (ServerConnection.step) without an FMU, all against one
``hydrolink serve`` on loopback TCP.

The scene: the Task-10 sphere in heave, regular waves, dt 0.02 s. Each FMU is driven by fmpy from
this script (per step: set displacement and velocity, read the force, doStep), the same loop for
both, so the difference is the FMU itself; the Python client sends the same states. Medians of
``--repeat`` runs of ``--steps`` steps.

    python bench/bench_fmu.py [--steps 3000] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import re
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "examples" / "data"
SCENE = """[simulation]
dt = 0.02
duration = 600.0
[water]
density = 1000.0
depth = 200.0
[waves]
type = "regular"
height = 1.0
period = 6.0
[hydro]
irf_duration = 15.0
[[bodies]]
name = "sphere"
hdb = "sphere.h5"
mass = 261724.0
dofs = ["heave"]
"""


def drive_fmu(path: Path, server: str, steps: int, tmp: Path) -> float:
    """Seconds per step of fmpy driving the FMU (FMI 2.0)."""
    from fmpy import extract, read_model_description
    from fmpy.fmi2 import FMU2Slave
    md = read_model_description(path)
    vr = {v.name: v.valueReference for v in md.modelVariables}
    fmu = FMU2Slave(guid=md.guid, unzipDirectory=extract(path, unzipdir=tempfile.mkdtemp(dir=tmp)),
                    modelIdentifier=md.coSimulation.modelIdentifier, instanceName="bench")
    fmu.instantiate()
    fmu.setupExperiment(startTime=0.0)
    fmu.setString([vr["server_address"]], [server])
    fmu.enterInitializationMode()
    fmu.exitInitializationMode()
    inputs = [vr["sphere.heave.displacement"], vr["sphere.heave.velocity"]]
    force = [vr["sphere.heave.force"]]
    t0 = time.perf_counter()
    for k in range(steps):
        fmu.setReal(inputs, [0.01 * np.sin(0.1 * k), 0.01 * np.cos(0.1 * k)])
        fmu.getReal(force)
        fmu.doStep(k * 0.02, 0.02)
    elapsed = time.perf_counter() - t0
    fmu.terminate()
    fmu.freeInstance()
    return elapsed / steps


def drive_client(folder: Path, server: str, steps: int) -> float:
    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.server.hdb.io import file_set
    with ServerConnection(server) as conn:
        setup = conn.hello(SCENE, {"sphere.h5": file_set(folder / "sphere.h5")})
        pos, vel = setup.equilibrium_position.copy(), np.zeros((1, 6))
        t0 = time.perf_counter()
        for k in range(steps):
            pos[0, 2] = setup.equilibrium_position[0, 2] + 0.01 * np.sin(0.1 * k)
            vel[0, 2] = 0.01 * np.cos(0.1 * k)
            conn.step(k, k * 0.02, pos, vel)
        return (time.perf_counter() - t0) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=3000)
    parser.add_argument("--repeat", type=int, default=3)
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        shutil.copy(DATA / "sphere_task10" / "sphere.h5", tmp / "sphere.h5")
        (tmp / "scene.toml").write_text(SCENE)
        cli = [sys.executable, "-m", "hydrolink.clients.cli"]
        for flag in ("--native", "--python"):
            out = subprocess.run([*cli, "fmu", "export", str(tmp / "scene.toml"), "-o",
                                  str(tmp / f"sphere{flag}.fmu"), flag], capture_output=True, text=True)
            if out.returncode:
                raise SystemExit(out.stderr)
        proc = subprocess.Popen([*cli, "serve", "--bind", "tcp://127.0.0.1:*", "--store", str(tmp / "store")],
                                stderr=subprocess.PIPE, text=True)
        server = re.search(r"listening on (tcp://\S+)", proc.stderr.readline()).group(1)
        try:
            cases = {"native FMU (C), fmpy": lambda: drive_fmu(tmp / "sphere--native.fmu", server, args.steps, tmp),
                     "pythonfmu FMU, fmpy": lambda: drive_fmu(tmp / "sphere--python.fmu", server, args.steps, tmp),
                     "Python client (no FMU)": lambda: drive_client(tmp, server, args.steps)}
            for name, case in cases.items():
                case()   # warm-up: the server's first session, the HDB read once
                times = [case() for _ in range(args.repeat)]
                print(f"{name:26s} {statistics.median(times) * 1e6:8.0f} us/step  "
                      f"[{min(times) * 1e6:.0f}-{max(times) * 1e6:.0f}]")
        finally:
            proc.terminate()
            proc.wait(10)
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
