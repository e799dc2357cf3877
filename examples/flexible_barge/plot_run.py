"""Plot a flexible-barge run of `hydrolink run` (examples/flexible_barge/barge.toml): the rigid
heave, roll and pitch and the three modal coordinates over a window, and each one's spectrum
beside the wave's (the bending modes answer near their wet natural frequencies).

    hydrolink run examples/flexible_barge/barge.toml -o barge_run.nc
    python examples/flexible_barge/plot_run.py barge_run.nc -o barge_run.png
"""

from __future__ import annotations

import argparse

import numpy as np
import xarray as xr
from scipy.signal import welch


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("results", help="the run's results file (hydrolink run ... -o FILE)")
    parser.add_argument("-o", "--output", default="barge_run.png", help="PNG to write")
    parser.add_argument("--window", type=float, nargs=2, default=(300.0, 400.0), metavar=("T0", "T1"),
                        help="the time window shown [s]")
    args = parser.parse_args()
    ds = xr.load_dataset(args.results)
    t = ds["time"].values
    rigid = ds["position"].values[:, 0, :] - ds["equilibrium_position"].values[0]
    dofs = [str(d) for d in ds["dof"].values]
    series = [(name, rigid[:, dofs.index(name)], "m" if name == "heave" else "rad")
              for name in ("heave", "roll", "pitch")]
    # the build's beam modes are scaled to 1 at the beam's ends: a bending coordinate is the ends' deflection
    series += [(str(m).split(".", 1)[1] + " (mode)", ds["modal_position"].values[:, k], "m" if "bend" in str(m) else "rad")
               for k, m in enumerate(ds["mode"].values)]

    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    settled = t >= t[-1] / 2
    fs = 1.0 / float(t[1] - t[0])
    fig, axes = plt.subplots(len(series), 2, figsize=(12, 2.0 * len(series)), sharex="col")
    shown = (t >= args.window[0]) & (t <= args.window[1])
    f_eta, s_eta = welch(ds["wave_elevation"].values[settled], fs=fs, nperseg=2048)
    for (name, x, unit), (ax, sx) in zip(series, axes):
        ax.plot(t[shown], x[shown], lw=0.8)
        ax.set_ylabel(f"{name} [{unit}]")
        ax.grid(True, alpha=0.3)
        f, s = welch(x[settled], fs=fs, nperseg=2048)
        sx.semilogy(2 * np.pi * f, s, label=name)
        sx.semilogy(2 * np.pi * f_eta, s_eta * s.max() / s_eta.max(), lw=0.6, color="grey", label="wave (scaled)")
        sx.set_xlim(0.0, 2.5)
        sx.set_ylim(1e-6 * s.max(), 10 * s.max())
        sx.grid(True, alpha=0.3)
    axes[-1, 0].set_xlabel("t [s]")
    axes[-1, 1].set_xlabel("ω [rad/s]")
    for ax in axes[:, 1]:
        ax.legend(fontsize=8)
    fig.suptitle("Flexible barge in an irregular sea from 30°: rigid DOFs and generalized modes (time domain)")
    fig.tight_layout()
    fig.savefig(args.output, dpi=70)
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
