"""Issue 26's goals, each beside the linear step of the same scene in the same run: the Task-10
sphere in a JONSWAP sea of 300 components (Hs 2 m, Tp 8 s, over the HDB's 0.05-12 rad/s),
HydroModel.step linear; with ``nonlinear = "froude-krylov"`` on Capytaine sphere hulls of about
1,000 and 8,000 triangles, the body moving (heave 0.5 m, pitch 0.1 rad at 0.2 Hz) so the cut
changes every step; with a 20-segment Morison member. Goals: FK <= 5x (1,000) and <= 20x
(8,000) the linear step, Morison <= 2x.

    python bench/bench_nonlinear.py [--steps 300]
"""

from __future__ import annotations

import argparse
import os

from bench_forces import DATA, per_step, scene_text

IRREGULAR = 'type = "irregular"\nspectrum = "jonswap"\nhs = 2.0\ntp = 8.0'
MORISON = ('[[morison]]\nbody = "sphere"\npoint_a = [0.0, 0.0, -25.0]\npoint_b = [0.0, 0.0, -5.0]\n'
           'diameter = 3.0\ncd = 1.0\nca = 1.0\nsegments = 20')


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=300)
    args = ap.parse_args()
    import capytaine as cpt
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.hdb.io import load_hdb
    from hydrolink.server.model import HydroModel
    from hydrolink.server.wetted_surface import closed_hull

    hdb = load_hdb(DATA / "sphere_task10" / "sphere.h5")
    fk = scene_text(IRREGULAR, "").replace("irf_duration = 10.0", 'irf_duration = 10.0\nnonlinear = "froude-krylov"')
    hulls = {}
    for res in ((20, 26), (60, 70)):
        mesh = cpt.mesh_sphere(radius=5.0, resolution=res)
        mesh = mesh.merged() if hasattr(mesh, "merged") else mesh
        hulls[res] = closed_hull(mesh.vertices, mesh.faces)
    cases = [("Morison, 20 segments", 2.0, parse_scene(scene_text(IRREGULAR, MORISON)), {}, False)]
    cases += [(f"froude-krylov, {hull.n_triangles} triangles", goal, parse_scene(fk), {"sphere": hull}, True)
              for hull, goal in zip(hulls.values(), (5.0, 20.0))]
    rows = []
    for label, goal, scene, hull, moving in cases:
        linear = per_step(HydroModel(parse_scene(scene_text(IRREGULAR, "")), {"sphere": hdb}), args.steps)
        cost = per_step(HydroModel(scene, {"sphere": hdb}, hulls=hull), args.steps, moving=moving)
        rows.append((label, linear, cost, goal))
    print(f"# bench_nonlinear: µs per HydroModel.step, {args.steps} steps, load {os.getloadavg()[0]:.2f}\n")
    print("| case | linear step | with the term | ratio | goal |\n|---|---|---|---|---|")
    for label, linear, cost, goal in rows:
        print(f"| {label} | {linear:.1f} | {cost:.1f} | {cost / linear:.1f}x | <= {goal:g}x |")


if __name__ == "__main__":
    main()
