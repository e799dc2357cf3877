"""The MPC example (examples/controllers/mpc.py) against the constrained optimum on the WaveBot, and
its QP solve time (docs/optimal-control.md "MPC").

    python bench/bench_mpc.py [--quick] [--cases 0 4 ...]

Each case: ``hydrolink optimize`` of the scene, then ``hydrolink run`` with the MPC joined as an
external controller over the loopback (examples/optimal_control/run_mpc.py ``mpc_run``); mean power
over the last wave periods (regular) or the sea's last repeat period (irregular) against the optimum,
limit utilisation (WECCCOMP metrics of the run) and the solve time of DAQP's solve per
control step (p50/p99/max wall clock, and p99 of the thread's CPU time; the first 10 steps left out). Prints a markdown table and the
machine's load (the solve-time tail is the scheduler's on a loaded machine).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "examples" / "optimal_control"))

CASES = [  # (sea, predictor, rate Hz, duration s, horizon s, PTO efficiency)
    ("regular", "preview", 10.0, 60.0, 4.0, 1.0),
    ("regular", "preview", 100.0, 60.0, 4.0, 1.0),
    ("regular", "gauge", 10.0, 60.0, 4.0, 1.0),
    ("regular", "gauge", 100.0, 60.0, 4.0, 1.0),
    ("regular", "preview", 10.0, 60.0, 4.0, 0.8),
    ("irregular", "preview", 10.0, 120.0, 6.0, 1.0),
    ("irregular", "preview", 100.0, 120.0, 6.0, 1.0),
    ("irregular", "gauge", 10.0, 120.0, 6.0, 1.0),
    ("irregular", "gauge", 100.0, 120.0, 6.0, 1.0),
]


def main() -> None:
    from run_mpc import mpc_run

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="the regular-wave cases only")
    ap.add_argument("--cases", type=int, nargs="+", help="only these rows of CASES (0-based)")
    args = ap.parse_args()
    cases = [c for c in CASES if c[0] == "regular"] if args.quick else CASES
    if args.cases:
        cases = [CASES[i] for i in args.cases]
    print(f"load before: {os.getloadavg()}")
    print("| sea | excitation | rate | efficiency | optimum (W) | MPC (W) | MPC / optimum | max force / limit | "
          "fallbacks | solve p50 (ms) | p99 (ms) | max (ms) | CPU p99 (ms) | period (ms) | load |")
    print("|---|---|---|---|---|---|---|---|---|---|---|---|---|---|---|")
    with tempfile.TemporaryDirectory() as d:
        for sea, predictor, rate, duration, horizon, eta in cases:
            r = mpc_run(Path(d), rate=rate, predictor=predictor, sea=sea, duration=duration, horizon=horizon,
                        efficiency=eta)
            force = next(u for u in r["metrics"].limits if u.label.endswith(".force"))
            opt, mpc, ratio = r["optimum"], r["mpc"], r["ratio"]
            if eta < 1:     # electrical power: the optimum's of the electrical power, the MPC's of the mechanical
                opt, mpc, ratio = r["optimum_electrical"], r["metrics"].electrical_power, r["electrical_ratio"]
            print(f"| {sea} | {predictor} | {rate:g} Hz | {eta:g} | {opt:.2f} | {mpc:.2f} | "
                  f"{100 * ratio:.1f} % | {force.utilisation:.4f} | {r['fallbacks']} | {1e3 * r['solve_p50']:.2f} | "
                  f"{1e3 * r['solve_p99']:.2f} | {1e3 * r['solve_max']:.2f} | {1e3 * r['solve_cpu_p99']:.2f} | "
                  f"{1e3 * r['period']:.0f} | "
                  f"{os.getloadavg()[0]:.1f} |", flush=True)
    print(f"load after: {os.getloadavg()}")


if __name__ == "__main__":
    main()
