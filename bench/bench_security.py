"""Cost per lockstep step of message security on loopback TCP: plain, HMAC-signed (SPEC §3.3,
``--key-file``) and CURVE (SPEC §1.1). RM3 (examples/rm3/rm3.toml), ``hydrolink serve`` in its own
process, the Exudyn client in this one; wall time per step of the whole run loop, best of
``--repeat``.

    python bench/bench_security.py [--duration 100] [--repeat 3]
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


def serve(extra: list[str], env: dict) -> tuple[subprocess.Popen, str]:
    proc = subprocess.Popen([*HYDROLINK, "serve", "--bind", "tcp://127.0.0.1:*", *extra], stderr=subprocess.PIPE,
                            text=True, env={**os.environ, **env})
    line = proc.stderr.readline()
    if "listening on" not in line:
        raise SystemExit(f"server did not start: {line}")
    return proc, line.split("listening on ")[1].split()[0]


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--duration", type=float, default=100.0)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
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
        "plain": ([], {}, {}),
        "HMAC (--key-file)": ([], {"HYDROLINK_KEY_FILE": str(key_file)}, {"key": read_hmac_key(key_file)}),
        "CURVE": (["--curve-secret", str(work / "server" / "server.key_secret"), "--curve-clients",
                   str(work / "clients")], {},
                  {"curve": client_keys(work / "server" / "server.key", work / "clients" / "client.key_secret")}),
    }
    print(f"# bench_security: RM3, {args.duration:g} s, loopback TCP, best of {args.repeat} "
          f"(load {os.getloadavg()[0]:.2f})\n")
    print("| mode | µs/step | vs plain |")
    print("|---|---|---|")
    base = None
    try:
        for name, (extra, env, client) in modes.items():
            proc, address = serve(extra, env)
            try:
                best = float("inf")
                for _ in range(args.repeat):
                    s = run_scene_file(scene, work / "out.nc", server=address, progress=False, **client)
                    best = min(best, 1e6 * s.wall_time / s.steps)
            finally:
                proc.terminate()
                proc.wait(10)
            base = base or best
            print(f"| {name} | {best:.0f} | {best - base:+.0f} µs ({100 * (best / base - 1):+.1f} %) |")
    finally:
        import shutil
        shutil.rmtree(work, ignore_errors=True)


if __name__ == "__main__":
    main()
