"""4N3LA: total PTO power time series (and wave elevation) from a `hydrolink run` results file.

    python examples/node_4n3la/plot.py 4n3la.nc -o 4n3la.png
"""

from __future__ import annotations

import argparse

import numpy as np
import xarray as xr


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("results")
    ap.add_argument("-o", "--output", default="4n3la.png")
    args = ap.parse_args()
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    ds = xr.load_dataset(args.results)
    t = ds.time.values
    total = ds.total_pto_power.values
    names = [str(n) for n in ds.pto.values]
    bending = [n for n in names if not n.endswith(".roll")]       # pitch + yaw: the power take-off
    p_bend = ds.pto_power.sel(pto=bending).values.sum(axis=1)
    steady = t >= min(t[-1] / 2, 20.0)
    fig, ax = plt.subplots(2, 1, figsize=(10, 6), sharex=True)
    ax[0].plot(t, ds.wave_elevation.values, lw=0.7)
    ax[0].set_ylabel("wave elevation (m)")
    ax[1].plot(t, total, lw=0.7, label=f"total (mean {total[steady].mean():.3f} W)")
    ax[1].plot(t, p_bend, lw=0.5, alpha=0.7, label=f"pitch + yaw axes (mean {p_bend[steady].mean():.3f} W)")
    ax[1].set(xlabel="time (s)", ylabel="PTO power (W)")
    ax[1].legend(fontsize=8)
    fig.suptitle("4N3LA: absorbed PTO power, 6 rotary PTOs (pitch + yaw axes; roll = arm spin restraint)")
    fig.tight_layout()
    fig.savefig(args.output, dpi=90)
    print(f"wrote {args.output}")
    print(f"mean total PTO power {total[steady].mean():.4f} W (t >= {t[steady][0]:g} s); max {np.max(total):.3f} W")


if __name__ == "__main__":
    main()
