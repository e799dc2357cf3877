"""``hydrolink optimize SCENE.toml``: load, linearise (clients/analysis/steady.py), solve the QP, write
the optimum's trajectories over one (repeat) period as an xarray dataset (the results layout of
``hydrolink run``: dims time, body, dof, pto) with its power, the unconstrained bound, the active
limits and the WECCCOMP metrics in the attributes; returns a summary."""

from __future__ import annotations

import json
import math
import time as _time
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydrolink.clients.analysis.optimal.metrics import RunMetrics, run_metrics, scene_limits
from hydrolink.clients.analysis.optimal.problem import OptimalProblem, build_problem
from hydrolink.clients.analysis.optimal.solver import OptimalSolution, solve_optimal
from hydrolink.clients.analysis.steady import period_times, sampling_time
from hydrolink.protocol.scene import DOF_NAMES, Scene


@dataclass(frozen=True)
class OptimizeSummary:
    output: str
    power: float                  # W, constrained optimum
    unconstrained_power: float    # W, complex-conjugate bound of the same model
    period: float                 # s
    order: int
    active: list[str]
    utilisation: dict[str, float]
    metrics: RunMetrics
    solver: str
    status: str
    solve_seconds: float
    wall_time: float
    warnings: list[str]


def excitation_of(model, sys_) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The wave components over the system's n coordinates: (omega_c, X_c (n_c, n), eta_c)."""
    w, x_c, e_c = model.excitation_phasors()
    x = np.zeros((w.size, sys_.M.shape[0]), complex)
    x[:, sys_.wet_index] = x_c
    return w, x, e_c


def optimize_scene(scene: Scene, hdbs: dict) -> tuple[OptimalProblem, OptimalSolution, object]:
    """Linearise ``scene`` and solve its optimum; returns (problem, solution, setup)."""
    from hydrolink.clients.analysis.steady import check_mechanism, hydro_model, linearize

    bare = scene.model_copy(update={"controllers": []})     # the optimum replaces any controller
    model = hydro_model(bare, hdbs)
    setup = model.setup_info()
    sys_ = linearize(bare, model, setup, check=check_mechanism)
    prob = build_problem(bare, sys_, excitation_of(model, sys_))
    prob.warnings.extend(model.warnings)
    return prob, solve_optimal(prob), setup


def trajectories(prob: OptimalProblem, u: np.ndarray, times: np.ndarray) -> dict[str, np.ndarray]:
    """Position/velocity of every body, PTO force/stroke/velocity/power and the wave elevation at
    ``times`` for the force nodes ``u`` (trigonometric interpolation of the nodal values)."""
    s, p, m = prob.system, prob.points, prob.n_pto
    k = np.arange(-prob.order, prob.order + 1)
    from hydrolink.clients.analysis.steady import fourier_matrices

    E = fourier_matrices(prob.order, prob.omega0)[2]
    ev = np.exp(1j * np.outer(k * prob.omega0, times))

    def at(nodal: np.ndarray, d: int = 0) -> np.ndarray:
        return np.real((nodal @ E.T) * (1j * k * prob.omega0) ** d @ ev)

    q = prob.N @ (prob.z0 + prob.S @ u).reshape(-1, p)
    ext = (prob.s0 + prob.Ts @ u).reshape(m, p)
    f = at(u.reshape(m, p)).T
    vel = at(ext, 1).T
    nb = len(s.body_names)
    omega_c, _, eta_c = prob.excitation
    return {"position": s.reference[None] + at(q)[s.body_index].T.reshape(-1, nb, 6),
            "velocity": at(q, 1)[s.body_index].T.reshape(-1, nb, 6),
            "pto_force": f, "pto_velocity": vel, "pto_stroke": at(ext).T, "pto_power": f * vel,
            "total_pto_power": (f * vel).sum(axis=1),
            "wave_elevation": np.real(np.exp(-1j * np.outer(times, omega_c)) @ eta_c)}


