"""A shared server under the receive-path attacks of issue 35 (items 1-3), at full size.

Against a separately started ``hydrolink serve`` (default 64 MiB message limit, ``--max-sessions
1``) over loopback TCP: a victim session (the IEA Task-10 sphere, heave, dt = 0.05 s) steps in
lockstep in a process of its own and every round trip is timed; while it steps, one attack:

1. ``frames``: one multipart message of 47 frames x 32 MiB (each under the limit, 1.5 GiB together);
2. ``lists``: a 60 MiB ``ping`` holding 63 million empty lists in one list (the issue's form), and
   ``nested``: 63 lists of a million empty lists each (each list under msgpack's length bound);
   ``deep``: 20 million 2-character strings in lists nested 1000 deep (57 MiB: no list complete
   before the innermost, so a decoder's completion hooks see none of them until the end);
3. ``hellos``: 100 hellos padded to 30 MiB, from 100 connections at once (the victim holds the one
   session), and ``pipelined``: the same 100 on one connection without waiting.

Each attack gets a fresh server. Printed per attack: the replies the attacker got (type and code),
the server's peak RSS growth over the attack (VmHWM, reset through /proc/PID/clear_refs before it;
the goal: <= 256 MB), the victim's step latency during the attack (p50 / p99 / max, the goal: max
<= 100 ms), and whether the server still answers. ``--tree DIR`` runs the server from another
source tree (a directory holding ``hydrolink/``, e.g. ``git archive`` of an older commit), for a
before/after in the same run. Messages are sent zero-copy from one buffer: the attacker costs this
process little.

    python bench/bench_attacks.py [--only frames,lists,nested,deep,hellos,pipelined] [--tree DIR] [--scale 1]
"""

from __future__ import annotations

import argparse
import multiprocessing
import os
import re
import subprocess
import sys
import threading
import time
from pathlib import Path

import numpy as np
import zmq

from hydrolink.clients.lockstep.connection import ServerConnection
from hydrolink.clients.scene_inputs import load_scene_hdbs
from hydrolink.protocol import codec
from hydrolink.protocol.scene import parse_scene

from bench_setup_isolation import scene   # bench/ is on the path

REPO = Path(__file__).resolve().parents[1]
MiB = 2**20
ATTACKS = ("frames", "lists", "nested", "deep", "hellos", "pipelined")
SCENE = scene(0.05, 1e5)   # the heave-only Task-10 sphere of bench_setup_isolation.py, for as long as an attack lasts


def status_kb(pid: int, field: str) -> int:
    return int(re.search(rf"{field}:\s+(\d+) kB", Path(f"/proc/{pid}/status").read_text()).group(1))


def reset_peak(pid: int) -> None:
    Path(f"/proc/{pid}/clear_refs").write_text("5")   # VmHWM := VmRSS (Linux >= 4.0)


def start_server(tree: Path | None) -> tuple[subprocess.Popen, str]:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    proc = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", "serve", "--bind", "tcp://127.0.0.1:*",
                             "--max-sessions", "1"], stderr=subprocess.PIPE, text=True, env=env, cwd="/")
    line = proc.stderr.readline()
    match = re.search(r"listening on (tcp://\S+)", line)
    if not match:
        proc.kill()
        proc.wait()
        raise RuntimeError(f"hydrolink serve printed {line!r}")
    threading.Thread(target=drain, args=(proc,), daemon=True).start()
    return proc, match.group(1)


LOG: list[str] = []   # the server's log lines (drained from its stderr)


def drain(proc: subprocess.Popen) -> None:
    for line in proc.stderr:
        LOG.append(line.rstrip())


def ping_with(pad: bytes) -> bytes:
    """A ping frame with one entry more whose value is the raw msgpack ``pad``."""
    head = bytearray(codec.pack(codec.message("ping", "attack", None)))
    head[0] += 1
    return bytes(head) + b"\xa3pad" + pad


def array_header(n: int) -> bytes:
    return b"\xdd" + n.to_bytes(4, "big")


def dealer(ctx: zmq.Context, address: str) -> zmq.Socket:
    sock = ctx.socket(zmq.DEALER)
    sock.setsockopt(zmq.LINGER, 0)
    sock.setsockopt(zmq.SNDHWM, 0)
    sock.connect(address)
    return sock


def collect(socks: list[zmq.Socket], expected: int, timeout: float) -> list[str]:
    """The replies (``type code``) to ``expected`` requests over ``socks``, or ``no reply`` for those
    that did not come within ``timeout`` s."""
    poller = zmq.Poller()
    for s in socks:
        poller.register(s, zmq.POLLIN)
    got: list[str] = []
    deadline = time.monotonic() + timeout
    while len(got) < expected and (left := deadline - time.monotonic()) > 0:
        for s, _ in poller.poll(int(left * 1000)):
            while True:
                try:
                    frame = s.recv(zmq.NOBLOCK)
                except zmq.Again:
                    break
                r = codec.unpack(frame)
                got.append(f"{r['type']} {r.get('code', '')} {r.get('limit', '')}".strip())
    return got + ["no reply"] * (expected - len(got))


