"""HDBs sent as their original files, by content (SPEC §5.1 "HDB file set", §5.8): the same forces
as the converted map, bit for bit, for the WAMIT, BEMIO and Capytaine data in examples/data; hash
references that hit and miss; bad sets, corrupted and oversized uploads answered with errors
naming the field while the server keeps serving."""

from __future__ import annotations

import hashlib

import numpy as np
import pytest
from conftest import IDLE_S, REPLY_S, SPHERE_WATER, regular_waves, rm3_float, rm3_spar, scene_toml, sphere_body

from hydrolink.clients.lockstep.connection import RemoteError, ServerConnection
from hydrolink.protocol.hdb.wire import HDBFiles
from hydrolink.server.hdb.io import file_set, load_hdb
from hydrolink.server.hdb.store import ContentStore
from hydrolink.server.service.force_server import serve_in_thread


@pytest.fixture
def store(tmp_path) -> ContentStore:
    return ContentStore(tmp_path / "store", disk_bytes=64 * 2**20)


@pytest.fixture
def server(store):
    srv, thread = serve_in_thread(session_timeout=IDLE_S, store=store)
    yield srv
    srv.stop()
    thread.join(5.0)


def rm3_scene(hdb: str) -> str:
    return scene_toml(dt=0.05, duration=5.0, waves=regular_waves(1.0, 8.0), hydro={"irf_duration": 10.0},
                      bodies=[rm3_float(hdb), rm3_spar(hdb)])


def sphere_scene(hdb: str) -> str:
    return scene_toml(dt=0.05, duration=5.0, water=SPHERE_WATER, waves=regular_waves(1.0, 6.0),
                      hydro={"irf_duration": 10.0}, bodies=[sphere_body(hdb, mass=2.6e5)])


CASES = {   # format: (file in examples/data, scene)
    "wamit": ("rm3_wamit/rm3.1", rm3_scene),
    "bemio": ("sphere_task10/sphere.h5", sphere_scene),
    "netcdf": ("rm3_capytaine/rm3_hydrodynamics.nc", rm3_scene),
}


def forces(address: str, scene: str, hdbs: dict, steps: int = 40) -> tuple[list[dict], list[str]]:
    """The replies to ``steps`` pseudo-random states, and the contents the hello uploaded."""
    rng = np.random.default_rng(7)
    with ServerConnection(address, timeout=REPLY_S) as conn:
        setup = conn.hello(scene, hdbs)
        n = len(setup.bodies)
        out = []
        for k in range(steps):
            r = conn.step(k, k * 0.05, 0.05 * rng.standard_normal((n, 6)), 0.3 * rng.standard_normal((n, 6)))
            out.append({f: np.array(r[f]) for f in ("excitation", "radiation", "hydrostatic")})
        return out, list(conn.uploads)


@pytest.mark.filterwarnings("ignore:.*rotational modes are taken about the origin")
@pytest.mark.parametrize("fmt", list(CASES))
def test_files_by_hash_give_the_map_forces_bit_for_bit(fmt, reference_data, server):
    rel, make_scene = CASES[fmt]
    path = reference_data / rel
    key = path.name
    scene = make_scene(key)
    files = file_set(path)
    assert files.format == fmt
    by_map, _ = forces(server.address, scene, {key: load_hdb(path)})
    first, uploaded = forces(server.address, scene, {key: files})
    assert sorted(uploaded) == sorted(files.contents())           # a miss: every content uploaded once
    again, uploaded_again = forces(server.address, scene, {key: files})
    assert uploaded_again == []                                   # a hit: nothing uploaded
    for a, b, c in zip(by_map, first, again):
        for f in a:
            assert np.array_equal(a[f], b[f]) and np.array_equal(a[f], c[f]), f
    assert np.abs(by_map[-1]["radiation"]).max() > 0


def test_wamit_file_set_holds_what_the_reader_reads(reference_data):
    files = file_set(reference_data / "rm3_wamit" / "rm3")
    assert [p.name for p in files.paths] == ["rm3.1", "rm3.3", "rm3.hst", "rm3.out", "rm3.cfg", "rm3.pot", "rm3.frc"]


def test_inline_bytes_fill_the_store(reference_data, server, store):
    path = reference_data / "sphere_task10" / "sphere.h5"
    data = path.read_bytes()
    digest = hashlib.sha256(data).hexdigest()
    with ServerConnection(server.address) as conn:
        inline = {"format": "bemio", "files": {"sphere.h5": data}}
        reply = conn.request("hello", role="multibody", scene=sphere_scene("sphere.h5"), hdbs={"sphere.h5": inline})
        assert reply["type"] == "welcome"
    assert store.get(digest) == data
    # a server started later on the same folder has it too (the disk tier)
    assert ContentStore(store.folder).get(digest) == data


