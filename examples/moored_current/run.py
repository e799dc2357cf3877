"""RM3 on MoorDyn in an irregular sea, with and without the current: runs both and plots the spar's
offset and the fairlead tensions.

    python examples/moored_current/run.py [-o OUTDIR]        (default OUTDIR: out/)

Writes the two scenes, OUTDIR/with_current.toml (moored_current.toml as it is) and
OUTDIR/without_current.toml (the same with its [current] left out), their results
OUTDIR/with_current.nc and OUTDIR/without_current.nc, and OUTDIR/moored_current.png; prints the
mean and extreme offset and tensions of both and the files it wrote.
"""

from __future__ import annotations

import argparse
import tomllib
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

from hydrolink.clients.run import run_scene_file  # noqa: E402
from hydrolink.clients.studies.grid import absolute_paths, dump_toml  # noqa: E402

HERE = Path(__file__).resolve().parent
SCENE = HERE / "moored_current.toml"
SETTLED = 200.0        # s: the statistics leave out the ramp and the drift to the current's mean offset


def run(outdir: Path) -> dict[str, Path]:
    """Both runs, each from its scene written to OUTDIR: the scene as it is, and without its [current]."""
    doc = absolute_paths(tomllib.loads(SCENE.read_text()), SCENE)
    scenes = {"with current": doc, "without current": {k: v for k, v in doc.items() if k != "current"}}
    out = {}
    for label, scene in scenes.items():
        name = label.replace(" ", "_")
        (outdir / f"{name}.toml").write_text(dump_toml(scene))
        out[label] = outdir / f"{name}.nc"
        run_scene_file(outdir / f"{name}.toml", out[label], progress=False)
        print(f"wrote {outdir / f'{name}.toml'} and {out[label]}", flush=True)
    return out


def summary(ds: xr.Dataset) -> dict[str, float]:
    """Mean and extreme spar surge (m) and fairlead tension (kN) from SETTLED on."""
    t = ds["time"].values
    keep = t >= SETTLED
    x = (ds["position"] - ds["equilibrium_position"]).sel(body="spar", dof="surge").values[keep]
    ten = ds["line_tension"].values[keep] / 1e3
    return {"surge mean": x.mean(), "surge max": x.max(), "surge std": x.std(),
            **{f"line {i + 1} mean": ten[:, i].mean() for i in range(ten.shape[1])},
            **{f"line {i + 1} max": ten[:, i].max() for i in range(ten.shape[1])}}


def plot(results: dict[str, Path], output: Path) -> None:
    fig, axes = plt.subplots(3, 1, figsize=(9, 9), sharex=True)
    for label, path in results.items():
        with xr.open_dataset(path) as ds:
            t = ds["time"].values
            x = (ds["position"] - ds["equilibrium_position"]).sel(body="spar", dof="surge").values
            axes[0].plot(t, x, label=label, lw=0.8)
            for ax, line in zip(axes[1:], ("1", "2")):
                ax.plot(t, ds["line_tension"].values[:, int(line) - 1] / 1e3, label=label, lw=0.8)
    axes[0].set_ylabel("spar surge [m]")
    axes[0].set_title("RM3 on MoorDyn, JONSWAP Hs 2.5 m Tp 8 s; current 0.3 m/s (1/7 power law) towards +x")
    axes[1].set_ylabel("line 1 tension [kN]\n(anchor downstream)")
    axes[2].set_ylabel("line 2 tension [kN]\n(anchor upstream)")
    axes[2].set_xlabel("time [s]")
    for ax in axes:
        ax.legend(loc="upper right", fontsize="small")
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(output, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--outdir", type=Path, default=Path("out"), help="folder for the scenes, results and plot")
    args = parser.parse_args()
    args.outdir.mkdir(parents=True, exist_ok=True)
    results = run(args.outdir)
    for label, path in results.items():
        with xr.open_dataset(path) as ds:
            print(label + ": " + ", ".join(f"{k} {v:.3g}" for k, v in summary(ds).items()))
    plot(results, args.outdir / "moored_current.png")
    print(f"wrote {args.outdir / 'moored_current.png'}")


if __name__ == "__main__":
    main()
