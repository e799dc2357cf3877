"""A shared server under the attacks of issue 35 (items 1-9), at full size.

Against a separately started ``hydrolink serve`` (default 64 MiB message limit, ``--max-sessions
1``) over loopback TCP: a victim session (the IEA Task-10 sphere, heave, dt = 0.05 s) steps in
lockstep in a process of its own and every round trip is timed; while it steps, one attack:

1. ``frames``: one multipart message of 47 frames x 32 MiB (each under the limit, 1.5 GiB together);
2. ``lists``: a 60 MiB ``ping`` holding 63 million empty lists in one list (the issue's form), and
   ``nested``: 63 lists of a million empty lists each (each list under msgpack's length bound);
   ``deep``: 20 million 2-character strings in lists nested 1000 deep (57 MiB: no list complete
   before the innermost, so a decoder's completion hooks see none of them until the end);
3. ``hellos``: 100 hellos padded to 30 MiB, from 100 connections at once (the victim holds the one
   session), and ``pipelined``: the same 100 on one connection without waiting;
4. ``heavy``: a legal heavy session (20 bodies, 100,000 wave components) steps beside the victim
   (the victim's p50 / p99 alone and beside it: the goal p50 <= 2x alone, p99 <= 10 ms), and
   ``preview``: a controller's 30 s wave preview of that sea per control step (in this process:
   the old evaluation of the whole window against the window computed along the run);
5. ``memory``: 7 big legal sessions (20 bodies, 50,000 components) against ``--max-memory-mib 600``;
6. ``deferred``: a step deferred for its controller's join, then 110 steps padded to 20 MiB
   pipelined behind it;
7. ``corrupt``: 10 corrupt HDB file sets sent by hash, each timed, each followed by a valid hello;
8. ``stranger``: a stranger's controller hello without and with a wrong join token, and its bye;
9. ``keyfile``: ``serve --key-file`` on 256 random bytes (lines printed, exit status), and
   ``logflood``: 3000 late controller commands (the server's log lines and bytes).

Each attack gets a fresh server. Printed per attack: the replies the attacker got (type and code),
the server's peak RSS growth over the attack (VmHWM, reset through /proc/PID/clear_refs before it;
the goal: <= 256 MB), the victim's step latency during the attack (p50 / p99 / max, the goal: max
<= 100 ms), and whether the server still answers. ``--tree DIR`` runs the server from another
source tree (a directory holding ``hydrolink/``, e.g. ``git archive`` of an older commit), for a
before/after in the same run. Messages are sent zero-copy from one buffer: the attacker costs this
process little.

Every attack against the victim prints the server up or gone, the replies (type, code, limit), the
peak RSS growth and the victim's step latency alone and during (``heavy``: during the heavy
session's steps only).

    python bench/bench_attacks.py [--only frames,...,logflood] [--tree DIR] [--scale 1]
"""

from __future__ import annotations

import argparse
import contextlib
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

from hydrolink.clients.lockstep.connection import RemoteError, ServerConnection
from hydrolink.clients.scene_inputs import load_scene_hdbs
from hydrolink.protocol import codec
from hydrolink.protocol.scene import parse_scene

from bench_setup_isolation import scene   # bench/ is on the path

REPO = Path(__file__).resolve().parents[1]
MiB = 2**20
ATTACKS = ("frames", "lists", "nested", "deep", "hellos", "pipelined", "heavy", "preview", "memory", "deferred",
           "corrupt", "stranger", "keyfile", "logflood")
SCENE = scene(0.05, 1e5)   # the heave-only Task-10 sphere of bench_setup_isolation.py, for as long as an attack lasts
SERVER_ARGS = {"memory": ("--max-memory-mib", "600", "--max-workers", "8", "--max-sessions", "64"),
               "deferred": ("--max-sessions", "8"), "stranger": ("--max-sessions", "8"),
               "logflood": ("--max-sessions", "8"),
               "heavy": ("-v", "--max-sessions", "8"), "corrupt": ("--max-sessions", "8")}
