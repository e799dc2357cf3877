"""The server's ZMTP front end (server/service/frontend.py, zmtp.py; SPEC §1): unmodified pyzmq
DEALER and REQ peers, and raw TCP peers writing ZMTP 3.1 by hand from RFC 23 / RFC 37 (the framing
written out below, independently of the server's encoder), to cut frames across TCP segments,
break the greeting, or leave in the middle of a message."""

from __future__ import annotations

import socket
import struct
import time

import pytest
import zmq

from hydrolink.protocol import codec, transport
from hydrolink.server.service.force_server import serve_in_thread
from hydrolink.server.service.frontend import StreamFront

LIMIT = 256 * 2**10
WAIT_MS = 5000


def ping(msg_id="p-1", pad: int = 0) -> bytes:
    msg = codec.message("ping", msg_id, None)
    if pad:
        msg["pad"] = bytes(pad)
    return codec.pack(msg)


@pytest.fixture(scope="module")
def server():
    srv, thread = serve_in_thread(max_message_bytes=LIMIT)
    yield srv
    srv.stop()
    thread.join(5)
    assert not thread.is_alive()


@pytest.fixture
def ctx():
    c = zmq.Context()
    yield c
    c.destroy(linger=0)


def connect(ctx: zmq.Context, address: str, kind: int = zmq.DEALER) -> zmq.Socket:
    sock = ctx.socket(kind)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(address)
    return sock


def reply_of(sock: zmq.Socket) -> list[bytes]:
    assert sock.poll(WAIT_MS), f"no reply within {WAIT_MS} ms"
    return sock.recv_multipart()


# ------------------------------------------------------------------ a raw ZMTP peer (RFC 23 / RFC 37)

def frame(body: bytes, more: bool = False, command: bool = False) -> bytes:
    """One ZMTP frame: flags (bit 0 MORE, bit 1 LONG, bit 2 COMMAND), a 1- or 8-byte size, the body."""
    flags = (1 if more else 0) | (4 if command else 0)
    if len(body) > 255:
        return struct.pack(">BQ", flags | 2, len(body)) + body
    return struct.pack(">BB", flags, len(body)) + body


def cmd(name: bytes, data: bytes = b"") -> bytes:
    return frame(bytes([len(name)]) + name + data, command=True)


class RawPeer:
    """A TCP connection speaking ZMTP 3.1, NULL mechanism, as a DEALER, written by hand."""

    def __init__(self, address: str, handshake: bool = True, minor: int = 1):
        """``minor``: the ZMTP 3 minor version it announces (0: libzmq 4.1, no heartbeats)."""
        host, port = address.removeprefix("tcp://").rsplit(":", 1)
        self.sock = socket.create_connection((host, int(port)), timeout=WAIT_MS / 1000)
        self.sock.setsockopt(socket.IPPROTO_TCP, socket.TCP_NODELAY, 1)
        self.buf = b""
        if handshake:
            self.send(b"\xff" + b"\0" * 8 + b"\x7f\x03" + bytes([minor]) + b"NULL" + b"\0" * 16 + b"\0" * 32)
            self.send(cmd(b"READY", b"\x0bSocket-Type" + struct.pack(">I", 6) + b"DEALER"))
            greeting = self.read(64)
            assert greeting[0] == 0xFF and greeting[9] == 0x7F and greeting[10] == 3
            assert greeting[12:16] == b"NULL"
            name, data = self.command()
            assert name == b"READY" and b"Socket-Type\x00\x00\x00\x06ROUTER" in data

    def send(self, data: bytes) -> None:
        self.sock.sendall(data)

    def read(self, n: int) -> bytes:
        while len(self.buf) < n:
            chunk = self.sock.recv(65536)
            if not chunk:
                raise ConnectionError("closed by the server")
            self.buf += chunk
        out, self.buf = self.buf[:n], self.buf[n:]
        return out

    def next_frame(self) -> tuple[int, bytes]:
        flags = self.read(1)[0]
        size = struct.unpack(">Q", self.read(8))[0] if flags & 2 else self.read(1)[0]
        return flags, self.read(size)

    def command(self) -> tuple[bytes, bytes]:
        flags, body = self.next_frame()
        assert flags & 4, "a message where a command was due"
        return body[1:1 + body[0]], body[1 + body[0]:]

    def message(self) -> list[bytes]:
        """The next message's frames (commands before it skipped)."""
        frames: list[bytes] = []
        while True:
            flags, body = self.next_frame()
            if flags & 4:
                continue
            frames.append(body)
            if not flags & 1:
                return frames

    def closed_by_server(self) -> bool:
        try:
            while self.sock.recv(65536):
                pass
            return True
        except ConnectionResetError:   # closed with bytes of ours unread
            return True
        except TimeoutError:
            return False

    def close(self) -> None:
        self.sock.close()


