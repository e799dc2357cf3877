"""The polled server's direct channel to its controllers (server/service/direct.py, SPEC §5.7.5):
tickets, framing and limits of the listener; a controller's requests over it handled as on ZeroMQ.
A whole run over it (bit-identical to ZeroMQ) is in tests/test_controllers.py."""

from __future__ import annotations

import os
import socket
import stat
import struct

import pytest

from hydrolink.protocol import codec
from hydrolink.server.service.direct import DirectError, DirectListener
from hydrolink.server.service.force_server import ForceServer

HEADER = struct.Struct("<I")


def frame(data: bytes) -> bytes:
    return HEADER.pack(len(data)) + data


def connect(listener: DirectListener) -> socket.socket:
    where = listener.offer_address
    sock = socket.socket(socket.AF_UNIX) if "path" in where else socket.create_connection(("127.0.0.1", where["port"]))
    if "path" in where:
        sock.connect(where["path"])
    sock.settimeout(5.0)
    return sock


def accepted(listener: DirectListener):
    for _ in range(1000):
        link = listener.accept()
        if link is not None:
            link.sock.setblocking(True)   # the test reads what it sent at once
            return link
    raise AssertionError("no connection accepted")


@pytest.mark.parametrize("endpoint", ["tcp://0.0.0.0:5555", "tcp://127.0.0.1:5555", "ipc:///tmp/whatever.sock"])
def test_ticket_binds_a_connection_and_frames_are_reassembled(endpoint):
    """A connection showing an offered ticket is bound to the controller it was offered to (once:
    a ticket is one use); frames split over reads, or several in one, come out whole and in order."""
    listener = DirectListener(endpoint, max_bytes=1000)
    try:
        offer = listener.offer("own-id")
        assert set(offer) == {"ticket", "port" if "0.0.0.0" in endpoint else "path"}   # loopback: a Unix socket
        if "path" in offer:   # a private folder: this user only
            assert stat.S_IMODE(os.stat(os.path.dirname(offer["path"])).st_mode) == 0o700
        client = connect(listener)
        link = accepted(listener)
        client.sendall(frame(offer["ticket"].encode()))
        (ticket,) = list(link.read())
        assert listener.admit(link, ticket) and link.own == "own-id"
        assert not listener.admit(link, ticket)          # used: a second connection with it is refused
        data = frame(b"a" * 10) + frame(b"") + frame(b"b" * 300)
        client.sendall(data[:7])
        assert list(link.read()) == []                   # a header and part of a body: nothing yet
        client.sendall(data[7:])
        got = []
        while len(got) < 3:
            got += list(link.read())
        assert got == [b"a" * 10, b"", b"b" * 300]
        link.write(b"reply")
        assert client.recv(100) == frame(b"reply")
        client.close()
        with pytest.raises(ConnectionError, match="closed"):
            list(link.read())
    finally:
        listener.close()
    if endpoint.startswith("ipc"):
        assert not os.path.exists(os.path.dirname(offer["path"]))   # the folder goes with the listener


def test_oversize_frame_and_foreign_ticket_are_refused():
    """A frame whose length passes the message limit breaks the connection before its body is
    read; a ticket never offered is not admitted; an inproc endpoint has no direct channel."""
    listener = DirectListener("ipc:///tmp/x", max_bytes=64)
    try:
        client = connect(listener)
        link = accepted(listener)
        assert not listener.admit(link, b"a-ticket-nobody-offered")
        client.sendall(HEADER.pack(65))
        with pytest.raises(ConnectionError, match="65 bytes; at most 64"):
            list(link.read())
    finally:
        listener.close()
    with pytest.raises(DirectError, match="tcp:// and ipc://"):
        DirectListener("inproc://x", 64)


def test_polled_server_answers_over_its_direct_channel_and_drops_a_wrong_ticket():
    """A polled server offers the channel in a controller's welcome (here: its listener, as
    _controller_hello does); a connection with a foreign ticket is closed and the server goes on; a
    request on an admitted one is answered there, as the socket would answer it; a non-polled
    server offers none."""
    srv = ForceServer("tcp://127.0.0.1:*", polled=True)
    try:
        direct = srv._direct
        assert direct is not None
        stranger = connect(direct)
        stranger.sendall(frame(b"x" * 43))
        client = connect(direct)
        client.sendall(frame(direct.offer("own")["ticket"].encode()))
        client.sendall(frame(codec.pack(codec.message("ping", "k1", None))))
        srv._serve_ready()
        for _ in range(50):
            srv.serve_once()
            if not any(link.own is None for link in direct.links):
                break
        assert stranger.recv(10) == b""                  # closed: not an offered ticket
        size = HEADER.unpack(client.recv(4))[0]
        reply = codec.unpack(client.recv(size))
        assert (reply["type"], reply["parent"]) == ("pong", "k1")
    finally:
        srv.close()
    assert not direct.links and direct.sock.fileno() < 0   # closed with the server
    threaded = ForceServer("tcp://127.0.0.1:*")
    try:
        assert threaded._direct is None
    finally:
        threaded.close()


def test_controller_end_times_out_and_sees_a_closed_channel():
    """The controller's end of the channel (clients/control.py): shows its ticket first; a reply
    that does not come within the request's time is a TimeoutError after about that time (the
    kernel's receive timeout), a channel the server closed a ConnectionError: both OSErrors,
    on which the controller goes back to ZeroMQ."""
    import time

    from hydrolink.clients.control import _DirectChannel

    listener = DirectListener("ipc:///tmp/x", max_bytes=1000)
    try:
        offer = listener.offer("own")
        channel = _DirectChannel.open("ipc:///tmp/x", offer)
        link = accepted(listener)
        assert list(link.read()) == [offer["ticket"].encode()]
        t0 = time.monotonic()
        with pytest.raises(TimeoutError):
            channel.request(codec.pack(codec.message("ping", "k1", "own")), "k1", 0.3, None)
        assert 0.25 < time.monotonic() - t0 < 3.0
        link.close()
        with pytest.raises(ConnectionError):   # the send's broken pipe, or the receive's end of stream
            channel.request(codec.pack(codec.message("ping", "k2", "own")), "k2", 5.0, None)
        channel.close()
    finally:
        listener.close()
