"""The loads along the bodies that ask for them (``bodies[i].sections``), added to a run's results
file after its last row (server/loads/sections.py; docs/generalized-modes.md "Loads along a body"),
and the panel pressures of those with ``pressure_output`` in a file of their own beside it
(``<results>.pressures.nc``: server/loads/pressures.py; dims time, panel, xyz; center, normal, area,
panel_body, still_pressure (panel), pressure (time, panel): the dynamic part, Pa).

Variables (dims ``section``: every station of every such body in scene order, ``axis3``: x, y, z of
the body's axes)::

    section_force, section_moment             (time, section, axis3)  N, N m: the rest of the body's load
                                                                     on the part beyond the station
    section_still_force, section_still_moment (section, axis3)        their still-water part (included above)
    section_station (section) m, section_body (section)
"""

from __future__ import annotations

import json
from dataclasses import dataclass
from pathlib import Path
from typing import Mapping

import netCDF4
import numpy as np
import xarray as xr

from hydrolink.protocol.scene import Body, Scene, resolve_path
from hydrolink.server.errors import ModelError
from hydrolink.server.hdb.build.panels import PanelFileError, PanelPressures, read_panel_pressures
from hydrolink.server.loads.sections import AXES, SectionCuts, section_cuts, section_loads
from hydrolink.server.loads.pressures import panel_series, still_pressure
from hydrolink.server.loads.water import recorded_motion
from hydrolink.server.sea.seastate import run_components
from hydrolink.server.sea.waves import WaveComponents, WaveError

ATTACHED = ("joints", "ptos", "moorings", "morison")
RESIDUAL_WARNING = 0.05   # the whole free body's load (rms) against the largest along it: warned about beyond
BODY_FORCES = ("linear_damping", "quadratic_damping", "drag", "nonlinear")


def panel_set(scene: Scene, i: int, scene_path: str | Path, hdb: xr.Dataset | None) -> PanelPressures:
    """Body ``i``'s panel set: its ``panel_pressures`` file, else the one its HDB build names;
    ModelError naming ``bodies[i].sections`` (or ``.pressure_output``) when there is none or it is
    another body's."""
    body = scene.bodies[i]
    key = f"bodies[{i}]." + ("sections" if body.sections is not None else "pressure_output")
    given = body.panel_pressures
    named = hdb.attrs.get("panel_pressure_file") if hdb is not None else None
    if given is None and named is None:
        raise ModelError(key, f"the HDB {body.hdb} carries no per-panel pressures (the force distribution along "
                              "the body is not known from a WAMIT, BEMIO, NEMOH or Capytaine file): build it with "
                              f"`hydrolink hdb build` and `panel_pressures = true`, or give bodies[{i}].panel_pressures")
    path = resolve_path(scene_path, given) if given is not None else Path(named)
    try:
        ps = read_panel_pressures(path)
    except PanelFileError as exc:
        raise ModelError(f"bodies[{i}].panel_pressures" if given else key, str(exc)) from None
    if ps.body != body.hdb_body_name or len(ps.dofs) != 6:
        raise ModelError(f"bodies[{i}].panel_pressures" if given else key,
                         f"{path}: the panel set of body {ps.body!r} over {len(ps.dofs)} DOFs, not of "
                         f"{body.hdb_body_name!r} over its six rigid DOFs")
    return ps


def run_waves(scene: Scene, hdbs: Mapping[str, xr.Dataset]) -> WaveComponents:
    """The wave components the model used: the scene's sea over the HDBs' common frequency range,
    Doppler-shifted as the model does (server/model.py); ModelError naming ``waves.type`` or
    ``waves.excitation`` for a sea the loads are not built for."""
    waves = scene.waves
    kind = getattr(waves, "type", "")
    if kind in ("elevation", "gauges"):
        raise ModelError("waves.type", f"the loads along a body are built for wave components, not a {kind!r} sea "
                                       "(its excitation is not a sum of components)")
    if getattr(waves, "excitation", "superposition") == "convolution":
        raise ModelError("waves.excitation", "the loads along a body sum the components (\"superposition\"), "
                                             "not an excitation by convolution")
    lo = max(float(hdbs[b.hdb]["omega"].values[0]) for b in scene.bodies if b.hdb is not None)
    hi = min(float(hdbs[b.hdb]["omega"].values[-1]) for b in scene.bodies if b.hdb is not None)
    try:
        return run_components(waves, scene, lo, hi)
    except WaveError as exc:
        raise ModelError(exc.key, exc.why) from None


