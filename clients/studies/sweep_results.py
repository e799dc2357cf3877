"""``sweep.nc``: every case's summary on one dimension per sweep key, and the power matrix + AEP.

Per case (its file's summary over its averaging window; clients/studies/sweep_case_file.py):

=========================  =================================  =====================================
variable                   dims (after the sweep keys)        meaning
=========================  =================================  =====================================
mean_total_pto_power       -                                  W, mean of total_pto_power
mean_pto_power             pto                                W, mean of pto_power
max_pto_force              pto                                N or N m, max |pto_force|
motion_std                 body, dof                          std of position - equilibrium
motion_max                 body, dof                          max |position - equilibrium|
max_joint_force            joint, joint_component             max |joint_force| (scenes with joints)
max_mooring_force          mooring, mooring_component         max |mooring_force| (with moorings)
sea_state_height/_period   -                                  Hm0 and Te (irregular) or H and T (s)
energy_flux                -                                  W/m, J of the sea state
capture_width(_ratio)      -                                  m (P / J), - (CW / characteristic width)
wall_time, attempts        -                                  s of the whole case; runs it took
status, error, solver      -                                  "complete" / "failed" / "absent"
case_id, label             -                                  the case's key (its record's) and name
case_name                  -                                  the stem of its files (cases/<case_name>.*)
window_start, window_end   -                                  s, the averaging window
=========================  =================================  =====================================

A cell of the key grid that no case fills ("zip" and "axes" modes, explicit cases) has status
"absent" and NaN elsewhere. Power matrix (clients/studies/power_matrix.py), one per combination of the
sweep keys other than the sea state's and ``waves.seed``: ``power_matrix``,
``capture_width_matrix``, ``energy_flux_matrix``, ``case_count`` over (hm0, te) (H, T for regular
waves), and with a site ``occurrence`` (hm0, te), ``annual_energy`` (Wh) and
``uncovered_occurrence``.
"""

from __future__ import annotations

import json
import math
from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.clients.studies.power_matrix import PowerMatrix, SeaState, annual_energy, power_matrix, sea_state
from hydrolink.clients.lockstep.results import DOF_NAMES, package_versions
from hydrolink.clients.studies.sweep_file import Case, Sweep
from hydrolink.clients.studies.sweep_case_file import CaseSummary
from hydrolink.clients.studies.sweep_worker import CaseRecord
from hydrolink.protocol.scene import RegularWave


def averaging_window(case: Case, window: tuple[float, float] | None, steady: bool) -> tuple[float, float]:
    """The case's window: the sweep's, else from the end of the wave ramp to the end; for regular
    waves shortened at its start to whole wave periods; a steady solution's: its one period."""
    scene = case.scene
    if steady:
        return (0.0, float(scene.waves.period))
    duration = float(scene.simulation.duration)
    ramp = float(getattr(scene.waves, "ramp", 0.0) or 0.0)
    start, end = window if window is not None else (ramp if ramp < duration else 0.0, duration)
    end = min(end, duration)
    if isinstance(scene.waves, RegularWave):
        period = float(scene.waves.period)
        k = math.floor((end - start) / period + 1e-9)
        if k >= 1:
            start = end - k * period
    return (start, end)


def _coords(sweep: Sweep) -> dict[str, list]:
    """Each sweep key's values over the cases: numbers sorted, other values in order of appearance."""
    out = {}
    for key in sweep.keys:
        vals = list(dict.fromkeys(c.coords[key] for c in sweep.cases))
        if all(isinstance(v, float) for v in vals):
            vals = sorted(v for v in vals if not math.isnan(v)) + [v for v in vals if math.isnan(v)][:1]
        out[key] = vals
    return out


def _cell(coords: dict[str, list], case: Case) -> tuple[int, ...]:
    def index(values, v):
        if isinstance(v, float) and math.isnan(v):
            return next(i for i, x in enumerate(values) if isinstance(x, float) and math.isnan(x))
        return values.index(v)
    return tuple(index(values, case.coords[k]) for k, values in coords.items())


