"""A sweep case's results file (``OUTDIR/cases/<name>.nc``): what a user needs to re-plot the case.

The worker runs the case into a full results file (``hydrolink run`` / ``steady``'s), summarises it
over the case's averaging window (:func:`summarise`) and writes the case's file from it
(:func:`write_case_file`):

- the summary the sweep's ``sweep.nc`` is built from, as variables ``summary_<name>`` on the results'
  own dimensions (pto, body, dof, joint, mooring, ...), the window in ``summary_window_start`` /
  ``summary_window_end``;
- the time series: by default (sweep key ``case_series = "tail"``) the last ``tail`` seconds of every
  series at the run's own sampling (default: 5 wave periods), or every sample of the run
  (``case_series = "full"``); attribute ``case_series`` says which, ``tail_seconds`` how long;
- the results file's attributes (scene, warnings, versions, status), compressed (zlib).

``sweep.nc`` is built from the summaries (:func:`read_summary`), never from the series, so a tail
loses nothing of it.
"""

from __future__ import annotations

import math
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.server.disk_cache import write_atomic

SUMMARY_PREFIX = "summary_"


@dataclass
class CaseSummary:
    """The numbers a case contributes to sweep.nc (NaN / empty where it has none)."""
    mean_total_pto_power: float = math.nan
    mean_pto_power: dict[str, float] = field(default_factory=dict)
    max_pto_force: dict[str, float] = field(default_factory=dict)
    bodies: list[str] = field(default_factory=list)
    motion_std: np.ndarray | None = None        # (body, dof)
    motion_max: np.ndarray | None = None
    joint_force: tuple[list[str], list[str], np.ndarray] | None = None
    mooring_force: tuple[list[str], list[str], np.ndarray] | None = None
    window: tuple[float, float] = (math.nan, math.nan)


def summarise(path: Path, window: tuple[float, float], steady: bool) -> CaseSummary:
    """A case's summary from its full results file over ``window`` (samples start < t <= end; a
    steady file's one period: every row)."""
    with xr.open_dataset(path, engine="netcdf4") as ds:
        t = ds["time"].values
        sel = np.ones(t.size, bool) if steady else (t > window[0] + 1e-9) & (t <= window[1] + 1e-9)
        if sel.sum() < 2:
            raise ValueError(f"{path.name}: fewer than 2 samples in the window [{window[0]:g}, {window[1]:g}] s")
        d = ds.isel(time=np.flatnonzero(sel)).load()
    s = CaseSummary(window=window)
    if "total_pto_power" in d:
        s.mean_total_pto_power = float(d["total_pto_power"].mean())
        for name in map(str, d["pto"].values):
            s.mean_pto_power[name] = float(d["pto_power"].sel(pto=name).mean())
            s.max_pto_force[name] = float(np.abs(d["pto_force"].sel(pto=name)).max())
    s.bodies = [str(b) for b in d["body"].values]
    motion = d["position"].values - d["equilibrium_position"].values[None]
    s.motion_std = motion.std(axis=0)
    s.motion_max = np.abs(motion).max(axis=0)
    if "joint_force" in d:
        s.joint_force = ([str(x) for x in d["joint"].values], [str(x) for x in d["joint_component"].values],
                         np.abs(d["joint_force"].values).max(axis=0))
    if "mooring_force" in d:
        s.mooring_force = ([str(x) for x in d["mooring"].values], [str(x) for x in d["mooring_component"].values],
                           np.abs(d["mooring_force"].values).max(axis=0))
    return s


def _summary_variables(s: CaseSummary) -> dict[str, tuple]:
    """The summary as (dims, values, attrs) per variable name (without the prefix), on the results'
    dimensions (their coordinates are the results file's own)."""
    out: dict[str, tuple] = {
        "window_start": ((), s.window[0], {"units": "s"}), "window_end": ((), s.window[1], {"units": "s"}),
        "motion_std": (("body", "dof"), s.motion_std, {"long_name": "std of position - equilibrium over the window"}),
        "motion_max": (("body", "dof"), s.motion_max, {"long_name": "max |position - equilibrium| over the window"}),
    }
    if not math.isnan(s.mean_total_pto_power):
        ptos = list(s.mean_pto_power)
        out["mean_total_pto_power"] = ((), s.mean_total_pto_power, {"units": "W"})
        out["mean_pto_power"] = (("pto",), [s.mean_pto_power[p] for p in ptos], {"units": "W"})
        out["max_pto_force"] = (("pto",), [s.max_pto_force[p] for p in ptos], {"units": "N (linear); N m (rotary)"})
    if s.joint_force is not None:
        out["max_joint_force"] = (("joint", "joint_component"), s.joint_force[2], {})
    if s.mooring_force is not None:
        out["max_mooring_force"] = (("mooring", "mooring_component"), s.mooring_force[2], {})
    return out


def write_case_file(full: Path, path: Path, summary: CaseSummary, tail: float | None) -> None:
    """The case's file at ``path`` (atomically) from its full results file ``full``: the summary and
    the last ``tail`` seconds of every series (``tail`` None: every sample)."""
    with xr.open_dataset(full, engine="netcdf4") as ds:
        t = ds["time"].values
        keep = slice(None) if tail is None else slice(int(np.searchsorted(t, t[-1] - tail - 1e-9)), None)
        d = ds.isel(time=keep).load()
    for name, (dims, values, attrs) in _summary_variables(summary).items():
        d[SUMMARY_PREFIX + name] = (dims, np.asarray(values, float), attrs)
    d.attrs["case_series"] = "full" if tail is None else "tail"
    d.attrs["tail_seconds"] = float(t[-1] - t[0]) if tail is None else float(tail)
    for v in d.variables.values():   # the run's file is written row by row (chunks of one row): not this one
        v.encoding = {}
    d.encoding = {}
    encoding = {v: {"zlib": True, "complevel": 4} for v in d.data_vars if d[v].dtype.kind == "f"}
    write_atomic(path, lambda tmp: d.to_netcdf(tmp, encoding=encoding))


def read_summary(path: Path) -> CaseSummary:
    """The summary a case file holds (:func:`write_case_file`); ValueError when it holds none."""
    with xr.open_dataset(path, engine="netcdf4") as ds:
        v = {k[len(SUMMARY_PREFIX):]: ds[k].load() for k in ds.data_vars if str(k).startswith(SUMMARY_PREFIX)}
        if "motion_std" not in v:
            raise ValueError(f"{path.name}: no summary variables ({SUMMARY_PREFIX}*): not a sweep case file")
        s = CaseSummary(window=(float(v["window_start"]), float(v["window_end"])),
                        bodies=[str(b) for b in ds["body"].values],
                        motion_std=v["motion_std"].values, motion_max=v["motion_max"].values)
        if "mean_pto_power" in v:
            ptos = [str(p) for p in ds["pto"].values]
            s.mean_total_pto_power = float(v["mean_total_pto_power"])
            s.mean_pto_power = dict(zip(ptos, map(float, v["mean_pto_power"].values)))
            s.max_pto_force = dict(zip(ptos, map(float, v["max_pto_force"].values)))
        for name, dims, attr in (("max_joint_force", ("joint", "joint_component"), "joint_force"),
                                 ("max_mooring_force", ("mooring", "mooring_component"), "mooring_force")):
            if name in v:
                setattr(s, attr, ([str(x) for x in ds[dims[0]].values], [str(x) for x in ds[dims[1]].values],
                                  v[name].values))
    return s
