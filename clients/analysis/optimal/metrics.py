"""WECCCOMP-style metrics of a run with limits, computed once from its results dataset.

Metrics (the WEC Control Competition's quantities, Ringwood et al. 2019): mean absorbed power,
peak-to-average power (max |total PTO power| / mean), the mean electrical power under ``[optimize]
efficiency`` eta (each PTO's eta p while it absorbs, p / eta while it feeds power back), and for every limit the utilisation
max |value| / limit and its violations (samples above the limit by more than ``tolerance``, and the
largest excess). Values come from the results variables: ``pto_force``, ``pto_velocity``,
``pto_stroke`` (written by ``hydrolink optimize``; for a ``hydrolink run`` the stroke is the time
integral of ``pto_velocity`` from the first row, where the run starts at equilibrium),
``position - equilibrium_position`` and ``velocity`` for a body DOF. Nothing here runs per step.
"""

from __future__ import annotations

import json
import math
from dataclasses import asdict, dataclass

import numpy as np

from hydrolink.protocol.scene import DOF_NAMES, LinearPTO, Scene


@dataclass(frozen=True)
class Limit:
    """A limit as the results see it: ``quantity`` of ``target`` (a PTO label, or body.dof)."""
    label: str
    key: str
    target: str
    quantity: str       # force | stroke | velocity | displacement | body_velocity
    bound: float


@dataclass(frozen=True)
class LimitUse:
    label: str
    bound: float
    utilisation: float      # max |value| / bound
    violations: int         # samples above bound (1 + tolerance)
    max_excess: float       # max(|value| / bound - 1, 0)


@dataclass(frozen=True)
class RunMetrics:
    mean_power: float
    peak_to_average: float
    limits: list[LimitUse]
    electrical_power: float     # W, under the efficiency rule (= mean_power at efficiency 1)
    efficiency: float = 1.0

    def attributes(self, prefix: str = "wecccomp_") -> dict[str, float | str]:
        """NetCDF attributes (scalars and one JSON table of the limits)."""
        return {f"{prefix}mean_power": self.mean_power, f"{prefix}peak_to_average": self.peak_to_average,
                f"{prefix}electrical_power": self.electrical_power, f"{prefix}efficiency": self.efficiency,
                f"{prefix}limits": json.dumps([asdict(u) for u in self.limits])}


def scene_limits(scene: Scene) -> list[Limit]:
    """The limits of ``scene``: ``[[optimize.limits]]`` and the PTOs' force/torque limits (an
    ``optimize`` force limit replaces the PTO's own)."""
    out: list[Limit] = []
    forces: dict[str, Limit] = {}
    for i, p in enumerate(scene.ptos):
        lim = p.force_limit if isinstance(p, LinearPTO) else p.torque_limit
        if lim is not None:
            labels = [p.name] if isinstance(p, LinearPTO) else [f"{p.name}.{a}" for a in p.axes]
            for label in labels:
                forces[label] = Limit(f"{label}.force", f"ptos[{i}]", label, "force", float(lim))
    for i, lim in enumerate(scene.optimize.limits):
        key = f"optimize.limits[{i}]"
        target = lim.pto if lim.pto is not None else f"{lim.body}.{lim.dof}"
        for q in ("force", "stroke", "displacement", "velocity"):
            bound = getattr(lim, q)
            if bound is None:
                continue
            quantity = "body_velocity" if (q == "velocity" and lim.body is not None) else q
            item = Limit(f"{target}.{q}", f"{key}.{q}", target, quantity, float(bound))
            if q == "force":
                forces[target] = item
            else:
                out.append(item)
    return list(forces.values()) + out


def _series(ds, limit: Limit) -> np.ndarray:
    """The limited quantity's time series from the results dataset."""
    if limit.quantity in ("displacement", "body_velocity"):
        body, dof = limit.target.rsplit(".", 1)
        j = DOF_NAMES.index(dof)
        if limit.quantity == "body_velocity":
            return np.asarray(ds["velocity"].sel(body=body).values[:, j], float)
        return np.asarray(ds["position"].sel(body=body).values[:, j] - ds["equilibrium_position"].sel(body=body).values[j],
                          float)
    name = {"force": "pto_force", "velocity": "pto_velocity", "stroke": "pto_stroke"}[limit.quantity]
    if name in ds:
        return np.asarray(ds[name].sel(pto=limit.target).values, float)
    from scipy.integrate import cumulative_trapezoid

    v = np.asarray(ds["pto_velocity"].sel(pto=limit.target).values, float)
    return cumulative_trapezoid(v, np.asarray(ds["time"].values, float), initial=0.0)


def run_metrics(ds, limits: list[Limit], *, tolerance: float = 1e-3, start: float | None = None,
                efficiency: float = 1.0) -> RunMetrics:
    """The metrics of the results ``ds`` (from time ``start``, default the first row) with the PTOs'
    ``efficiency`` (``[optimize] efficiency``)."""
    if start is not None:
        ds = ds.sel(time=slice(start, None))
    p = np.asarray(ds["total_pto_power"].values, float)
    mean = float(p.mean()) if p.size else math.nan
    uses = []
    for lim in limits:
        x = np.abs(_series(ds, lim)) / lim.bound
        uses.append(LimitUse(lim.label, lim.bound, float(x.max(initial=0.0)), int((x > 1 + tolerance).sum()),
                             float(max(x.max(initial=0.0) - 1.0, 0.0))))
    electrical = mean
    if efficiency < 1:
        pp = np.asarray(ds["pto_power"].values, float)
        electrical = float(np.where(pp >= 0, efficiency * pp, pp / efficiency).sum(axis=1).mean()) if pp.size else math.nan
    return RunMetrics(mean, float(np.abs(p).max(initial=0.0) / mean) if mean > 0 else math.inf, uses, electrical,
                      efficiency)
