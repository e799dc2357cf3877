"""The WEC Control Competition's figures of a WaveStar run (examples/wavestar), after the ramp.

    python examples/wavestar/report.py wavestar.nc [--json report.json]

Mean absorbed power (the PTO's power, positive when absorbed), the 95th percentiles of the PTO's
|force| and |power| (the competition's "peak" values), their ratio to the mean (the mean-to-peak
power ratio, a utilisation figure), the largest arm rotation and, with a controller, its events.
The mean power is hydrolink's WECCCOMP metric (clients/analysis/optimal/metrics.py); the percentiles
are the competition's own; this script only reads the results file.
"""

from __future__ import annotations

import argparse
import json

import numpy as np
import xarray as xr

from hydrolink.clients.analysis.optimal.metrics import run_metrics
from hydrolink.protocol.scene import parse_scene


def competition_figures(ds: xr.Dataset, pto: str = "pto") -> dict:
    """The figures of the module docstring over t >= the scene's ramp."""
    scene = parse_scene(ds.attrs["scene"])
    t = ds["time"].values
    after = t >= getattr(scene.waves, "ramp", 0.0)
    force = ds["pto_force"].sel(pto=pto).values[after]
    power = ds["pto_power"].sel(pto=pto).values[after]
    pitch = (ds["position"] - ds["equilibrium_position"]).sel(body="arm", dof="pitch").values[after]
    mean = run_metrics(ds, [], start=float(t[after][0])).mean_power   # the one PTO's mean absorbed power
    out = {"window_s": [float(t[after][0]), float(t[-1])], "mean_power_W": mean,
           "force_p95_N": float(np.percentile(np.abs(force), 95)),
           "power_p95_W": float(np.percentile(np.abs(power), 95)),
           "max_arm_rotation_deg": float(np.degrees(np.max(np.abs(pitch))))}
    out["mean_to_peak_power"] = mean / out["power_p95_W"] if out["power_p95_W"] > 0 else float("nan")
    if "controller_events" in ds.attrs:
        out["controller_events"] = json.loads(ds.attrs["controller_events"])
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("results", help="results NetCDF written by `hydrolink run`")
    parser.add_argument("--json", help="also write the figures to this JSON file")
    args = parser.parse_args()
    with xr.open_dataset(args.results) as ds:
        figures = competition_figures(ds.load())
    for key, value in figures.items():
        print(f"{key:24s} {value}")
    if args.json:
        with open(args.json, "w") as fh:
            json.dump(figures, fh, indent=2)


if __name__ == "__main__":
    main()