def held_bytes(srv) -> int:
    return srv._sock.budget.held   # the front end's count of bytes kept of messages arriving


def settle(condition, seconds: float = 5.0) -> bool:
    deadline = time.monotonic() + seconds
    while not condition():
        if time.monotonic() > deadline:
            return False
        time.sleep(0.01)
    return True


# ------------------------------------------------------------------ tests

def test_unmodified_dealer_and_req_peers_are_served(server, ctx):
    """pyzmq's DEALER (with the heartbeats hydrolink's clients set) and REQ: the handshake, a reply
    to each; a DEALER's routing frames come back verbatim in front of the reply (SPEC §1)."""
    dealer = connect(ctx, server.address)
    transport.apply_heartbeats(dealer)
    dealer.send(ping("d-1"))
    reply = codec.unpack(reply_of(dealer)[-1])
    assert (reply["type"], reply["parent"]) == ("pong", "d-1")
    req = connect(ctx, server.address, zmq.REQ)
    req.send(ping("r-1"))
    assert codec.unpack(req.recv())["parent"] == "r-1"
    dealer.send_multipart([b"route-a", b"", ping("d-2", pad=50_000)])   # a long frame, several TCP reads
    frames = reply_of(dealer)
    assert frames[:2] == [b"route-a", b""] and codec.unpack(frames[2])["parent"] == "d-2"


def test_a_message_over_the_limit_by_many_small_frames_is_refused_and_the_next_served(server, ctx):
    """15000 frames of 20 bytes (each tiny, 300 kB together, over the 256 KiB limit): error 1 naming
    the limit, sent to the connection alone; nothing of it kept; the next message answered."""
    sock = connect(ctx, server.address)
    sock.send_multipart([b"x" * 20] * 15_000 + [ping("big")])
    reply = codec.unpack(reply_of(sock)[-1])
    assert (reply["code"], reply["limit"], reply["maximum"], reply["parent"]) == (1, "message_bytes", LIMIT, None)
    assert held_bytes(server) == 0
    sock.send(ping("after"))
    assert codec.unpack(reply_of(sock)[-1])["parent"] == "after"
    sock.send_multipart([b"r"] * 9 + [ping("routes")])   # under the limit in bytes, over it in frames
    reply = codec.unpack(reply_of(sock)[-1])
    assert (reply["code"], reply["limit"]) == (1, "routing_frames")


def test_frames_cut_across_tcp_segments_make_the_same_message(server):
    """A raw peer writes its greeting, READY and a message one byte at a time (TCP_NODELAY, a pause
    between writes: the server reads them in many pieces, long frame headers cut too); the message
    is answered as if sent at once, and so is the next one sent in one write."""
    peer = RawPeer(server.address, handshake=False)
    try:
        wire = (b"\xff" + b"\0" * 8 + b"\x7f\x03\x01" + b"NULL" + b"\0" * 48
                + cmd(b"READY", b"\x0bSocket-Type" + struct.pack(">I", 6) + b"DEALER")
                + frame(b"hop", more=True) + frame(ping("slow", pad=400)))
        for i in range(0, len(wire), 7):
            peer.send(wire[i:i + 7])
            time.sleep(0.002)
        assert peer.read(64)[:11] == b"\xff" + b"\0" * 8 + b"\x7f\x03" and peer.command()[0] == b"READY"
        frames = peer.message()
        assert frames[0] == b"hop" and codec.unpack(frames[1])["parent"] == "slow"
        peer.send(frame(ping("fast")))
        assert codec.unpack(peer.message()[0])["parent"] == "fast"
    finally:
        peer.close()


def test_ping_is_answered_with_pong_and_a_silent_peer_is_pinged(server):
    """ZMTP 3.1 heartbeats: a PING's context comes back in a PONG; a peer silent for a second is
    sent a PING by the server."""
    peer = RawPeer(server.address)
    try:
        peer.send(cmd(b"PING", b"\x00\x64ctx-1"))
        assert peer.command() == (b"PONG", b"ctx-1")
        name, data = peer.command()   # within the read timeout: after about a second of silence
        assert name == b"PING" and struct.unpack(">H", data[:2])[0] == int(transport.LINK_TIMEOUT_S * 10)
    finally:
        peer.close()


