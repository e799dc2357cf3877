"""Cost per lockstep step of message security on loopback TCP: plain, HMAC-signed (SPEC §3.3,
``--key-file``) and CURVE (SPEC §1.1). RM3 (examples/rm3/rm3.toml), ``hydrolink serve`` in its own
process, the Exudyn client in this one; wall time per step of the whole run loop, best of
``--repeat``.

"plain" and "HMAC" step over the server's direct channel (SPEC §5.7.5, revision 1.16: a plain
stream socket, no ZeroMQ I/O thread); CURVE over ZeroMQ (no direct channel beside it). ``--fronts``
adds the plain run kept on ZeroMQ (``direct=False``: the stream front end, as before 1.16) and
the comparison of the server's two front ends (server/service/frontend.py) with no security: a
bench-only server (:class:`RouterServer`, started by this script with ``--serve-router``)
answering through libzmq's ROUTER, which ``hydrolink serve`` uses only with CURVE (its receive is
bounded per frame by libzmq, not while a message arrives: SPEC §1, so it is no user-facing
choice). ``--gc`` adds ``hydrolink serve`` with its heap not frozen after start-up (``gc.freeze``
made a no-op in a child of this script, ``--serve-unfrozen``): the A/B of that freeze. The modes
are interleaved ``--repeat`` times, best of each kept.

    python bench/bench_security.py [--duration 100] [--repeat 3] [--fronts] [--gc]
"""

from __future__ import annotations

import argparse
import os
import subprocess
import sys
import tempfile
from pathlib import Path

REPO = Path(__file__).resolve().parents[1]
HYDROLINK = [sys.executable, "-m", "hydrolink.clients.cli"]
ROUTER = "plain, ROUTER front end (bench-only server)"
UNFROZEN = "plain (direct channel), heap not frozen after start-up (bench-only)"


def serve(extra: list[str], env: dict, command: list[str] = (*HYDROLINK, "serve")) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([*command, "--bind", "tcp://127.0.0.1:*", *extra], stderr=subprocess.PIPE,
                            text=True, env={**os.environ, **env})
    line = proc.stderr.readline()
    if "listening on" not in line:
        raise SystemExit(f"server did not start: {line}")
    return proc, line.split("listening on ")[1].split()[0]


def serve_router(bind: str) -> None:
    """The bench-only server of ``--fronts``: ``hydrolink serve``'s defaults, its messages through
    libzmq's ROUTER without CURVE; runs until SIGTERM."""
    import signal

    from hydrolink.protocol import codec
    from hydrolink.server.processes import start_children
    from hydrolink.server.service import force_server as fs
    from hydrolink.server.service import frontend

    class RouterServer(fs.ForceServer):
        """A ForceServer whose socket is the ROUTER front end with no CURVE (bench only)."""

        def _bind(self, bind: str, context, polled: bool, curve, max_message_bytes: int,
                  direct_port: int | None) -> None:
            self._ctx = context or fs.zmq.Context(io_threads=fs.IO_THREADS)
            self._sock = frontend.RouterFront(self._ctx, max_message_bytes, codec.MAX_ROUTING_FRAMES + 1, fs.RCVHWM)
            self._sock.set_timeout(fs.POLL_MS)
            self._sock.bind(bind)
            self._address = self._sock.address

    server = RouterServer(bind)
    start_children()
    signal.signal(signal.SIGTERM, lambda signum, frame: server.stop())
    print(f"hydrolink force server listening on {server.address} (bench: ROUTER front end, no CURVE)",
          file=sys.stderr, flush=True)
    server.serve_forever()


def serve_unfrozen(bind: str) -> None:
    """The ``--gc`` server: ``hydrolink serve`` itself, with ``gc.freeze`` a no-op."""
    import gc

    from hydrolink.clients.cli import main as cli
    gc.freeze = lambda: None
    sys.argv = ["hydrolink", "serve", "--bind", bind]
    cli()


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=100.0)
    ap.add_argument("--repeat", type=int, default=3)
    ap.add_argument("--fronts", action="store_true", help="also the ROUTER front end without security (bench-only server)")
    ap.add_argument("--gc", action="store_true", help="also hydrolink serve without its gc.freeze after start-up")
    ap.add_argument("--serve-router", action="store_true", help=argparse.SUPPRESS)   # the --fronts server (a child)
    ap.add_argument("--serve-unfrozen", action="store_true", help=argparse.SUPPRESS)  # the --gc server (a child)
    ap.add_argument("--bind", help=argparse.SUPPRESS)                                 # its endpoint
    args = ap.parse_args()
    if args.serve_router:
        return serve_router(args.bind)
    if args.serve_unfrozen:
        return serve_unfrozen(args.bind)
    from hydrolink.clients.run import run_scene_file
    from hydrolink.protocol.security import client_keys, new_hmac_key, new_key_pair, read_hmac_key

    work = Path(tempfile.mkdtemp(prefix="bench-security-"))
    import tomllib

    from hydrolink.clients.studies.grid import absolute_paths, dump_toml
    rm3 = REPO / "examples" / "rm3" / "rm3.toml"
    doc = absolute_paths(tomllib.loads(rm3.read_text()), rm3)
    doc["simulation"]["duration"] = args.duration
    scene = work / "rm3.toml"
    scene.write_text(dump_toml(doc))
    key_file = new_hmac_key(work / "shared.key")
    new_key_pair(work / "server", "server")
    new_key_pair(work / "clients", "client")
    modes = {
        "plain (direct channel)": ([], {}, {}),
        **({"plain, over ZeroMQ (stream front end)": ([], {}, {"direct": False}), ROUTER: ([], {}, {})}
           if args.fronts else {}),
        **({UNFROZEN: ([], {}, {})} if args.gc else {}),
        "HMAC (--key-file, direct channel)": ([], {"HYDROLINK_KEY_FILE": str(key_file)}, {"key": read_hmac_key(key_file)}),
        "CURVE": (["--curve-secret", str(work / "server" / "server.key_secret"), "--curve-clients",
                   str(work / "clients")], {},
                  {"curve": client_keys(work / "server" / "server.key", work / "clients" / "client.key_secret")}),
    }
    print(f"# bench_security: RM3, {args.duration:g} s, loopback TCP, best of {args.repeat} "
          f"(load {os.getloadavg()[0]:.2f})\n")
    print("| mode | µs/step | vs plain |")
    print("|---|---|---|")
    best = {name: float("inf") for name in modes}
    try:
        for _ in range(args.repeat):   # the modes interleaved: a change of load touches each alike
            for name, (extra, env, client) in modes.items():
                child = {ROUTER: "--serve-router", UNFROZEN: "--serve-unfrozen"}.get(name)
                proc, address = serve(extra, env, [*HYDROLINK, "serve"] if child is None else [sys.executable, __file__, child])
                try:
                    s = run_scene_file(scene, work / "out.nc", server=address, progress=False, **client)
                    best[name] = min(best[name], 1e6 * s.wall_time / s.steps)
                finally:
                    proc.terminate()
                    proc.wait(10)
        base = best["plain (direct channel)"]
        for name, us in best.items():
            print(f"| {name} | {us:.0f} | {us - base:+.0f} µs ({100 * (us / base - 1):+.1f} %) |")
    finally:
        import shutil
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
