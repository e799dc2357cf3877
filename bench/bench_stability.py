"""Stability at the extremes, long cases and the stability map (docs/stability.md).

    python bench/bench_stability.py [--out docs] [--quick]

1. The map: coupling scheme × added-mass ratio A∞/m × dt on the Task-10 sphere in heave (free decay
   from 0.5 m, 10 s, 20 s of memory; mass scaled, displaced volume dropped so no net buoyancy acts).
   Each run is classed against a monolithic Cummins integration at dt = 1 ms written here:
   "accurate" (max error < 1 % of the initial displacement), "stable" (bounded, less accurate),
   "stopped" (an early stop whose message names the cause and the setting: the added-mass watch or the
   blow-up guard) or "refused" (refused before the first step, e.g. explicit above explicit_limit).
   The explicit schemes run with allow_unstable=True to show the instability; without it they are
   refused above coupling.explicit_limit = 0.9. Writes stability_map.png and a Markdown table.
2. Iterations per step of the implicit scheme against A∞/m.
3. 3,600 s in irregular waves (mass-matrix and implicit): complete, finite, bounded.
Every case asserts its expected outcome.
"""

from __future__ import annotations

import argparse
import sys
import tempfile
import textwrap
import time
from pathlib import Path

import numpy as np

REPO = Path(__file__).resolve().parents[1]
sys.path.insert(0, str(REPO / "tests"))

from test_stability import cummins, heave, kernel, scene_text, simulate  # noqa: E402

from hydrolink.clients.exudyn.client import RunInterrupted  # noqa: E402
from hydrolink.protocol.scene import SceneError  # noqa: E402
from hydrolink.server.hdb.io import load_hdb  # noqa: E402

SCHEMES = ("mass-matrix", "explicit", "explicit-predictor", "implicit")
RATIOS = (0.01, 0.1, 0.5, 0.9, 1.1, 2.0, 10.0, 100.0)
DTS = (0.01, 0.05, 0.2)
X0, DURATION, IRF = 0.5, 10.0, 20.0


def load_sphere():
    ds = load_hdb(REPO / "examples" / "data" / "sphere_task10" / "sphere.h5")
    return ds.drop_vars(["displaced_volume", "center_of_buoyancy"])


def reference(sphere, mass, a33, c33, h=0.001):
    n = int(round(DURATION / h))
    k = kernel(sphere, np.arange(int(round(IRF / h)) + 1) * h)
    return np.arange(n + 1) * h, cummins(mass + a33, c33, k, X0, h, n)


def one(sphere, scheme, mass, dt, ref, folder, allow_unstable=True):
    text = scene_text(mass, dt=dt, duration=DURATION, scheme=scheme, irf=IRF, x0=X0)
    t0 = time.perf_counter()
    try:
        summary, ds, _ = simulate(text, sphere, folder / "run.nc", allow_unstable=allow_unstable)
    except SceneError as exc:
        return {"outcome": "refused", "message": str(exc)}
    except RunInterrupted as exc:
        return {"outcome": "stopped", "message": str(exc), "step": exc.step}
    wall = time.perf_counter() - t0
    z = heave(ds)
    t = ds["time"].values
    assert np.isfinite(z).all()
    err = float(np.abs(z - np.interp(t, *ref)).max() / X0)
    return {"outcome": "accurate" if err < 0.01 else "stable", "error": err, "wall": wall,
            "iterations": summary.coupling.iterations_mean}


def stability_map(sphere, folder, ratios, dts):
    a33 = float(sphere["added_mass_inf"].values[2, 2])
    c33 = float(sphere["hydrostatic_stiffness"].values[2, 2])
    res = {}
    for r in ratios:
        mass = a33 / r
        ref = reference(sphere, mass, a33, c33)
        for dt in dts:
            for scheme in SCHEMES:
                res[scheme, r, dt] = out = one(sphere, scheme, mass, dt, ref, folder)
                extra = f"err {out['error']:.2e}" if "error" in out else out["message"][:90]
                print(f"{scheme:18s} A/m {r:6g} dt {dt:6g}: {out['outcome']:8s} {extra}", flush=True)
                # expected outcomes
                if scheme in ("mass-matrix", "implicit"):
                    assert out["outcome"] in ("accurate", "stable"), out
                elif r > 1.0:
                    assert out["outcome"] == "stopped", out
                    assert "A∞/m > 1" in out["message"] and "mass-matrix" in out["message"], out
    return res


