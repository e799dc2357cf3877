"""Radiation options measured: server compute per step and accuracy (docs/radiation.md).

    python bench/bench_radiation.py cost [--steps 400] [--bodies 1 3 9 27]
    python bench/bench_radiation.py accuracy [--duration 30]

``cost``: HydroModel.step timed in-process (exactly what the server's session times as compute) for
1, 3, 9 and 27 bodies, every DOF active, full interaction, dt = 0.01 s, irf_duration = 10 s, regular
waves, random velocities; convolution vs state-space, dense (coupling_tolerance = 0) vs pruned
(coupling_tolerance = --prune). Bodies: 1 and 3 nodes and the whole of the 9N9LA HDB (Capytaine,
9 cylinders solved together, built from examples/node_9n9la/node_9n9la_hdb.toml and cached); 27 =
three 9N9LA arrays 200 m apart in one HDB, their cross blocks zero (the far-apart limit), excitation
phase-shifted by the offset. Median over --repeat timings of --steps steps after a warm-up.

``accuracy``: the 9-body fully coupled scene (9N9LA, all 54 DOFs, a vertical linear PTO damper
from every node to the seabed, regular waves T = 1.6 s, H = 0.04 m) run end to end through
``hydrolink run`` (Exudyn client, embedded server) with each radiation setting; heave amplitude of
every node and mean PTO power over the last 5 periods against the full convolution.
"""

from __future__ import annotations

import argparse
import statistics
import sys
import tempfile
import time
from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.protocol.scene import parse_scene
from hydrolink.server.hdb.build.builder import build_hdb
from hydrolink.protocol.hdb.schema import make_hdb, select_bodies, to_netcdf
from hydrolink.server.model import HydroModel

REPO = Path(__file__).resolve().parents[1]
SPEC = REPO / "examples" / "node_9n9la" / "node_9n9la_hdb.toml"
NODES = ["R0", "R1", "R2", "R3", "R4", "R5", "O0", "O2", "O4"]
MASS = 117.81                       # rho V of a node (fresh water)
DT, IRF, PERIOD, HEIGHT = 0.01, 10.0, 1.6, 0.04
SETTINGS = {  # label -> [hydro] lines
    "convolution": 'radiation = "convolution"',
    "convolution, taper 0.2": 'radiation = "convolution"\nirf_taper = 0.2',
    "state-space 0.3 %, taper 0.2": ('radiation = "state-space"\nirf_taper = 0.2\nss_tolerance = 0.003\n'
                                     'ss_max_order = 30'),
    "state-space 1 %, taper 0.5": 'radiation = "state-space"\nirf_taper = 0.5\nss_tolerance = 0.01',
    "constant": 'radiation = "constant"',
}


def node_9n9la() -> xr.Dataset:
    return build_hdb(SPEC, progress=False)


def array_27(ds: xr.Dataset, spacing: float = 200.0) -> xr.Dataset:
    """Three copies of the 9-body HDB, ``spacing`` apart along x, no cross coupling."""
    n = 54
    om = ds["omega"].values
    k = om ** 2 / float(ds.attrs["g"])                       # deep water wavenumber
    big = lambda v: np.zeros((om.size, 3 * n, 3 * n))        # noqa: E731
    a, b = big(0), big(0)
    a_inf, c = np.zeros((3 * n, 3 * n)), np.zeros((3 * n, 3 * n))
    x = np.zeros((om.size, ds["wave_direction"].size, 3 * n), complex)
    refs, names = [], []
    for c_ in range(3):
        s = slice(c_ * n, (c_ + 1) * n)
        a[:, s, s] = ds["added_mass"].values
        b[:, s, s] = ds["radiation_damping"].values
        a_inf[s, s] = ds["added_mass_inf"].values
        c[s, s] = ds["hydrostatic_stiffness"].values
        x[:, :, s] = ds["excitation_force"].values * np.exp(1j * k * c_ * spacing)[:, None, None]
        refs.append(ds["reference_point"].values + [c_ * spacing, 0, 0])
        names += [f"{b_}_{c_}" for b_ in map(str, ds["body"].values)]
    return make_hdb(bodies=names, omega=om, wave_direction=ds["wave_direction"].values, added_mass=a,
                    radiation_damping=b, excitation_force=x, hydrostatic_stiffness=c,
                    reference_point=np.concatenate(refs), rho=float(ds.attrs["rho"]), g=float(ds.attrs["g"]),
                    water_depth=float(ds.attrs["water_depth"]), source="9N9LA x 3", added_mass_inf=a_inf,
                    displaced_volume=np.tile(ds["displaced_volume"].values, 3))


def scene_text(names: list[str], refs: np.ndarray, hydro: str, *, duration: float = 10.0, ptos: bool = False,
               hdb: str = "hdb.nc") -> str:
    bodies = "".join(f'''
[[bodies]]
name = "{nm}"
hdb = "{hdb}"
mass = {MASS}
center_of_mass = [{r[0]}, {r[1]}, -0.4]
inertia = [4.0, 4.0, 3.7]
''' for nm, r in zip(names, refs))
    pto = "".join(f'''
[[ptos]]
name = "pto_{nm}"
type = "linear"
body1 = "{nm}"
point1 = [{r[0]}, {r[1]}, {r[2]}]
body2 = "ground"
point2 = [{r[0]}, {r[1]}, -20.0]
damping = 150.0
''' for nm, r in zip(names, refs)) if ptos else ""
    return f'''[simulation]
dt = {DT}
duration = {duration}
progress = false
[water]
density = 1000.0
[waves]
type = "regular"
height = {HEIGHT}
period = {PERIOD}
ramp = 5.0
[hydro]
irf_duration = {IRF}
{hydro}
{bodies}{pto}'''


