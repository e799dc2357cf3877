"""Pseudo-spectral steady state (``hydrolink steady``) against time stepping (``hydrolink run``).

For a scene in regular waves: the time-domain run at several dt and durations (wall time, steady
amplitude fitted over its last periods) and the collocation at several orders in both forms (DAE,
ODE; wall time of the solve and of the whole command without the HDB load); the amplitude of every
active DOF's first harmonic compared. Prints a Markdown table; ``--plot`` writes the cost plot.

    python bench/bench_steady.py examples/rm3/rm3.toml examples/hinged_barges/scene.toml --plot docs/steady_cost.png
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")        # small dense solves: threads only add noise
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

import argparse
import re
import tempfile
import time
from pathlib import Path

import numpy as np

from hydrolink.clients.scene_inputs import load_scene_hdbs
from hydrolink.clients.run import run_scene_file
from hydrolink.clients.analysis.steady import hydro_model, linearize, solve
from hydrolink.protocol.scene import load_scene, resolve_path


def scene_variant(scene_path: Path, folder: Path, *, dt: float, duration: float, extra: str = "") -> Path:
    """The scene with another dt/duration (HDB paths made absolute), written into ``folder``."""
    text = scene_path.read_text()
    text = re.sub(r'(?m)^(\s*hdb\s*=\s*)"([^"]+)"',
                  lambda m: f'{m.group(1)}"{resolve_path(scene_path, m.group(2)).as_posix()}"', text)
    text = re.sub(r"(?m)^dt\s*=.*$", f"dt = {dt!r}", text)
    text = re.sub(r"(?m)^duration\s*=.*$", f"duration = {duration!r}", text)
    text = re.sub(r"(?m)^progress\s*=.*$", "", text)
    text = text.replace("[simulation]", "[simulation]\nprogress = false", 1) + extra
    out = folder / f"{scene_path.stem}_{dt:g}_{duration:g}.toml"
    out.write_text(text)
    return out


def fundamental(t: np.ndarray, x: np.ndarray, omega: float, periods: float = 5.0) -> np.ndarray:
    """Complex first-harmonic amplitude X (x ~ Re(X e^{-i w t})) fitted over the last periods, x (T, ...)."""
    sel = t > t[-1] - periods * 2 * np.pi / omega + 1e-9
    basis = np.c_[np.ones(sel.sum()), np.cos(omega * t[sel]), np.sin(omega * t[sel])]
    fit = np.linalg.lstsq(basis, x[sel].reshape(sel.sum(), -1), rcond=None)[0]
    return (fit[1] + 1j * fit[2]).reshape(x.shape[1:])


def time_domain(scene_path: Path, dt: float, duration: float, folder: Path, extra: str = "") -> dict:
    import xarray as xr

    path = scene_variant(scene_path, folder, dt=dt, duration=duration, extra=extra)
    t0 = time.perf_counter()
    summary = run_scene_file(path, folder / "td.nc", progress=False)
    wall = time.perf_counter() - t0
    ds = xr.load_dataset(folder / "td.nc")
    scene, _ = load_scene(path)
    w = 2 * np.pi / scene.waves.period
    x = (ds["position"] - ds["equilibrium_position"]).values
    out = {"wall": wall, "run_wall": summary.wall_time, "steps": summary.steps,
           "amplitude": fundamental(ds["time"].values, x, w), "ds": ds}
    if "pto_power" in ds:
        sel = ds["time"].values > ds["time"].values[-1] - 5 * scene.waves.period + 1e-9
        out["power"] = ds["pto_power"].values[sel].mean(axis=0)
    return out


def spectral(scene_path: Path, order: int, formulation: str, repeat: int = 3) -> dict:
    """Best of ``repeat``: setup (force model + linearisation) and the collocation solve."""
    scene, _ = load_scene(scene_path)
    hdbs = load_scene_hdbs(scene, scene_path, progress=False)
    best = None
    for _ in range(repeat):
        t0 = time.perf_counter()
        model = hydro_model(scene, hdbs)
        setup = model.setup_info()
        lin = linearize(scene, model, setup)
        t1 = time.perf_counter()
        sol = solve(lin, order, formulation)
        t2 = time.perf_counter()
        if best is None or t2 - t0 < best["wall"]:
            best = {"wall": t2 - t0, "setup": t1 - t0, "solve": t2 - t1, "sol": sol}
    sol = best["sol"]
    q = sol.harmonic(sol.q[lin.body_index]).reshape(-1, 6)
    best["amplitude"] = q
    best["iterations"] = sol.iterations
    best["unknowns"] = sol.unknowns
    p = sol.t.size
    if lin.ptos:
        tt = np.linspace(0, 2 * np.pi / lin.omega, 64 * p, endpoint=False)
        from hydrolink.clients.analysis.steady import sample
        best["power"] = sample(sol, tt)["pto_power"].mean(axis=0)
    return best


def active_mask(scene) -> np.ndarray:
    return np.array([b.active_mask for b in scene.bodies], bool)


CONVOLUTION = '\n[steady]\nradiation = "convolution"\n'


def amplitude_error(a: np.ndarray, ref: np.ndarray, keep: np.ndarray) -> float:
    return float(np.abs(np.abs(a[keep]) / np.abs(ref[keep]) - 1).max())


def bench_scene(path: Path, orders: list[int], spp: list[int], periods: list[int], repeat: int) -> dict:
    scene, _ = load_scene(path)
    T = scene.waves.period
    names = np.array([f"{b.name}.{d}" for b in scene.bodies for d in ("surge", "sway", "heave", "roll", "pitch", "yaw")])
    ref = spectral(path, max(orders), "dae", repeat=1)["amplitude"]
    keep = active_mask(scene) & (np.abs(ref) > 1e-3 * np.abs(ref).max())
    print(f"\n### {path} (T = {T} s; DOFs compared: {', '.join(names[keep.reshape(-1)])})\n")
    print("| method | setting | wall (s) | Newton | amplitude error vs TD (dt = T/%d, %d periods) |" % (spp[-1], periods[-1]))
    print("|---|---|---|---|---|")
    res = {"spectral": [], "dt": [], "duration": []}
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        td_best = time_domain(path, T / spp[-1], periods[-1] * T, tmp)
        conv_best = scene_variant(path, tmp, dt=T / spp[-1], duration=periods[-1] * T, extra=CONVOLUTION)
        for radiation in ("hdb", "convolution"):
            for form in ("dae", "ode"):
                for n in orders:
                    sp = path if radiation == "hdb" else conv_best
                    s = spectral(sp, n, form, repeat)
                    err = amplitude_error(s["amplitude"], td_best["amplitude"], keep)
                    res["spectral"].append((radiation, form, n, s["wall"], s["solve"], err))
                    print(f"| spectral {form.upper()}, A/B {radiation} | N = {n} ({s['unknowns']} unknowns) | "
                          f"{s['wall']:.3f} (solve {s['solve'] * 1e3:.1f} ms) | {s['iterations']} | {err:.2e} |")
        print()
        print("| time domain | steps | wall (s) | amplitude error vs spectral A/B hdb (N = %d) | vs spectral A/B convolution at this dt |" % max(orders))
        print("|---|---|---|---|---|")
        for k in spp:
            for npd in (periods if k == 100 else periods[-1:]):
                td = td_best if (k == spp[-1] and npd == periods[-1]) else time_domain(path, T / k, npd * T, tmp)
                conv = spectral(scene_variant(path, tmp, dt=T / k, duration=npd * T, extra=CONVOLUTION),
                                max(orders), "ode", 1)["amplitude"]
                e1, e2 = amplitude_error(td["amplitude"], ref, keep), amplitude_error(td["amplitude"], conv, keep)
                if npd == periods[-1]:
                    res["dt"].append((k, td["wall"], e1, e2))
                if k == 100:
                    res["duration"].append((npd, td["wall"], e1, e2))
                print(f"| dt = T/{k}, {npd} periods | {td['steps']} | {td['wall']:.2f} | {e1:.2e} | {e2:.2e} |")
    return res


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--orders", default="1,3,5,10,20")
    ap.add_argument("--steps-per-period", default="25,50,100,200")
    ap.add_argument("--periods", default="25,50,100", help="durations in wave periods (TD)")
    ap.add_argument("--repeat", type=int, default=3, help="spectral: best of")
    ap.add_argument("--plot", type=Path)
    args = ap.parse_args()
    orders = [int(x) for x in args.orders.split(",")]
    spp = [int(x) for x in args.steps_per_period.split(",")]
    periods = [int(x) for x in args.periods.split(",")]
    curves = {(path.parent.name if path.stem == "scene" else path.stem): bench_scene(path, orders, spp, periods, args.repeat) for path in args.scenes}
    if args.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(1, 2, figsize=(10, 4))
        for name, res in curves.items():
            l, = ax[0].loglog([k for k, *_ in res["dt"]], [w for _, w, *_ in res["dt"]], "o-",
                              label=f"{name}: time stepping, {periods[-1]} periods")
            ax[1].loglog([p for p, *_ in res["duration"]], [w for _, w, *_ in res["duration"]], "o-",
                         color=l.get_color(), label=f"{name}: time stepping, dt = T/100")
            for form, ls in (("dae", "--"), ("ode", ":")):
                w = [r[3] for r in res["spectral"] if r[0] == "hdb" and r[1] == form and r[2] == max(orders)][0]
                for a in ax:
                    a.axhline(w, ls=ls, color=l.get_color(), lw=1.2,
                              label=f"{name}: spectral {form.upper()}, N = {max(orders)}")
        ax[0].set(xlabel="time steps per wave period (T/dt)", ylabel="wall time (s)", title="cost against dt")
        ax[1].set(xlabel="simulated duration (wave periods)", ylabel="wall time (s)", title="cost against duration")
        for a in ax:
            a.legend(fontsize=6)
            a.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        fig.savefig(args.plot, dpi=110)
        print(f"\nplot: {args.plot}")


if __name__ == "__main__":
    main()
