"""The server's front ends per message (server/service/frontend.py, SPEC §1): the ZMTP reader on a
STREAM socket against libzmq's ROUTER, each answering an unmodified DEALER client in another process
with a step-sized request (383 bytes) and reply (589 bytes), lockstep, rounds alternated in one run.

Figures: the serving thread's CPU per message in ``recv`` and in ``send_multipart``
(time.thread_time: load-robust) and the client's round trip (wall, p50: load-sensitive).

    python bench/bench_frontend.py [--messages 5000] [--rounds 3] [--connect tcp://host:port]
"""

from __future__ import annotations

import argparse
import os
import statistics
import subprocess
import sys
import time

import zmq

from hydrolink.server.service import frontend

REQUEST, REPLY = 383, 589
LIMIT, FRAMES, BUDGET, RCVHWM = 64 * 2**20, 5, 128 * 2**20, 1000


def client(address: str, n: int) -> None:
    """Lockstep round trips from a DEALER, as hydrolink's clients send them; prints the wall p50 (µs)."""
    ctx = zmq.Context()
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.connect(address)
    msg = b"s" * REQUEST
    times = []
    for i in range(n + n // 10):   # the first tenth warms up
        t = time.perf_counter()
        sock.send(msg)
        sock.recv()
        if i >= n // 10:
            times.append(time.perf_counter() - t)
    print(f"{1e6 * statistics.median(times):.1f}", flush=True)
    ctx.destroy(0)


def serve(kind: str, n: int) -> tuple[float, float, float]:
    """(recv µs CPU, send µs CPU, client round trip p50 µs) for ``n`` messages through front ``kind``."""
    ctx = zmq.Context(io_threads=2)
    front = (frontend.StreamFront(ctx, LIMIT, FRAMES, BUDGET) if kind == "stream"
             else frontend.RouterFront(ctx, LIMIT, FRAMES, RCVHWM))
    front.set_timeout(1000)
    front.bind("tcp://127.0.0.1:*")
    proc = subprocess.Popen([sys.executable, __file__, "--client", front.address, "--messages", str(n)],
                            stdout=subprocess.PIPE, text=True)
    reply = b"r" * REPLY
    cpu_recv = cpu_send = 0.0
    served = 0
    try:
        total = n + n // 10
        while served < total:
            t0 = time.thread_time()
            try:
                frames, _, _ = front.recv()
            except zmq.Again:
                if proc.poll() is not None:
                    raise RuntimeError(f"the client ended after {served} messages") from None
                continue
            t1 = time.thread_time()
            front.send_multipart([frames[0], reply])
            t2 = time.thread_time()
            served += 1
            if served > n // 10:
                cpu_recv += t1 - t0
                cpu_send += t2 - t1
        rtt = float(proc.communicate(timeout=60)[0])
    finally:
        if proc.poll() is None:
            proc.kill()
        proc.wait()
        front.close()
        ctx.term()
    return 1e6 * cpu_recv / n, 1e6 * cpu_send / n, rtt


def main() -> None:
    p = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    p.add_argument("--messages", type=int, default=5000)
    p.add_argument("--rounds", type=int, default=3)
    p.add_argument("--client", metavar="ADDRESS", help=argparse.SUPPRESS)
    args = p.parse_args()
    if args.client:
        client(args.client, args.messages)
        return
    print(f"load {os.getloadavg()[0]:.1f}; {args.messages} messages a round")
    print("| front end | round | recv CPU / message | send CPU / message | round trip p50 |\n|---|---|---|---|---|")
    for r in range(args.rounds):
        for kind in ("stream", "router"):
            rc, sc, rtt = serve(kind, args.messages)
            print(f"| {kind} | {r + 1} | {rc:.1f} µs | {sc:.1f} µs | {rtt:.0f} µs |", flush=True)
    print(f"load {os.getloadavg()[0]:.1f}")


if __name__ == "__main__":
    main()