def time_model(ds: xr.Dataset, hydro: str, steps: int, repeat: int) -> tuple[float, HydroModel, float]:
    names = [str(b) for b in ds["body"].values]
    refs = ds["reference_point"].values
    t0 = time.perf_counter()
    m = HydroModel(parse_scene(scene_text(names, refs, hydro)), {nm: ds for nm in names})
    setup = time.perf_counter() - t0
    rng = np.random.default_rng(0)
    pos = m.setup_info().equilibrium_position
    vel = 0.01 * rng.standard_normal((steps * (repeat + 1), len(names), 6))
    per = []
    k = 0
    for r in range(repeat + 1):
        t0 = time.perf_counter()
        for _ in range(steps):
            m.step(k * DT, pos, vel[k])
            k += 1
        if r:  # the first round is a warm-up
            per.append((time.perf_counter() - t0) / steps)
    return statistics.median(per) * 1e6, m, setup


def cost(args) -> None:
    ds9 = node_9n9la()
    sets = {1: select_bodies(ds9, NODES[:1]), 3: select_bodies(ds9, NODES[:3]), 9: ds9}
    if 27 in args.bodies:
        sets[27] = array_27(ds9)
    print(f"| bodies | DOFs | method | coupling | kept DOF pairs | dropped blocks | states | setup s | µs/step |")
    print("|---|---|---|---|---|---|---|---|---|")
    for nb in args.bodies:
        ds = sets[nb]
        for method in ("convolution", "state-space"):
            for tol in (0.0, args.prune):
                hydro = f'radiation = "{method}"\ncoupling_tolerance = {tol}'
                if method == "state-space":
                    hydro += f"\nirf_taper = 0.2\nss_tolerance = {args.ss_tolerance}\nss_max_order = 30"
                us, m, setup = time_model(ds, hydro, args.steps, args.repeat)
                info = m.setup_info()
                ss = info.state_space
                print(f"| {nb} | {6 * nb} | {method} | {'dense' if tol == 0 else f'pruned {tol:g}'} | "
                      f"{info['radiation_pairs']} ({100 * (1 - info['dropped_pair_fraction']):.0f} %) | "
                      f"{info['dropped_blocks']} of {nb * (nb - 1)} | {ss['states'] if ss else '-'} | "
                      f"{setup:.1f} | {us:.0f} |", flush=True)


def _fit(t: np.ndarray, y: np.ndarray, w: float) -> complex:
    basis = np.c_[np.cos(w * t), np.sin(w * t), np.ones(t.size), t - t.mean()]
    c = np.linalg.lstsq(basis, y, rcond=None)[0]
    return complex(c[0], c[1])


def accuracy(args) -> None:
    from hydrolink.clients.run import run_scene_file
    ds9 = node_9n9la()
    names = [str(b) for b in ds9["body"].values]
    refs = ds9["reference_point"].values
    w = 2 * np.pi / PERIOD
    results = {}
    with tempfile.TemporaryDirectory() as tmp:
        to_netcdf(ds9, Path(tmp) / "hdb.nc")
        for label, hydro in SETTINGS.items():
            if args.only and label not in args.only and label != "convolution":
                continue
            path = Path(tmp) / "scene.toml"
            path.write_text(scene_text(names, refs, hydro, duration=args.duration, ptos=True))
            t0 = time.perf_counter()
            summary = run_scene_file(path, Path(tmp) / "out.nc", progress=False)
            wall = time.perf_counter() - t0
            out = xr.load_dataset(Path(tmp) / "out.nc")
            t = out["time"].values
            sel = t >= t[-1] - 5 * PERIOD - 1e-9
            amp = np.array([abs(_fit(t[sel], (out["position"].sel(body=b, dof="heave")
                                              - out["equilibrium_position"].sel(body=b, dof="heave")).values[sel], w))
                            for b in names])
            n_per = int(round(5 * PERIOD / DT))
            power = out["pto_power"].values[-n_per:].mean(axis=0)
            results[label] = (amp, power, (summary.server_compute_us_per_step or float("nan")), wall)
    ref_amp, ref_pow = results["convolution"][:2]
    print(f"| setting | server µs/step | run wall s | max heave amplitude error | max PTO power error | total power error |")
    print("|---|---|---|---|---|---|")
    for label, (amp, power, us, wall) in results.items():
        print(f"| {label} | {us:.0f} | {wall:.1f} | {100 * np.max(np.abs(amp / ref_amp - 1)):.3f} % | "
              f"{100 * np.max(np.abs(power / ref_pow - 1)):.3f} % | {100 * (power.sum() / ref_pow.sum() - 1):+.3f} % |")
    print("reference heave amplitudes [mm]:", " ".join(f"{1e3 * a:.3f}" for a in ref_amp))
    print("reference mean PTO power [mW]:", " ".join(f"{1e3 * p:.3f}" for p in ref_pow))


def main(argv=None) -> None:
    p = argparse.ArgumentParser(description=__doc__, formatter_class=argparse.RawDescriptionHelpFormatter)
    p.add_argument("what", choices=["cost", "accuracy"])
    p.add_argument("--steps", type=int, default=300)
    p.add_argument("--repeat", type=int, default=3)
    p.add_argument("--bodies", type=int, nargs="+", default=[1, 3, 9, 27])
    p.add_argument("--prune", type=float, default=0.05)
    p.add_argument("--ss-tolerance", type=float, default=0.003)
    p.add_argument("--duration", type=float, default=30.0)
    p.add_argument("--only", nargs="*", help="accuracy: these settings (labels) besides the reference")
    args = p.parse_args(argv)
    (cost if args.what == "cost" else accuracy)(args)


if __name__ == "__main__":
    sys.exit(main())
