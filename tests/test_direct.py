"""The server's direct channel (server/service/direct.py, SPEC §5.7.5): tickets, framing and limits
of the listener (a ticket's length, the receive budget); a controller's requests over it handled as
on ZeroMQ; a multibody client of a server with its own loop stepping over it (revision 1.16),
bit-identical to ZeroMQ, and back on ZeroMQ when it breaks. A controller's whole run over it
(bit-identical to ZeroMQ) is in tests/test_controllers.py."""

from __future__ import annotations

import logging
import os
import socket
import stat
import struct
import time

import numpy as np
import pytest

from analytic_hdb import make_body_hdb
from conftest import body, regular_waves, scene_toml
from hydrolink.clients.lockstep.connection import ServerConnection
from hydrolink.protocol import codec
from hydrolink.server.service import direct as direct_module
from hydrolink.server.service.direct import MAX_LINKS, FREE_BYTES, TICKET_BYTES, TICKET_S, DirectError, DirectListener
from hydrolink.server.service.force_server import ForceServer, serve_in_thread
from hydrolink.server.service.zmtp import Budget

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
    request on an admitted one is answered there, as the socket would answer it; a server with a
    loop of its own (hydrolink serve) has one too (revision 1.16), its frames in the front end's
    receive budget."""
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
        assert threaded._direct is not None and threaded._direct.budget is threaded._sock.budget
    finally:
        threaded.close()


def test_a_link_closed_by_a_failed_write_and_pruned_between_turns_leaves_the_loops_poller():
    """A polled server's loop waits on one poller over its socket, the listener and the links,
    rebuilt when they change. A link closed by a failed write (its controller gone) and forgotten
    by :meth:`DirectListener.ready_now` (the server's ``_serve_ready`` before a request of the
    run's own) is a change too: the next wait is on the live descriptors only. Before, the poller
    kept the closed one, which poll reports at once (POLLNVAL, as POLLERR), so the loop's wait
    returned at once on every turn (a spin), on a descriptor number the process may give to
    another file."""
    srv = ForceServer("tcp://127.0.0.1:*", polled=True)
    try:
        direct = srv._direct
        client = connect(direct)
        client.sendall(frame(direct.offer("own")["ticket"].encode()))
        for _ in range(50):
            srv.serve_once()
            if direct.links and direct.links[0].own == "own":
                break
        (link,) = direct.links
        srv._direct_ready(0)   # the poller, built over the link
        client.close()
        assert not link.write(b"measurements")   # the controller is gone: the link closes
        srv._serve_ready()                       # and ready_now forgets it
        assert direct.links == []
        live = {srv._sock.socket, direct.fileno()}
        assert set(srv._direct_ready(50)) <= live
    finally:
        srv.close()


def test_controller_end_times_out_and_sees_a_closed_channel():
    """The controller's end of the channel (clients/control.py): shows its ticket first; a reply
    that does not come within the request's time is a TimeoutError after about that time (the
    kernel's receive timeout), a channel the server closed a ConnectionError: both OSErrors,
    on which the controller goes back to ZeroMQ."""
    import time

    from hydrolink.clients.lockstep.direct_channel import DirectChannel

    listener = DirectListener("ipc:///tmp/x", max_bytes=1000)
    try:
        offer = listener.offer("own")
        channel = DirectChannel.open("ipc:///tmp/x", offer)
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


def test_first_frame_longer_than_a_ticket_and_frames_past_the_budget_close_the_connection():
    """Before its ticket a connection may send TICKET_BYTES; a frame longer than FREE_BYTES holds
    the receive budget while it arrives (given back once whole, or when its connection closes) and
    one that would pass it closes its connection before its body is read."""
    budget = Budget(3 * FREE_BYTES)
    listener = DirectListener("ipc:///tmp/x", max_bytes=10 * FREE_BYTES, budget=budget)
    try:
        stranger = connect(listener)
        link = accepted(listener)
        stranger.sendall(HEADER.pack(TICKET_BYTES + 1))
        with pytest.raises(ConnectionError, match=f"first frame of {TICKET_BYTES + 1} bytes"):
            list(link.read())
        links = []
        for _ in range(2):
            client = connect(listener)
            link = accepted(listener)
            client.sendall(frame(listener.offer("own")["ticket"].encode()))
            assert listener.admit(link, next(link.read()))
            links.append((client, link))
        (c1, l1), (c2, l2) = links
        c1.sendall(HEADER.pack(2 * FREE_BYTES) + b"x" * 10)
        assert list(l1.read()) == [] and budget.held == 2 * FREE_BYTES   # arriving: held
        c2.sendall(HEADER.pack(2 * FREE_BYTES))
        with pytest.raises(ConnectionError, match="would pass the server's 0.1875 MiB"):
            list(l2.read())
        c1.sendall(b"x" * (2 * FREE_BYTES - 10))
        got = []
        while not got:
            got = list(l1.read())
        assert got == [b"x" * (2 * FREE_BYTES)] and budget.held == 0   # whole: given back
        c1.sendall(HEADER.pack(2 * FREE_BYTES))
        assert list(l1.read()) == [] and budget.held == 2 * FREE_BYTES
        l1.close()
        assert budget.held == 0                                          # closed: given back
    finally:
        listener.close()


def test_a_ticket_must_arrive_whole_in_time_and_a_full_listener_closes_the_oldest_without_one(monkeypatch, caplog):
    """A slow-loris sending its ticket a byte at a time is closed TICKET_S after its accept, its
    bytes still coming (the deadline covers the whole ticket); a connection that comes when
    MAX_LINKS are open closes the oldest one without a ticket, or itself when each open one has
    shown its ticket. Each closure is counted in the log (through its limiter)."""
    monkeypatch.setattr(direct_module, "MAX_LINKS", 3)
    listener = DirectListener("ipc:///tmp/x", max_bytes=1000)
    try:
        with caplog.at_level(logging.WARNING, logger="hydrolink.server.service.direct"):
            t0 = time.monotonic()
            loris = connect(listener)
            slow = accepted(listener)
            t1 = time.monotonic()
            ticket = listener.offer("own")["ticket"].encode()
            loris.sendall(HEADER.pack(len(ticket)))
            for i, byte in enumerate(ticket[:-1]):   # all but the last byte, each read on its own
                loris.sendall(bytes([byte]))
                assert list(slow.read()) == []
                assert not listener.expire(t0 + TICKET_S * i / len(ticket))   # before its deadline: kept
            assert listener.expire(t1 + TICKET_S) and slow.closed and listener.links == []
            assert loris.recv(10) == b""
            assert listener.closed_unticketed == 1
            idle = [connect(listener) for _ in range(2)]
            first, second = accepted(listener), accepted(listener)
            client = connect(listener)
            link = accepted(listener)   # the third: full now
            client.sendall(frame(ticket))
            assert listener.admit(link, next(link.read()))
            late = connect(listener)
            assert accepted(listener) is not None and first.closed and not second.closed   # the oldest made room
            assert idle[0].recv(10) == b""
            assert listener.closed_unticketed == 2
            for peer in (idle[1], late):   # the two without a ticket show theirs: every one open has one
                peer.sendall(frame(listener.offer("own")["ticket"].encode()))
            for waiting in listener.links[:]:
                if waiting.own is None:
                    assert listener.admit(waiting, next(waiting.read()))
            refused = connect(listener)
            assert listener.accept() is None and refused.recv(10) == b""   # full, each with its ticket
            assert len(listener.links) == 3 and not listener.expire(t1 + 10 * TICKET_S)   # ticketed: no deadline
        lines = [r.getMessage() for r in caplog.records]
        assert f"direct channel: 1 connection(s) closed (no ticket within {TICKET_S:g} s); 1 so far" in lines
        assert any("(3 open, the oldest without a ticket closed for a new one); 2 so far" in line for line in lines)
        assert "direct connection refused: 3 open already, each with its ticket" in lines
    finally:
        listener.close()


def test_idle_connections_holding_every_slot_are_closed_and_a_client_then_gets_the_channel(caplog):
    """A stranger opens MAX_LINKS connections to a served direct channel and sends nothing: the
    server closes each TICKET_S after its accept (the log counts them), and a client's hello after
    that takes the channel: its steps reach the loop without the ZeroMQ front end."""
    srv, thread = serve_in_thread("tcp://127.0.0.1:*")
    idle = []
    try:
        for _ in range(MAX_LINKS):
            sock = socket.socket(socket.AF_UNIX)
            sock.connect(srv._direct.offer_address["path"])   # blocking: waits while the listener's backlog is full
            sock.settimeout(30.0)
            idle.append(sock)
        caplog.set_level(logging.WARNING, logger="hydrolink.server.service.direct")
        assert all(sock.recv(10) == b"" for sock in idle)   # each closed by the server (30 s at most)
        taken = []
        recv = srv._sock.recv

        def counted():
            message = recv()
            taken.append(message[0])
            return message
        with ServerConnection(srv.address) as conn:
            conn.hello(SCENE, {"float.nc": make_body_hdb()})
            assert conn._direct is not None
            srv._sock.recv = counted
            for seq in range(10):
                conn.step(seq, 0.05 * seq, np.zeros((1, 6)), np.zeros((1, 6)))
            assert conn._direct is not None and taken == []   # ten steps, none through the front end
    finally:
        for sock in idle:
            sock.close()
        srv.stop()
        thread.join(10)
    assert srv._direct.closed_unticketed == MAX_LINKS   # the loop's counts read once it has ended
    closed = [r.getMessage() for r in caplog.records if "closed (no ticket within" in r.getMessage()]
    assert 0 < len(closed) <= 20 and closed[-1].endswith(f"; {MAX_LINKS} so far")   # the limiter's burst a minute


SCENE = scene_toml(dt=0.05, duration=100.0, waves=regular_waves(1.0, 6.0), hydro={"irf_duration": 4.0},
                   bodies=[body("float", hdb="float.nc", mass=3.0e5, center_of_mass=[0, 0, -1],
                                inertia=[1e7, 1e7, 2e7])])


def test_a_served_multibody_client_steps_over_the_direct_channel_and_falls_back_to_zeromq():
    """A server with a loop of its own (as ``hydrolink serve``) offers a multibody session the direct
    channel in its welcome (a Unix socket on loopback); the client steps over it, its DEALER idle,
    and gets the same forces bit for bit as a client on ZeroMQ; when the channel breaks, the step
    goes again over ZeroMQ and the run goes on. A paced session is offered none (its replies wait
    for their release on the loop)."""
    srv, thread = serve_in_thread("tcp://127.0.0.1:*")
    hdb = make_body_hdb()
    t = 0.05 * np.arange(40)
    states = [(np.outer(np.sin(0.7 * ti) * 0.1, np.ones(6)).reshape(1, 6), np.full((1, 6), 0.07 * np.cos(0.7 * ti)))
              for ti in t]
    try:
        with ServerConnection(srv.address) as direct, ServerConnection(srv.address, direct=False) as zmq_only:
            direct.hello(SCENE, {"float.nc": hdb})
            zmq_only.hello(SCENE, {"float.nc": hdb})
            assert direct._direct is not None and zmq_only._direct is None
            assert [link.own for link in srv._direct.links] == [direct.session]
            taken = []   # the messages the ZeroMQ front end hands the loop from now on
            recv = srv._sock.recv

            def counted():
                message = recv()   # zmq.Again (none within the timeout) is not counted
                taken.append(message[0])
                return message
            srv._sock.recv = counted
            for seq, (x, v) in enumerate(states):
                if seq == 20:   # the channel breaks: the step goes over ZeroMQ, and the rest
                    direct._direct.sock.shutdown(2)
                a = direct.step(seq, t[seq], x, v)
                b = zmq_only.step(seq, t[seq], x, v)
                for key in ("excitation", "radiation", "hydrostatic"):
                    assert np.array_equal(a[key], b[key]), (seq, key)
                assert (direct._direct is not None) == (seq < 20)
                if seq == 19:   # the direct client's 20 steps went over the channel: the front end took
                    assert len(taken) == 20   # the ZeroMQ client's only
            assert len(taken) == 20 + 2 * 20   # from the break on, both clients' steps
        with ServerConnection(srv.address) as paced:
            paced.hello(SCENE, {"float.nc": hdb}, realtime=1.0)
            assert paced._direct is None
    finally:
        srv.stop()
        thread.join(10)
