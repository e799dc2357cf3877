"""WECCCOMP's WaveStar at 1 kHz, paced at wall clock (``hydrolink run --realtime``): with the WAPPAC
controller (examples/wavestar/wappac_damping.py through ``hydrolink control``, its own process,
loopback TCP, a force command every step) and with no controller (the same damper in the PTO).

    python bench/bench_wavestar.py [--seconds 60] [--unpaced-seconds 5]

The scenes are examples/wavestar/wavestar.toml and wavestar_passive.toml as they stand (dt = 1 ms,
state-space radiation, the float's 6 DOFs on the arm's hinge, 330 wave components, three gauges),
shortened to ``--seconds``. Each case: an unpaced run first (what a step costs here: p50/p99 of its
steps' times from their actual start, bench_realtime.step_cost), then the paced one: its steps,
overruns, latency from the scheduled release (p50, p99, max), where the time went and the overrun
flags in its results file beside the summary's count (bench_realtime.breakdown). The goal (issue
36): <= 0.1 % overruns and p99 <= 0.5 ms on a host at load <= 1.5. The load average is printed
before and after: on a loaded 2-core host the figures are the host's as much as the code's.
"""

from __future__ import annotations

import argparse
import os
import secrets
import subprocess
import sys
import tempfile
from pathlib import Path

from bench_realtime import UNPACED, breakdown, free_port, step_cost   # bench/ is on the path

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "wavestar"
HDB = REPO / "examples" / "data" / "wavestar" / "wavestar.out"
TOKEN = secrets.token_urlsafe(32)


def scene(name: str, seconds: float) -> str:
    """The example scene ``name`` shortened to ``seconds``, its HDB by absolute path, no progress bar."""
    text = (EXAMPLE / name).read_text()
    for a, b in (("duration = 141.2 ", f"duration = {seconds} "), ("progress = true", "progress = false"),
                 ('"../data/wavestar/wavestar.out"', f'"{HDB.as_posix()}"')):
        assert a in text, a
        text = text.replace(a, b)
    return text


def run(tmp: Path, controlled: bool, seconds: float, realtime: float):
    """One run (with the WAPPAC controller process when ``controlled``); returns its RunSummary."""
    from hydrolink.clients.run import run_scene_file

    name = "wavestar.toml" if controlled else "wavestar_passive.toml"
    path = tmp / f"{'wappac' if controlled else 'none'}_{'paced' if realtime == 1.0 else 'free'}.toml"
    path.write_text(scene(name, seconds))
    if not controlled:
        return run_scene_file(path, path.with_suffix(".nc"), progress=False, realtime=realtime)
    address = f"tcp://127.0.0.1:{free_port()}"
    ctl = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "control", str(EXAMPLE / "wappac_damping.py"),
                            "--server", address, "--token", TOKEN, "--join-wait", "60"],
                           stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        return run_scene_file(path, path.with_suffix(".nc"), progress=False, listen=address, control_token=TOKEN,
                              realtime=realtime)
    finally:
        try:
            ctl.communicate(timeout=30)
        except subprocess.TimeoutExpired:
            ctl.kill()
            ctl.communicate()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated (= wall) seconds of each paced run")
    ap.add_argument("--unpaced-seconds", type=float, default=5.0, help="simulated seconds of each unpaced run")
    args = ap.parse_args()
    rows, notes = [], []
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        for controlled in (True, False):
            label = "WAPPAC controller" if controlled else "no controller"
            unpaced = run(tmp, controlled, args.unpaced_seconds, UNPACED)
            paced = run(tmp, controlled, args.seconds, 1.0)
            rt = paced.realtime
            c50, c99 = step_cost(unpaced)
            notes.append(breakdown(1000.0, paced).replace("- 1000 Hz", f"- {label}") +
                         f"; unpaced: the server's model {unpaced.server_compute_us_per_step:.1f} µs per step")
            rows.append((label, 1e3 * c50, 1e3 * c99, rt.steps, rt.overruns, 1e3 * rt.worst_lateness,
                         1e3 * rt.latency_p50, 1e3 * rt.latency_p99, 1e3 * rt.latency_max))
            print(f"{label}: unpaced {unpaced.realtime}; paced {rt}", file=sys.stderr, flush=True)
    load1 = os.getloadavg()
    print(f"WaveStar at 1 kHz; load average {load0[0]:.2f} before, {load1[0]:.2f} after ({os.cpu_count()} CPUs)\n")
    print("| case | unpaced step p50 (ms) | unpaced p99 (ms) | paced steps | overruns | worst lateness (ms) | "
          "paced latency p50 (ms) | p99 (ms) | max (ms) |")
    print("|---|---|---|---|---|---|---|---|---|")
    for r in rows:
        print(f"| {r[0]} | {r[1]:.3f} | {r[2]:.3f} | {r[3]} | {r[4]} ({100 * r[4] / max(r[3], 1):.2g} %) | {r[5]:.2f} | "
              f"{r[6]:.3f} | {r[7]:.3f} | {r[8]:.2f} |")
    print()
    for line in notes:
        print(line)


if __name__ == "__main__":
    main()
