"""Progressive NetCDF results file of a run (NETCDF4, unlimited ``time``).

Rows are buffered in memory and written + synced together every ``flush_seconds`` of wall time or
``flush_rows`` rows, so the file is only touched during a flush: a run killed part way (even with
SIGKILL) leaves a readable file holding every row up to the last flush. The global ``status``
attribute says "running", then "complete" or "interrupted: <why>". To look at a file while its
run is still going, read it with ``HDF5_USE_FILE_LOCKING=FALSE`` set (HDF5 locks files open for
writing); a killed run's file opens normally.

Layout (readable with ``xarray.open_dataset``)::

    dims   time (unlimited), body, dof (surge, sway, heave, roll, pitch, yaw)
    vars   position, velocity, excitation_force, radiation_force, hydrostatic_force  (time, body, dof)
           wave_elevation (time), equilibrium_position (body, dof)
    extra  variables declared by the client with :meth:`ResultWriter.add_variable`, dims
           (time, *their dims): joint outputs over ``joint``; ``pto_force``, ``pto_velocity``,
           ``pto_power`` over ``pto`` and ``total_pto_power``; ``mooring_force`` over
           (``mooring``, ``mooring_component``); MoorDyn: ``line_tension`` (its own fairlead tension)
           and ``line_end_force`` over ``line`` and
           ``line_node_position`` over (``line``, ``node``, ``xyz``); attribute ``moordyn`` (JSON:
           files, initial tensions and loads, static offsets); the optional forces' variables
           (``viscous_force``, ``viscous_power``, ``morison_force``, ...: protocol/reply.py) with
           :func:`add_force_term_variables` / :meth:`ResultWriter.stage_forces`

Extra variables: ``add_variable(name, dims, coords, units, long_name)`` before the first row
(``coords`` gives the labels of any dimension not yet in the file), then per row
``stage_extra({name: value, ...})`` BEFORE ``append(...)``: the staged values belong to the row
that ``append`` adds (a variable not staged for a row keeps its previous value, NaN at first).
"""

from __future__ import annotations

import datetime as _dt
import json
import time as _time
from importlib import metadata
from pathlib import Path
from typing import Any, Mapping

import numpy as np
import netCDF4

from hydrolink.protocol.capabilities import reply_fields
from hydrolink.protocol.reply import dissipated_power, reply_field
from hydrolink.protocol.scene import Scene
from hydrolink.protocol.setup import Setup

DOF_NAMES: tuple[str, ...] = ("surge", "sway", "heave", "roll", "pitch", "yaw")

_TRANSLATION_ROTATION = "(surge, sway, heave); {rot} (roll, pitch, yaw)"
ROW_VARIABLES: dict[str, tuple[str, str]] = {
    "position": ("m " + _TRANSLATION_ROTATION.format(rot="rad"),
                 "absolute position of the body reference point and small rotation angles"),
    "velocity": ("m/s " + _TRANSLATION_ROTATION.format(rot="rad/s"),
                 "velocity of the body reference point and angular velocity (angle rates)"),
    "excitation_force": ("N " + _TRANSLATION_ROTATION.format(rot="N m"),
                         "wave excitation force and moment about the reference point"),
    "radiation_force": ("N " + _TRANSLATION_ROTATION.format(rot="N m"),
                        "radiation memory force -int K(tau) v(t - tau) dtau (the infinite-frequency "
                        "added mass is in the mass matrix, not here)"),
    "hydrostatic_force": ("N " + _TRANSLATION_ROTATION.format(rot="N m"),
                          "linear restoring force -C (x - x_eq), gravity terms included"),
}
_VERSIONED = ("hydrolink", "exudyn", "numpy", "capytaine", "xarray")


def package_versions() -> dict[str, str]:
    """Installed versions of the packages a result depends on ("not installed" if absent)."""
    out = {}
    for name in _VERSIONED:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