def test_missing_hash_is_error_13_listing_it(reference_data, server):
    files = file_set(reference_data / "rm3_wamit" / "rm3.1")
    entry = files.entry()
    with ServerConnection(server.address) as conn:
        with pytest.raises(RemoteError) as err:
            conn.request("hello", role="multibody", scene=rm3_scene("rm3.1"), hdbs={"rm3.1": entry})
    e = err.value
    assert (e.code, e.name, e.field) == (13, "missing_content", 'hdbs["rm3.1"].files')
    assert sorted(e.extra["missing"]) == sorted(files.contents())
    assert "upload" in e.message


def test_bad_uploads_are_refused_and_the_server_keeps_serving(tmp_path, reference_data):
    small = ContentStore(tmp_path / "small", disk_bytes=100_000)
    srv, thread = serve_in_thread(store=small)
    try:
        with ServerConnection(srv.address) as conn:
            data = b"0123456789" * 100
            wrong = hashlib.sha256(data + b"x").hexdigest()
            with pytest.raises(RemoteError) as err:
                conn.request("upload", sha256=wrong, data=data)   # corrupted on the way, or a wrong hash
            assert (err.value.code, err.value.field) == (5, "sha256")
            assert not small.has(wrong) and not small.has(hashlib.sha256(data).hexdigest())
            big = bytes(200_000)
            with pytest.raises(RemoteError) as err:
                conn.request("upload", sha256=hashlib.sha256(big).hexdigest(), data=big)
            assert (err.value.code, err.value.field) == (5, "data") and "100000" in err.value.message
            for bad in ({"sha256": "ABC", "data": data}, {"sha256": hashlib.sha256(data).hexdigest(), "data": "text"}):
                with pytest.raises(RemoteError) as err:
                    conn.request("upload", **bad)
                assert err.value.code == 5
            ok = conn.request("upload", sha256=hashlib.sha256(data).hexdigest(), data=data)
            assert (ok["type"], ok["size"], ok["new"]) == ("uploaded", 1000, True)
            assert conn.request("upload", sha256=ok["sha256"], data=data)["new"] is False
            assert conn.request("ping")["type"] == "pong"
    finally:
        srv.stop()
        thread.join(5.0)


@pytest.mark.parametrize("entry, field, words", [
    ({"format": "fortran", "files": {"a.1": b"x"}}, 'hdbs["rm3.1"].format', "must be one of"),
    ({"format": "wamit", "files": {"../rm3.1": b"x"}}, 'hdbs["rm3.1"].files["../rm3.1"]', "file name"),
    ({"format": "wamit", "files": {".rm3.1": b"x"}}, 'hdbs["rm3.1"].files[".rm3.1"]', "file name"),
    ({"format": "wamit", "files": {"rm3.1": 12}}, 'hdbs["rm3.1"].files["rm3.1"]', "SHA-256"),
    ({"format": "wamit", "files": {"rm3.1": "f" * 63}}, 'hdbs["rm3.1"].files["rm3.1"]', "SHA-256"),
    ({"format": "wamit", "files": {"rm3.3": b"x"}}, 'hdbs["rm3.1"].files', "exactly one .1"),
    ({"format": "wamit", "files": {"rm3.1": b"x", "other.3": b"y"}}, 'hdbs["rm3.1"].files', "other.3"),
    ({"format": "bemio", "files": {"a.h5": b"x", "b.h5": b"y"}}, 'hdbs["rm3.1"].files', "exactly one"),
    ({"format": "bemio", "files": {"a.h5": b"x"}, "rho": 1025.0}, 'hdbs["rm3.1"].rho', "only for WAMIT"),
    ({"format": "wamit", "files": {}}, 'hdbs["rm3.1"].files', "1 to 16"),
])
def test_bad_file_sets_name_the_field(entry, field, words, server):
    with ServerConnection(server.address) as conn:
        with pytest.raises(RemoteError) as err:
            conn.request("hello", role="multibody", scene=rm3_scene("rm3.1"), hdbs={"rm3.1": entry})
        assert (err.value.code, err.value.field) == (5, field)
        assert words in err.value.message
        assert conn.request("ping")["type"] == "pong"


def test_corrupt_contents_are_bad_hdb_naming_the_file(reference_data, server, tmp_path):
    """Real file names with damaged contents: error 9 naming the file; nothing is written outside
    the server's temporary folder and the next good session works."""
    src = reference_data / "rm3_wamit"
    damaged = tmp_path / "rm3.1"
    damaged.write_bytes((src / "rm3.1").read_bytes()[:5000] + b"\nnot numbers at all\n")
    files = HDBFiles("wamit", (damaged, src / "rm3.3", src / "rm3.hst"))
    with ServerConnection(server.address) as conn:
        with pytest.raises(RemoteError) as err:
            conn.hello(rm3_scene("rm3.1"), {"rm3.1": files})
        assert err.value.code == 9 and err.value.field.startswith('hdbs["rm3.1"].files["rm3.1"]')
        assert "/tmp" not in err.value.message
    h5 = tmp_path / "sphere.h5"
    h5.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(300))
    with ServerConnection(server.address) as conn:
        with pytest.raises(RemoteError) as err:
            conn.hello(sphere_scene("sphere.h5"), {"sphere.h5": HDBFiles("bemio", (h5,))})
        assert err.value.code == 9 and err.value.field.startswith('hdbs["sphere.h5"].files["sphere.h5"]')
    good, _ = forces(server.address, rm3_scene("rm3.1"), {"rm3.1": file_set(src / "rm3.1")}, steps=2)
    assert np.isfinite(good[-1]["radiation"]).all()