def results_dataset(prob: OptimalProblem, sol: OptimalSolution, scene_text: str, dt: float):
    """The optimum over one period [0, T) every ``dt`` (``unconstrained_*``: the bound's trajectory)."""
    import xarray as xr

    from hydrolink.clients.lockstep.results import package_versions

    period = 2 * math.pi / prob.omega0
    times = period_times(period, dt, 6 * len(prob.system.body_names))
    opt, free = trajectories(prob, sol.u, times), trajectories(prob, sol.unconstrained_u, times)
    s = prob.system
    units = {"position": "m, rad", "velocity": "m/s, rad/s", "pto_force": "N (linear); N m (rotary axis)",
             "pto_velocity": "m/s; rad/s", "pto_stroke": "m; rad (extension from equilibrium)",
             "pto_power": "W", "total_pto_power": "W", "wave_elevation": "m"}
    dims = {"position": ("time", "body", "dof"), "velocity": ("time", "body", "dof"), "pto_force": ("time", "pto"),
            "pto_velocity": ("time", "pto"), "pto_stroke": ("time", "pto"), "pto_power": ("time", "pto"),
            "total_pto_power": ("time",), "wave_elevation": ("time",)}
    data = {k: xr.Variable(dims[k], opt[k], {"units": units[k]}) for k in dims}
    for k in ("pto_force", "pto_velocity", "pto_stroke", "total_pto_power"):
        data[f"unconstrained_{k}"] = xr.Variable(dims[k], free[k], {"units": units[k],
                                                                    "long_name": f"{k} at the unconstrained optimum"})
    data["equilibrium_position"] = xr.Variable(("body", "dof"), s.reference)
    ds = xr.Dataset(data, coords={"time": times, "body": s.body_names, "dof": list(DOF_NAMES), "pto": s.pto_names})
    ds.attrs.update({"title": "hydrolink optimize: PTO forces maximising the absorbed power under limits, one period",
                     "scene": scene_text, "status": "complete", "dt": float(dt),
                     "optimize_power": sol.power, "optimize_unconstrained_power": sol.unconstrained_power,
                     "optimize_electrical_power": sol.electrical_power, "optimize_efficiency": prob.efficiency,
                     "optimize_period": period, "optimize_order": prob.order, "optimize_solver": sol.solver,
                     "optimize_status": sol.status, "optimize_solve_seconds": sol.solve_seconds,
                     "optimize_active_limits": json.dumps(sol.active),
                     "optimize_utilisation": json.dumps(sol.utilisation),
                     "warnings": json.dumps(prob.warnings)})
    from importlib.metadata import version

    ds.attrs.update({f"{k}_version": v for k, v in package_versions().items()})
    ds.attrs["daqp_version"] = version("daqp")
    return ds


def optimize_scene_file(scene_path: str | Path, output: str | Path | None = None, *, dt: float | None = None,
                        progress: bool = True, hdbs: dict | None = None) -> OptimizeSummary:
    """``hydrolink optimize``: load, solve, write ``output`` (default SCENE.optimal.nc)."""
    from hydrolink.clients.scene_inputs import load_scene_hdbs
    from hydrolink.protocol.scene import load_scene

    scene_path = Path(scene_path)
    scene, text = load_scene(scene_path)
    dt = scene.simulation.dt if dt is None else sampling_time(dt)
    if hdbs is None:
        hdbs = load_scene_hdbs(scene, scene_path, progress=progress)
    wall0 = _time.perf_counter()
    prob, sol, _ = optimize_scene(scene, hdbs)
    ds = results_dataset(prob, sol, text, dt)
    metrics = run_metrics(ds, scene_limits(scene), efficiency=scene.optimize.efficiency)
    ds.attrs.update(metrics.attributes())
    output = Path(output) if output else scene_path.with_suffix(".optimal.nc")
    ds.to_netcdf(output)
    return OptimizeSummary(str(output), sol.power, sol.unconstrained_power, 2 * math.pi / prob.omega0, prob.order,
                           sol.active, sol.utilisation, metrics, sol.solver, sol.status, sol.solve_seconds,
                           _time.perf_counter() - wall0, prob.warnings)
