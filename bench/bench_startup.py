"""CPU seconds a ``hydrolink`` process spends, command by command: what every test, example and
script that starts one pays before (and around) its own work.

    python bench/bench_startup.py [--repeat 3] [--keep DIR]

Each process's CPU (user + system) is read from the kernel when it is reaped (``os.wait4``), so
the figures count the process's own work only, not the time it waited for a core on a loaded
machine; the median of ``--repeat`` runs is printed, with the load average before and after
(state it beside any figure). The commands:

- ``help``: ``hydrolink --help``;
- ``run``: ``hydrolink run`` of the IEA Task-10 sphere (examples/data/sphere_task10) in heave,
  regular waves, 10 steps, embedded force server;
- ``serve`` + ``run --server``: a ``hydrolink serve`` process that answers one such run from a
  ``hydrolink run --server`` process, then is stopped (SIGTERM); both processes' CPU;
- ``control`` (+ its ``run``): the sphere on a linear PTO to ground, driven by
  examples/controllers/passive.py in a ``hydrolink control`` process joining the run's own server
  (``hydrolink run --listen``), 10 steps; both processes' CPU.
- ``import cli``: ``python -c "import hydrolink.clients.cli"``, the module every command loads;
- ``serve's children``: the CPU of the ``serve`` process's children (the forkserver of HDB parses
  and session workers, with what it reaped; multiprocessing's resource tracker) while it answered
  that run, read from /proc before it is stopped (they outlive it unreaped, so ``wait4`` misses them);
- ``serve: first welcome``: wall seconds from starting ``hydrolink serve`` to the ``welcome`` of a
  hello of the sphere (its HDB as a map) sent as soon as it listens, and the hello's own round trip
  (wall clock: noisy under load, compare interleaved runs only).

``--tree DIR`` (repeatable) measures the hydrolink of each DIR (a folder holding a ``hydrolink``
package, e.g. ``git archive 58bba31`` unpacked into DIR/hydrolink; put first on PYTHONPATH),
interleaved command by command: an A/B comparison under the same load.
"""

from __future__ import annotations

import argparse
import math
import os
import re
import secrets
import shutil
import signal
import socket
import statistics
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
SPHERE = REPO / "examples" / "data" / "sphere_task10" / "sphere.h5"
PASSIVE = REPO / "examples" / "controllers" / "passive.py"
HYDROLINK = [sys.executable, "-m", "hydrolink.clients.cli"]
TIMEOUT_S = 600.0

sys.path.insert(0, str(REPO / "tests"))
from conftest import SPHERE_WATER, linear_pto, regular_waves, scene_toml, sphere_body  # noqa: E402  (the tests' scene builder)

BODY = sphere_body("sphere.h5", mass=261800.0, dofs=["heave"])
SCENE = scene_toml(dt=0.05, duration=0.5, progress=False, water=SPHERE_WATER, waves=regular_waves(1.0, 8.0),
                   bodies=[BODY])
# the sphere on a PTO to ground, its force from examples/controllers/passive.py
CONTROLLED = scene_toml(dt=0.05, duration=0.5, progress=False, water=SPHERE_WATER, waves=regular_waves(1.0, 8.0),
                        bodies=[BODY], ptos=[linear_pto("pto", "sphere", [0.0, 0.0, 0.0], "ground", [0.0, 0.0, -20.0],
                                                        damping=0.0)],
                        controllers=[{"name": "passive", "ptos": ["pto"], "command": "force",
                                      "measurements": ["pto_velocity"], "parameters": {"damping": 1.0e5}}])


def _reap(proc: subprocess.Popen) -> float:
    """Wait for ``proc`` and return its CPU seconds (user + system), failing on a non-zero status."""
    _, status, usage = os.wait4(proc.pid, 0)
    proc.returncode = os.waitstatus_to_exitcode(status)
    if proc.returncode not in (0, -signal.SIGTERM):
        raise RuntimeError(f"{proc.args} ended with status {proc.returncode}")
    return usage.ru_utime + usage.ru_stime


def _free_address() -> str:
    with socket.socket() as sock:
        sock.bind(("127.0.0.1", 0))
        return f"tcp://127.0.0.1:{sock.getsockname()[1]}"


def help_cpu(folder: Path) -> dict[str, float]:
    return {"help": _reap(subprocess.Popen([*HYDROLINK, "--help"], cwd=folder, stdout=subprocess.DEVNULL))}


def import_cpu(folder: Path) -> dict[str, float]:
    return {"import cli": _reap(subprocess.Popen([sys.executable, "-c", "import hydrolink.clients.cli"], cwd=folder))}


def run_cpu(folder: Path) -> dict[str, float]:
    proc = subprocess.Popen([*HYDROLINK, "run", "scene.toml", "-o", "run.nc"], cwd=folder, stdout=subprocess.DEVNULL)
    return {"run": _reap(proc)}


