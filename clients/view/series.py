"""``hydrolink view``'s ParaView series: one transient VTKHDF file per part in the output folder
(``<body>.vtkhdf`` per body, ``free_surface.vtkhdf``, ``markers.vtkhdf``, ``moorings.vtkhdf``),
written frame by frame with a progress bar (memory: one block of rows and one frame)."""

from __future__ import annotations

import time as _time
from contextlib import ExitStack
from dataclasses import dataclass
from pathlib import Path

import numpy as np

from hydrolink.clients.lockstep.driver import progress_bar
from hydrolink.clients.view.frames import Stage, ViewOptions, frames, make_stage
from hydrolink.clients.view.markers import KINDS, VTK_VERTEX
from hydrolink.clients.view.results import RunFile, frame_rows, open_run
from hydrolink.clients.view.vtkhdf import TransientGrid


@dataclass(frozen=True)
class ViewSummary:
    """What was written: the files, the frames, the seconds it took, and what was left out."""
    folder: Path
    files: tuple[Path, ...]
    frames: int
    seconds: float
    notes: tuple[str, ...]


def _writers(stage: Stage, folder: Path, stack: ExitStack) -> dict[str, TransientGrid]:
    out = {}
    for m in stage.meshes:
        out[m.name] = stack.enter_context(TransientGrid(
            folder / f"{m.name}.vtkhdf", m.connectivity, m.offsets, m.types, len(m.vertices),
            {"velocity": 3}, {}, {f: 6 for f in stage.forces}))
    if stage.grid is not None:
        arrays = {"elevation": 1, "incident": 1} | ({"radiated": 1, "diffracted": 1} if stage.disturbed else {})
        out["free_surface"] = stack.enter_context(TransientGrid(
            folder / "free_surface.vtkhdf", *stage.grid.cells(), stage.grid.x.size * stage.grid.y.size, arrays, {}))
    if stage.markers:
        n = len(stage.markers)
        out["markers"] = stack.enter_context(TransientGrid(
            folder / "markers.vtkhdf", np.arange(n), np.arange(n + 1), np.full(n, VTK_VERTEX, np.uint8), n,
            {"kind": 1}, {}))
    if stage.lines is not None:
        ln = stage.lines
        out["moorings"] = stack.enter_context(TransientGrid(
            folder / "moorings.vtkhdf", ln.connectivity, ln.offsets, ln.types, ln.n_points, {}, {}))
    return out


def write_series(stage: Stage, rows: np.ndarray, folder: Path, *, block: int = 64,
                 progress: bool = True) -> tuple[list[Path], int]:
    """Every part's file over the frames at ``rows``; returns the files and the frame count."""
    folder.mkdir(parents=True, exist_ok=True)
    kinds = np.array([KINDS.index(m.kind) for m in stage.markers], float)
    with ExitStack() as stack:
        writers = _writers(stage, folder, stack)
        bar = stack.enter_context(progress_bar(rows.size, progress, desc="hydrolink view"))
        n = 0
        for frame in frames(stage, rows, block):
            for m, (pts, vel, forces) in zip(stage.meshes, frame.bodies):
                writers[m.name].append(frame.time, pts, {"velocity": vel}, {}, forces)
            if frame.surface is not None:
                pts = stage.grid.points
                pts[:, 2] = frame.surface["elevation"]
                writers["free_surface"].append(frame.time, pts, frame.surface, {})
            if frame.markers is not None:
                writers["markers"].append(frame.time, frame.markers, {"kind": kinds}, {})
            if frame.lines is not None:
                writers["moorings"].append(frame.time, frame.lines, {}, {})
            n += 1
            bar.update(1)
        return [w.path for w in writers.values()], n


def view_results(results: str | Path, folder: str | Path, options: ViewOptions = ViewOptions(), *,
                 scene_dir: str | Path | None = None, progress: bool = True) -> tuple[ViewSummary, Stage, np.ndarray]:
    """Open a results file, set its stage up and write its series into ``folder``; returns the
    summary, the stage and the rows written (for an animation of the same scene)."""
    t0 = _time.perf_counter()
    run: RunFile = open_run(results, scene_dir)
    rows = frame_rows(run.time, options.start, options.end, options.stride)
    stage = make_stage(run, options)
    files, n = write_series(stage, rows, Path(folder), block=options.block, progress=progress)
    return ViewSummary(Path(folder), tuple(files), n, _time.perf_counter() - t0, tuple(stage.notes)), stage, rows