def unmodelled(scene: Scene, i: int, body: Body) -> str | None:
    """A warning naming ``bodies[i].sections`` when loads other than the water's, the weight and the
    inertia act on the body (not distributed along it), else None."""
    found = [f"{kind}[{j}]" for kind in ATTACHED for j, item in enumerate(getattr(scene, kind))
             if body.name in {getattr(item, k, None) for k in ("body", "body1", "body2")}]
    found += [f"bodies[{i}].{k}" for k in BODY_FORCES if getattr(body, k) not in (None, False, "none")]
    if len(body.dofs) < 6:
        found.append(f"bodies[{i}].dofs (locked: its constraint loads)")
    if not found:
        return None
    return (f"bodies[{i}].sections: {', '.join(found)} act on {body.name!r} and are not distributed along it: the "
            "loads along the body hold the water's, the weight's and the inertia's; the near end carries theirs")


@dataclass(frozen=True)
class SectionPlan:
    """What the loads along the bodies need, made and checked before the run (a bad key is refused
    before any step): each asking body's index, panel set and cut rows; the run's waves; the warnings."""
    # each body: its index, panel set, cut rows (None: no sections; a free body's first station is the
    # hull's start, the whole body's check, computed with the others and not written) and whether it has it
    bodies: tuple[tuple[int, PanelPressures, SectionCuts | None, bool], ...]
    waves: WaveComponents
    warnings: tuple[str, ...]


def plan_sections(scene: Scene, scene_path: str | Path, hdbs: Mapping[str, xr.Dataset]) -> SectionPlan | None:
    """The plan of the bodies with ``sections`` (None: no body asks); ModelError naming the key of
    what cannot be computed."""
    asked = [i for i, b in enumerate(scene.bodies) if b.sections is not None or b.pressure_output]
    if not asked:
        return None
    waves = run_waves(scene, hdbs)
    warnings, bodies = [], []
    for i in asked:
        body = scene.bodies[i]
        ps = panel_set(scene, i, scene_path, hdbs.get(body.hdb))
        w = waves.hdb_omega
        if w.size and (w.min() < ps.omega[0] * (1 - 1e-9) or w.max() > ps.omega[-1] * (1 + 1e-9)):
            raise ModelError(f"bodies[{i}].panel_pressures" if body.panel_pressures else f"bodies[{i}].hdb",
                             f"{ps.source}: the panel pressures span {ps.omega[0]:.4g}..{ps.omega[-1]:.4g} rad/s, the "
                             f"waves {w.min():.4g}..{w.max():.4g} rad/s: a panel set of the HDB's frequencies is needed")
        if body.sections is None:
            bodies.append((i, ps, None, False))
            continue
        others = unmodelled(scene, i, body)
        # a free body's whole load must vanish: the run checks itself at the hull's start (not written)
        start = float(ps.center[:, AXES[body.sections.axis]].min())
        asked = body.sections if others else body.sections.model_copy(update={"stations": [start, *body.sections.stations]})
        cuts, notes = section_cuts(ps, asked, body, f"bodies[{i}].sections", scene.water.density, scene.water.gravity)
        warnings += notes + [w for w in (others,) if w]   # (the panel pressures have no such limit)
        bodies.append((i, ps, cuts, not others))
    return SectionPlan(tuple(bodies), waves, tuple(warnings))


def add_section_loads(output: str | Path, plan: SectionPlan, scene: Scene) -> None:
    """The loads of the plan's bodies from the results file ``output``, added to it (module
    docstring) with the plan's warnings."""
    with xr.open_dataset(output, engine="netcdf4") as raw:
        names = [str(b) for b in raw["body"].values]
        rows = {v: np.asarray(raw[v].values, float) for v in ("time", "position", "velocity", "equilibrium_position")}
    parts, warnings, panels = [], list(plan.warnings), []
    for i, ps, cuts, checked in plan.bodies:
        k = names.index(scene.bodies[i].name)
        motion = recorded_motion(rows["time"], rows["position"][:, k], rows["velocity"][:, k],
                                 rows["equilibrium_position"][k])
        if scene.bodies[i].pressure_output:
            panels.append((scene.bodies[i].name, ps, panel_series(ps, motion, scene, plan.waves, scene.bodies[i].name,
                                                                  f"bodies[{i}].pressure_output")))
        if cuts is None:
            continue
        loads = section_loads(cuts, ps, motion, scene, plan.waves)
        if checked:
            warnings += self_check(i, loads[:, 1:] - cuts.still[1:], loads[:, 0] - cuts.still[0])
            cuts, loads = cuts.after_first(), loads[:, 1:]
        parts.append((cuts, loads))
    if parts:
        _write(output, parts, warnings)
    if panels:
        write_pressures(pressure_file(output), rows["time"], panels, scene)


