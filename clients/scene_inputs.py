"""A scene's input files, loaded as every tool needs them: its HDBs (read, built or sent as files, with
NEMOH QTFs added), its bodies' hulls for nonlinear terms, its wave elevation series and gauge records."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import xarray as xr

from hydrolink.protocol.hdb.external_matrices import ExternalMatrices
from hydrolink.protocol.hdb.wire import HDBFiles
from hydrolink.protocol.scene import Scene, SceneError, resolve_path


def load_scene_hdbs(scene: Scene, scene_path: str | Path, *, progress: bool = True,
                    as_files: bool = False) -> dict[str, xr.Dataset | HDBFiles]:
    """HDBs of a scene keyed by each body's ``hdb`` string (one load per distinct file).

    A ``.toml`` HDB is a build spec: it is built with Capytaine (or taken from the cache).
    ``as_files``: the other HDBs as their original files (SPEC §5.1 "HDB file set"), not read here:
    the server reads them and checks the bodies' names in them."""
    from hydrolink.server.hdb.io import file_set, load_hdb, nondimensional   # raise HDBError naming the file and field

    hdbs: dict[str, xr.Dataset | HDBFiles] = {}
    for i, body, hdb, scene_key in scene.hdb_keys():   # each body's hdb and its hydro_states' HDBs
        if hdb in hdbs:
            continue
        path = resolve_path(scene_path, hdb)
        if not path.exists() and not path.with_suffix(".1").exists():
            raise SceneError(scene_path, scene_key, f"file not found: {path}")
        qtf = next((j for j, b in enumerate(scene.bodies) if b.hdb == hdb and b.qtf is not None), None)
        if path.suffix == ".toml":
            from hydrolink.server.hdb.build.builder import build_hdb
            hdbs[hdb] = build_hdb(path, progress=progress)
        elif as_files and qtf is None:   # with NEMOH QTF files: read here and sent as a map
            # a nondimensional (WAMIT) run takes the scene's density; the server reads it with the
            # scene's bodies[i].wamit facts
            hdbs[hdb] = file_set(path, rho=scene.water.density if nondimensional(path) else None)
        else:
            stated = next((b.hdb_convention for b in scene.bodies if b.hdb == hdb and b.hdb_convention), None)
            hdbs[hdb] = load_hdb(path, convention=stated, wamit=scene.wamit_statement(hdb),
                                 rho=scene.water.density if nondimensional(path) else None)
        if qtf is not None:
            hdbs[hdb] = with_nemoh_qtf(hdbs[hdb], scene, qtf, scene_path)
    for i, body, hdb, scene_key in scene.hdb_keys():
        if isinstance(hdbs[hdb], HDBFiles):
            continue
        names = [str(b) for b in hdbs[hdb]["body"].values]
        if body.hdb_body_name not in names:
            key = scene_key if body.hdb != hdb else f"bodies[{i}].{'hdb_body' if body.hdb_body else 'name'}"
            raise SceneError(scene_path, key,
                             f"the HDB {hdb} holds no body {body.hdb_body_name!r} (it holds {names}); "
                             "set hdb_body to one of those")
    return hdbs


