"""WECCCOMP's WaveStar at 1 kHz, paced at wall clock (``hydrolink run --realtime``): with the WAPPAC
controller (examples/wavestar/wappac_damping.py through ``hydrolink control``, its own process,
loopback TCP, a force command every step) and with no controller (the same damper in the PTO).

    python bench/bench_wavestar.py [--seconds 60] [--unpaced-seconds 5] [--rt-priority N]

The scenes are examples/wavestar/wavestar.toml and wavestar_passive.toml as they stand (dt = 1 ms,
state-space radiation, the float's 6 DOFs on the arm's hinge, 330 wave components, three gauges),
shortened to ``--seconds``. Each case: an unpaced run first (what a step costs here: p50/p99 of its
steps' times from their actual start, bench_realtime.step_cost), then the paced one: its steps,
overruns, latency from the scheduled release (p50, p99, max), where the time went and the overrun
flags in its results file beside the summary's count (bench_realtime.breakdown). The goal (issue
36): <= 0.1 % overruns and p99 <= 0.5 ms on a host at load <= 1.5. The load average is printed
before and after: on a loaded 2-core host the figures are the host's as much as the code's.
``--rt-priority N``: the run and the controller process under SCHED_FIFO at N (bench_realtime's).
"""

from __future__ import annotations

import argparse
import json
import os
import platform
import sys
import tempfile
from pathlib import Path

from bench_realtime import UNPACED, breakdown, run_controlled, step_cost   # bench/ is on the path

REPO = Path(__file__).resolve().parents[1]
EXAMPLE = REPO / "examples" / "wavestar"
HDB = REPO / "examples" / "data" / "wavestar" / "wavestar.out"


def scene(name: str, seconds: float) -> str:
    """The example scene ``name`` shortened to ``seconds``, its HDB by absolute path, no progress bar."""
    text = (EXAMPLE / name).read_text()
    for a, b in (("duration = 141.2 ", f"duration = {seconds} "), ("progress = true", "progress = false"),
                 ('"../data/wavestar/wavestar.out"', f'"{HDB.as_posix()}"')):
        assert a in text, a
        text = text.replace(a, b)
    return text


def run(tmp: Path, controlled: bool, seconds: float, realtime: float, rt_priority: int | None = None):
    """One run (with the WAPPAC controller process when ``controlled``); returns its RunSummary.
    ``rt_priority``: the run's loop and the controller's under SCHED_FIFO at that priority."""
    from hydrolink.clients.run import run_scene_file

    name = "wavestar.toml" if controlled else "wavestar_passive.toml"
    path = tmp / f"{'wappac' if controlled else 'none'}_{'paced' if realtime == 1.0 else 'free'}.toml"
    path.write_text(scene(name, seconds))
    if controlled:
        return run_controlled(path, EXAMPLE / "wappac_damping.py", realtime, rt_priority=rt_priority)
    return run_scene_file(path, path.with_suffix(".nc"), progress=False, realtime=realtime, rt_priority=rt_priority)


def case(tmp: Path, controlled: bool, seconds: float, unpaced_seconds: float, rt_priority: int | None = None) -> dict:
    """The unpaced and the paced run of one case: what a step costs, what the pacing kept."""
    unpaced = run(tmp, controlled, unpaced_seconds, UNPACED, rt_priority)
    paced = run(tmp, controlled, seconds, 1.0, rt_priority)
    rt = paced.realtime
    c50, c99 = step_cost(unpaced)
    return {"controller": "WAPPAC wappac_damping.py" if controlled else None,
            "unpaced_step_ms": {"p50": 1e3 * c50, "p99": 1e3 * c99},
            "server_model_us_per_step": unpaced.server_compute_us_per_step,
            "paced": {"steps": rt.steps, "overruns": rt.overruns, "overrun_percent": 100 * rt.overruns / max(rt.steps, 1),
                      "worst_lateness_ms": 1e3 * rt.worst_lateness, "latency_ms": {
                          "p50": 1e3 * rt.latency_p50, "p99": 1e3 * rt.latency_p99, "max": 1e3 * rt.latency_max}},
            "where": breakdown(1000.0, paced).removeprefix("- 1000 Hz: ")}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seconds", type=float, default=60.0, help="simulated (= wall) seconds of each paced run")
    ap.add_argument("--unpaced-seconds", type=float, default=5.0, help="simulated seconds of each unpaced run")
    ap.add_argument("--json", help="also write the figures to this file")
    ap.add_argument("--rt-priority", type=int, default=None, metavar="N",
                    help="the run and the controller under SCHED_FIFO at N (1-98; needs CAP_SYS_NICE or ulimit -r)")
    args = ap.parse_args()
    load0 = os.getloadavg()
    with tempfile.TemporaryDirectory() as d:
        cases = {label: case(Path(d), controlled, args.seconds, args.unpaced_seconds, args.rt_priority)
                 for label, controlled in (("wappac", True), ("no_controller", False))}
    out = {"case": "WECCCOMP WaveStar, dt 1 ms, paced at 1 kHz", "machine": platform.node(),
           "processor": platform.processor() or platform.machine(), "cpus": os.cpu_count(),
           "load_average_before": load0[0], "load_average_after": os.getloadavg()[0],
           "rt_priority": args.rt_priority,
           "goal": "<= 0.1 % overruns and p99 <= 0.5 ms at load <= 1.5", "cases": cases}
    text = json.dumps(out, indent=2)
    print(text)
    if args.json:
        Path(args.json).write_text(text)
    print(f"load {out['load_average_before']:.2f} -> {out['load_average_after']:.2f}", file=sys.stderr)


if __name__ == "__main__":
    main()
