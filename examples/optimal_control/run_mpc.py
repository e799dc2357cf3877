"""Run examples/controllers/mpc.py against the constrained optimum on the WaveBot (wavebot.toml):

    python examples/optimal_control/run_mpc.py [--rate 10] [--predictor preview|gauge] [--sea regular|irregular]
                                               [--duration 60] [--realtime]

1. ``hydrolink optimize`` of the scene (regular: one period; irregular: the sea's repeat period);
2. ``hydrolink run`` of the same scene with the PTO's force commanded by the MPC, an external
   controller joining over the loopback (in a thread of this process, so its solve times can be read)
   at ``rate`` Hz (latency one control period), optionally paced in real time;
3. prints the MPC's mean power over the last ``--window`` s against the optimum, the WECCCOMP metrics
   of the run (clients/analysis/optimal/metrics.py) and the QP solve time percentiles.
Library use: :func:`mpc_run` (bench/bench_mpc.py, tests/test_optimal_mpc.py).
"""

from __future__ import annotations

import argparse
import math
import secrets
import socket
import sys
import threading
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
REPO = HERE.parents[1]
SCENE = HERE / "wavebot.toml"
REPEAT = 80.0       # s: the irregular sea's repeat period
GAUGE_HISTORY = 40.0   # s of an up-wave gauge's record fitted in an irregular sea
SETTLE = 10.0       # s after the ramp before the average (the MPC's start-up transient)
IRREGULAR = '''[waves]
type = "irregular"
spectrum = "jonswap"
hs = 0.15
tp = 3.3333333333333335
gamma = 3.3
components = {components}
omega_range = [{lo!r}, {hi!r}]
seed = 3
ramp = 10.0
'''


def scene_text(sea: str, dt: float, duration: float, ramp: float | None = None, base: Path = SCENE, *,
               repeat: float = REPEAT, first: int = 7, components: int = 60) -> str:
    """The WaveBot scene (HDB path made absolute) in its regular wave or a JONSWAP sea that repeats
    after ``repeat`` s: ``components`` at odd multiples of dw/2 (dw = 4 pi / repeat) from ``first`` dw
    (omega_range starts at a multiple of dw; the default: 60 components over 1.10 ... 10.5 rad/s)."""
    text = base.read_text().replace('"../data/', f'"{(base.parent.parent / "data").as_posix()}/')
    text = text.replace("dt = 0.03333333333333333   # s = T/100", f"dt = {dt!r}")
    text = text.replace("duration = 200.0", f"duration = {duration!r}")
    if ramp is not None:
        text = text.replace("ramp = 20.0", f"ramp = {ramp!r}")
    if sea == "irregular":
        dw = 2 * math.pi / repeat * 2      # components at odd multiples of dw / 2: the sea repeats after `repeat` s
        lo, n = first * dw, components     # around the peak at 1.88 rad/s
        start = text.index("[waves]")
        end = text.index("[hydro]")
        text = text[:start] + IRREGULAR.format(components=n, lo=lo, hi=lo + n * dw) + "\n" + text[end:]
        text = text.replace("\norder = 7 ", "\n# order: the sea's highest harmonic ")
    return text


def excitation_per_metre(scene, hdbs, omega: np.ndarray) -> np.ndarray:
    """(n_w, n_excitation_inputs): the plant's excitation inputs (every active DOF of the wet body)
    per metre of wave amplitude at the origin, exp(-iwt), the server model's own interpolation."""
    from hydrolink.server.sea.headings import interpolate_excitation

    b = scene.bodies[0]
    ds = hdbs[b.hdb]
    x = np.asarray(ds["excitation_force"].values, complex)      # (n_w, n_dir, 6)
    xi = interpolate_excitation(ds["omega"].values, ds["wave_direction"].values, x, omega,
                                math.radians(scene.waves.direction))
    active = [("surge", "sway", "heave", "roll", "pitch", "yaw").index(d) for d in (b.dofs or [])]
    return xi[:, active]


