"""server/hdb/reader_warnings.py: what an HDB reader finds doubtful travels with the HDB to every
client's ``setup.warnings`` and into the results' ``warnings`` attribute (issue 40 item 5).

The file is the repository's RM3 Capytaine export, which records no rotation centre: its reader
warns that the rotational modes are taken about the origin. The scene keeps the default sea-water
density, so the server adds its own warning (the HDB's 1000 kg/m³ rescaled). Both must reach the
client: when the client reads the file itself (embedded server), and when the server reads the
files sent by hash (in its child process), where the warning names the file as the client sent it.
The FMU paths are tested in test_fmu_native.py and test_fmu_slave.py."""

from __future__ import annotations

import json
import shutil
import warnings
from pathlib import Path

import netCDF4
import pytest

from conftest import REPLY_S, rm3_float, rm3_spar, scene_toml, write_scene
from hydrolink.protocol.hdb.layout import HDBError, hdb_warnings
from hydrolink.protocol.hdb.wire import from_wire, to_wire
from hydrolink.server.hdb.io import load_hdb
from hydrolink.server.hdb.reader_warnings import HDBWarning

READER_NOTE = "rm3.nc: no rotation_center or center_of_mass recorded"
SERVER_NOTE = "water: the scene's density 1025 kg/m^3 differs"


@pytest.fixture(scope="module")
def scene(tmp_path_factory, reference_data) -> Path:
    folder = tmp_path_factory.mktemp("reader_warnings")
    shutil.copy(reference_data / "rm3_capytaine" / "rm3_hydrodynamics.nc", folder / "rm3.nc")
    return write_scene(folder, scene_toml(dt=0.1, duration=0.5, progress=False, hydro={"irf_duration": 10.0},
                                          bodies=[rm3_float("rm3.nc", dofs=["heave"]),
                                                  rm3_spar("rm3.nc", dofs=["heave"])]))


def _said(notes, text: str) -> int:
    return sum(text in n for n in notes)


def test_the_reader_keeps_its_warning_with_the_hdb_and_shows_nothing(scene):
    with warnings.catch_warnings(record=True) as caught:
        warnings.simplefilter("always")
        ds = load_hdb(scene.parent / "rm3.nc")
    assert not [w for w in caught if issubclass(w.category, HDBWarning)]
    notes = hdb_warnings(ds)
    assert len(notes) == 1 and READER_NOTE in notes[0] and "record it in the file" in notes[0]
    assert "reference_points" not in notes[0]       # no Python argument a scene cannot give


def test_the_wire_carries_them_and_checks_their_type(scene):
    ds = load_hdb(scene.parent / "rm3.nc")
    data = to_wire(ds)
    assert data["attrs"]["warnings"] == list(hdb_warnings(ds))
    assert hdb_warnings(from_wire(data, "hdbs[0]")) == hdb_warnings(ds)
    data["attrs"]["warnings"] = "not a list"
    with pytest.raises(HDBError, match=r"hdbs\[1\].*attrs.warnings.*list of str"):
        from_wire(data, "hdbs[1]")


def _check_run(summary, out: Path) -> None:
    for notes in (summary.warnings, json.loads(netCDF4.Dataset(out).getncattr("warnings"))):
        assert _said(notes, READER_NOTE) == 1, notes
        assert _said(notes, SERVER_NOTE) == 1, notes
        assert not any("hydrolink-hdb-" in n for n in notes), notes   # not the server's temporary folder


def test_local_run_gets_them_in_setup_and_results(scene, tmp_path):
    from hydrolink.clients.run import run_scene_file
    out = tmp_path / "local.nc"
    _check_run(run_scene_file(scene, out, progress=False), out)


def test_remote_run_with_files_by_hash_gets_them_from_the_servers_child(scene, tmp_path):
    """A server on a socket (in a thread here: the parse runs in its child process all the same)."""
    from hydrolink.clients.run import run_scene_file
    from hydrolink.server.service.force_server import serve_in_thread
    out = tmp_path / "remote.nc"
    server, thread = serve_in_thread()
    try:
        summary = run_scene_file(scene, out, server=server.address, hdb_files=True, progress=False, timeout=REPLY_S)
    finally:
        server.stop()
        thread.join(5.0)
    assert any("rm3.nc (sha256 " in n for n in summary.warnings)   # the server read the files, not a map
    _check_run(summary, out)
