"""Issue 26's goals, each beside the linear step of the same scene in the same run: the Task-10
sphere in a JONSWAP sea of 300 components (Hs 2 m, Tp 8 s, over the HDB's 0.05-12 rad/s),
HydroModel.step linear; with ``nonlinear = "froude-krylov"`` on Capytaine sphere hulls of about
1,000 and 8,000 triangles, the body moving (heave 0.5 m, pitch 0.1 rad at 0.2 Hz) so the cut
changes every step; with a 20-segment Morison member. Goals: FK <= 5x (1,000) and <= 20x
(8,000) the linear step, Morison <= 2x. Then ``[hydro] froude_krylov_energy`` (the FK pressure
from the most energetic components holding that share of the variance): cost, and the largest
difference of the ``nonlinear_froude_krylov`` reply from the full evaluation over the same
motion, per DOF relative to the full one's largest value. ``--only morison``: the Morison row
alone. BLAS runs one thread, as under the ``hydrolink`` command (README "BLAS threads"), unless
OPENBLAS_NUM_THREADS is set.

    python bench/bench_nonlinear.py [--steps 300] [--repeat 3] [--only morison]
"""

from __future__ import annotations

import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # before numpy, as the hydrolink command (README "Performance")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import argparse

import numpy as np
from bench_forces import DATA, per_step, scene_text

IRREGULAR = 'type = "irregular"\nspectrum = "jonswap"\nhs = 2.0\ntp = 8.0'
MORISON = ('[[morison]]\nbody = "sphere"\npoint_a = [0.0, 0.0, -25.0]\npoint_b = [0.0, 0.0, -5.0]\n'
           'diameter = 3.0\ncd = 1.0\nca = 1.0\nsegments = 20')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--only", choices=["morison"], help="the Morison row alone (no hull is built)")
    ap.add_argument("--repeat", type=int, default=3, help="runs of each (linear, term) pair, alternating; the "
                    "fastest of each counted (other jobs on the machine only ever add time)")
    args = ap.parse_args()
    import capytaine as cpt
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.hdb.io import load_hdb
    from hydrolink.server.model import HydroModel
    from hydrolink.server.terms.hulls import closed_hull

    hdb = load_hdb(DATA / "sphere_task10" / "sphere.h5")
    fk = scene_text(IRREGULAR, "").replace("irf_duration = 10.0", 'irf_duration = 10.0\nnonlinear = "froude-krylov"')
    hulls = {}
    for res in (() if args.only else ((20, 26), (60, 70))):
        mesh = cpt.mesh_sphere(radius=5.0, resolution=res)
        mesh = mesh.merged() if hasattr(mesh, "merged") else mesh
        hulls[res] = closed_hull(mesh.vertices, mesh.faces)
    cases = [("Morison, 20 segments", 2.0, parse_scene(scene_text(IRREGULAR, MORISON)), {}, False)]
    cases += [(f"froude-krylov, {hull.n_triangles} triangles", goal, parse_scene(fk), {"sphere": hull}, True)
              for hull, goal in zip(hulls.values(), (5.0, 20.0))]
    rows = []
    for label, goal, scene, hull, moving in cases:
        linear, cost = np.inf, np.inf
        for _ in range(args.repeat):
            linear = min(linear, per_step(HydroModel(parse_scene(scene_text(IRREGULAR, "")), {"sphere": hdb}), args.steps))
            cost = min(cost, per_step(HydroModel(scene, {"sphere": hdb}, hulls=hull), args.steps, moving=moving))
        rows.append((label, linear, cost, goal))
    print(f"# bench_nonlinear: µs per HydroModel.step, {args.steps} steps, fastest of {args.repeat}, "
          f"load {os.getloadavg()[0]:.2f}, OPENBLAS_NUM_THREADS={os.environ['OPENBLAS_NUM_THREADS']}\n")
    print("| case | linear step | with the term | ratio | goal |\n|---|---|---|---|---|")
    for label, linear, cost, goal in rows:
        print(f"| {label} | {linear:.1f} | {cost:.1f} | {cost / linear:.2f}x | <= {goal:g}x |")
    if args.only:
        return
    print("\n| hull | froude_krylov_energy | components | µs per step | ratio to linear | largest FK difference |")
    print("|---|---|---|---|---|---|")
    for hull in hulls.values():
        full = None
        for energy in (1.0, 0.999, 0.99):
            text = fk.replace('nonlinear = "froude-krylov"', f'nonlinear = "froude-krylov"\nfroude_krylov_energy = {energy}')
            model = HydroModel(parse_scene(text), {"sphere": hdb}, hulls={"sphere": hull})
            term = next(t for t in model.terms if t.name == "nonlinear_hydrostatics")
            linear = per_step(HydroModel(parse_scene(scene_text(IRREGULAR, "")), {"sphere": hdb}), args.steps)
            cost = per_step(model, args.steps, moving=True)
            series = _fk_series(term.model, model.setup_info().equilibrium_position, model.dt, args.steps)
            full = series if full is None else full
            err = np.max(np.abs(series - full), axis=0) / np.maximum(np.max(np.abs(full), axis=0), 1e-300)
            print(f"| {hull.n_triangles} | {energy:g} | {term.model.omega.size} | {cost:.1f} | {cost / linear:.1f}x | "
                  f"{err.max():.2e} |")


def _fk_series(model, eq: np.ndarray, dt: float, steps: int) -> np.ndarray:
    """The Froude-Krylov difference (steps, 6) of body 0 for per_step's moving pose."""
    phase = np.sin(2 * np.pi * 0.2 * dt * np.arange(steps))
    out = np.empty((steps, 6))
    for k in range(steps):
        pos = eq.copy()
        pos[0, 2] += 0.5 * phase[k]
        pos[0, 4] += 0.1 * phase[k]
        out[k] = model.force(k * dt, pos)[1][0]
    return out


if __name__ == "__main__":
    main()
