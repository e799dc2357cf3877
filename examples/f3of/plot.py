"""F3OF plots: the base pitch RAO sweep (time domain vs frequency domain) and the flap decay test.

    python examples/f3of/plot.py rao -o examples/f3of/f3of_rao.png      # runs the 11 periods (~5 min)
    python examples/f3of/plot.py decay f3of_decay.nc [f3of_decay_none.nc] -o f3of_decay.png

``rao`` runs ``f3of.toml`` (regular waves, amplitude 0.01 m) at T = 5, 6, ..., 15 s with dt = T/100,
fits the steady state (a cos wt + b sin wt + c over the last 400 s) and compares it with the
frequency-domain solution of the same linear model in the 5 constrained coordinates (base surge,
heave, pitch; flap angles about the hinges), both with the HDB's A(w), B(w) and with the effective
A, B that the truncated radiation convolution realises (README.md). It prints the table and plots
the base pitch RAO.
"""

from __future__ import annotations

import argparse
import tempfile
from pathlib import Path

import matplotlib

matplotlib.use("Agg")
import matplotlib.pyplot as plt  # noqa: E402
import numpy as np  # noqa: E402
import xarray as xr  # noqa: E402

HERE = Path(__file__).resolve().parent
PERIODS = np.arange(5.0, 16.0)
AMPLITUDE = 0.01
STEPS_PER_PERIOD = 100
DURATION, FIT = 2400.0, 400.0     # s: the 11 s mode decays with tau ~ 460 s (README)
BODIES = ("base", "flap1", "flap2")
MASS = {"base": (1089825.0, 7.63e7), "flap1": (179250.0, 1.3e6), "flap2": (179250.0, 1.3e6)}
HINGE_X = {"flap1": -12.5, "flap2": 12.5}
Z_BASE, Z_FLAP = -9.0, -5.5          # CoG = HDB reference points; hinges at z = 0
K_MOORING = 1.0e5
COORDS = ("base surge [m]", "base heave [m]", "base pitch [rad]", "flap1 angle [rad]", "flap2 angle [rad]")


# -- frequency domain ---------------------------------------------------------------------------

def hinge_map() -> np.ndarray:
    """T (9 x 5): surge, heave, pitch of base, flap1, flap2 (at their CoGs) from the coordinates
    q = (base surge x, base heave z, base pitch th, flap1 pitch p1, flap2 pitch p2), linearised.
    The hinge point h moves with the base by (x + (h_z - z_b) th, z - h_x th) and with the flap by
    (x_f + (h_z - z_f) p, z_f): x_f = x + 9 th - 5.5 p, z_f = z - h_x th (pitch: x-displacement
    of a point = +th (z_point - z_ref), z-displacement = -th (x_point - x_ref))."""
    t = np.zeros((9, 5))
    t[0, 0] = t[1, 1] = t[2, 2] = 1.0
    for i, body in enumerate(("flap1", "flap2")):
        r = 3 + 3 * i
        t[r, 0], t[r, 2], t[r, 3 + i] = 1.0, (0.0 - Z_BASE), -(0.0 - Z_FLAP)
        t[r + 1, 1], t[r + 1, 2] = 1.0, -HINGE_X[body]
        t[r + 2, 3 + i] = 1.0
    return t


def hdb_blocks(hdb):
    names = [str(n) for n in hdb["influenced_dof"].values]
    idx = [names.index(f"{b}.{d}") for b in BODIES for d in ("surge", "heave", "pitch")]
    a = hdb["added_mass"].values[:, idx][:, :, idx]
    b = hdb["radiation_damping"].values[:, idx][:, :, idx]
    return (idx, a, b,
            hdb["added_mass_inf"].values[np.ix_(idx, idx)], hdb["hydrostatic_stiffness"].values[np.ix_(idx, idx)],
            hdb["excitation_force"].values[:, 0, idx])