@pytest.mark.filterwarnings("ignore:.*rotational modes are taken about the origin")
def test_map_and_file_set_mix_in_one_hello(reference_data, server):
    """Bodies from two HDBs, one sent as files and one as a map: the forces of the same scene sent
    as two maps, bit for bit."""
    rm3, nc = reference_data / "rm3_wamit" / "rm3.1", reference_data / "rm3_capytaine" / "rm3_hydrodynamics.nc"
    scene = scene_toml(dt=0.05, duration=5.0, waves=regular_waves(1.0, 8.0), hydro={"irf_duration": 10.0},
                       bodies=[rm3_float("rm3.1"), rm3_spar("rm3_hydrodynamics.nc")])
    mixed, _ = forces(server.address, scene, {"rm3.1": file_set(rm3), "rm3_hydrodynamics.nc": load_hdb(nc)}, 10)
    maps, _ = forces(server.address, scene, {"rm3.1": load_hdb(rm3), "rm3_hydrodynamics.nc": load_hdb(nc)}, 10)
    for a, b in zip(mixed, maps):
        for f in a:
            assert np.array_equal(a[f], b[f]), f


def test_strangers_files_are_named_errors_and_free_the_server(reference_data, server, tmp_path):
    """Issue 35 item 7: files that make a reader allocate terabytes or raise from deep inside its
    library are parsed in a child process (server/hdb/isolated.py): each is error 9 naming the
    file, never 99, and a valid hello is served right after each."""
    src = reference_data / "rm3_wamit"
    lines = (src / "rm3.1").read_text().splitlines(keepends=True)
    huge = tmp_path / "huge" / "rm3.1"      # one mode index 99999: a (n, 599994, 599994) table
    huge.parent.mkdir()
    huge.write_text("".join([lines[0], lines[1].replace("     1     1", " 99999     1", 1), *lines[2:]]))
    nc = tmp_path / "garbage.nc"
    nc.write_bytes(b"CDF\x01" + bytes(range(256)) * 40)         # a NetCDF-3 magic number, then noise
    h5 = tmp_path / "garbage.h5"
    h5.write_bytes(b"\x89HDF\r\n\x1a\n" + bytes(range(256)) * 40)
    cases = [("rm3.1", rm3_scene("rm3.1"), HDBFiles("wamit", (huge, src / "rm3.3", src / "rm3.hst", src / "rm3.out"))),
             ("garbage.nc", rm3_scene("garbage.nc"), HDBFiles("netcdf", (nc,))),
             ("garbage.h5", sphere_scene("garbage.h5"), HDBFiles("bemio", (h5,)))]
    for name, scene, files in cases:
        with ServerConnection(server.address, timeout=REPLY_S) as conn:
            with pytest.raises(RemoteError) as err:
                conn.hello(scene, {name: files})
        assert err.value.code == 9, (name, err.value.code, err.value.message)
        assert err.value.field.startswith(f'hdbs["{name}"].files["{name}"]'), err.value.field
        good, _ = forces(server.address, rm3_scene("rm3.1"), {"rm3.1": file_set(src / "rm3.1")}, steps=1)
        assert np.isfinite(good[-1]["excitation"]).all()


def test_a_parse_over_its_time_limit_is_stopped_and_named(reference_data, tmp_path):
    """A parse that takes longer than the reader's limit (here a valid HDB and a limit of 1 µs: the
    child cannot answer in time) is stopped, the child killed, and named; the same set parses at
    the default limit right after, to the same dataset as a read in this process."""
    from hydrolink.server.hdb.file_set import FileSetReader
    from hydrolink.server.hdb.isolated import ParseFailure, load_isolated
    from hydrolink.protocol.codec import ProtocolError

    src = reference_data / "sphere_task10" / "sphere.h5"
    store = ContentStore(tmp_path / "store", disk_bytes=16 * 2**20)
    entry = HDBFiles("bemio", (src,)).entry(inline=True)
    with pytest.raises(ProtocolError) as err:
        FileSetReader(store, parse_timeout=1e-6).read(entry, 'hdbs["sphere.h5"]', None)
    assert err.value.code == 9 and "longer than" in err.value.message and "sphere.h5" in err.value.message
    ds = FileSetReader(store).read(entry, 'hdbs["sphere.h5"]', None)
    direct = load_hdb(src)
    for var in ("added_mass", "radiation_damping", "excitation_force", "hydrostatic_stiffness"):
        np.testing.assert_array_equal(ds[var].values, direct[var].values)
    with pytest.raises(ParseFailure, match="longer than"):
        load_isolated(src, timeout=1e-6)
