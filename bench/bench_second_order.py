"""Server cost per step of the second-order wave force (server/terms/second_order.py, issue 23): the
Task-10 sphere (6 DOFs) in a JONSWAP sea of 100, 300 and 600 components, HydroModel.step with no
second-order force beside "mean-drift", "newman", "qtf" and "qtf" + sum_frequency, all in the same
run; and the term's own force() per step. The sphere's HDB gets a mean drift on its own grid and
difference/sum QTFs on a 40-frequency grid over the same range (random Hermitian / symmetric
squares: the cost does not depend on the values).

    python bench/bench_second_order.py [--steps 2000] [--qtf-frequencies 40]
"""

from __future__ import annotations

import argparse
import os
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # before numpy, as the hydrolink command (README "Performance")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np
from bench_forces import scene_text   # the same sphere scene (bench/ is on the path)

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "examples" / "data"
MODES = (("none", False), ("mean-drift", False), ("newman", False), ("qtf", False), ("qtf", True))


def drift_hdb(n_q: int, folder: Path) -> Path:
    """The sphere's HDB with mean drift and QTFs (see module docstring), written as NetCDF."""
    from hydrolink.protocol.hdb.schema import to_netcdf
    from hydrolink.protocol.hdb.second_order import QTF, MeanDrift
    from hydrolink.protocol.hdb.schema import with_second_order
    from hydrolink.server.hdb.io import load_hdb

    ds = load_hdb(DATA / "sphere_task10" / "sphere.h5")
    w = ds["omega"].values
    rng = np.random.default_rng(1)
    drift = np.zeros((1, w.size, 1, 6))
    drift[0, :, 0, [0, 2, 4]] = 1e3 * rng.uniform(-0.2, 1.0, (3, w.size))
    grid = np.linspace(w[0], w[-1], n_q)
    r = rng.standard_normal((n_q, n_q, 1, 6)) + 1j * rng.standard_normal((n_q, n_q, 1, 6))
    diff = 0.5 * (r + np.conj(np.swapaxes(r, 0, 1)))
    summ = 0.5 * (r + np.swapaxes(r, 0, 1))
    ds = with_second_order(ds, mean_drift=MeanDrift(("momentum",), w, np.zeros(1), drift),
                           qtf=QTF(grid, np.zeros(1), np.zeros(1), 1e3 * diff, 1e3 * summ, "bench"))
    path = folder / "sphere_drift.nc"
    to_netcdf(ds, path)
    return path


def scene(components: int, mode: str, sum_frequency: bool) -> str:
    """bench_forces' sphere scene in a JONSWAP sea, the body's second_order and [hydro] sum_frequency."""
    waves = f'type = "irregular"\nspectrum = "jonswap"\nhs = 2.5\ntp = 8.0\ncomponents = {components}'
    text = scene_text(waves, f'second_order = "{mode}"')
    return text.replace("[hydro]\n", f"[hydro]\nsum_frequency = {str(sum_frequency).lower()}\n", 1)


def per_step(model, steps: int, blocks: int = 4) -> tuple[float, float]:
    """(µs per HydroModel.step, µs per second-order force() alone) at rest: the best of ``blocks``
    consecutive blocks of steps / blocks steps (the machine is shared: the best block is the cost)."""
    eq = model.setup_info().equilibrium_position
    vel = 0.1 * np.random.default_rng(0).standard_normal((steps, 1, 6))
    terms = [t for t in model.terms if t.name == "second_order"]
    n = steps // blocks
    step, term = np.inf, np.inf if terms else 0.0
    for b in range(blocks):
        ks = range(b * n, (b + 1) * n)
        t0 = time.perf_counter()
        for k in ks:
            model.step(k * model.dt, eq, vel[k])
        step = min(step, 1e6 * (time.perf_counter() - t0) / n)
        if terms:
            t0 = time.perf_counter()
            for k in ks:
                terms[0].force(k * model.dt, eq, vel[k])
            term = min(term, 1e6 * (time.perf_counter() - t0) / n)
    return step, term


def main() -> None:
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.hdb.io import load_hdb
    from hydrolink.server.model import HydroModel

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=2000)
    ap.add_argument("--qtf-frequencies", type=int, default=40)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        path = drift_hdb(args.qtf_frequencies, Path(tmp))
        ds = load_hdb(path)
        print(f"sphere, 6 DOFs, dt 0.05 s, {args.steps} steps, QTF grid {args.qtf_frequencies} frequencies")
        print(f"{'components':>10} {'second_order':>16} {'step µs':>9} {'term µs':>9} {'+step µs':>9}")
        for n in (100, 300, 600):
            base = None
            for mode, summ in MODES:
                model = HydroModel(parse_scene(scene(n, mode, summ)), {"sphere": ds})
                step, term = per_step(model, args.steps)
                base = step if base is None else base
                label = mode + (" + sum" if summ else "")
                print(f"{n:>10} {label:>16} {step:9.1f} {term:9.1f} {step - base:9.1f}")


if __name__ == "__main__":
    main()
