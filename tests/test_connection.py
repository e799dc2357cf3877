"""clients/lockstep/connection.py: ZeroMQ heartbeats and the link watch. A server killed (SIGKILL) while a
reply is pending is noticed within about a second (its host refuses the reconnects), not after
the receive timeout, with a line naming the server; a slow but live server is waited for. Lossy
links and outages: tests/test_remote.py (network namespaces)."""

from __future__ import annotations

import signal
import subprocess
import sys
import threading
import time

import numpy as np
import pytest
import zmq

from analytic_hdb import make_body_hdb
from conftest import EXIT_S, REPLY_S, body, regular_waves, scene_toml, stopped
from hydrolink.clients.lockstep.connection import ServerConnection
from hydrolink.protocol import codec

HYDROLINK = [sys.executable, "-m", "hydrolink.clients.cli"]
SCENE = scene_toml(dt=0.05, duration=100.0, waves=regular_waves(1.0, 6.0), hydro={"irf_duration": 4.0},
                   bodies=[body("float", hdb="float.nc", mass=3.0e5, center_of_mass=[0, 0, -1],
                                inertia=[1e7, 1e7, 2e7])])


def start_server() -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([*HYDROLINK, "serve", "--bind", "tcp://127.0.0.1:*"], stderr=subprocess.PIPE, text=True)
    line = proc.stderr.readline()
    if "listening on" not in line:   # not started as expected: ended, not left running
        stopped(proc)
        raise AssertionError(f"hydrolink serve printed {line!r}")
    return proc, line.split("listening on ")[1].split()[0]


@pytest.mark.timing
def test_a_killed_server_is_noticed_within_two_seconds():
    proc, address = start_server()
    try:
        with ServerConnection(address, timeout=REPLY_S) as conn:
            conn.hello(SCENE, {"float.nc": make_body_hdb()})
            z = np.zeros((1, 6))
            conn.step(0, 0.0, z, z)
            proc.send_signal(signal.SIGKILL)
            proc.wait(EXIT_S)
            t0 = time.monotonic()
            with pytest.raises(ConnectionError, match=f"the hydrolink server at {address} went away .* the server stopped"):
                conn.step(1, 0.05, z, z)
            assert time.monotonic() - t0 < 2.5          # the receive timeout is 60 s
    finally:
        proc.kill()
        proc.wait(EXIT_S)


def test_a_slow_live_server_is_waited_for():
    """A server that takes 3 s to answer (longer than the heartbeat timeout) is not cut off:
    ZeroMQ's I/O thread answers the heartbeats while the reply is being computed."""
    ctx = zmq.Context.instance()
    router = ctx.socket(zmq.ROUTER)
    router.setsockopt(zmq.LINGER, 0)
    from hydrolink.protocol.transport import apply_heartbeats
    apply_heartbeats(router)
    port = router.bind_to_random_port("tcp://127.0.0.1")

    def slow_server() -> None:
        ident, frame = router.recv_multipart()
        msg = codec.unpack(frame)
        time.sleep(3.0)
        router.send_multipart([ident, codec.pack(codec.message("pong", "srv-1", None, msg["msg_id"], sessions=0))])

    thread = threading.Thread(target=slow_server, daemon=True)
    thread.start()
    try:
        with ServerConnection(f"tcp://127.0.0.1:{port}", timeout=REPLY_S) as conn:
            t0 = time.monotonic()
            assert conn.ping()["type"] == "pong"
            assert time.monotonic() - t0 >= 2.9
    finally:
        thread.join(5)
        router.close(0)


def test_a_request_with_no_peer_to_send_to_times_out_instead_of_hanging():
    """A DEALER with no connected peer (nothing accepted it, or a CURVE server refused its
    handshake: test_deploy's plaintext client) blocks a plain send for ever; the request instead
    gives the missing reply's TimeoutError within its timeout."""
    address = "tcp://127.0.0.1:9"   # never connected below: the socket has no peer at all
    with ServerConnection(address, timeout=0.5) as conn:
        conn._sock.disconnect(address)
        t0 = time.monotonic()
        with pytest.raises(TimeoutError, match="no reply to 'ping'"):
            conn.ping()
        assert time.monotonic() - t0 < 30.0   # the timeout, not for ever (generous on a loaded machine)
