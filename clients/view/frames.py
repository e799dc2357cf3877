"""The scene ``hydrolink view`` draws, frame by frame: what is set up once (:class:`Stage`: meshes,
grid, wave fields, markers) and the frames it yields a block of rows at a time (:func:`frames`),
which the VTKHDF writer and the animation both consume."""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass, field
from pathlib import Path

import numpy as np

from hydrolink.clients.view.convolved import ConvolvedField
from hydrolink.clients.view.disturbed import DisturbedField, disturbed_field
from hydrolink.clients.view.markers import Marker, MooringLines, marker_points, mooring_lines, scene_markers
from hydrolink.clients.view.placement import BodyMesh, body_meshes, rigid_points, rigid_velocity
from hydrolink.clients.view.results import RunFile, ViewError, read_rows
from hydrolink.clients.view.surface import Grid, IncidentField, make_grid, run_waves
from hydrolink.server.sea.dispersion import wave_number
from hydrolink.server.terms.nonlinear.hull import rotation_xyz

PARTS = ("bodies", "surface", "moorings", "markers")
DEFAULT_CELLS = (100, 100)


#: how far from the origin a free-surface grid may reach, m
MAX_EXTENT = 1.0e6


@dataclass(frozen=True)
class ViewOptions:
    """What to draw: rows with ``start`` <= t <= ``end``, every ``stride``-th; the free-surface
    grid's ``extent`` (x0, x1, y0, y1; default around the bodies) and ``cells`` (nx, ny); the
    ``parts`` (of PARTS); ``block`` rows read from the file at a time."""
    start: float | None = None
    end: float | None = None
    stride: int = 1
    extent: tuple[float, float, float, float] | None = None
    cells: tuple[int, int] = DEFAULT_CELLS
    parts: tuple[str, ...] = PARTS
    block: int = 64

    def __post_init__(self) -> None:
        bad = [p for p in self.parts if p not in PARTS]
        if bad or not self.parts:
            raise ViewError("", "--parts", f"unknown part(s) {bad}: choose from {list(PARTS)}" if bad
                            else f"at least one of {list(PARTS)}")
        if self.extent is not None:
            x0, x1, y0, y1 = self.extent
            if not (all(abs(v) <= MAX_EXTENT for v in self.extent) and x0 < x1 and y0 < y1):   # also NaN
                raise ViewError("", "--grid-extent", f"{list(self.extent)}: x0 < x1 and y0 < y1, metres within "
                                f"±{MAX_EXTENT:g} of the origin")


@dataclass
class Stage:
    """Everything set up once for a run: ``notes`` say what is left out and why."""
    run: RunFile
    meshes: list[BodyMesh]
    forces: tuple[str, ...]
    grid: Grid | None = None
    incident: IncidentField | None = None
    disturbed: DisturbedField | ConvolvedField | None = None
    markers: list[Marker] = field(default_factory=list)
    gauges: IncidentField | None = None
    lines: MooringLines | None = None
    notes: list[str] = field(default_factory=list)


@dataclass(frozen=True)
class Frame:
    """One output time: per body (in ``Stage.meshes`` order) its moved vertices and their velocity,
    the body's (6,) per-term forces; the free surface's arrays; markers' and lines' points."""
    time: float
    bodies: list[tuple[np.ndarray, np.ndarray, dict[str, np.ndarray]]]
    surface: dict[str, np.ndarray] | None
    markers: np.ndarray | None
    lines: np.ndarray | None


def _default_extent(meshes: list[BodyMesh], markers: list[Marker], comps, gravity: float, depth: float):
    """The bodies' and markers' horizontal box, padded on every side by the larger of its size and
    the longest wave's half length (at least 5 m)."""
    pts = [m.vertices[:, :2] for m in meshes] + [np.array([mk.point[:2] for mk in markers]).reshape(-1, 2)]
    xy = np.concatenate(pts) if any(p.size for p in pts) else np.zeros((1, 2))
    lo, hi = xy.min(axis=0), xy.max(axis=0)
    wave = 0.0
    if comps is not None and comps.size:
        wave = float(np.pi / wave_number(float(comps.omega.min()), gravity, depth))
    pad = max(float((hi - lo).max()), wave, 5.0)
    return (float(lo[0] - pad), float(hi[0] + pad), float(lo[1] - pad), float(hi[1] + pad))


