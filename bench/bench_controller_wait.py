"""The controller's wait for its reply (clients/lockstep/direct_channel.py): a blocking receive
against spinning on non-blocking receives for up to N µs before blocking, on a Unix stream socket
(the direct channel on loopback, SPEC §5.7.5).

    python bench/bench_controller_wait.py [--work-us 300] [--spins 0 50 200 1000] [--round-trips 4000]

A forked "server" answers each 8-byte request after busy work of ``--work-us`` (the run's step,
which the controller waits for); the controller measures each round trip (perf_counter: the median
and 99th percentile over the work) and its own CPU per round trip (process_time). Each spin is run
twice, interleaved; the load average is printed beside each line.
"""

from __future__ import annotations

import argparse
import os
import socket
import time


def serve(sock: socket.socket, work_s: float) -> None:
    """Answer every request after ``work_s`` of busy work, until the peer closes."""
    while True:
        data = sock.recv(64)
        if not data:
            return
        end = time.perf_counter() + work_s
        while time.perf_counter() < end:
            pass
        sock.sendall(data)


def receive(sock: socket.socket, spin_s: float) -> bytes:
    """A reply: non-blocking receives for up to ``spin_s``, then a blocking one."""
    if spin_s > 0:
        end = time.perf_counter() + spin_s
        while time.perf_counter() <= end:
            try:
                return sock.recv(64, socket.MSG_DONTWAIT)
            except BlockingIOError:
                pass
    return sock.recv(64)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--work-us", type=float, default=300.0)
    ap.add_argument("--spins", type=float, nargs="+", default=[0.0, 50.0, 200.0, 1000.0])
    ap.add_argument("--round-trips", type=int, default=4000)
    args = ap.parse_args()
    ours, theirs = socket.socketpair(socket.AF_UNIX, socket.SOCK_STREAM)
    pid = os.fork()
    if pid == 0:
        ours.close()
        serve(theirs, args.work_us / 1e6)
        os._exit(0)
    theirs.close()
    n = args.round_trips
    try:
        for _ in range(2):
            for spin in args.spins:
                rtt = []
                c0 = time.process_time()
                for _ in range(n):
                    t0 = time.perf_counter()
                    ours.sendall(b"x" * 8)
                    receive(ours, spin / 1e6)
                    rtt.append(time.perf_counter() - t0)
                cpu = (time.process_time() - c0) / n
                rtt.sort()
                print(f"work {args.work_us:.0f} µs, spin {spin:5.0f} µs: round trip over the work p50 "
                      f"{1e6 * rtt[n // 2] - args.work_us:6.1f} µs, p99 {1e6 * rtt[int(n * 0.99)] - args.work_us:7.1f} µs; "
                      f"controller CPU {1e6 * cpu:6.1f} µs a round trip; load {os.getloadavg()[0]:.2f}", flush=True)
    finally:
        ours.close()
        os.waitpid(pid, 0)


if __name__ == "__main__":
    main()