def attack(kind: str, ctx: zmq.Context, address: str, scale: float) -> list[str]:
    """Send the attack (its sizes times ``scale``); the replies it got."""
    if kind == "frames":
        big = bytes(int(32 * MiB * scale))
        sock = dealer(ctx, address)
        for _ in range(47):
            sock.send(big, zmq.SNDMORE, copy=False)
        sock.send(codec.pack(codec.message("ping", "attack", None)), copy=False)
        try:
            return collect([sock], 1, 120)
        finally:
            sock.close(0)
    if kind in ("lists", "nested", "deep"):
        n = int(63_000_000 * scale)
        per = int(20_000 * scale)
        pad = (array_header(n) + b"\x90" * n if kind == "lists" else
               array_header(63) + (array_header(n // 63) + b"\x90" * (n // 63)) * 63 if kind == "nested" else
               b"".join(array_header(per + (i < 999)) + b"\xa2ab" * per for i in range(1000)))
        frame = ping_with(pad)
        assert len(frame) < 64 * MiB
        sock = dealer(ctx, address)
        sock.send(frame, copy=False)
        try:
            return collect([sock], 1, 300)
        finally:
            sock.close(0)
    hello = codec.pack(codec.message("hello", "attack", None, role="multibody", scene=SCENE, hdbs={},
                                     pad=bytes(int(30 * MiB * scale))))
    socks = [dealer(ctx, address) for _ in range(100 if kind == "hellos" else 1)]
    try:
        for i in range(100):
            socks[i % len(socks)].send(hello, copy=False)
        return collect(socks, 100, 600)
    finally:
        for s in socks:
            s.close(0)


def stats(ms: np.ndarray) -> str:
    if ms.size == 0:
        return "no steps"
    return (f"{ms.size:5d} steps  p50 {np.percentile(ms, 50):6.2f}  p99 {np.percentile(ms, 99):7.2f}  "
            f"max {ms.max():8.2f} ms")


def victim(address: str, pipe) -> None:
    """The victim session, in a process of its own (its timing is not this process's GIL): steps
    200 times to warm up and 500 alone, says "ready", steps until told "stop", then sends both
    latency lists [ms]."""
    hdbs = load_scene_hdbs(parse_scene(SCENE), REPO)
    with ServerConnection(address, timeout=300.0) as conn:
        setup = conn.hello(SCENE, hdbs)
        x = np.array(setup.equilibrium_position, float)
        v = np.zeros_like(x)
        seq = 0

        def step() -> float:
            nonlocal seq
            t0 = time.perf_counter()
            conn.step(seq, seq * 0.05, x, v)
            seq += 1
            return (time.perf_counter() - t0) * 1e3

        for _ in range(200):
            step()
        alone = [step() for _ in range(500)]
        pipe.send("ready")
        during = []
        while not pipe.poll():
            during.append(step())
        pipe.recv()
        after = step()
        pipe.send((alone, during, after))


def run(kind: str, tree: Path | None, scale: float) -> None:
    LOG.clear()
    proc, address = start_server(tree)
    ctx = zmq.Context()
    mp = multiprocessing.get_context("spawn")
    here, there = mp.Pipe()
    child = mp.Process(target=victim, args=(address, there))
    child.start()
    try:
        if not here.poll(300) or here.recv() != "ready":
            raise RuntimeError("the victim session did not start")
        rss0 = status_kb(proc.pid, "VmRSS") / 1024
        reset_peak(proc.pid)
        t0 = time.perf_counter()
        replies = attack(kind, ctx, address, scale)
        took = time.perf_counter() - t0
        alive = proc.poll() is None
        peak = status_kb(proc.pid, "VmHWM") / 1024 if alive else float("nan")
        here.send("stop")
        if not here.poll(300):
            raise RuntimeError("the victim session did not answer")
        alone, during, after = here.recv()
        counts = {r: replies.count(r) for r in dict.fromkeys(replies)}
        print(f"{kind:9s} replies {counts}; {took:6.2f} s; server {'up' if alive else 'GONE'} "
              f"(a step after: {after:.2f} ms); RSS {rss0:.0f} MB, peak growth {peak - rss0:+.0f} MB", flush=True)
        dropped = sum("dropped" in line for line in LOG)
        if dropped:
            print(f"{'':9s} the server's log: {dropped} line(s) of replies dropped (the peer gone)", flush=True)
        print(f"{'':9s} victim alone   {stats(np.array(alone))}", flush=True)
        print(f"{'':9s} victim during  {stats(np.array(during))}", flush=True)
    except Exception as exc:  # noqa: BLE001 - a server that died mid-attack is a result
        print(f"{kind:9s} failed: {type(exc).__name__}: {exc}; server {'up' if proc.poll() is None else 'GONE'} "
              f"(status {proc.poll()})", flush=True)
    finally:
        ctx.term()
        proc.terminate()
        try:
            proc.wait(20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        child.join(30)
        if child.is_alive():
            child.kill()
            child.join()


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--only", default=",".join(ATTACKS), help=f"comma-separated of {ATTACKS}")
    parser.add_argument("--tree", type=Path, help="run the server from this source tree (holding hydrolink/)")
    parser.add_argument("--scale", type=float, default=1.0, help="every attack's sizes times this (a quick try)")
    args = parser.parse_args()
    print(f"server from {args.tree or 'this tree'}; load average {os.getloadavg()}", flush=True)
    for kind in args.only.split(","):
        run(kind, args.tree, args.scale)


if __name__ == "__main__":
    main()
