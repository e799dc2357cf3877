"""`hydrolink run`: a scene file in, a results file out.

Loads the scene and its HDBs (building those given as build specs), connects to a force server —
or, when none is given, embeds one in this process — and drives the Exudyn client.
"""

from __future__ import annotations

import json
import logging
import math
import sys
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path
from typing import TYPE_CHECKING

import xarray as xr

from hydrolink.clients.lockstep.section_results import add_section_loads, plan_sections
from hydrolink.clients.lockstep.summary import RunSummary
from hydrolink.clients.scene_inputs import (load_gauge_files, load_modal_structures, load_scene_hdbs, load_scene_hulls,
                                            load_spectrum_files, load_wave_elevation)
from hydrolink.protocol.scene import load_scene

if TYPE_CHECKING:
    from hydrolink.clients.analysis.optimal.metrics import RunMetrics

log = logging.getLogger(__name__)


def _write_summary_attributes(writer, summary: RunSummary) -> None:
    """The run's warnings and, when paced, its realtime report (JSON global attributes; its
    ``overruns`` is the sum of the file's ``overrun``)."""
    writer.set_attribute("warnings", json.dumps(summary.warnings))
    if summary.realtime is not None:
        from dataclasses import asdict
        writer.set_attribute("realtime", json.dumps(asdict(summary.realtime)))


def _limit_metrics(scene, output: Path) -> RunMetrics | None:
    """The WECCCOMP metrics of a run whose scene has limits (PTO force limits, ``[optimize]``
    limits), after the ramp, written into the results file's attributes; None without limits."""
    import netCDF4

    from hydrolink.clients.analysis.optimal.metrics import run_metrics, scene_limits

    limits = scene_limits(scene)
    if not limits:
        return None
    with xr.open_dataset(output, engine="netcdf4") as ds:   # lazily: only the series the limits use are read
        metrics = run_metrics(ds, limits, start=getattr(scene.waves, "ramp", None),
                              efficiency=scene.optimize.efficiency)
    with netCDF4.Dataset(output, "a") as nc:
        nc.setncatts(metrics.attributes())
    return metrics


def _announce_controllers(scene, server: str, token: str | None) -> None:
    """Say on stderr how the scene's controllers join (the session's join token, SPEC §5.7.2)."""
    print(f"hydrolink run: session on {server} waits for controllers {[c.name for c in scene.controllers]}: "
          f"hydrolink control FILE.py --server {server} --token {token}", file=sys.stderr, flush=True)


def _after_the_run(scene, output: Path, sections) -> RunMetrics | None:
    """What the run's rows give after its last step: the loads along the bodies and their panel
    pressures (``sections``, a SectionPlan: no per-step cost), then the limits' metrics."""
    if sections is not None:
        add_section_loads(output, sections, scene)
    return _limit_metrics(scene, output)


def _datasets(scene, scene_path: Path, hdbs: dict, progress: bool) -> dict[str, xr.Dataset]:
    """The scene's HDBs as datasets (those sent as files read here), for what the client computes
    from them itself; only when some body asks for its loads along its axis or numbers its modes'
    structure file by its HDB (``bodies[i].modes.mmx``)."""
    if not any(b.sections is not None or b.pressure_output for b in scene.bodies) and not scene.modal_files():
        return {}
    if all(isinstance(h, xr.Dataset) for h in hdbs.values()):
        return hdbs
    return load_scene_hdbs(scene, scene_path, progress=progress)


def _client_inputs(scene, scene_path: Path, hdbs: dict, progress: bool) -> tuple:
    """What the client reads and plans itself before any step: the scene with its modes' structure
    files read, the wave elevation series, the loads along the bodies planned, and the structure
    files' body blocks for ``hello.modal_structure``."""
    datasets = _datasets(scene, scene_path, hdbs, progress)
    scene, modal_structure = load_modal_structures(scene, scene_path, datasets)
    return (scene, load_wave_elevation(scene, scene_path), plan_sections(scene, scene_path, datasets),
            modal_structure)


