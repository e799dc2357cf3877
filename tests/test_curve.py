"""CURVE transport security (SPEC §1.1): `hydrolink keys new`, `hydrolink serve --curve-secret
--curve-clients`, clients with `--curve-server-key --curve-secret`. A separate server process on
loopback; an allowed client runs, an unknown key and a plaintext client are refused and logged."""

from __future__ import annotations

import subprocess
import sys
import time
from pathlib import Path

import pytest
import xarray as xr
import zmq

from hydrolink.clients.lockstep.connection import ServerConnection
from hydrolink.clients.run import run_scene_file
from hydrolink.protocol.security import ClientKeys

from conftest import EXIT_S, REPLY_S, cli_here, rm3_example_text, stopped

# One pytest-xdist worker runs this whole module (pyproject: --dist loadgroup): its module fixture (a CURVE
# server process) costs ~4 s, paid once per worker otherwise.
pytestmark = pytest.mark.xdist_group("curve")

REPO = Path(__file__).resolve().parents[1]
HYDROLINK = [sys.executable, "-m", "hydrolink.clients.cli"]


def keys_new(directory: Path, name: str) -> None:
    out = cli_here("keys", "new", str(directory), "--name", name, cwd=directory.parent)
    assert out.returncode == 0, out.stderr
    assert (directory / f"{name}.key").is_file() and (directory / f"{name}.key_secret").is_file()


@pytest.fixture(scope="module")
def curve_server(tmp_path_factory):
    tmp = tmp_path_factory.mktemp("curve")
    keys_new(tmp / "server", "server")
    keys_new(tmp / "client", "alice")
    keys_new(tmp / "stranger", "mallory")
    allowed = tmp / "allowed"
    allowed.mkdir()
    (allowed / "alice.key").write_bytes((tmp / "client" / "alice.key").read_bytes())
    log = tmp / "server.log"
    with open(log, "w") as err:
        proc = subprocess.Popen([*HYDROLINK, "serve", "--bind", "tcp://127.0.0.1:*", "--curve-secret",
                                 str(tmp / "server" / "server.key_secret"), "--curve-clients", str(allowed)],
                                stdout=subprocess.DEVNULL, stderr=err)
    try:
        address = None
        deadline = time.monotonic() + 120.0   # the server's start (imports, forkserver) under load: 10 s ran out
        while address is None and time.monotonic() < deadline and proc.poll() is None:
            text = log.read_text()
            if "listening on" in text:
                address = text.split("listening on ", 1)[1].split()[0]
            else:
                time.sleep(0.05)
        assert address and "(CURVE" in log.read_text(), log.read_text()
        yield {"address": address, "log": log, "dir": tmp}
    finally:
        stopped(proc)


def wait_for_log(log: Path, text: str, timeout: float = 5.0) -> str:
    end = time.monotonic() + timeout
    while time.monotonic() < end:
        content = log.read_text()
        if text in content:
            return content
        time.sleep(0.05)
    return log.read_text()


def test_keys_new_refuses_to_overwrite(tmp_path):
    keys_new(tmp_path, "a")
    out = cli_here("keys", "new", str(tmp_path), "--name", "a", cwd=tmp_path)
    assert out.returncode != 0 and "exists" in out.stderr
    assert oct((tmp_path / "a.key_secret").stat().st_mode & 0o777) == "0o600"


def test_authenticated_run(curve_server, reference_data, tmp_path):
    """An allowed key runs an RM3 scene end to end over the encrypted connection (CLI `hydrolink run`)."""
    text = rm3_example_text("rm3.toml")
    text = text.replace('"../data/rm3_wamit/rm3.1"', f'"{(reference_data / "rm3_wamit" / "rm3.1").as_posix()}"')
    text = text.replace("duration = 400.0", "duration = 0.8")
    scene = tmp_path / "rm3.toml"
    scene.write_text(text)
    d = curve_server["dir"]
    out = subprocess.run([*HYDROLINK, "run", str(scene), "-o", str(tmp_path / "out.nc"), "--server", curve_server["address"],
                          "--no-progress", "--curve-server-key", str(d / "server" / "server.key"),
                          "--curve-secret", str(d / "client" / "alice.key_secret")],
                         capture_output=True, text=True, timeout=EXIT_S)
    assert out.returncode == 0, out.stderr
    assert xr.load_dataset(tmp_path / "out.nc").sizes["time"] == 11
    # the same in-process, with the library API
    keys = ClientKeys.from_files(d / "server" / "server.key", d / "client" / "alice.key_secret")
    summary = run_scene_file(scene, tmp_path / "out2.nc", server=curve_server["address"], progress=False, curve=keys, timeout=REPLY_S)
    assert summary.steps == 10


def test_unknown_key_refused_and_logged(curve_server):
    d = curve_server["dir"]
    keys = ClientKeys.from_files(d / "server" / "server.key", d / "stranger" / "mallory.key_secret")
    with ServerConnection(curve_server["address"], timeout=1.5, curve=keys) as conn:
        with pytest.raises(TimeoutError, match="curve-clients"):
            conn.ping()
    public = (d / "stranger" / "mallory.key").read_text().split('public-key = "')[1].split('"')[0]
    log = wait_for_log(curve_server["log"], public)
    assert f"refused CURVE client key {public} from 127.0.0.1" in log, log


