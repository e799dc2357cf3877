"""State-space radiation setup measured: HydroModel construction, cold (empty fit cache) and from cache.

    python bench/bench_setup.py [--bodies 9 27] [--prune 0.0] [--ss-tolerance 0.003] [--max-order 30]

Scenes as ``bench_radiation.py cost``: 9 = the whole 9N9LA HDB (Capytaine, built from
examples/node_9n9la/node_9n9la_hdb.toml and cached), 27 = three 9N9LA arrays 200 m apart in one HDB
(cross blocks zero), every DOF active, full interaction, dt = 0.01 s, irf_duration = 10 s,
irf_taper = 0.2. Each case runs in a fresh temporary fit cache ($HYDROLINK_STATE_SPACE_CACHE): the
first model fits (cold), the second is built from the cache. Wall and CPU seconds are printed (on a
shared machine the wall time includes waiting for a core).
"""

from __future__ import annotations

import argparse
import os
import sys
import tempfile
import time
from pathlib import Path

sys.path.insert(0, str(Path(__file__).resolve().parent))

from bench_radiation import array_27, node_9n9la, scene_text  # noqa: E402

from hydrolink.protocol.scene import parse_scene  # noqa: E402
from hydrolink.protocol.setup import StateSpaceReport  # noqa: E402
from hydrolink.server.model import HydroModel  # noqa: E402


def build(ds, hydro: str) -> tuple[float, float, StateSpaceReport]:
    """Wall s, CPU s and the state-space report of one HydroModel over every body of ``ds``."""
    names = [str(b) for b in ds["body"].values]
    scene = parse_scene(scene_text(names, ds["reference_point"].values, hydro))
    t0, c0 = time.perf_counter(), time.process_time()
    m = HydroModel(scene, {nm: ds for nm in names})
    return time.perf_counter() - t0, time.process_time() - c0, m.setup_info().state_space


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("--bodies", type=int, nargs="+", default=[9, 27], choices=[9, 27])
    p.add_argument("--prune", type=float, default=0.0, help="hydro.coupling_tolerance")
    p.add_argument("--ss-tolerance", type=float, default=0.003)
    p.add_argument("--max-order", type=int, default=30)
    args = p.parse_args(argv)
    ds9 = node_9n9la()
    hydro = (f'radiation = "state-space"\nirf_taper = 0.2\nss_tolerance = {args.ss_tolerance}\n'
             f'ss_max_order = {args.max_order}\ncoupling_tolerance = {args.prune}')
    print("| bodies | run | wall s | CPU s | pairs | pairs fitted | states | max order | max fit error |")
    print("|---|---|---|---|---|---|---|---|---|")
    for nb in args.bodies:
        ds = ds9 if nb == 9 else array_27(ds9)
        with tempfile.TemporaryDirectory() as tmp:
            os.environ["HYDROLINK_STATE_SPACE_CACHE"] = tmp
            for run in ("cold", "cached"):
                wall, cpu, ss = build(ds, hydro)
                print(f"| {nb} | {run} | {wall:.1f} | {cpu:.1f} | {ss.pairs} | {ss.fitted_pairs} | {ss.states} | "
                      f"{ss.max_order} | {ss.max_fit_error:.3g} |", flush=True)


if __name__ == "__main__":
    sys.exit(main())
