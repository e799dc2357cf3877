"""The weathervaning barge (passive_yaw.toml) with and without passive yaw: runs both and plots the
barge's yaw against the waves' direction.

    python examples/passive_yaw/run.py [-o OUTDIR] [--duration SECONDS]        (default OUTDIR: out/)

Writes OUTDIR/<variant>.nc and OUTDIR/passive_yaw.png, and prints each run's mean and standard
deviation of the yaw and its mean drift force from SETTLED s on.
"""

from __future__ import annotations

import argparse
import copy
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
SCENE = HERE / "passive_yaw.toml"
SETTLED = 300.0         # s: the statistics leave out the ramp and the turn
WAVES_FROM = 40.0       # deg: the heading at which the bow faces the waves (they travel towards -140 deg)
VARIANTS = {"passive_yaw": True, "fixed_heading": False}
LABELS = {"passive_yaw": "passive yaw (forces at the relative heading)",
          "fixed_heading": "fixed heading (forces of the initial heading)"}


def run(outdir: Path, duration: float | None = None) -> dict[str, Path]:
    """Both runs, each written to OUTDIR/<variant>.nc."""
    doc = absolute_paths(tomllib.loads(SCENE.read_text()), SCENE)
    out = {}
    for name, passive in VARIANTS.items():
        d = copy.deepcopy(doc)
        d["bodies"][0]["passive_yaw"] = passive
        if not passive:
            d["bodies"][0].pop("passive_yaw_coefficients")
        if duration is not None:
            d["simulation"]["duration"] = duration
        scene = outdir / f"{name}.toml"
        scene.write_text(dump_toml(d))
        out[name] = outdir / f"{name}.nc"
        run_scene_file(scene, out[name], progress=False)
        print(f"wrote {scene} and {out[name]}", flush=True)
    return out


def yaw(ds: xr.Dataset) -> np.ndarray:
    """The barge's yaw (deg)."""
    return np.rad2deg(ds["position"].sel(body="barge", dof="yaw").values)


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("-o", "--outdir", type=Path, default=Path("out"))
    parser.add_argument("--duration", type=float, default=None)
    args = parser.parse_args()
    args.outdir.mkdir(parents=True, exist_ok=True)
    results = run(args.outdir, args.duration)
    fig, ax = plt.subplots(figsize=(9, 4))
    for name, path in results.items():
        with xr.open_dataset(path) as ds:
            t, psi = ds["time"].values, yaw(ds)
            keep = t >= SETTLED
            drift = ds["drift_force"].sel(body="barge").values[keep].mean(axis=0)
            print(f"{name}: yaw mean {psi[keep].mean():.1f} deg, std {psi[keep].std():.2f} deg; mean drift "
                  f"surge {drift[0] / 1e3:.1f} kN, sway {drift[1] / 1e3:.1f} kN, yaw {drift[5] / 1e3:.1f} kN m")
            ax.plot(t, psi, label=LABELS[name])
    ax.axhline(WAVES_FROM, color="k", ls="--", lw=0.8, label="bow facing the waves")
    ax.set(xlabel="time (s)", ylabel="yaw (deg)", title="Bow-turret barge in an oblique regular sea")
    ax.legend()
    fig.tight_layout()
    fig.savefig(args.outdir / "passive_yaw.png", dpi=110)
    print(f"wrote {args.outdir / 'passive_yaw.png'}")


if __name__ == "__main__":
    main()
