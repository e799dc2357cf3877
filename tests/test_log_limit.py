"""server/service/log_limit.py: at most ``burst`` lines per kind and window, the rest counted and reported
with the next line of that kind after the window; and a real server flooded with bad requests
answers each of them while its log holds at most the burst of that error code."""

from __future__ import annotations

import logging

import zmq
from conftest import IDLE_S
from hydrolink.protocol import codec
from hydrolink.server.service.log_limit import LimitedLog
from hydrolink.server.service.force_server import serve_in_thread


def test_burst_per_kind_then_the_left_out_count(caplog):
    now = [0.0]
    limited = LimitedLog(logging.getLogger("test.log_limit"), burst=2, window=10.0, clock=lambda: now[0])
    with caplog.at_level(logging.INFO, logger="test.log_limit"):
        for i in range(5):
            limited.log("a", logging.INFO, "a %d", i)
        limited.log("b", logging.INFO, "b %d", 0)           # another kind: its own burst
        now[0] = 10.5
        limited.log("a", logging.INFO, "a %d", 5)
    assert [r.getMessage() for r in caplog.records] == [
        "a 0", "a 1", "b 0", "3 more like the next were not logged (at most 2 a 10 s window)", "a 5"]


def test_a_flood_of_bad_requests_is_answered_but_logged_within_the_burst(caplog):
    server, thread = serve_in_thread(session_timeout=IDLE_S)
    sock = zmq.Context.instance().socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.RCVTIMEO, 10_000)
    try:
        with caplog.at_level(logging.INFO, logger="hydrolink.server"):
            sock.connect(server.address)
            for i in range(300):
                sock.send(codec.pack({"v": 1, "msg_id": f"t-{i}", "type": "fly"}))
            replies = [codec.unpack(sock.recv()) for _ in range(300)]
        assert [(r["type"], r["code"], r["parent"]) for r in replies] == [("error", 3, f"t-{i}") for i in range(300)]
        lines = [r.getMessage() for r in caplog.records if r.getMessage().startswith("error 3 ")]
        assert 1 <= len(lines) <= 20          # LimitedLog's burst: not one line a request
    finally:
        sock.close(0)
        server.stop()
        thread.join(timeout=5)
