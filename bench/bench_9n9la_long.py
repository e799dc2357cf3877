"""9N9LA long run (issue 3 acceptance): 3,600 s of irregular waves, joint violation at the end, NaN
check, wall time and per-step costs (client, server).

    OPENBLAS_NUM_THREADS=1 python bench/bench_9n9la_long.py [--duration 3600] [-o 9n9la_long.nc]

OpenBLAS threads: on a small, busy machine a multi-threaded BLAS makes the server's 54 x 13,554
convolution matvec 20x slower (18 ms instead of 0.9 ms per step, measured here); this script pins
it to one thread unless OPENBLAS_NUM_THREADS is already set.
"""

from __future__ import annotations

import argparse
import os

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import re  # noqa: E402
import tempfile  # noqa: E402
import time  # noqa: E402
from pathlib import Path  # noqa: E402

import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

from hydrolink.clients.run import run_scene_file  # noqa: E402

EXAMPLE = Path(__file__).resolve().parents[1] / "examples" / "node_9n9la" / "node_9n9la.toml"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=3600.0)
    ap.add_argument("-o", "--output", default=None, help="results file (default: a temporary file)")
    args = ap.parse_args()
    text = EXAMPLE.read_text()
    text = re.sub(r"(?m)^duration = .*$", f"duration = {args.duration!r}", text, count=1)
    text = text.replace('hdb = "', f'hdb = "{EXAMPLE.parent}/')
    with tempfile.TemporaryDirectory() as tmp:
        scene = Path(tmp) / "node_9n9la_long.toml"
        scene.write_text(text)
        out = Path(args.output) if args.output else Path(tmp) / "long.nc"
        t0 = time.perf_counter()
        s = run_scene_file(scene, out, progress=False)
        wall = time.perf_counter() - t0
        ds = xr.load_dataset(out)
    viol = ds.joint_violation.values
    rot = ds.joint_rotation_violation.values
    finite = all(np.isfinite(ds[v].values).all() for v in ("position", "velocity", "joint_violation", "pto_power"))
    t = ds.time.values
    half = t >= t[-1] / 2
    print(f"9N9LA {args.duration:g} s, dt {t[1] - t[0]:g} s, {s.steps} steps: status {ds.attrs['status']}")
    print(f"  wall time {wall:.1f} s (run {s.wall_time:.1f} s) = {s.wall_time / args.duration:.3f} s per simulated s")
    print(f"  client {s.client_us_per_step:.0f} us/step, server round trip {s.round_trip_us_per_step:.0f} "
          f"us/step (server compute {(s.server_compute_us_per_step or float('nan')):.0f})")
    print(f"  joint violation at the end: max {viol[-1].max():.3e} m (whole run max {viol.max():.3e} m); "
          f"rotation violation {rot[-1].max():.3e} rad")
    jf = np.abs(ds.joint_force.values)
    print(f"  max |joint force|: first 100 s {jf[t <= 100].max():.1f} N, last 100 s {jf[t >= t[-1] - 100].max():.1f} N")
    print(f"  no NaN: {finite}; mean total PTO power over the second half {ds.total_pto_power.values[half].mean():.4f} W")
    print(f"  max |surge|, |sway| drift of R0: {np.abs(ds.position.sel(body='R0').values[:, :2] - ds.position.sel(body='R0').values[0, :2]).max():.4f} m")


if __name__ == "__main__":
    main()
