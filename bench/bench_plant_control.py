"""The model-based controller against the best passive damper and the complex-conjugate limit, RM3
in an irregular sea (docs/plant.md "A controller designed on the plant").

    python bench/bench_plant_control.py [--duration 650] [--max-force 1e6]

Frequency domain (written here, exp(-iwt), every wave component of the run's own sea: the server
model's excitation phasors): the 2x2 heave impedance Z = -w^2 (M + A(w)) - i w B(w) + C from the
WAMIT HDB; the PTO sees u = v_f - v_s = u0 - Y T (Y = -i w e^T Z^-1 e, e = [1, -1]). Mean power of
a PTO impedance Z_c (T = Z_c u): sum 1/2 Re(Z_c) |u0 / (1 + Y Z_c)|^2; complex-conjugate limit
sum |u0/Y|^2 / (8 Re(1/Y)); best passive damper: the c maximising the sum with Z_c = c.
Time domain: ``hydrolink run`` of the passive damper at that c, and of the scene with passive
damping 0 and examples/controllers/plant_pi.py as an external controller (its own process,
loopback), mean PTO power over [ramp, end]. Prints a markdown table.
"""

from __future__ import annotations

import argparse
import re
import secrets
import socket
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np
import xarray as xr

TOKEN = secrets.token_urlsafe(32)   # the runs' join token, handed to their controllers (SPEC §5.7.2)

REPO = Path(__file__).resolve().parents[1]
HDB = REPO / "examples" / "data" / "rm3_wamit" / "rm3.1"
MASS = np.diag([725833.0, 886687.0])
HEAVE = [2, 8]
E = np.array([1.0, -1.0])


def scene(duration: float, damping: float, controller: str = "") -> str:
    text = (REPO / "examples" / "rm3" / "rm3_irregular.toml").read_text()
    for a, b in (('"../data/rm3_wamit/rm3.1"', f'"{HDB.as_posix()}"'), ("duration = 700.0", f"duration = {duration}")):
        assert a in text
        text = text.replace(a, b)
    text, n = re.subn(r"(?m)^damping = [0-9.e+]+", f"damping = {damping!r}", text)
    assert n == 1
    return text + controller


def thevenin(text: str):
    """(omega, u0, Y) per wave component of the scene's sea (exp(-iwt))."""
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.hdb.io import load_hdb
    from hydrolink.server.model import HydroModel

    sc = parse_scene(text)
    ds = load_hdb(HDB)
    model = HydroModel(sc.model_copy(update={"hydro": sc.hydro.model_copy(update={"irf_duration": 0.0})}),
                       {b.name: ds for b in sc.bodies})
    w, f, _ = model.excitation_phasors()
    om = ds["omega"].values
    out = []
    c = ds["hydrostatic_stiffness"].values[np.ix_(HEAVE, HEAVE)]
    for k, wk in enumerate(w):
        a = np.array([[np.interp(wk, om, ds["added_mass"].values[:, i, j]) for j in HEAVE] for i in HEAVE])
        b = np.array([[np.interp(wk, om, ds["radiation_damping"].values[:, i, j]) for j in HEAVE] for i in HEAVE])
        z = -wk ** 2 * (MASS + a) - 1j * wk * b + c
        zi = np.linalg.inv(z)
        out.append((wk, -1j * wk * E @ zi @ f[k, HEAVE], -1j * wk * E @ zi @ E))
    w, u0, y = (np.array(v) for v in zip(*out))
    return w, u0, y


def fd_power(u0, y, zc) -> float:
    return float(np.sum(0.5 * np.real(zc) * np.abs(u0 / (1 + y * zc)) ** 2))


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def td(tmp: Path, name: str, text: str, ramp: float, controller: bool):
    from hydrolink.clients.run import run_scene_file
    path = tmp / f"{name}.toml"
    path.write_text(text)
    proc = None
    listen = f"tcp://127.0.0.1:{free_port()}"
    if controller:
        proc = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "control",
                                 str(REPO / "examples" / "controllers" / "plant_pi.py"), "--server", listen, "--token", TOKEN,
                                 "--join-wait", "60"], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True)
    try:
        summary = run_scene_file(path, path.with_suffix(".nc"), progress=False, listen=listen, control_token=TOKEN)
    finally:
        if proc is not None:
            _, err = proc.communicate(timeout=60)
            if proc.returncode:
                print(err, file=sys.stderr)
    ds = xr.load_dataset(path.with_suffix(".nc"))
    sel = ds["time"].values >= ramp
    z = (ds["position"] - ds["equilibrium_position"]).sel(dof="heave").values
    stroke = z[sel, 0] - z[sel, 1]
    return (float(ds["pto_power"].values[sel].mean()), float(np.abs(ds["pto_force"].values[sel]).max()),
            float(np.abs(stroke).max()), summary)


