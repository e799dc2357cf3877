"""Paced lockstep (docs/realtime.md): RM3 with an external controller over loopback TCP, run at wall
clock (``hydrolink run --realtime``) at 100 Hz, 200 Hz and 1 kHz: overruns and step-latency
percentiles, beside the unpaced cost of a step of the same run.

    python bench/bench_realtime.py [--rates 100 200 1000] [--seconds 60] [--unpaced-seconds 10] [--radiation state-space]

Each rate: the scene's dt = 1/rate, the run's own force server listening on a loopback port, the
example controller examples/controllers/reactive.py in its own process (force command every step,
latency 1 step). The unpaced run is the same setup without --realtime: its wall time per step is
what a step costs here; a paced run can keep its rate only if that cost stays below 1/rate.
Prints a markdown table.
"""

from __future__ import annotations

import argparse
import secrets
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

TOKEN = secrets.token_urlsafe(32)   # the runs' join token, handed to their controllers (SPEC §5.7.2)

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "examples" / "data"
UNPACED = 1e9   # pace factor of the unpaced runs: every release is already past
CONTROLLER = ('\n[[controllers]]\nname = "ctl"\nptos = ["pto"]\ncommand = "force"\ntimeout = 1.0\njoin_timeout = 30.0\n'
              'measurements = ["pto_displacement", "pto_velocity"]\nparameters = { damping = 3.9e5, stiffness = 1.36e6 }\n')


def scene(dt: float, duration: float, radiation: str = "convolution") -> str:
    """examples/rm3/rm3.toml at ``dt``, ``duration`` s, passive damping 0, the reactive controller."""
    text = (REPO / "examples" / "rm3" / "rm3.toml").read_text().replace(
        'interaction = "full"', f'interaction = "full"\nradiation = "{radiation}"')
    for a, b in (('"../data/rm3_wamit/rm3.1"', f'"{(DATA / "rm3_wamit" / "rm3.1").as_posix()}"'),
                 ("duration = 400.0", f"duration = {duration}"), ("dt = 0.08", f"dt = {dt}"),
                 ("ramp = 40.0", "ramp = 10.0"), ("damping = 1.2e6          # N s/m", "damping = 0.0")):
        assert a in text
        text = text.replace(a, b)
    return text + CONTROLLER


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def run(tmp: Path, rate: float, seconds: float, realtime: float | None, radiation: str):
    """One run with the controller process; returns the RunSummary."""
    from hydrolink.clients.run import run_scene_file

    path = tmp / f"rm3_{int(rate)}_{'paced' if realtime else 'free'}.toml"
    path.write_text(scene(1.0 / rate, seconds, radiation))
    port = free_port()
    address = f"tcp://127.0.0.1:{port}"
    ctl = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "control",
                            str(REPO / "examples" / "controllers" / "reactive.py"), "--server", address, "--token", TOKEN,
                            "--join-wait", "60"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        summary = run_scene_file(path, path.with_suffix(".nc"), progress=False, listen=address, control_token=TOKEN, realtime=realtime)
    finally:
        try:
            ctl.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            ctl.kill()
            ctl.communicate()
    return summary


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rates", type=float, nargs="+", default=[100.0, 200.0, 1000.0])
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated (= wall) seconds of each paced run")
    ap.add_argument("--unpaced-seconds", type=float, default=10.0, help="simulated seconds of each unpaced run")
    ap.add_argument("--radiation", default="convolution", choices=["convolution", "state-space"],
                    help="[hydro] radiation: the convolution's cost grows with irf_duration/dt (40 000 samples "
                         "at 1 kHz), the state-space fit's does not")
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for rate in args.rates:
            # unpaced: released at once (a factor no step can keep up with); its latencies are the
            # step costs, measured from the first release (the controller's join left out)
            free = run(tmp, rate, args.unpaced_seconds, UNPACED, args.radiation).realtime
            paced = run(tmp, rate, args.seconds, 1.0, args.radiation)
            rt = paced.realtime
            rows.append((rate, 1e3 / rate, 1e3 * free.latency_p50, 1e3 * free.latency_p99, rt.steps, rt.overruns,
                         1e3 * rt.worst_lateness, 1e3 * rt.latency_p50, 1e3 * rt.latency_p99, 1e3 * rt.latency_max,
                         paced.wall_time))
            print(f"{rate:g} Hz: unpaced {free}; paced {rt}", file=sys.stderr, flush=True)
    print("| rate | budget (ms) | unpaced step p50 (ms) | unpaced p99 (ms) | paced steps | overruns | "
          "worst lateness (ms) | paced latency p50 (ms) | p99 (ms) | max (ms) | loop wall (s) |")
    print("|---|---|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]:g} Hz | {r[1]:.3g} | {r[2]:.3f} | {r[3]:.3f} | {r[4]} | {r[5]} ({100 * r[5] / max(r[4], 1):.2g} %) | "
              f"{r[6]:.2f} | {r[7]:.3f} | {r[8]:.3f} | {r[9]:.2f} | {r[10]:.1f} |")


if __name__ == "__main__":
    main()
