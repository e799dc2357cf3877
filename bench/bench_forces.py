"""Server cost per step of the force terms beyond potential flow (issue 10): the Task-10 sphere
(6 DOFs) in regular and irregular seas, HydroModel.step without them, with quadratic damping, with
relative drag, with a 20-segment Morison member (20 m x 3 m below the sphere); and the drag term
alone for 9 bodies (54 DOFs) with 300 wave components; nonlinear hydrostatics and Froude-Krylov
on sphere hulls of about 1,000 and 4,000 triangles, the body moving (heave and pitch) each step.

    python bench/bench_forces.py [--steps 4000]
"""

from __future__ import annotations

import argparse
import os
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
DATA = REPO / "examples" / "data"


def scene_text(waves: str, extra: str) -> str:
    return f"""[simulation]
dt = 0.05
duration = 1000.0
[water]
density = 1000.0
depth = 200.0
[waves]
{waves}
[hydro]
irf_duration = 10.0
[[bodies]]
name = "sphere"
hdb = "sphere.h5"
mass = 261800.0
center_of_mass = [0.0, 0.0, -2.0]
inertia = [2.6e6, 2.6e6, 2.6e6]
{extra}
"""


def per_step(model, steps: int, moving: bool = False) -> float:
    """µs per HydroModel.step; ``moving``: heave 0.5 m and pitch 0.1 rad at 0.2 Hz (else at rest)."""
    eq = model.setup_info().equilibrium_position
    rng = np.random.default_rng(0)
    vel = 0.1 * rng.standard_normal((steps, 1, 6))
    phase = np.sin(2 * np.pi * 0.2 * model.dt * np.arange(steps))
    pos = np.repeat(eq[None], steps, axis=0)
    if moving:
        pos[:, 0, 2] += 0.5 * phase
        pos[:, 0, 4] += 0.1 * phase
    t0 = time.perf_counter()
    for k in range(steps):
        model.step(k * model.dt, pos[k], vel[k])
    return 1e6 * (time.perf_counter() - t0) / steps


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--steps", type=int, default=4000)
    args = ap.parse_args()
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.hdb.io import load_hdb
    from hydrolink.server.sea.kinematics import Kinematics
    from hydrolink.server.model import HydroModel
    from hydrolink.server.terms.viscous import DragTerm, ViscousDamping
    from hydrolink.server.sea.waves import wave_components
    from hydrolink.protocol.scene import IrregularWave

    hdb = load_hdb(DATA / "sphere_task10" / "sphere.h5")
    seas = {"regular": 'type = "regular"\nheight = 1.0\nperiod = 6.0',
            "irregular (300 components)": 'type = "irregular"\nspectrum = "jonswap"\nhs = 2.0\ntp = 8.0'}
    terms = {"none": "", "quadratic_damping": "quadratic_damping = [1e4, 1e4, 8e4, 1e6, 1e6, 1e6]",
             "relative drag": 'drag = { cd = [1, 1, 0.8, 0, 0, 0], area = [40, 40, 78.5, 0, 0, 0], relative = true }',
             "Morison, 20 segments": '[[morison]]\nbody = "sphere"\npoint_a = [0.0, 0.0, -25.0]\n'
                                     'point_b = [0.0, 0.0, -5.0]\ndiameter = 3.0\ncd = 1.0\nca = 1.0\nsegments = 20'}
    print(f"# bench_forces: server µs per step (HydroModel.step, {args.steps} steps; load {os.getloadavg()[0]:.2f})\n")
    print("| sea | " + " | ".join(terms) + " |")
    print("|---|" + "---|" * len(terms))
    for sea, waves in seas.items():
        cells = [f"{per_step(HydroModel(parse_scene(scene_text(waves, extra)), {'sphere': hdb}), args.steps):.1f}"
                 for extra in terms.values()]
        print(f"| {sea} | " + " | ".join(cells) + " |")
    comps = wave_components(IrregularWave(type="irregular", spectrum="jonswap", hs=2.0, tp=8.0), 0.2, 3.0)
    points = np.column_stack([np.arange(9) * 20.0, np.zeros(9), np.full(9, -2.0)])
    rows = np.full(54, 27)
    for k in range(9):
        rows[6 * k:6 * k + 3] = 3 * k + np.arange(3)
    term = ViscousDamping(None, None, DragTerm(np.full(54, 1e4), Kinematics(comps, points, 9.81, 200.0), rows))
    v = np.zeros(54)
    t0 = time.perf_counter()
    for k in range(args.steps):
        term.force(k * 0.05, v)
    print(f"\n9 bodies (54 DOFs), relative drag, 300 components: {1e6 * (time.perf_counter() - t0) / args.steps:.1f} µs "
          "per step for the drag term alone")