def with_nemoh_qtf(ds: xr.Dataset, scene: Scene, i: int, scene_path: str | Path) -> xr.Dataset:
    """The HDB ``ds`` of body ``i`` with the NEMOH QTF files its ``qtf`` names (relative to the
    scene; unit and convention as stated there); SceneError naming ``bodies[i].qtf`` and the key
    (the file's own line or field in the message) when a file is missing or unreadable, or the HDB
    already holds a QTF (one source per HDB)."""
    from hydrolink.protocol.hdb.layout import HDBError
    from hydrolink.protocol.hdb.second_order import qtf_kinds
    from hydrolink.protocol.hdb.schema import with_second_order
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
    ``hello.meshes`` (SPEC §5.1): :func:`load_body_hull` of each; the server checks that each hull
    is closed."""
    return {body.name: load_body_hull(scene, scene_path, i, f"it has nonlinear hydrostatics ({scene.nonlinear_of(body)!r})")
            for i, body in enumerate(scene.bodies) if scene.nonlinear_of(body) != "none"}


def load_body_hull(scene: Scene, scene_path: str | Path, i: int, needs: str) -> tuple[np.ndarray, np.ndarray]:
    """The closed hull (vertices, faces; global frame at equilibrium) of ``scene.bodies[i]``: its
    ``mesh`` file (relative to the scene; any format Capytaine reads), else the hull of its HDB build
    spec. SceneError naming bodies[i].mesh when there is neither (``needs``: why the hull is needed)
    or the file cannot be read."""
    body, key = scene.bodies[i], f"bodies[{i}].mesh"
    if body.mesh is not None:
        import capytaine as cpt

        path = resolve_path(scene_path, body.mesh)
        if not path.is_file():
            raise SceneError(scene_path, key, f"file not found: {path}")
        try:
            mesh = cpt.load_mesh(str(path))
        except Exception as exc:  # noqa: BLE001 - any reader failure is a bad scene input
            raise SceneError(scene_path, key, f"cannot read the mesh {path}: {exc}") from None
        return np.asarray(mesh.vertices, float), np.asarray(mesh.faces)
    spec_path = build_spec_of(scene, scene_path, i)
    if spec_path is None:
        raise SceneError(scene_path, key, f"required: body {body.name!r} needs its closed hull ({needs}) and its "
                                          f"HDB {body.hdb} is not a build spec to take the hull from; name its "
                                          "closed hull's mesh file")
    from hydrolink.server.hdb.build.mesh import closed_hull
    from hydrolink.server.hdb.build.spec import load_spec
    spec = load_spec(spec_path)
    names = [b.name for b in spec.all_bodies]
    index = names.index(body.hdb_body_name) if body.hdb_body_name in names else 0
    return closed_hull(spec, index, spec_path)


def build_spec_of(scene: Scene, scene_path: str | Path, i: int) -> Path | None:
    """The HDB build spec of ``scene.bodies[i]``: its ``hdb`` when that is one, else its modes'
    ``shapes`` (the spec its HDB was built from); None when it has neither."""
    body = scene.bodies[i]
    if body.hdb is not None and body.hdb.endswith(".toml"):
        return resolve_path(scene_path, body.hdb)
    shapes = body.modes.shapes if body.modes is not None else None
    return resolve_path(scene_path, shapes) if shapes is not None else None


def load_wave_elevation(scene: Scene, scene_path: str | Path):
    """The (time, eta) series of ``[waves] type = "elevation"`` read from its file (relative to the
    scene), or None for other waves; SceneError naming waves.file when missing or malformed."""
    if getattr(scene.waves, "type", None) != "elevation":
        return None
    from hydrolink.server.sea.waves import WaveError, read_elevation
    try:
        return read_elevation(resolve_path(scene_path, scene.waves.file))
    except WaveError as exc:
        raise SceneError(scene_path, exc.key, exc.why) from None


def load_spectrum_files(scene: Scene, scene_path: str | Path) -> dict[str, tuple[list[float], list[float] | None, list]]:
    """The tables of the scene's spectrum files (``waves.systems[i].file``, relative to the scene) by
    their key: (omega, theta or None, density), in the system's ``units``. A CSV file: a header row
    then one row per frequency — "omega,density" (S(w)) or "omega/theta" and the directions in
    degrees, then on each row the frequency and S(w, theta) per direction. A NetCDF file: a variable
    ``density`` over the dimension ``omega`` (and ``theta``, degrees), with those coordinates.
    SceneError naming the key and the file when one cannot be read as such a table."""
    out = {}
    for key, name in scene.spectrum_files():
        path = resolve_path(scene_path, name)
        try:
            out[key] = _spectrum_csv(path) if path.suffix.lower() == ".csv" else _spectrum_netcdf(path)
        except (OSError, ValueError, KeyError) as exc:
            raise SceneError(scene_path, key, f"{path}: {exc}") from None
    try:       # each table checked as an inline one would be (negative, unordered, all zero...)
        scene.with_spectra(out)
    except ValueError as exc:
        key, _, why = str(exc).partition(": ")
        raise SceneError(scene_path, key, why) from None
    return out


def _spectrum_csv(path: Path) -> tuple[list[float], list[float] | None, list]:
    """A CSV table (load_spectrum_files)."""
    lines = [ln for ln in path.read_text().splitlines() if ln.strip()]
    if len(lines) < 3:
        raise ValueError("needs a header row and at least two frequencies")
    head = [c.strip() for c in lines[0].split(",")]
    rows = [[float(c) for c in ln.split(",")] for ln in lines[1:]]
    if head == ["omega", "density"]:
        if any(len(r) != 2 for r in rows):
            raise ValueError("every row of an 'omega,density' table needs two values")
        return [r[0] for r in rows], None, [r[1] for r in rows]
    if head[0] != "omega/theta" or len(head) < 3:
        raise ValueError(f"header {lines[0]!r}: expected 'omega,density' or 'omega/theta' and the directions in degrees")
    theta = [float(c) for c in head[1:]]
    if any(len(r) != len(theta) + 1 for r in rows):
        raise ValueError(f"every row needs a frequency and {len(theta)} densities (one per direction)")
    return [r[0] for r in rows], theta, [r[1:] for r in rows]


def _spectrum_netcdf(path: Path) -> tuple[list[float], list[float] | None, list]:
    """A NetCDF table (load_spectrum_files)."""
    with xr.open_dataset(path, engine="netcdf4") as ds:
        density = ds["density"]
        if density.dims not in (("omega",), ("omega", "theta")):
            raise ValueError(f"variable 'density' has dimensions {density.dims}: expected ('omega',) or "
                             "('omega', 'theta') (theta in degrees)")
        theta = ds["theta"].values.astype(float).tolist() if "theta" in density.dims else None
        return ds["omega"].values.astype(float).tolist(), theta, density.values.astype(float).tolist()


def load_gauge_files(scene: Scene, scene_path: str | Path) -> dict[str, tuple[np.ndarray, np.ndarray]]:
    """The (time, eta) records of ``[waves] type = "gauges"`` by key (``waves.gauges[i].file``,
    relative to the scene; read as ``type = "elevation"`` reads its file), checked as the server
    fits them (one uniform grid shared by all gauges, the run inside them: server/sea/gauges.py);
    SceneError naming the key and the file otherwise."""
    from hydrolink.server.sea.gauges import gauge_records
    from hydrolink.server.sea.waves import WaveError, read_elevation
    out = {}
    try:
        for key, gauge in scene.gauge_files():
            out[key] = read_elevation(resolve_path(scene_path, gauge.file), key, gauge.variable)
        if out:
            gauge_records(scene.with_gauges(out).waves)
    except WaveError as exc:
        raise SceneError(scene_path, exc.key, exc.why) from None
    except ValueError as exc:
        key, _, why = str(exc).partition(": ")
        raise SceneError(scene_path, key, why) from None
    return out


def load_modal_structures(scene: Scene, scene_path: str | Path,
                          hdbs: dict[str, xr.Dataset]) -> tuple[Scene, dict[str, ExternalMatrices]]:
    """The scene with its bodies' modes' structure files read (``bodies[i].modes.mmx``, relative to the
    scene: a WAMIT ``.mmx`` numbered as the body's HDB ``hdbs[body.hdb]``), and each body's block by
    key for ``hello.modal_structure`` (SPEC §5.1). SceneError naming the key, with the file (and the
    HDB where their modes differ), when one cannot be read as the body's structure."""
    from hydrolink.protocol.hdb.layout import HDBError
    from hydrolink.protocol.hdb.schema import hdb_dofs
    from hydrolink.server.hdb.wamit.modal_structure import body_external_matrices

    out = {}
    for key, i, body in scene.modal_files():
        path = resolve_path(scene_path, body.modes.mmx)
        try:
            out[key] = body_external_matrices(path, hdb_dofs(hdbs[body.hdb]), body.hdb_body_name)
        except HDBError as exc:
            raise SceneError(scene_path, key, f"{path} against the HDB {body.hdb}: {exc}") from None
    try:
        return scene.with_modal_structure(out), out
    except ValueError as exc:
        key, _, why = str(exc).partition(": ")
        raise SceneError(scene_path, key, why) from None
