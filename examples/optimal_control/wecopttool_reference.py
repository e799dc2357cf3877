"""WecOptTool's own optimum on the WaveBot scenes of this folder, the peer reference of ``hydrolink
optimize`` (tests/test_optimal_wecopttool.py), written to ``wecopttool_reference.json``:

    python examples/optimal_control/wecopttool_reference.py [--cases regular irregular] [-o FILE]

Needs WecOptTool 3.3 (``pip install --no-deps wecopttool==3.3.0 jax jaxlib ml_dtypes opt_einsum``, as
.ci/run does). For each sea — the regular wave of wavebot.toml (7 harmonics of 0.3 Hz) and run_mpc.py's
JONSWAP sea (Hs 0.15 m, Tp 3.33 s) shortened to repeat after 40 s: 16 components at the odd harmonics
9 ... 39 of 1/40 Hz, 1.41 ... 6.13 rad/s, order 39 — WecOptTool's SLSQP
maximises the mean mechanical power of its PTO with and without the 2000 N force limit (enforced on
its sub-step grid, 8 points per collocation interval), at the same harmonics as hydrolink.

Both tools get the same hydrodynamics, taken from hydrolink's linearised model of the scene (so the
comparison is of the optimisation, not of the interpolation of the HDB): the intrinsic impedance
Z(w) = B(w) + i w (m + A(w)) + K / (i w) at every harmonic, and each wave component's excitation per
metre and elevation (WecOptTool's exp(+iwt): the conjugates of hydrolink's exp(-iwt) phasors). The
irregular cases take minutes (jax tracing, SLSQP on 156 unknowns under 624 constraint rows): the test
reads this file and recomputes only hydrolink's side, after checking the sea recorded here is the scene's.
"""

from __future__ import annotations

import argparse
import json
import logging
import math
import sys
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
OUTPUT = HERE / "wecopttool_reference.json"
F_MAX = 2000.0       # N, wavebot.toml's [[optimize.limits]] force
NSUB = 8             # WecOptTool's constraint grid: sub-steps per collocation interval
FINE = 40            # sub-steps per interval of the grid its force's peak is measured on
IRREGULAR = {"repeat": 40.0, "first": 4, "components": 16}    # run_mpc.scene_text's sea, shortened


def scene(sea: str):
    """(scene, hdbs) of the WaveBot in ``sea`` (``regular``: wavebot.toml; ``irregular``: run_mpc's sea)."""
    sys.path.insert(0, str(HERE))
    from run_mpc import scene_text

    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import parse_scene

    sc = parse_scene(scene_text(sea, 0.01, 200.0, **(IRREGULAR if sea == "irregular" else {})))
    return sc, load_scene_hdbs(sc, HERE / "wavebot.toml", progress=False)


def hydrolink_problem(sea: str):
    """hydrolink's optimal-control problem of the sea's scene and its solution."""
    from hydrolink.clients.analysis.optimal.run import optimize_scene

    prob, sol, _ = optimize_scene(*scene(sea))
    return prob, sol


def wave_record(prob) -> dict:
    """The sea as the reference records it: harmonic numbers of f1 and the elevation phasors (exp(-iwt))."""
    omega_c, _, eta_c = prob.excitation
    return {"f1": prob.omega0 / (2 * math.pi), "order": prob.order,
            "harmonics": [int(h) for h in np.round(omega_c / prob.omega0)],
            "eta_re": [float(e.real) for e in eta_c], "eta_im": [float(e.imag) for e in eta_c]}


