"""Plot an RM3 + MoorDyn run: wave elevation, float and spar motion, fairlead tensions.

    python examples/rm3_moordyn/plot.py rm3_moordyn.nc -o rm3_moordyn.png
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import xarray as xr  # noqa: E402

from hydrolink.clients.cli import run_headline  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", help="results NetCDF written by `hydrolink run`")
    parser.add_argument("-o", "--output", default="rm3_moordyn.png", help="PNG to write")
    args = parser.parse_args()

    ds = xr.open_dataset(args.results)
    t = ds["time"].values
    x = ds["position"] - ds["equilibrium_position"]
    fig, axes = plt.subplots(4, 1, figsize=(9, 10), sharex=True)
    axes[0].plot(t, ds["wave_elevation"].values)
    axes[0].set_ylabel("wave elevation [m]")
    axes[0].set_title("RM3 on a three-line MoorDyn spread")
    for body in map(str, ds["body"].values):
        axes[1].plot(t, x.sel(body=body, dof="heave").values, label=f"{body} heave")
        axes[2].plot(t, x.sel(body=body, dof="surge").values, label=f"{body} surge")
    axes[1].set_ylabel("heave [m]")
    axes[2].set_ylabel("surge [m]")
    for line in map(str, ds["line"].values):
        axes[3].plot(t, ds["line_tension"].sel(line=line).values / 1e3, label=line)
    axes[3].set_ylabel("fairlead tension [kN]")
    axes[3].set_xlabel("time [s]")
    for ax in axes[1:]:
        ax.legend(loc="upper left", fontsize="small")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(args.output, dpi=110)
    print(f"wrote {args.output}")
    print(run_headline(args.results))     # the run's headline figures (as `hydrolink run` ends with)


if __name__ == "__main__":
    main()
