"""Cost per step of generalized modes (issue 38 item 3) beside the rigid body, in the same run:
the flexible barge (examples/data/flexible_barge) with 0 (its rigid six DOFs: the HDB's mode rows
and columns dropped), 1, 2 and 3 modes, in a 200-component irregular sea from 30 deg, state-space
radiation. Measured in interleaved blocks (each variant's block after the others', repeated) as
CPU time of this process:

- the server's model step (HydroModel.step) on the compiled and on the numpy path;
- the Exudyn client's integration step alone (ExudynModel.advance with the modal node in the hydro
  object, the force vector set each step);
- a whole run (hydrolink's Exudyn client and an in-process server: the integration, the wire, the
  results file), per step.

    python bench/bench_modes.py [--steps 2000] [--blocks 5]
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

REPO = Path(__file__).resolve().parents[1]
HDB = REPO / "examples" / "data" / "flexible_barge" / "flexible_barge.nc"
MODES = ["bend_z1", "bend_z2", "twist1"]
MODAL = {"bend_z1": (164000.0, 39106.55, 3203.4), "bend_z2": (164000.0, 297151.3, 8830.2),
         "twist1": (1995333.0, 6168503.0, 140332.3)}


def variant(k: int):
    """The barge's HDB with its first ``k`` modes (0: the rigid six DOFs)."""
    from hydrolink.server.hdb.io import load_hdb
    ds = load_hdb(HDB)
    keep = list(range(6 + k))
    return ds.isel(influenced_dof=keep, radiating_dof=keep)


def scene(hdb: str, k: int, duration: float) -> str:
    modes = ""
    if k:
        names = MODES[:k]
        cols = list(zip(*(MODAL[n] for n in names)))
        modes = (f"[bodies.modes]\nnames = {names!r}\nmass = {list(cols[0])}\nstiffness = {list(cols[1])}\n"
                 f"damping = {list(cols[2])}\n").replace("'", '"')
    return f"""[simulation]
dt = 0.05
duration = {duration}
progress = false
[water]
density = 1025.0
[waves]
type = "irregular"
spectrum = "jonswap"
hs = 1.5
tp = 8.0
direction = 30.0
omega_range = [0.3, 1.8]
components = 200
seed = 38
[hydro]
radiation = "state-space"
irf_duration = 10.0
irf_taper = 0.2
[[bodies]]
name = "barge"
hdb = "{hdb}"
mass = 656000.0
center_of_mass = [0.0, 0.0, 0.0]
inertia = [3990666.7, 87466666.7, 87466666.7]
linear_damping = [5.0e4, 5.0e4, 0.0, 1.7e6, 0.0, 1.0e7]
{modes}"""


def model_cost(models: dict, steps: int, blocks: int) -> dict[str, list[float]]:
    """CPU µs per HydroModel.step, per variant, one value per block (interleaved)."""
    out: dict[str, list[float]] = {name: [] for name in models}
    rng = np.random.default_rng(0)
    for _ in range(blocks):
        for name, model in models.items():
            x0 = model.setup_info().equilibrium_position
            m = model.modes.size
            xs = x0 + 0.01 * rng.standard_normal((steps,) + x0.shape)
            qs = 0.01 * rng.standard_normal((steps, m))
            model.set_state(model._bench_start)
            t0 = time.process_time()
            for i in range(steps):
                kw = {"modal_position": qs[i], "modal_velocity": qs[i]} if m else {}
                model.step(i * model.dt, xs[i], xs[i] - x0, **kw)
            out[name].append(1e6 * (time.process_time() - t0) / steps)
    return out


def client_cost(setups: dict, steps: int, blocks: int) -> dict[int, list[float]]:
    """CPU µs per Exudyn integration step (set_force + advance), per mode count, interleaved."""
    from hydrolink.clients.exudyn.client import build_model
    models = {}
    for k, (scene, setup) in setups.items():
        model = build_model(scene, setup)
        model.set_force(np.zeros(setup.n_dofs))
        model.initialize()
        models[k] = model
    rng = np.random.default_rng(1)
    out: dict[int, list[float]] = {k: [] for k in models}
    t = {k: 0.0 for k in models}
    for _ in range(blocks):
        for k, model in models.items():
            forces = 1e3 * rng.standard_normal((steps, model.wet_index.size))
            t0 = time.process_time()
            for f in forces:
                model.set_force(f)
                model.advance(t[k], t[k] + model.dt)
                t[k] += model.dt
            out[k].append(1e6 * (time.process_time() - t0) / steps)
    for model in models.values():
        model.close()
    return out


def run_cost(folder: Path, steps: int, blocks: int) -> dict[int, list[float]]:
    """CPU µs per step of a whole run (client + in-process server + results), per mode count: the
    CPU of a run of 2 ``steps`` less that of a run of ``steps`` (the set-up, the same in both, cancels)."""
    from hydrolink.clients.run import run_scene_file

    def cpu(k: int, n: int) -> float:
        path = folder / f"modes{k}_{n}.toml"
        path.write_text(scene(f"barge{k}.nc", k, n * 0.05))
        t0 = time.process_time()
        run_scene_file(path, folder / f"out{k}.nc", progress=False)
        return time.process_time() - t0

    for k in range(4):       # warm: imports, fits cached, kernels compiled
        cpu(k, 10)
    out: dict[int, list[float]] = {k: [] for k in range(4)}
    for _ in range(blocks):
        for k in range(4):
            out[k].append(1e6 * (cpu(k, 2 * steps) - cpu(k, steps)) / steps)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--blocks", type=int, default=5)
    args = parser.parse_args()
    from hydrolink.protocol.hdb.schema import to_netcdf
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.model import HydroModel
    print(f"load at start: {os.getloadavg()}")
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        models = {}
        for k in range(4):
            ds = variant(k)
            to_netcdf(ds, folder / f"barge{k}.nc")
            for compiled in (True, False):
                model = HydroModel(parse_scene(scene("x.nc", k, 1e4)), {"barge": ds}, compiled=compiled)
                model._bench_start = model.state()
                models[f"{k} modes, {'compiled' if compiled else 'numpy'}"] = model
        cost = model_cost(models, args.steps, args.blocks)
        print(f"\nserver model step, CPU us/step over {args.steps} steps x {args.blocks} interleaved blocks (median, min-max):")
        for name, v in cost.items():
            print(f"  {name:22s} {np.median(v):8.1f}  ({min(v):.1f}-{max(v):.1f})")
        setups = {}
        for k in range(4):
            scene_k = parse_scene(scene("x.nc", k, 1e4))
            setups[k] = (scene_k, models[f"{k} modes, numpy"].setup_info())
        client = client_cost(setups, args.steps, args.blocks)
        print(f"\nExudyn integration step (set_force + advance), CPU us/step over {args.steps} steps x {args.blocks} "
              "interleaved blocks:")
        for k, v in client.items():
            print(f"  {k} modes                {np.median(v):8.1f}  ({min(v):.1f}-{max(v):.1f})")
        runs = run_cost(folder, args.steps, max(1, args.blocks // 2))
        print(f"\nwhole run (Exudyn client + in-process server + results), CPU us/step (2x{args.steps} less "
              f"{args.steps} steps):")
        for k, v in runs.items():
            print(f"  {k} modes                {np.median(v):8.1f}  ({min(v):.1f}-{max(v):.1f})")
    print(f"load at end: {os.getloadavg()}")


if __name__ == "__main__":
    main()
