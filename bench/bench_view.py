"""``hydrolink view`` on RM3: file sizes and write time per frame, against the floor (computing the
frames without writing them) and, where the ``vtk`` package is installed, the alternative of one
``.vtu`` file per frame written by VTK's own XML writer (what a ``.pvd`` collection would list).

    python bench/bench_view.py                      # runs examples/rm3/rm3.toml first (about a minute)
    python bench/bench_view.py --results rm3.nc     # a results file of it
    python bench/bench_view.py --long 9n9la.nc      # a long run (9N9LA, 3,600 s at dt 0.05): every row's
                                                    # bodies and markers, then the surface at a stride,
                                                    # with the resident memory sampled as the frames go

    python bench/bench_view.py --long 9n9la.nc --synthesize   # first write that file: 9N9LA's scene,
                                                    # 3,600 s at dt 0.05 (72,000 rows), its nine bodies
                                                    # moving by a sum of sinusoids, its sea's elevation

A real long run instead: ``python bench/bench_9n9la_long.py --duration 3600 -o 9n9la.nc`` with
``dt = 0.05`` in its scene (about 20 minutes on a quiet machine; the view's cost depends on the sizes,
not on the motion's values).

Prints a Markdown table with the machine's load (``os.getloadavg``): the figures are wall times.
"""

from __future__ import annotations

import argparse
import os
import resource
import tempfile
import time
from pathlib import Path

import numpy as np

from hydrolink.clients.view.frames import ViewOptions, frames, make_stage
from hydrolink.clients.view.results import frame_rows, open_run
from hydrolink.clients.view.series import write_series

REPO = Path(__file__).resolve().parents[1]
SCENE = REPO / "examples" / "rm3" / "rm3.toml"


def _size(files) -> int:
    return sum(Path(f).stat().st_size for f in files)


def floor(stage, rows) -> float:
    """Seconds to compute the frames (read rows, move meshes, waves) without writing them."""
    t0 = time.perf_counter()
    for _ in frames(stage, rows):
        pass
    return time.perf_counter() - t0


def vtu_per_frame(stage, rows, folder: Path) -> tuple[float, int]:
    """Seconds and bytes of one binary .vtu per frame and part (VTK's XML writer)."""
    import vtk
    from vtk.util.numpy_support import numpy_to_vtk, numpy_to_vtkIdTypeArray

    def grid(conn, offsets, types):
        cells = vtk.vtkCellArray()
        cells.SetData(numpy_to_vtkIdTypeArray(np.asarray(offsets, np.int64), deep=True),
                      numpy_to_vtkIdTypeArray(np.asarray(conn, np.int64), deep=True))
        g = vtk.vtkUnstructuredGrid()
        g.SetCells(numpy_to_vtk(np.asarray(types, np.uint8), deep=True, array_type=vtk.VTK_UNSIGNED_CHAR), cells)
        return g
    grids = [grid(m.connectivity, m.offsets, m.types) for m in stage.meshes]
    if stage.grid is not None:
        grids.append(grid(*stage.grid.cells()))
    writer = vtk.vtkXMLUnstructuredGridWriter()
    writer.SetDataModeToAppended()
    written = []
    t0 = time.perf_counter()
    for k, frame in enumerate(frames(stage, rows)):
        parts = [(p, {"velocity": v}) for p, v, _ in frame.bodies]
        if frame.surface is not None:
            pts = stage.grid.points
            pts[:, 2] = frame.surface["elevation"]
            parts.append((pts, frame.surface))
        for j, (g, (pts, arrays)) in enumerate(zip(grids, parts)):
            points = vtk.vtkPoints()
            points.SetData(numpy_to_vtk(np.ascontiguousarray(pts), deep=True))
            g.SetPoints(points)
            for name, a in arrays.items():
                arr = numpy_to_vtk(np.ascontiguousarray(a), deep=True)
                arr.SetName(name)
                g.GetPointData().AddArray(arr)
            path = folder / f"part{j}_{k:06d}.vtu"
            writer.SetFileName(str(path))
            writer.SetInputData(g)
            writer.Write()
            written.append(path)
    return time.perf_counter() - t0, _size(written)