def build_dataset(sweep: Sweep, records: dict[str, CaseRecord], summaries: dict[str, CaseSummary],
                  states: dict[str, SeaState | None]) -> xr.Dataset:
    """sweep.nc's dataset (module docstring) from each case's record, summary and sea state."""
    coords = _coords(sweep)
    dims = list(coords)
    shape = tuple(len(v) for v in coords.values())
    ptos = list(dict.fromkeys(p for s in summaries.values() for p in s.mean_pto_power))
    bodies = list(dict.fromkeys(b for s in summaries.values() for b in s.bodies))
    joints = _labels(s.joint_force for s in summaries.values())
    moorings = _labels(s.mooring_force for s in summaries.values())

    def grid(extra: tuple[int, ...] = (), fill=np.nan, dtype=float):
        return np.full(shape + extra, fill, dtype=dtype)
    v = {name: grid() for name in ("mean_total_pto_power", "sea_state_height", "sea_state_period", "energy_flux",
                                   "capture_width", "capture_width_ratio", "wall_time", "window_start",
                                   "window_end")}
    v["attempts"] = grid(fill=0, dtype=int)
    text = {name: grid(fill="", dtype=object) for name in ("status", "error", "solver", "case_id", "case_name",
                                                          "label")}
    text["status"][...] = "absent"
    per_pto = {name: grid((len(ptos),)) for name in ("mean_pto_power", "max_pto_force")}
    motion = {name: grid((len(bodies), 6)) for name in ("motion_std", "motion_max")}
    jf = grid((len(joints[0]), len(joints[1]))) if joints[0] else None
    mf = grid((len(moorings[0]), len(moorings[1]))) if moorings[0] else None
    width = sweep.spec.characteristic_width
    for case in sweep.cases:
        cell = _cell(coords, case)
        rec = records.get(case.case_id)
        text["case_id"][cell], text["label"][cell], text["solver"][cell] = case.case_id, case.label, case.solver
        text["case_name"][cell] = case.name
        state = states.get(case.case_id)
        if state is not None:
            v["sea_state_height"][cell], v["sea_state_period"][cell] = state.height, state.period
            v["energy_flux"][cell] = state.energy_flux
        if rec is None:
            text["status"][cell] = "not run"
            continue
        text["status"][cell], text["error"][cell] = rec.status, rec.error
        v["wall_time"][cell], v["attempts"][cell] = rec.wall_time, rec.attempt
        s = summaries.get(case.case_id)
        if s is None:
            continue
        v["window_start"][cell], v["window_end"][cell] = s.window
        v["mean_total_pto_power"][cell] = s.mean_total_pto_power
        if state is not None and state.energy_flux > 0:
            v["capture_width"][cell] = s.mean_total_pto_power / state.energy_flux
            if width:
                v["capture_width_ratio"][cell] = v["capture_width"][cell] / width
        for i, p in enumerate(ptos):
            per_pto["mean_pto_power"][cell + (i,)] = s.mean_pto_power.get(p, np.nan)
            per_pto["max_pto_force"][cell + (i,)] = s.max_pto_force.get(p, np.nan)
        for i, b in enumerate(bodies):
            if b in s.bodies:
                motion["motion_std"][cell + (i,)] = s.motion_std[s.bodies.index(b)]
                motion["motion_max"][cell + (i,)] = s.motion_max[s.bodies.index(b)]
        for target, src, labels in ((jf, s.joint_force, joints), (mf, s.mooring_force, moorings)):
            if target is not None and src is not None:
                for i, name in enumerate(src[0]):
                    for j, comp in enumerate(src[1]):
                        target[cell + (labels[0].index(name), labels[1].index(comp))] = src[2][i, j]
    units = {"mean_total_pto_power": "W", "sea_state_height": "m", "sea_state_period": "s", "energy_flux": "W/m",
             "capture_width": "m", "capture_width_ratio": "1", "wall_time": "s", "window_start": "s",
             "window_end": "s", "mean_pto_power": "W", "max_pto_force": "N (linear); N m (rotary)",
             "motion_std": "m (surge, sway, heave); rad (roll, pitch, yaw)", "motion_max":
             "m (surge, sway, heave); rad (roll, pitch, yaw)", "max_joint_force": "N (fx, fy, fz); N m (mx, my, mz)",
             "max_mooring_force": "N; N m"}
    data = {k: (dims, a) for k, a in v.items()}
    data.update({k: (dims, a.astype(str)) for k, a in text.items()})
    data.update({k: (dims + ["pto"], a) for k, a in per_pto.items()})
    data.update({k: (dims + ["body", "dof"], a) for k, a in motion.items()})
    if jf is not None:
        data["max_joint_force"] = (dims + ["joint", "joint_component"], jf)
    if mf is not None:
        data["max_mooring_force"] = (dims + ["mooring", "mooring_component"], mf)
    extra = {"pto": ptos, "body": bodies, "dof": list(DOF_NAMES)}
    if jf is not None:
        extra.update(joint=joints[0], joint_component=joints[1])
    if mf is not None:
        extra.update(mooring=moorings[0], mooring_component=moorings[1])
    ds = xr.Dataset(data, coords={**{k: np.asarray(vals) for k, vals in coords.items()}, **extra})
    for k, u in units.items():
        if k in ds:
            ds[k].attrs["units"] = u
    kinds = {s.kind for s in states.values() if s is not None}
    ds.attrs.update({
        "title": "hydrolink sweep", "sweep_file": sweep.text, "scene": sweep.scene_text,
        "sweep_keys": json.dumps(sweep.keys), "cases": len(sweep.cases),
        "sea_state": sea_state_note(states),
        **({"characteristic_width": width} if width else {}),
        **{f"{k}_version": x for k, x in package_versions().items()}})
    if kinds:
        add_power_matrix(ds, sweep, kinds)
    return ds


def _labels(items) -> tuple[list[str], list[str]]:
    names, comps = [], []
    for it in items:
        if it is not None:
            names += [n for n in it[0] if n not in names]
            comps += [c for c in it[1] if c not in comps]
    return names, comps