REFUSED = "refused a connection on tcp://127.0.0.1:"


def test_plaintext_client_refused_and_logged(curve_server):
    before = curve_server["log"].read_text().count(REFUSED)
    with ServerConnection(curve_server["address"], timeout=1.5) as conn:
        with pytest.raises(TimeoutError, match="refuses plaintext"):
            conn.ping()
    end = time.monotonic() + 5
    while curve_server["log"].read_text().count(REFUSED) == before and time.monotonic() < end:
        time.sleep(0.05)
    log = curve_server["log"].read_text()
    assert log.count(REFUSED) > before, log
    assert "not a CURVE client of this server (a plaintext client" in log


def test_wrong_server_key_gets_no_answer(curve_server):
    """A client that trusts another server key cannot talk to this server (nor it to the client)."""
    d = curve_server["dir"]
    keys = ClientKeys.from_files(d / "stranger" / "mallory.key", d / "client" / "alice.key_secret")
    with ServerConnection(curve_server["address"], timeout=1.5, curve=keys) as conn:
        with pytest.raises(TimeoutError):
            conn.ping()


def test_allowed_client_ping_and_plaintext_server_refused_by_curve_client(curve_server, tmp_path):
    d = curve_server["dir"]
    keys = ClientKeys.from_files(d / "server" / "server.key", d / "client" / "alice.key_secret")
    with ServerConnection(curve_server["address"], timeout=REPLY_S, curve=keys) as conn:
        assert conn.ping()["type"] == "pong"
    # a CURVE client does not talk to a plaintext server either
    ctx = zmq.Context.instance()
    rep = ctx.socket(zmq.ROUTER)
    port = rep.bind_to_random_port("tcp://127.0.0.1")
    try:
        with ServerConnection(f"tcp://127.0.0.1:{port}", timeout=0.5, curve=keys) as conn:
            with pytest.raises(TimeoutError):
                conn.ping()
        assert rep.poll(100) == 0
    finally:
        rep.close(0)


def test_serve_needs_both_curve_options(tmp_path):
    out = subprocess.run([*HYDROLINK, "serve", "--bind", "tcp://127.0.0.1:*", "--curve-secret", str(tmp_path / "x")],
                         capture_output=True, text=True, timeout=EXIT_S)
    assert out.returncode != 0 and "CURVE needs both" in out.stderr, out.stderr
    out = subprocess.run([*HYDROLINK, "serve", "--bind", "tcp://127.0.0.1:*", "--curve-secret", str(tmp_path / "x"),
                          "--curve-clients", str(tmp_path)], capture_output=True, text=True, timeout=EXIT_S)
    assert out.returncode != 0 and "no such key file" in out.stderr, out.stderr


def test_a_failed_curve_setup_releases_the_servers_context(tmp_path):
    """A ForceServer whose CURVE set-up fails after its socket is made (here libzmq refuses a
    malformed secret key) releases what it made, its socket, the authenticator and its own ZeroMQ
    context (an I/O thread and its descriptors), itself: not when the half-made server is
    collected, which a caller that keeps the error (its traceback holds the server) puts off."""
    import os

    import zmq.auth

    from hydrolink.protocol.security import ServerKeys, new_key_pair
    from hydrolink.server.service.force_server import ForceServer

    public, _ = zmq.auth.load_certificate(str(new_key_pair(tmp_path, "server")[0]))
    keys = ServerKeys(public=public, secret=b"not a z85 key", clients_dir=tmp_path, allowed=())

    def fds() -> int:
        return len(os.listdir("/proc/self/fd"))

    kept: list[BaseException] = []

    def refused() -> None:
        with pytest.raises(zmq.ZMQError) as info:
            ForceServer("tcp://127.0.0.1:*", curve=keys)
        kept.append(info.value)

    refused()                      # first use: whatever the imports open once
    before = fds()
    for _ in range(10):
        refused()
    left = fds() - before
    kept.clear()
    assert left <= 0, f"{left} descriptors left open by 10 servers whose CURVE set-up failed"


def test_serve_refuses_curve_options_before_loading_the_server(tmp_path):
    """``hydrolink serve``'s CURVE options are read and checked (protocol/security.py server_keys)
    before the server's modules are imported: a missing key file is said without them."""
    out = subprocess.run([sys.executable, "-c", "import sys\n"
                  "from hydrolink.clients.cli import main\n"
                  "try:\n    main()\nexcept SystemExit as e:\n    code = e.code\n"
                  "print('LOADED' if 'hydrolink.server.service.force_server' in sys.modules else 'NOT LOADED', code)\n",
                  "serve", "--bind", "tcp://127.0.0.1:*", "--curve-secret", str(tmp_path / "x"),
                  "--curve-clients", str(tmp_path)], capture_output=True, text=True, timeout=EXIT_S)
    assert "no such key file" in out.stderr, out.stderr
    assert "NOT LOADED" in out.stdout, out.stdout