HEAVY_SECONDS = 20.0   # the heavy session steps this long beside the victim


def heavy_scene(bodies: int = 20, components: int = 100_000, controller: str = "") -> str:
    """The issue's heavy legal session: ``bodies`` Task-10 spheres 30 m apart in irregular waves."""
    text = scene(0.05, 1e5).split("[[bodies]]")[0].replace(
        '[waves]\ntype = "regular"\nheight = 1.0\nperiod = 8.0',
        f'[waves]\ntype = "irregular"\nspectrum = "jonswap"\nhs = 2.0\ntp = 8.0\ncomponents = {components}\nseed = 1')
    sphere = (REPO / "examples" / "data" / "sphere_task10" / "sphere.h5").as_posix()
    for i in range(bodies):
        text += (f'[[bodies]]\nname = "s{i}"\nhdb = "{sphere}"\nhdb_body = "sphere"\nmass = 261800.0\n'
                 f'center_of_mass = [{30.0 * i}, 0.0, -2.0]\ninertia = [1.0e6, 1.0e6, 1.0e6]\n')
    return text + controller


CONTROLLED = scene(0.05, 1e5).replace('dofs = ["heave"]', 'dofs = ["heave"]') + """
[[ptos]]
name = "pto"
type = "linear"
body1 = "sphere"
point1 = [0.0, 0.0, -2.0]
body2 = "ground"
point2 = [0.0, 0.0, -30.0]
damping = 1.0e5
[[controllers]]
name = "ctl"
ptos = ["pto"]
timeout = 0.05
join_timeout = 600.0
"""


def status_kb(pid: int, field: str) -> int:
    return int(re.search(rf"{field}:\s+(\d+) kB", Path(f"/proc/{pid}/status").read_text()).group(1))


def reset_peak(pid: int) -> None:
    Path(f"/proc/{pid}/clear_refs").write_text("5")   # VmHWM := VmRSS (Linux >= 4.0)


def start_server(tree: Path | None, *args: str) -> tuple[subprocess.Popen, str]:
    env = dict(os.environ, OPENBLAS_NUM_THREADS="1")
    if tree is not None:
        env["PYTHONPATH"] = str(tree)
    verbose = ["-v"] if "-v" in args else []   # info lines: where each session steps
    args = tuple(a for a in args if a != "-v")
    proc = subprocess.Popen([sys.executable, "-m", "hydrolink.clients.cli", *verbose, "serve", "--bind",
                             "tcp://127.0.0.1:*", *(args or ("--max-sessions", "1"))], stderr=subprocess.PIPE,
                            text=True, env=env, cwd="/")
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


# ---------------------------------------------------------------- items 4-9


def heavy_session(address: str, seconds: float, pipe) -> None:
    """The heavy session, in a process of its own: hello, says "stepping", steps ``seconds``, then
    sends (window start, end, its step latencies [ms]) on the monotonic clock."""
    text = heavy_scene()
    hdbs = load_scene_hdbs(parse_scene(text), REPO)
    with ServerConnection(address, timeout=600.0) as conn:
        setup = conn.hello(text, hdbs)
        x = np.array(setup.equilibrium_position, float)
        v = np.zeros_like(x)
        pipe.send("stepping")
        t0 = time.monotonic()
        own, seq = [], 0
        while time.monotonic() - t0 < seconds:
            a = time.perf_counter()
            conn.step(seq, seq * 0.05, x, v)
            own.append((time.perf_counter() - a) * 1e3)
            seq += 1
        t1 = time.monotonic()
        conn.bye()
    pipe.send((t0, t1, own))