def sea_state_note(states: dict[str, SeaState | None]) -> str:
    """How the sea states were characterised, said explicitly (the spectra and their Te / Tp)."""
    notes = []
    for s in {(x.kind, x.spectrum, round(x.te_over_tp, 6) if x.kind == "irregular" else None)
              for x in states.values() if x is not None}:
        if s[0] == "irregular":
            notes.append(f"irregular, {s[1]}: Hm0 = 4 sqrt(m0) = hs, Te = m-1/m0 of that spectrum = {s[2]:.4f} Tp; "
                         "J = rho g int c_g S df")
        else:
            notes.append("regular: H, T; J = rho g H^2/8 c_g")
    return "; ".join(sorted(notes))


def add_power_matrix(ds: xr.Dataset, sweep: Sweep, kinds: set[str]) -> None:
    """Power matrix variables (and AEP with a site) per combination of the other sweep keys."""
    if len(kinds) > 1:
        ds.attrs["power_matrix"] = "not computed: the sweep mixes regular and irregular sea states"
        return
    others = [k for k in sweep.other_keys if k in ds.dims]
    scatter = sweep.scatter
    h = ds["sea_state_height"].values
    t = ds["sea_state_period"].values
    if scatter is not None:
        hc, tc = scatter.hm0, scatter.te
    else:
        hc = np.unique(np.round(h[np.isfinite(h)], 9))
        tc = np.unique(np.round(t[np.isfinite(t)], 9))
    if hc.size == 0 or tc.size == 0:
        return
    sizes = [ds.sizes[k] for k in others]
    pm_shape = tuple(sizes) + (hc.size, tc.size)
    out = {n: np.full(pm_shape, np.nan) for n in ("power_matrix", "capture_width_matrix", "energy_flux_matrix")}
    count = np.zeros(pm_shape, int)
    aep = np.full(tuple(sizes), np.nan)
    uncovered = np.full(tuple(sizes), np.nan)
    p_all = ds["mean_total_pto_power"]
    j_all = ds["energy_flux"]
    for idx in np.ndindex(*sizes) if sizes else [()]:
        sel = {k: i for k, i in zip(others, idx)}
        pm: PowerMatrix = power_matrix(ds["sea_state_height"].isel(sel).values.ravel(),
                                       ds["sea_state_period"].isel(sel).values.ravel(),
                                       p_all.isel(sel).values.ravel(), j_all.isel(sel).values.ravel(), hc, tc)
        out["power_matrix"][idx] = pm.power
        out["capture_width_matrix"][idx] = pm.capture_width
        out["energy_flux_matrix"][idx] = pm.energy_flux
        count[idx] = pm.count
        if scatter is not None:
            aep[idx], uncovered[idx] = annual_energy(pm, scatter.occurrence)
    regular = kinds == {"regular"}
    hname, tname = ("height", "period") if regular else ("hm0", "te")
    mdims = others + [hname, tname]
    ds.coords[hname] = (hname, hc, {"units": "m", "long_name": "wave height H" if regular else
                                    "significant wave height Hm0 (bin centre)"})
    ds.coords[tname] = (tname, tc, {"units": "s", "long_name": "wave period T" if regular else
                                    "energy period Te (bin centre)"})
    for n, u in (("power_matrix", "W"), ("capture_width_matrix", "m"), ("energy_flux_matrix", "W/m")):
        ds[n] = (mdims, out[n], {"units": u})
    ds["case_count"] = (mdims, count)
    ds["power_matrix"].attrs["long_name"] = ("mean capture width x mean energy flux per bin (IEC TS 62600-100; "
                                             "the case's mean power when a bin holds one case)")
    if scatter is not None:
        ds["occurrence"] = ((hname, tname), scatter.occurrence, {"long_name": "site occurrence (sums to 1)"})
        ds["annual_energy"] = (others, aep, {"units": "Wh", "long_name": "AEP = 8766 h sum P occurrence"})
        ds["uncovered_occurrence"] = (others, uncovered, {"long_name": "occurrence of site bins without a case"})
        ds.attrs["site_scatter"] = scatter.path
        ds.attrs["site_source"] = scatter.source


def case_sea_states(sweep: Sweep) -> dict[str, SeaState | None]:
    return {c.case_id: sea_state(c.scene) for c in sweep.cases}


def write_cases_csv(ds: xr.Dataset, sweep: Sweep, path: Path) -> None:
    """One row per case (a flat view of sweep.nc): keys, status, power, sea state, wall time, error."""
    import csv
    cols = ["label", *sweep.keys, "status", "mean_total_pto_power", "sea_state_height", "sea_state_period",
            "energy_flux", "capture_width", "capture_width_ratio", "wall_time", "attempts", "solver", "case_id",
            "case_name", "error"]
    with open(path, "w", newline="") as fh:
        w = csv.writer(fh)
        w.writerow(cols)
        coords = _coords(sweep)
        for case in sweep.cases:
            cell = ds.isel(dict(zip(coords, _cell(coords, case))))
            row = [case.label, *[case.coords[k] for k in sweep.keys]]
            for c in cols[len(sweep.keys) + 1:]:
                x = cell[c].values.item()
                row.append(f"{x:.6g}" if isinstance(x, float) else x)
            w.writerow(row)
