"""The results file ``hydrolink view`` reads: its scene, bodies, times and rows, read a block of
output frames at a time (bounded memory whatever the run's length)."""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import netCDF4
import numpy as np

from hydrolink.protocol.errors import KeyedError
from hydrolink.protocol.scene import Scene, SceneError, parse_scene


class ViewError(KeyedError):
    """An input of ``hydrolink view`` that cannot be shown: the file or option at fault and why."""


@dataclass(frozen=True)
class RunFile:
    """A results file of ``hydrolink run`` / ``steady`` (or a sweep's case file): its scene (from
    its ``scene`` attribute), the folder its scene's relative paths start from, its bodies (the
    ``body`` dimension), times and the equilibrium positions (B, 6)."""
    path: Path
    scene: Scene
    scene_dir: Path
    bodies: tuple[str, ...]
    time: np.ndarray
    equilibrium: np.ndarray
    variables: frozenset[str]
    body_series: tuple[str, ...]     # the (time, body, dof) variables: position, velocity, the forces
    steady: bool = False             # a `hydrolink steady` file: one period of the steady state (no ramp)

    @property
    def scene_path(self) -> Path:
        """Where the scene's relative paths start from (a file name in ``scene_dir``)."""
        return self.scene_dir / "scene.toml"


def open_run(path: str | Path, scene_dir: str | Path | None = None) -> RunFile:
    """Read a results file's header; ViewError naming the file when it has no ``position``
    (a sweep's ``sweep.nc``: view its case files) or no scene."""
    path = Path(path)
    if not path.is_file():
        raise ViewError(path, "", "file not found")
    try:
        ds = netCDF4.Dataset(path, "r")
    except OSError as exc:
        raise ViewError(path, "", f"not a NetCDF results file: {exc}") from None
    with ds:
        names = frozenset(ds.variables)
        if "position" not in names or "time" not in names:
            hint = (" (a sweep's summary: view one of its case files, OUTDIR/cases/<name>.nc)"
                    if "sweep_file" in ds.ncattrs() else "")
            raise ViewError(path, "position", "the file has no body positions over time: not a results "
                            f"file of hydrolink run or steady{hint}")
        if "scene" not in ds.ncattrs() or not ds.getncattr("scene"):
            raise ViewError(path, "scene", "the file has no scene attribute: the bodies cannot be placed")
        base = Path(scene_dir) if scene_dir is not None else path.resolve().parent
        try:
            scene = parse_scene(ds.getncattr("scene"), base / "scene.toml")
        except SceneError as exc:
            raise ViewError(path, "scene", f"its scene does not parse: {exc}") from None
        time = np.asarray(ds["time"][:], float)
        if time.size == 0:
            raise ViewError(path, "time", "the file holds no rows")
        series = tuple(n for n, v in ds.variables.items() if v.dimensions == ("time", "body", "dof"))
        return RunFile(path, scene, base, tuple(str(b) for b in ds["body"][:]), time,
                       np.asarray(ds["equilibrium_position"][:], float), names, series,
                       "steady_period" in ds.ncattrs())


def frame_rows(time: np.ndarray, start: float | None, end: float | None, stride: int) -> np.ndarray:
    """The row indices shown: every ``stride``-th row with ``start`` <= t <= ``end``."""
    if stride < 1:
        raise ViewError("", "--stride", f"must be at least 1, got {stride}")
    lo = -np.inf if start is None else start
    hi = np.inf if end is None else end
    rows = np.flatnonzero((time >= lo - 1e-12) & (time <= hi + 1e-12))[::stride]
    if rows.size == 0:
        raise ViewError("", "--start/--end", f"no row of the file lies in [{lo:g}, {hi:g}] s (it holds "
                                             f"{time[0]:g}-{time[-1]:g} s)")
    return rows


def read_rows(path: Path, names: list[str], rows: np.ndarray) -> dict[str, np.ndarray]:
    """The variables ``names`` at the given rows (a block of frames): one contiguous read per
    variable of the rows' span, then the rows picked (a strided span costs its stride in reads)."""
    lo, hi = int(rows[0]), int(rows[-1]) + 1
    with netCDF4.Dataset(path, "r") as ds:
        ds.set_auto_mask(False)
        return {n: np.asarray(ds[n][lo:hi], float)[rows - lo] for n in names}
