"""A network lab on one machine: participants in their own network namespaces, joined through a
hub namespace, with a one-way delay between any two of them (tests/test_remote.py,
bench/bench_remote_latency.py, docs/remote.md).

Topology (``prefix`` is unique per lab, so labs never collide and cleanup is by name)::

    <prefix>-server  <prefix>-client  <prefix>-ctl ...   one namespace per participant
          |  veth          |  veth        |  veth        198.18.0.k/24 (RFC 2544 benchmark range)
          +-----------  <prefix>-hub  ----+               no addresses: a switch

The hub forwards Ethernet frames between the participants and delays each one by ``delay``
seconds, so a request/reply between two participants takes 2 x ``delay`` more than locally:

- ``mode = "netem"``: a kernel bridge in the hub and ``tc qdisc ... netem delay`` on every
  participant's egress (kernels built with sch_netem);
- ``mode = "switch"``: this module's user-space delay switch in the hub (``python -m
  netlab switch``): AF_PACKET sockets with PACKET_VNET_HDR on the hub's ends of
  the veths (so checksum-offload and GSO metadata pass through unchanged), a MAC-learning switch
  whose frames leave ``delay`` after they came in. For kernels without netem (this project's VMs:
  ``CONFIG_NET_SCH_NETEM`` is not set). It adds a few tens of µs per hop (one Python process).

``mode = "auto"`` takes netem when the kernel has it. Needs root, ``ip`` (iproute2) and netns
support: :func:`unsupported_reason` says why not, for a test skip.
"""

from __future__ import annotations

import collections
import os
import select
import shutil
import signal
import socket
import subprocess
import sys
import time
from pathlib import Path

SUBNET = "198.18.0"
ETH_P_ALL = 3
SOL_PACKET = 263
PACKET_VNET_HDR = 15
VNET_HDR = 10  # struct virtio_net_hdr


def _ip(*args: str, check: bool = True) -> subprocess.CompletedProcess:
    return subprocess.run(["ip", *args], capture_output=True, text=True, check=check, timeout=20)


def unsupported_reason() -> str | None:
    """None if this machine can build a lab, else why not (for ``pytest.skip``)."""
    if not sys.platform.startswith("linux"):
        return "network namespaces need Linux"
    if os.geteuid() != 0:
        return "creating network namespaces needs root"
    if shutil.which("ip") is None:
        return "no `ip` command (apt-get install iproute2)"
    name = f"hlprobe{os.getpid()}"
    try:
        out = _ip("netns", "add", name, check=False)
        if out.returncode:
            return f"cannot create a network namespace: {out.stderr.strip()}"
        out = _ip("-n", name, "link", "add", "p0", "type", "veth", "peer", "name", "p1", check=False)
        if out.returncode:
            return f"cannot create a veth pair: {out.stderr.strip()}"
    finally:
        _ip("netns", "del", name, check=False)
    return None


def has_netem() -> bool:
    """Whether the kernel has the netem qdisc (probed on a veth in a scratch namespace)."""
    if shutil.which("tc") is None:
        return False
    name = f"hlnetem{os.getpid()}"
    try:
        if _ip("netns", "add", name, check=False).returncode:
            return False
        _ip("-n", name, "link", "add", "p0", "type", "veth", "peer", "name", "p1", check=False)
        out = subprocess.run(["ip", "netns", "exec", name, "tc", "qdisc", "add", "dev", "p0", "root", "netem",
                              "delay", "1ms"], capture_output=True, text=True, timeout=20)
        return out.returncode == 0
    finally:
        _ip("netns", "del", name, check=False)


