"""Signed sessions (SPEC §3.3) from the command line: `hydrolink keys hmac` makes a key file,
`hydrolink serve --key-file` (or HYDROLINK_KEY_FILE) requires every request signed with it,
`hydrolink run --key-file` signs; unsigned and wrongly signed requests are refused with error 11
and logged by the server. Real processes on loopback."""

from __future__ import annotations

import os
import shutil
import stat
import subprocess
import sys
import time
from pathlib import Path

import pytest

from conftest import REPLY_S, SPHERE_WATER, cli_here, regular_waves, scene_toml, sphere_body, stopped, write_scene
from hydrolink.clients.lockstep.connection import RemoteError, ServerConnection
from hydrolink.protocol.security import CurveKeyError, read_hmac_key

HYDROLINK = [sys.executable, "-m", "hydrolink.clients.cli"]


def _cli(*args: str, cwd: Path, env: dict | None = None) -> subprocess.CompletedProcess:
    return subprocess.run([*HYDROLINK, *args], cwd=cwd, capture_output=True, text=True, timeout=120,
                          env={**os.environ, **(env or {})})


@pytest.fixture(scope="module")
def signed_server(tmp_path_factory):
    """`hydrolink serve` with a key file given by HYDROLINK_KEY_FILE; yields (address, key file, log file).
    One server for the module's tests (each serve process costs ~4.5 s of CPU to start): each test
    reads only the log lines written after it began."""
    tmp_path = tmp_path_factory.mktemp("signed")
    assert cli_here("keys", "hmac", "shared.key", cwd=tmp_path).returncode == 0
    log = tmp_path / "server.log"
    with open(log, "w") as fh:
        proc = subprocess.Popen([*HYDROLINK, "serve", "--bind", "tcp://127.0.0.1:*"], cwd=tmp_path, stderr=fh,
                                env={**os.environ, "HYDROLINK_KEY_FILE": str(tmp_path / "shared.key")})
    try:
        end = time.monotonic() + 30
        while "listening on" not in log.read_text() and time.monotonic() < end:
            time.sleep(0.05)
        first = log.read_text().splitlines()[0]
        assert "every message signed" in first, first
        yield first.split("listening on ")[1].split()[0], tmp_path / "shared.key", log
    finally:
        stopped(proc)


def test_key_file_is_new_private_and_never_overwritten(tmp_path: Path):
    r = cli_here("keys", "hmac", "k", cwd=tmp_path)
    assert r.returncode == 0, r.stderr
    assert stat.S_IMODE((tmp_path / "k").stat().st_mode) == 0o600
    assert len(read_hmac_key(tmp_path / "k")) == 32
    again = cli_here("keys", "hmac", "k", cwd=tmp_path)
    assert again.returncode != 0 and "exists" in again.stderr
    (tmp_path / "bad").write_text("not hex\n")
    with pytest.raises(CurveKeyError, match=r"bad: not a key file"):
        read_hmac_key(tmp_path / "bad")
    (tmp_path / "short").write_text("abcd\n")
    with pytest.raises(CurveKeyError, match=r"short: the key is 2 bytes; at least 32"):
        read_hmac_key(tmp_path / "short")


@pytest.mark.xdist_group("signed_server")   # one worker: the module's server started once
def test_signed_server_refuses_unsigned_and_wrong_key_and_logs(signed_server, tmp_path: Path):
    address, key_file, log = signed_server
    before = len(log.read_text())       # the server is the module's: this test's lines come after
    key = read_hmac_key(key_file)
    with ServerConnection(address, timeout=REPLY_S, key=key) as conn:
        assert conn.ping()["type"] == "pong"
    for wrong in (None, b"\x01" * 32):
        with ServerConnection(address, timeout=REPLY_S, key=wrong) as conn:
            with pytest.raises((RemoteError, ConnectionError)) as err:
                conn.ping()
            if isinstance(err.value, RemoteError):        # unsigned: the reply is signed, the client cannot check it
                assert err.value.code == 11
    end = time.monotonic() + 5
    while log.read_text()[before:].count("refused a request") < 2 and time.monotonic() < end:
        time.sleep(0.05)
    text = log.read_text()[before:]
    assert "refused a request: message is not signed" in text and "refused a request: signature does not match" in text


@pytest.mark.xdist_group("signed_server")   # one worker: the module's server started once
def test_run_signs_with_its_key_file(signed_server, tmp_path: Path, reference_data: Path):
    address, key_file, _ = signed_server
    shutil.copy(reference_data / "sphere_task10" / "sphere.h5", tmp_path / "sphere.h5")
    write_scene(tmp_path, scene_toml(dt=0.05, duration=2.0, progress=False, water=SPHERE_WATER,
                                     waves=regular_waves(1.0, 6.0), hydro={"irf_duration": 5.0},
                                     bodies=[sphere_body("sphere.h5", mass=261.8e3, dofs=["heave"])]))
    ok = _cli("run", "scene.toml", "-o", "out.nc", "--server", address, "--key-file", str(key_file), cwd=tmp_path)
    assert ok.returncode == 0 and "40 steps" in ok.stdout, ok.stderr
    unsigned = _cli("run", "scene.toml", "-o", "x.nc", "--server", address, cwd=tmp_path)
    assert unsigned.returncode != 0
    assert "bad_signature" in unsigned.stderr or "unreadable reply" in unsigned.stderr, unsigned.stderr


@pytest.mark.parametrize("content, why", [
    (os.urandom(256) + b"\xff", "not a key file: binary data"),
    (b"zz" * 40 + b"\n", "not a key file: not hex"),
    (b"ab" * 3000, "not a key file: more than 4096 bytes"),
    (b"ab" * 8 + b"\n", "the key is 8 bytes; at least 32"),
])
def test_serve_on_a_bad_key_file_says_why_in_one_line_and_exits_2(tmp_path: Path, content: bytes, why: str):
    """Issue 35 item 9 (`serve --key-file` on 256 random bytes: a 35-line traceback): one line naming
    the file and why, exit status 2, nothing bound."""
    bad = tmp_path / "bad.key"
    bad.write_bytes(content)
    done = _cli("serve", "--bind", "tcp://127.0.0.1:*", "--key-file", str(bad), cwd=tmp_path)
    assert done.returncode == 2, done
    assert done.stderr.strip().splitlines() == [f"Error: {bad}: {why}" + (
        " (one line of hex digits; make one with `hydrolink keys hmac FILE`)" if "not a key" in why else "")], done


def test_a_key_file_is_read_with_a_bound():
    """/dev/zero (endless) is refused after MAX_KEY_FILE_BYTES + 1 bytes, naming the file."""
    if not Path("/dev/zero").exists():
        pytest.skip("no /dev/zero")
    with pytest.raises(CurveKeyError, match=r"^/dev/zero: not a key file: more than 4096 bytes"):
        read_hmac_key("/dev/zero")
