"""Results flushing by wall time (``simulation.flush_seconds``): work lost at a SIGKILL, and the
cost per step of the setting.

For each flush interval, a real ``hydrolink run`` (Task-10 sphere in heave, regular waves, dt
0.01 s) is killed with SIGKILL at a random moment after rows appear; the script watches the
results file (each flush changes its size) and reports the wall time since the last flush and
the rows that time held (from the run's own rate, rows on disk / seconds since the first flush).
Then each interval's wall time per step over a 20,000-step run (no kill).

    python bench/bench_flush.py [--kills 3]
"""

from __future__ import annotations

import argparse
import os
import random
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import netCDF4

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "examples" / "data"
HYDROLINK = [sys.executable, "-m", "hydrolink.clients.cli"]
SCENE = """[simulation]
dt = 0.01
duration = {duration}
progress = false
flush_seconds = {flush}
[water]
density = 1000.0
depth = 200.0
[waves]
type = "regular"
height = 1.0
period = 6.0
ramp = 5.0
[hydro]
irf_duration = 10.0
[[bodies]]
name = "sphere"
hdb = "sphere.h5"
mass = 261800.0
center_of_mass = [0.0, 0.0, -2.0]
inertia = [1.0e7, 1.0e7, 1.0e7]
dofs = ["heave"]
"""


def killed_run(work: Path, flush: float, rng: random.Random) -> tuple[float, float]:
    (work / "scene.toml").write_text(SCENE.format(duration=5000.0, flush=flush))
    out = work / "out.nc"
    out.unlink(missing_ok=True)
    proc = subprocess.Popen([*HYDROLINK, "run", "scene.toml", "-o", str(out)], cwd=work,
                            stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    first = last = None
    size, kill_at = -1, None
    while kill_at is None or time.monotonic() < kill_at:
        if out.exists() and out.stat().st_size != size:
            size, last = out.stat().st_size, time.monotonic()
            first = first or last
            if kill_at is None and size > 200_000:
                kill_at = last + 2.0 + rng.uniform(0, 2 * flush)
        time.sleep(0.005)
    proc.send_signal(signal.SIGKILL)
    killed = time.monotonic()
    proc.wait()
    with netCDF4.Dataset(out) as ds:
        rows = ds.dimensions["time"].size
    rate = rows / (last - first) if last > first else float("nan")
    return killed - last, (killed - last) * rate


def step_cost(work: Path, flush: float) -> float:
    (work / "scene.toml").write_text(SCENE.format(duration=200.0, flush=flush))
    r = subprocess.run([*HYDROLINK, "run", "scene.toml", "-o", "cost.nc"], cwd=work, capture_output=True, text=True)
    if r.returncode:
        raise SystemExit(r.stderr)
    import re
    m = re.search(r"wrote .*: (\d+) steps in ([\d.]+) s", r.stdout)
    return 1e6 * float(m.group(2)) / int(m.group(1))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--kills", type=int, default=3)
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench-flush-"))
    shutil.copy(DATA / "sphere_task10" / "sphere.h5", work / "sphere.h5")
    rng = random.Random(1)
    print(f"# bench_flush (load {os.getloadavg()[0]:.2f})\n")
    print("| flush_seconds | wall time lost at SIGKILL (worst of %d) | rows lost (worst) | µs/step (20,000 steps, whole run) |" % args.kills)
    print("|---|---|---|---|")
    try:
        for flush in (0.1, 0.25, 1.0, 5.0):
            lost = [killed_run(work, flush, rng) for _ in range(args.kills)]
            cost = step_cost(work, flush)
            print(f"| {flush:g} | {max(l[0] for l in lost):.2f} s | {max(l[1] for l in lost):.0f} | {cost:.1f} |")
    finally:
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