def main() -> None:
    from scipy.optimize import minimize_scalar

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=650.0)
    ap.add_argument("--max-force", type=float, default=1.0e7, help="the controller's loose max_force (N); it also "
                    "runs at the passive damper's peak force")
    args = ap.parse_args()
    text0 = scene(args.duration, 0.0)
    from hydrolink.protocol.scene import parse_scene
    sc = parse_scene(text0)
    ramp = float(sc.waves.ramp)
    w, u0, y = thevenin(text0)
    p_cc = float(np.sum(np.abs(u0 / y) ** 2 / (8 * np.real(1 / y))))
    best = minimize_scalar(lambda lc: -fd_power(u0, y, np.exp(lc)), bounds=(np.log(1e4), np.log(1e8)), method="bounded")
    c_best = float(np.exp(best.x))
    p_passive_fd = fd_power(u0, y, c_best)
    # the controller's gains, as it computes them from the plant
    sys.path.insert(0, str(REPO / "examples" / "controllers"))
    from plant_pi import MARGIN, design

    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.clients.analysis.plant import build_plant
    path = Path(tempfile.mkdtemp()) / "s.toml"
    path.write_text(text0)
    plant = build_plant(sc, load_scene_hdbs(sc, path, progress=False))
    wp = 2 * np.pi / float(sc.waves.tp)
    c, k = design(plant, "pto", wp)
    p_pi_fd = fd_power(u0, y, c + 1j * k / w)        # exp(-iwt): T = c u + k x, x = u / (-i w)
    def ctl(limit: float) -> str:
        return (f'\n[[controllers]]\nname = "ctl"\nptos = ["pto"]\ncommand = "force"\ntimeout = 5.0\n'
                f'measurements = ["pto_displacement", "pto_velocity"]\nmax_force = {limit!r}\n')
    with tempfile.TemporaryDirectory() as d:
        tmp = Path(d)
        passive = td(tmp, "passive", scene(args.duration, c_best), ramp, False)
        limits = [args.max_force, passive[1]]   # a loose limit, and the passive damper's own peak force
        pis = [td(tmp, f"plant_pi_{i}", scene(args.duration, 0.0, ctl(lim)), ramp, True) for i, lim in enumerate(limits)]
    print(f"sea: JONSWAP Hs {sc.waves.hs} m, Tp {sc.waves.tp} s, gamma {sc.waves.gamma}, seed {sc.waves.seed}, "
          f"{w.size} components; mean over t >= {ramp:g} s of {args.duration:g} s, dt {sc.simulation.dt} s")
    print(f"plant PI gains at Tp (stability margin {MARGIN} 1/s): c = {c:.4g} N s/m, k = {k:.4g} N/m; best passive c = {c_best:.4g} N s/m\n")
    print("| PTO | mean power FD (kW) | mean power TD (kW) | % of best passive (TD) | % of CC limit | max |force| TD (N) | max |stroke| TD (m) |")
    print("|---|---|---|---|---|---|---|")
    print(f"| complex-conjugate limit (unconstrained) | {p_cc / 1e3:.1f} | - | {100 * p_cc / passive[0]:.0f} | 100 | - | - |")
    print(f"| best passive damper c = {c_best:.3g} | {p_passive_fd / 1e3:.1f} | {passive[0] / 1e3:.1f} | 100 | "
          f"{100 * passive[0] / p_cc:.0f} | {passive[1]:.3g} | {passive[2]:.2f} |")
    for lim, pi in zip(limits, pis):
        print(f"| plant_pi.py, max_force {lim:.3g} N | {p_pi_fd / 1e3:.1f} (unclipped) | {pi[0] / 1e3:.1f} | "
              f"{100 * pi[0] / passive[0]:.0f} | {100 * pi[0] / p_cc:.0f} | {pi[1]:.3g} | {pi[2]:.2f} |")
        print(f"controller events: {pi[3].controllers}", file=sys.stderr)


if __name__ == "__main__":
    main()
