"""How much of a controlled run's set-up runs under SCHED_FIFO (``--rt-priority``; docs/realtime.md,
"The priority for the loop only"): ``hydrolink run --realtime --rt-priority N`` (RM3 at 1 kHz,
bench_realtime.scene) and ``hydrolink control --rt-priority N`` (examples/controllers/reactive.py) as
real processes, watched from outside.

    python bench/bench_rt_setup.py [--seconds 3] [--rt-priority 10] [--repeat 2]

Every 2 ms: each process's main thread's policy and CPU time and the process's CPU time
(/proc/PID/task/PID/stat, /proc/PID/stat), and whether the run's results writer process
(hydrolink.clients.lockstep.results, started right before the first paced exchange) exists. Prints
per run when each process was first seen under SCHED_FIFO, and the wall and CPU time it spent under
it before the run's loop (the writer's start), with the load average. Needs CAP_SYS_NICE or
``ulimit -r``.
"""

from __future__ import annotations

import argparse
import os
import secrets
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import bench_realtime

REPO = Path(__file__).resolve().parents[1]
TICK = os.sysconf("SC_CLK_TCK")


def cpu_and_policy(pid: int) -> tuple[int, float, float] | None:
    """(main thread's policy, its CPU s, the process's CPU s); None once the process is gone."""
    try:
        with open(f"/proc/{pid}/task/{pid}/stat") as f:
            main = f.read().rsplit(")", 1)[1].split()
        with open(f"/proc/{pid}/stat") as f:
            whole = f.read().rsplit(")", 1)[1].split()
    except (FileNotFoundError, ProcessLookupError):
        return None
    # fields after the command: utime (14) and stime (15) are [11] and [12], policy (41) is [38]
    return int(main[38]), (int(main[11]) + int(main[12])) / TICK, (int(whole[11]) + int(whole[12])) / TICK


def writer_started(pid: int) -> bool:
    """Whether the run ``pid`` has started its results writer's process (its loop is about to begin)."""
    try:
        with open(f"/proc/{pid}/task/{pid}/children") as f:
            children = f.read().split()
    except FileNotFoundError:
        return False
    for child in children:
        try:
            with open(f"/proc/{child}/cmdline") as f:
                if "lockstep.results" in f.read():
                    return True
        except FileNotFoundError:
            continue
    return False


def one(tmp: Path, seconds: float, priority: int) -> str:
    """One run and its controller; the report's lines."""
    (tmp / "rm3.toml").write_text(bench_realtime.scene(0.001, seconds, "state-space"))
    address, token = f"tcp://127.0.0.1:{bench_realtime.free_port()}", secrets.token_urlsafe(32)
    t0 = time.perf_counter()
    run = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "run", str(tmp / "rm3.toml"), "-o",
                            str(tmp / "rm3.nc"), "--no-progress", "--listen", address, "--control-token", token,
                            "--realtime", "--rt-priority", str(priority)],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    ctl = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "control",
                            str(REPO / "examples" / "controllers" / "reactive.py"), "--server", address, "--token",
                            token, "--join-wait", "120", "--rt-priority", str(priority)],
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    first: dict[str, tuple[float, float, float]] = {}
    loop = None
    try:
        while run.poll() is None:
            now = time.perf_counter() - t0
            seen = {"run": cpu_and_policy(run.pid), "controller": cpu_and_policy(ctl.pid)}
            for name, s in seen.items():
                if s is not None and s[0] == os.SCHED_FIFO and name not in first:
                    first[name] = (now, s[1], s[2])
            if loop is None and writer_started(run.pid):
                loop = (now, seen)
            time.sleep(0.002)
        _, err = run.communicate()
    finally:
        for proc in (run, ctl):
            try:
                proc.wait(60)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait()
    if run.returncode != 0 or loop is None:
        raise RuntimeError(f"the run failed (status {run.returncode}): {err[-500:]}")
    at, seen = loop
    lines = [f"load {os.getloadavg()[0]:.2f}: the run's writer process (its loop next) at {at:.2f} s, the run's "
             f"main thread {seen['run'][1]:.2f} s CPU by then"]
    for name in ("run", "controller"):
        if name not in first:
            lines.append(f"  {name}: never under SCHED_FIFO")
            continue
        t, cpu, cpu_all = first[name]
        if t < at:
            lines.append(f"  {name}: under SCHED_FIFO from {t:.2f} s: {at - t:.2f} s before the run's loop, its main "
                         f"thread {seen[name][1] - cpu:.2f} s CPU, the process {seen[name][2] - cpu_all:.2f} s")
        else:
            lines.append(f"  {name}: under SCHED_FIFO from {t:.2f} s, {t - at:.2f} s after the writer's start: "
                         "none of its set-up")
    return "\n".join(lines)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=3.0, help="simulated (= wall) seconds of each paced run")
    ap.add_argument("--rt-priority", type=int, default=10, metavar="N")
    ap.add_argument("--repeat", type=int, default=2)
    args = ap.parse_args()
    for _ in range(args.repeat):
        with tempfile.TemporaryDirectory() as d:
            print(one(Path(d), args.seconds, args.rt_priority), flush=True)


if __name__ == "__main__":
    main()