def test_a_peer_silent_past_the_ttl_of_its_ping_is_dropped(server):
    """RFC 37: a PING's TTL (here 0.5 s) asks the receiver to close the connection after that long
    without traffic. The peer goes silent after its PING: the server closes it with an ERROR naming
    the TTL, before its own PING to a peer silent for a second (the peer's TTL is shorter than the
    server's link timeout, so it decides)."""
    peer = RawPeer(server.address)
    try:
        peer.send(cmd(b"PING", struct.pack(">H", 5) + b"ttl"))
        assert peer.command() == (b"PONG", b"ttl")
        name, data = peer.command()
        assert name == b"ERROR" and b"TTL" in data[1:1 + data[0]]
        assert peer.closed_by_server()
    finally:
        peer.close()


def test_a_zmtp_3_0_peer_gets_no_ping_and_keepalive_watches_its_connection(server):
    """A ZMTP 3.0 peer (libzmq 4.1: no PING or PONG) silent for over a second is sent no PING, which
    it could not parse (the server's next frame to it is its reply), and is not dropped for a
    silence it cannot break; the kernel's keepalive timer is armed on the server's side of its
    connection instead (read from the kernel with ``ss``), so a gone host is still found."""
    import shutil
    import subprocess

    peer = RawPeer(server.address, minor=0)
    try:
        time.sleep(1.5)   # past the second of silence after which a 3.1 peer is sent a PING
        peer.send(frame(ping("quiet")))
        flags, body = peer.next_frame()
        assert not flags & 4 and codec.unpack(body)["parent"] == "quiet"
        if shutil.which("ss") is None:
            pytest.skip("no `ss` (iproute2) to read the connection's timers")
        port = peer.sock.getsockname()[1]
        timers = []   # once the reply is acknowledged, the retransmission timer gives way to keepalive's

        def keepalive() -> bool:
            timers.append(subprocess.run(["ss", "-tnoH", "state", "established", f"( dport = :{port} )"],
                                         capture_output=True, text=True, timeout=10).stdout)
            return "timer:(keepalive" in timers[-1]

        assert settle(keepalive), timers[-1]
    finally:
        peer.close()


@pytest.mark.parametrize("greeting", [
    b"GET / HTTP/1.1\r\nHost: x\r\n\r\n",                                   # not ZMTP
    b"\xff" + b"\0" * 8 + b"\x7f\x02\x00" + b"\0" * 52,                      # ZMTP 2.0
    b"\xff" + b"\0" * 8 + b"\x7f\x03\x01" + b"CURVE" + b"\0" * 47,           # another mechanism
    b"\xff" + b"\0" * 8 + b"\x7f\x03\x01" + b"NULL" + b"\0" * 48
    + cmd(b"READY", b"\x0bSocket-Type" + struct.pack(">I", 3) + b"PUB"),   # a socket type it does not serve
    b"\xff" + b"\0" * 8 + b"\x7f\x03\x01" + b"NULL" + b"\0" * 48 + frame(b"data before READY"),
])
def test_a_bad_greeting_or_handshake_closes_that_connection_and_the_server_serves_on(server, ctx, greeting):
    peer = RawPeer(server.address, handshake=False)
    try:
        peer.send(greeting)
        assert peer.closed_by_server()
    finally:
        peer.close()
    sock = connect(ctx, server.address)
    sock.send(ping("next"))
    assert codec.unpack(reply_of(sock)[-1])["parent"] == "next"


def test_a_peer_leaving_mid_message_frees_what_was_kept(server, ctx):
    """A raw peer sends 150 kB of a 200 kB frame and closes: the server holds the 150 kB while the
    frame arrives and nothing once the connection is gone."""
    peer = RawPeer(server.address)
    peer.send(struct.pack(">BQ", 2, 200_000) + bytes(150_000))
    assert settle(lambda: held_bytes(server) == 150_000)
    peer.close()
    assert settle(lambda: held_bytes(server) == 0 and len(server._sock._peers) <= 1)
    sock = connect(ctx, server.address)
    sock.send(ping("next"))
    assert codec.unpack(reply_of(sock)[-1])["parent"] == "next"


