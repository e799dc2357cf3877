"""Plot the switching-draft runs: heave with and without the state switch, the state, the heave forces.

    python examples/switching_draft/plot.py switching.nc fixed.nc -o switching_draft.png
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import xarray as xr  # noqa: E402


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("switching", help="results of switching.toml (hydrolink run)")
    parser.add_argument("fixed", help="results of fixed.toml (the nominal HDB throughout)")
    parser.add_argument("-o", "--output", default="switching_draft.png", help="PNG to write")
    args = parser.parse_args()

    sw, fx = xr.open_dataset(args.switching), xr.open_dataset(args.fixed)
    fig, axes = plt.subplots(3, 1, figsize=(9, 7), sharex=True, gridspec_kw={"height_ratios": [3, 1, 3]})
    for ds, label in ((fx, "nominal HDB throughout"), (sw, "switching draft")):
        disp = ds["position"] - ds["equilibrium_position"]
        axes[0].plot(ds["time"], disp.sel(body="cylinder", dof="heave"), label=label)
    for level in (-0.3, -0.1):
        axes[0].axhline(level, color="grey", lw=0.6, ls="--")
    axes[0].set_ylabel("heave [m]")
    axes[0].legend(loc="upper right")
    axes[0].set_title("cylinder: heave (dashed: the rules' thresholds, -0.3 m -> sunk, -0.1 m -> nominal)")
    axes[1].step(sw["time"], sw["hydro_state"], where="post")
    axes[1].set_yticks([0, 1], ["nominal", "sunk"])
    axes[1].set_ylabel("hydro state")
    for var in ("excitation_force", "radiation_force"):
        axes[2].plot(sw["time"], sw[var].sel(body="cylinder", dof="heave"), label=var.replace("_", " "), lw=0.8)
    axes[2].set_ylabel("heave force [N]")
    axes[2].set_xlabel("time [s]")
    axes[2].legend(loc="upper right")
    axes[2].set_xlim(30, 45)
    fig.tight_layout()
    fig.savefig(args.output, dpi=110)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
