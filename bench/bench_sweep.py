"""``hydrolink sweep`` on Dask: speed-up, per-case overhead, and the same numbers on a separate cluster.

Part 1 (irregular): RM3 (examples/rm3/rm3_irregular.toml: float + spar heave, linear damper PTO,
JONSWAP gamma 3.3) over 4 Hs x 3 Tp, ``--duration`` s at ``--dt`` each (default one hour at 0.05 s,
``--components`` 3000 so that the sea does not repeat within the hour: 2 pi / d(omega) = 3640 s).
12 cases, an even number, so that 2 workers share them equally (9 equal cases on 2 workers take 5
rounds: a speed-up of at most 9/5, measured 1.72x with the fixed costs).

- ``hydrolink sweep --workers 1`` and ``--workers 2`` (each command timed whole: Python start,
  cluster start, HDB load, the cases, sweep.nc and plots): wall time, cases per hour, speed-up;
- every case alone as ``hydrolink run CASE.toml`` (the case's own scene file, written by the sweep),
  one after the other: the per-case overhead of the sweep machinery = (1-worker sweep) / (sum of
  the lone runs) - 1 (negative: the sweep is cheaper, it loads Python and the HDB once per worker);
- ``dask scheduler`` + 2 ``dask worker`` processes on loopback, started separately, and the same
  sweep with ``--scheduler``: every sweep.nc variable but wall_time and every case's results file
  compared with the LocalCluster's, bit for bit.

Part 2 (``--steady``): RM3 in regular waves (examples/rm3/rm3.toml), 2 heights x 7 periods,
``solver = "run"`` (400 s at dt 0.08 s, whole periods after 200 s averaged) against
``solver = "steady"``: mean PTO power difference per case and the per-case and sweep wall times.

The machine's load average is printed with every timing (other jobs share its two cores).

    python bench/bench_sweep.py [--duration 3600] [--dt 0.05] [--components 3000] [--steady]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse
import json
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
HYDROLINK = [sys.executable, "-m", "hydrolink.clients.cli"]


def load() -> str:
    return "load {:.2f} {:.2f} {:.2f}".format(*os.getloadavg())


def timed(cmd: list[str]) -> float:
    t0 = time.perf_counter()
    r = subprocess.run(cmd, capture_output=True, text=True)
    wall = time.perf_counter() - t0
    if r.returncode:
        raise SystemExit(f"{' '.join(cmd)} failed:\n{r.stdout}\n{r.stderr}")
    return wall


def sweep_file(folder: Path, name: str, scene: Path, body: str) -> Path:
    path = folder / f"{name}.toml"
    path.write_text(f'scene = "{scene}"\n' + body)
    return path


def same_results(a: Path, b: Path) -> tuple[bool, str]:
    """Every sweep.nc variable (wall time aside) and every case's results equal bit for bit."""
    import xarray as xr
    da, db = xr.load_dataset(a / "sweep.nc"), xr.load_dataset(b / "sweep.nc")
    for name in da.data_vars:
        if name != "wall_time" and not np.array_equal(da[name].values, db[name].values, equal_nan=da[name].dtype.kind == "f"):
            return False, f"sweep.nc {name} differs"
    for f in sorted((a / "cases").glob("*.nc")):
        x, y = xr.load_dataset(f), xr.load_dataset(b / "cases" / f.name)
        for name in x.data_vars:
            if not np.array_equal(x[name].values, y[name].values, equal_nan=True):
                return False, f"{f.name} {name} differs"
    return True, f"{len(list((a / 'cases').glob('*.nc')))} case files and sweep.nc identical"


def remote_cluster(n: int):
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        port = s.getsockname()[1]
    dask = [sys.executable, "-m", "dask"]
    procs = [subprocess.Popen(dask + ["scheduler", "--host", "127.0.0.1", "--port", str(port), "--no-dashboard"],
                              stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True)]
    address = f"tcp://127.0.0.1:{port}"
    for _ in range(n):
        procs.append(subprocess.Popen(dask + ["worker", address, "--nthreads", "1", "--no-dashboard"],
                                      stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, start_new_session=True))
    from distributed import Client
    with Client(address, timeout="30s") as client:
        client.wait_for_workers(n, timeout=60)
    return address, procs


def stop(procs) -> None:
    for p in procs[::-1]:
        os.killpg(p.pid, signal.SIGTERM)
    for p in procs:
        p.wait(30)