def test_messages_arriving_over_the_budget_are_refused_for_memory(ctx):
    """Raw peers against a front end whose budget is 210 kB: one is 150 kB into a 200 kB frame,
    another 120 kB into one: the second's bytes pass the budget, it keeps nothing more and, once
    its message has arrived, is refused for memory (error 14 ``memory``, ReceiveMemoryError); a
    small message (a step's size) from a third is delivered meanwhile; the first is delivered
    whole; the budget is free afterwards."""
    import threading

    front = StreamFront(ctx, 2**20, 9, budget=210_000)
    front.bind("tcp://127.0.0.1:*")
    front.set_timeout(20)
    got: list = []
    done = threading.Event()

    def pump():   # the front end reads while the peers write (their handshakes need its answers)
        while not done.is_set():
            try:
                got.append(front.recv())
            except zmq.Again:
                pass
            except transport.ReceiveMemoryError as exc:
                got.append(("memory", exc.identity))

    thread = threading.Thread(target=pump)
    thread.start()
    peers: list[RawPeer] = []
    try:
        a, b, c = (RawPeer(front.address) for _ in range(3))
        peers += [a, b, c]
        a.send(struct.pack(">BQ", 2, 200_000) + bytes(150_000))
        assert settle(lambda: front.budget.held == 150_000)
        b.send(struct.pack(">BQ", 2, 200_000) + bytes(120_000))
        assert settle(lambda: any(p.reader._msg.refused == "memory" for p in front._peers.values()))
        assert front.budget.held == 150_000   # b's bytes given back when they passed the budget
        c.send(frame(b"s" * 1000))
        assert settle(lambda: len(got) == 1) and got[0][0][1] == b"s" * 1000
        a.send(bytes(50_000))
        b.send(bytes(80_000))
        assert settle(lambda: len(got) == 3)
        whole = next(g for g in got[1:] if g[0] != "memory")
        refused = next(g for g in got[1:] if g[0] == "memory")
        assert len(whole[0]) == 2 and len(whole[0][1]) == 200_000 and whole[1] == 200_000 + len(whole[0][0])
        assert refused[1] not in (whole[0][0], got[0][0][0]) and len(refused[1]) == 5
        assert front.budget.held == 0
    finally:
        done.set()
        thread.join()
        for p in peers:
            p.close()
        front.close()


def test_whole_messages_in_one_read_are_read_as_when_they_come_byte_by_byte():
    """The reader's one-pass path (whole messages of small frames in one read) against its
    frame-by-frame path: the same reads fed at once and one byte at a time give the messages that
    were written, frames, sizes and counts — also where a read mixes them with a PING, a long
    (8-byte size) frame, a message of over 64 KiB or one over the frame limit."""
    from hydrolink.server.service import zmtp

    messages = [[b"hop", b"", b"s" * 383], [b""], [b"x" * 300], [b"y" * 70_000], [b"f"] * 5, [b"r", b"z" * 1000]]
    wire = b"".join(frame(f, more=i < len(m) - 1) for m in messages[:3] for i, f in enumerate(m))
    mixed = (cmd(b"PING", b"\x00\x0actx") + wire
             + b"".join(frame(f, more=i < len(m) - 1) for m in messages[3:] for i, f in enumerate(m)))
    handshake = (b"\xff" + b"\0" * 8 + b"\x7f\x03\x01" + b"NULL" + b"\0" * 48
                 + cmd(b"READY", b"\x0bSocket-Type" + struct.pack(">I", 6) + b"DEALER"))

    def read(chunks):
        reader = zmtp.Reader(2**20, 4, zmtp.Budget(2**20))
        got = reader.feed(handshake)
        for chunk in chunks:
            got += reader.feed(chunk)
        return [(m.frames, m.size, m.count, m.refused) for m in got], reader.replies

    expected = [(m, sum(map(len, m)), len(m), None) for m in messages]
    expected[4] = ([], 5, 5, "limit")   # five frames: over the reader's four
    for data in (wire, mixed):
        whole, pongs = read([data])
        assert whole == expected[:len(whole)] and len(whole) == (3 if data is wire else 6)
        assert read([data[i:i + 1] for i in range(len(data))]) == (whole, pongs)
        assert pongs == ([] if data is wire else [cmd(b"PONG", b"ctx")])
