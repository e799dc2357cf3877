"""`hydrolink run`: a scene file in, a results file out.

Loads the scene and its HDBs (building those given as build specs), connects to a force server —
or, when none is given, embeds one in this process — and drives the Exudyn client.
"""

from __future__ import annotations

import json
import logging
from contextlib import ExitStack
from dataclasses import replace
from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.clients.lockstep.summary import RunSummary
from hydrolink.protocol.hdb_wire import HDBFiles
from hydrolink.protocol.scene import Scene, SceneError, load_scene, resolve_path

log = logging.getLogger(__name__)


def load_scene_hdbs(scene: Scene, scene_path: str | Path, *, progress: bool = True,
                    as_files: bool = False) -> dict[str, xr.Dataset | HDBFiles]:
    """HDBs of a scene keyed by each body's ``hdb`` string (one load per distinct file).

    A ``.toml`` HDB is a build spec: it is built with Capytaine (or taken from the cache).
    ``as_files``: the other HDBs as their original files (SPEC §5.1 "HDB file set"), not read here:
    the server reads them and checks the bodies' names in them."""
    from hydrolink.server.hdb.io import file_set, load_hdb   # raise HDBError naming the file and field

    hdbs: dict[str, xr.Dataset | HDBFiles] = {}
    for i, body in enumerate(scene.bodies):
        if body.hdb is None or body.hdb in hdbs:
            continue
        path = resolve_path(scene_path, body.hdb)
        if not path.exists() and not path.with_suffix(".1").exists():
            raise SceneError(scene_path, f"bodies[{i}].hdb", f"file not found: {path}")
        qtf = next((j for j, b in enumerate(scene.bodies) if b.hdb == body.hdb and b.qtf is not None), None)
        if path.suffix == ".toml":
            from hydrolink.server.hdb.build import build_hdb
            hdbs[body.hdb] = build_hdb(path, progress=progress)
        elif as_files and qtf is None:   # with NEMOH QTF files: read here and sent as a map
            hdbs[body.hdb] = file_set(path)
        else:
            stated = next((b.hdb_convention for b in scene.bodies if b.hdb == body.hdb and b.hdb_convention), None)
            hdbs[body.hdb] = load_hdb(path, convention=stated)
        if qtf is not None:
            hdbs[body.hdb] = with_nemoh_qtf(hdbs[body.hdb], scene, qtf, scene_path)
    for i, body in enumerate(scene.bodies):
        if body.hdb is None or isinstance(hdbs[body.hdb], HDBFiles):
            continue
        names = [str(b) for b in hdbs[body.hdb]["body"].values]
        if body.hdb_body_name not in names:
            key = "hdb_body" if body.hdb_body else "name"
            raise SceneError(scene_path, f"bodies[{i}].{key}",
                             f"the HDB {body.hdb} holds no body {body.hdb_body_name!r} (it holds {names}); "
                             "set hdb_body to one of those")
    return hdbs


def with_nemoh_qtf(ds: xr.Dataset, scene: Scene, i: int, scene_path: str | Path) -> xr.Dataset:
    """The HDB ``ds`` of body ``i`` with the NEMOH QTF files its ``qtf`` names (relative to the
    scene; unit and convention as stated there); SceneError naming ``bodies[i].qtf`` and the key
    (the file's own line or field in the message) when a file is missing or unreadable, or the HDB
    already holds a QTF (one source per HDB)."""
    from hydrolink.protocol.hdb_schema import HDBError
    from hydrolink.protocol.hdb_second_order import qtf_kinds, with_second_order
    from hydrolink.server.hdb.nemoh_qtf import read_nemoh_qtf

    q, key = scene.bodies[i].qtf, f"bodies[{i}].qtf"
    if qtf_kinds(ds):
        raise SceneError(scene_path, key, f"the HDB {scene.bodies[i].hdb} already holds a QTF "
                                          f"({ds.attrs.get('qtf_source', '?')}): one QTF source per HDB")
    paths = {}
    for name in ("difference", "sum"):
        if getattr(q, name) is not None:
            paths[name] = resolve_path(scene_path, getattr(q, name))
            if not paths[name].is_file():
                raise SceneError(scene_path, f"{key}.{name}", f"file not found: {paths[name]}")
    try:
        qtf = read_nemoh_qtf(difference=paths.get("difference"), total_sum=paths.get("sum"),
                             rho=float(ds.attrs["rho"]), g=float(ds.attrs["g"]), n_dof=6 * ds.sizes["body"],
                             frequency_unit=q.frequency_unit, convention=q.convention)
        return with_second_order(ds, qtf=qtf)
    except HDBError as exc:
        which = next((n for n, p in paths.items() if Path(str(exc.source)).name == p.name), None)
        raise SceneError(scene_path, f"{key}.{which}" if which else key, str(exc)) from None


