"""Files hydrolink writes get the user's umask: every file renamed into place after being written
under a temporary name (server/disk_cache.py ``write_atomic``: the sweep's sweep.nc and case files,
the HDB store, the HDB build and state-space fit caches) has mode 0666 less the umask, as any file
the user creates; a sweep's whole output folder likewise (files 0666, folders 0777, less the umask)."""

from __future__ import annotations

import os
import stat
from pathlib import Path

import numpy as np
import pytest
import xarray as xr
from click.testing import CliRunner

from conftest import SPHERE_WATER, linear_pto, regular_waves, scene_toml, sphere_body, sweep_toml, write_scene


@pytest.fixture(params=[0o027, 0o002, 0o077], ids=lambda m: f"umask-{m:03o}")
def umask(request):
    old = os.umask(request.param)
    try:
        yield request.param
    finally:
        os.umask(old)


def mode(path: Path) -> int:
    return stat.S_IMODE(path.stat().st_mode)


def test_write_atomic_gives_the_umask_mode(tmp_path, umask):
    """Written in place (bytes), written by a writer that deletes and recreates the file with its
    own mode 0600, written by xarray's NetCDF writer: each final file has 0666 & ~umask."""
    from hydrolink.server.disk_cache import write_atomic

    def recreate(tmp: str) -> None:
        os.unlink(tmp)
        os.close(os.open(tmp, os.O_WRONLY | os.O_CREAT | os.O_EXCL, 0o600))

    want = 0o666 & ~umask
    for name, write in (("bytes.bin", lambda tmp: Path(tmp).write_bytes(b"x")), ("recreated.bin", recreate),
                        ("data.nc", lambda tmp: xr.Dataset({"a": ("x", np.arange(3.0))}).to_netcdf(tmp))):
        write_atomic(tmp_path / "sub" / name, write)
        assert oct(mode(tmp_path / "sub" / name)) == oct(want), name
    assert [p.name for p in (tmp_path / "sub").iterdir() if p.name.endswith(".tmp")] == []


def test_hdb_store_entries_get_the_umask_mode(tmp_path, umask):
    from hydrolink.server.hdb.store import ContentStore
    store = ContentStore(tmp_path / "store")
    digest, new = store.put(b"an HDB's bytes")
    assert new and oct(mode(tmp_path / "store" / digest)) == oct(0o666 & ~umask)


def test_a_sweeps_outputs_get_the_umask_mode(tmp_path, sphere_path):
    """A one-case sweep run through the CLI (its LocalCluster's worker started under the umask):
    sweep.nc, cases.csv, the plots and the case's scene, file and record are 0640 under umask 027,
    the folders 0750 (on main sweep.nc's temporary-file mode 0600 could stay)."""
    old = os.umask(0o027)
    try:
        write_scene(tmp_path, scene_toml(
            dt=0.05, duration=30.0, water={**SPHERE_WATER, "gravity": 9.81}, waves=regular_waves(1.0, 6.0, ramp=5.0),
            bodies=[sphere_body(str(sphere_path), mass=261.724e3, dofs=["heave"])],
            ptos=[linear_pto("damper", "sphere", [0, 0, 0], "ground", [0, 0, -50], damping=2e5)]), "sphere.toml")
        sweep = tmp_path / "modes.toml"
        sweep.write_text(sweep_toml("sphere.toml", grid={"waves.period": [6.0, 7.0]}))
        out = tmp_path / "out"
        r = CliRunner().invoke(__import__("hydrolink.clients.cli", fromlist=["cli"]).cli,
                               ["sweep", str(sweep), "-o", str(out), "--workers", "1", "--no-progress"],
                               catch_exceptions=False)
    finally:
        os.umask(old)
    assert r.exit_code == 0, r.output
    files = sorted(p for p in out.rglob("*") if p.is_file())
    assert {p.name for p in files} >= {"sweep.nc", "cases.csv", "capture_width.png",
                                       "case-000_waves.period=6.nc", "case-000_waves.period=6.json",
                                       "case-000_waves.period=6.toml"}
    assert {p.relative_to(out).as_posix(): oct(mode(p)) for p in files} == \
        {p.relative_to(out).as_posix(): oct(0o640) for p in files}
    assert oct(mode(out / "cases")) == oct(0o750)