def part_irregular(args, work: Path) -> None:
    scene = REPO / "examples" / "rm3" / "rm3_irregular.toml"
    sweep = sweep_file(work, "irregular", scene,
                       f'window = [{min(100.0, args.duration / 2)}, {args.duration}]\n'
                       f'[set]\n"simulation.duration" = {args.duration}\n"simulation.dt" = {args.dt}\n'
                       f'"waves.ramp" = 50.0\n"waves.components" = {args.components}\n[grid]\n"waves.hs" = [1.5, 2.5, 3.5, 4.5]\n"waves.tp" = [7.0, 9.0, 11.0]\n')
    n = 12
    print(f"## RM3 irregular: 4 Hs x 3 Tp, {args.duration:g} s at dt {args.dt:g} s ({int(args.duration / args.dt)} "
          f"steps per case), {args.components} wave components\n")
    walls = {}
    for workers in (1, 2):
        out = work / f"local{workers}"
        before = load()
        walls[workers] = timed(HYDROLINK + ["sweep", str(sweep), "-o", str(out), "--workers", str(workers),
                                            "--no-progress"])
        print(f"- {workers} worker(s): {walls[workers]:.1f} s, {3600 * n / walls[workers]:.0f} cases/hour "
              f"({before} -> {load()})")
    print(f"- speed-up 2 workers / 1: {walls[1] / walls[2]:.2f}x")
    records = [json.loads(p.read_text()) for p in (work / "local1" / "cases").glob("*.json")]
    in_worker = sum(r["wall_time"] for r in records)
    lone = 0.0
    before = load()
    for p in sorted((work / "local1" / "cases").glob("*.toml")):
        lone += timed(HYDROLINK + ["run", str(p), "-o", str(work / "lone.nc"), "--no-progress"])
    print(f"- lone `hydrolink run` of the {n} cases one after the other: {lone:.1f} s ({lone / n:.2f} s per case; "
          f"{before} -> {load()}); the 1-worker sweep per case: {walls[1] / n:.2f} s, overhead "
          f"{100 * (walls[1] / lone - 1):+.1f} %; inside the worker a case takes {in_worker / n:.2f} s")
    address, procs = remote_cluster(2)
    try:
        before = load()
        wall = timed(HYDROLINK + ["sweep", str(sweep), "-o", str(work / "remote"), "--scheduler", address,
                                  "--no-progress"])
    finally:
        stop(procs)
    same, why = same_results(work / "local2", work / "remote")
    print(f"- `dask scheduler` + 2 `dask worker` on loopback: {wall:.1f} s ({before} -> {load()}); "
          f"same results as the LocalCluster, bit for bit: {'yes' if same else 'NO'} ({why})\n")


def part_steady(work: Path) -> None:
    import xarray as xr
    scene = REPO / "examples" / "rm3" / "rm3.toml"
    grid = '[grid]\n"waves.height" = [1.0, 2.5]\n"waves.period" = [6.0, 7.0, 8.0, 9.0, 10.0, 11.0, 12.0]\n'
    out = {}
    for solver in ("run", "steady"):
        sweep = sweep_file(work, f"regular_{solver}", scene, f'solver = "{solver}"\nwindow = [200.0, 400.0]\n' + grid)
        before = load()
        wall = timed(HYDROLINK + ["sweep", str(sweep), "-o", str(work / solver), "--workers", "2", "--no-progress"])
        ds = xr.load_dataset(work / solver / "sweep.nc")
        out[solver] = (wall, ds)
        print(f"- solver {solver}: sweep {wall:.1f} s, per case {float(ds.wall_time.mean()):.3f} s inside the worker "
              f"({before} -> {load()})")
    p_run, p_st = out["run"][1].mean_total_pto_power.values, out["steady"][1].mean_total_pto_power.values
    rel = np.abs(p_st / p_run - 1)
    speed = float(out["run"][1].wall_time.mean() / out["steady"][1].wall_time.mean())
    print(f"- mean PTO power, steady against run: max {100 * rel.max():.3f} %, mean {100 * rel.mean():.3f} % over "
          f"{rel.size} cases; per-case speed-up {speed:.0f}x, whole sweep {out['run'][0] / out['steady'][0]:.2f}x\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=3600.0, help="s simulated per irregular case")
    ap.add_argument("--components", type=int, default=3000, help="wave components of the irregular cases")
    ap.add_argument("--dt", type=float, default=0.05)
    ap.add_argument("--steady", action="store_true", help="also part 2 (regular waves: run against steady)")
    ap.add_argument("--keep", type=Path, help="keep the outputs in this folder")
    args = ap.parse_args()
    work = Path(tempfile.mkdtemp(prefix="bench-sweep-"))
    try:
        print(f"# bench_sweep ({os.cpu_count()} CPUs; {load()})\n")
        part_irregular(args, work)
        if args.steady:
            print("## RM3 regular: 2 H x 7 T, time domain against steady state (2 workers)\n")
            part_steady(work)
    finally:
        if args.keep:
            shutil.copytree(work, args.keep, dirs_exist_ok=True)
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