class Lab:
    """Namespaces for ``participants`` (names), addresses ``198.18.0.1``, ``.2``, ... in that order.

    ::

        with Lab(["server", "client"], delay=0.01) as lab:
            srv = lab.popen("server", ["hydrolink", "serve", "--bind", f"tcp://{lab.address('server')}:5555"])
            lab.run("client", [...], timeout=60)

    Every process started with :meth:`popen` is ended (SIGTERM, then SIGKILL) and every namespace
    deleted on exit, also after an error."""

    def __init__(self, participants: list[str], delay: float = 0.0, *, mode: str = "auto", max_time: float = 900.0,
                 loss: float = 0.0):
        """``loss``: the probability that a frame is dropped (each frame alone, seeded), and
        :meth:`outage` takes the link down for a while: both in the user-space switch (``mode``
        "auto" then picks it)."""
        if mode not in ("auto", "netem", "switch"):
            raise ValueError(f"mode must be auto, netem or switch, got {mode!r}")
        if not 0.0 <= loss < 1.0:
            raise ValueError(f"loss must be in [0, 1), got {loss}")
        self.participants = list(participants)
        self.delay = float(delay)
        self.loss = float(loss)
        self.mode = ("netem" if has_netem() and not loss else "switch") if mode == "auto" else mode
        if self.loss and self.mode != "switch":
            raise ValueError("loss is simulated by the user-space switch: mode = \"switch\" or \"auto\"")
        self._switch: subprocess.Popen | None = None
        self.max_time = max_time
        self.prefix = f"hl{os.getpid() % 100000}{os.urandom(2).hex()}"
        self.hub = f"{self.prefix}-hub"
        self._namespaces: list[str] = []
        self._procs: list[subprocess.Popen] = []

    # ------------------------------------------------------------ names

    def ns(self, who: str) -> str:
        return f"{self.prefix}-{who}"

    def address(self, who: str) -> str:
        return f"{SUBNET}.{self.participants.index(who) + 1}"

    def _veth(self, i: int, end: str) -> str:  # interface names are at most 15 characters
        return f"{self.prefix[:9]}{i}{end}"

    # ------------------------------------------------------------ lifecycle

    def __enter__(self) -> "Lab":
        try:
            self._build()
        except BaseException:
            self.close()
            raise
        return self

    def __exit__(self, *exc) -> None:
        self.close()

    def _build(self) -> None:
        _ip("netns", "add", self.hub)
        self._namespaces.append(self.hub)
        hub_ports = []
        for i, who in enumerate(self.participants):
            ns = self.ns(who)
            _ip("netns", "add", ns)
            self._namespaces.append(ns)
            inner, outer = self._veth(i, "a"), self._veth(i, "b")
            _ip("-n", self.hub, "link", "add", outer, "type", "veth", "peer", "name", inner, "netns", ns)
            _ip("-n", ns, "addr", "add", f"{self.address(who)}/24", "dev", inner)
            _ip("-n", ns, "link", "set", "lo", "up")
            _ip("-n", ns, "link", "set", inner, "up")
            _ip("-n", self.hub, "link", "set", outer, "up")
            hub_ports.append(outer)
            if self.mode == "netem" and self.delay > 0:
                subprocess.run(["ip", "netns", "exec", ns, "tc", "qdisc", "add", "dev", inner, "root", "netem",
                                "delay", f"{self.delay * 1e3:g}ms", "limit", "100000"], check=True,
                               capture_output=True, timeout=20)
        if self.mode == "netem":
            _ip("-n", self.hub, "link", "add", "br0", "type", "bridge")
            for port in hub_ports:
                _ip("-n", self.hub, "link", "set", port, "master", "br0")
            _ip("-n", self.hub, "link", "set", "br0", "up")
        else:
            self._switch = self.popen(None, [sys.executable, str(Path(__file__).resolve()), "switch", "--delay",
                                             repr(self.delay), "--loss", repr(self.loss), "--max-time",
                                             repr(self.max_time), *hub_ports], namespace=self.hub,
                                      stdout=subprocess.DEVNULL, stderr=subprocess.PIPE)
        self._wait_reachable()

    def outage(self, seconds: float) -> None:
        """Take the link down (every frame dropped, both ways) for ``seconds``, then up again
        (user-space switch only: SIGUSR1 toggles it)."""
        if self._switch is None:
            raise RuntimeError("an outage needs the user-space switch (mode \"switch\")")
        self._switch.send_signal(signal.SIGUSR1)
        try:
            time.sleep(seconds)
        finally:
            self._switch.send_signal(signal.SIGUSR1)

    def _wait_reachable(self, timeout: float = 10.0) -> None:
        """Until the first participant reaches every other one (a TCP connect refused counts:
        the frame went through the hub and back)."""
        if len(self.participants) < 2:
            return
        probe = ("import socket,sys\ns=socket.socket();s.settimeout(0.5)\n"
                 "try:\n s.connect((sys.argv[1],9))\nexcept ConnectionRefusedError:\n pass\n")
        end = time.monotonic() + timeout
        for who in self.participants[1:]:
            while True:
                out = subprocess.run(["ip", "netns", "exec", self.ns(self.participants[0]), sys.executable, "-c", probe,
                                      self.address(who)], capture_output=True, text=True, timeout=20)
                if out.returncode == 0:
                    break
                if time.monotonic() > end:
                    raise RuntimeError(f"lab {self.prefix}: {who} not reachable: {out.stderr.strip()[-300:]}")
                time.sleep(0.05)

    def command(self, who: str | None, argv: list[str], namespace: str | None = None) -> list[str]:
        return ["ip", "netns", "exec", namespace or self.ns(who), *argv]

    def popen(self, who: str | None, argv: list[str], *, namespace: str | None = None, **kw) -> subprocess.Popen:
        """Start ``argv`` inside ``who``'s namespace; ended on :meth:`close`."""
        kw.setdefault("stdout", subprocess.PIPE)
        kw.setdefault("stderr", subprocess.PIPE)
        kw.setdefault("text", True)
        proc = subprocess.Popen(self.command(who, argv, namespace), **kw)
        self._procs.append(proc)
        return proc

    def run(self, who: str, argv: list[str], *, timeout: float, **kw) -> subprocess.CompletedProcess:
        return subprocess.run(self.command(who, argv), capture_output=True, text=True, timeout=timeout, **kw)

    def close(self) -> None:
        for proc in self._procs:
            if proc.poll() is None:
                proc.send_signal(signal.SIGTERM)
        for proc in self._procs:
            try:
                proc.wait(5)
            except subprocess.TimeoutExpired:
                proc.kill()
                proc.wait(5)
            for stream in (proc.stdout, proc.stderr):
                if stream is not None:
                    stream.close()
        self._procs.clear()
        for ns in reversed(self._namespaces):
            _ip("netns", "del", ns, check=False)
        self._namespaces.clear()


