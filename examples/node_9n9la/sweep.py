"""9N9LA relative-pitch RAOs of two nodes (R0, O0: the outer arm along the wave direction) for a
sweep of the rotary PTOs' pitch/yaw stiffness K and damping C, regular waves, short runs.

    OPENBLAS_NUM_THREADS=1 python examples/node_9n9la/sweep.py -o sweep.csv --plot sweep.png

RAO = amplitude of pitch(O0) - pitch(R0) (global pitch, about y = the arm's pitch axis) per wave
amplitude (rad/m), fitted (a0 + a cos wt + b sin wt) over the last 4 periods of each run.
"""

from __future__ import annotations

import argparse
import csv
import math
import os
import re
import tempfile
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

from hydrolink.clients.run import run_scene_file  # noqa: E402

HERE = Path(__file__).resolve().parent
PERIODS = (1.0, 1.25, 1.5, 1.75, 2.0, 2.5)                    # s
CASES = ((50.0, 15.0), (150.0, 15.0), (400.0, 15.0), (150.0, 5.0), (150.0, 45.0))   # (K N m/rad, C N m s/rad)
HEIGHT = 0.02                                                # m


def scene_text(period: float, k: float, c: float, duration: float) -> str:
    text = (HERE / "node_9n9la.toml").read_text()
    text = re.sub(r"(?ms)^\[waves\].*?(?=^\[hydro\])",
                  f'[waves]\ntype = "regular"\nheight = {HEIGHT}\nperiod = {period}\nramp = 3.0\n\n', text)
    text = re.sub(r"(?m)^duration = .*$", f"duration = {duration}", text, count=1)
    text = re.sub(r"(?m)^stiffness = \[10.0, [^\]]*\]$", f"stiffness = [10.0, {k}, {k}]", text)
    text = re.sub(r"(?m)^damping = \[0.3, [^\]]*\]$", f"damping = [0.3, {c}, {c}]", text)
    return text.replace('hdb = "', f'hdb = "{HERE}/')


def amplitude(t, x, w, t0):
    m = t >= t0
    a = np.column_stack([np.ones(m.sum()), np.cos(w * t[m]), np.sin(w * t[m])])
    coef, *_ = np.linalg.lstsq(a, x[m], rcond=None)
    return float(np.hypot(coef[1], coef[2]))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("-o", "--output", default="sweep.csv")
    ap.add_argument("--plot", default=None)
    ap.add_argument("--duration", type=float, default=60.0)
    args = ap.parse_args()
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for k, c in CASES:
            for period in PERIODS:
                path = Path(tmp) / "s.toml"
                path.write_text(scene_text(period, k, c, args.duration))
                s = run_scene_file(path, Path(tmp) / "s.nc", progress=False)
                ds = xr.load_dataset(Path(tmp) / "s.nc")
                t, w = ds.time.values, 2 * math.pi / period
                rel = ds.position.sel(body="O0", dof="pitch").values - ds.position.sel(body="R0", dof="pitch").values
                rao = amplitude(t, rel, w, t[-1] - 4 * period) / (HEIGHT / 2)
                power = float(ds.total_pto_power.values[t >= t[-1] - 4 * period].mean()) / (HEIGHT / 2) ** 2
                rows.append({"K": k, "C": c, "period": period, "rel_pitch_rao": rao, "power_per_a2": power,
                             "max_violation": float(ds.joint_violation.max()), "wall_s": s.wall_time})
                print(f"K {k:6g} C {c:5g} T {period:5g} s: RAO {rao:.3f} rad/m, P/a^2 {power:.1f} W/m^2 "
                      f"({s.wall_time:.1f} s)", flush=True)
    with open(args.output, "w", newline="") as fh:
        wr = csv.DictWriter(fh, fieldnames=list(rows[0]))
        wr.writeheader()
        wr.writerows(rows)
    print(f"wrote {args.output}: {len(rows)} runs; largest P/a^2 {max(r['power_per_a2'] for r in rows):.1f} W/m^2")
    if args.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(1, 2, figsize=(10, 4))
        for k, c in CASES:
            r = [x for x in rows if x["K"] == k and x["C"] == c]
            ax[0].plot([x["period"] for x in r], [x["rel_pitch_rao"] for x in r], "o-", label=f"K {k:g}, C {c:g}")
            ax[1].plot([x["period"] for x in r], [x["power_per_a2"] for x in r], "o-", label=f"K {k:g}, C {c:g}")
        ax[0].set(xlabel="wave period (s)", ylabel="relative pitch O0 - R0 (rad/m)", title="9N9LA relative-pitch RAO")
        ax[1].set(xlabel="wave period (s)", ylabel="mean PTO power / a^2 (W/m^2)", title="total PTO power")
        ax[0].legend(fontsize=8)
        fig.tight_layout()
        fig.savefig(args.plot, dpi=90)
        print(f"wrote {args.plot}")


if __name__ == "__main__":
    main()
