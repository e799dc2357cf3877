"""Plot an RM3 run: wave elevation, heave of the float and the spar, PTO power.

    python examples/rm3/plot.py rm3.nc -o rm3.png
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import xarray as xr  # noqa: E402

from hydrolink.protocol.scene import parse_scene  # noqa: E402
from hydrolink.clients.cli import run_headline  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", help="results NetCDF written by `hydrolink run`")
    parser.add_argument("-o", "--output", default="rm3.png", help="PNG to write")
    args = parser.parse_args()

    ds = xr.open_dataset(args.results)
    t = ds["time"].values
    scene = parse_scene(ds.attrs["scene"])
    interaction = scene.hydro.interaction
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    axes[0].plot(t, ds["wave_elevation"].values)
    axes[0].set_ylabel("wave elevation [m]")
    axes[0].set_title(f"RM3, interaction = {interaction!r}")
    for body in map(str, ds["body"].values):
        z = ds["position"].sel(body=body, dof="heave") - ds["equilibrium_position"].sel(body=body, dof="heave")
        axes[1].plot(t, z.values, label=body)
    axes[1].set_ylabel("heave [m]")
    axes[1].legend()
    period = getattr(scene.waves, "period", 8.0)
    steady = t > t[-1] - 5 * period + 1e-9          # the last five wave periods
    dim = [d for d in ds["pto_power"].dims if d != "time"][0]
    for name in ds[dim].values:
        p = ds["pto_power"].sel({dim: name}).values
        axes[2].plot(t, p / 1e3, label=f"{name}: mean over the last 5 periods {p[steady].mean() / 1e3:.1f} kW")
        print(f"PTO {name}: mean power over the last 5 wave periods {p[steady].mean() / 1e3:.1f} kW")
    axes[2].set_ylabel("PTO power [kW]")
    axes[2].set_xlabel("time [s]")
    axes[2].legend()
    fig.tight_layout()
    fig.savefig(args.output, dpi=110)
    print(f"wrote {args.output}")
    print(run_headline(args.results))     # the run's headline figures (as `hydrolink run` ends with)


if __name__ == "__main__":
    main()