def nonlinear(steps: int) -> None:
    """Server µs per step with [hydro] nonlinear on the sphere (hull: Capytaine sphere meshes), in
    still water ("hydrostatic"), regular and irregular seas ("froude-krylov"); the pose moves
    (heave 0.5 m, pitch 0.1 rad at 0.2 Hz) so the cut changes every step."""
    import capytaine as cpt
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.hdb.io import load_hdb
    from hydrolink.server.model import HydroModel
    from hydrolink.server.terms.hulls import closed_hull

    hdb = load_hdb(DATA / "sphere_task10" / "sphere.h5")
    seas = {"still water, hydrostatic": ('type = "still"', "hydrostatic"),
            "regular, froude-krylov": ('type = "regular"\nheight = 1.0\nperiod = 6.0', "froude-krylov"),
            "irregular (300 components), froude-krylov": ('type = "irregular"\nspectrum = "jonswap"\nhs = 2.0\ntp = 8.0',
                                                           "froude-krylov")}
    hulls = []
    for res in ((20, 26), (40, 52)):
        mesh = cpt.mesh_sphere(radius=5.0, resolution=res)
        mesh = mesh.merged() if hasattr(mesh, "merged") else mesh
        hulls.append(closed_hull(mesh.vertices, mesh.faces))
    print("\n| nonlinear, sphere | none | " + " | ".join(f"{h.n_triangles} triangles" for h in hulls) + " |")
    print("|---|---|" + "---|" * len(hulls))
    for sea, (waves, mode) in seas.items():
        cells = [f"{per_step(HydroModel(parse_scene(scene_text(waves, '')), {'sphere': hdb}), steps):.1f}"]
        for hull in hulls:
            text = scene_text(waves, "").replace("irf_duration = 10.0", f'irf_duration = 10.0\nnonlinear = "{mode}"')
            model = HydroModel(parse_scene(text), {"sphere": hdb}, hulls={"sphere": hull})
            cells.append(f"{per_step(model, steps, moving=True):.1f}")
        print(f"| {sea} | " + " | ".join(cells) + " |")


def rm3_power(duration: float = 400.0) -> None:
    """RM3 (examples/rm3/rm3.toml, H 2.5 m, T 8 s, PTO 1.2e6 N s/m) with and without quadratic
    drag on the float's heave: Cd 1 on the waterplane area pi 10^2 m^2 (the float's radius is 10 m;
    Cd 1 in heave is the value of a WEC-Sim RM3 input in a public model library, quadDrag.cd =
    [1 1 1 0 0 0]); mean PTO power over the last 200 s."""
    import tomllib
    import tempfile
    import xarray as xr
    from hydrolink.clients.studies.grid import absolute_paths, dump_toml
    from hydrolink.clients.run import run_scene_file
    rm3 = REPO / "examples" / "rm3" / "rm3.toml"
    base = absolute_paths(tomllib.loads(rm3.read_text()), rm3)
    base["simulation"]["duration"] = duration
    out = {}
    with tempfile.TemporaryDirectory() as tmp:
        for label, drag in (("no drag", None), ("float heave drag Cd 1", {"cd": [0, 0, 1.0, 0, 0, 0],
                                                                         "area": [0, 0, 314.16, 0, 0, 0],
                                                                         "relative": True})):
            doc = {k: (dict(v) if isinstance(v, dict) else [dict(e) for e in v] if isinstance(v, list) else v)
                   for k, v in base.items()}
            if drag:
                doc["bodies"][0]["drag"] = drag
            path = Path(tmp) / "rm3.toml"
            path.write_text(dump_toml(doc))
            run_scene_file(path, Path(tmp) / "rm3.nc", progress=False)
            ds = xr.load_dataset(Path(tmp) / "rm3.nc")
            sel = ds["time"].values > duration - 200.0
            out[label] = float(ds["total_pto_power"].values[sel].mean())
    base_p = out["no drag"]
    print("\n| RM3 at T = 8 s, H 2.5 m | mean PTO power | vs no drag |\n|---|---|---|")
    for label, p in out.items():
        print(f"| {label} | {p / 1e3:.1f} kW | {100 * (p / base_p - 1):+.1f} % |")


if __name__ == "__main__":
    main()
    nonlinear(2000)
    rm3_power()