def wecopttool_optimum(prob, f_max: float | None) -> dict:
    """WecOptTool's optimal mean mechanical power (W) of ``prob``'s device and sea, its force's peak on
    a FINE-point-per-interval grid, and how its solver ended."""
    import jax.numpy as jnp
    import wecopttool as wot
    import xarray as xr

    logging.getLogger("wecopttool").setLevel(logging.ERROR)
    s = prob.system
    nfreq, f1 = prob.order, prob.omega0 / (2 * math.pi)
    freqs = f1 * np.arange(1, nfreq + 1)
    w = 2 * np.pi * freqs
    heave = s.wet_index[2]
    m = s.M[heave, heave] - s.added_mass_inf[2, 2]           # body mass (M holds A_inf)
    k = s.K[heave, heave]
    z = np.empty((nfreq, 1, 1), complex)
    for i, wi in enumerate(w):
        a, b = s.radiation(wi)
        z[i, 0, 0] = b[2, 2] + 1j * wi * (m + a[2, 2]) + k / (1j * wi)
    _, x_c, eta_c = prob.excitation
    idx = np.round(prob.excitation[0] / prob.omega0).astype(int) - 1
    exc = np.zeros((nfreq, 1, 1), complex)
    exc[idx, 0, 0] = np.conj(x_c[:, heave] / eta_c)              # per metre, WecOptTool's exp(+iwt)
    amp, phase = np.zeros((nfreq, 1)), np.zeros((nfreq, 1, 1))
    amp[idx, 0] = np.abs(eta_c)
    phase[idx, 0, 0] = np.degrees(-np.angle(eta_c))
    dims = ("omega", "radiating_dof", "influenced_dof")
    impedance = xr.DataArray(z, dims=dims, coords={"omega": w, "radiating_dof": ["Heave"], "influenced_dof": ["Heave"]})
    exc_coeff = xr.DataArray(exc, dims=("omega", "wave_direction", "influenced_dof"),
                             coords={"omega": w, "wave_direction": [0.0], "influenced_dof": ["Heave"]})
    pto = wot.pto.PTO(1, np.eye(1), None, None, None, ["PTO_Heave"])
    constraints = []
    if f_max is not None:
        constraints = [{"type": "ineq",
                        "fun": lambda wec, x_wec, x_opt, wave: f_max - jnp.abs(
                            pto.force_on_wec(wec, x_wec, x_opt, wave, NSUB).flatten())}]
    wec = wot.WEC.from_impedance(freqs, impedance, exc_coeff, np.array([[k]]), f_add={"PTO": pto.force_on_wec},
                                 constraints=constraints, min_damping=0.0)
    waves = wot.waves.elevation_fd(f1, nfreq, 0.0, 1, amp, phase)
    t0 = time.perf_counter()
    res = wec.solve(waves, pto.mechanical_average_power, 2 * nfreq, x_wec_0=np.zeros(2 * nfreq),
                    x_opt_0=np.zeros(2 * nfreq), scale_x_wec=1e1, scale_x_opt=1e-3, scale_obj=1e-2,
                    optim_options={"maxiter": 1000, "ftol": 1e-10})
    seconds = time.perf_counter() - t0
    x_wec, x_opt = wec.decompose_state(res[0].x)
    force = pto.force_on_wec(wec, x_wec, x_opt, waves.sel(realization=0), FINE)
    return {"power": -float(res[0].fun), "force_peak": float(np.abs(force).max()), "success": bool(res[0].success),
            "message": str(res[0].message), "iterations": int(res[0].nit), "seconds": round(seconds, 1)}


def main() -> None:
    from importlib.metadata import version

    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", nargs="+", choices=["regular", "irregular"], default=["regular", "irregular"])
    ap.add_argument("-o", "--output", type=Path, default=OUTPUT)
    args = ap.parse_args()
    out = json.loads(args.output.read_text()) if args.output.exists() else {}
    out["wecopttool_version"] = version("wecopttool")
    out["force_limit"] = F_MAX
    for sea in args.cases:
        prob, sol = hydrolink_problem(sea)
        case = {"wave": wave_record(prob)}
        for name, f_max in (("unconstrained", None), ("force_limit", F_MAX)):
            case[name] = wecopttool_optimum(prob, f_max)
            print(f"{sea} order {prob.order}, {name}: WecOptTool {case[name]['power']:.4f} W "
                  f"(peak force {case[name]['force_peak']:.1f} N, {case[name]['iterations']} iterations, "
                  f"{case[name]['seconds']} s, {case[name]['message']}); hydrolink "
                  f"{sol.unconstrained_power if f_max is None else sol.power:.4f} W", flush=True)
        out[sea] = case
    args.output.write_text(json.dumps(out, indent=1) + "\n")
    print(f"wrote {args.output}")


if __name__ == "__main__":
    main()
