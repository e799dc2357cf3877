"""Plot an RM3 run: wave elevation, heave of the float and the spar, PTO power.

    python examples/rm3/plot.py rm3.nc -o rm3.png

The PTO power is the results file's ``pto_power`` when the client wrote it; otherwise it is
recomputed from the bodies' velocities for the scene's linear PTOs (damper part, c (dL/dt)^2, with
dL/dt = (v2 - v1) . e — exact for RM3, whose PTO points are the bodies' reference points).
"""

from __future__ import annotations

import argparse

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

from hydrolink.protocol.scene import LinearPTO, parse_scene  # noqa: E402


def pto_power(ds: xr.Dataset) -> dict[str, np.ndarray]:
    """Power absorbed by each PTO [W] over time."""
    if "pto_power" in ds:
        dim = [d for d in ds["pto_power"].dims if d != "time"][0]
        return {str(n): ds["pto_power"].sel({dim: n}).values for n in ds[dim].values}
    scene = parse_scene(ds.attrs["scene"])
    out = {}
    for p in scene.ptos:
        if not isinstance(p, LinearPTO) or "ground" in (p.body1, p.body2):
            continue
        e = np.subtract(p.point2, p.point1)
        e = e / np.linalg.norm(e)
        v = ds["velocity"].sel(dof=["surge", "sway", "heave"])
        rate = ((v.sel(body=p.body2) - v.sel(body=p.body1)).values @ e)
        out[p.name] = p.damping * rate ** 2
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", help="results NetCDF written by `hydrolink run`")
    parser.add_argument("-o", "--output", default="rm3.png", help="PNG to write")
    args = parser.parse_args()

    ds = xr.open_dataset(args.results)
    t = ds["time"].values
    interaction = parse_scene(ds.attrs["scene"]).hydro.interaction
    fig, axes = plt.subplots(3, 1, figsize=(9, 8), sharex=True)
    axes[0].plot(t, ds["wave_elevation"].values)
    axes[0].set_ylabel("wave elevation [m]")
    axes[0].set_title(f"RM3, interaction = {interaction!r}")
    for body in map(str, ds["body"].values):
        z = ds["position"].sel(body=body, dof="heave") - ds["equilibrium_position"].sel(body=body, dof="heave")
        axes[1].plot(t, z.values, label=body)
    axes[1].set_ylabel("heave [m]")
    axes[1].legend()
    steady = t >= t[-1] - 5 * 8.0
    for name, p in pto_power(ds).items():
        axes[2].plot(t, p / 1e3, label=f"{name}: mean of last 40 s {p[steady].mean() / 1e3:.1f} kW")
    axes[2].set_ylabel("PTO power [kW]")
    axes[2].set_xlabel("time [s]")
    axes[2].legend()
    fig.tight_layout()
    fig.savefig(args.output, dpi=110)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