def pressure_file(output: str | Path) -> Path:
    """The panel pressures' file beside the results ``output``."""
    return Path(output).with_suffix(".pressures.nc")


def write_pressures(path: Path, time: np.ndarray, panels: list, scene: Scene) -> None:
    """The panel pressures (module docstring) of each (body, panel set, (T, P) series)."""
    ds = xr.Dataset(
        {"center": (("panel", "xyz"), np.concatenate([ps.center for _, ps, _ in panels])),
         "normal": (("panel", "xyz"), np.concatenate([ps.normal for _, ps, _ in panels])),
         "area": (("panel",), np.concatenate([ps.area for _, ps, _ in panels])),
         "panel_body": (("panel",), np.concatenate([[name] * ps.panels for name, ps, _ in panels])),
         "still_pressure": (("panel",), np.concatenate([still_pressure(ps, scene.water.density, scene.water.gravity)
                                                        for _, ps, _ in panels])),
         "pressure": (("time", "panel"), np.concatenate([p for _, _, p in panels], axis=1))},
        coords={"time": time, "xyz": ["x", "y", "z"]},
        attrs={"title": "hydrolink panel pressures", "frame": "the body's axes (the global frame at rest); normals "
               "out of the body", "pressure": "the linear dynamic pressure at each panel's centre (Pa): hydrostatic "
               "change, incident + diffracted, radiated; the still part in still_pressure"})
    ds["pressure"].attrs["units"] = ds["still_pressure"].attrs["units"] = "Pa"
    ds.to_netcdf(path, engine="netcdf4")


def self_check(i: int, along: np.ndarray, whole: np.ndarray) -> list[str]:
    """A warning naming ``simulation.dt`` when the whole free body's load (T, 6), which must vanish, is
    over RESIDUAL_WARNING of the largest (rms) along it ``along`` (T, S, 6): the loads are differences of
    terms many times larger, and their error is the run's (second order in dt)."""
    rms_along = np.sqrt((along ** 2).mean(axis=0)).max(axis=0)
    ratio = np.sqrt((whole ** 2).mean(axis=0)) / np.maximum(rms_along, 1e-300)
    if not ratio.max() > RESIDUAL_WARNING:
        return []
    names = ("x force", "y force", "z force", "x moment", "y moment", "z moment")
    return [f"simulation.dt: bodies[{i}].sections: the whole free body's load, which must vanish, is "
            f"{100 * ratio.max():.3g} % of the largest {names[int(ratio.argmax())]} along it (rms): the loads are "
            "small differences of the inertia's and the water's; a smaller dt (their error goes as dt^2)"]


def _write(output: str | Path, parts: list, warnings: list[str]) -> None:
    """The loads' variables into the results file (module docstring), the warnings to its list."""
    with netCDF4.Dataset(output, "a") as ds:
        count = sum(c.stations.size for c, _ in parts)
        ds.createDimension("section", count)
        ds.createDimension("axis3", 3)
        ax = ds.createVariable("axis3", str, ("axis3",))
        for j, a in enumerate("xyz"):
            ax[j] = a
        body = ds.createVariable("section_body", str, ("section",))
        station = ds.createVariable("section_station", "f8", ("section",))
        station.units, station.long_name = "m", "the station along the body's axis (global frame at rest)"
        station.axis_of_body = json.dumps({c.body: "xyz"[c.axis] for c, _ in parts})
        loads = np.concatenate([values for _, values in parts], axis=1)          # (T, section, 6)
        still = np.concatenate([c.still for c, _ in parts], axis=0)
        at = 0
        for c, _ in parts:
            for s in c.stations:
                body[at], station[at] = c.body, float(s)
                at += 1
        what = "the load the rest of the body exerts on the part beyond the station, body axes"
        for name, units, cols in (("force", "N", slice(0, 3)), ("moment", "N m", slice(3, 6))):
            v = ds.createVariable(f"section_{name}", "f8", ("time", "section", "axis3"))
            v.units, v.long_name = units, f"{name} at the station: {what}" + (", about the station" if name == "moment" else "")
            v[:] = loads[:, :, cols]
            s = ds.createVariable(f"section_still_{name}", "f8", ("section", "axis3"))
            s.units, s.long_name = units, f"the still-water part of section_{name}"
            s[:] = still[:, cols]
        if warnings:
            ds.setncattr("warnings", json.dumps(json.loads(ds.getncattr("warnings")) + warnings))