def run_scene_file(scene_path: str | Path, output: str | Path | None = None, *,
                   server: str | None = None, progress: bool = True, timeout: float = 60.0,
                   listen: str = "tcp://127.0.0.1:*", hdbs: dict[str, xr.Dataset] | None = None,
                   curve=None, key: bytes | None = None, link_timeout: float = 10.0, hdb_files: bool = False,
                   realtime: float | None = None, control_token: str | None = None, direct: bool = True,
                   rt_priority: int | None = None) -> RunSummary:
    """Run a scene end to end; returns the run summary (steps, wall time, output path, the server's side).

    A scene with ``[[controllers]]`` and no ``server`` makes its own force server with a socket on ``listen``
    (controllers connect to it; SPEC §5.7), polled from this thread (``ForceServer(..., polled=True)``: the run's
    requests handed to it in-process, its socket served while a step waits for the controllers), and says on stderr
    where the controllers should connect. ``curve``: a :class:`hydrolink.protocol.security.ClientKeys` for a
    ``server`` that requires CURVE; ``key``: the shared HMAC key (SPEC §3.3) of ``server``, or of the run's own
    listening server, whose controllers must then sign too; ``link_timeout``: how long the link to a remote
    ``server`` may stay down (SPEC §1) before the run ends (its rows kept); ``hdb_files``: send the HDBs as their
    files by SHA-256 (:func:`load_scene_hdbs` ``as_files``; the summary's ``hdb_uploads`` counts the contents the
    server lacked); ``realtime``: release each exchange at its wall-clock time, FACTOR x wall clock
    (protocol/pacing.py; the summary's ``realtime``, a PacedRunReport, and the results' ``step_latency``,
    ``overrun`` and ``step_time``, docs/realtime.md); ``control_token``: the secret the scene's controllers show to
    join (SPEC §5.7.2: ``hydrolink control --token``; None: the server draws one, printed on stderr); ``direct``:
    take a ``server``'s direct channel offered (SPEC §5.7.5); ``rt_priority``: the loop (not the set-up) under
    SCHED_FIFO at that priority (clients/lockstep/rt_priority.py)."""
    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.clients.exudyn.client import result_bodies, run
    from hydrolink.clients.lockstep.results import ResultWriter

    scene_path = Path(scene_path)
    scene, text = load_scene(scene_path, have_hdbs=hdbs or ())   # every schema and file problem at once
    if hdbs is None:  # (a caller running one scene many times may pass them, e.g. hydrolink bench)
        hdbs = load_scene_hdbs(scene, scene_path, progress=progress, as_files=hdb_files)
    scene, series, sections, modal_structure = _client_inputs(scene, scene_path, hdbs, progress)   # before any step
    moordyn_files = None
    if any(getattr(m, "type", "") == "moordyn" for m in scene.moorings):
        from hydrolink.clients.exudyn.moordyn_mooring import load_moordyn_files
        moordyn_files = load_moordyn_files(scene, scene_path)
    output = Path(output) if output else scene_path.with_suffix(".out.nc")
    if not scene.served_bodies:
        # no hydrodynamics: the mechanism runs alone, without a force server
        setup = None
        names, reference = result_bodies(scene, None)
        with ResultWriter(output, scene=scene, scene_text=text, dt=scene.simulation.dt, bodies=names,
                          equilibrium_position=reference, flush_seconds=scene.simulation.flush_seconds) as writer:
            summary = run(scene, text, None, None, writer, progress=progress, moordyn_files=moordyn_files,
                          realtime=realtime, rt_priority=rt_priority)
            _write_summary_attributes(writer, summary)
        return replace(summary, output=str(output), server=None)
    with ExitStack() as stack:
        if server is None and scene.controllers:
            # the run's own server with a socket on ``listen`` for the controllers, polled from this
            # thread (no server thread, no loopback hop to it): a step waiting for the controllers'
            # commands serves the socket until they are in; one session (this run's)
            from hydrolink.clients.analysis.plant import build_plant
            from hydrolink.server.service.force_server import ForceServer
            srv = ForceServer(listen, key=key, plant_builder=build_plant, polled=True, max_sessions=1,
                              isolate_step_s=math.inf)
            stack.callback(srv.close)
            server = srv.address
            conn = stack.enter_context(ServerConnection(srv, timeout=timeout, key=key))
        elif server is None:
            # embedded: the force server's request handler in this process, fed the same wire
            # frames as over a socket (same codec, same results) but with no thread or transport
            # to wake up each step
            from hydrolink.clients.analysis.plant import build_plant
            from hydrolink.server.service.force_server import ForceServer
            embedded = ForceServer(None, plant_builder=build_plant)
            stack.callback(embedded.close)
            conn = stack.enter_context(ServerConnection(embedded, timeout=timeout))
            server = embedded.address
            log.info("embedded force server (in-process)")
        else:
            conn = stack.enter_context(ServerConnection(server, timeout=timeout, curve=curve, key=key,
                                                        link_timeout=link_timeout, direct=direct))
        setup = conn.hello(text, hdbs, wave_elevation=series, meshes=load_scene_hulls(scene, scene_path), control_token=control_token,
                           spectra=load_spectrum_files(scene, scene_path), gauges=load_gauge_files(scene, scene_path),
                           modal_structure=modal_structure)
        if scene.controllers:
            _announce_controllers(scene, server, conn.control_token)
        names, reference = result_bodies(scene, setup)
        writer = stack.enter_context(ResultWriter(output, scene=scene, scene_text=text, setup=setup,
                                                  bodies=names, equilibrium_position=reference,
                                                  flush_seconds=scene.simulation.flush_seconds))
        if scene.client.type == "fmu":
            from hydrolink.clients.fmu.master import run as run_fmu
            summary = run_fmu(scene, text, conn, setup, writer, scene_path=scene_path, progress=progress,
                              realtime=realtime, rt_priority=rt_priority)
        else:
            summary = run(scene, text, conn, setup, writer, progress=progress, moordyn_files=moordyn_files,
                          realtime=realtime, rt_priority=rt_priority)
        _write_summary_attributes(writer, summary)
        goodbye = conn.bye()
    metrics = _after_the_run(scene, output, sections)
    # the server's side: its compute per step, the radiation option and its pruning ([hydro] radiation,
    # coupling_tolerance), the state-space pairs fitted in this setup (the rest from the on-disk fit cache)
    return replace(summary, output=str(output), server=server, hdb_uploads=len(conn.uploads), metrics=metrics,
                   server_compute_us_per_step=(1e6 * goodbye["compute_s"] / goodbye["steps"]
                                               if goodbye.get("steps") else None),
                   radiation=setup.radiation, radiation_pairs=setup.radiation_pairs,
                   dropped_pair_fraction=setup.dropped_pair_fraction,
                   dropped_block_fraction=setup.dropped_block_fraction,
                   state_space_fitted_pairs=setup.state_space.fitted_pairs if setup.state_space else None)