def load_scene_hulls(scene: Scene, scene_path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The closed hulls (vertices, faces) of the scene's nonlinear bodies by name, for
    ``hello.meshes`` (SPEC §5.1): the body's ``mesh`` file (relative to the scene; any format
    Capytaine reads), else the hull of its HDB build spec. SceneError naming bodies[i].mesh when
    there is neither or the file cannot be read; the server checks that each hull is closed."""
    hulls: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    for i, body in enumerate(scene.bodies):
        if scene.nonlinear_of(body) == "none":
            continue
        key = f"bodies[{i}].mesh"
        if body.mesh is not None:
            import capytaine as cpt

            path = resolve_path(scene_path, body.mesh)
            if not path.is_file():
                raise SceneError(scene_path, key, f"file not found: {path}")
            try:
                mesh = cpt.load_mesh(str(path))
            except Exception as exc:  # noqa: BLE001 - any reader failure is a bad scene input
                raise SceneError(scene_path, key, f"cannot read the mesh {path}: {exc}") from None
            hulls[body.name] = (np.asarray(mesh.vertices, float), np.asarray(mesh.faces))
            continue
        spec_path = resolve_path(scene_path, body.hdb)
        if spec_path.suffix != ".toml":
            raise SceneError(scene_path, key, f"required: body {body.name!r} has nonlinear hydrostatics "
                                              f"({scene.nonlinear_of(body)!r}) and its HDB {body.hdb} is not a build spec "
                                              "to take the hull from; name its closed hull's mesh file")
        from hydrolink.server.hdb.build_mesh import closed_hull
        from hydrolink.server.hdb.build_spec import load_spec
        spec = load_spec(spec_path)
        names = [b.name for b in spec.all_bodies]
        index = names.index(body.hdb_body_name) if body.hdb_body_name in names else 0
        hulls[body.name] = closed_hull(spec, index, spec_path)
    return hulls


def load_wave_elevation(scene: Scene, scene_path: str | Path):
    """The (time, eta) series of ``[waves] type = "elevation"`` read from its file (relative to the
    scene), or None for other waves; SceneError naming waves.file when missing or malformed."""
    if getattr(scene.waves, "type", None) != "elevation":
        return None
    from hydrolink.server.waves import WaveError, read_elevation
    try:
        return read_elevation(resolve_path(scene_path, scene.waves.file))
    except WaveError as exc:
        raise SceneError(scene_path, exc.key, exc.why) from None


def _write_summary_attributes(writer, summary: RunSummary) -> None:
    """The run's warnings and, when paced, its realtime report (JSON global attributes; its
    ``overruns`` is the sum of the file's ``overrun``)."""
    writer.set_attribute("warnings", json.dumps(summary.warnings))
    if summary.realtime is not None:
        from dataclasses import asdict
        writer.set_attribute("realtime", json.dumps(asdict(summary.realtime)))


