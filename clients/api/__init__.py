"""hydrolink: co-simulation of wave energy converters — the public API, ``import hydrolink``.

What a script needs, as the ``hydrolink`` command's verbs do it::

    import hydrolink

    scene = hydrolink.load_scene("examples/rm3/rm3.toml")            # validated; errors name the key
    hdb = hydrolink.load_hdb("examples/data/rm3_wamit/rm3.1")         # any supported format -> xarray
    summary = hydrolink.run("examples/rm3/rm3.toml", "rm3.nc")        # embedded server + Exudyn client
    plant = hydrolink.linearize("examples/rm3/rm3.toml", dt=0.01)     # linear state-space plant

This folder is the package ``hydrolink`` itself (pyproject.toml maps it; the design card's folders are
its subpackages ``hydrolink.server``, ``.clients`` and ``.protocol``). Its functions import what they
use when called, so importing any part of hydrolink stays as light as that part.
"""

from __future__ import annotations

from pathlib import Path
from typing import TYPE_CHECKING

if TYPE_CHECKING:
    import xarray as xr

    from hydrolink.clients.lockstep.summary import RunSummary
    from hydrolink.clients.analysis.plant import Plant
    from hydrolink.protocol.scene import Scene

__all__ = ["build_hdb", "linearize", "load_hdb", "load_scene", "run"]


def load_scene(path: str | Path) -> "Scene":
    """The scene file at ``path``, validated (SceneError naming the file and key otherwise)."""
    from hydrolink.protocol.scene import load_scene as _load

    return _load(path)[0]


def load_hdb(path: str | Path) -> "xr.Dataset":
    """An HDB file of any supported format (Capytaine, BEMIO .h5, WAMIT, hydrolink .nc) in the internal
    layout: SI units, exp(-iwt) (HDBError naming the file and field otherwise). What its reader
    found doubtful is in ``attrs["warnings"]`` and shown as HDBWarnings."""
    from hydrolink.server.hdb.io import load_hdb as _load

    return _shown(_load(path))


def build_hdb(spec_path: str | Path, *, progress: bool = False) -> "xr.Dataset":
    """The HDB of an ``hdb build`` spec, computed with Capytaine or read from the cache (docs/hdb-spec.md)."""
    from hydrolink.server.hdb.build.builder import build_hdb as _build

    return _shown(_build(spec_path, progress=progress))


def _shown(ds: "xr.Dataset") -> "xr.Dataset":
    """``ds``, its reader's or builder's warnings (attribute ``warnings``) shown as HDBWarnings."""
    import warnings

    from hydrolink.protocol.hdb.layout import hdb_warnings
    from hydrolink.server.hdb.reader_warnings import HDBWarning

    for note in hdb_warnings(ds):
        warnings.warn(note, HDBWarning, stacklevel=3)
    return ds


def run(scene_path: str | Path, output: str | Path | None = None, *, server: str | None = None,
        realtime: float | None = None, progress: bool = False) -> "RunSummary":
    """Co-simulate the scene at ``scene_path`` as ``hydrolink run`` does (an embedded force server unless
    ``server`` gives an address), writing the results to ``output`` (NetCDF) when given."""
    from hydrolink.clients.run import run_scene_file

    return run_scene_file(scene_path, output, server=server, realtime=realtime, progress=progress)


def linearize(scene_path: str | Path, *, dt: float | None = None, output: str | Path | None = None,
              progress: bool = False) -> "Plant":
    """The device of the scene as a linear state-space plant about its equilibrium (``hydrolink
    linearize``; docs/plant.md): continuous, or zero-order hold at ``dt``; written to ``output`` (.npz,
    .mat or .nc) when given."""
    from hydrolink.clients.analysis.plant import linearize_scene, linearize_scene_file

    if output is not None:
        return linearize_scene_file(scene_path, output, dt=dt, progress=progress)
    return linearize_scene(scene_path, dt=dt, progress=progress)