def _children_cpu(pid: int) -> float:
    """CPU seconds of the live children of ``pid`` (user + system, with what each has reaped)."""
    tick = os.sysconf("SC_CLK_TCK")
    kids = set()
    for task in Path(f"/proc/{pid}/task").iterdir():
        kids.update((task / "children").read_text().split())
    total = 0
    for kid in kids:
        try:
            fields = Path(f"/proc/{kid}/stat").read_text().rsplit(")", 1)[1].split()
        except FileNotFoundError:
            continue
        total += sum(int(f) for f in fields[11:15])   # utime stime cutime cstime
    return total / tick


def _listening(serve: subprocess.Popen) -> str:
    line = serve.stderr.readline()
    match = re.search(r"listening on (tcp://\S+)", line)
    if not match:
        raise RuntimeError(f"hydrolink serve printed {line!r}")
    return match.group(1)


def first_reply(folder: Path) -> dict[str, float]:
    """Wall seconds from ``hydrolink serve``'s start to its first welcome (a hello sent as soon as it
    listens), and that hello's round trip."""
    import time

    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import parse_scene

    hdbs = load_scene_hdbs(parse_scene(SCENE), folder / "scene.toml", progress=False)
    t0 = time.perf_counter()
    serve = subprocess.Popen([*HYDROLINK, "serve", "--bind", "tcp://127.0.0.1:*"], cwd=folder,
                             stderr=subprocess.PIPE, text=True)
    try:
        address = _listening(serve)
        t1 = time.perf_counter()
        with ServerConnection(address, timeout=TIMEOUT_S) as conn:
            conn.hello(SCENE, hdbs)
            t2 = time.perf_counter()
            conn.bye()
    finally:
        serve.terminate()
        _reap(serve)
    return {"serve: first welcome (wall s)": t2 - t0, "serve: its hello (wall s)": t2 - t1}


def served_cpu(folder: Path) -> dict[str, float]:
    serve = subprocess.Popen([*HYDROLINK, "serve", "--bind", "tcp://127.0.0.1:*"], cwd=folder,
                             stderr=subprocess.PIPE, text=True)
    children = math.nan
    try:
        client = subprocess.Popen([*HYDROLINK, "run", "scene.toml", "-o", "served.nc", "--server", _listening(serve)],
                                  cwd=folder, stdout=subprocess.DEVNULL)
        run = _reap(client)
        children = _children_cpu(serve.pid)
    finally:
        serve.terminate()
    return {"serve (one run)": _reap(serve), "serve's children": children, "run --server": run}


def control_cpu(folder: Path) -> dict[str, float]:
    address, token = _free_address(), secrets.token_urlsafe(32)
    run = subprocess.Popen([*HYDROLINK, "run", "controlled.toml", "-o", "controlled.nc", "--listen", address,
                            "--control-token", token], cwd=folder, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
    control = subprocess.Popen([*HYDROLINK, "control", str(PASSIVE), "--server", address, "--token", token],
                               cwd=folder, stderr=subprocess.DEVNULL)
    try:
        return {"control": _reap(control), "run (with a controller)": _reap(run)}
    finally:
        for proc in (run, control):
            if proc.returncode is None:
                proc.kill()
                proc.wait(TIMEOUT_S)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=3)
    parser.add_argument("--tree", type=Path, action="append",
                        help="A folder holding a hydrolink package to measure (repeatable: interleaved A/B).")
    parser.add_argument("--keep", type=Path, help="Folder to run in (kept); default a temporary one.")
    parser.add_argument("--only", help="Comma-separated measures of help, import, run, served, first, control.")
    args = parser.parse_args()
    folder = args.keep or Path(tempfile.mkdtemp(prefix="hydrolink-startup-"))
    folder.mkdir(parents=True, exist_ok=True)
    shutil.copy(SPHERE, folder / "sphere.h5")
    (folder / "scene.toml").write_text(SCENE)
    (folder / "controlled.toml").write_text(CONTROLLED)
    os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
    load_before = os.getloadavg()
    samples: dict[str, list[float]] = {}
    trees = args.tree or [None]
    measures = [m for m in (help_cpu, import_cpu, run_cpu, served_cpu, first_reply, control_cpu)
                if args.only is None or m.__name__.split("_")[0] in args.only.split(",")]
    try:
        for _ in range(args.repeat):     # interleaved, so a change of load touches every command alike
            for measure in measures:
                for tree in trees:
                    if tree is not None:
                        os.environ["PYTHONPATH"] = str(tree)
                    for name, cpu in measure(folder).items():
                        samples.setdefault(name if tree is None else f"{name} [{tree.name}]", []).append(cpu)
    finally:
        if args.keep is None:
            shutil.rmtree(folder, ignore_errors=True)
    print(f"load average before {load_before[0]:.1f} {load_before[1]:.1f}, after {os.getloadavg()[0]:.1f} "
          f"{os.getloadavg()[1]:.1f}; {args.repeat} runs each")
    print(f"{'process':40s} {'CPU s (median)':>14s}  all")
    for name, values in samples.items():
        print(f"{name:40s} {statistics.median(values):14.2f}  " + " ".join(f"{v:.2f}" for v in values))


if __name__ == "__main__":
    main()
