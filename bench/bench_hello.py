"""What opening a session costs by the form the HDB travels in (SPEC §5.1, §5.8): the converted map,
the raw files on a miss (the server's store lacks them: hello, error 13, uploads, hello again,
the server reads the files), and the raw files by hash on a hit (nothing sent but 64-character
hashes; the server reuses the HDB it read).

Against a separately started ``hydrolink serve`` over loopback TCP (a fresh store per miss), for
RM3 (WAMIT files, examples/rm3/rm3.toml) and the 9N9LA node array (nine bodies, one HDB built by
Capytaine from examples/node_9n9la/node_9n9la_hdb.toml, sent as its NetCDF file). Each time is the
median over ``--repeat`` hellos of the client's hello call (session closed with bye after it, not
timed); the bytes are those of the hello request(s) and uploads.

    python bench/bench_hello.py [--repeat 5]
"""

from __future__ import annotations

import argparse
import os
import re
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")

from hydrolink.clients.lockstep.connection import ServerConnection  # noqa: E402
from hydrolink.clients.scene_inputs import load_scene_hdbs  # noqa: E402
from hydrolink.protocol import codec  # noqa: E402
from hydrolink.protocol.hdb.wire import HDBFiles, to_wire  # noqa: E402
from hydrolink.protocol.scene import load_scene  # noqa: E402
from hydrolink.server.hdb.io import file_set  # noqa: E402
from hydrolink.protocol.hdb.schema import to_netcdf  # noqa: E402

REPO = Path(__file__).resolve().parents[1]
HYDROLINK = [sys.executable, "-m", "hydrolink.clients.cli"]


class Server:
    """``hydrolink serve`` on a free loopback port with its own store folder."""

    def __init__(self, store: Path):
        self.proc = subprocess.Popen([*HYDROLINK, "serve", "--bind", "tcp://127.0.0.1:*", "--store", str(store)],
                                     stderr=subprocess.PIPE, text=True)
        self.address = re.search(r"listening on (tcp://\S+)", self.proc.stderr.readline()).group(1)

    def close(self) -> None:
        self.proc.terminate()
        self.proc.wait(10)


def timed_hello(address: str, text: str, hdbs: dict) -> tuple[float, int]:
    """Seconds of one hello (uploads included) and the contents uploaded."""
    with ServerConnection(address, timeout=120.0) as conn:
        t0 = time.perf_counter()
        conn.hello(text, hdbs)
        elapsed = time.perf_counter() - t0
        return elapsed, len(conn.uploads)


def bench(name: str, scene_path: Path, files: HDBFiles, repeat: int, tmp: Path) -> None:
    scene, text = load_scene(scene_path)
    key = next(b.hdb for b in scene.bodies if b.hdb)
    ds = load_scene_hdbs(scene, scene_path, progress=False)[key]
    map_bytes = len(codec.pack({"hdbs": {key: to_wire(ds)}}))
    file_bytes = sum(len(v) for v in files.contents().values())
    hash_bytes = len(codec.pack({"hdbs": {key: files.entry()}}))
    times: dict[str, list[float]] = {"map": [], "files, miss": [], "files, hit": []}
    for i in range(repeat):
        server = Server(tmp / f"{name}-store-{i}")   # an empty store: the first files hello misses
        try:
            timed_hello(server.address, text, {key: ds})            # warm the server (imports, first model)
            times["map"].append(timed_hello(server.address, text, {key: ds})[0])
            miss, uploaded = timed_hello(server.address, text, {key: files})
            assert uploaded == len(files.contents()), uploaded
            times["files, miss"].append(miss)
            hit, uploaded = timed_hello(server.address, text, {key: files})
            assert uploaded == 0
            times["files, hit"].append(hit)
        finally:
            server.close()
    print(f"\n{name}: HDB {len(ds['body'])} bodies x {ds['omega'].size} frequencies; map {map_bytes / 1e6:.2f} MB, "
          f"files {file_bytes / 1e6:.2f} MB ({', '.join(p.name for p in files.paths)}), hashes {hash_bytes} B")
    print(f"  {'form':14s} {'hello median':>13s} {'min':>8s} {'max':>8s}")
    for form, values in times.items():
        print(f"  {form:14s} {statistics.median(values) * 1e3:10.1f} ms {min(values) * 1e3:6.1f} ms "
              f"{max(values) * 1e3:6.1f} ms")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--repeat", type=int, default=5)
    args = parser.parse_args()
    print(f"load average {os.getloadavg()[0]:.2f}")
    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        rm3 = REPO / "examples" / "rm3" / "rm3.toml"
        scene, _ = load_scene(rm3)
        bench("RM3 (WAMIT)", rm3, file_set((rm3.parent / scene.bodies[0].hdb).resolve()), args.repeat, tmp)
        node = REPO / "examples" / "node_9n9la" / "node_9n9la.toml"
        scene, _ = load_scene(node)
        built = load_scene_hdbs(scene, node, progress=False)[scene.bodies[0].hdb]
        to_netcdf(built, tmp / "node_9n9la.nc")
        bench("9N9LA (Capytaine-built, NetCDF)", node, HDBFiles("netcdf", (tmp / "node_9n9la.nc",)), args.repeat, tmp)
    print(f"load average {os.getloadavg()[0]:.2f}")


if __name__ == "__main__":
    main()