def make_stage(run: RunFile, options: ViewOptions) -> Stage:
    """Meshes, the grid and its wave fields, markers and lines of the parts asked for."""
    parts, water = set(options.parts), run.scene.water
    meshes, undrawn = body_meshes(run) if "bodies" in parts or "surface" in parts else ([], [])
    forces = tuple(n for n in run.body_series if n not in ("position", "velocity"))
    stage = Stage(run, meshes if "bodies" in parts else [], forces)
    markers, left = scene_markers(run) if "markers" in parts else ([], [])
    stage.markers, stage.notes = markers, (undrawn if "bodies" in parts else []) + left
    comps = run_waves(run) if "surface" in parts or any(m.kind == "wave_gauge" for m in markers) else None
    if "surface" in parts and comps is None:
        stage.notes.append("surface: the waves are an elevation series at the origin (waves.type = \"elevation\"): "
                           "no field to draw")
    elif "surface" in parts:
        default_grid = (options.extent, options.cells) == (None, DEFAULT_CELLS)
        stage.disturbed, stored, note = disturbed_field(run, comps, wanted=default_grid)
        stage.notes += [note] if note else []
        if stored is not None and default_grid:
            stage.grid = stored                      # the build's grid, where its waves are known
        else:
            if stored is not None:
                stage.notes.append("radiated/diffracted waves: known on the HDB build's [free_surface] grid only; "
                                   "leave --grid-extent and --grid-cells unset to draw them")
            extent = options.extent or _default_extent(meshes, markers, comps, water.gravity, water.depth_m)
            stage.grid = make_grid(extent, options.cells, comps.size)
        stage.incident = IncidentField(comps, stage.grid.points, water.gravity, water.depth_m)
    gauges = [m.point for m in markers if m.kind == "wave_gauge"]
    if gauges and comps is not None:
        stage.gauges = IncidentField(comps, np.array(gauges), water.gravity, water.depth_m)
    if "moorings" in parts:
        stage.lines = mooring_lines(run)
    return stage


def frames(stage: Stage, rows: np.ndarray, block: int = 64) -> Iterator[Frame]:
    """The frames at ``rows`` of the results file, read ``block`` rows at a time."""
    run = stage.run
    names = ["position", "velocity", *stage.forces] + (["line_node_position"] if stage.lines else [])
    modal = any(m.shapes is not None for m in stage.meshes)
    names += ["modal_position", "modal_velocity"] if modal else []
    for b0 in range(0, rows.size, max(1, block)):
        chunk = rows[b0:b0 + block]
        data = read_rows(run.path, names, chunk)
        if stage.disturbed is not None:
            stage.disturbed.prepare(run, chunk)
        for k, row in enumerate(chunk):
            t = float(run.time[row])
            pos, vel = data["position"][k], data["velocity"][k]
            bodies = []
            for m in stage.meshes:
                if m.shapes is None:
                    moved = rigid_points(m.vertices, m.reference, pos[m.row])
                    velocity = rigid_velocity(moved, pos[m.row], vel[m.row])
                else:     # deformed in the body's axes, then moved: x = p + R (v - r + sum q phi)
                    moved = rigid_points(m.vertices + m.shapes.displacement(data["modal_position"][k]), m.reference,
                                         pos[m.row])
                    velocity = (rigid_velocity(moved, pos[m.row], vel[m.row])
                                + m.shapes.displacement(data["modal_velocity"][k]) @ rotation_xyz(pos[m.row, 3:]).T)
                bodies.append((moved, velocity, {f: data[f][k, m.row] for f in stage.forces}))
            surface = None
            if stage.grid is not None:
                incident = stage.incident(t)
                surface = {"incident": incident}
                total = incident
                if stage.disturbed is not None:
                    surface.update(stage.disturbed.at(k, t))
                    total = incident + surface["radiated"] + surface["diffracted"]
                surface["elevation"] = total
            markers = (marker_points(stage.markers, run, pos, stage.gauges(t) if stage.gauges else None)
                       if stage.markers else None)
            lines = data["line_node_position"][k][stage.lines.index] if stage.lines else None
            yield Frame(t, bodies, surface, markers, lines)