def _rss_mib() -> float:
    """The process's resident memory now (MiB)."""
    with open("/proc/self/statm") as f:
        return int(f.read().split()[1]) * os.sysconf("SC_PAGE_SIZE") / 2**20


NINE = REPO / "examples" / "node_9n9la" / "node_9n9la.toml"


def synthesize_9n9la(path: Path, duration: float = 3600.0, dt: float = 0.05) -> None:
    """A results file of 9N9LA's scene: its wet bodies about their centres of mass moving by a sum of
    three sinusoids per DOF (0.05 m, 0.05 rad), the sea's own elevation at the origin."""
    import re

    from hydrolink.clients.lockstep.results import ResultWriter
    from hydrolink.protocol.scene import parse_scene
    from hydrolink.server.sea.seastate import sea_components
    from hydrolink.server.sea.waves import elevation

    text = re.sub(r"(?m)^dt = .*$", f"dt = {dt!r}", re.sub(r"(?m)^duration = .*$", f"duration = {duration!r}",
                                                            NINE.read_text(), count=1), count=1)
    scene = parse_scene(text, NINE)
    wet = [b for b in scene.bodies if b.wet]
    eq = np.array([[*b.center_of_mass, 0.0, 0.0, 0.0] for b in wet])
    t = np.arange(0.0, duration + dt / 2, dt)
    comps = sea_components(scene.waves, *scene.waves.omega_range)
    w = np.array([0.9, 1.7, 4.5])
    rng = np.random.default_rng(0)
    c = 0.05 / 3 * np.exp(2j * np.pi * rng.random((3, len(wet), 6)))
    with ResultWriter(path, scene_text=text, bodies=[b.name for b in wet], equilibrium_position=eq, dt=dt) as out:
        zero = np.zeros((len(wet), 6))
        for a in range(0, t.size, 4096):
            tt = t[a:a + 4096]
            e = np.exp(-1j * np.outer(tt, w))                          # (n, 3)
            pos = eq[None] + np.real(np.einsum("nk,kbd->nbd", e, c))
            vel = np.real(np.einsum("nk,kbd->nbd", e * (-1j * w), c))
            eta = elevation(comps, tt)
            for k in range(tt.size):
                out.append(float(tt[k]), pos[k], vel[k], zero, zero, zero, float(eta[k]))


