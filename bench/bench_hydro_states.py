"""Server cost per step of variable hydrodynamics (server/hydro_states.py, issue 37 item 4) beside the
same body with one HDB, in the same run: the switching-draft cylinder (examples/switching_draft,
heave only; six DOFs with --dofs 6) in a regular wave and an irregular sea of 100 components, on the
compiled and the numpy path, with 2 and 4 states (the extra states repeat the two HDBs), for each
radiation memory method. Rules switch the state every 2 s (a time rule per switch), so both
switching and holding steps are timed. CPU time (time.process_time) in interleaved blocks.

    python bench/bench_hydro_states.py [--steps 2000] [--dofs 1|6]
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
DATA = REPO / "examples" / "data" / "switching_draft"
SEAS = {
    "regular": 'type = "regular"\nheight = 1.0\nperiod = 3.5',
    "irregular 100": 'type = "irregular"\nspectrum = "jonswap"\nhs = 1.0\ntp = 3.5\ncomponents = 100\n'
                     'omega_range = [0.5, 5.0]',
}


def scene_text(sea: str, states: int, memory: str, dofs: int, duration: float) -> str:
    names = ["sunk", "nominal2", "sunk2"][:states - 1]
    files = ["sunk.nc", "nominal.nc", "sunk.nc"]
    extra = ""
    if states > 1:
        extra = f'hydro_state = "nominal"\nhydro_memory = "{memory}"\n' + "".join(
            f'\n[[bodies.hydro_states]]\nname = "{n}"\nhdb = "{DATA / f}"\n' for n, f in zip(names, files))
        order = ["nominal", *names]
        extra += "".join(f'\n[[hydro_switches]]\nbody = "cylinder"\nstate = "{order[(k + 1) % states]}"\n'
                         f'time = {2.0 * (k + 1)}\n' for k in range(int(duration / 2.0) - 1))
    dof = '["heave"]' if dofs == 1 else '["surge", "sway", "heave", "roll", "pitch", "yaw"]'
    inertia = "" if dofs == 1 else "center_of_mass = [0.0, 0.0, -0.5]\ninertia = [1408.4, 1408.4, 1609.6]\n"
    return (f"[simulation]\ndt = 0.01\nduration = {duration}\nprogress = false\n\n[water]\ndensity = 1025.0\n"
            f"gravity = 9.81\ndepth = \"inf\"\n\n[waves]\n{SEAS[sea]}\n\n[hydro]\nirf_duration = 15.0\n\n"
            f"[[bodies]]\nname = \"cylinder\"\nhdb = \"{DATA / 'nominal.nc'}\"\nmass = 3220.1\n{inertia}dofs = {dof}\n"
            + extra)


def build(sea: str, states: int, memory: str, dofs: int, compiled: bool, duration: float):
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.hdb.io import load_hdb
    from hydrolink.server.hydro_states import hydro_model, state_datasets
    scene = parse_scene(scene_text(sea, states, memory, dofs, duration))
    by_hdb = {str(DATA / f): load_hdb(DATA / f) for f in ("nominal.nc", "sunk.nc")}
    return hydro_model(scene, {"cylinder": by_hdb[str(DATA / "nominal.nc")]}, state_datasets(scene, by_hdb),
                       compiled=compiled)


def per_step(model, k0: int, steps: int) -> float:
    x, v = np.zeros((1, 6)), np.zeros((1, 6))
    t0 = time.process_time()
    for k in range(k0, k0 + steps):
        x[0, 2], v[0, 2] = 0.3 * np.sin(0.01 * k), 0.2 * np.cos(0.01 * k)
        model.step(k * model.dt, x, v)
    return (time.process_time() - t0) / steps


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--steps", type=int, default=2000)
    parser.add_argument("--dofs", type=int, choices=(1, 6), default=1)
    args = parser.parse_args()
    blocks, size = 4, args.steps // 4
    duration = 0.01 * (blocks * size + 10)
    print(f"load {os.getloadavg()[0]:.1f}; {args.steps} steps per case in {blocks} interleaved blocks; us/step (CPU)")
    print("| sea | path | one HDB | 2 states current-kernel | 2 states kernel-at-emission | 4 states current-kernel |")
    print("|---|---|---|---|---|---|")
    for sea in SEAS:
        for compiled in (True, False):
            cases = [(1, "current-kernel"), (2, "current-kernel"), (2, "kernel-at-emission"), (4, "current-kernel")]
            models = [build(sea, n, mem, args.dofs, compiled, duration) for n, mem in cases]
            cost = np.zeros(len(models))
            for b in range(blocks):
                for i, m in enumerate(models):
                    cost[i] += per_step(m, b * size, size) / blocks
            cells = " | ".join(f"{1e6 * c:.1f}" + ("" if i == 0 else f" ({c / cost[0]:.2f}x)") for i, c in enumerate(cost))
            print(f"| {sea} | {'compiled' if compiled else 'numpy'} | {cells} |")
    print(f"load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