def controller_block(rate: float, dt: float, predictor: str, omega, x, horizon: float, gauge: float,
                     history: float, force_penalty: float = 0.0) -> str:
    period = 1.0 / rate
    latency = int(round(period / dt))
    preview = horizon + 1.0 if predictor == "preview" else 0.0
    probe = "[[0.0, 0.0]]" if predictor == "preview" else f"[[{-gauge!r}, 0.0]]"
    lst = lambda v: "[" + ", ".join(repr(float(a)) for a in np.ravel(v)) + "]"   # noqa: E731
    return (f'\n[[controllers]]\nname = "mpc"\nptos = ["pto"]\ncommand = "force"\nperiod = {period!r}\n'
            f'latency = {latency}\ntimeout = 5.0\njoin_timeout = 120.0\nmax_force = 2000.0\n'
            f'measurements = ["body_position", "body_velocity", "pto_velocity", "wave_elevation"]\n'
            f'wave_points = {probe}\npreview = {preview!r}\n'
            f'parameters = {{ omega = {lst(omega)}, excitation_re = {lst(x.real)}, excitation_im = {lst(x.imag)}, '
            f'horizon = {horizon!r}, blocks = 40, predictor = "{predictor}", gauge_distance = {gauge!r}, '
            f'history = {history!r}, force_penalty = {force_penalty!r} }}\n')


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


def mpc_run(folder: Path, *, rate: float = 10.0, predictor: str = "preview", sea: str = "regular",
            duration: float = 60.0, dt: float = 0.01, horizon: float = 4.0, gauge: float = 30.0,
            realtime: bool = False, ramp: float | None = None, efficiency: float = 1.0) -> dict:
    """Optimum + MPC run; returns powers, metrics and solve times (module docstring). ``efficiency`` < 1:
    the optimum maximises the electrical power ([optimize] efficiency); the MPC the mechanical power minus
    the force penalty rho sum u^2 Ts that solver.loss_penalty tunes on the collocation model."""
    import xarray as xr

    sys.path.insert(0, str(REPO / "examples" / "controllers"))
    from mpc import MPC

    from hydrolink.clients.analysis.optimal.metrics import run_metrics, scene_limits
    from hydrolink.clients.analysis.optimal.run import optimize_scene
    from hydrolink.clients.analysis.optimal.solver import loss_penalty
    from hydrolink.clients.control import run_controller
    from hydrolink.clients.run import run_scene_file
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import parse_scene

    base = scene_text(sea, dt, duration, ramp)
    if efficiency < 1:
        base = base.replace("\n[optimize]\n", f"\n[optimize]\nefficiency = {efficiency!r}\n")
    scene = parse_scene(base)
    path = folder / f"wavebot_{sea}_{predictor}_{int(rate)}hz.toml"
    path.write_text(base)
    hdbs = load_scene_hdbs(scene, path, progress=False)
    prob, opt, _ = optimize_scene(scene, hdbs)
    penalty = loss_penalty(prob, efficiency)[0] if efficiency < 1 else 0.0    # the MPC's convex stand-in
    if sea == "regular":
        omega = np.array([2 * math.pi / scene.waves.period])
    else:
        if predictor == "preview":
            omega = np.linspace(0.6, 6.0, 28)        # the predictor's grid over the spectrum
        else:                                        # the gauge record's own resolution, 2 pi / GAUGE_HISTORY
            omega = 2 * math.pi / GAUGE_HISTORY * np.arange(4, 42)
    x = excitation_per_metre(scene, hdbs, omega)
    history = GAUGE_HISTORY if (sea, predictor) == ("irregular", "gauge") else max(2 * math.pi / float(np.min(omega)), 10.0)
    text = base + controller_block(rate, dt, predictor, omega, x, horizon, gauge, history, penalty)
    path.write_text(text)
    token = secrets.token_urlsafe(32)
    listen = f"tcp://127.0.0.1:{_free_port()}"
    ctl = MPC()
    errors: list[BaseException] = []

    def serve():
        try:
            run_controller(ctl, listen, token=token, join_wait=120.0)
        except BaseException as exc:      # reported after the run
            errors.append(exc)

    th = threading.Thread(target=serve, daemon=True)
    th.start()
    out = path.with_suffix(".nc")
    summary = run_scene_file(path, out, progress=False, listen=listen, control_token=token, hdbs=hdbs,
                             realtime=1.0 if realtime else None)
    th.join(60.0)
    if errors:
        raise errors[0]
    ds = xr.load_dataset(out)
    start = duration - window(scene, duration)
    metrics = run_metrics(ds, scene_limits(scene), tolerance=0.01, start=start,
                          efficiency=scene.optimize.efficiency)
    st = np.asarray(ctl.solve_times[10:])
    return {"optimum": opt.power, "unconstrained": opt.unconstrained_power, "mpc": metrics.mean_power,
            "ratio": metrics.mean_power / opt.power, "metrics": metrics, "optimum_electrical": opt.electrical_power,
            "electrical_ratio": metrics.electrical_power / opt.electrical_power, "force_penalty": penalty, "fallbacks": ctl.fallbacks,
            "solve_p50": float(np.percentile(st, 50)), "solve_p99": float(np.percentile(st, 99)),
            "solve_max": float(st.max()), "solve_cpu_p99": float(np.percentile(ctl.solve_cpu_times[10:], 99)), "period": 1.0 / rate, "wall": summary.wall_time, "output": str(out), "scene": str(path)}