def at(omega_grid, values, w):
    flat = values.reshape(omega_grid.size, -1)
    out = [np.interp(w, omega_grid, f.real) + 1j * np.interp(w, omega_grid, f.imag) for f in flat.T]
    return np.array(out).reshape(values.shape[1:])


def effective_ab(omega_grid, b, a_inf, w, irf, dt):
    """A_eff, B_eff of the trapezoid convolution of K(t) = (2/pi) int B cos wt dw over [0, irf]."""
    om = np.r_[0.0, omega_grid]
    bb = np.concatenate([np.zeros((1, *b.shape[1:])), b])
    t = np.arange(int(round(irf / dt)) + 1) * dt
    k = np.array([2 / np.pi * np.trapezoid(bb * np.cos(om * ti)[:, None, None], om, axis=0) for ti in t])
    wt = np.full(t.size, dt)
    wt[[0, -1]] *= 0.5
    return (a_inf - np.tensordot(wt * np.sin(w * t), k, axes=(0, 0)) / w,
            np.tensordot(wt * np.cos(w * t), k, axes=(0, 0)))


def frequency_domain(hdb, w: float, *, effective: tuple[float, float] | None = None) -> np.ndarray:
    """Complex amplitudes of the 5 coordinates per metre of wave amplitude (exp(-iwt))."""
    _, a, b, a_inf, c, x = hdb_blocks(hdb)
    om = hdb["omega"].values
    if effective is None:
        aw, bw = at(om, a, w).real, at(om, b, w).real
    else:
        aw, bw = effective_ab(om, b, a_inf, w, *effective)
    m = np.diag([v for body in BODIES for v in (MASS[body][0], MASS[body][0], MASS[body][1])])
    k = c.copy()
    k[0, 0] += K_MOORING          # the mooring acts at the base's CoG = its reference point
    t = hinge_map()
    z = t.T @ (-w ** 2 * (m + aw) - 1j * w * bw + k) @ t
    return np.linalg.solve(z, t.T @ at(om, x, w))


# -- time domain --------------------------------------------------------------------------------

def coordinates(ds) -> np.ndarray:
    """(n_t, 5) base surge, heave, pitch and the flap pitch angles from a results file."""
    d = ds["position"] - ds["equilibrium_position"]
    cols = [d.sel(body="base", dof=k).values for k in ("surge", "heave", "pitch")]
    cols += [d.sel(body=f, dof="pitch").values for f in ("flap1", "flap2")]
    return np.column_stack(cols)


def steady_amplitudes(ds, period: float, window: float) -> np.ndarray:
    """Complex amplitudes (5,) fitted as a cos wt + b sin wt + c over the last ``window`` s."""
    t = ds["time"].values
    w = 2 * np.pi / period
    sel = t > t[-1] - window + 1e-9
    basis = np.c_[np.cos(w * t[sel]), np.sin(w * t[sel]), np.ones(sel.sum())]
    c = np.linalg.lstsq(basis, coordinates(ds)[sel], rcond=None)[0]
    return c[0] + 1j * c[1]


def scene_for(period: float, duration: float, steps: int = STEPS_PER_PERIOD) -> str:
    text = (HERE / "f3of.toml").read_text()
    text = text.replace('hdb = "f3of_hdb.toml"', f'hdb = "{(HERE / "f3of_hdb.toml").as_posix()}"')
    text = text.replace("dt = 0.08 ", f"dt = {period / steps!r} ").replace("duration = 1000.0", f"duration = {duration!r}")
    return text.replace("period = 8.0 ", f"period = {period!r} ")


def run_period(period: float, folder: Path, duration: float = DURATION) -> xr.Dataset:
    from hydrolink.clients.run import run_scene_file
    scene = folder / f"f3of_T{period:g}.toml"
    scene.write_text(scene_for(period, duration))
    run_scene_file(scene, folder / f"f3of_T{period:g}.nc", progress=False)
    return xr.load_dataset(folder / f"f3of_T{period:g}.nc")