def attack_heavy(address: str) -> tuple[list[str], tuple[float, float], list[str]]:
    mp = multiprocessing.get_context("spawn")
    here, there = mp.Pipe()
    child = mp.Process(target=heavy_session, args=(address, HEAVY_SECONDS, there))
    t0 = time.perf_counter()
    child.start()
    try:
        if not here.poll(900) or here.recv() != "stepping":
            raise RuntimeError("the heavy session did not start")
        setup = time.perf_counter() - t0
        if not here.poll(HEAVY_SECONDS + 600):
            raise RuntimeError("the heavy session did not finish")
        start, end, own = here.recv()
    finally:
        child.join(60)
    where = [line for line in LOG if "in worker process" in line]
    return (["welcome"], (start, end),
            [f"heavy session: set-up {setup:.1f} s, {'in a worker process' if where else 'on the loop'}; its own "
             f"steps {stats(np.array(own))}"])


def preview_cost(scale: float) -> list[str]:
    """A controller's 30 s preview of a 100,000-component sea, per control step (every step of
    0.05 s; preview step 0.05 s: 600 samples): the old whole-window evaluation against the window
    computed along the run (server/sea/probes.py), in this process."""
    from hydrolink.server.model import HydroModel
    from hydrolink.server.sea.probes import PreviewGrid, WaveProbes

    text = heavy_scene(1, int(100_000 * scale))
    sc = parse_scene(text)
    model = HydroModel(sc, {b.name: d for b, d in zip(sc.wet_bodies, load_scene_hdbs(sc, REPO).values())})
    grid = PreviewGrid(((0.0, 0.0),), 0.05, 1, 600)
    probes = WaveProbes.on_grid(model.waves, grid, 9.81, 200.0)
    out = []
    rss0 = status_kb(os.getpid(), "VmRSS") / 1024
    reset_peak(os.getpid())
    c = probes._cr + 1j * probes._ci
    t = time.perf_counter()
    times = 40 * 0.05 + grid.offsets   # the old code: one exp of components x samples, then a matvec
    e = np.exp(-1j * np.outer(model.waves.omega, times))
    np.real(c @ e)
    old = time.perf_counter() - t
    del e
    peak = status_kb(os.getpid(), "VmHWM") / 1024 - rss0
    out.append(f"preview old: {old * 1e3:.0f} ms per control step, peak +{peak:.0f} MB")
    reset_peak(os.getpid())
    rss0 = status_kb(os.getpid(), "VmRSS") / 1024
    t = time.perf_counter()
    probes.at_step(0)
    first = time.perf_counter() - t
    each = []
    for k in range(1, 201):
        t = time.perf_counter()
        probes.at_step(k)
        each.append((time.perf_counter() - t) * 1e3)
    peak = status_kb(os.getpid(), "VmHWM") / 1024 - rss0
    out.append(f"preview new: first window {first * 1e3:.0f} ms, then {stats(np.array(each))}; peak +{peak:.0f} MB "
               "(in the session's worker for a heavy session, and only once a controller joined)")
    return out


def attack_memory(address: str) -> list[str]:
    text = heavy_scene(20, 50_000)
    hdbs = load_scene_hdbs(parse_scene(text), REPO)
    replies, conns = [], []
    for _ in range(7):
        conn = ServerConnection(address, timeout=900.0)
        conns.append(conn)
        try:
            conn.hello(text, hdbs)
            replies.append("welcome")
        except RemoteError as exc:
            replies.append(f"error {exc.code} {exc.extra.get('limit', '')}".strip())
    for conn in conns:
        conn.close()
    return replies


def attack_deferred(ctx: zmq.Context, address: str, scale: float) -> list[str]:
    with owner_and_dealer(ctx, address) as (owner, sock):
        sock.send(codec.pack(codec.message("step", "s-0", owner.session, seq=0, time=0.0,
                                           position=np.zeros((1, 6)), velocity=np.zeros((1, 6)))))
        pad = bytes(int(20 * MiB * scale))
        for i in range(110):
            sock.send(codec.pack(codec.message("step", f"p-{i}", owner.session, seq=1, time=0.05,
                                               position=np.zeros((1, 6)), velocity=np.zeros((1, 6)), pad=pad)),
                      copy=False)
        refused = [r for r in collect([sock], 110, 30) if r != "no reply"]
        ctl = dealer(ctx, address)   # the controller joins: the deferred step and those held behind it are answered
        ctl.send(codec.pack(codec.message("hello", "c-0", owner.session, role="controller", controller="ctl",
                                          token=owner.control_token)))
        collect_raw(ctl)
        ctl.close(0)
        return refused + collect([sock], 111 - len(refused), 300)


