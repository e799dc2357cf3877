"""Cost of the loads along a body and of its panel pressures (issue 38 item 4), beside the run that
gives their rows: a 20 x 6 m box barge (1 m panels: 224 hull panels, an hdb build with panel_pressures
kept in a temporary cache), an irregular sea from 30 deg, radiation by convolution (irf_duration 10 s).
CPU time of this process (time.process_time), median of ``--repeat``:

- the run itself (hydrolink run without sections), per row;
- the plan (panel set read, cut rows made) and the loads at ``--stations`` stations from the rows;
- the panel pressures (rows x panels) from the rows.

    python bench/bench_sections.py [--duration 200] [--dt 0.05] [--stations 9] [--repeat 3]
"""

from __future__ import annotations

import argparse
import os
import statistics
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")   # before numpy, as the hydrolink command (README "Performance")
os.environ.setdefault("OMP_NUM_THREADS", "1")

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

RHO, L, B, T = 1025.0, 20.0, 6.0, 2.0


def cpu(f) -> tuple[float, object]:
    t0 = time.process_time()
    out = f()
    return time.process_time() - t0, out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=200.0)
    ap.add_argument("--dt", type=float, default=0.05)
    ap.add_argument("--stations", type=int, default=9)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    from conftest import body, box_build_spec, irregular_waves, scene_toml
    from hydrolink.clients.lockstep.section_results import add_section_loads, plan_sections
    from hydrolink.clients.run import run_scene_file
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import load_scene
    from hydrolink.server.loads.pressures import panel_series
    from hydrolink.server.loads.water import recorded_motion
    import xarray as xr

    tmp = Path(tempfile.mkdtemp(prefix="bench_sections_"))
    os.environ["HYDROLINK_CACHE"] = str(tmp / "cache")
    spec = tmp / "box.toml"
    spec.write_text(box_build_spec(name="barge", length=L, width=B, draft=T, panel_size=1.0, density=RHO,
                                   frequencies="omega_min = 0.2\nomega_max = 2.0\nn = 19"))
    mass = RHO * L * B * T
    sections = {"stations": list(np.linspace(-L / 2, L / 2, args.stations + 2)[1:-1]), "mass_stations": [-L / 2, L / 2],
                "mass_per_length": [mass / L]}
    def text(**outputs) -> str:
        return scene_toml(dt=args.dt, duration=args.duration, water={"density": RHO},
                          waves=irregular_waves(0.05, 8.0, direction=30.0, ramp=20.0, seed=3),
                          hydro={"radiation": "convolution", "irf_duration": 10.0},
                          bodies=[body("barge", hdb=str(spec), mass=mass, center_of_mass=[0.0, 0.0, -0.5],
                                       inertia=[1e6, 8.3e6, 8.9e6], **outputs)])
    path, plain = tmp / "barge.toml", tmp / "plain.toml"
    path.write_text(text(sections=sections, pressure_output=True))
    plain.write_text(text())
    load_scene_hdbs(load_scene(plain)[0], plain, progress=False)            # the build, once
    run_cpu, _ = cpu(lambda: run_scene_file(plain, tmp / "plain.nc", progress=False))
    scene, _ = load_scene(path)
    hdbs = load_scene_hdbs(scene, path, progress=False)
    rows = xr.load_dataset(tmp / "plain.nc")
    n = rows.sizes["time"]
    plans, loads, pressures = [], [], []
    for _ in range(args.repeat):
        c, plan = cpu(lambda: plan_sections(scene, path, hdbs))
        plans.append(c)
        out = tmp / "rows.nc"
        rows.to_netcdf(out)
        loads.append(cpu(lambda: add_section_loads(out, plan, scene))[0])
        _, ps, _, _ = plan.bodies[0]
        motion = recorded_motion(rows["time"].values, rows["position"].values[:, 0], rows["velocity"].values[:, 0],
                                 rows["equilibrium_position"].values[0])
        pressures.append(cpu(lambda: panel_series(ps, motion, scene, plan.waves, "barge", "x"))[0])
    os.system("uptime")
    print(f"{n} rows, {args.stations} stations, {plan.bodies[0][1].panels} panels, "
          f"{plan.waves.size} wave components")
    print(f"the run (no outputs): {run_cpu:.2f} s CPU ({1e6 * run_cpu / n:.0f} us a row)")
    print(f"plan: {statistics.median(plans):.3f} s; loads from the rows (the sections' and the whole body's, "
          f"written): {statistics.median(loads):.3f} s ({1e6 * statistics.median(loads) / n:.1f} us a row)")
    print(f"panel pressures: {statistics.median(pressures):.3f} s ({1e6 * statistics.median(pressures) / n:.1f} us a row)")


if __name__ == "__main__":
    main()