def rao(output: str) -> None:
    from hydrolink.server.hdb.build.builder import build_hdb
    hdb = build_hdb(HERE / "f3of_hdb.toml", progress=False)
    rows = []
    with tempfile.TemporaryDirectory() as tmp:
        for period in PERIODS:
            ds = run_period(float(period), Path(tmp))
            td = steady_amplitudes(ds, period, FIT) / AMPLITUDE
            w = 2 * np.pi / period
            fd_eff = frequency_domain(hdb, w, effective=(40.0, period / STEPS_PER_PERIOD))
            fd_hdb = frequency_domain(hdb, w)
            rows.append((period, td, fd_eff, fd_hdb))
            err = np.abs(td) / np.abs(fd_eff) - 1
            print(f"T {period:4.1f} s: base pitch TD {np.degrees(abs(td[2])):8.4f} deg/m, FD(effective) "
                  f"{np.degrees(abs(fd_eff[2])):8.4f}, FD(HDB A, B) {np.degrees(abs(fd_hdb[2])):8.4f}; "
                  f"TD/FD(eff) - 1: " + " ".join(f"{e:+.2%}" for e in err), flush=True)
    p = np.array([r[0] for r in rows])
    pitch = np.degrees(np.abs(np.array([[r[1][2], r[2][2], r[3][2]] for r in rows])))
    wf = np.linspace(2 * np.pi / 15.5, 2 * np.pi / 4.8, 400)
    dense = np.degrees([abs(frequency_domain(hdb, w)[2]) for w in wf])
    fig, ax = plt.subplots(figsize=(8, 5))
    ax.semilogy(2 * np.pi / wf, dense, "-", color="0.6", label="frequency domain, HDB A(ω), B(ω)")
    ax.semilogy(p, pitch[:, 1], "s", mfc="none", ms=9, label="frequency domain, effective A, B (IRF 40 s)")
    ax.semilogy(p, pitch[:, 0], "o", ms=5, label="time domain (hydrolink run, dt = T/100)")
    ax.set_xlabel("wave period T [s]")
    ax.set_ylabel("base pitch RAO [deg/m]")
    ax.set_title("F3OF base pitch RAO, regular waves of 0.01 m amplitude")
    ax.grid(True, which="both", alpha=0.3)
    ax.legend()
    fig.tight_layout()
    fig.savefig(output, dpi=90)
    print(f"wrote {output}")


def decay(results: list[str], output: str) -> None:
    fig, axes = plt.subplots(len(results), 1, figsize=(9, 3.4 * len(results)), sharex=True, squeeze=False)
    for ax, path in zip(axes[:, 0], results):
        ds = xr.load_dataset(path)
        from hydrolink.protocol.scene import parse_scene
        interaction = parse_scene(ds.attrs["scene"]).hydro.interaction
        t = ds["time"].values
        q = coordinates(ds)
        ax.plot(t, np.degrees(q[:, 3]), label="flap 1 (released from 10°)")
        ax.plot(t, np.degrees(q[:, 4]), label=f"flap 2: max |angle| {np.degrees(np.abs(q[:, 4]).max()):.3g}°")
        ax.set_ylabel("flap angle [deg]")
        ax.set_title(f"F3OF decay, base held fixed, interaction = {interaction!r}")
        ax.grid(alpha=0.3)
        ax.legend(loc="upper right")
    axes[-1, 0].set_xlabel("time [s]")
    fig.tight_layout()
    fig.savefig(output, dpi=90)
    print(f"wrote {output}")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    sub = parser.add_subparsers(dest="what", required=True)
    r = sub.add_parser("rao", help="run the 5-15 s sweep and plot the base pitch RAO")
    r.add_argument("-o", "--output", default="f3of_rao.png")
    d = sub.add_parser("decay", help="plot decay-test results (one or more files)")
    d.add_argument("results", nargs="+")
    d.add_argument("-o", "--output", default="f3of_decay.png")
    args = parser.parse_args()
    if args.what == "rao":
        rao(args.output)
    else:
        decay(args.results, args.output)


if __name__ == "__main__":
    main()