def corrupt_sets(folder: Path) -> list[tuple[str, str, object]]:
    """10 corrupt HDB file sets (name, scene, HDBFiles)."""
    from hydrolink.protocol.hdb.wire import HDBFiles

    sys.path.insert(0, str(REPO / "tests"))
    from conftest import regular_waves, rm3_float, rm3_spar, scene_toml

    def rm3(name: str) -> str:
        return scene_toml(dt=0.05, duration=5.0, waves=regular_waves(1.0, 8.0), hydro={"irf_duration": 10.0},
                          bodies=[rm3_float(name), rm3_spar(name)])

    src = REPO / "examples" / "data"
    wamit = src / "rm3_wamit"
    lines = (wamit / "rm3.1").read_text().splitlines(keepends=True)
    nc_bytes = (src / "rm3_capytaine" / "rm3_hydrodynamics.nc").read_bytes()
    h5_bytes = (src / "sphere_task10" / "sphere.h5").read_bytes()
    sets = []

    def wamit_with(tag: str, first: str, second: str | None = None) -> None:
        d = folder / tag
        d.mkdir()
        (d / "rm3.1").write_text(first)
        (d / "rm3.3").write_text(second if second is not None else (wamit / "rm3.3").read_text())
        sets.append((tag, "rm3.1", rm3("rm3.1"),
                     HDBFiles("wamit", (d / "rm3.1", d / "rm3.3", wamit / "rm3.hst", wamit / "rm3.out"))))

    for index in (" 99999", "  1000"):   # one mode index far beyond the file: terabytes, and gigabytes
        wamit_with(f"wamit-index-{index.strip()}",
                   "".join([lines[0], lines[1].replace("     1     1", f"{index}     1", 1), *lines[2:]]))
    wamit_with("wamit-not-numbers", "".join(lines[:20]) + "not numbers at all\n")
    wamit_with("wamit-3-garbage", (wamit / "rm3.1").read_text(), "\x00\x01garbage\n" * 100)
    for tag, data in (("nc-noise", b"CDF\x01" + bytes(range(256)) * 40),
                      ("nc-truncated", nc_bytes[:len(nc_bytes) // 2]),
                      ("nc-hdf5-noise", b"\x89HDF\r\n\x1a\n" + bytes(range(256)) * 400)):
        d = folder / tag
        d.mkdir()
        (d / "rm3.nc").write_bytes(data)
        sets.append((tag, "rm3.nc", rm3("rm3.nc"), HDBFiles("netcdf", (d / "rm3.nc",))))
    for tag, data in (("h5-noise", b"\x89HDF\r\n\x1a\n" + bytes(range(256)) * 40),
                      ("h5-truncated", h5_bytes[:len(h5_bytes) // 3]),
                      ("h5-empty", b"")):
        d = folder / tag
        d.mkdir()
        (d / "sphere.h5").write_bytes(data)
        sets.append((tag, "sphere.h5", scene(0.05, 5.0).replace(SPHERE_PATH, "sphere.h5"),
                     HDBFiles("bemio", (d / "sphere.h5",))))
    return sets


SPHERE_PATH = (REPO / "examples" / "data" / "sphere_task10" / "sphere.h5").as_posix()


def attack_corrupt(address: str) -> tuple[list[str], list[str]]:
    import tempfile

    from hydrolink.protocol.hdb.wire import HDBFiles

    replies, notes = [], []
    valid = {"sphere.h5": HDBFiles("bemio", (Path(SPHERE_PATH),))}
    with tempfile.TemporaryDirectory() as tmp:
        for tag, name, text, files in corrupt_sets(Path(tmp)):
            t = time.perf_counter()
            try:
                with ServerConnection(address, timeout=120.0) as conn:
                    conn.hello(text, {name: files})
                    got = "welcome"
            except RemoteError as exc:
                got = f"error {exc.code}"
            except TimeoutError:
                got = "no reply"
            took = time.perf_counter() - t
            t = time.perf_counter()
            with ServerConnection(address, timeout=120.0) as conn:
                conn.hello(scene(0.05, 5.0).replace(SPHERE_PATH, "sphere.h5"), valid)
                conn.bye()
            replies.append(got)
            after = time.perf_counter() - t
            notes.append(f"{tag:18s} {got:9s} in {took:5.2f} s; a valid hello right after: {after:5.2f} s")
    return replies, notes


@contextlib.contextmanager
def owner_and_dealer(ctx: zmq.Context, address: str):
    """A session of the controlled scene (its owner's connection) and a raw DEALER beside it."""
    hdbs = load_scene_hdbs(parse_scene(CONTROLLED), REPO)
    with ServerConnection(address, timeout=300.0) as owner:
        owner.hello(CONTROLLED, hdbs)
        sock = dealer(ctx, address)
        try:
            yield owner, sock
        finally:
            sock.close(0)


def attack_stranger(ctx: zmq.Context, address: str) -> list[str]:
    with owner_and_dealer(ctx, address) as (owner, sock):
        for i, fields in enumerate(({"controller": "ctl"}, {"controller": "ctl", "token": "x" * 43},
                                    {"controller": "ctl", "token": owner.control_token[::-1]})):
            sock.send(codec.pack(codec.message("hello", f"h-{i}", None, role="controller", **fields)))
        sock.send(codec.pack(codec.message("bye", "b-0", "0" * 32)))   # a stranger cannot know the owner's id
        got = collect([sock], 4, 60)
        got.append("owner still open" if owner.request("ping")["type"] == "pong" else "owner gone")
        return got


def attack_keyfile() -> list[str]:
    import tempfile

    with tempfile.NamedTemporaryFile(suffix=".key") as f:
        f.write(os.urandom(256))
        f.flush()
        proc = subprocess.run([sys.executable, "-m", "hydrolink.clients.cli", "serve", "--bind", "tcp://127.0.0.1:*",
                               "--key-file", f.name], capture_output=True, text=True, timeout=120)
    lines = proc.stderr.strip().splitlines()
    return [f"exit {proc.returncode}, {len(lines)} line(s): {lines[-1][:100] if lines else ''}"]


def attack_logflood(ctx: zmq.Context, address: str) -> list[str]:
    with owner_and_dealer(ctx, address) as (owner, sock):
        sock.send(codec.pack(codec.message("hello", "c-0", owner.session, role="controller", controller="ctl",
                                           token=owner.control_token)))
        welcome = collect_raw(sock)
        epoch, own = welcome["epoch"], welcome["session"]
        sock.send(codec.pack(codec.message("measure", "c-1", own, controller="ctl", epoch=epoch, wait=60.0)))
        x = np.zeros((1, 6))
        owner.step(0, 0.0, x, x)
        meas = {"step": 0, "pto_displacement": np.zeros(1), "pto_velocity": np.zeros(1), "pto_force": np.zeros(1),
                "body_position": x, "body_velocity": x}
        owner.step(1, 0.05, x, x, measurements=meas)   # after the 0.05 s timeout: the command is late
        collect_raw(sock)
        before = len(LOG)
        chars = sum(map(len, LOG))
        t = time.perf_counter()
        for i in range(3000):
            sock.send(codec.pack(codec.message("command", f"late-{i}", own, controller="ctl", epoch=epoch, step=0,
                                               commands={"pto": {"force": 1.0}})))
        got = collect([sock], 3000, 300)
        took = time.perf_counter() - t
        time.sleep(0.5)
        return [*got, f"{len(LOG) - before} log lines, {sum(map(len, LOG)) - chars} bytes in {took:.1f} s"]


def collect_raw(sock: zmq.Socket) -> dict:
    if not sock.poll(60_000):
        raise RuntimeError("no reply within 60 s")
    return codec.unpack(sock.recv())


def stats(ms: np.ndarray) -> str:
    if ms.size == 0:
        return "no steps"
    return (f"{ms.size:5d} steps  p50 {np.percentile(ms, 50):6.2f}  p99 {np.percentile(ms, 99):7.2f}  "
            f"max {ms.max():8.2f} ms")


def victim(address: str, pipe) -> None:
    """The victim session, in a process of its own (its timing is not this process's GIL): steps
    200 times to warm up and 500 alone, says "ready", steps until told "stop", then sends both
    latency lists [ms] (the second with each step's end on the monotonic clock)."""
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
        during = []   # (when it ended on the monotonic clock, ms)
        while not pipe.poll():
            during.append((step(), time.monotonic()))
        pipe.recv()
        after = step()
        pipe.send((alone, during, after))


def launch(kind: str, ctx: zmq.Context, address: str, scale: float):
    """The attack ``kind``: (its replies, the window of the victim's steps to report or None, notes)."""
    if kind == "heavy":
        return attack_heavy(address)
    if kind == "memory":
        return attack_memory(address), None, []
    if kind == "deferred":
        return attack_deferred(ctx, address, scale), None, []
    if kind == "corrupt":
        replies, notes = attack_corrupt(address)
        return replies, None, notes
    if kind == "stranger":
        return attack_stranger(ctx, address), None, []
    if kind == "logflood":
        got = attack_logflood(ctx, address)
        return got[:-1], None, got[-1:]
    return attack(kind, ctx, address, scale), None, []


def run(kind: str, tree: Path | None, scale: float) -> None:
    if kind == "preview":
        for line in preview_cost(scale):
            print(f"{kind:9s} {line}", flush=True)
        return
    if kind == "keyfile":
        print(f"{kind:9s} {attack_keyfile()[0]}", flush=True)
        return
    LOG.clear()
    proc, address = start_server(tree, *SERVER_ARGS.get(kind, ()))
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
        replies, window, notes = launch(kind, ctx, address, scale)
        took = time.perf_counter() - t0
        alive = proc.poll() is None
        peak = status_kb(proc.pid, "VmHWM") / 1024 if alive else float("nan")
        here.send("stop")
        if not here.poll(300):
            raise RuntimeError("the victim session did not answer")
        alone, during, after = here.recv()
        if window is not None:
            during = [(ms, t) for ms, t in during if window[0] <= t <= window[1]]
        during = np.array([ms for ms, _ in during])
        counts = {r: replies.count(r) for r in dict.fromkeys(replies)}
        print(f"{kind:9s} replies {counts}; {took:6.2f} s; server {'up' if alive else 'GONE'} "
              f"(a step after: {after:.2f} ms); RSS {rss0:.0f} MB, peak growth {peak - rss0:+.0f} MB "
              "(the loop's process; workers apart)", flush=True)
        for line in notes:
            print(f"{'':9s} {line}", flush=True)
        dropped = sum("dropped" in line for line in LOG)
        if dropped:
            print(f"{'':9s} the server's log: {dropped} line(s) of replies dropped (the peer gone)", flush=True)
        print(f"{'':9s} victim alone   {stats(np.array(alone))}", flush=True)
        print(f"{'':9s} victim during  {stats(during)}", flush=True)
        if during.size and alone:
            print(f"{'':9s} p50 during / alone {np.percentile(during, 50) / np.percentile(alone, 50):.2f}x", flush=True)
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
        print(f"{'':9s} load average {os.getloadavg()}", flush=True)


if __name__ == "__main__":
    main()