# ---------------------------------------------------------------- the delay switch

def delay_switch(ports: list[str], delay: float, max_time: float, loss: float = 0.0, seed: int = 1) -> None:
    """Forward frames between the interfaces ``ports`` (MAC learning, flooding unknown and
    broadcast destinations), each ``delay`` s after it arrived, dropping each with probability
    ``loss`` and all of them while the link is down (SIGUSR1 toggles it); returns after
    ``max_time`` s or on SIGTERM/SIGINT."""
    import random
    rng = random.Random(seed)
    down = [False]
    signal.signal(signal.SIGUSR1, lambda *a: down.__setitem__(0, not down[0]))
    socks = []
    for port in ports:
        s = socket.socket(socket.AF_PACKET, socket.SOCK_RAW, socket.htons(ETH_P_ALL))
        s.setsockopt(SOL_PACKET, PACKET_VNET_HDR, 1)
        s.setsockopt(socket.SOL_SOCKET, socket.SO_RCVBUF, 4 << 20)
        s.bind((port, 0))
        s.setblocking(False)
        socks.append(s)
    poller = select.epoll()
    index = {}
    for i, s in enumerate(socks):
        poller.register(s.fileno(), select.EPOLLIN)
        index[s.fileno()] = i
    where: dict[bytes, int] = {}
    queue: collections.deque = collections.deque()   # (due, [out ports], frame): constant delay = FIFO
    buf = bytearray(1 << 18)
    stop = []
    signal.signal(signal.SIGTERM, lambda *a: stop.append(1))
    signal.signal(signal.SIGINT, lambda *a: stop.append(1))
    end = time.monotonic() + max_time
    everyone = list(range(len(socks)))
    while not stop and time.monotonic() < end:
        now = time.monotonic()
        while queue and queue[0][0] <= now:
            _, outs, frame = queue.popleft()
            for o in outs:
                try:
                    socks[o].send(frame)
                except OSError:
                    pass  # like a full wire: dropped
        wait = max(0.0, queue[0][0] - time.monotonic()) if queue else 0.2
        try:
            events = poller.poll(wait)
        except InterruptedError:
            continue
        for fd, _ in events:
            i = index[fd]
            s = socks[i]
            while True:
                try:
                    n, addr = s.recvfrom_into(buf)
                except (BlockingIOError, InterruptedError):
                    break
                if addr[2] == socket.PACKET_OUTGOING:
                    continue  # our own sends
                frame = bytes(buf[:n])
                dst, src = frame[VNET_HDR:VNET_HDR + 6], frame[VNET_HDR + 6:VNET_HDR + 12]
                where[src] = i
                o = where.get(dst) if not dst[0] & 1 else None
                outs = [o] if o is not None else [j for j in everyone if j != i]
                if o == i or down[0] or (loss and rng.random() < loss):
                    continue
                queue.append((time.monotonic() + delay, outs, frame))


def main(argv: list[str] | None = None) -> None:
    import argparse
    p = argparse.ArgumentParser(prog="python -m netlab")
    sub = p.add_subparsers(dest="cmd", required=True)
    sw = sub.add_parser("switch", help="user-space delay switch between interfaces (run inside a namespace)")
    sw.add_argument("ports", nargs="+")
    sw.add_argument("--delay", type=float, default=0.0, help="one-way delay per frame, s")
    sw.add_argument("--loss", type=float, default=0.0, help="probability that a frame is dropped")
    sw.add_argument("--max-time", type=float, default=900.0, help="stop after this many seconds")
    args = p.parse_args(argv)
    delay_switch(args.ports, args.delay, args.max_time, args.loss)


if __name__ == "__main__":
    main()
