"""The Task-10 sphere on MoorDyn in an irregular sea, with and without Newman's slow drift and the
current: runs the four combinations and plots the sphere's offset and two fairlead tensions.

    python examples/moored_drift/run.py [-o OUTDIR] [--duration SECONDS]        (default OUTDIR: out/)

Writes OUTDIR/<variant>.nc and OUTDIR/moored_drift.png, and prints the mean, standard deviation and
maximum surge offset, the mean and maximum fairlead tensions and the mean second-order force of
each run (from SETTLED s on).
"""

from __future__ import annotations

import argparse
import copy
import tomllib
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import xarray as xr  # noqa: E402

from hydrolink.clients.run import run_scene_file  # noqa: E402
from hydrolink.clients.studies.grid import absolute_paths, dump_toml  # noqa: E402

HERE = Path(__file__).resolve().parent
SCENE = HERE / "moored_drift.toml"
SETTLED = 200.0        # s: the statistics leave out the ramp and the drift to the mean offset
# variant name -> ([hydro] second_order, keep [current])
VARIANTS = {"linear": ("none", False), "newman": ("newman", False),
            "linear_current": ("none", True), "newman_current": ("newman", True)}
LABELS = {"linear": "first order only", "newman": "Newman slow drift",
          "linear_current": "first order + current", "newman_current": "Newman slow drift + current"}


def variant(doc: dict, second_order: str, current: bool, duration: float | None = None) -> dict:
    """The scene document with ``[hydro] second_order``, with or without its [current]."""
    out = copy.deepcopy(doc)
    out["hydro"]["second_order"] = second_order
    if not current:
        out.pop("current")
    if duration is not None:
        out["simulation"]["duration"] = duration
    return out


def run(outdir: Path, duration: float | None = None) -> dict[str, Path]:
    """The four runs, each written to OUTDIR/<variant>.nc."""
    doc = absolute_paths(tomllib.loads(SCENE.read_text()), SCENE)
    out = {}
    for name, (second_order, current) in VARIANTS.items():
        scene = outdir / f"{name}.toml"
        scene.write_text(dump_toml(variant(doc, second_order, current, duration)))
        out[name] = outdir / f"{name}.nc"
        run_scene_file(scene, out[name], progress=False)
        print(f"wrote {scene} and {out[name]}", flush=True)
    return out


def surge(ds: xr.Dataset):
    """The sphere's surge offset from its moored still-water equilibrium (m)."""
    return (ds["position"] - ds["equilibrium_position"]).sel(body="sphere", dof="surge").values


def summary(ds: xr.Dataset) -> dict[str, float]:
    """Surge offset (m), fairlead tensions (kN) and second-order surge force (kN) from SETTLED on."""
    keep = ds["time"].values >= SETTLED
    x = surge(ds)[keep]
    ten = ds["line_tension"].values[keep] / 1e3
    return {"surge mean": x.mean(), "surge std": x.std(), "surge max": x.max(),
            **{f"line {i + 1} mean": ten[:, i].mean() for i in range(ten.shape[1])},
            **{f"line {i + 1} max": ten[:, i].max() for i in range(ten.shape[1])},
            "drift force mean": ds["drift_force"].sel(body="sphere", dof="surge").values[keep].mean() / 1e3
            if "drift_force" in ds else 0.0}


def plot(results: dict[str, Path], output: Path) -> None:
    fig, axes = plt.subplots(3, 1, figsize=(9, 9.5), sharex=True)
    for name, path in results.items():
        with xr.open_dataset(path) as ds:
            t = ds["time"].values
            style = dict(lw=0.8, ls="-" if "newman" in name else "--")
            axes[0].plot(t, surge(ds), label=LABELS[name], **style)
            axes[1].plot(t, ds["line_tension"].values[:, 1] / 1e3, label=LABELS[name], **style)
            axes[2].plot(t, ds["line_tension"].values[:, 0] / 1e3, label=LABELS[name], **style)
    axes[0].set_ylabel("sphere surge [m]")
    axes[0].set_title("Task-10 sphere on MoorDyn, JONSWAP Hs 2.5 m Tp 6 s; current 0.5 m/s towards +x")
    axes[1].set_ylabel("line 2 tension [kN]\n(anchor upstream)")
    axes[2].set_ylabel("line 1 tension [kN]\n(anchor downstream)")
    axes[2].set_xlabel("time [s]")
    for ax in axes:
        ax.legend(loc="upper left", fontsize="small", ncol=2)
        ax.grid(alpha=0.3)
    fig.tight_layout()
    fig.savefig(output, dpi=110)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--outdir", type=Path, default=Path("out"), help="folder for the scenes, results and plot")
    parser.add_argument("--duration", type=float, default=None, help="s (default: the scene's)")
    args = parser.parse_args()
    args.outdir.mkdir(parents=True, exist_ok=True)
    results = run(args.outdir, args.duration)
    for name, path in results.items():
        with xr.open_dataset(path) as ds:
            print(f"{LABELS[name]}: " + ", ".join(f"{k} {v:.3g}" for k, v in summary(ds).items()))
    plot(results, args.outdir / "moored_drift.png")
    print(f"wrote {args.outdir / 'moored_drift.png'}")


if __name__ == "__main__":
    main()
