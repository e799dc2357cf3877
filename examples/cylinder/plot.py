"""Plot a cylinder run: wave elevation, heave/surge/pitch motion and the heave forces.

    python examples/cylinder/plot.py examples/cylinder/scene.out.nc -o cylinder.png
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
    parser.add_argument("-o", "--output", default="cylinder.png", help="PNG to write")
    args = parser.parse_args()

    ds = xr.open_dataset(args.results)
    body = str(ds["body"].values[0])
    disp = ds["position"].sel(body=body) - ds["equilibrium_position"].sel(body=body)
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    ds["wave_elevation"].plot(ax=axes[0])
    axes[0].set_title(f"{body}: wave elevation at the origin")
    for dof in ("surge", "heave"):
        disp.sel(dof=dof).plot(ax=axes[1], label=dof)
    axes[1].set_ylabel("displacement [m]")
    axes[1].legend()
    axes[1].set_title("")
    for var in ("excitation_force", "radiation_force", "hydrostatic_force"):
        ds[var].sel(body=body, dof="heave").plot(ax=axes[2], label=var.replace("_", " "))
    axes[2].set_ylabel("heave force [N]")
    axes[2].legend()
    axes[2].set_title("")
    fig.tight_layout()
    fig.savefig(args.output, dpi=110)
    print(f"wrote {args.output}")
    print(run_headline(args.results))     # the run's headline figures (as `hydrolink run` ends with)


if __name__ == "__main__":
    main()