def long_run(results: Path, scene_dir: Path | None, stride: int, surface_stride: int, cells: int) -> None:
    """Every ``stride``-th row's bodies and markers, then the surface every ``surface_stride``-th row on a
    ``cells`` x ``cells`` grid: time per frame, bytes, and the resident memory sampled every 0.5 s
    (its first, middle and last quarter: flat when the memory is bounded)."""
    import threading

    from hydrolink.clients.view.series import view_results

    run = open_run(results, scene_dir)
    print(f"{results.name}: {run.time.size} rows, {len(run.bodies)} bodies, {run.time[-1]:g} s; load "
          f"{os.getloadavg()[0]:.2f} (1 min), {os.cpu_count()} CPUs\n")
    print("| parts | frames | s | ms/frame | MB written | RSS MiB at 10 / 50 / 100 % of the frames |")
    print("|---|---|---|---|---|---|")
    for parts, stride, grid in ((("bodies", "markers"), stride, None), (("surface",), surface_stride, (cells, cells))):
        samples, done = [], threading.Event()

        def sample() -> None:
            while not done.wait(0.5):
                samples.append(_rss_mib())
        with tempfile.TemporaryDirectory() as tmp:
            sampler = threading.Thread(target=sample, daemon=True)
            sampler.start()
            options = ViewOptions(stride=stride, parts=parts, **({"cells": grid} if grid else {}))
            summary, _, _ = view_results(results, Path(tmp), options, scene_dir=scene_dir, progress=False)
            done.set()
            sampler.join()
            size = _size(summary.files)
        at = [samples[min(len(samples) - 1, int(q * len(samples)))] for q in (0.1, 0.5, 0.999)] if samples else []
        print(f"| {'+'.join(parts)}{f' {grid[0]} x {grid[1]}' if grid else ''} (stride {stride}) | {summary.frames} | "
              f"{summary.seconds:.0f} | {1e3 * summary.seconds / summary.frames:.2f} | {size / 1e6:.0f} | "
              + " / ".join(f"{r:.0f}" for r in at) + " |")
    print(f"\npeak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB; load "
          f"{os.getloadavg()[0]:.2f} at the end")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--results", type=Path, help="an RM3 results file (default: run examples/rm3/rm3.toml)")
    ap.add_argument("--frames", type=int, default=200, help="frames written (every stride-th row)")
    ap.add_argument("--long", type=Path, help="a long results file: every row (bodies, markers), the surface at a stride")
    ap.add_argument("--scene-dir", type=Path, help="the long run's scene folder (default: the file's)")
    ap.add_argument("--stride", type=int, default=1, help="the long run's bodies and markers: every N-th row")
    ap.add_argument("--surface-stride", type=int, default=20, help="the long run's surface: every N-th row")
    ap.add_argument("--cells", type=int, default=50, help="the long run's surface grid: N x N cells")
    ap.add_argument("--synthesize", action="store_true", help="write --long's file first (9N9LA's scene, 3,600 s)")
    args = ap.parse_args()
    if args.long and args.synthesize:
        t0 = time.perf_counter()
        synthesize_9n9la(args.long)
        print(f"wrote {args.long} in {time.perf_counter() - t0:.0f} s ({args.long.stat().st_size / 1e6:.0f} MB)")
    if args.long:
        scene_dir = args.scene_dir or (NINE.parent if args.synthesize else None)
        long_run(args.long, scene_dir, args.stride, args.surface_stride, args.cells)
        return
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        results = args.results
        if results is None:
            from hydrolink.clients.run import run_scene_file
            results = tmp / "rm3.nc"
            run_scene_file(SCENE, results, progress=False)
        run = open_run(results, SCENE.parent)
        stride = max(1, run.time.size // args.frames)
        rows = frame_rows(run.time, None, None, stride)[:args.frames]
        print(f"RM3 {results.name}: {run.time.size} rows, {rows.size} frames (stride {stride}); load "
              f"{os.getloadavg()[0]:.2f} (1 min), {os.cpu_count()} CPUs\n")
        print("| parts | points/frame | floor ms/frame | VTKHDF ms/frame | VTKHDF kB/frame | .vtu ms/frame | .vtu kB/frame |")
        print("|---|---|---|---|---|---|---|")
        for parts in (("bodies",), ("surface",), ("bodies", "surface", "markers")):
            stage = make_stage(run, ViewOptions(parts=parts))
            n_points = sum(len(m.vertices) for m in stage.meshes) + (stage.grid.points.shape[0] if stage.grid else 0)
            base = floor(stage, rows)
            out = tmp / ("_".join(parts))
            t0 = time.perf_counter()
            files, n = write_series(stage, rows, out, progress=False)
            hdf = time.perf_counter() - t0
            cells = [f"{n_points}", f"{1e3 * base / n:.2f}", f"{1e3 * hdf / n:.2f}", f"{_size(files) / n / 1e3:.1f}"]
            try:
                vt_folder = tmp / ("vtu_" + "_".join(parts))
                vt_folder.mkdir()
                vt, vb = vtu_per_frame(stage, rows, vt_folder)
                cells += [f"{1e3 * vt / n:.2f}", f"{vb / n / 1e3:.1f}"]
            except ImportError:
                cells += ["(no vtk)", ""]
            print(f"| {'+'.join(parts)} | " + " | ".join(cells) + " |")
        print(f"\npeak RSS {resource.getrusage(resource.RUSAGE_SELF).ru_maxrss / 1024:.0f} MiB; load "
              f"{os.getloadavg()[0]:.2f} at the end")


if __name__ == "__main__":
    main()
