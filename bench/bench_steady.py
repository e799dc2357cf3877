"""Pseudo-spectral steady state (``hydrolink steady``) against time stepping (``hydrolink run``).

For a scene in regular waves: the time-domain run at several dt and durations (wall time, steady
amplitude fitted over its last periods) and the collocation at several orders in both forms (DAE,
ODE; wall time of the solve and of the whole command without the HDB load); the amplitude of every
active DOF's first harmonic compared. Prints a Markdown table; ``--plot`` writes the cost plot.

    python bench/bench_steady.py examples/rm3/rm3.toml examples/hinged_barges/scene.toml --plot docs/steady_cost.png
"""

from __future__ import annotations

import argparse
import re
import tempfile
import time
from pathlib import Path

import numpy as np

from hydrolink.clients.run import load_scene_hdbs, run_scene_file
from hydrolink.clients.steady import hydro_model, linearize, solve
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
    out = {"wall": wall, "run_wall": summary["wall_time"], "steps": summary["steps"],
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
        from hydrolink.clients.steady import sample
        best["power"] = sample(sol, tt)["pto_power"].mean(axis=0)
    return best


def active_mask(scene) -> np.ndarray:
    return np.array([b.active_mask for b in scene.bodies], bool)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    ap.add_argument("scenes", nargs="+", type=Path)
    ap.add_argument("--orders", default="1,3,5,10,20")
    ap.add_argument("--steps-per-period", default="25,50,100,200")
    ap.add_argument("--periods", default="25,50,100", help="durations in wave periods (TD)")
    ap.add_argument("--plot", type=Path)
    args = ap.parse_args()
    orders = [int(x) for x in args.orders.split(",")]
    spp = [int(x) for x in args.steps_per_period.split(",")]
    periods = [int(x) for x in args.periods.split(",")]
    curves = {}
    for path in args.scenes:
        scene, _ = load_scene(path)
        T = scene.waves.period
        mask = active_mask(scene)
        names = [f"{b.name}.{d}" for b in scene.bodies for d in ("surge", "sway", "heave", "roll", "pitch", "yaw")]
        ref = spectral(path, max(orders), "dae", repeat=1)["amplitude"]
        big = np.abs(ref) > 1e-3 * np.abs(ref).max()
        keep = mask & big
        print(f"\n## {path}  (T = {T} s; DOFs compared: {', '.join(np.array(names)[keep.reshape(-1)])})\n")
        print("| method | setting | wall (s) | max amplitude error vs spectral N=" f"{max(orders)} DAE |")
        print("|---|---|---|---|")
        rows_s, rows_dt, rows_dur = [], [], []
        for form in ("dae", "ode"):
            for n in orders:
                s = spectral(path, n, form)
                err = np.abs(np.abs(s["amplitude"][keep]) / np.abs(ref[keep]) - 1).max()
                rows_s.append((form, n, s["wall"], s["solve"], err))
                print(f"| spectral {form.upper()} | N = {n} ({s['unknowns']} unknowns, {s['iterations']} Newton) | "
                      f"{s['wall']:.4f} (solve {s['solve'] * 1e3:.1f} ms) | {err:.2e} |")
        with tempfile.TemporaryDirectory() as tmp:
            for k in spp:
                dur = periods[-1] * T
                td = time_domain(path, T / k, dur, Path(tmp))
                err = np.abs(np.abs(td["amplitude"][keep]) / np.abs(ref[keep]) - 1).max()
                rows_dt.append((k, td["wall"], err))
                print(f"| time domain | dt = T/{k}, {periods[-1]} periods ({td['steps']} steps) | {td['wall']:.2f} | {err:.2e} |")
            for npd in periods[:-1]:
                td = time_domain(path, T / 100, npd * T, Path(tmp))
                err = np.abs(np.abs(td["amplitude"][keep]) / np.abs(ref[keep]) - 1).max()
                rows_dur.append((npd, td["wall"], err))
                print(f"| time domain | dt = T/100, {npd} periods ({td['steps']} steps) | {td['wall']:.2f} | {err:.2e} |")
        curves[path.stem] = (rows_s, rows_dt, rows_dur)
    if args.plot:
        import matplotlib
        matplotlib.use("Agg")
        import matplotlib.pyplot as plt
        fig, ax = plt.subplots(1, 2, figsize=(10, 4))
        for name, (rows_s, rows_dt, _) in curves.items():
            l, = ax[0].loglog([k for k, _, _ in rows_dt], [w for _, w, _ in rows_dt], "o-", label=f"{name}: time stepping")
            for form, style in (("dae", "s--"), ("ode", "^:")):
                best = min(r[2] for r in rows_s if r[0] == form and r[1] == max(r_[1] for r_ in rows_s))
                ax[0].axhline(best, ls=style[1:], color=l.get_color(), lw=1)
            ax[1].loglog([n for f, n, *_ in rows_s if f == "dae"], [w for f, n, w, *_ in rows_s if f == "dae"], "s-",
                         color=l.get_color(), label=f"{name}: DAE")
            ax[1].loglog([n for f, n, *_ in rows_s if f == "ode"], [w for f, n, w, *_ in rows_s if f == "ode"], "^:",
                         color=l.get_color(), label=f"{name}: ODE")
        ax[0].set(xlabel="time steps per wave period (T/dt)", ylabel="wall time (s)",
                  title="time stepping (lines: spectral, highest order)")
        ax[1].set(xlabel="harmonics N", ylabel="wall time (s)", title="spectral: setup + solve")
        for a in ax:
            a.legend(fontsize=7)
            a.grid(True, which="both", alpha=0.3)
        fig.tight_layout()
        fig.savefig(args.plot, dpi=110)
        print(f"\nplot: {args.plot}")


if __name__ == "__main__":
    main()