class ResultWriter:
    """Append-only results file; use as a context manager (an exception marks it interrupted)."""

    def __init__(self, path: str | Path, *, scene: Any = None, scene_text: str = "",
                 setup: Setup | None = None, bodies: list[str] | None = None,
                 equilibrium_position: np.ndarray | None = None, dt: float | None = None,
                 flush_seconds: float = 1.0, flush_rows: int = 2000):
        """``bodies``/``equilibrium_position`` default to the setup's wet bodies (else the scene's
        bodies at the origin); ``dt`` (the row spacing, an attribute) to the setup's."""
        if bodies is None:
            bodies = list(setup.bodies) if setup else [b.name for b in scene.bodies]
        if equilibrium_position is None:
            equilibrium_position = setup.equilibrium_position if setup else np.zeros((len(bodies), 6))
        if dt is None and setup:
            dt = setup.dt
        eq = np.asarray(equilibrium_position, float)
        if eq.shape != (len(bodies), 6):
            raise ValueError(f"equilibrium_position must have shape ({len(bodies)}, 6), got {eq.shape}")
        self.path = Path(path)
        self.path.parent.mkdir(parents=True, exist_ok=True)
        self.n_bodies = len(bodies)
        self.flush_seconds, self.flush_rows = float(flush_seconds), int(flush_rows)
        self.rows_written = 0
        self.status = "running"
        # rows are buffered in preallocated blocks (no per-row allocation): row i of the block
        # holds time, the (N, 6) row variables in ROW_VARIABLES order, and the wave elevation
        rows = max(self.flush_rows, 1)
        self._time = np.empty(rows)
        self._rows = np.empty((len(ROW_VARIABLES), rows, self.n_bodies, 6))
        self._eta = np.empty(rows)
        self._buffered = 0
        self._extra: dict[str, np.ndarray] = {}      # name -> (rows, *shape) block
        self._staged: set[str] = set()               # extras staged for the next row
        self._prev_row = 0                           # where row 0's unstaged extras come from
        self._last_flush = _time.monotonic()
        self._ds = netCDF4.Dataset(self.path, "w", format="NETCDF4")
        try:
            self._create(bodies, eq, scene_text, dt, setup.warnings if setup else ())
        except BaseException:
            self._ds.close()
            raise

    # -- layout ------------------------------------------------------------------------------
    def _create(self, bodies: list[str], eq: np.ndarray, scene_text: str, dt: float | None,
                warnings: tuple[str, ...]) -> None:
        ds, n = self._ds, len(bodies)
        ds.createDimension("time", None)
        ds.createDimension("body", n)
        ds.createDimension("dof", 6)
        chunk = 512
        t = ds.createVariable("time", "f8", ("time",), chunksizes=(chunk,))
        t.units, t.long_name, t.standard_name = "s", "simulation time", "time"
        b = ds.createVariable("body", str, ("body",))
        b.long_name = "body name"
        for i, name in enumerate(bodies):
            b[i] = name
        d = ds.createVariable("dof", str, ("dof",))
        d.long_name = "degree of freedom (rotations about the body reference point)"
        for i, name in enumerate(DOF_NAMES):
            d[i] = name
        for name, (units, long_name) in ROW_VARIABLES.items():
            v = ds.createVariable(name, "f8", ("time", "body", "dof"), chunksizes=(chunk, n, 6))
            v.units, v.long_name = units, long_name
        w = ds.createVariable("wave_elevation", "f8", ("time",), chunksizes=(chunk,))
        w.units, w.long_name = "m", "undisturbed incident wave elevation at the origin"
        e = ds.createVariable("equilibrium_position", "f8", ("body", "dof"))
        e.units = ROW_VARIABLES["position"][0]
        e.long_name = "body reference point at equilibrium (where the HDB's rotational modes refer), zero angles"
        e[:] = eq
        attrs = {
            "title": "hydrolink co-simulation results",
            "scene": scene_text,
            "created": _dt.datetime.now(_dt.timezone.utc).isoformat(timespec="seconds"),
            "status": self.status,
            "dof_convention": "positions absolute (reference point xyz + small rotation angles); "
                              "forces act at the reference point",
        }
        if dt is not None:
            attrs["dt"] = float(dt)
        attrs["warnings"] = json.dumps(list(warnings))  # the setup's; run_scene_file writes the run's final list
        attrs.update({f"{k}_version": v for k, v in package_versions().items()})
        ds.setncatts(attrs)
        ds.sync()

    def add_variable(self, name: str, dims: tuple[str, ...], coords: dict[str, list[str]] | None = None,
                     units: str = "", long_name: str = "") -> None:
        """Declare an extra per-row variable with dims (time, *dims); see the module docstring."""
        if self.rows_written or self._buffered:
            raise RuntimeError(f"add_variable({name!r}) after rows were written")
        if name in self._ds.variables:
            raise ValueError(f"results variable {name!r} already exists")
        coords = coords or {}
        shape = []
        for dim in dims:
            if dim not in self._ds.dimensions:
                if dim not in coords:
                    raise ValueError(f"add_variable({name!r}): labels for the new dimension {dim!r} are needed")
                labels = list(coords[dim])
                self._ds.createDimension(dim, len(labels))
                c = self._ds.createVariable(dim, str, (dim,))
                for i, label in enumerate(labels):
                    c[i] = str(label)
            shape.append(len(self._ds.dimensions[dim]))
        v = self._ds.createVariable(name, "f8", ("time", *dims), chunksizes=(512, *shape))
        v.units, v.long_name = units, long_name
        block = np.empty((self._time.size, *shape))
        block[0] = np.nan
        self._extra[name] = block

    def stage_forces(self, optional: Mapping[str, np.ndarray], rows: np.ndarray, velocity: np.ndarray) -> None:
        """Stage the variables of the optional forces for the next row: each force (6N over the
        served bodies) put at the flat positions ``rows`` of the file's (B, 6) bodies (zero for the
        others); ``velocity`` (B, 6) the row's, for a dissipated power."""
        for name, part in optional.items():
            full = np.zeros((self.n_bodies, 6))
            full.reshape(-1)[rows] = part
            self.stage_extra({v.name: full if v.value == "force" else dissipated_power(full, velocity)
                              for v in reply_field(name).variables})

    def stage_extra(self, values: dict[str, Any]) -> None:
        """Values of extra variables for the row the next :meth:`append` adds."""
        i = self._buffered
        for name, value in values.items():
            self._extra[name][i] = value
        self._staged.update(values)

    # -- rows --------------------------------------------------------------------------------
    def append(self, time: float, position, velocity, excitation, radiation, hydrostatic,
               wave_elevation) -> None:
        """Buffer one row: (N, 6) arrays and a number for the elevation (copied into the block);
        flushes when the wall-time or row budget is used up."""
        block = self.row()
        block[0] = position
        block[1] = velocity
        block[2] = excitation
        block[3] = radiation
        block[4] = hydrostatic
        self.commit(time, wave_elevation)

    def row(self) -> np.ndarray:
        """The next row's slot in the block, (5, N, 6) in ROW_VARIABLES order, to be filled in
        place (e.g. with ``out=``) and then added by :meth:`commit` — :meth:`append` without copies."""
        return self._rows[:, self._buffered]

    def commit(self, time: float, wave_elevation: float) -> None:
        """Add the row filled in :meth:`row` (and the extras staged); flushes when the wall-time
        or row budget is used up."""
        i = self._buffered
        self._time[i] = time
        self._eta[i] = wave_elevation
        if self._extra:
            staged = self._staged
            if len(staged) < len(self._extra):   # unstaged values repeat the previous row
                prev = i - 1 if i else self._prev_row
                for name, block in self._extra.items():
                    if name not in staged:
                        block[i] = block[prev]
            staged.clear()
        self._buffered = i + 1
        if (self._buffered >= self._time.size
                or _time.monotonic() - self._last_flush >= self.flush_seconds):
            self.flush()

    def flush(self) -> None:
        """Write the buffered rows and sync the file to disk."""
        if self._buffered and self._ds.isopen():
            m, i0 = self._buffered, self.rows_written
            i1 = i0 + m
            ds = self._ds
            for k, name in enumerate(ROW_VARIABLES):
                ds[name][i0:i1] = self._rows[k, :m]
            ds["wave_elevation"][i0:i1] = self._eta[:m]
            for name, block in self._extra.items():
                ds[name][i0:i1] = block[:m]
            self._prev_row = m - 1   # the next block's row 0 repeats the last row written
            ds["time"][i0:i1] = self._time[:m]  # last: marks the rows as present
            self.rows_written = i1
            self._buffered = 0
        if self._ds.isopen():
            self._ds.sync()
        self._last_flush = _time.monotonic()

    def set_attribute(self, name: str, value: Any) -> None:
        """Set a global attribute of the file (e.g. a run summary)."""
        if self._ds.isopen():
            self._ds.setncattr(name, value)

    # -- end ---------------------------------------------------------------------------------
    @property
    def rows(self) -> int:
        """Rows appended so far (written or still buffered; all are saved by :meth:`finish`)."""
        return self.rows_written + self._buffered

    def finish(self, status: str) -> None:
        """Flush everything and record the final status ("complete" or "interrupted: ...")."""
        self.status = status
        if self._ds.isopen():
            self.flush()
            self._ds.setncattr("status", status)
            self._ds.setncattr("rows", self.rows_written)
            self._ds.sync()

    def close(self) -> None:
        """Flush and close; a file still "running" is marked as not finished."""
        if not self._ds.isopen():
            return
        if self.status == "running":
            self.finish("interrupted: closed before the run finished")
        self._ds.close()

    def __enter__(self) -> "ResultWriter":
        return self

    def __exit__(self, exc_type, exc, tb) -> None:
        if exc_type is not None and self.status == "running":
            why = f"{exc_type.__name__}: {exc}" if str(exc) else exc_type.__name__
            self.finish(f"interrupted: {why}")
        self.close()


def add_force_term_variables(writer: ResultWriter, scene: Scene) -> None:
    """The results variables of the optional forces the scene's replies carry (its features'
    reply fields, protocol/capabilities.py), each as protocol/reply.py declares it, and the
    ``nonlinear`` attribute; :meth:`ResultWriter.stage_forces` fills them each row."""
    modes = {b.name: scene.nonlinear_of(b) for b in scene.nonlinear_bodies}
    if modes:
        writer.set_attribute("nonlinear", json.dumps(modes))
    for name in reply_fields(scene):
        for v in reply_field(name).variables:
            writer.add_variable(v.name, v.dims, None, v.units, v.description)