def plot_map(res, ratios, dts, path):
    import matplotlib
    matplotlib.use("Agg")
    import matplotlib.pyplot as plt
    from matplotlib.colors import ListedColormap
    code = {"accurate": 0, "stable": 1, "stopped": 2, "refused": 3}
    cmap = ListedColormap(["#3a9d5d", "#e8c547", "#d9534f", "#7f7f7f"])
    fig, axes = plt.subplots(1, len(SCHEMES), figsize=(4.0 * len(SCHEMES), 3.6), sharey=True)
    for ax, scheme in zip(axes, SCHEMES):
        grid = np.array([[code[res[scheme, r, dt]["outcome"]] for r in ratios] for dt in dts])
        ax.imshow(grid, cmap=cmap, vmin=0, vmax=3, aspect="auto", origin="lower")
        for i, dt in enumerate(dts):
            for j, r in enumerate(ratios):
                o = res[scheme, r, dt]
                label = f"{100 * o['error']:.2g}%" if "error" in o else o["outcome"][:4]
                ax.text(j, i, label, ha="center", va="center", fontsize=7)
        ax.set_xticks(range(len(ratios)), [f"{r:g}" for r in ratios], fontsize=8)
        ax.set_yticks(range(len(dts)), [f"{dt:g}" for dt in dts])
        ax.set_xlabel("A∞/m")
        ax.set_title(scheme)
    axes[0].set_ylabel("dt (s)")
    handles = [plt.Rectangle((0, 0), 1, 1, color=cmap(i)) for i in range(4)]
    fig.legend(handles, ["accurate (< 1 %)", "stable, less accurate", "stopped with message", "refused"],
               loc="lower center", ncol=4, fontsize=8)
    fig.suptitle("Sphere heave decay: max error vs a 1 ms monolithic Cummins integration", fontsize=10)
    fig.tight_layout(rect=(0, 0.08, 1, 0.95))
    fig.savefig(path, dpi=110)


def table(res, ratios, dts) -> str:
    lines = ["| scheme | dt (s) | " + " | ".join(f"A∞/m = {r:g}" for r in ratios) + " |",
             "|---|---|" + "---|" * len(ratios)]
    for scheme in SCHEMES:
        for dt in dts:
            cells = []
            for r in ratios:
                o = res[scheme, r, dt]
                cells.append(f"{o['outcome']} {100 * o['error']:.2g} %" if "error" in o else
                             f"**{o['outcome']}** (step {o.get('step', 0)})")
            lines.append(f"| {scheme} | {dt:g} | " + " | ".join(cells) + " |")
    return "\n".join(lines)


def implicit_iterations(sphere, folder, ratios):
    a33 = float(sphere["added_mass_inf"].values[2, 2])
    rows = []
    for r in ratios:
        s, _, _ = simulate(scene_text(a33 / r, dt=0.01, duration=DURATION, scheme="implicit", irf=IRF, x0=X0),
                           sphere, folder / "it.nc")
        c = s["coupling"]
        rows.append((r, c["iterations_mean"], c["iterations_max"], c["initial_iterations"]))
        print(f"implicit A/m {r:g}: {c['iterations_mean']:.3f} iterations/step (max {c['iterations_max']}), "
              f"{c['initial_iterations']} at t = 0", flush=True)
        assert c["iterations_max"] <= 6
    return rows


def long_runs(sphere, folder, duration=3600.0):
    a33 = float(sphere["added_mass_inf"].values[2, 2])
    waves = textwrap.dedent("""\
        [waves]
        type = "irregular"
        spectrum = "jonswap"
        hs = 2.0
        tp = 8.0
        ramp = 20.0
        """)
    out = []
    for scheme in ("mass-matrix", "implicit"):
        t0 = time.perf_counter()
        s, ds, _ = simulate(scene_text(a33 * 2, dt=0.05, duration=duration, scheme=scheme, irf=IRF, x0=0.0,
                                       waves=waves), sphere, folder / f"long_{scheme}.nc")
        z = heave(ds)
        wall = time.perf_counter() - t0
        assert s["status"] == "complete" and np.isfinite(z).all() and np.abs(z).max() < 5.0
        out.append((scheme, duration, wall, float(np.abs(z).max()), float(z.std()), s["coupling"]["iterations_mean"]))
        print(f"{scheme}: {duration:g} s in {wall:.1f} s wall, max |z| {np.abs(z).max():.3f} m, "
              f"std {z.std():.3f} m", flush=True)
    assert abs(out[0][4] / out[1][4] - 1) < 0.01     # the two schemes agree on the heave std
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--out", default=str(REPO / "docs"))
    ap.add_argument("--quick", action="store_true", help="fewer cells and a 600 s long run")
    args = ap.parse_args()
    sphere = load_sphere()
    ratios = (0.5, 2.0) if args.quick else RATIOS
    dts = (0.01,) if args.quick else DTS
    with tempfile.TemporaryDirectory() as tmp:
        folder = Path(tmp)
        res = stability_map(sphere, folder, ratios, dts)
        its = implicit_iterations(sphere, folder, ratios)
        longs = long_runs(sphere, folder, 600.0 if args.quick else 3600.0)
    out = Path(args.out)
    plot_map(res, ratios, dts, out / "stability_map.png")
    print("\n" + table(res, ratios, dts))
    print("\n| A∞/m | iterations/step (mean) | max | at t = 0 |\n|---|---|---|---|")
    for r, m, mx, i0 in its:
        print(f"| {r:g} | {m:.3f} | {mx} | {i0} |")
    print("\n| scheme | simulated (s) | wall (s) | max abs(z) (m) | std z (m) | iterations/step |\n|---|---|---|---|---|---|")
    for scheme, d, wall, zmax, zstd, it in longs:
        print(f"| {scheme} | {d:g} | {wall:.1f} | {zmax:.3f} | {zstd:.4f} | {it:.3f} |")


if __name__ == "__main__":
    main()
