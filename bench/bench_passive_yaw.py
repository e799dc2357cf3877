"""Server cost per step of passive yaw (server/sea/passive_yaw.py, issue 37 item 3) beside the same
body at a fixed heading, in the same run: the crossing-sea barge (6 DOFs, HDB 0-90 deg completed by
heading_symmetry = "both") in a regular wave and in irregular seas of 100 and 300 components
(unidirectional) and of 60 x 5 directions (cos-2s), HydroModel.step on the compiled and on the numpy
path, without second-order forces, with the mean drift and with a difference QTF (random ones added
to the HDB on 20 frequencies: the cost does not depend on the values). The yaw turns each step (0.3 rad/s), so every step blends two tabulated yaws.
WEC-Sim's irregular passive-yaw run is 70x slower than its regular one (issue 37); here the ratio
that matters is the passive step's cost over the fixed one's, per sea.

    python bench/bench_passive_yaw.py [--steps 2000]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # before numpy, as the hydrolink command (README "Performance")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

REPO = Path(__file__).resolve().parents[1]
HDB = REPO / "examples" / "data" / "barge_headings" / "barge_headings.nc"
SEAS = {
    "regular": 'type = "regular"\nheight = 1.5\nperiod = 6.0\ndirection = -140.0',
    "irregular 100": 'type = "irregular"\nspectrum = "jonswap"\nhs = 1.5\ntp = 6.0\ncomponents = 100\n'
                     'direction = -140.0\nomega_range = [0.3, 2.8]',
    "irregular 300": 'type = "irregular"\nspectrum = "jonswap"\nhs = 1.5\ntp = 6.0\ncomponents = 300\n'
                     'direction = -140.0\nomega_range = [0.3, 2.8]',
    "spread 60 x 5": 'type = "irregular"\nspectrum = "jonswap"\nhs = 1.5\ntp = 6.0\ncomponents = 60\n'
                     'direction = -140.0\nomega_range = [0.3, 2.8]\nspreading = "cos2s"\ns = 10.0\ndirections = 5',
}


def barge():
    """The barge's HDB with a random mean drift (surge/sway/yaw) on its own headings."""
    from hydrolink.protocol.hdb.schema import with_second_order
    from hydrolink.protocol.hdb.second_order import QTF, MeanDrift
    from hydrolink.server.hdb.io import load_hdb
    ds = load_hdb(HDB)
    w, b = ds["omega"].values, ds["wave_direction"].values
    rng = np.random.default_rng(1)
    drift = np.zeros((1, w.size, b.size, 6))
    drift[0][..., [0, 1, 5]] = 1e3 * rng.uniform(-1.0, 1.0, (w.size, b.size, 3))
    grid = np.linspace(0.3, 2.8, 20)      # a difference QTF on 20 frequencies, the diagonal heading pairs
    r = rng.standard_normal((20, 20, b.size, 6)) + 1j * rng.standard_normal((20, 20, b.size, 6))
    qtf = QTF(grid, b, b, 1e3 * 0.5 * (r + np.conj(np.swapaxes(r, 0, 1))), None, "bench")
    return with_second_order(ds, mean_drift=MeanDrift(("momentum",), w, b, drift), qtf=qtf)


def scene(waves: str, passive: bool, drift: str) -> str:
    return f"""[simulation]
dt = 0.1
duration = 1000.0
[water]
density = 1025.0
gravity = 9.81
depth = "inf"
[waves]
{waves}
[hydro]
irf_duration = 40.0
[[bodies]]
name = "barge"
hdb = "{HDB}"
mass = 328000.0
center_of_mass = [0.0, 0.0, 0.0]
inertia = [2.0e6, 1.12e7, 1.27e7]
heading_symmetry = "both"
passive_yaw = {str(passive).lower()}
second_order = "{drift}"
"""


def per_step(models, steps: int, blocks: int = 8) -> list[float]:
    """µs per HydroModel.step of each model, blocks of the models interleaved (a shared machine:
    each model's best block is its cost, measured under the same load), the yaw turning at 0.3 rad/s."""
    x = [m.setup_info().equilibrium_position.copy() for m in models]
    v = np.zeros((1, 6))
    n = steps // blocks
    best = [np.inf] * len(models)
    for b in range(blocks):
        for i, model in enumerate(models):
            t0 = time.perf_counter()
            for k in range(b * n, (b + 1) * n):
                x[i][0, 5] = 0.03 * k
                model.step(k * model.dt, x[i], v)
            best[i] = min(best[i], 1e6 * (time.perf_counter() - t0) / n)
    return best


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    args = parser.parse_args()
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.model import HydroModel
    ds = barge()
    print(f"load {os.getloadavg()[0]:.1f} (1-min average; 2 vCPUs); set-up s: the passive model's")
    print(f"{'sea':<16}{'path':<10}{'drift':<11}{'fixed µs':>10}{'passive µs':>12}{'ratio':>8}{'set-up s':>10}")
    for name, waves in SEAS.items():
        for compiled in (True, False):
            for drift in ("none", "mean-drift") + (("qtf",) if "spread" not in name else ()):   # (diagonal pairs)
                models = []
                for passive in (False, True):
                    t0 = time.perf_counter()
                    models.append(HydroModel(parse_scene(scene(waves, passive, drift)), {"barge": ds},
                                             compiled=compiled))
                    setup = time.perf_counter() - t0
                costs = per_step(models, args.steps)
                print(f"{name:<16}{'compiled' if compiled else 'numpy':<10}{drift:<11}"
                      f"{costs[0]:>10.1f}{costs[1]:>12.1f}{costs[1] / costs[0]:>8.2f}{setup:>10.2f}")


if __name__ == "__main__":
    main()
    print(f"load {os.getloadavg()[0]:.1f} at the end")