def window(scene, duration: float) -> float:
    """The averaging window: whole wave periods (regular) or the last repeat period (irregular)."""
    if scene.waves.type == "regular":
        t = scene.waves.period
        return t * math.floor(min(duration - scene.waves.ramp - SETTLE, 10 * t) / t)
    return REPEAT


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rate", type=float, default=10.0)
    ap.add_argument("--predictor", choices=["preview", "gauge"], default="preview")
    ap.add_argument("--sea", choices=["regular", "irregular"], default="regular")
    ap.add_argument("--duration", type=float, default=60.0)
    ap.add_argument("--horizon", type=float, default=4.0)
    ap.add_argument("--realtime", action="store_true")
    ap.add_argument("--efficiency", type=float, default=1.0,
                    help="PTO efficiency: the optimum of the electrical power; the MPC with a tuned force penalty")
    ap.add_argument("-o", "--output-dir", type=Path, default=Path("mpc_runs"),
                    help="folder for the run's scene and results (default mpc_runs/)")
    args = ap.parse_args()
    args.output_dir.mkdir(parents=True, exist_ok=True)
    r = mpc_run(args.output_dir, rate=args.rate, predictor=args.predictor, sea=args.sea, duration=args.duration,
                horizon=args.horizon, realtime=args.realtime, efficiency=args.efficiency)
    print(f"wrote {r['scene']} (the scene with the MPC joined) and {r['output']} (the run's results)")
    print(f"optimum {r['optimum']:.2f} W (unconstrained {r['unconstrained']:.2f} W); MPC {r['mpc']:.2f} W = "
          f"{100 * r['ratio']:.1f} % of the optimum; {r['fallbacks']} fallbacks")
    for u in r["metrics"].limits:
        print(f"  {u.label}: {100 * u.utilisation:.2f} % of {u.bound:g}, {u.violations} samples over 1 %")
    if r["metrics"].efficiency < 1:
        print(f"  electrical power at efficiency {r['metrics'].efficiency:g}: MPC {r['metrics'].electrical_power:.2f} W = "
              f"{100 * r['electrical_ratio']:.1f} % of the optimum's {r['optimum_electrical']:.2f} W (MPC force "
              f"penalty {r['force_penalty']:.3g} W/N^2)")
    print(f"  peak-to-average {r['metrics'].peak_to_average:.2f}; QP solve p50 {1e3 * r['solve_p50']:.2f} ms, "
          f"p99 {1e3 * r['solve_p99']:.2f} ms, max {1e3 * r['solve_max']:.2f} ms (control period {1e3 * r['period']:.0f} ms); "
          f"CPU time p99 {1e3 * r['solve_cpu_p99']:.2f} ms")


if __name__ == "__main__":
    main()