def run_scene_file(scene_path: str | Path, output: str | Path | None = None, *,
                   server: str | None = None, progress: bool = True, timeout: float = 60.0,
                   listen: str = "tcp://127.0.0.1:*", hdbs: dict[str, xr.Dataset] | None = None,
                   curve=None, key: bytes | None = None, link_timeout: float = 10.0,
                   hdb_files: bool = False, realtime: float | None = None) -> RunSummary:
    """Run a scene end to end; returns the run summary (steps, wall time, output path, the server's side).

    A scene with ``[[controllers]]`` and no ``server`` starts a force server with a socket on
    ``listen`` in a thread of this process (controllers connect to it; SPEC §5.7) instead of the
    in-process one, and says on stderr where the controllers should connect. ``curve``: a
    :class:`hydrolink.protocol.security.ClientKeys` for a ``server`` that requires CURVE; ``key``:
    the shared HMAC key (SPEC §3.3) of ``server``, or of the run's own listening server, whose
    controllers must then sign too; ``link_timeout``: how long the link to a remote ``server`` may
    stay down (SPEC §1) before the run ends (its rows kept); ``hdb_files``: send the HDBs as their
    files by SHA-256 (:func:`load_scene_hdbs` ``as_files``; the summary's ``hdb_uploads`` counts
    the contents the server lacked); ``realtime``: release each exchange at its wall-clock time,
    FACTOR x wall clock (protocol/pacing.py; the summary's ``realtime``, a PacedRunReport, and the
    results' ``step_latency``, ``overrun`` and ``step_time``, docs/realtime.md)."""
    from hydrolink.clients.lockstep.connection import ServerConnection
    from hydrolink.clients.exudyn.client import result_bodies, run
    from hydrolink.clients.lockstep.results import ResultWriter

    scene_path = Path(scene_path)
    scene, text = load_scene(scene_path)
    if hdbs is None:  # (a caller running one scene many times may pass them, e.g. hydrolink bench)
        hdbs = load_scene_hdbs(scene, scene_path, progress=progress, as_files=hdb_files)
    series = load_wave_elevation(scene, scene_path)
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
                          realtime=realtime)
            _write_summary_attributes(writer, summary)
        return replace(summary, output=str(output), server=None)
    with ExitStack() as stack:
        if server is None and scene.controllers:
            from hydrolink.server.service import serve_in_thread
            srv, thread = serve_in_thread(listen, key=key)

            def _stop_server() -> None:
                srv.stop()
                thread.join(5.0)
            stack.callback(_stop_server)
            server = srv.address
            conn = stack.enter_context(ServerConnection(server, timeout=timeout, key=key))
        elif server is None:
            # embedded: the force server's request handler in this process, fed the same wire
            # frames as over a socket (same codec, same results) but with no thread or transport
            # to wake up each step
            from hydrolink.server.service import ForceServer
            embedded = ForceServer(None)
            stack.callback(embedded.close)
            conn = stack.enter_context(ServerConnection(embedded, timeout=timeout))
            server = embedded.address
            log.info("embedded force server (in-process)")
        else:
            conn = stack.enter_context(ServerConnection(server, timeout=timeout, curve=curve, key=key,
                                                        link_timeout=link_timeout))
        setup = conn.hello(text, hdbs, wave_elevation=series, meshes=load_scene_hulls(scene, scene_path))
        if scene.controllers:
            import sys
            print(f"hydrolink run: session {conn.session} on {server} waits for controllers "
                  f"{[c.name for c in scene.controllers]}: hydrolink control FILE.py --server {server} "
                  f"--session {conn.session}", file=sys.stderr, flush=True)
        names, reference = result_bodies(scene, setup)
        writer = stack.enter_context(ResultWriter(output, scene=scene, scene_text=text, setup=setup,
                                                  bodies=names, equilibrium_position=reference,
                                                  flush_seconds=scene.simulation.flush_seconds))
        if scene.client.type == "fmu":
            from hydrolink.clients.fmu.master import run as run_fmu
            summary = run_fmu(scene, text, conn, setup, writer, scene_path=scene_path, progress=progress,
                              realtime=realtime)
        else:
            summary = run(scene, text, conn, setup, writer, progress=progress, moordyn_files=moordyn_files,
                          realtime=realtime)
        _write_summary_attributes(writer, summary)
        goodbye = conn.bye()
    # the server's side: its compute per step, the radiation option and its pruning ([hydro]
    # radiation, coupling_tolerance), the state-space pairs fitted in this setup (the rest came
    # from the on-disk fit cache)
    return replace(summary, output=str(output), server=server, hdb_uploads=len(conn.uploads),
                   server_compute_us_per_step=(1e6 * goodbye["compute_s"] / goodbye["steps"]
                                               if goodbye.get("steps") else None),
                   radiation=setup.radiation, radiation_pairs=setup.radiation_pairs,
                   dropped_pair_fraction=setup.dropped_pair_fraction,
                   dropped_block_fraction=setup.dropped_block_fraction,
                   state_space_fitted_pairs=setup.state_space.fitted_pairs if setup.state_space else None)
